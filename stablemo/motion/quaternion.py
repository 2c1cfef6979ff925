"""Quaternions (w, x, y, z), Hamilton product, v' = q v q*; numpy and torch twins.

numpy versions serve the (offline, float64) feature extraction; torch versions serve the
differentiable recovery and anyone who needs rotations on tensors. Shapes broadcast: q (..., 4),
v (..., 3).
"""

from __future__ import annotations

import numpy as np
import torch

# --------------------------------------------------------------------------- numpy


def qmul_np(q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Hamilton product q ⊗ r."""
    w1, x1, y1, z1 = np.moveaxis(q, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(r, -1, 0)
    return np.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        axis=-1,
    )


def qinv_np(q: np.ndarray) -> np.ndarray:
    """Conjugate (= inverse for unit quaternions)."""
    return q * np.array([1.0, -1.0, -1.0, -1.0], dtype=q.dtype)


def qrot_np(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate v by unit quaternion q: q v q*."""
    w = q[..., :1]
    u = q[..., 1:]
    uv = np.cross(u, v)
    return v + 2.0 * (w * uv + np.cross(u, uv))


def qbetween_np(a: np.ndarray, b: np.ndarray, eps: float = 1e-9) -> np.ndarray:
    """Shortest-arc unit quaternion taking direction a to direction b.

    normalise(|a||b| + a·b, a×b). For (nearly) opposite directions that formula vanishes; we then
    return a half turn about an axis perpendicular to a, a valid answer where the formula has none.
    """
    a, b = np.broadcast_arrays(a, b)
    w = np.sqrt((a**2).sum(-1) * (b**2).sum(-1)) + (a * b).sum(-1)
    q = np.concatenate([w[..., None], np.cross(a, b)], axis=-1)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    scale = np.sqrt((a**2).sum(-1) * (b**2).sum(-1))[..., None]
    bad = (norm <= eps * np.maximum(scale, 1e-30)) | (norm == 0)
    if np.any(bad):
        q = q.copy()
        bad1 = bad[..., 0]
        aa = a[bad1]
        # pick the coordinate axis least aligned with a, build a perpendicular axis from it
        helper = np.zeros_like(aa)
        helper[np.arange(len(aa)), np.argmin(np.abs(aa), axis=-1)] = 1.0
        axis = np.cross(aa, helper)
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        q[bad1] = np.concatenate([np.zeros_like(axis[:, :1]), axis], axis=-1)
        norm = np.where(bad, 1.0, norm)
    return q / norm


def quat_to_matrix_np(q: np.ndarray) -> np.ndarray:
    """Unit quaternion (..., 4) -> rotation matrix (..., 3, 3)."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def quat_to_rot6d_np(q: np.ndarray) -> np.ndarray:
    """Continuous 6D rotation: first matrix column, then the second (..., 6)."""
    m = quat_to_matrix_np(q)
    return np.concatenate([m[..., :, 0], m[..., :, 1]], axis=-1)


# --------------------------------------------------------------------------- torch


def cross(a: torch.Tensor, b: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """a × b over axis `dim` (3 long). Written out: torch.linalg.cross takes about twice as long on
    the CPU for the (..., 3) batches of joints that everything here works on."""
    ax, ay, az = a.unbind(dim)
    bx, by, bz = b.unbind(dim)
    return torch.stack([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx], dim=dim)


def norm(v: torch.Tensor, dim: int = -1, keepdim: bool = False) -> torch.Tensor:
    """Euclidean length over axis `dim`: the root of the summed squares. torch.linalg.vector_norm
    over a leading axis (components first, (3, B, T, J)) takes ~70x as long on the CPU."""
    return (v * v).sum(dim, keepdim=keepdim).sqrt()


def qmul(q: torch.Tensor, r: torch.Tensor, dim: int = -1) -> torch.Tensor:
    w1, x1, y1, z1 = q.unbind(dim)
    w2, x2, y2, z2 = r.unbind(dim)
    return torch.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        dim=dim,
    )


def _along(values: list[float], like: torch.Tensor, dim: int) -> torch.Tensor:
    """A constant vector laid along axis `dim` of `like`, to broadcast against it."""
    shape = [1] * like.dim()
    shape[dim] = len(values)
    return like.new_tensor(values).view(shape)


def qinv(q: torch.Tensor, dim: int = -1) -> torch.Tensor:
    return q * _along([1.0, -1.0, -1.0, -1.0], q, dim)


def qrot(q: torch.Tensor, v: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """Rotate v (..., 3) by unit quaternion q (..., 4); broadcasts (dim: the component axis)."""
    w = q.narrow(dim, 0, 1)
    u = q.narrow(dim, 1, 3)
    u, v = torch.broadcast_tensors(u, v)
    uv = cross(u, v, dim)
    return v + 2.0 * (w * uv + cross(u, uv, dim))


def rot6d_to_matrix(d6: torch.Tensor) -> torch.Tensor:
    """6D (first two columns, col 0 then col 1) -> rotation matrix (..., 3, 3), Gram-Schmidt:
    x = a1/|a1|, z = normalise(x × a2), y = z × x; the result has columns x, y, z."""
    a1, a2 = d6[..., :3], d6[..., 3:]
    x = torch.nn.functional.normalize(a1, dim=-1)
    z = torch.nn.functional.normalize(cross(x, a2), dim=-1)
    y = cross(z, x)
    return torch.stack([x, y, z], dim=-1)


def matrix_to_rot6d(m: torch.Tensor) -> torch.Tensor:
    return torch.cat([m[..., :, 0], m[..., :, 1]], dim=-1)


def qbetween(a: torch.Tensor, b: torch.Tensor, eps: float = 1e-9, dim: int = -1) -> torch.Tensor:
    """Shortest-arc unit quaternion taking direction a (..., 3) to b (..., 3): the twin of
    qbetween_np, including its half turn for (nearly) opposite directions. Branch-free (torch.where),
    so a batch on a GPU needs no host round trip (on the CPU the half turn is skipped when no pair needs it).
    dim: the component axis (a constant `a` may stay unexpanded: it broadcasts)."""
    scale = torch.sqrt((a**2).sum(dim) * (b**2).sum(dim))  # |a||b|
    w = scale + (a * b).sum(dim)
    q = torch.cat([w.unsqueeze(dim), cross(*torch.broadcast_tensors(a, b), dim)], dim=dim)
    size = norm(q, dim, keepdim=True)
    bad = (size <= eps * scale.unsqueeze(dim).clamp(min=1e-30)) | (size == 0)
    if not q.is_cuda and not bool(bad.any()):  # on the CPU a check is free and the half turn rarely needed
        return q / size
    # the coordinate axis least aligned with a gives an axis perpendicular to a
    a = torch.broadcast_tensors(a, b)[0]
    helper = torch.nn.functional.one_hot(a.abs().argmin(dim), 3).to(a.dtype).movedim(-1, dim)
    axis = cross(a, helper, dim)
    axis = axis / norm(axis, dim, keepdim=True)
    half_turn = torch.cat([torch.zeros_like(axis.narrow(dim, 0, 1)), axis], dim=dim)
    q = torch.where(bad, half_turn, q)
    return q / torch.where(bad, torch.ones_like(size), size)


def quat_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """Unit quaternion (..., 4) -> rotation matrix (..., 3, 3); the same expressions as quat_to_matrix_np."""
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        dim=-2,
    )


def quat_to_rot6d(q: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """Continuous 6D rotation (..., 6): the first matrix column, then the second (as quat_to_rot6d_np);
    quat_to_matrix's expressions for those six entries only. dim: the component axis."""
    w, x, y, z = q.unbind(dim)
    return torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y),
                        2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)], dim=dim)


def yaw_rotate(q: torch.Tensor, v: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """qrot for a rotation about y alone, q = (w, 0, y, 0) (..., 4): a turn by 2·atan2(y, w) in the
    xz plane, v (..., 3). The root rotations of the motion features are such; this is a third of
    qrot's work on the (B, T, J, 3) batches they turn. dim: the component axis."""
    qw, _, qy, _ = q.unbind(dim)
    c = qw * qw - qy * qy  # cos of the turn
    s = 2.0 * qw * qy  # its sine
    vx, vy, vz = v.unbind(dim)
    vy = vy.expand(torch.broadcast_shapes(vy.shape, c.shape))
    return torch.stack([c * vx + s * vz, vy, c * vz - s * vx], dim=dim)
