"""Composites of 1-3 actions, length-checked, with their captions."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stablemo.data.synth import actions, captions
from stablemo.data.synth.timeline import FPS, Built, Timeline
from stablemo.motion.skeleton import MAX_FRAMES as HUMANML3D_MAX_FRAMES

MIN_FRAMES = 40  # feature frames (HumanML3D's minimum clip length)
MAX_FRAMES = HUMANML3D_MAX_FRAMES  # feature frames (HumanML3D's maximum motion length)
PART_WEIGHTS = (0.45, 0.35, 0.20)  # P(1 action), P(2), P(3)


@dataclass
class SynthMotion:
    joints: np.ndarray  # (T+1, 22, 3) positions; features have T frames
    contacts: np.ndarray  # (T+1, 4) bool
    parts: list  # list[timeline.Part]
    captions: list[str]  # whole-clip captions
    sub_captions: list[tuple[str, float, float]]  # (caption, from s, to s) per part of a composite

    @property
    def actions(self) -> list[str]:
        return [p.action for p in self.parts]


def build(plan: list[tuple[str, dict]], lead_in: float = 0.2, lead_out: float = 0.3) -> Built:
    """Build a motion from (action, params) pairs, with short still moments around it."""
    tl = Timeline()
    actions.build_stand(tl, dict(duration=lead_in, phase=0.0))
    tl.parts.clear()
    for name, params in plan:
        actions.BUILDERS[name](tl, params)
    actions.build_stand(tl, dict(duration=lead_out, phase=0.0))
    tl.parts.pop()
    return tl.build(tl.t)


# Relative frequency of actions (walking is the backbone of text-to-motion data).
ACTION_WEIGHTS = {"walk": 2.0, "turn": 1.2, "circle": 1.2, "stand": 0.6}


def sample_names(rng: np.random.Generator) -> list[str]:
    k = int(rng.choice(3, p=PART_WEIGHTS)) + 1
    weights = np.array([ACTION_WEIGHTS.get(a, 1.0) for a in actions.ACTIONS])
    names: list[str] = []
    while len(names) < k:
        name = str(rng.choice(actions.ACTIONS, p=weights / weights.sum()))
        if names and name == names[-1]:
            continue
        if name == "stand" and k > 1 and rng.uniform() < 0.6:  # standing is a dull part of composites
            continue
        names.append(name)
    return names


def generate_motion(rng: np.random.Generator, max_tries: int = 40) -> SynthMotion:
    """One motion of 40..196 feature frames. Parameters are redrawn (then the actions) until the
    plan fits, so long actions are not crowded out of composites."""
    for attempt in range(max_tries):
        if attempt % 8 == 0:
            names = sample_names(rng)
        plan = [(n, actions.sample_params(n, rng)) for n in names]
        lead_in, lead_out = float(rng.uniform(0.1, 0.4)), float(rng.uniform(0.2, 0.5))
        try:
            built = build(plan, lead_in, lead_out)
        except OverflowError:
            continue
        frames = len(built.joints) - 1
        if frames > MAX_FRAMES:
            continue
        if frames < MIN_FRAMES:
            lead_out += (MIN_FRAMES - frames) / FPS + rng.uniform(0.0, 0.5)
            built = build(plan, lead_in, lead_out)
        return _caption(built, plan, rng)
    raise RuntimeError("could not fit a motion into the length limits")


def _caption(built: Built, plan: list[tuple[str, dict]], rng: np.random.Generator) -> SynthMotion:
    texts = captions.captions_for(plan, rng)
    subs: list[tuple[str, float, float]] = []
    n_feat = len(built.joints) - 1
    if len(plan) > 1:
        for part in built.parts:
            start, end = part.start, min(part.end, n_feat)
            subs.append((captions.part_caption(part.action, part.params, rng), start / FPS, end / FPS))
    return SynthMotion(built.joints, built.contacts, built.parts, texts, subs)


def text_file(m: SynthMotion) -> str:
    lines = [captions.caption_line(t) for t in m.captions]
    lines += [captions.caption_line(t, a, b) for t, a, b in m.sub_captions]
    return "\n".join(lines) + "\n"
