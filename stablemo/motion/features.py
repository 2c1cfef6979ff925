"""HumanML3D motion features <-> joint positions.

Extraction (numpy, float64 inside, float32 out) follows HumanML3D's `motion_representation.ipynb` step by step;
recovery (torch, differentiable) follows its `recover_from_ric`. Layout per frame (J joints, D = 12J − 1):
root angular velocity 1 | root linear velocity xz 2 | root height 1 | ric 3(J−1) | rot 6D 6(J−1)
| local velocity 3J | foot contacts 4.

One deliberate deviation: the reference takes the root angular velocity as arcsin of the y part
of r_{t+1} r_t⁻¹. When the facing crosses ±180° relative to the initial facing, that product has a
negative real part and arcsin returns the wrong sign, so recovery turns the body the wrong way
(a bug of the reference on fast or full turns). We flip the quaternion to the w ≥ 0 hemisphere
first. Whenever the reference is right (w ≥ 0) the two are identical.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.ndimage import gaussian_filter1d

from stablemo.errors import StableMoError
from stablemo.motion.quaternion import (
    qbetween_np,
    qinv,
    qinv_np,
    qmul_np,
    qrot,
    qrot_np,
    quat_to_rot6d_np,
    yaw_rotate,
)
from stablemo.motion.skeleton import Skeleton, get_skeleton

FACING_SIGMA = 20.0  # frames, Gaussian smoothing of the per-frame facing direction
_Y = np.array([0.0, 1.0, 0.0])
_Z = np.array([0.0, 0.0, 1.0])


def feature_slices(skeleton: Skeleton | str) -> dict[str, slice]:
    """Named column groups of the feature vector."""
    skel = get_skeleton(skeleton)
    j = skel.num_joints
    bounds = {
        "root_rot_vel": 1,
        "root_lin_vel": 2,
        "root_y": 1,
        "ric": 3 * (j - 1),
        "rot6d": 6 * (j - 1),
        "local_vel": 3 * j,
        "contacts": 4,
    }
    out, start = {}, 0
    for key, width in bounds.items():
        out[key] = slice(start, start + width)
        start += width
    assert start == skel.feature_dim
    return out


# --------------------------------------------------------------------------- extraction (numpy)


def _check_joints(joints: np.ndarray, skel: Skeleton) -> np.ndarray:
    if torch.is_tensor(joints):
        joints = joints.detach().cpu().numpy()
    arr = np.asarray(joints)
    if not np.issubdtype(arr.dtype, np.number):
        raise StableMoError(f"joints: expected a numeric array, got dtype {arr.dtype}")
    if arr.ndim not in (3, 4) or arr.shape[-2:] != (skel.num_joints, 3):
        raise StableMoError(
            f"joints: expected shape (T, {skel.num_joints}, 3) or (B, T, {skel.num_joints}, 3) "
            f"for skeleton {skel.name}, got {arr.shape}"
        )
    if arr.shape[-3] < 2:
        raise StableMoError(f"joints: need at least 2 frames, got {arr.shape[-3]}")
    if not np.all(np.isfinite(arr)):
        raise StableMoError("joints: contain NaN or Inf")
    return arr.astype(np.float64)


def _normalize(v: np.ndarray) -> np.ndarray:
    # a zero vector stays zero (instead of NaN): in the facing average it then simply does not vote
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(norm > 1e-12, norm, 1.0)


def _across(x: np.ndarray, a: int, b: int, c: int, d: int) -> np.ndarray:
    """normalise((X_a − X_b) + (X_c − X_d)) over the joint axis of x (..., J, 3)."""
    return _normalize((x[..., a, :] - x[..., b, :]) + (x[..., c, :] - x[..., d, :]))


def _check_facing(forward: np.ndarray, what: str) -> None:
    norm = np.linalg.norm(forward, axis=-1)
    if np.any(norm < 1e-6):
        raise StableMoError(
            f"joints: {what} undefined (hip and shoulder lines cancel or are vertical); not a body pose?"
        )


def uniform_skeleton(joints: np.ndarray, skeleton: Skeleton | str) -> np.ndarray:
    """Step 1: retarget to the target bone lengths. joints (..., T, J, 3) -> same shape.

    The reference does IK with swing rotations from the raw offsets, then FK with target offsets.
    Each swing maps the raw direction exactly onto the measured bone direction and the FK product
    telescopes, so the result is: root scaled by s (leg-bone ratio at frame 0), every other joint =
    its parent + target length × measured unit bone direction. We compute that closed form, which
    also stays defined where the swing quaternion would not (a bone opposite its raw direction).
    """
    skel = get_skeleton(skeleton)
    x = np.asarray(joints, dtype=np.float64)
    parents = np.array(skel.parents)
    b1, b2 = skel.leg_bones
    src_leg = (
        np.linalg.norm(x[..., 0, b1, :] - x[..., 0, parents[b1], :], axis=-1)
        + np.linalg.norm(x[..., 0, b2, :] - x[..., 0, parents[b2], :], axis=-1)
    )  # (...,)
    tgt_leg = skel.bone_lengths[b1] + skel.bone_lengths[b2]
    if np.any(src_leg <= 0):
        raise StableMoError("joints: zero-length leg bones at frame 0, cannot scale")
    scale = (tgt_leg / src_leg)[..., None, None]  # (..., 1, 1)
    out = np.empty_like(x)
    out[..., 0, :] = x[..., 0, :] * scale
    for chain in skel.kinematic_chains:
        for parent, child in zip(chain[:-1], chain[1:]):
            bone = x[..., child, :] - x[..., parent, :]
            length = np.linalg.norm(bone, axis=-1, keepdims=True)
            # a zero-length bone has no direction; the reference yields NaN there, we fall back
            # to the raw rest direction
            direction = np.where(length > 1e-12, bone / np.maximum(length, 1e-300), skel.raw_offsets[child])
            out[..., child, :] = out[..., parent, :] + skel.bone_lengths[child] * direction
    return out


def canonicalize_joints(joints: np.ndarray, skeleton: Skeleton | str, refit: bool = True) -> np.ndarray:
    """Steps 1–4 of the extraction: uniform skeleton, floor at y = 0, frame-0 root xz at the origin,
    frame-0 facing along +z. joints (T, J, 3) or (B, T, J, 3) -> float64 of the same shape.
    Recovering joints from the features reproduces exactly these positions.

    refit=False skips steps 1–2 (skeleton and floor) and keeps only the rigid placement: for joints
    that already live in feature space (recovered from generated features, then edited), whose
    bone lengths and floor are the motion's own — refitting them would move the feet again.
    """
    skel = get_skeleton(skeleton)
    x = np.array(_check_joints(joints, skel), dtype=np.float64)
    if refit:
        x = uniform_skeleton(x, skel)
        x[..., 1] -= x[..., 1].min(axis=(-2, -1))[..., None, None]
    root0 = x[..., :1, :1, :].copy()  # (..., 1, 1, 3)
    root0[..., 1] = 0.0
    x = x - root0
    r_hip, l_hip, r_sdr, l_sdr = skel.face_joints
    across = _across(x[..., 0, :, :], r_hip, l_hip, r_sdr, l_sdr)  # (..., 3)
    forward = np.cross(_Y, across)
    _check_facing(forward, "initial facing")
    q = qbetween_np(_normalize(forward), _Z)[..., None, None, :]  # (..., 1, 1, 4)
    return qrot_np(np.broadcast_to(q, x.shape[:-1] + (4,)), x)


def facing_rotations(x: np.ndarray, skeleton: Skeleton | str, smooth: bool = True) -> np.ndarray:
    """Root rotations r_t (..., T, 4) taking the (smoothed) facing to +z; r_0 = identity.

    The facing uses face_joints in IK order: (X_{i1} − X_{i0}) + (X_{i2} − X_{i3}) — hips and
    shoulders enter with opposite sides, as in the reference; we keep it.
    """
    skel = get_skeleton(skeleton)
    i0, i1, i2, i3 = skel.face_joints
    across = _across(x, i1, i0, i2, i3)  # (..., T, 3)
    forward = np.cross(_Y, across)
    if smooth:
        forward = gaussian_filter1d(forward, FACING_SIGMA, axis=-2, mode="nearest")
    _check_facing(forward, "facing")
    forward = _normalize(forward)
    r = qbetween_np(forward, _Z)
    r[..., 0, :] = (1.0, 0.0, 0.0, 0.0)
    return r


def swing_rotations(x: np.ndarray, root_rot: np.ndarray, skeleton: Skeleton | str) -> np.ndarray:
    """Per-joint local rotations (..., T, J, 4): along each chain, the swing from the raw rest
    direction to the measured bone, relative to the accumulated rotation of the chain (which starts
    from the root rotation for every chain, branches included). Stored at the child joint."""
    skel = get_skeleton(skeleton)
    quats = np.zeros(x.shape[:-1] + (4,))
    quats[..., 0, :] = root_rot
    for chain in skel.kinematic_chains:
        acc = root_rot
        for parent, child in zip(chain[:-1], chain[1:]):
            bone = _normalize(x[..., child, :] - x[..., parent, :])
            swing = qbetween_np(np.broadcast_to(skel.raw_offsets[child], bone.shape), bone)
            local = qmul_np(qinv_np(acc), swing)
            quats[..., child, :] = local
            acc = qmul_np(acc, local)
    return quats


def foot_contacts(x: np.ndarray, skeleton: Skeleton | str) -> np.ndarray:
    """(..., T−1, 4) binary [L_a, L_b, R_a, R_b]: squared per-frame displacement below τ."""
    skel = get_skeleton(skeleton)
    feet = x[..., list(skel.contact_joints), :]
    disp2 = ((feet[..., 1:, :, :] - feet[..., :-1, :, :]) ** 2).sum(-1)
    return (disp2 < skel.contact_threshold).astype(np.float64)


def joints_to_features(joints: np.ndarray, skeleton: Skeleton | str = "humanml3d", refit: bool = True) -> np.ndarray:
    """Joint positions (T, J, 3) or (B, T, J, 3) -> features (T−1, D) or (B, T−1, D), float32.
    refit: put the motion on the standard skeleton and floor first (see canonicalize_joints)."""
    return joints_to_features_f64(joints, skeleton, refit).astype(np.float32)


def joints_to_features_f64(joints: np.ndarray, skeleton: Skeleton | str = "humanml3d", refit: bool = True) -> np.ndarray:
    """joints_to_features before its float32 cast: the float64 reference that the batched torch
    twin (stablemo.motion.extract_torch) is tested against."""
    skel = get_skeleton(skeleton)
    x = canonicalize_joints(joints, skel, refit)  # (..., T, J, 3), global positions
    contacts = foot_contacts(x, skel)

    r = facing_rotations(x, skel, smooth=True)  # (..., T, 4)
    quats = swing_rotations(x, r, skel)  # (..., T, J, 4)
    rot6d = quat_to_rot6d_np(quats[..., 1:, :])  # (..., T, J-1, 6)

    root = x[..., 0, :]  # (..., T, 3)
    lin_vel = qrot_np(r[..., 1:, :], root[..., 1:, :] - root[..., :-1, :])[..., [0, 2]]
    dq = qmul_np(r[..., 1:, :], qinv_np(r[..., :-1, :]))
    # hemisphere fix (see module docstring): sign(w) * y, with w == 0 counted as positive
    rot_vel = np.arcsin(np.clip(np.where(dq[..., :1] < 0, -dq[..., 2:3], dq[..., 2:3]), -1.0, 1.0))

    rel = x.copy()
    rel[..., [0, 2]] -= x[..., :1, [0, 2]]
    ric = qrot_np(r[..., None, :], rel)[..., 1:, :]  # (..., T, J-1, 3)
    local_vel = qrot_np(r[..., :-1, None, :], x[..., 1:, :, :] - x[..., :-1, :, :])  # (..., T-1, J, 3)

    lead = x.shape[:-3]
    n = x.shape[-3] - 1
    parts = [
        rot_vel,
        lin_vel,
        root[..., :-1, 1:2],
        ric[..., :-1, :, :].reshape(*lead, n, -1),
        rot6d[..., :-1, :, :].reshape(*lead, n, -1),
        local_vel.reshape(*lead, n, -1),
        contacts,
    ]
    feats = np.concatenate(parts, axis=-1)
    assert feats.shape[-1] == skel.feature_dim
    return feats


# --------------------------------------------------------------------------- recovery (torch)


def recover_root(features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Root yaw quaternion q_t (..., T, 4) and root position (..., T, 3) from features (..., T, D)."""
    rot_vel = features[..., 0]
    # a_0 = 0, a_t = sum_{k<t} d_k[0]
    angle = torch.cumsum(torch.cat([torch.zeros_like(rot_vel[..., :1]), rot_vel[..., :-1]], dim=-1), dim=-1)
    zeros = torch.zeros_like(angle)
    q = torch.stack([torch.cos(angle), zeros, torch.sin(angle), zeros], dim=-1)
    lin = features[..., :-1, 1:3]  # velocity k-1 is expressed in the facing frame of k
    step = torch.stack([lin[..., 0], torch.zeros_like(lin[..., 0]), lin[..., 1]], dim=-1)
    step = qrot(qinv(q[..., 1:, :]), step)
    # the root starts at the origin; new_zeros, not zeros_like(step[..., :1, :]), which is empty for one frame
    xz = torch.cat([step.new_zeros(*step.shape[:-2], 1, 3), torch.cumsum(step, dim=-2)], dim=-2)
    pos = torch.stack([xz[..., 0], features[..., 3], xz[..., 2]], dim=-1)
    return q, pos


def features_to_joints(features, skeleton: Skeleton | str = "humanml3d"):
    """Features (..., T, D) -> joint positions (..., T, J, 3). Differentiable (torch); numpy in,
    numpy out (same dtype)."""
    skel = get_skeleton(skeleton)
    as_numpy = isinstance(features, np.ndarray)
    feats = torch.from_numpy(features) if as_numpy else features
    if not torch.is_tensor(feats) or feats.ndim < 2 or feats.shape[-1] != skel.feature_dim:
        shape = tuple(getattr(features, "shape", ()))
        raise StableMoError(
            f"features: expected shape (..., T, {skel.feature_dim}) for skeleton {skel.name}, got {shape}"
        )
    if not feats.is_floating_point():
        feats = feats.float()
    q, root = recover_root(feats)
    sl = feature_slices(skel)["ric"]
    # components first, (3, ..., T, J-1): each a contiguous block, so the turn is a few vectorised
    # passes (on the interleaved (..., J-1, 3) columns it was most of this function's time)
    ric = feats[..., sl].unflatten(-1, (skel.num_joints - 1, 3)).movedim(-1, 0).contiguous()
    joints = joints_from_ric(q, root, ric)
    return joints.numpy() if as_numpy else joints


def joints_from_ric(q: torch.Tensor, root: torch.Tensor, ric: torch.Tensor) -> torch.Tensor:
    """The recovery's last step: joints (..., T, J, 3) from the root's rotation q (..., T, 4) and
    position root (..., T, 3) (recover_root) and the ric columns components first, (3, ..., T, J-1),
    in any memory layout. One function for features_to_joints and the finishing step, whose joints
    are its features' recovery to the bit."""
    xz = root.new_tensor([1.0, 0.0, 1.0])
    # q turns about y alone: the cheaper exact rotation
    body = yaw_rotate(qinv(q).movedim(-1, 0)[..., None], ric, dim=0) + (root * xz).movedim(-1, 0)[..., None]
    return torch.cat([root.movedim(-1, 0)[..., None], body], dim=-1).movedim(0, -1).contiguous()  # (..., T, J, 3)
