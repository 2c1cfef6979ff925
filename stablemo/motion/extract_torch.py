"""Batched torch twin of the numpy feature extraction (stablemo.motion.features).

For code that must stay on the sample's device: the foot-skate hook runs this at every hooked
sampling step. joints (B, T, J, 3) + lengths (B,) -> canonical joints (B, T, J, 3) or features
(B, T−1, D), float64, on the joints' device, no loop over samples. The numpy functions stay the
reference (they are checked against the official HumanML3D code); tests/test_extract_torch.py
holds this twin to them at <= 1e-9.

Per-sample validity. The numpy code sees one motion at a time: its floor is the minimum over that
motion's frames and its facing smoothing (Gaussian, 'nearest' edges) repeats the motion's own
last frame. Here every frame past a sample's length is first replaced by its last valid frame.
Then a minimum over all T frames is the minimum over the valid ones, and smoothing the padded
tensor with edge replication is exactly the per-sample 'nearest' filter, so the batch needs no
masks inside; rows that involve a padding frame are zeroed at the end.
"""

from __future__ import annotations

import numpy as np
import torch

from stablemo.errors import StableMoError
from stablemo.motion.features import FACING_SIGMA
from stablemo.motion.quaternion import (
    cross,
    norm,
    qbetween,
    qinv,
    qmul,
    qrot,
    quat_to_rot6d,
    yaw_rotate,
)
from stablemo.motion.skeleton import Skeleton, get_skeleton

# scipy.ndimage.gaussian_filter1d's kernel (truncate 4.0): radius int(4σ + 0.5), normalised
# exp(−x²/2σ²); computed with the same numpy expressions so the weights are bit-identical
_RADIUS = int(4.0 * FACING_SIGMA + 0.5)
_X = np.arange(-_RADIUS, _RADIUS + 1)
_PHI = np.exp(-0.5 / (FACING_SIGMA * FACING_SIGMA) * _X**2)
FACING_KERNEL = _PHI / _PHI.sum()  # (2R+1,) float64, symmetric


def _joints(joints: torch.Tensor, skel: Skeleton) -> torch.Tensor:
    if not torch.is_tensor(joints):
        joints = torch.as_tensor(np.asarray(joints))
    if joints.dim() != 4 or tuple(joints.shape[-2:]) != (skel.num_joints, 3):
        raise StableMoError(
            f"joints: expected shape (B, T, {skel.num_joints}, 3) for skeleton {skel.name}, got {tuple(joints.shape)}"
        )
    if joints.dtype.is_complex or joints.dtype == torch.bool:
        raise StableMoError(f"joints: expected a real-valued tensor, got dtype {joints.dtype}")
    return joints.detach().to(torch.float64)


def valid_lengths(lengths, batch: int, frames: int, device: torch.device, min_frames: int = 2) -> torch.Tensor:
    """lengths (B,) as a long tensor on `device`, each in [min_frames, frames] (one host sync)."""
    n = torch.as_tensor(lengths, dtype=torch.long).to(device).reshape(-1)
    if n.numel() != batch or bool(((n < min_frames) | (n > frames)).any()):
        raise StableMoError(f"lengths: expected {batch} values in [{min_frames}, {frames}], got {n.tolist()}")
    return n


def fill_padding(x: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
    """x (B, T, ...) -> same, every frame from lengths[b] on replaced by the sample's last valid one."""
    b, t = x.shape[:2]
    idx = torch.minimum(torch.arange(t, device=x.device)[None, :], lengths[:, None] - 1)  # (B, T)
    return torch.gather(x, 1, idx.view(b, t, *([1] * (x.dim() - 2))).expand_as(x))


def known_neighbours(known: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """known (B, T) bool -> (last, first) (B, T) long: the last known frame at or before each frame
    (-1: none) and the first known frame at or after it (T: none)."""
    b, t = known.shape
    idx = torch.arange(t, device=known.device).expand(b, t)
    last = torch.where(known, idx, torch.full_like(idx, -1)).cummax(1).values
    first = torch.where(known, idx, torch.full_like(idx, t)).flip(1).cummin(1).values.flip(1)
    return last, first


def smooth_frames(v: torch.Tensor, sigma: float, radius: int | None = None) -> torch.Tensor:
    """Gaussian smoothing of v (B, T) along T (sigma in frames; radius: the kernel's half width,
    default 3 sigma), edges replicated: run it on padding-filled rows to smooth each motion alone."""
    radius = max(1, int(3.0 * sigma + 0.5)) if radius is None else radius
    offs = torch.arange(-radius, radius + 1, dtype=v.dtype, device=v.device)
    kernel = torch.exp(-0.5 * (offs / sigma) ** 2)
    kernel = kernel / kernel.sum()
    padded = torch.nn.functional.pad(v[:, None], (radius, radius), mode="replicate")[:, 0]
    # a weighted sum of shifted copies, element by element: unlike a matrix product, whose kernel
    # and summation order depend on the batch's shape, each motion gets the same bits in any batch
    t = v.shape[1]
    out = kernel[0] * padded[:, :t]
    for k in range(1, 2 * radius + 1):
        out = out + kernel[k] * padded[:, k:k + t]
    return out


def _normalize(v: torch.Tensor, dim: int = -1) -> torch.Tensor:
    # as the numpy twin: a zero vector stays zero, so it does not vote in the facing average
    size = norm(v, dim, keepdim=True)
    return v / torch.where(size > 1e-12, size, torch.ones_like(size))


def _axis(v: torch.Tensor, axis: int) -> torch.Tensor:
    """Unit coordinate vector broadcast to v (..., 3)."""
    e = torch.zeros(3, dtype=v.dtype, device=v.device)
    e[axis] = 1.0
    return e.expand_as(v)


def _forward(x: torch.Tensor, a: int, b: int, c: int, d: int) -> torch.Tensor:
    """Facing direction y × normalise((X_a − X_b) + (X_c − X_d)) of x (..., J, 3) -> (..., 3)."""
    across = _normalize((x[..., a, :] - x[..., b, :]) + (x[..., c, :] - x[..., d, :]))
    return cross(_axis(across, 1), across)


def _check_facing(forward: torch.Tensor, what: str) -> None:
    if bool((torch.linalg.vector_norm(forward, dim=-1) < 1e-6).any()):
        raise StableMoError(
            f"joints: {what} undefined (hip and shoulder lines cancel or are vertical); not a body pose?"
        )


def _bones(skel: Skeleton) -> tuple[list[int], list[int]]:
    """Child and parent joint of every bone (J-1 each), in kinematic-chain order (parents placed first)."""
    pairs = [(c, p) for chain in skel.kinematic_chains for p, c in zip(chain[:-1], chain[1:])]
    return [c for c, _ in pairs], [p for _, p in pairs]


def _raw_offsets(skel: Skeleton, like: torch.Tensor) -> torch.Tensor:
    return torch.tensor(np.array(skel.raw_offsets), dtype=like.dtype, device=like.device)  # (J, 3)


def _uniform_skeleton(x: torch.Tensor, skel: Skeleton) -> torch.Tensor:
    """Closed form of the reference's IK/FK retargeting (see features.uniform_skeleton): root
    scaled by the frame-0 leg ratio, each joint = parent + target length × measured bone direction.
    x: (B, T, J, 3) -> (B, T, J, 3)."""
    parents = skel.parents
    b1, b2 = skel.leg_bones
    frame0 = x[:, 0]  # (B, J, 3)
    src_leg = (torch.linalg.vector_norm(frame0[:, b1] - frame0[:, parents[b1]], dim=-1)
               + torch.linalg.vector_norm(frame0[:, b2] - frame0[:, parents[b2]], dim=-1))  # (B,)
    if bool((src_leg <= 0).any()):
        raise StableMoError("joints: zero-length leg bones at frame 0, cannot scale")
    scale = (float(skel.bone_lengths[b1] + skel.bone_lengths[b2]) / src_leg)[:, None, None]  # (B, 1, 1)
    children, parents_of = _bones(skel)
    bone = x[:, :, children] - x[:, :, parents_of]  # (B, T, J-1, 3), every bone at once
    length = torch.linalg.vector_norm(bone, dim=-1, keepdim=True)
    raw = _raw_offsets(skel, x)[children]  # (J-1, 3)
    # a zero-length bone has no direction: fall back to the raw rest direction (as numpy)
    direction = torch.where(length > 1e-12, bone / length.clamp(min=1e-300), raw)
    target = torch.as_tensor(skel.bone_lengths[children], dtype=x.dtype, device=x.device)  # (J-1,)
    step = target[:, None] * direction  # (B, T, J-1, 3)
    out: list[torch.Tensor | None] = [None] * skel.num_joints  # per joint (B, T, 3)
    out[0] = x[:, :, 0] * scale
    for k, (child, parent) in enumerate(zip(children, parents_of)):  # chain order: parents first
        out[child] = out[parent] + step[:, :, k]
    return torch.stack(out, dim=2)


def _canonicalize(x: torch.Tensor, skel: Skeleton, refit: bool) -> torch.Tensor:
    """Steps 1–4 on padding-filled joints x (B, T, J, 3) float64 -> (B, T, J, 3)."""
    if refit:
        x = _uniform_skeleton(x, skel)
        floor = x[..., 1].amin(dim=(1, 2))  # (B,): padding repeats valid frames, so this is per sample
        x = torch.stack([x[..., 0], x[..., 1] - floor[:, None, None], x[..., 2]], dim=-1)
    xz = torch.tensor([1.0, 0.0, 1.0], dtype=x.dtype, device=x.device)
    x = x - x[:, :1, :1, :] * xz  # frame-0 root to the origin in xz, heights kept
    r_hip, l_hip, r_sdr, l_sdr = skel.face_joints
    forward = _forward(x[:, 0], r_hip, l_hip, r_sdr, l_sdr)  # (B, 3)
    _check_facing(forward, "initial facing")
    forward = _normalize(forward)
    q = qbetween(forward, _axis(forward, 2))  # (B, 4): frame-0 facing -> +z
    return qrot(q[:, None, None, :], x)


def _smooth(v: torch.Tensor) -> torch.Tensor:
    """Gaussian (σ = FACING_SIGMA frames, 'nearest' edges) along T of v (B, T, C) -> (B, T, C)."""
    kernel = torch.as_tensor(FACING_KERNEL, dtype=v.dtype, device=v.device)  # (K,), symmetric
    b, t, c = v.shape
    padded = torch.nn.functional.pad(v.transpose(1, 2), (_RADIUS, _RADIUS), mode="replicate")  # (B, C, T+2R)
    # one channel per row: a convolution, not unfold @ kernel, which copies the (B, C, T, K) windows
    out = torch.nn.functional.conv1d(padded.reshape(b * c, 1, -1), kernel.view(1, 1, -1))  # (B*C, 1, T)
    return out.view(b, c, t).transpose(1, 2)


def _facing_rotations(x: torch.Tensor, skel: Skeleton) -> torch.Tensor:
    """Root rotations r (B, T, 4) taking the smoothed facing to +z; r_0 = identity (as the reference)."""
    i0, i1, i2, i3 = skel.face_joints
    forward = _smooth(_forward(x, i1, i0, i2, i3))  # (B, T, 3); IK order: hips and shoulders opposite
    _check_facing(forward, "facing")
    forward = _normalize(forward)
    r = qbetween(forward, _axis(forward, 2))
    identity = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=r.dtype, device=r.device).expand(r.shape[0], 1, 4)
    return torch.cat([identity, r[:, 1:]], dim=1)


def _swing_rotations(x: torch.Tensor, r: torch.Tensor, skel: Skeleton) -> torch.Tensor:
    """Local rotations (J-1, 4, B, T) of joints 1.., joint-major, from joints x (J, 3, B, T) and
    root rotations r (1, 4, B, T): each chain's swing from the raw rest direction to the measured
    bone, relative to the chain's accumulated rotation.

    The reference accumulates acc <- acc * local along a chain with local = acc^-1 * swing, so after
    each bone acc is that bone's swing: the local rotation is the previous bone's swing (r for a
    chain's first bone) inverted, times this bone's swing. All bones at once, no loop."""
    parents = list(skel.parents[1:])
    bone = x[1:] - x[parents]  # (J-1, 3, B, T), bone j-1 ends at joint j
    raw = _raw_offsets(skel, x)[1:, :, None, None]  # (J-1, 3, 1, 1)
    # qbetween divides by |raw||bone| itself: normalising the bones first (as the reference does)
    # changes the result by rounding only and cost a tenth of this function
    swing = qbetween(raw, bone, dim=1)  # (J-1, 4, B, T)
    acc = torch.cat([swing, r]).index_select(0, torch.tensor(rotation_before(skel), device=x.device))
    return qmul(qinv(acc, dim=1), swing, dim=1)


def rotation_columns(x: torch.Tensor, r: torch.Tensor, skel: Skeleton) -> torch.Tensor:
    """The features' 6D rotation columns of joint-major joints x (J, 3, B, T) seen from root rotations
    r (1, 4, B, T), joint-major: (J-1, 6, B, T). Extraction's, and what a training term compares a
    network's own columns with (stablemo.training.geometry)."""
    return quat_to_rot6d(_swing_rotations(x, r, skel), dim=1)


def rotation_before(skel: Skeleton) -> list[int]:
    """Per bone (bone j-1 ends at joint j): the bone whose swing its local rotation is relative to,
    the previous one along its kinematic chain, or J-1 (the root's rotation) for a chain's first."""
    before = [skel.num_joints - 1] * (skel.num_joints - 1)
    for chain in skel.kinematic_chains:
        for p, child in zip(chain[1:-1], chain[2:]):
            before[child - 1] = p - 1
    return before


def _features(x: torch.Tensor, skel: Skeleton) -> torch.Tensor:
    """Canonical, padding-filled joints x (B, T, J, 3) -> features (B, T−1, D), every row."""
    r = _facing_rotations(x, skel)  # (B, T, 4)
    root = x[:, :, 0]  # (B, T, 3)
    lin_vel = qrot(r[:, 1:], root[:, 1:] - root[:, :-1])[..., [0, 2]]  # (B, T-1, 2)
    dq = qmul(r[:, 1:], qinv(r[:, :-1]))
    # hemisphere fix of the numpy twin (module docstring of features.py): sign(w) * y, w == 0 positive
    rot_vel = torch.asin(torch.where(dq[..., :1] < 0, -dq[..., 2:3], dq[..., 2:3]).clamp(-1.0, 1.0))
    feats = torch.cat([rot_vel, lin_vel, body_features(x, r, skel)], dim=-1)
    assert feats.shape[-1] == skel.feature_dim
    return feats


def body_features(x: torch.Tensor, r: torch.Tensor, skel: Skeleton) -> torch.Tensor:
    """The feature columns after the root's rotation and linear velocity (root height, ric, 6D
    rotations, local velocities, foot contacts) of joints x (B, T, J, 3) seen from root rotations
    r (B, T, 4) -> (B, T−1, D − 3). Split out so that a motion whose root rotation is already known
    (the finishing step keeps the network's) skips the facing estimate."""
    return body_columns(x.permute(2, 3, 0, 1).contiguous(), r, skel)


def root_relative(x: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """The features' ric columns, joint-major: joints x (J, 3, B, T) seen from the root, in xz
    relative to it and turned by the root rotations r (1, 4, B, T), heights absolute -> (J-1, 3, B, T)."""
    xz = x.new_tensor([1.0, 0.0, 1.0]).view(1, 3, 1, 1)
    # r turns about y alone (a facing, or recover_root's yaw): the cheaper exact rotation
    return yaw_rotate(r, x[1:] - x[:1] * xz, dim=1)


def body_columns(x: torch.Tensor, r: torch.Tensor, skel: Skeleton) -> torch.Tensor:
    """body_features of joint-major joints x (J, 3, B, T) -> (B, T−1, D − 3).

    Joint-major, each joint's x, y and z lie in one contiguous block, so every step below is a
    vectorised pass; on (B, T, J, 3) each one strode over the interleaved coordinates (the
    finishing step spent most of its time here)."""
    rq = r.permute(2, 0, 1)[None, :, :, :-1]  # (1, 4, B, T-1), the frames that get a row
    feet = x[list(skel.contact_joints)]  # (4, 3, B, T)
    disp2 = ((feet[..., 1:] - feet[..., :-1]) ** 2).sum(1)  # (4, B, T-1)
    contacts = (disp2 < skel.contact_threshold).to(x.dtype).permute(1, 2, 0)
    now = x[..., :-1]  # (J, 3, B, T-1)
    rot6d = rotation_columns(now, rq, skel)  # (J-1, 6, B, T-1)
    ric = root_relative(now, rq)  # (J-1, 3, B, T-1)
    # r turns about y alone (a facing, or recover_root's yaw): the cheaper exact rotation
    local_vel = yaw_rotate(rq, x[..., 1:] - now, dim=1)  # (J, 3, B, T-1)

    def rows(v: torch.Tensor) -> torch.Tensor:  # (K, C, B, T-1) -> (B, T-1, K * C), one strided copy
        return v.permute(2, 3, 0, 1).flatten(2)

    return torch.cat([now[0, 1, ..., None], rows(ric), rows(rot6d), rows(local_vel), contacts], dim=-1)


def canonicalize_joints_batched(joints: torch.Tensor, lengths, skeleton: Skeleton | str = "humanml3d",
                                refit: bool = True) -> torch.Tensor:
    """Batched twin of canonicalize_joints: joints (B, T, J, 3), lengths (B,) -> float64 (B, T, J, 3)
    on the joints' device, each sample placed from its own valid frames, zero on padding."""
    skel = get_skeleton(skeleton)
    x = _joints(joints, skel)
    n = valid_lengths(lengths, x.shape[0], x.shape[1], x.device)
    x = fill_padding(x, n)
    if not bool(torch.isfinite(x).all()):  # padding is filled from valid frames: only those count
        raise StableMoError("joints: contain NaN or Inf")
    out = _canonicalize(x, skel, refit)
    mask = torch.arange(x.shape[1], device=x.device)[None, :] < n[:, None]  # (B, T)
    return torch.where(mask[..., None, None], out, torch.zeros((), dtype=out.dtype, device=out.device))


def joints_to_features_batched(joints: torch.Tensor, lengths, skeleton: Skeleton | str = "humanml3d",
                               refit: bool = True, place: bool = True) -> torch.Tensor:
    """Batched twin of joints_to_features: joints (B, T, J, 3), lengths (B,) valid frames (>= 2)
    -> float64 features (B, T−1, D) on the joints' device; sample b has lengths[b] − 1 rows, the
    rest is zero. refit as in canonicalize_joints.

    place=False (implies no refit) skips the canonical placement too: for joints recovered from
    features (frame-0 root at the origin, root rotation identity at frame 0), whose features then
    recover exactly these joints, wherever the body faces at frame 0. Placing them would turn the
    whole motion by the frame-0 facing of the hips and shoulders (a few degrees on generated
    motions), moving its far end and any joint targets it was asked to meet."""
    skel = get_skeleton(skeleton)
    x = _joints(joints, skel)
    n = valid_lengths(lengths, x.shape[0], x.shape[1], x.device)
    x = fill_padding(x, n)
    if not bool(torch.isfinite(x).all()):
        raise StableMoError("joints: contain NaN or Inf")
    feats = _features(_canonicalize(x, skel, refit) if place else x, skel)  # (B, T-1, D)
    rows = torch.arange(feats.shape[1], device=x.device)[None, :] < (n - 1)[:, None]  # (B, T-1)
    return torch.where(rows[..., None], feats, torch.zeros((), dtype=feats.dtype, device=feats.device))
