"""Frames and rotations for the retargeting: unit vectors, the part of a vector across an axis,
orthonormal frames from an aim and a side axis, the rotation between two frames or two directions,
and a rig's up axis. Arrays carry frames in their leading axes: (..., 3) vectors, (..., 3, 3)
rotations (columns: the frame's axes).
"""

from __future__ import annotations

import numpy as np

from stablemo.errors import StableMoError

EPS = 1e-9


def unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > EPS, n, 1.0)


def across(v: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The part of v (..., 3) perpendicular to axis (..., 3)."""
    a = unit(axis)
    return v - (v * a).sum(-1, keepdims=True) * a


def basis(aim: np.ndarray, side: np.ndarray) -> np.ndarray:
    """(..., 3, 3) orthonormal frame, columns: aim, side made perpendicular to it, aim x side."""
    a = unit(np.broadcast_to(aim, np.broadcast_shapes(np.shape(aim), np.shape(side))))
    s = across(np.broadcast_to(side, a.shape), a)
    # a side along the aim (never in a body, but a file may hold anything): any perpendicular
    spare = np.where(np.abs(a[..., :1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    s = np.where(np.linalg.norm(s, axis=-1, keepdims=True) > 1e-6, s, across(spare, a))
    s = unit(s)
    return np.stack([a, s, np.cross(a, s)], axis=-1)


def align(aim_now, side_now, aim_rest, side_rest) -> np.ndarray:
    """(T, 3, 3) world rotation taking the rest frame (aim, side) onto the frame now."""
    return basis(aim_now, side_now) @ np.swapaxes(basis(aim_rest, side_rest), -1, -2)


def swing(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(T, 3, 3) the shortest rotation taking direction a (T, 3) onto b (T, 3)."""
    a, b = unit(a), unit(b)
    v = np.cross(a, b)
    c = (a * b).sum(-1)[..., None, None]
    vx = np.zeros(v.shape + (3,))
    vx[..., 0, 1], vx[..., 0, 2], vx[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    vx = vx - np.swapaxes(vx, -1, -2)
    return np.eye(3) + vx + vx @ vx / np.maximum(1.0 + c, 1e-9)


def up_axes(rest: np.ndarray, roles, where: str) -> np.ndarray:
    """(3, 3) the rotation taking our y-up world to the rig's: identity for y-up rigs (glTF, most
    BVH), a quarter turn about x for z-up ones (Blender's own BVH export: y -> z, our forward +z ->
    -y, Blender's front). The rig's up: the world axis nearest its hips -> head at rest."""
    up = rest[roles.head] - rest[roles.hips]
    axis = int(np.argmax(np.abs(up)))
    if np.linalg.norm(up) <= EPS:
        raise StableMoError(f"{where}: the head sits on the hips at rest; cannot tell which way is up")
    target = np.zeros(3)
    target[axis] = np.sign(up[axis])
    if target[1] < -0.5:  # upside down: half a turn about z (x -> -x), not a reflection
        return np.diag([-1.0, -1.0, 1.0])
    return swing(np.array([[0.0, 1.0, 0.0]]), target[None])[0]
