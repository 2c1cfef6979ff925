"""Path walks: a person walks forward along a random curved path, facing where they go.

The regular actions walk straight ahead of the body's first heading, or in a circle: a joint-control
model trained on them never sees a pelvis path that starts to the side or behind, bends, or turns
back, and so cannot learn to turn the body onto a path. A path walk is one action (`walk_path`):

1. when the path starts well away from the body's heading (50 degrees or more), the person first
   turns on the spot toward it (the turn of locomotion.build_turn, any angle);
2. then walks forward along a chain of 1-4 segments, each straight, a bend (20-120 degrees, radius
   >= 0.6 m) or a U-turn (150-200 degrees, radius 0.45-0.7 m), stepping all the way
   (locomotion.locomote with a `turning` profile). A smaller start angle is a first bend.

The shapes are drawn from this generic chain, not from the families the heading check measures
(stablemo.eval.paths), so that check stays held out. Captions say a forward walk and, where the path
has them, its bends and turnarounds ("walks forward and curves to the left", "walks forward, turns
around and walks back").
"""

from __future__ import annotations

import numpy as np

from stablemo.data.synth.actions import WALK_SPEEDS
from stablemo.data.synth.locomotion import build_turn, locomote
from stablemo.data.synth.timeline import Timeline

SPOT_TURN = np.deg2rad(50.0)  # a start this far from the heading is turned on the spot first
MAX_WALK_S = 6.5  # seconds of walking at most (the clip's other frames: the turn and the rest)


def sample_params(rng: np.random.Generator) -> dict:
    """A path walk's parameters: speed, first foot, the start direction and the segments."""
    u = rng.uniform
    speed_label = str(rng.choice(list(WALK_SPEEDS)))
    speed = float(u(*WALK_SPEEDS[speed_label]))
    start = float(u(-np.pi, np.pi)) if u() < 0.7 else float(u(-0.3, 0.3))
    segments: list[tuple[float, float]] = []  # (length m, heading change rad)
    if abs(start) < SPOT_TURN:
        segments.append((float(u(0.7, 1.3)), start))
    budget = speed * float(u(2.5, MAX_WALK_S))  # metres to walk
    walked = sum(length for length, _ in segments)
    for _ in range(int(rng.integers(1, 5))):
        kind = rng.choice(["straight", "bend", "uturn"], p=[0.35, 0.45, 0.2])
        side = float(rng.choice([-1.0, 1.0]))
        if kind == "straight":
            seg = (float(u(0.6, 2.5)), 0.0)
        elif kind == "bend":
            angle = float(np.deg2rad(u(20, 120)))
            seg = (angle * float(u(0.6, 2.0)), side * angle)
        else:
            angle = float(np.deg2rad(u(150, 200)))
            seg = (angle * float(u(0.45, 0.7)), side * angle)
        if walked + seg[0] > budget and segments:
            break
        segments.append(seg)
        walked += seg[0]
    if walked < budget:  # the rest of the walk goes straight on
        segments.append((budget - walked, 0.0))
    return dict(speed_label=speed_label, speed=speed, first_foot=int(rng.integers(2)),
                spot_turn=start if abs(start) >= SPOT_TURN else 0.0,
                turn_rate=float(u(120, 170)), segments=segments)


def heading_profile(segments: list[tuple[float, float]]):
    """s (n,) metres -> heading change (n,) rad: constant curvature within each segment."""
    ends = np.cumsum([0.0] + [length for length, _ in segments])
    turns = np.cumsum([0.0] + [angle for _, angle in segments])

    def turning(s: np.ndarray) -> np.ndarray:
        return np.interp(s, ends, turns)  # linear in s within a segment: constant curvature

    return turning


def build_walk_path(tl: Timeline, p: dict) -> None:
    """Turn on the spot toward the path when it starts far off (p['spot_turn']), then walk it."""
    start = tl.t
    if p["spot_turn"]:
        spot = p["spot_turn"]
        build_turn(tl, dict(direction="left" if spot > 0 else "right", angle=float(np.rad2deg(abs(spot))),
                            rate=p["turn_rate"]))
        tl.parts.pop()  # one action: the turn is part of the path walk
    distance = sum(length for length, _ in p["segments"])
    locomote(tl, p, "walk", 0.0, distance=distance, turning=heading_profile(p["segments"]))
    tl.add_part("walk_path", p, start)


def shape_words(p: dict) -> tuple[str, str | None]:
    """(the turn before walking, the path's shape) as caption pieces; either may be empty/None."""
    spot = p["spot_turn"]
    first = ""
    if spot:
        d = "left" if spot > 0 else "right"
        first = f"turns around to the {d}" if abs(spot) > np.deg2rad(135) else f"turns to the {d}"
    angles = [a for _, a in p["segments"]]
    if any(abs(a) >= np.deg2rad(150) for a in angles):
        return first, "turns around and walks back"
    net = float(sum(angles)) - (angles[0] if not spot and len(angles) > 1 else 0.0)
    bends = [a for a in angles if abs(a) >= np.deg2rad(20)]
    if len(bends) >= 2 and np.sign(bends[0]) != np.sign(bends[-1]):
        return first, "weaves along a winding path"
    if abs(net) >= np.deg2rad(20):
        return first, f"curves to the {'left' if net > 0 else 'right'}"
    return first, None


def phrases(p: dict) -> list[str]:
    """Paraphrases of one path walk (third person, present tense)."""
    pace = {"slow": " slowly", "normal": "", "fast": " quickly"}[p["speed_label"]]
    first, shape = shape_words(p)
    if shape is None:
        walks = [f"walks forward{pace}", f"walks{pace} along a path", f"walks{pace} ahead",
                 f"takes a walk forward{pace}"]
    elif shape == "turns around and walks back":
        walks = [f"walks forward{pace}, turns around and walks back", f"walks{pace} out and back",
                 f"walks forward{pace} and comes back", f"walks{pace} there and back again"]
    else:
        walks = [f"walks forward{pace} and {shape}", f"walks{pace} and {shape}",
                 f"walks{pace} along a curved path" if "curves" in shape else f"walks{pace} in a zigzag"]
    if first:
        return [f"{first}, then {w}" for w in walks[:3]] + [f"{first} and {walks[0]}"]
    return walks


__all__ = ["build_walk_path", "heading_profile", "phrases", "sample_params", "shape_words"]
