"""Pelvis paths a user draws, as joint-control targets: the held-out families of the heading check.

Each family is a horizontal curve from the origin, walked at a constant speed (arc-length
parameterised), starting in any direction (the body starts facing +z at frame 0, so a path that
starts elsewhere asks the body to turn):

- straight: a line at heading `start`;
- arc: a circular arc of radius r turning `turn` radians (left > 0);
- s_curve: two arcs of opposite turn, one after the other;
- out_and_back: a line out, a half-circle turn of small radius, the line back.

`family_path(name, rng, frames, fps, speed)` draws one with random parameters; `path_control` makes
the JointControl of the pelvis at every frame with the given heights (e.g. a free motion's own, as
the page does).
"""

from __future__ import annotations

import math

import numpy as np

FAMILIES = ("straight", "arc", "s_curve", "out_and_back")


def _walk(curvature: np.ndarray, start: float, ds: float) -> np.ndarray:
    """Integrate a curvature profile (per step, 1/units) from the origin at heading `start`
    (yaw, 0 = +z): (N + 1, 2) xz points ds apart."""
    yaw = start + np.concatenate([[0.0], np.cumsum(curvature[:-1] * ds)])
    steps = ds * np.stack([np.sin(yaw), np.cos(yaw)], -1)
    return np.concatenate([np.zeros((1, 2)), np.cumsum(steps, 0)])


def family_path(name: str, rng: np.random.Generator, frames: int, fps: float, speed: float) -> np.ndarray:
    """(frames, 2) xz of a `name` path walked at `speed` units/s, random parameters from `rng`."""
    if name not in FAMILIES:
        raise ValueError(f"unknown path family {name!r}; choose from {FAMILIES}")
    length = speed * (frames - 1) / fps
    n = 4 * (frames - 1)  # fine arc-length steps, then resampled per frame
    ds = length / n
    s = np.arange(n) * ds
    start = float(rng.uniform(-math.pi, math.pi))
    k = np.zeros(n)
    if name == "arc":
        turn = float(rng.choice([-1, 1]) * rng.uniform(math.pi / 3, math.pi))
        k[:] = turn / length
    elif name == "s_curve":
        turn = float(rng.choice([-1, 1]) * rng.uniform(math.pi / 3, 2 * math.pi / 3))
        half = s < length / 2
        k[half], k[~half] = turn / (length / 2), -turn / (length / 2)
    elif name == "out_and_back":
        radius = float(rng.uniform(0.3, 0.6))
        arc = math.pi * radius
        leg = max((length - arc) / 2, 0.0)
        side = float(rng.choice([-1, 1]))
        k[(s >= leg) & (s < leg + arc)] = side / radius
    points = _walk(k, start, ds)
    return points[:: 4][:frames]


def path_control(xz: np.ndarray, heights: np.ndarray, num_joints: int):
    """A JointControl of the pelvis at every frame: xz (T, 2), heights (T,)."""
    from stablemo.control.spec import JointControl

    T = len(xz)
    positions = np.zeros((T, num_joints, 3), np.float32)
    positions[:, 0] = np.stack([xz[:, 0], heights[:T], xz[:, 1]], -1)
    mask = np.zeros((T, num_joints), bool)
    mask[:, 0] = True
    return JointControl(positions, mask)


__all__ = ["FAMILIES", "family_path", "path_control"]
