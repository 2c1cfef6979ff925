"""Generated joints -> one rigid body: every bone at the body's length, the root path, hands and
feet kept where they were generated (when the rigid limb can reach them).

A denoiser predicts joint positions (the features' ric part) independently per joint, so its bones
change length within a motion (the demo models: 10-30 cm). This step rebuilds the pose from the
root outwards:

- the trunk (spine, neck, head, hips, collars, shoulders) and every bone beyond a hand or a foot by
  forward kinematics: each bone keeps its generated direction and takes the body's length, except
  the children of a branching joint (the hips and spine around the pelvis; the neck and collars
  around the upper chest), which keep one shape per motion, turned with the joint's frame, so the
  pelvis and chest are rigid too (a BVH or SMPL rig, whose pelvis is one bone, then fits exactly);
- each two-bone limb of the skeleton (`Skeleton.ik_limbs`: hip-knee-ankle, shoulder-elbow-wrist)
  by analytic two-bone IK: the end (ankle, wrist) goes to its generated position, or as close as
  the straight limb reaches along the same line; the middle joint (knee, elbow) bends in the plane
  the generated pose bends in (through the generated knee/elbow), so a knee never flips backwards.

Everything is closed form and vectorised over batch and frames, on the joints' device. Applied to a
motion that is already rigid with these lengths it returns the motion unchanged (up to rounding).
"""

from __future__ import annotations

import numpy as np
import torch

from stablemo.errors import StableMoError
from stablemo.motion.skeleton import Skeleton, get_skeleton

_EPS = 1e-9


def _unit(v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(unit vector, norm (..., 1)); a zero vector stays zero."""
    norm = torch.linalg.vector_norm(v, dim=-1, keepdim=True)
    return v / norm.clamp(min=_EPS), norm


def _facing(x: torch.Tensor, skel: Skeleton) -> torch.Tensor:
    """Unit forward direction (B, T, 3) of the hips and shoulders (up × across), horizontal."""
    r_hip, l_hip, r_sdr, l_sdr = skel.face_joints
    across = (x[..., l_hip, :] - x[..., r_hip, :]) + (x[..., l_sdr, :] - x[..., r_sdr, :])
    up = torch.zeros_like(across)
    up[..., 1] = 1.0
    return _unit(torch.linalg.cross(up, across, dim=-1))[0]


def _two_bone(upper: torch.Tensor, target: torch.Tensor, pole: torch.Tensor, fallback_bend: torch.Tensor,
              rest_dir: torch.Tensor, l1: float, l2: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Middle and end positions (B, T, 3) of a limb rooted at `upper` whose end aims at `target`.

    pole: the generated middle joint, whose side of the upper->target line sets the bend plane;
    fallback_bend: the bend direction where the generated limb is straight (knees forward, elbows
    back); rest_dir: the aim where the target sits on the upper joint itself.
    """
    aim, dist = _unit(target - upper)
    aim = torch.where(dist > _EPS, aim, rest_dir)
    # the reachable distance: neither longer than the straight limb nor shorter than the folded one
    d = dist.clamp(min=abs(l1 - l2) + 1e-6, max=l1 + l2)
    to_pole = pole - upper
    bend = to_pole - (to_pole * aim).sum(-1, keepdim=True) * aim  # the pole's part across the aim line
    bend, across = _unit(bend)
    alt = fallback_bend - (fallback_bend * aim).sum(-1, keepdim=True) * aim
    alt = _unit(alt)[0]
    bend = torch.where(across > 1e-4 * l1, bend, alt)
    cos_a = ((l1 * l1 + d * d - l2 * l2) / (2.0 * l1 * d)).clamp(-1.0, 1.0)
    sin_a = (1.0 - cos_a * cos_a).clamp(min=0.0).sqrt()
    middle = upper + l1 * (cos_a * aim + sin_a * bend)
    return middle, upper + d * aim


def _branch_frames(x: torch.Tensor, skel: Skeleton, valid: torch.Tensor) -> dict:
    """Rigid frames of the joints with several children (the pelvis, the upper chest).

    A bone-by-bone rebuild keeps every length but lets the hips, or the neck and collars, swing
    against each other: the pelvis would change width. Here each such joint gets a frame per frame
    (y: towards its up child, the spine; x: from its -x child to its +x child, the body's right and
    left), the children's offsets are read in that frame, and their median over the motion's valid
    frames becomes the joint's fixed shape. -> {parent: (frames (B, T, 3, 3) columns x, y, z,
    {child: unit offset (B, 3) in the frame})}; joints without an up and two side children are left
    to the bone-by-bone rule."""
    raw = skel.raw_offsets
    out = {}
    for parent in range(skel.num_joints):
        kids = [c for c in range(skel.num_joints) if skel.parents[c] == parent]
        up = [c for c in kids if raw[c][1] > 0.5]
        pos = [c for c in kids if raw[c][0] > 0.5]
        neg = [c for c in kids if raw[c][0] < -0.5]
        if len(kids) < 2 or len(up) != 1 or len(pos) != 1 or len(neg) != 1:
            continue
        y = _unit(x[..., up[0], :] - x[..., parent, :])[0]
        side = x[..., pos[0], :] - x[..., neg[0], :]
        xa = _unit(side - (side * y).sum(-1, keepdim=True) * y)[0]
        frame = torch.stack([xa, y, torch.linalg.cross(xa, y, dim=-1)], dim=-1)  # (B, T, 3, 3)
        shape = {}
        for c in kids:
            local = (frame.transpose(-1, -2) @ (x[..., c, :] - x[..., parent, :])[..., None])[..., 0]  # (B, T, 3)
            local = torch.where(valid[..., None], _unit(local)[0], torch.full_like(local, float("nan")))
            shape[c] = _unit(local.nanmedian(dim=1).values)[0]  # (B, 3)
        out[parent] = (frame, shape)
    return out


def rigid_joints(joints: torch.Tensor, skeleton: Skeleton | str, bone_lengths=None, lengths=None) -> torch.Tensor:
    """joints (B, T, J, 3) or (T, J, 3) -> the same shape on the body with `bone_lengths` (J,)
    parent -> joint, root 0, in the skeleton's units (None: the skeleton's standard body); lengths
    (B,): valid frames per motion (the shapes of the pelvis and chest are measured on those)."""
    skel = get_skeleton(skeleton)
    x = torch.as_tensor(joints)
    if x.dim() not in (3, 4) or tuple(x.shape[-2:]) != (skel.num_joints, 3) or not x.is_floating_point():
        raise StableMoError(f"joints: expected a float array (B, T, {skel.num_joints}, 3) for skeleton {skel.name}, "
                            f"got {tuple(x.shape)} {x.dtype}")
    if x.dim() == 3:
        return rigid_joints(x[None], skel, bone_lengths, None if lengths is None else [lengths])[0]
    frames_n = torch.full((x.shape[0],), x.shape[1]) if lengths is None else torch.as_tensor(lengths).reshape(-1)
    valid = torch.arange(x.shape[1])[None, :] < frames_n[:, None]  # (B, T)
    branches = _branch_frames(x, skel, valid.to(x.device))
    body = np.asarray(skel.bone_lengths if bone_lengths is None else bone_lengths, dtype=np.float64)
    if body.shape != (skel.num_joints,) or not np.isfinite(body).all() or (body[1:] <= 0).any():
        raise StableMoError(f"bone_lengths: expected {skel.num_joints} finite lengths > 0 (root 0) for skeleton "
                            f"{skel.name}, got shape {body.shape}")
    raw_dir = torch.tensor(np.array(skel.raw_offsets), dtype=x.dtype, device=x.device)  # (J, 3) rest directions
    forward = _facing(x, skel)  # (..., T, 3)
    limb_of_end = {end: (upper, mid) for upper, mid, end in skel.ik_limbs}
    mids = {mid for _, mid, _ in skel.ik_limbs}
    legs = set(skel.feet_left + skel.feet_right)
    out: list[torch.Tensor | None] = [None] * skel.num_joints  # per joint (..., T, 3)
    out[0] = x[..., 0, :]
    for chain in skel.kinematic_chains:  # chains start at placed joints, parents before children
        for parent, child in zip(chain[:-1], chain[1:]):
            if child in mids:
                continue  # placed with its limb's end
            if child in limb_of_end:
                upper, mid = limb_of_end[child]
                # knees bend forward, elbows backward, where the generated limb is straight
                bend = forward if child in legs else -forward
                out[mid], out[child] = _two_bone(out[upper], x[..., child, :], x[..., mid, :], bend,
                                                 raw_dir[mid].expand_as(forward), float(body[mid]),
                                                 float(body[child]))
                continue
            if parent in branches:  # the joint's fixed shape, turned with its frame
                frame, shape = branches[parent]
                direction = (frame @ shape[child][:, None, :, None])[..., 0]  # (B, T, 3)
            else:
                direction, norm = _unit(x[..., child, :] - x[..., parent, :])
                direction = torch.where(norm > _EPS, direction, raw_dir[child].expand_as(direction))
            out[child] = out[parent] + float(body[child]) * direction
    return torch.stack(out, dim=-2)


def bone_lengths_of(joints: torch.Tensor, skeleton: Skeleton | str) -> torch.Tensor:
    """Every bone's length per frame: joints (..., J, 3) -> (..., J), root 0."""
    skel = get_skeleton(skeleton)
    x = torch.as_tensor(joints)
    parents = torch.tensor([max(p, 0) for p in skel.parents], device=x.device)
    return torch.linalg.vector_norm(x - x[..., parents, :], dim=-1)


__all__ = ["bone_lengths_of", "rigid_joints"]
