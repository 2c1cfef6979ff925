"""The last step of every generation: the network's motion -> one rigid body standing on the floor.

Every output path (generate, edit, control, timelines and streams, the server, the Python API) goes
through `Finish`: the raw joints are rebuilt on the bundle's body (stablemo.motion.rigid), put on
the floor (stablemo.motion.floor), and the features are extracted again from those joints, so the
features file, the joints file, BVH, SMPL, the GIF and the page all show the same body. The root
keeps the network's rotation and path, and the other columns are computed from the new joints as
seen from that root: recovering the features gives these joints back (to float32 rounding) in the
generation's own frame, so joint targets met by the sampler stay met.

The body is the bundle's `body.bone_lengths` (its training data's bone lengths, written by
`stablemo export`), else the skeleton's standard body, which our feature extraction retargets every
training clip to.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numpy as np
import torch

from stablemo.control.spec import ControlTargets
from stablemo.errors import StableMoError
from stablemo.fast import motion as fast_motion
from stablemo.motion.extract_torch import (
    body_columns,
    fill_padding,
    joints_to_features_batched,
    root_relative,
    valid_lengths,
)
from stablemo.motion.features import (
    feature_slices,
    features_to_joints,
    joints_from_ric,
    recover_root,
)
from stablemo.motion.floor import lowest_shift, target_pins
from stablemo.motion.quaternion import norm
from stablemo.motion.rigid import rigid_joint_major
from stablemo.motion.skeleton import Skeleton, get_skeleton


def body_lengths(config: dict, skeleton: Skeleton | str, source: str = "config.json") -> np.ndarray:
    """The body's bone lengths (J,) from a bundle config's `body` entry, else the skeleton's."""
    skel = get_skeleton(skeleton)
    body = config.get("body")
    if body is None:
        return np.array(skel.bone_lengths, dtype=np.float64)
    values = body.get("bone_lengths") if isinstance(body, dict) else None
    try:
        lengths = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        lengths = np.zeros(0)
    if lengths.shape != (skel.num_joints,) or not np.isfinite(lengths).all() or (lengths[1:] <= 0).any():
        raise StableMoError(f"{source}: 'body.bone_lengths' must be {skel.num_joints} finite numbers, > 0 after "
                            f"the root's (skeleton {skel.name})")
    return lengths


GIVEN_FADE = 5  # frames over which a foot anchor fades in beside frames whose feet were given
# A planted ankle (or toe) moves at most this far to its stance's anchor: further, a "stance" is a
# pivot or a mislabelled step. 8 cm before; at 12 cm (72 prompts x 4 seeds, 120 and 196 frames) the
# stance feet slide 18-23 % less (teacher 5.7 -> 4.7 and 4.6 -> 3.9 cm/s, student 10.4 -> 8.0 and
# 10.2 -> 8.0) for FID +0.001 to +0.003, and the teacher walking a path with guidance 1.43 -> 1.27x
# its free walk's (out-and-back); at 16 cm 4.1 / 3.5 / 6.7 / 6.6 cm/s for FID +0.002 to +0.007.
ANCHOR_REACH_M = 0.12
# An ankle faster than this is swinging, whatever its contact channel says: a stance ends there, so a
# channel held on through a step does not average two footfalls into one anchor between them (the
# input-head student's channels do: 0.47 m from a stance's mean at the 90th percentile, against 0.19
# before). Between a sliding stance (the generated walks: ~0.35 m/s) and a swing's peak (2-4 m/s);
# 0.9 m/s (the low-and-slow contact rule's) also cut the slow ends of swings, and the skating ratio
# rose (the 1-step student, tight benchmark: 0.215 against 0.180 unsplit and 0.173 at 1.5).
SWING_SPEED_M_S = 1.5
HOLD_S = 0.25  # a hand's hold on its joint target fades in and out over this many seconds
# A hand without a joint target keeps its arm's generated angles (each bone along its generated
# direction at the body's length), so its wrist moves with the body's arm length. Holding it towards
# its generated wrist instead (half way, shipped on 2026-12-06 and withdrawn the same day) moved the
# 1-step student's hands less (2.30 against 3.01 cm over 72 prompts x 12 seeds at 120 frames) but
# damped what the arm does: the student's raw wrists swing less than its arm's angles carry them
# (a left-hand wave, seed 1: 2.0 cm against 2.8 at the 95th percentile about the running mean), and
# its waves fell below the behaviour suite's 3-cm swing, 73.9 -> 68.8 % of the suite's motions
# passing (a hand's body part 71.2 -> 61.0 %, composites' order 70.3 -> 56.6 %), at FID 0.167
# against 0.157 (raw 0.182); the teacher's hands 1.01 against 0.64 cm, FID 0.128 against 0.127.


class Foot(NamedTuple):
    """One leg's foot as the finishing step plants it: its ankle (the leg's IK end), its tip (the joint
    the side's second contact channel labels: HumanML3D's foot joint, KIT's toe) and every joint
    past the ankle (HumanML3D one, KIT two), parents first."""

    ankle: int
    toe: int
    past: tuple[int, ...]


@dataclass(frozen=True)
class Finish:
    """Raw de-normalised features -> (features, joints) of the rigid body on the floor."""

    skeleton: Skeleton
    bone_lengths: np.ndarray  # (J,) parent -> joint, root 0, skeleton units
    fps: float

    @classmethod
    def from_config(cls, config: dict, skeleton: Skeleton | str, fps: float, source: str = "config.json") -> Finish:
        skel = get_skeleton(skeleton)
        return cls(skel, body_lengths(config, skel, source), float(fps))

    def joints(self, joints: torch.Tensor, lengths, control: ControlTargets | None = None,
               contacts: torch.Tensor | None = None, given: torch.Tensor | None = None) -> torch.Tensor:
        """Raw joints (B, T, J, 3) -> the rigid body on the floor, same shape (padding as given).
        control: the joint targets the motion was generated for; frames with targets keep their
        heights, and a hand with a target reaches it. contacts (B, T, 4): the motion's foot-contact
        channels (features' last four columns), which say when a foot is planted (None: always).
        given (B, T) bool: frames whose feet were given (an edit's kept part): their feet are not
        anchored, and a stance that reaches into them is anchored where they put it."""
        return self.body(joints, lengths, control, contacts, given).permute(2, 3, 0, 1).contiguous()

    def body(self, joints: torch.Tensor, lengths, control: ControlTargets | None = None,
             contacts: torch.Tensor | None = None, given: torch.Tensor | None = None) -> torch.Tensor:
        """Finish.joints, joint-major: raw joints (B, T, J, 3) -> the body (J, 3, B, T). The step keeps
        this layout from the rebuild to the features (stablemo.motion.rigid.rigid_joint_major: every
        joint's coordinates contiguous, so each of its many small steps is one vectorised pass)."""
        t = joints.shape[1]
        mask = None if control is None else control.mask[:, :t].to(joints.device)
        # padding repeats the last frame, so the ramps see each motion as if alone
        n = valid_lengths(lengths, *joints.shape[:2], joints.device)
        contacts = None if contacts is None else fill_padding(contacts.to(joints.device), n)
        held = None if mask is None else fill_padding(mask, n)
        hold = self.hold(joints, held, contacts)
        given = None if given is None else fill_padding(given.to(joints.device), n)
        x = joints.permute(2, 3, 0, 1).contiguous()  # (J, 3, B, T)
        ends = self.anchored(x, hold, n, given)
        body = rigid_joint_major(x, self.skeleton, self.bone_lengths, n, hold, ends, place=fast_motion.place_body)
        body = self.planted_toes(body, ends, hold)
        heights = body[:, 1]  # (J, B, T)
        pins = pinned = held_up = None
        limb_ends = [end for _, _, end in self.skeleton.ik_limbs]
        if control is not None:
            # a limb end's target is reached by the limb (below), whatever the floor does; the other
            # targets (the pelvis, the head) can only be met by the frame's height: they pin it
            trunk = mask.clone()
            trunk[..., limb_ends] = False
            pins, pinned = target_pins(heights.permute(1, 2, 0), control.targets[:, :t].to(body), trunk)
            held_up = pinned.clone()  # frames whose feet are lifted out of the floor if it pins them below
        if given is not None:  # frames whose feet were given keep their heights (no shift), so the kept
            # part of an edit stays where it was; the shift of the new part fades in beside them
            pins = torch.zeros_like(given, dtype=body.dtype) if pins is None else torch.where(given, 0.0, pins)
            pinned = given if pinned is None else pinned | given
        lowest = heights.amin(0)  # (B, T)
        shift = lowest_shift(lowest, n, self.skeleton, self.fps, pins, pinned)  # (B, T): onto the floor
        # a frame a target pins keeps its height, so a foot generated below the floor there would stay
        # below it (an edit's given frames are left as given)
        sunk = None if held_up is None else ((-(lowest + shift)).clamp(min=0) * held_up)  # (B, T)
        targeted = mask is not None and bool(mask[..., limb_ends].any())
        if targeted or (sunk is not None and bool(sunk.any())):
            # the limbs again: each targeted end aimed at its target less the frame's shift, so that it
            # lands on the target once the body is on the floor, and the feet of a pinned frame lifted
            # out of the floor (the knees bend). Only limbs move, so the lowest joint, and the shift,
            # stay as they were unless a targeted hand is the lowest.
            ends = ends.clone()
            if sunk is not None:
                hold = hold.clone()
                lift = (sunk > 0).to(hold.dtype)  # a lifted foot is held where it is lifted to
                for _, _, ankle in self.skeleton.legs.values():
                    ends[ankle, 1] += sunk
                    hold[..., ankle] = torch.maximum(hold[..., ankle], lift)
            if targeted:
                goal = fill_padding(control.targets[:, :t].to(body), n).permute(2, 3, 0, 1)[limb_ends]  # (L, 3, B, T), a copy
                goal[:, 1] -= fill_padding(shift, n)
                aimed = fill_padding(mask, n).permute(2, 0, 1)[limb_ends, None]  # (L, 1, B, T)
                ends[limb_ends] = torch.where(aimed, goal, ends[limb_ends])
            body = self.planted_toes(rigid_joint_major(x, self.skeleton, self.bone_lengths, n, hold, ends,
                                                       place=fast_motion.place_body), ends, hold)
        body[:, 1] += shift
        return body

    def hold(self, joints: torch.Tensor, mask: torch.Tensor | None, contacts: torch.Tensor | None) -> torch.Tensor:
        """How firmly (B, T, J) each limb's end keeps its generated place (stablemo.motion.rigid).

        A foot while it is planted (its contact channels, ramped in and out over a few frames), so
        planted feet stay where they were generated while a swinging leg keeps its generated knee
        angle: holding swinging feet too costs FID (the 196-frame teacher: 0.212 raw, 0.239 held
        always, 0.223 held when planted). A hand on the frames where it has a joint target and,
        fading out, HOLD_S before and after them (so the arm turns from its own angles to the target
        smoothly); other hands keep their arms' angles (the note beside HOLD_S)."""
        skel = self.skeleton
        b, t = joints.shape[:2]
        hold = torch.zeros(b, t, skel.num_joints, dtype=joints.dtype, device=joints.device)
        if mask is not None:
            r = max(1, round(HOLD_S * self.fps))
            m = mask.to(joints.dtype).transpose(1, 2)  # (B, J, T)
            near = torch.nn.functional.max_pool1d(m, 2 * r + 1, 1, r)  # within r frames of a target
            ramp = torch.nn.functional.avg_pool1d(near, 2 * r + 1, 1, r, count_include_pad=False)
            hold = torch.maximum(m, ramp).transpose(1, 2).clone()
        for side, (_, _, ankle) in skel.legs.items():
            if contacts is None:
                planted = torch.ones(b, t, 2, dtype=joints.dtype, device=joints.device)
            else:
                c = contacts[..., :2] if side == "left" else contacts[..., 2:]  # [L_a, L_b, R_a, R_b]
                planted = torch.stack([c.amax(-1), c[..., 1]], -1)  # (B, T, 2): the foot, its toe
                planted = ((planted.to(joints.dtype) - 0.3) / 0.4).clamp(0.0, 1.0)
                planted = torch.nn.functional.avg_pool1d(planted.transpose(1, 2), 5, 1, 2,
                                                         count_include_pad=False).transpose(1, 2)
            hold[..., ankle] = torch.maximum(hold[..., ankle], planted[..., 0])
            hold[..., self.feet[side].toe] = planted[..., 1]  # its own channel: a heel-off keeps the toe down
        return hold

    @cached_property
    def feet(self) -> dict[str, Foot]:
        """Each side's foot (Foot), read from the skeleton once."""
        skel = self.skeleton
        out = {}
        for side, (_, _, ankle) in skel.legs.items():
            below = [ankle]
            for j in range(skel.num_joints):  # parents come before their children
                if skel.parents[j] in below:
                    below.append(j)
            toe = (skel.feet_left if side == "left" else skel.feet_right)[1]
            out[side] = Foot(ankle, toe, tuple(below[1:]))
        return out

    def planted_toes(self, body: torch.Tensor, ends: torch.Tensor, hold: torch.Tensor) -> torch.Tensor:
        """The body (J, 3, B, T), in place, with each foot past its ankle turned about the vertical
        through the ankle, so that its toe points at the toe's anchor (ends (J, 3, B, T)) as firmly as
        the toe's hold (B, T, J) says; returns body.

        The rigid rebuild places a foot along its generated bone directions, so a foot that turns
        while planted sweeps its toe over the floor even with the ankle anchored: the demo teacher
        walking an out-and-back path with guidance, stance toes 18-20 cm/s against its ankles' 8-11
        (scripts/control/heading_check.py's measure per joint). Turned towards the toe's stance
        anchor, the toe stays where the foot was put down; a turn about the vertical keeps the
        foot's pitch and its bones' lengths."""
        for ankle, toe, past in self.feet.values():
            foot = list(past)
            w = hold[..., toe][None]  # (1, B, T)
            own = body[toe, 0::2] - body[ankle, 0::2]  # (2, B, T) on the floor
            own = own / norm(own, 0, keepdim=True).clamp(min=1e-9)
            aim = ends[toe, 0::2] - body[ankle, 0::2]
            aim = aim / norm(aim, 0, keepdim=True).clamp(min=1e-9)
            turn = own + w * (aim - own)
            turn = turn / norm(turn, 0, keepdim=True).clamp(min=1e-9)
            cos = (own * turn).sum(0)  # (B, T): the turn from own to turn, on the (x, z) floor
            sin = own[0] * turn[1] - own[1] * turn[0]
            rel = body[foot][:, 0::2] - body[ankle, 0::2]  # (F, 2, B, T)
            body[foot, 0] = body[ankle, 0] + cos * rel[:, 0] - sin * rel[:, 1]
            body[foot, 2] = body[ankle, 2] + sin * rel[:, 0] + cos * rel[:, 1]
        return body

    def anchored(self, x: torch.Tensor, hold: torch.Tensor, n: torch.Tensor,
                 given: torch.Tensor | None = None) -> torch.Tensor:
        """Joint-major joints x (J, 3, B, T) with each planted ankle's (and toe's: its own channel and
        stances, for planted_toes) horizontal place fixed over its stance.

        A generated stance foot drifts (the demo student's free walks: ~30 cm/s; more where a path
        or guidance moves the pelvis under it), and holding it where it was generated keeps the
        drift. Over each stretch where the foot is planted (hold above one half), the ankle goes to
        one anchor, the stretch's hold-weighted mean place, blended in from the stretch's edges
        (weight 2 hold - 1), so the foot lands, stays and lifts off without a jump; an ankle moves at
        most ANCHOR_REACH_M; a stance ends where the ankle moves faster than SWING_SPEED_M_S. n (B,): valid
        frames (padding takes no part in an anchor, so a motion is finished alike alone or batched);
        given (B, T) bool: frames whose feet the user gave stay as given and pin their stance's anchor."""
        out = x.clone()
        b, t = x.shape[2:]
        valid = torch.arange(t, device=x.device)[None, :] < n[:, None]
        away = None
        if given is not None:  # 0 on given frames, rising to 1 over GIVEN_FADE frames beside them
            r = GIVEN_FADE
            near = torch.nn.functional.max_pool1d(given.to(x.dtype)[:, None], 2 * r + 1, 1, r)
            away = 1 - torch.nn.functional.avg_pool1d(near, 2 * r + 1, 1, r, count_include_pad=False)[:, 0]
            away = torch.where(given, torch.zeros_like(away), away)
        feet = self.feet.values()
        for foot in [f.ankle for f in feet] + [f.toe for f in feet]:  # the ankles, then the toes
            h = hold[..., foot]  # (B, T)
            xz = x[foot, 0::2]  # (2, B, T)
            step = norm(xz[..., 1:] - xz[..., :-1], 0) * self.fps / self.skeleton.per_metre  # (B, T-1) m/s
            step = step * valid[:, 1:]  # no step into the padding: a motion is finished alike alone or batched
            # frame t's speed: the larger of its two steps (a stance ends on both sides of a swing)
            speed = torch.maximum(torch.cat([step[:, :1], step], 1), torch.cat([step, step[:, -1:]], 1))
            inside = (h > 0.5) & valid & (speed < SWING_SPEED_M_S)
            # half the hold on a stance's end frames, so a stance that a swing ends (not the contact
            # channel's own ramp) lets go of its anchor without a jump
            out_of_stance = (~inside & valid).to(x.dtype)[:, None]
            edge = 1 - 0.5 * torch.nn.functional.max_pool1d(out_of_stance, 3, 1, 1)[:, 0]
            lock = ((2 * h - 1) * inside * edge).clamp(0, 1)
            weight = lock  # of each frame in its stance's anchor
            if given is not None:
                weight = weight + 1e3 * (given & inside)  # a given foot decides where its stance is
                lock = lock * away  # and is left as given, the anchor fading in beside it
            start = inside & ~torch.cat([torch.zeros_like(inside[:, :1]), inside[:, :-1]], 1)
            run = start.long().cumsum(1) * inside  # (B, T): 1, 2, ... per stance, 0 outside
            sums = torch.zeros(3, b, t + 1, dtype=x.dtype, device=x.device)
            sums.scatter_add_(2, run[None].expand(3, -1, -1), torch.cat([xz * weight, weight[None]]))
            anchor = sums[:2] / sums[2:].clamp(min=1e-9)  # (2, B, T+1) per stance
            shift = anchor.gather(2, run[None].expand(2, -1, -1)) - xz
            reach = norm(shift, 0, keepdim=True)
            # a "stance" whose foot travels far is a pivot or a mislabelled step: move it a little only
            shift = shift * (ANCHOR_REACH_M * self.skeleton.per_metre / reach.clamp(min=1e-9)).clamp(max=1.0)
            out[foot, 0::2] = xz + lock * shift
        return out

    @torch.no_grad()  # an output step, never differentiated: autograd's bookkeeping cost ~2 % of its time
    def __call__(self, features: torch.Tensor, lengths, control: ControlTargets | None = None,
                 raw_joints: torch.Tensor | None = None,
                 given: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """features (B, T, D), zero past lengths[b] -> (features (B, T, D), joints (B, T, J, 3)), zero on
        padding, the joints recovered from the returned features. raw_joints: the features' joints
        when the caller has them already (the pipeline does). given (B, T) bool: frames whose feet
        an edit kept (see joints).

        The root keeps the network's rotation and path (its first three columns are kept as they
        are): the step moves joints, not the root, so only the columns seen from the root are
        computed again, from the new joints."""
        n = valid_lengths(lengths, *features.shape[:2], features.device)
        raw = features_to_joints(features, self.skeleton) if raw_joints is None else raw_joints.to(features)
        contacts = features[..., feature_slices(self.skeleton)["contacts"]]
        return self.rows(features, self.body(raw, n, control, contacts, given), n)

    @torch.no_grad()
    def rows(self, features: torch.Tensor, body: torch.Tensor, lengths) -> tuple[torch.Tensor, torch.Tensor]:
        """The features (B, T, D) with every column seen from the root computed again from the joint-major
        body (J, 3, B, T), and their joints (B, T, J, 3); both zero past lengths[b]. The root's rotation
        and path columns stay the network's. (__call__'s second half: scripts/results/finish_fid_parts.py
        hands it the raw joints, to measure what the recomputation alone changes.)"""
        n = valid_lengths(lengths, *features.shape[:2], features.device)
        b, t = features.shape[:2]
        q, root = recover_root(features)  # (B, T, 4), (B, T, 3): the root rotation and path recovery will use
        ext, last = self._extended(body, n)
        r = torch.cat([q, q.gather(1, last[..., None].expand(b, 1, 4))], dim=1)  # (B, T+1, 4)
        rows = fast_motion.finish_rows(ext, r, features[..., :3], n, root, self.skeleton)
        if rows is not None:  # the compiled kernel: the same rows in one pass (stablemo.fast.motion)
            return rows
        feats = torch.cat([features[..., :3], body_columns(ext, r, self.skeleton)], dim=-1)
        mask = torch.arange(t, device=features.device)[None, :] < n[:, None]  # (B, T)
        feats = torch.where(mask[..., None], feats, torch.zeros((), dtype=feats.dtype, device=feats.device))
        # the joints are the features' recovery, features_to_joints(feats) on the valid frames, from
        # the very numbers written there (the network's root path, the body's height and ric columns)
        # without reading them back from the interleaved rows
        root = torch.stack([root[..., 0], body[0, 1], root[..., 2]], dim=-1)
        ric = root_relative(body, q.permute(2, 0, 1)[None])  # (J-1, 3, B, T)
        joints = joints_from_ric(q, root, ric.permute(1, 2, 3, 0))
        return feats, torch.where(mask[..., None, None], joints, torch.zeros((), dtype=joints.dtype, device=joints.device))

    @staticmethod
    def _extended(body: torch.Tensor, n: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Joint-major body (J, 3, B, T) -> (J, 3, B, T+1) with frames n.. the last pose moved on by the
        last root step (a rigid move: row n-1's velocities need frame n), and last = n - 1 as (B, 1)."""
        j, _, b, t = body.shape
        frames = torch.arange(t + 1, device=body.device)[None, :]
        last = (n - 1)[:, None]  # (B, 1)
        root = body[0]  # (3, B, T)
        flat = body.new_tensor([1.0, 0.0, 1.0])[:, None, None]
        step = (root.gather(2, last[None].expand(3, b, 1)) - root.gather(2, last[None].expand(3, b, 1) - 1)) * flat
        ahead = (frames - last).clamp(min=0).to(body.dtype)  # (B, T+1)
        index = torch.minimum(frames, last)[None, None].expand(j, 3, b, t + 1)
        return body.gather(3, index) + ahead * step, last  # step (3, B, 1): the horizontal root step

    def features_of(self, body: torch.Tensor, lengths) -> torch.Tensor:
        """Features (B, T, D) float64 of joints (B, T, J, 3) in any frame (a stream's global one), the
        root rotation estimated from the hips and shoulders as in extraction; zero past lengths[b].
        Recovering them gives these joints back when frame 0's root is at the origin facing +z."""
        n = valid_lengths(lengths, *body.shape[:2], body.device)
        ext, _ = self._extended(body.permute(2, 3, 0, 1), n)
        feats = joints_to_features_batched(ext.permute(2, 3, 0, 1), n + 1, self.skeleton, refit=False, place=False)
        mask = torch.arange(body.shape[1], device=body.device)[None, :] < n[:, None]  # (B, T)
        return torch.where(mask[..., None], feats, torch.zeros((), dtype=feats.dtype, device=feats.device))


__all__ = ["Finish", "Foot", "body_lengths"]
