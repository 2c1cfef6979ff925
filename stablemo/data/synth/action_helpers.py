"""Shared helpers for the action builders: gravity, weight envelopes, heading/body-frame
directions, unit-vector tiling for arm poses, holding the pelvis in place, and smoothing."""

from __future__ import annotations

import numpy as np

from stablemo.data.synth.gait import smoothstep
from stablemo.data.synth.timeline import Timeline

G = 9.81


def dir2(theta):
    """World xz direction of a body heading (yaw)."""
    theta = np.asarray(theta, float)
    return np.stack([np.sin(theta), np.cos(theta)], -1)


def body_to_world(yaw, x, z):
    """Body-frame (left x, forward z) offsets -> world xz."""
    yaw = np.asarray(yaw, float)
    left = np.stack([np.cos(yaw), -np.sin(yaw)], -1)
    return np.asarray(x)[..., None] * left + np.asarray(z)[..., None] * dir2(yaw)


def envelope(n: int, rise: float, fall: float) -> np.ndarray:
    """(n,) weight rising over `rise` frames, holding 1, falling over the last `fall` frames."""
    f = np.arange(n, dtype=float)
    return smoothstep(f / max(rise, 1e-6)) * smoothstep((n - 1 - f) / max(fall, 1e-6))


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def tile(v, n):
    return np.tile(_unit(v), (n, 1))


def hold_root(tl: Timeline, n: int) -> slice:
    sl = tl.frames(n)
    tl.set_root(sl, np.tile(tl.pos, (n, 1)), np.full(n, tl.heading))
    return sl


def gaussian_smooth(x, sigma):
    from scipy.ndimage import gaussian_filter1d
    return gaussian_filter1d(x, sigma, mode="nearest")
