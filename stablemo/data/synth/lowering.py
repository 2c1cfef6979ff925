"""Lowering the body: squat, crouch and bow (knee bend / forward bend with arm poses)."""

from __future__ import annotations

import numpy as np

from stablemo.data.synth.action_helpers import (
    body_to_world,
    gaussian_smooth,
    hold_root,
    tile,
)
from stablemo.data.synth.body import LEFT, RIGHT, SIDE_SIGN
from stablemo.data.synth.gait import smoothstep
from stablemo.data.synth.timeline import FPS, Timeline

# --- lowering the body ---------------------------------------------------------------------------


def build_squat(tl: Timeline, p: dict) -> None:
    start = tl.t
    count, depth = p["count"], p.get("depth", 0.36)
    per = p.get("period", 1.7) * FPS
    n = int(np.ceil(count * per + 0.5 * FPS))
    sl = hold_root(tl, n)
    f = np.arange(n, dtype=float)
    down = np.zeros(n)
    for i in range(count):
        u = (f - 4 - i * per) / per
        down += np.where((u >= 0) & (u <= 1), np.sin(np.pi * np.clip(u, 0, 1)) ** 2, 0.0)
    _lower(tl, sl, down, depth, back=0.14, lean=0.55)
    arms = smoothstep(gaussian_smooth(down, 2.0) * 1.6)
    for s in (LEFT, RIGHT):
        sg = SIDE_SIGN[s]
        tl.blend_arm(s, sl, tile([sg * 0.12, 0.0, 1.0], n), tile([sg * 0.08, 0.05, 1.0], n), arms)
    tl.t += n
    tl.add_part("squat", p, start)


def build_crouch(tl: Timeline, p: dict) -> None:
    start = tl.t
    hold = p.get("hold", 1.2) * FPS
    go = 0.8 * FPS
    n = int(np.ceil(2 * go + hold + 0.4 * FPS))
    sl = hold_root(tl, n)
    f = np.arange(n, dtype=float)
    down = smoothstep((f - 2) / go) * (1 - smoothstep((f - 2 - go - hold) / go))
    _lower(tl, sl, down, p.get("depth", 0.42), back=0.12, lean=0.7)
    tl.head_pitch[sl] += -0.3 * down
    for s in (LEFT, RIGHT):
        sg = SIDE_SIGN[s]
        tl.blend_arm(s, sl, tile([sg * 0.1, -0.55, 0.85], n), tile([sg * 0.02, -0.75, 0.6], n), down)
    tl.t += n
    tl.add_part("crouch", p, start)


def _lower(tl: Timeline, sl: slice, down: np.ndarray, depth: float, back: float, lean: float) -> None:
    """Bend the knees: pelvis down and back, chest forward, knees out over the toes."""
    n = len(down)
    tl.root_y[sl] -= depth * down
    xz = tl.root_xz[sl] + body_to_world(np.full(n, tl.heading), 0.0, -back * down)
    tl.set_root(sl, xz, tl.yaw[sl].copy())
    tl.torso_pitch[sl] += lean * down
    tl.knee_out[sl] += 0.35 * down


def build_bow(tl: Timeline, p: dict) -> None:
    start = tl.t
    angle = np.deg2rad(p.get("angle", 50.0))
    go, hold = 0.7 * FPS, p.get("hold", 0.6) * FPS
    n = int(np.ceil(2 * go + hold + 0.4 * FPS))
    sl = hold_root(tl, n)
    f = np.arange(n, dtype=float)
    w = smoothstep((f - 2) / go) * (1 - smoothstep((f - 2 - go - hold) / go))
    tl.torso_pitch[sl] += angle * w
    tl.head_pitch[sl] += 0.25 * w
    xz = tl.root_xz[sl] + body_to_world(np.full(n, tl.heading), 0.0, -0.09 * w * angle)
    tl.set_root(sl, xz, tl.yaw[sl].copy())
    tl.root_y[sl] -= 0.02 * w
    tl.t += n
    tl.add_part("bow", p, start)
