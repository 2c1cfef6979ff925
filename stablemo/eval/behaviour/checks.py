"""Verdicts: does one motion do what its prompt says, attribute by attribute?

`score(prompt, joints, fps)` -> {attribute: Verdict(passed, measured)} for the attributes the prompt
tests (stablemo.eval.behaviour.table), from the joint measures of stablemo.eval.behaviour.measures.
Composites are scored on their order: each part's characteristic event (`events`) must be found,
and the parts' median event times must come in the order the text names them.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise

import numpy as np

from stablemo.eval.behaviour import measures as m
from stablemo.eval.behaviour.table import Prompt
from stablemo.eval.heading import BACKWARD_DEG, SIDEWAYS_DEG

# Speed classes: the synthetic generator's ranges (stablemo.data.synth.actions.sample_params), cut
# half-way between neighbours: walks slow 0.7-0.9 / normal 1.1-1.35 / fast 1.6-1.85 m/s, jog 2.0-2.5,
# run 3.0-3.7; backwards slow 0.45-0.6 / normal 0.75-0.95. Measured as the cruising speed: the
# CRUISE_PERCENTILE of the pelvis's speed over moving frames (a 3 s run spends half its moving
# frames speeding up and slowing down, so its median is a jog's).
SPEED_BANDS = {
    "walk": {"slow": (0.0, 1.0), "normal": (1.0, 1.475), "fast": (1.475, 1.925)},
    "jog": {"jog": (1.925, 2.75)},
    "run": {"run": (2.75, np.inf)},
    "walk_backward": {"slow": (0.0, 0.675), "normal": (0.675, 1.5)},
}
CRUISE_PERCENTILE = 90.0
TURN_MIN_DEG = 45.0  # a turn: at least this much (half of the smaller asked angle)
ANGLE_TOLERANCE_DEG = {"turn": 45.0, "circle": 90.0}  # 90 and 180 stay apart; a circle is 270-450
CIRCLE_MIN_DEG = 180.0  # a circle in a direction: at least half way round
JUMP_FORWARD_M = 0.3  # a jump forward travels at least this far (synthetic: 0.5-0.9 m per jump)
STAND_STILL_M = 0.3  # standing: the pelvis ends within this of where it started
CROUCH_DEPTH_M = 0.25  # a crouch goes this far down (synthetic 0.38-0.45 m) ...
CROUCH_HOLD_S = 0.5  # ... and stays down at least this long
POSE_MIN_S = 0.3  # a raised arm's pose (up, sideways, forward), a bow: held at least this long
EVENT_MIN_FRAMES = 2  # a composite's part needs at least this many event frames to be placed in time


@dataclass(frozen=True)
class Verdict:
    passed: bool
    measured: str  # what the joints showed, for the report


def _frames(fps: float, seconds: float) -> int:
    return max(1, round(seconds * fps))


def _held(mask: np.ndarray, fps: float, seconds: float) -> bool:
    return bool(m.spans(mask, None, _frames(fps, seconds)))


def _sides(value: str) -> set[str]:
    return {"left", "right"} if value == "both" else {value}


def _gait_verdict(g: dict, fps: float, want: str) -> Verdict:
    if not m.moving_enough(g, fps):
        return Verdict(False, "did not move")
    angle = float(np.median(g["angle"][g["moving"]]))
    signed = float(np.median(g["signed"][g["moving"]]))
    if angle < SIDEWAYS_DEG:
        got = "forward"
    elif angle > BACKWARD_DEG:
        got = "backward"
    else:
        got = "left" if signed > 0 else "right"
    return Verdict(got == want, f"{got} (facing vs travel {angle:.0f} deg)")


def _count(action: str, j: np.ndarray, fps: float, params: dict) -> int:
    if action in ("jump", "jump_forward"):
        return len(m.airborne_spans(j, fps))
    if action == "hop":
        return len(m.hop_spans(j, params["leg"], fps))
    if action == "squat":
        return len(m.dip_spans(j, fps))
    if action == "punch":
        return sum(len(m.punch_spans(j, s, fps)) for s in m.SIDES)
    if action == "clap":
        return len(m.clap_spans(j, fps))
    raise KeyError(action)


def _side(action: str, j: np.ndarray, fps: float, want: str) -> Verdict:
    if action == "hop":
        n = {s: len(m.hop_spans(j, s, fps)) for s in m.SIDES}
        got = {s for s in m.SIDES if n[s]}
        return Verdict(got == {want}, f"hops on left {n['left']}, right {n['right']}")
    if action == "kick":
        got = {s for s in m.SIDES if m.kick_frames(j, s, fps).any()}
        peaks = {s: float(m.foot_height(j, s).max()) for s in m.SIDES}
        return Verdict(got == {want}, f"foot peaks left {peaks['left']:.2f} m, right {peaks['right']:.2f} m")
    if action in ("wave", "walk"):
        got = {s for s in m.SIDES if m.raised_spans(j, s, fps)}
    elif action == "raise_arms":
        got = {s for s in m.SIDES if _held(m.arm_pose(j, s, fps)["lifted"], fps, m.RAISED_MIN_S)}
    elif action == "punch":
        got = {s for s in m.SIDES if m.punch_spans(j, s, fps)}
    else:
        raise KeyError(action)
    return Verdict(got == _sides(want), "none" if not got else "both" if len(got) == 2 else got.pop())


def _direction(action: str, j: np.ndarray, fps: float, params: dict, want: str) -> Verdict:
    if action in ("walk", "jog", "run", "walk_backward", "walk_sideways"):
        return _gait_verdict(m.gait(j, fps), fps, want)
    if action in ("turn", "circle"):
        turned = m.heading_change(j, fps)
        got = "left" if turned > 0 else "right"
        if action == "circle":
            got = {"left": "counterclockwise", "right": "clockwise"}[got]
        least = TURN_MIN_DEG if action == "turn" else CIRCLE_MIN_DEG
        return Verdict(got == want and abs(turned) >= least, f"turned {turned:+.0f} deg (+ = left)")
    if action == "jump_forward":
        forward, left = m.start_frame_displacement(j, fps)
        return Verdict(forward > max(JUMP_FORWARD_M, abs(left)), f"moved {forward:.2f} m forward, {left:.2f} m left")
    if action == "raise_arms":
        held = {s: [pose for pose in ("up", "sideways", "forward") if _held(m.arm_pose(j, s, fps)[pose], fps, POSE_MIN_S)]
                for s in m.SIDES}
        ok = all(want in held[s] for s in _sides(params["hand"]))
        return Verdict(ok, "; ".join(f"{s}: {'/'.join(held[s]) or 'down'}" for s in m.SIDES))
    raise KeyError(action)


def _angle(action: str, j: np.ndarray, fps: float, want: int) -> Verdict:
    turned = m.heading_change(j, fps)
    return Verdict(abs(abs(turned) - want) <= ANGLE_TOLERANCE_DEG[action], f"turned {abs(turned):.0f} deg")


def _speed(action: str, j: np.ndarray, fps: float, want: str) -> Verdict:
    g = m.gait(j, fps)
    if not m.moving_enough(g, fps):
        return Verdict(False, "did not move")
    speed = float(np.percentile(g["speed"][g["moving"]], CRUISE_PERCENTILE))
    lo, hi = SPEED_BANDS[action][want]
    return Verdict(lo <= speed < hi, f"{speed:.2f} m/s")


def _body_part(action: str, j: np.ndarray, fps: float) -> Verdict:
    if action == "hop":
        n = sum(len(m.hop_spans(j, s, fps)) for s in m.SIDES)
        return Verdict(n > 0, f"{n} one-footed hops")
    if action == "kick":
        peak = max(float(m.foot_height(j, s).max()) for s in m.SIDES)
        return Verdict(any(m.kick_frames(j, s, fps).any() for s in m.SIDES), f"highest foot {peak:.2f} m")
    if action == "wave":
        got = [s for s in m.SIDES if m.wave_spans(j, s, fps)]
        return Verdict(bool(got), f"waving: {', '.join(got) or 'none'}")
    if action == "raise_arms":
        got = [s for s in m.SIDES if _held(m.arm_pose(j, s, fps)["lifted"], fps, m.RAISED_MIN_S)]
        return Verdict(bool(got), f"raised: {', '.join(got) or 'none'}")
    if action == "punch":
        n = sum(len(m.punch_spans(j, s, fps)) for s in m.SIDES)
        return Verdict(n > 0, f"{n} punches")
    if action == "clap":
        n = len(m.clap_spans(j, fps))
        return Verdict(n > 0, f"{n} claps")
    if action == "bow":
        return _action("bow", j, fps)
    raise KeyError(action)


def events(action: str, j: np.ndarray, fps: float) -> np.ndarray:
    """(T,) bool: the frames where the action's characteristic event shows (for order and action)."""
    T = len(j)
    if action in ("walk", "jog", "run", "walk_backward", "walk_sideways"):
        g = m.gait(j, fps)
        want = {"walk_backward": g["angle"] > BACKWARD_DEG,
                "walk_sideways": (g["angle"] >= SIDEWAYS_DEG) & (g["angle"] <= BACKWARD_DEG)}
        return g["moving"] & want.get(action, g["angle"] < SIDEWAYS_DEG)
    if action == "circle":
        return m.gait(j, fps)["moving"] & m.turning(j, fps)
    if action == "turn":
        return m.turning(j, fps)
    if action in ("jump", "jump_forward"):
        return m.span_mask(m.airborne_spans(j, fps), T)
    if action == "hop":
        return m.span_mask([r for s in m.SIDES for r in m.hop_spans(j, s, fps)], T)
    if action == "kick":
        return m.kick_frames(j, "left", fps) | m.kick_frames(j, "right", fps)
    if action == "squat":
        return m.pelvis_drop(j) > m.DIP_ON_M
    if action == "crouch":
        return m.pelvis_drop(j) > CROUCH_DEPTH_M
    if action == "bow":
        return m.bow_frames(j, fps)
    if action == "wave":
        return m.span_mask([r for s in m.SIDES for r in m.wave_spans(j, s, fps)], T)
    if action == "raise_arms":
        return m.arm_pose(j, "left", fps)["lifted"] | m.arm_pose(j, "right", fps)["lifted"]
    if action == "punch":
        return m.span_mask([r for s in m.SIDES for r in m.punch_spans(j, s, fps)], T)
    if action == "clap":
        return m.span_mask(m.clap_spans(j, fps), T)
    if action == "stand":
        return ~m.gait(j, fps)["moving"]
    raise KeyError(action)


def _action(action: str, j: np.ndarray, fps: float) -> Verdict:
    if action == "stand":
        forward, left = m.start_frame_displacement(j, fps)
        moved = float(np.hypot(forward, left))
        flights = len(m.airborne_spans(j, fps))
        return Verdict(moved < STAND_STILL_M and not flights, f"moved {moved:.2f} m, {flights} flights")
    if action == "crouch":
        runs = m.dip_spans(j, fps, CROUCH_DEPTH_M)
        longest = max((b - a for a, b in runs), default=0) / fps
        return Verdict(len(runs) >= 1 and longest >= CROUCH_HOLD_S, f"{len(runs)} dips, held {longest:.1f} s")
    if action == "bow":
        mask = events("bow", j, fps)
        return Verdict(_held(mask, fps, POSE_MIN_S), f"head forward {mask.sum() / fps:.1f} s")
    mask = events(action, j, fps)
    return Verdict(int(mask.sum()) >= EVENT_MIN_FRAMES, f"{mask.sum() / fps:.1f} s of {action}")


def _order(actions: list[str], j: np.ndarray, fps: float) -> Verdict:
    times = []
    for action in actions:
        frames = np.flatnonzero(events(action, j, fps))
        times.append(float(np.median(frames)) / fps if len(frames) >= EVENT_MIN_FRAMES else None)
    shown = " < ".join(f"{a}@{'none' if t is None else f'{t:.1f}s'}" for a, t in zip(actions, times))
    ok = None not in times and all(a < b for a, b in pairwise(times))
    return Verdict(ok, shown)


def score(prompt: Prompt, joints: np.ndarray, fps: float) -> dict[str, Verdict]:
    """{attribute: Verdict} for every attribute `prompt` tests, on one motion (T, 22, 3) metres."""
    j = np.asarray(joints, dtype=np.float64)
    part = prompt.parts[0]
    action, params = part.action, part.params
    out = {}
    for attribute, want in prompt.tests.items():
        if attribute == "order":
            out[attribute] = _order(want, j, fps)
        elif attribute == "action":
            out[attribute] = _action(action, j, fps)
        elif attribute == "count":
            n = _count(action, j, fps, params)
            out[attribute] = Verdict(n == want, str(n))
        elif attribute == "side":
            out[attribute] = _side(action, j, fps, want)
        elif attribute == "direction":
            out[attribute] = _direction(action, j, fps, params, want)
        elif attribute == "angle":
            out[attribute] = _angle(action, j, fps, want)
        elif attribute == "speed":
            out[attribute] = _speed(action, j, fps, want)
        elif attribute == "body_part":
            out[attribute] = _body_part(action, j, fps)
    return out


__all__ = ["SPEED_BANDS", "Verdict", "events", "score"]
