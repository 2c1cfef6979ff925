"""Generated joints -> one rigid body: every bone at the body's length, the root's path kept, planted
feet (and hands with targets) where they were generated when the rigid limb can reach them.

A denoiser predicts joint positions (the features' ric part) independently per joint, so its bones
change length within a motion (the demo models: 10-30 cm). This step rebuilds the pose from the
root outwards:

- the trunk (spine, neck, head, hips, collars, shoulders) and every bone beyond a hand or a foot by
  forward kinematics: each bone keeps its generated direction and takes the body's length, except
  the children of a branching joint (the hips and spine around the pelvis; the neck and collars
  around the upper chest), which keep one shape per motion, turned with the joint's frame, so the
  pelvis and chest are rigid too (a BVH or SMPL rig, whose pelvis is one bone, then fits exactly);
- each two-bone limb of the skeleton (`Skeleton.ik_limbs`: hip-knee-ankle, shoulder-elbow-wrist)
  with its generated angles (each bone along its generated direction), pulled by analytic
  two-bone IK towards the end's generated position as firmly as `hold` says (default: feet fully,
  hands not; stablemo.inference.finish holds a foot while it is planted and a hand on the frames
  of its joint target). The IK reaches the end where the limb can, else as close as the straight limb reaches
  along the same line; the middle joint (knee, elbow) bends in the plane the limb's own angles give,
  so a knee never flips backwards.

The root's horizontal path is kept. Its height moves (`_leg_drop`) so that the supporting leg
reaches its generated foot with its generated knee angle: a denoiser's stretched legs carry the
pelvis too high, its short ones too low. Everything is closed form and vectorised over batch and
frames, on the joints' device. Applied to a motion that is already rigid with these lengths it
returns the motion unchanged (up to rounding).
"""

from __future__ import annotations

import numpy as np
import torch

from stablemo.errors import StableMoError
from stablemo.motion.extract_torch import fill_padding, smooth_frames
from stablemo.motion.quaternion import cross, norm
from stablemo.motion.skeleton import Skeleton, get_skeleton

_EPS = 1e-9
# the most the root moves up or down to let the supporting leg keep its foot and knee angle: legs
# generated far too long in a wide stride would otherwise drop the body into a lunge (the README's
# prompt: 37 cm); beyond it the foot lands as close as the leg reaches
MAX_ROOT_MOVE_M = 0.10


def _unit(v: torch.Tensor, dim: int = -1) -> tuple[torch.Tensor, torch.Tensor]:
    """(unit vector, norm (keeping axis dim)) over the component axis dim; a zero vector stays zero."""
    size = norm(v, dim, keepdim=True)
    return v / size.clamp(min=_EPS), size


def _dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """a · b over the leading component axis (3, ...) -> (1, ...)."""
    return (a * b).sum(0, keepdim=True)


def two_bone(upper: torch.Tensor, target: torch.Tensor, pole: torch.Tensor, fallback_bend: torch.Tensor,
             rest_dir: torch.Tensor, l1, l2, dim: int = -1) -> tuple[torch.Tensor, torch.Tensor]:
    """Middle and end positions (B, T, 3) of a limb rooted at `upper` whose end aims at `target`.

    pole: the generated middle joint, whose side of the upper->target line sets the bend plane;
    fallback_bend: the bend direction where the generated limb is straight (knees forward, elbows
    back); rest_dir: the aim where the target sits on the upper joint itself. l1, l2: the bones'
    lengths, numbers or tensors that broadcast (rigid_joints solves all limbs at once, (L, 3, B, T)
    with lengths (L, 1, 1, 1)). dim: the component axis.
    """
    aim, dist = _unit(target - upper, dim)
    aim = torch.where(dist > _EPS, aim, rest_dir)
    # the reachable distance: neither longer than the straight limb nor shorter than the folded one
    d = torch.clamp(dist, min=abs(l1 - l2) + 1e-6, max=l1 + l2)
    to_pole = pole - upper
    bend = to_pole - (to_pole * aim).sum(dim, keepdim=True) * aim  # the pole's part across the aim line
    bend, across = _unit(bend, dim)
    alt = fallback_bend - (fallback_bend * aim).sum(dim, keepdim=True) * aim
    alt = _unit(alt, dim)[0]
    bend = torch.where(across > 1e-4 * l1, bend, alt)
    cos_a = ((l1 * l1 + d * d - l2 * l2) / (2.0 * l1 * d)).clamp(-1.0, 1.0)
    sin_a = (1.0 - cos_a * cos_a).clamp(min=0.0).sqrt()
    middle = upper + l1 * (cos_a * aim + sin_a * bend)
    return middle, upper + d * aim


def _branch_directions(x: torch.Tensor, skel: Skeleton, valid: torch.Tensor) -> dict[int, torch.Tensor]:
    """Where each child of a joint with several children (the pelvis, the upper chest) points,
    x (J, 3, B, T) -> {child: unit direction (3, B, T)}.

    A bone-by-bone rebuild keeps every length but lets the hips, or the neck and collars, swing
    against each other: the pelvis would change width. Here each such joint gets a frame per frame
    (y: towards its up child, the spine; x: from its -x child to its +x child, the body's right and
    left), the children's offsets are read in that frame, and their mean direction over the motion's
    valid frames (B, T) becomes the joint's fixed shape, turned back with the frame. Joints without
    an up and two side children are left to the bone-by-bone rule."""
    raw = skel.raw_offsets
    out = {}
    weight = valid.to(x.dtype)[None]  # (1, B, T): the mean unit offset over the valid frames
    for parent in range(skel.num_joints):
        kids = [c for c in range(skel.num_joints) if skel.parents[c] == parent]
        up = [c for c in kids if raw[c][1] > 0.5]
        pos = [c for c in kids if raw[c][0] > 0.5]
        neg = [c for c in kids if raw[c][0] < -0.5]
        if len(kids) < 2 or len(up) != 1 or len(pos) != 1 or len(neg) != 1:
            continue
        y = _unit(x[up[0]] - x[parent], 0)[0]  # (3, B, T) the frame's columns xa, y, z
        side = x[pos[0]] - x[neg[0]]
        xa = _unit(side - _dot(side, y) * y, 0)[0]
        z = cross(xa, y, 0)
        offset = x[kids] - x[parent]  # (K, 3, B, T), all children at once
        local = torch.stack([(offset * axis).sum(1) for axis in (xa, y, z)], 1)  # (K, 3, B, T) in the frame
        shape = _unit((_unit(local, 1)[0] * weight).sum(-1, keepdim=True) / weight.sum(-1, keepdim=True).clamp(min=1.0), 1)[0]
        turned = xa * shape[:, :1] + y * shape[:, 1:2] + z * shape[:, 2:]  # (K, 3, B, T)
        out.update(zip(kids, turned.unbind(0)))
    return out


def rigid_joints(joints: torch.Tensor, skeleton: Skeleton | str, bone_lengths=None, lengths=None,
                 hold: torch.Tensor | None = None, ends: torch.Tensor | None = None) -> torch.Tensor:
    """joints (B, T, J, 3) or (T, J, 3) -> the same shape on the body with `bone_lengths` (J,)
    parent -> joint, root 0, in the skeleton's units (None: the skeleton's standard body); lengths
    (B,): valid frames per motion (the shapes of the pelvis and chest are measured on those).

    hold (B, T, J) in [0, 1]: how firmly each limb's end (ankle, wrist) stays where it was generated;
    0 keeps the limb's generated angles instead (its end moves with the body's lengths). Default:
    feet 1 (planted feet stay planted), hands 0. Why hands keep angles: the demo models' upper arms
    are a third short, and reaching the generated wrists with arms of the body's length folds the
    elbows; on the synthetic benchmark that costs FID 0.15 -> 0.23 and R@3 0.77 -> 0.66, keeping
    the angles costs nothing (0.16, 0.77), for hands 4.7 cm further out on average (measured on the
    models of that time; stablemo.inference.finish, beside HOLD_S, has today's). ends (B, T, J, 3): where a held end goes
    (default: where it was generated; the finishing step gives planted feet their anchors).

    The work runs joint-major, (J, 3, B, T) (rigid_joint_major)."""
    skel = get_skeleton(skeleton)
    joints = torch.as_tensor(joints)
    if joints.dim() not in (3, 4) or tuple(joints.shape[-2:]) != (skel.num_joints, 3) or not joints.is_floating_point():
        raise StableMoError(f"joints: expected a float array (B, T, {skel.num_joints}, 3) for skeleton {skel.name}, "
                            f"got {tuple(joints.shape)} {joints.dtype}")
    if joints.dim() == 3:
        return rigid_joints(joints[None], skel, bone_lengths, None if lengths is None else [lengths],
                            None if hold is None else torch.as_tensor(hold)[None],
                            None if ends is None else torch.as_tensor(ends)[None])[0]
    ends = None if ends is None else torch.as_tensor(ends).to(joints).permute(2, 3, 0, 1)  # joint-major
    out = rigid_joint_major(joints.permute(2, 3, 0, 1).contiguous(), skel, bone_lengths, lengths, hold, ends)
    return out.permute(2, 3, 0, 1).contiguous()


def rigid_joint_major(x: torch.Tensor, skeleton: Skeleton | str, bone_lengths=None, lengths=None,
                      hold: torch.Tensor | None = None, ends: torch.Tensor | None = None,
                      place=None) -> torch.Tensor:
    """rigid_joints on joint-major joints x (J, 3, B, T) -> the body (J, 3, B, T); ends (J, 3, B, T)
    joint-major too, hold (B, T, J) as there. place: a compiled twin of the per-frame steps below
    (every bone's step, then trunk, limbs, feet; stablemo.fast.motion.place_body, which the finishing
    step hands in), called with its inputs and returning the body or None (then PyTorch places it).

    Joint-major, each joint's x, y and z are one contiguous block, so the many small steps of the
    rebuild (a few per bone) are vectorised passes; on (B, T, J, 3) every one strode over the
    interleaved coordinates, and this step cost as much as the network. The finishing step keeps
    its motion in this layout from the rebuild to the features."""
    skel = get_skeleton(skeleton)
    body = np.asarray(skel.bone_lengths if bone_lengths is None else bone_lengths, dtype=np.float64)
    if body.shape != (skel.num_joints,) or not np.isfinite(body).all() or (body[1:] <= 0).any():
        raise StableMoError(f"bone_lengths: expected {skel.num_joints} finite lengths > 0 (root 0) for skeleton "
                            f"{skel.name}, got shape {body.shape}")
    j, _, b, t = x.shape
    frames_n = torch.full((b,), t) if lengths is None else torch.as_tensor(lengths).reshape(-1).cpu()
    valid = (torch.arange(t)[None, :] < frames_n[:, None]).to(x.device)  # (B, T)
    legs = {ankle for _, _, ankle in skel.legs.values()}
    uppers, mids, ends_at = (list(v) for v in zip(*skel.ik_limbs))
    raw_dir = torch.tensor(np.array(skel.raw_offsets), dtype=x.dtype, device=x.device)[..., None, None]  # (J, 3, 1, 1)
    lengths_j = torch.tensor(body, dtype=x.dtype, device=x.device)[:, None, None, None]  # (J, 1, 1, 1)

    turned = _branch_directions(x, skel, valid)  # a branching joint's children: its shape, turned

    def directions(joints: list[int]) -> torch.Tensor:
        """Each joint's bone direction (K, 3, B, T): its generated one (its rest direction where the bone
        has none; a CPU check is free), or its branching parent's turned shape."""
        direction, size = _unit(x[joints] - x[[skel.parents[c] for c in joints]], 1)
        if x.is_cuda or bool((size <= _EPS).any()):
            direction = torch.where(size > _EPS, direction, raw_dir[joints])
        for k, c in enumerate(joints):
            if c in turned:
                direction[k] = turned[c]
        return direction

    # the hips from the generated root first (the leg's reach sets the root's height), with the legs'
    # own bone directions
    paths = []
    for upper in (u for u, _, e in skel.ik_limbs if e in legs):
        path = [upper]
        while skel.parents[path[-1]] != 0:
            path.append(skel.parents[path[-1]])
        paths.append(path[::-1])
    few = sorted({c for path in paths for c in path} | {c for _, m, e in skel.legs.values() for c in (m, e)})
    some = dict(zip(few, directions(few).unbind(0)))
    hips: list[torch.Tensor | None] = [None] * j
    hips[0] = x[0]
    for path in paths:
        for joint in path:
            hips[joint] = hips[skel.parents[joint]] + lengths_j[joint] * some[joint]
    out = torch.empty_like(x)  # (J, 3, B, T), filled parents before children
    out[0] = x[0]
    out[0, 1] += _leg_drop(hips, x, some, skel, body, valid)  # the root moves vertically only

    limbs = set(mids) | set(ends_at)
    beyond = set()  # joints past a limb's end (the feet), placed from the end the IK gives
    for chain in skel.kinematic_chains:
        for parent, child in zip(chain[:-1], chain[1:]):
            if parent in ends_at or parent in beyond:
                beyond.add(child)
    order = [c for chain in skel.kinematic_chains for c in chain[1:]]
    trunk = [c for c in order if c not in limbs and c not in beyond]
    beyond = [c for c in order if c in beyond]
    forward = _facing(x, skel)
    # knees bend forward, elbows backward, where the generated limb is straight
    side = torch.tensor([1.0 if e in legs else -1.0 for e in ends_at], dtype=x.dtype, device=x.device)
    if hold is None:
        w = torch.tensor([float(e in legs) for e in ends_at], dtype=x.dtype, device=x.device)[:, None, None]
        w = w.expand(len(ends_at), b, t)
    else:
        w = torch.as_tensor(hold).to(x)[..., ends_at].permute(2, 0, 1)  # (L, B, T)
    goal = (x if ends is None else ends)[ends_at]  # (L, 3, B, T)
    placed = None if place is None else place(x, turned, out[0], forward, w, goal, skel, trunk, beyond, side,
                                              raw_dir[:, :, 0, 0], lengths_j[:, 0, 0, 0])
    if placed is not None:
        return placed

    # every joint's step from its parent (J, 3, B, T), the body's length along its direction (row 0 unused)
    steps = lengths_j * torch.cat([torch.zeros_like(x[:1]), directions(list(range(1, j)))])

    for child in trunk:  # the trunk: its generated directions at the body's lengths
        torch.add(out[skel.parents[child]], steps[child], out=out[child])
    # each limb with its generated angles, then pulled by two-bone IK towards its end's goal as
    # firmly as `hold` says; one limb at a time: a (3, B, T) block stays under PyTorch's size for
    # splitting an operation across threads, whose every split waits for a second core
    for i, (upper, mid, end) in enumerate(skel.ik_limbs):
        middle = out[upper] + steps[mid]
        kept = middle + steps[end]
        out[mid], out[end] = two_bone(out[upper], kept + w[i, None] * (goal[i] - kept), middle, side[i] * forward,
                                      raw_dir[mid], lengths_j[mid], lengths_j[end], dim=0)
    for child in beyond:
        torch.add(out[skel.parents[child]], steps[child], out=out[child])
    return out


def _facing(x: torch.Tensor, skel: Skeleton) -> torch.Tensor:
    """Unit forward direction (3, B, T) of the hips and shoulders (up × across), horizontal;
    x (J, 3, B, T)."""
    r_hip, l_hip, r_sdr, l_sdr = skel.face_joints
    across = (x[l_hip] - x[r_hip]) + (x[l_sdr] - x[r_sdr])
    # (0, 1, 0) × across, written out
    return _unit(torch.stack([across[2], torch.zeros_like(across[0]), -across[0]]), 0)[0]


def _leg_drop(placed: list, x: torch.Tensor, directions: list, skel: Skeleton, body: np.ndarray,
              valid: torch.Tensor) -> torch.Tensor:
    """How far (B, T) to move the root up or down so that the supporting leg reaches its foot with
    the knee bent as generated; x (J, 3, B, T), placed per joint (3, B, T), directions {joint: (3, B, T)}
    the legs' generated bones'.

    A denoiser changes leg lengths (shins of 0.37 to 0.62 m instead of 0.43), so a leg of the body's
    length that reached the generated ankle from the generated hip height would bend its knee more or
    less than generated, or not reach at all: a walk would crouch or hang its feet in the air. The
    lower of the two ankles is the one the body stands on; the root moves vertically until that
    ankle is at the distance from the hip that the generated knee angle gives a leg of the body's
    length (the other leg reaches as it can), by at most MAX_ROOT_MOVE_M. Smoothed over a few frames,
    so the body does not bob with each frame's stretch."""
    legs = list(skel.legs.values())
    if len(legs) != 2:
        return torch.zeros(x.shape[2:], dtype=x.dtype, device=x.device)
    drops, heights = [], []
    for upper, mid, end in legs:
        l1, l2 = float(body[mid]), float(body[end])
        # the thigh and shin directions (the generated bones')
        want = (l1 * l1 + l2 * l2 + 2.0 * l1 * l2 * _dot(directions[mid], directions[end])[0]).clamp(min=0.0)  # (B, T) squared
        want = want.clamp(max=(0.999 * (l1 + l2)) ** 2)
        v = x[end] - placed[upper]  # (3, B, T) hip -> generated ankle
        vy = v[1]
        disc = vy * vy - _dot(v, v)[0] + want
        # move the hip by s along y so that |v - s y|^2 = want, the smaller move of the two; a foot out
        # of reach sideways at any height: the hip goes to its height at most
        root = disc.clamp(min=0).sqrt()
        s = torch.where((vy - root).abs() < (vy + root).abs(), vy - root, vy + root)
        drops.append(torch.where(disc >= 0, s, vy))
        heights.append(x[end, 1])
    support = heights[0] <= heights[1]
    drop = torch.where(support, drops[0], drops[1])
    reach = MAX_ROOT_MOVE_M * skel.per_metre
    drop = drop.clamp(-reach, reach)
    # padding repeats the last valid frame's move, so smoothing sees each motion as if alone
    drop = fill_padding(drop, valid.long().sum(1).clamp(min=1))
    return smooth_frames(drop, 1.0, radius=2)


def bone_lengths_of(joints: torch.Tensor, skeleton: Skeleton | str) -> torch.Tensor:
    """Every bone's length per frame: joints (..., J, 3) -> (..., J), root 0."""
    skel = get_skeleton(skeleton)
    x = torch.as_tensor(joints)
    parents = torch.tensor([max(p, 0) for p in skel.parents], device=x.device)
    return torch.linalg.vector_norm(x - x[..., parents, :], dim=-1)


__all__ = ["bone_lengths_of", "rigid_joint_major", "rigid_joints", "two_bone"]
