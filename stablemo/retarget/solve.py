"""The retargeting itself: a source's joint positions -> rotations of a target rig, all frames at once.

1. Proportions: the source is scaled by k = the target's leg length (thigh + shin) over the
   source's, about the world origin, so the root's travel is scaled by the leg ratio and the hips
   sit as high as the target's legs carry them; a rig standing on its floor at rest is raised (or
   lowered) so that its planted ankles are as high as its own ankles at rest (_floor_lift).
2. The trunk: the hips turn with the source's pelvis (up: towards the first spine joint; across:
   the legs); the spine and neck joints, whatever their number on either side, are matched by their
   fraction of the chain's length, each aiming where the source's chain runs at that fraction, its
   twist from the pelvis' and the shoulders' across-axis, blended along the chain.
3. Limbs: the feet go where the scaled source's feet are, except while the source plants a foot:
   then the target's foot moves exactly as the source's does (the scaling's offset is frozen over
   the contact, stablemo.retarget.contacts), so no retargeted foot slides more than its source; the
   hands go where the source's hands are (scaled); two-bone IK on the target's own thigh and shin
   (upper arm and forearm) reaches them (stablemo.motion.rigid.two_bone: as close as the straight
   limb reaches when it cannot), bending towards the source's knee (elbow), so no joint flips. Both
   bones of a limb share one bend axis, so the knee and elbow turn as hinges.
4. Clavicles and feet aim as the source's (swing from the parent, twist kept); hands and head turn
   as a BVH source's do, else (joint positions carry no such turn) they, the toes and every joint
   without a role (fingers, twist bones, props) keep their rest pose relative to their parent.

Rest poses: every rotation maps the target's own rest geometry (T-pose, A-pose, bent knees, any
facing) onto the source's pose, so nothing assumes a particular rest. Rotations are world-axis
local rotations (the BVH convention); stablemo.retarget.rest.RestRig.orient carries them to node
frames (glTF).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from stablemo.bvh.rig import Animation, continuous_hemisphere, matrix_to_quat
from stablemo.errors import StableMoError
from stablemo.motion.rigid import two_bone
from stablemo.retarget.contacts import hold, source_contacts
from stablemo.retarget.frames import EPS, across, align, basis, swing, unit, up_axes
from stablemo.retarget.names import LIMBS, SIDES, Roles
from stablemo.retarget.rest import RestRig
from stablemo.retarget.source import Source, guess_per_metre, leg_length


@dataclass(frozen=True)
class Solved:
    """anim: the target rig in motion (world-axis local rotations, root position, source fps);
    positions (T, J, 3) the target's joints; scaled (T, Js, 3) the source's joints scaled by `scale`
    (target units); contacts (T, 4) the source's [L ankle, L toe, R ankle, R toe] contacts; held
    (T, 2) how firmly each foot [L, R] is held by a contact (1 inside one, fading to 0 outside);
    axes (3, 3): the source's world (y up) in the target's (up_axes); roles: the target's."""

    anim: Animation
    positions: np.ndarray
    scaled: np.ndarray
    contacts: np.ndarray
    held: np.ndarray
    scale: float
    axes: np.ndarray
    roles: Roles
    source: Source
    target: RestRig


class _Polyline:
    """Points at fractions of a chain's length, every frame: the chain's joints (T, K, 3) and the
    fractions of its joints (K,) at their median lengths."""

    def __init__(self, points: np.ndarray):
        self.points = points
        lengths = np.median(np.linalg.norm(np.diff(points, axis=1), axis=-1), axis=0) if points.ndim == 3 else \
            np.linalg.norm(np.diff(points, axis=0), axis=-1)
        total = max(float(lengths.sum()), EPS)
        self.fractions = np.concatenate([[0.0], np.cumsum(lengths) / total])

    def at(self, f: float) -> np.ndarray:
        i = int(np.clip(np.searchsorted(self.fractions, f, side="right") - 1, 0, len(self.fractions) - 2))
        span = max(self.fractions[i + 1] - self.fractions[i], EPS)
        w = float(np.clip((f - self.fractions[i]) / span, 0.0, 1.0))
        return self.points[..., i, :] * (1 - w) + self.points[..., i + 1, :] * w


def solve(source: Source, target: RestRig, roles: Roles, contacts_cfg: dict) -> Solved:
    """Rotations of `target` (its roles: `roles`) following `source`; contacts_cfg: height_m,
    speed_m_s, ramp_s (stablemo/assets/retarget/humanoid.yaml)."""
    rest = target.rest  # (J, 3)
    sr = source.roles
    leg_t, leg_s = leg_length(rest, roles), source.leg_length()
    if leg_t <= EPS or leg_s <= EPS:
        raise StableMoError(f"{target.path if leg_t <= EPS else 'motion'}: legs of zero length")
    k = leg_t / leg_s
    unit_scale = guess_per_metre(leg_t) / source.per_metre  # target units per source unit
    axes = up_axes(rest, roles, target.path)
    contacts = _contacts(source, contacts_cfg)
    up = axes[:, 1]  # the rig's up axis
    standing = _stands(rest @ up, roles, leg_t)
    lift = up * (_floor_lift(source, rest @ up, roles, k, contacts, leg_t) if standing else 0.0)  # (3,)
    x = k * source.positions @ axes.T + lift  # (T, Js, 3) the source in the target's units, axes and floor
    frames = len(x)

    def src(side: str, role: str) -> np.ndarray:
        return x[:, sr.sides[side][role]]

    def tgt(side: str, role: str) -> np.ndarray:
        return rest[roles.sides[side][role]]

    # pelvis and chest frames: up and across (the body's left, +x for a body facing +z)
    up_s, up_r = x[:, sr.spine[0]] - x[:, sr.hips], rest[roles.spine[0]] - rest[roles.hips]
    hip_lat_s, hip_lat_r = src("Left", "UpperLeg") - src("Right", "UpperLeg"), tgt("Left", "UpperLeg") - tgt("Right", "UpperLeg")
    # the chest's across-axis: from the clavicles where both rigs have them (they sit on the chest),
    # else from the shoulders
    arm = "Shoulder" if all("Shoulder" in r.sides[side] for r in (sr, roles) for side in SIDES) else "UpperArm"
    chest_lat_s, chest_lat_r = src("Left", arm) - src("Right", arm), tgt("Left", arm) - tgt("Right", arm)
    forward_s, forward_r = unit(np.cross(hip_lat_s, up_s)), unit(np.cross(hip_lat_r, up_r))
    top_s = x[:, (sr.neck or (sr.head,))[0]] - x[:, sr.spine[-1]]
    top_r = rest[(roles.neck or (roles.head,))[0]] - rest[roles.spine[-1]]
    chest_fwd_s, chest_fwd_r = unit(np.cross(chest_lat_s, top_s)), unit(np.cross(chest_lat_r, top_r))

    frames_of: dict[int, np.ndarray] = {roles.hips: align(up_s, hip_lat_s, up_r, hip_lat_r)}
    # the pelvis is placed by its hip joints, not its centre: the legs then start where the scaled
    # source's do, whatever shape the two pelvises have (a hip joint 5 cm higher than the source's
    # would leave a straight leg 5 cm short of its foot)
    hip_mid_s = 0.5 * (src("Left", "UpperLeg") + src("Right", "UpperLeg"))
    hip_mid_r = 0.5 * (tgt("Left", "UpperLeg") + tgt("Right", "UpperLeg"))
    hips_at = hip_mid_s - frames_of[roles.hips] @ (hip_mid_r - rest[roles.hips])  # (T, 3)
    frames_of.update(_trunk_frames(x, rest, sr, roles, (hip_lat_s, hip_lat_r), (chest_lat_s, chest_lat_r)))

    ramp = max(1, round(contacts_cfg["ramp_s"] * source.fps))
    limbs = {}  # upper joint -> what its IK needs
    held = np.zeros((frames, 2))
    swings = {}  # joint -> (rest direction (3,), direction now (T, 3))
    for s_i, side in enumerate(SIDES):
        for limb, (upper, mid, end) in LIMBS.items():
            ju, jm, je = (roles.sides[side][r] for r in (upper, mid, end))
            if limb == "leg":
                goal, held[:, s_i] = _planted(source, k, unit_scale, side, contacts[:, 2 * s_i:2 * s_i + 2], ramp)
                goal = goal @ axes.T + lift
                fallback_s, fallback_r = forward_s, forward_r  # knees bend forward
            else:
                goal = src(side, end)
                fallback_s, fallback_r = -chest_fwd_s, -chest_fwd_r  # elbows bend backward
            bend_r = across(rest[jm] - rest[ju], rest[je] - rest[ju])
            if np.linalg.norm(bend_r) < 0.02 * np.linalg.norm(rest[jm] - rest[ju]):  # straight at rest
                bend_r = across(fallback_r, rest[jm] - rest[ju])
            # the source's own bend (its middle joint across its upper->end line), with a slight pull
            # the natural way (knees forward, elbows back) that only decides where it is straight
            l1 = float(np.linalg.norm(rest[jm] - rest[ju]))
            bend_s = across(src(side, mid) - src(side, upper), src(side, end) - src(side, upper))
            straight = np.maximum(0.0, 0.05 * l1 - np.linalg.norm(bend_s, axis=-1, keepdims=True))  # (T, 1)
            pole_offset = bend_s + straight * fallback_s
            limbs[ju] = (jm, je, goal, pole_offset, fallback_s, unit(bend_r))
        for role, child in (("Foot", "Toes"), ("Shoulder", "UpperArm")):
            jt, jc = roles.sides[side].get(role), roles.sides[side].get(child)
            js, jsc = sr.sides[side].get(role), sr.sides[side].get(child)
            if None not in (jt, jc, js, jsc):
                now = x[:, jsc] - x[:, js]
                if role == "Foot" and standing:
                    now = _foot_pitch(now, rest[jc] - rest[jt], up, contacts[:, 2 * s_i:2 * s_i + 2].all(-1))
                swings[jt] = (rest[jc] - rest[jt], now)

    frames_of.update(_turned_ends(source, target, roles, axes, hip_lat_r))
    world, pos = _pose(target, rest, roles, hips_at, frames_of, limbs, swings)
    parents = np.array(target.parents)
    parent_world = np.where((parents >= 0)[None, :, None, None], world[:, np.maximum(parents, 0)], np.eye(3))
    local = np.swapaxes(parent_world, -1, -2) @ world  # (T, J, 3, 3)
    if not np.all(np.isfinite(local)) or not np.all(np.isfinite(pos)):
        raise StableMoError("retarget: the solve gave a non-finite pose (coinciding joints in the motion or the rig?)")
    rotations = continuous_hemisphere(matrix_to_quat(local))
    anim = Animation(target.bvh_rig(), pos[:, 0].copy(), rotations, source.fps)
    return Solved(anim, pos, x, contacts, held, k, axes, roles, source, target)


def _pose(target: RestRig, rest: np.ndarray, roles: Roles, hips_at: np.ndarray, frames_of: dict, limbs: dict,
          swings: dict) -> tuple[np.ndarray, np.ndarray]:
    """Forward through the rig, parents first -> world rotations (T, J, 3, 3) and positions (T, J, 3):
    the root carries the hips to hips_at (T, 3); frames_of: joints turned as given; limbs: upper
    joints whose limb is solved by IK on the way (their middle joints then too); swings: joints aimed
    from their parent's frame; every other joint keeps its rest under its parent."""
    frames = len(hips_at)
    world = np.empty((frames, target.num_joints, 3, 3))
    pos = np.empty((frames, target.num_joints, 3))
    pending: dict[int, np.ndarray] = {}  # a limb's middle joint -> its world rotation, set with the limb
    eye = np.broadcast_to(np.eye(3), (frames, 3, 3))
    for j, p in enumerate(target.parents):
        parent = world[:, p] if p >= 0 else eye
        if p < 0:  # the joints above the hips stay at rest, so the root carries the hips' travel
            pos[:, j] = hips_at - (rest[roles.hips] - rest[j])
        else:
            pos[:, j] = pos[:, p] + parent @ target.offsets[j]
        if j in frames_of:
            world[:, j] = frames_of[j]
        elif j in limbs:
            jm, je, goal, pole_offset, fallback, bend_r = limbs[j]
            mid, end, bend = _reach(pos[:, j], goal, pos[:, j] + pole_offset, fallback, rest[jm] - rest[j],
                                    float(np.linalg.norm(rest[jm] - rest[j])), float(np.linalg.norm(rest[je] - rest[jm])))
            world[:, j] = align(mid - pos[:, j], bend, rest[jm] - rest[j], bend_r)
            pending[jm] = align(end - mid, bend, rest[je] - rest[jm], bend_r)
        elif j in pending:
            world[:, j] = pending.pop(j)
        elif j in swings:
            rest_dir, now = swings[j]
            world[:, j] = swing(parent @ rest_dir, now) @ parent
        else:
            world[:, j] = parent
    return world, pos


def _stands(heights: np.ndarray, roles: Roles, leg: float) -> bool:
    """Whether a rig is drawn standing on its floor at rest: its lowest joint on y = 0 (within 2 % of
    its leg) and its ankles above it as a foot holds them (by 2 % of the leg, above the toes too).
    Characters are modelled so (Blender, Mixamo, Unreal, VRM); a rig hanging from its root at the
    origin (our own BVH), or one whose ankles lie on the floor, says nothing of how its feet stand.
    heights (J,): the rest joints along the rig's up axis."""
    if abs(heights.min()) > 0.02 * leg:
        return False
    for side in SIDES:
        ankle, toes = heights[roles.sides[side]["Foot"]], heights[roles.sides[side].get("Toes", roles.sides[side]["Foot"])]
        if ankle - heights.min() < 0.02 * leg or (toes != ankle and ankle - toes < 0.02 * leg):
            return False
    return True


def _floor_lift(source: Source, heights: np.ndarray, roles: Roles, k: float, contacts: np.ndarray,
                leg: float) -> float:
    """How far (target units) to raise everything so the rig's planted ankles stand as high above
    its floor as its own ankles do at rest: rigs that stand on the floor at rest (Blender, Mixamo,
    Unreal, VRM) have feet of their own height (the Rigify metarig's ankles are 8.5 cm up, a scaled
    HumanML3D foot's 6 cm). heights (J,): the rig's rest joints along its up axis. Only for such
    rigs: one hanging from its root at the origin (our own BVH) says nothing of its floor."""
    rest_ankles = np.mean([heights[roles.sides[side]["Foot"]] for side in SIDES])
    planted = []
    for s_i, side in enumerate(SIDES):
        ankle = source.positions[:, source.roles.sides[side]["Foot"], 1]
        planted.append(ankle[contacts[:, 2 * s_i]])
    planted = np.concatenate(planted)
    if len(planted) == 0:  # never planted (a jump caught mid-air): nothing to stand on
        return 0.0
    return float(np.clip(rest_ankles - k * np.median(planted), -0.1 * leg, 0.1 * leg))


def _foot_pitch(now: np.ndarray, rest_dir: np.ndarray, up: np.ndarray, flat: np.ndarray) -> np.ndarray:
    """Foot directions (T, 3) pitched so that where the source's foot is flat on the floor (`flat`
    (T,): ankle and toe planted) the rig's foot has its own rest pitch: feet are drawn differently
    (a HumanML3D toe joint sits on the floor, 20 degrees below its ankle; the Rigify metarig's toe
    bone starts 7 cm below its ankle), and copying the direction would tilt a flat foot. The foot's
    heading and its pitch's changes are the source's."""
    if not flat.any():
        return now
    d = unit(now)
    pitch = np.arcsin(np.clip(d @ up, -1.0, 1.0))  # (T,) radians, negative: pointing down
    level = unit(across(d, up))
    rest_pitch = float(np.arcsin(np.clip(unit(rest_dir) @ up, -1.0, 1.0)))
    new = pitch + rest_pitch - float(np.median(pitch[flat]))
    return np.linalg.norm(now, axis=-1, keepdims=True) * (np.cos(new)[:, None] * level + np.sin(new)[:, None] * up)


def _trunk_frames(x: np.ndarray, rest: np.ndarray, sr: Roles, roles: Roles, hip_lat: tuple, chest_lat: tuple) -> dict:
    """World rotations (T, 3, 3) of the rig's spine and neck joints: the trunk hips -> spine -> first
    neck joint (or head) and the neck chain up to the head, matched by fraction of length; twist from
    the across-axes (source (T, 3), rig (3,)) of the hips and the chest, blended up the spine.
    x (T, Js, 3): the scaled source; rest (J, 3): the rig at rest."""
    out = {}
    trunk_t = [roles.hips, *roles.spine, (roles.neck or (roles.head,))[0]]
    trunk_s = _Polyline(x[:, [sr.hips, *sr.spine, (sr.neck or (sr.head,))[0]]])
    trunk_r = _Polyline(rest[trunk_t])
    chest_at = trunk_r.fractions[len(roles.spine)]  # the last spine joint's fraction: its twist is the chest's
    for i, joint in enumerate(roles.spine):
        f0, f1 = trunk_r.fractions[i + 1], trunk_r.fractions[i + 2]
        w = f0 / max(chest_at, EPS)
        out[joint] = align(trunk_s.at(f1) - trunk_s.at(f0), (1 - w) * hip_lat[0] + w * chest_lat[0],
                           rest[trunk_t[i + 2]] - rest[trunk_t[i + 1]], (1 - w) * hip_lat[1] + w * chest_lat[1])
    if roles.neck:
        neck_t = [*roles.neck, roles.head]
        neck_s = _Polyline(x[:, [*(sr.neck or (sr.spine[-1],)), sr.head]])
        neck_r = _Polyline(rest[neck_t])
        for i, joint in enumerate(roles.neck):
            f0, f1 = neck_r.fractions[i], neck_r.fractions[i + 1]
            out[joint] = align(neck_s.at(f1) - neck_s.at(f0), chest_lat[0], rest[neck_t[i + 1]] - rest[neck_t[i]],
                               chest_lat[1])
    return out


def _turned_ends(source: Source, target: RestRig, roles: Roles, axes: np.ndarray, hip_lat_r: np.ndarray) -> dict:
    """World rotations (T, 3, 3) of the rig's hands and head where the source is a BVH file whose
    hands and head turn on their own: each takes its source joint's turn from rest, the two rest
    bones matched first (their direction, and the hips' across-axis for the twist), so a rig whose
    hands hang in an A-pose follows a T-pose file's wrists. Empty for joint positions alone."""
    if source.orient is None:
        return {}
    sr, out = source.roles, {}
    lat_s = axes @ (source.rest[sr.sides["Left"]["UpperLeg"]] - source.rest[sr.sides["Right"]["UpperLeg"]])
    pairs = [(roles.head, sr.head)] + [(roles.sides[side]["Hand"], sr.sides[side]["Hand"]) for side in SIDES]
    for jt, js in pairs:
        kids = [c for c, p in enumerate(target.parents) if p == jt]
        t_dir = target.offsets[kids[0]] if kids else target.end_sites.get(jt)
        if t_dir is None or js not in source.ends or np.linalg.norm(t_dir) <= EPS:
            continue
        rest_match = basis(axes @ source.ends[js], lat_s) @ basis(t_dir, hip_lat_r).T  # rig rest -> file rest
        out[jt] = axes @ source.orient[:, js] @ axes.T @ rest_match
    return out


def _contacts(source: Source, cfg: dict) -> np.ndarray:
    """(T, 4) [L ankle, L toe, R ankle, R toe] contacts of the source (a missing toe: its ankle's)."""
    feet = []
    for side in SIDES:
        ankle = source.roles.sides[side]["Foot"]
        feet += [ankle, source.roles.sides[side].get("Toes", ankle)]
    return source_contacts(source.positions[:, feet] / source.per_metre, source.fps, cfg["height_m"], cfg["speed_m_s"])


def _planted(source: Source, k: float, unit_scale: float, side: str, contact: np.ndarray,
             ramp: int) -> tuple[np.ndarray, np.ndarray]:  # in the source's axes
    """(T, 3) where the target's ankle goes, and (T,) how firmly it is held: the scaled source's ankle, except while the source's foot
    is planted (its ankle or its toe): then the scaling's offset is frozen at its value at the
    contact's mean place, so the target's foot moves exactly as the source's does (in metres), and
    a foot the source plants stays planted however much larger or smaller the target is.
    unit_scale: target units per source unit (1 when both are in metres)."""
    ankle = source.positions[:, source.roles.sides[side]["Foot"]]  # (T, 3) source units
    w, held = hold(ankle, contact.any(-1), ramp)
    frozen = w[:, None] * held + (1.0 - w[:, None]) * ankle
    return unit_scale * ankle + (k - unit_scale) * frozen, w


def _reach(upper, goal, pole, fallback, rest_dir, l1: float, l2: float):
    """Two-bone IK (stablemo.motion.rigid.two_bone) -> middle (T, 3), end (T, 3), and the bend
    direction (T, 3): across the upper->end line, towards the middle joint (or the pole where the
    limb is straight, or `fallback` where the pole is on the line too)."""
    t = [torch.from_numpy(np.ascontiguousarray(a, dtype=np.float64)) for a in
         (upper, goal, pole, fallback, np.broadcast_to(unit(rest_dir), upper.shape))]
    mid, end = (v.numpy() for v in two_bone(*t, l1, l2))
    line = end - upper
    bend = across(mid - upper, line)
    for alt in (across(pole - upper, line), across(fallback, line)):
        bend = np.where(np.linalg.norm(bend, axis=-1, keepdims=True) > 1e-4 * l1, bend, alt)
    return mid, end, unit(bend)
