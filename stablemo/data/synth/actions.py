"""Procedural actions. Each `build_<name>(tl, params)` appends one action at the timeline cursor.

Every action starts and ends standing with both feet planted, and writes a `Part` recording its
caption parameters (speed, direction, count, side, ...). `sample_params(name, rng)` draws them.

This module is the registry (BUILDERS, ACTIONS, LOCOMOTION, WALK_SPEEDS, sample_params); the
builders live in locomotion.py, leaps.py, lowering.py and gestures.py, shared helpers in
action_helpers.py.
"""

from __future__ import annotations

import numpy as np

from stablemo.data.synth.action_helpers import G, envelope, gaussian_smooth
from stablemo.data.synth.gestures import (
    RAISE_POSES,
    build_clap,
    build_punch,
    build_raise_arms,
    build_wave,
)
from stablemo.data.synth.leaps import build_hop, build_jump, build_kick
from stablemo.data.synth.locomotion import (
    GAITS,
    build_circle,
    build_jog,
    build_run,
    build_stand,
    build_turn,
    build_walk,
    build_walk_backward,
    build_walk_sideways,
)
from stablemo.data.synth.lowering import build_bow, build_crouch, build_squat

__all__ = [
    "ACTIONS", "BUILDERS", "GAITS", "G", "LOCOMOTION", "RAISE_POSES", "WALK_SPEEDS", "envelope",
    "gaussian_smooth", "sample_params", "build_bow", "build_circle", "build_clap", "build_crouch",
    "build_hop", "build_jog", "build_jump", "build_kick", "build_punch", "build_raise_arms", "build_run",
    "build_squat", "build_stand", "build_turn", "build_walk", "build_walk_backward", "build_walk_sideways",
    "build_wave",
]


BUILDERS = {
    "stand": build_stand, "walk": build_walk, "walk_backward": build_walk_backward,
    "walk_sideways": build_walk_sideways, "jog": build_jog, "run": build_run, "turn": build_turn,
    "circle": build_circle, "jump": build_jump, "jump_forward": build_jump, "hop": build_hop,
    "kick": build_kick, "squat": build_squat, "crouch": build_crouch, "bow": build_bow,
    "wave": build_wave, "raise_arms": build_raise_arms, "punch": build_punch, "clap": build_clap,
}
ACTIONS = tuple(BUILDERS)
LOCOMOTION = ("walk", "walk_backward", "walk_sideways", "jog", "run", "circle")

WALK_SPEEDS = {"slow": (0.7, 0.9), "normal": (1.1, 1.35), "fast": (1.6, 1.85)}


def sample_params(name: str, rng: np.random.Generator) -> dict:
    """Draw caption-relevant parameters (and a few hidden style ones) for one action."""
    u = rng.uniform
    if name == "stand":
        return dict(duration=float(u(1.5, 3.0)), phase=float(u(0, 2 * np.pi)))
    if name == "walk":
        speed = str(rng.choice(list(WALK_SPEEDS)))
        waving = str(rng.choice(["left", "right", "both"])) if speed != "fast" and u() < 0.2 else None
        return dict(speed_label=speed, speed=float(u(*WALK_SPEEDS[speed])), duration=float(u(2.5, 4.5)),
                    first_foot=int(rng.integers(2)), waving=waving)
    if name == "walk_backward":
        speed = str(rng.choice(["slow", "normal"]))
        return dict(speed_label=speed, speed=float(u(0.45, 0.6) if speed == "slow" else u(0.75, 0.95)),
                    duration=float(u(2.5, 4.0)), first_foot=int(rng.integers(2)))
    if name == "walk_sideways":
        return dict(direction=str(rng.choice(["left", "right"])), speed=float(u(0.35, 0.55)),
                    duration=float(u(2.0, 3.5)))
    if name == "jog":
        return dict(speed=float(u(2.0, 2.5)), duration=float(u(2.2, 3.5)), first_foot=int(rng.integers(2)))
    if name == "run":
        return dict(speed=float(u(3.0, 3.7)), duration=float(u(2.2, 3.2)), first_foot=int(rng.integers(2)))
    if name == "turn":
        return dict(direction=str(rng.choice(["left", "right"])), angle=int(rng.choice([90, 180])),
                    rate=float(u(120, 170)))
    if name == "circle":
        return dict(direction=str(rng.choice(["clockwise", "counterclockwise"])), radius=float(u(0.6, 0.85)),
                    speed=float(u(0.9, 1.15)))
    if name == "jump":
        return dict(count=int(rng.integers(1, 4)), flight=float(u(0.36, 0.46)))
    if name == "jump_forward":
        return dict(count=int(rng.integers(1, 3)), distance=float(u(0.5, 0.9)), flight=float(u(0.4, 0.48)))
    if name == "hop":
        return dict(leg=str(rng.choice(["left", "right"])), count=int(rng.integers(2, 5)))
    if name == "kick":
        return dict(leg=str(rng.choice(["left", "right"])), height=float(u(0.4, 0.6)))
    if name == "squat":
        return dict(count=int(rng.integers(1, 4)), depth=float(u(0.3, 0.4)), period=float(u(1.5, 1.9)))
    if name == "crouch":
        return dict(hold=float(u(0.8, 1.8)), depth=float(u(0.38, 0.45)))
    if name == "bow":
        return dict(angle=float(u(40, 60)), hold=float(u(0.4, 1.0)))
    if name == "wave":
        return dict(hand=str(rng.choice(["left", "right", "both"])), duration=float(u(2.0, 3.2)))
    if name == "raise_arms":
        return dict(hand=str(rng.choice(["both", "both", "left", "right"])),
                    mode=str(rng.choice(list(RAISE_POSES))), hold=float(u(0.6, 1.4)))
    if name == "punch":
        return dict(hand=str(rng.choice(["left", "right", "both"])), count=int(rng.integers(1, 4)))
    if name == "clap":
        return dict(count=int(rng.integers(2, 5)))
    raise KeyError(name)
