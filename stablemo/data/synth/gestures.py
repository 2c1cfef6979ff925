"""Arm gestures: wave, raise arms, punch and clap (plus the waving overlay that walking reuses)."""

from __future__ import annotations

import numpy as np

from stablemo.data.synth.action_helpers import envelope, hold_root, tile
from stablemo.data.synth.body import LEFT, RIGHT, SIDE_SIGN
from stablemo.data.synth.gait import smoothstep
from stablemo.data.synth.timeline import FPS, Timeline

# --- arm gestures -----------------------------------------------------------------------------


def arm_sides(which: str):
    return {"left": (LEFT,), "right": (RIGHT,), "both": (LEFT, RIGHT)}[which]


def build_wave(tl: Timeline, p: dict) -> None:
    start = tl.t
    n = int(p.get("duration", 2.4) * FPS)
    sl = hold_root(tl, n)
    env = envelope(n, 0.45 * FPS, 0.45 * FPS)
    wave_arms(tl, sl, p["hand"], env)
    if p["hand"] != "both":
        tl.torso_roll[sl] += SIDE_SIGN[arm_sides(p["hand"])[0]] * 0.04 * env
    tl.t += n
    tl.add_part("wave", p, start)


def wave_arms(tl: Timeline, sl: slice, hand: str, env: np.ndarray) -> None:
    """Raise the hand(s) and swing the forearm side to side at 2 Hz, with weight env (n,)."""
    n = len(env)
    f = np.arange(n, dtype=float)
    both = hand == "both"
    for s in arm_sides(hand):
        sg = SIDE_SIGN[s]
        phi = 0.15 + 0.45 * np.sin(2 * np.pi * 2.0 * f / FPS) * smoothstep(2 * env - 1)
        upper = tile([sg * 0.7, 0.75 if both else 0.35, 0.25], n)
        fore = np.stack([sg * np.sin(phi), np.cos(phi), np.full(n, 0.2)], -1)
        tl.blend_arm(s, sl, upper, fore, env)


RAISE_POSES = {  # (upper, forearm) for the left arm; x is mirrored for the right
    "up": ([0.2, 1.0, 0.08], [0.12, 1.0, 0.05]),
    "sideways": ([1.0, 0.05, 0.0], [1.0, 0.08, 0.05]),
    "forward": ([0.12, 0.05, 1.0], [0.06, 0.07, 1.0]),
}


def build_raise_arms(tl: Timeline, p: dict) -> None:
    start = tl.t
    go, hold = 0.6 * FPS, p.get("hold", 1.0) * FPS
    n = int(np.ceil(2 * go + hold + 0.3 * FPS))
    sl = hold_root(tl, n)
    env = envelope(n, go, go)
    up, fore = RAISE_POSES[p["mode"]]
    for s in arm_sides(p["hand"]):
        sg = SIDE_SIGN[s]
        tl.blend_arm(s, sl, tile([sg * up[0], up[1], up[2]], n), tile([sg * fore[0], fore[1], fore[2]], n), env)
    tl.t += n
    tl.add_part("raise_arms", p, start)


def build_punch(tl: Timeline, p: dict) -> None:
    """Guard up, then `count` straight punches (alternating if hand == 'both'), guard down."""
    start = tl.t
    count = p["count"]
    guard_t, per = 0.45 * FPS, 0.45 * FPS
    n = int(np.ceil(2 * guard_t + count * per + 0.3 * FPS))
    sl = hold_root(tl, n)
    f = np.arange(n, dtype=float)
    guard = envelope(n, guard_t, guard_t)
    for s in (LEFT, RIGHT):
        sg = SIDE_SIGN[s]
        tl.blend_arm(s, sl, tile([sg * 0.3, -0.8, 0.5], n), tile([-sg * 0.25, 0.8, 0.55], n), guard)
    hands = [RIGHT if p["hand"] == "right" else LEFT if p["hand"] == "left" else (RIGHT, LEFT)[i % 2]
             for i in range(count)]
    tl.root_y[sl] -= 0.03 * guard
    for i, s in enumerate(hands):
        sg = SIDE_SIGN[s]
        u = (f - guard_t - i * per) / per
        ext = np.where((u >= 0) & (u <= 1), np.sin(np.pi * np.clip(u, 0, 1)) ** 1.5, 0.0)
        tl.blend_arm(s, sl, tile([-sg * 0.1, 0.12, 1.0], n), tile([-sg * 0.1, 0.12, 1.0], n), ext)
        tl.torso_twist[sl] += -sg * 0.35 * ext
    tl.t += n
    tl.add_part("punch", p, start)


def build_clap(tl: Timeline, p: dict) -> None:
    start = tl.t
    count = p["count"]
    go, per = 0.4 * FPS, 0.4 * FPS
    n = int(np.ceil(2 * go + count * per + 0.3 * FPS))
    sl = hold_root(tl, n)
    f = np.arange(n, dtype=float)
    env = envelope(n, go, go)
    closed = np.zeros(n)
    for i in range(count):
        u = (f - go - i * per) / per
        closed += np.where((u >= 0) & (u <= 1), np.sin(np.pi * np.clip(u, 0, 1)) ** 2, 0.0)
    for s in (LEFT, RIGHT):
        sg = SIDE_SIGN[s]
        tl.blend_arm(s, sl, tile([sg * 0.25, -0.5, 0.8], n), tile([sg * 0.2, 0.15, 0.9], n), env)
        tl.blend_arm(s, sl, tile([sg * 0.15, -0.5, 0.8], n), tile([-sg * 0.85, 0.2, 0.5], n), closed * env)
    tl.t += n
    tl.add_part("clap", p, start)
