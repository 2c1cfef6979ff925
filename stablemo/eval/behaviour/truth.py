"""Ground truth for the behaviour checks: the synthetic generator's own motion of a prompt, and
motions that are wrong in exactly one attribute.

`truth_joints(prompt, seed, frames)` builds the prompt's actions with stablemo.data.synth (the
parameters its text fixes; the others, and the hidden style ones, drawn from the generator's own
sampler by `seed`), standing still after them up to `frames`. `wrong_joints(prompt, attribute,
seed)` is the same kind of motion with that attribute changed: one more or one fewer jump, the
mirrored body (left <-> right, clockwise <-> counterclockwise), the parts reversed, another speed,
angle, direction or body part. Each check must pass on the first and fail on the second.
"""

from __future__ import annotations

import zlib

import numpy as np

from stablemo.data.synth import compose
from stablemo.data.synth.actions import sample_params
from stablemo.data.synth.timeline import FPS
from stablemo.errors import StableMoError
from stablemo.eval.behaviour.measures import J
from stablemo.eval.behaviour.table import Part, Prompt

MAX_DRAWS = 20000  # parameter draws to meet a part's fixed parameters (the rarest: a walk waving one hand)
MAX_PLANS = 50  # whole plans redrawn to fit the length limit
LEAD_IN_S, LEAD_OUT_S = 0.2, 0.3  # compose.build's still moments around the actions


def draw_params(part: Part, rng: np.random.Generator) -> dict:
    """Parameters for one part from the generator's own sampler, redrawn until they hold the
    part's fixed ones (a walk waves only when its part says so)."""
    fixed = dict(part.params)
    if part.action == "walk":
        fixed.setdefault("waving", None)
    for _ in range(MAX_DRAWS):
        params = sample_params(part.action, rng)
        if all(params.get(k) == v for k, v in fixed.items()):
            return params
    raise StableMoError(f"{part.action} {part.params}: the synthetic generator never draws these parameters")


def _rng(prompt_or_parts, seed: int) -> np.random.Generator:
    key = repr([(p.action, sorted(p.params.items())) for p in prompt_or_parts])
    return np.random.default_rng([seed, zlib.crc32(key.encode())])


def build_parts(parts: tuple[Part, ...], seed: int, frames: int | None = None) -> np.ndarray:
    """(T, 22, 3) float64 joints of the parts; T = `frames` when the actions fit in it (standing
    still after them), else their own length. Deterministic in (parts, seed)."""
    rng = _rng(parts, seed)
    for _ in range(MAX_PLANS):
        plan = [(p.action, draw_params(p, rng)) for p in parts]
        built = compose.build(plan, LEAD_IN_S, LEAD_OUT_S)
        natural = len(built.joints) - 1  # the generator's feature frames
        if natural <= compose.MAX_FRAMES:
            break
    else:
        raise StableMoError(f"{[p.action for p in parts]}: no draw fits {compose.MAX_FRAMES} frames")
    if frames is not None and frames > natural:
        built = compose.build(plan, LEAD_IN_S, LEAD_OUT_S + (frames - natural + 1) / FPS)
        return built.joints[:frames].astype(np.float64)
    return built.joints[:natural].astype(np.float64)


def truth_joints(prompt: Prompt, seed: int, frames: int | None = None) -> np.ndarray:
    return build_parts(prompt.parts, seed, frames)


def natural_frames(prompt: Prompt) -> int:
    """The prompt's length as the generator makes it (seed 0)."""
    return len(truth_joints(prompt, 0))


MIRROR = [J[n.replace("L_", "R_") if n.startswith("L_") else n.replace("R_", "L_")] for n in J]


def mirrored(joints: np.ndarray) -> np.ndarray:
    """The body mirrored left <-> right (x negated, left and right joints swapped)."""
    out = joints[:, MIRROR].copy()
    out[..., 0] *= -1
    return out


_NEXT_MODE = {"up": "sideways", "sideways": "forward", "forward": "up"}
_OTHER_SPEED = {"walk": {"slow": "fast", "normal": "fast", "fast": "slow"},
                "walk_backward": {"slow": "normal", "normal": "slow"}}
_OTHER_LIMB = {  # the same action's side done by another body part
    "kick": lambda p: Part("punch", {"hand": p["leg"], "count": 1}),
    "punch": lambda p: Part("kick", {"leg": "left" if p["hand"] == "both" else p["hand"]}),
    "hop": lambda p: Part("jump", {"count": min(p["count"], 3)}),  # the generator jumps 1-3 times
    "wave": lambda p: Part("kick", {"leg": "left" if p["hand"] == "both" else p["hand"]}),
    "raise_arms": lambda p: Part("kick", {"leg": "left" if p["hand"] == "both" else p["hand"]}),
    "clap": lambda p: Part("wave", {"hand": "both"}),
    "bow": lambda p: Part("squat", {"count": 1}),
}


def wrong_parts(prompt: Prompt, attribute: str) -> tuple[Part, ...] | str:
    """Parts wrong in `attribute` only, or "mirror" where the mirrored truth is the wrong motion."""
    if attribute == "order":
        return tuple(reversed(prompt.parts))
    part = prompt.parts[0]
    a, p = part.action, dict(part.params)
    if attribute == "action":
        return (Part("walk", {"speed_label": "normal"}),) if a == "stand" else (Part("stand", {}),)
    if attribute == "count":  # one more, or one fewer where the generator never draws more
        more = Part(a, {**p, "count": p["count"] + 1})
        try:
            draw_params(more, np.random.default_rng(0))
            return (more,)
        except StableMoError:
            return (Part(a, {**p, "count": p["count"] - 1}),)
    if attribute == "side":
        if prompt.tests["side"] == "both":
            return (Part(a, {**p, "hand": "left"}),)
        return "mirror"
    if attribute == "direction":
        if a in ("turn", "walk_sideways", "circle"):
            return "mirror"
        if a == "raise_arms":
            return (Part(a, {**p, "mode": _NEXT_MODE[p["mode"]]}),)
        if a == "walk_backward":
            return (Part("walk", {"speed_label": "normal"}),)
        if a == "jump_forward":
            return (Part("jump", {"count": p["count"]}),)
        return (Part("walk_backward", {"speed_label": "normal"}),)
    if attribute == "angle":
        if a == "circle":
            return (Part("turn", {"direction": "left" if p["direction"] == "counterclockwise" else "right", "angle": 180}),)
        return (Part(a, {**p, "angle": 270 - p["angle"]}),)
    if attribute == "speed":
        if a in _OTHER_SPEED:
            return (Part(a, {**p, "speed_label": _OTHER_SPEED[a][p["speed_label"]]}),)
        return (Part("jog" if a == "run" else "run", {}),)
    if attribute == "body_part":
        return (_OTHER_LIMB[a](p),)
    raise KeyError(attribute)


def wrong_joints(prompt: Prompt, attribute: str, seed: int, frames: int | None = None) -> np.ndarray:
    parts = wrong_parts(prompt, attribute)
    if parts == "mirror":
        return mirrored(truth_joints(prompt, seed, frames))
    return build_parts(parts, seed, frames)


__all__ = ["build_parts", "draw_params", "mirrored", "natural_frames", "truth_joints", "wrong_joints", "wrong_parts"]
