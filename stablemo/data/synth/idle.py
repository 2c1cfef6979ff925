"""Idle rest around a clip's action: the lead-in before it and the lead-out after it.

The person stands on both planted feet and idles: a slow postural sway of the pelvis, breathing in
the chest, the head and chest looking a little about, arms swinging slightly with the body, and
sometimes a shift of weight towards one foot; a lead-out begins by settling (a small give in the
knees and an exhale) after the action. Nothing here steps or lifts a foot (feet stay exactly put,
no skating), and nothing is captioned: the caption stays the action's.

A lead-in fades every offset out by its last frame, so the action starts from the neutral standing
pose its builder expects; a lead-out starts from zero (the pose the action ended in) and may end
with the weight shifted.

How long the rest is, is the generator's option `rest` (REST_MODES; compose.generate_motion).
"""

from __future__ import annotations

import numpy as np

from stablemo.data.synth import body
from stablemo.data.synth.action_helpers import body_to_world
from stablemo.data.synth.body import LEFT, RIGHT, SIDE_SIGN
from stablemo.data.synth.gait import smoothstep
from stablemo.data.synth.timeline import FPS, Timeline

REST_MODES = {
    "varied": "a clip's total length is drawn uniformly over the lengths its action fits (up to 196 "
              "frames) and the rest is split at random into an idle lead-in and lead-out, so length "
              "does not imply how often the action happens",
    "tight": "0.1-0.4 s of standing before the action and 0.2-0.5 s after it: a clip is as long as its "
             "action (the data of generator version 1 and of the shipped demo models)",
}
DEFAULT_REST = "varied"

FADE = 0.8 * FPS  # frames over which a lead-in's idling fades out before the action (and a lead-out's fades in)
SHIFT_FRAMES = 0.9 * FPS  # frames to move the weight onto one foot (or back)
SHIFT_MIN_FRAMES = {"in": 3 * FPS, "out": 2 * FPS}  # shorter rests do not shift the weight (no room to)
SETTLE_FRAMES = (5, 20)  # frames of the settling give after the action: down, then back up


def sample_style(rng: np.random.Generator) -> dict:
    """Draw one rest's idling: amplitudes (m, rad), periods (s), phases, and an optional weight shift."""
    u = rng.uniform
    return dict(
        sway=float(u(0.004, 0.01)), sway_period=float(u(3.0, 6.0)), sway_phase=float(u(0, 2 * np.pi)),
        sway_fwd=float(u(0.002, 0.005)), fwd_period=float(u(4.0, 7.0)), fwd_phase=float(u(0, 2 * np.pi)),
        breath=float(u(0.008, 0.016)), breath_period=float(u(3.0, 4.5)), breath_phase=float(u(0, 2 * np.pi)),
        look=float(u(0.0, 0.05)), look_period=float(u(5.0, 9.0)), look_phase=float(u(0, 2 * np.pi)),
        arm=float(u(0.01, 0.04)),
        shift=float(u(0.015, 0.03)) if u() < 0.6 else 0.0, shift_side=int(rng.integers(2)),
        shift_at=float(u()), settle=float(u(0.006, 0.018)),
    )


def _wave(f: np.ndarray, amp: float, period: float, phase: float) -> np.ndarray:
    return amp * np.sin(2 * np.pi * f / (period * FPS) + phase)


def _shift_profile(n: int, at: float, lead: str) -> np.ndarray:
    """(n,) weight-shift fraction 0..1: a lead-in goes over and comes back before its fade; a
    lead-out goes over at some moment after its settling and stays."""
    f = np.arange(n, dtype=float)
    if lead == "in":
        room = n - 2 * SHIFT_FRAMES - FADE  # frames left for holding the shift
        a = at * 0.5 * room
        b = a + SHIFT_FRAMES + 0.5 * room
        return smoothstep((f - a) / SHIFT_FRAMES) * (1 - smoothstep((f - b) / SHIFT_FRAMES))
    a = FADE + at * (n - FADE - SHIFT_FRAMES)
    return smoothstep((f - a) / SHIFT_FRAMES)


def build_idle(tl: Timeline, n: int, style: dict, lead: str) -> None:
    """Append `n` frames of idle rest at the cursor; lead "in" (before the action) or "out" (after it)."""
    if lead not in ("in", "out"):
        raise ValueError(f"lead={lead!r}: 'in' or 'out'")
    if n <= 0:
        return
    sl = tl.frames(n)
    f = np.arange(n, dtype=float)
    fade = min(FADE, n - 1.0) or 1.0
    # env (n,): 1 while idling, 0 where the action's pose holds (the lead-in's last frame, the lead-out's first)
    env = smoothstep((n - 1 - f) / fade) if lead == "in" else smoothstep(f / fade)
    s = style
    x = _wave(f, s["sway"], s["sway_period"], s["sway_phase"]) * env  # (n,) m towards the left
    z = _wave(f, s["sway_fwd"], s["fwd_period"], s["fwd_phase"]) * env  # (n,) m forward
    if s["shift"] > 0 and n >= SHIFT_MIN_FRAMES[lead]:
        x = x + SIDE_SIGN[s["shift_side"]] * s["shift"] * _shift_profile(n, s["shift_at"], lead) * env
    heading = tl.heading
    tl.set_root(sl, tl.pos + body_to_world(heading, x, z), np.full(n, heading))
    # the chest leans a little against the pelvis' sideways shift, keeping the head over the feet
    tl.torso_roll[sl] += 0.8 * x
    tl.torso_pitch[sl] += _wave(f, s["breath"], s["breath_period"], s["breath_phase"]) * env
    tl.torso_twist[sl] += _wave(f, s["look"], s["look_period"], s["look_phase"]) * env
    tl.head_pitch[sl] += _wave(f, 0.6 * s["look"], 0.7 * s["look_period"], s["look_phase"] + 1.0) * env
    if lead == "out":
        down, up = SETTLE_FRAMES
        give = smoothstep(f / down) * (1 - smoothstep((f - down) / up))  # (n,) 0 -> 1 -> 0
        tl.root_y[sl] -= s["settle"] * give
        tl.torso_pitch[sl] += 2.5 * s["settle"] * give
        tl.head_pitch[sl] += 3.0 * s["settle"] * give
    for side in (LEFT, RIGHT):
        # arms hang and swing a little with the sway, each at its own phase
        swing = _wave(f, s["arm"], 0.5 * s["sway_period"], s["sway_phase"] + 1.3 * side) * env  # (n,) rad
        tl.upper_arm[side][sl] = _unit(body.apply(body.rot_x(-swing), tl.upper_arm[side][sl]))
        tl.forearm[side][sl] = _unit(body.apply(body.rot_x(-1.3 * swing), tl.forearm[side][sl]))
    tl.t += n


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)
