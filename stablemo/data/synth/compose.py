"""Composites of 1-3 actions, length-checked, with their captions."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stablemo.data.synth import actions, captions, idle, path_walks
from stablemo.data.synth.captions import DEFAULT_CAPTIONS
from stablemo.data.synth.idle import DEFAULT_REST, REST_MODES
from stablemo.data.synth.timeline import FPS, Built, Timeline
from stablemo.motion.skeleton import MAX_FRAMES as HUMANML3D_MAX_FRAMES

MIN_FRAMES = 40  # feature frames (HumanML3D's minimum clip length)
MAX_FRAMES = HUMANML3D_MAX_FRAMES  # feature frames (HumanML3D's maximum motion length)
PART_WEIGHTS = (0.45, 0.35, 0.20)  # P(1 action), P(2), P(3)


# Every builder a plan may name: the regular actions, and the path walk (path_walks.py), drawn only
# into datasets that ask for path walks (writer.write_dataset's path_walks share).
BUILDERS = {**actions.BUILDERS, "walk_path": path_walks.build_walk_path}


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
        BUILDERS[name](tl, params)
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


def build_rested(plan: list[tuple[str, dict]], lead_in: int, lead_out: int, styles: tuple[dict, dict]) -> Built:
    """Build a motion from (action, params) pairs with `lead_in` and `lead_out` frames of idle rest
    around it (styles: the lead-in's and the lead-out's idle.sample_style)."""
    tl = Timeline()
    idle.build_idle(tl, lead_in, styles[0], "in")
    for name, params in plan:
        BUILDERS[name](tl, params)
    idle.build_idle(tl, lead_out, styles[1], "out")
    return tl.build(tl.t)


def generate_motion(rng: np.random.Generator, rest: str = DEFAULT_REST, max_tries: int = 40,
                    caption_mode: str = DEFAULT_CAPTIONS) -> SynthMotion:
    """One motion of 40..196 feature frames. Parameters are redrawn (then the actions) until the
    plan fits, so long actions are not crowded out of composites. rest: idle.REST_MODES; both
    modes draw the same actions, parameters and captions from `rng`, "varied" then draws the total
    length and the idling. caption_mode: captions.CAPTION_MODES (the motion does not depend on it)."""
    names: list[str] = []

    def draw(attempt: int) -> list[tuple[str, dict]]:
        nonlocal names
        if attempt % 8 == 0:
            names = sample_names(rng)
        return [(n, actions.sample_params(n, rng)) for n in names]

    return generate_plan(draw, rng, rest, max_tries, caption_mode)


def generate_path_walk(rng: np.random.Generator, rest: str = DEFAULT_REST, max_tries: int = 40,
                       caption_mode: str = DEFAULT_CAPTIONS) -> SynthMotion:
    """One path walk (path_walks.py) of 40..196 feature frames, with rest as in generate_motion."""
    return generate_plan(lambda attempt: [("walk_path", path_walks.sample_params(rng))], rng, rest, max_tries,
                         caption_mode)


def generate_plan(draw, rng: np.random.Generator, rest: str = DEFAULT_REST, max_tries: int = 40,
                  caption_mode: str = DEFAULT_CAPTIONS) -> SynthMotion:
    """The first plan from draw(attempt) -> [(action, params)] that fits 40..196 frames, built with
    its rest and captioned (all draws from `rng`, in a fixed order). Captions other than the plain
    ones are drawn from a stream jumped ahead of `rng`'s, after the plain draws, which still consume
    `rng`: so a dataset's motions are the same in every caption mode, and only the texts differ."""
    if rest not in REST_MODES:
        raise ValueError(f"rest={rest!r}: one of {', '.join(REST_MODES)}")
    if caption_mode not in captions.CAPTION_MODES:
        raise ValueError(f"caption_mode={caption_mode!r}: one of {', '.join(captions.CAPTION_MODES)}")
    for attempt in range(max_tries):
        plan = draw(attempt)
        lead_in, lead_out = float(rng.uniform(0.1, 0.4)), float(rng.uniform(0.2, 0.5))
        try:
            built = build(plan, lead_in, lead_out)
        except OverflowError:
            continue
        frames = len(built.joints) - 1
        if frames > MAX_FRAMES:
            continue
        shortest, short_rest = frames, (int(lead_in * FPS), int(lead_out * FPS))  # the plan's shortest clip
        if frames < MIN_FRAMES:
            # drawn in both modes, so that the captions' draws that follow are the same
            lead_out += (MIN_FRAMES - frames) / FPS + rng.uniform(0.0, 0.5)
            if rest == "tight":
                built = build(plan, lead_in, lead_out)
        # other captions: a stream jumped ahead from here (rng's state is not changed); the plain ones
        # are drawn in every mode, so that the draws after them (the rest) are the same
        other = np.random.Generator(rng.bit_generator.jumped()) if caption_mode != "plain" else None
        texts, part_texts = _draw_captions(plan, rng)
        if other is not None:
            texts, part_texts = _draw_captions(plan, other, caption_mode)
        if rest == "varied":
            built = draw_rest(plan, shortest, *short_rest, rng)
        return _caption(built, texts, part_texts)
    raise RuntimeError("could not fit a motion into the length limits")


def draw_rest(plan: list[tuple[str, dict]], shortest: int, lead_in: int, lead_out: int,
              rng: np.random.Generator) -> Built:
    """The plan with idle rest: total length uniform over [max(MIN_FRAMES, shortest), MAX_FRAMES]
    whatever the action's count, the extra frames split at random between lead-in and lead-out.
    shortest: the plan's feature frames with lead_in/lead_out frames of rest (the drawn short ones)."""
    total = int(rng.integers(max(MIN_FRAMES, shortest), MAX_FRAMES + 1))
    extra = total - shortest
    before = int(rng.integers(0, extra + 1))
    styles = (idle.sample_style(rng), idle.sample_style(rng))
    built = build_rested(plan, lead_in + before, lead_out + extra - before, styles)
    if len(built.joints) - 1 != total:  # the actions' own length never depends on where they start
        raise RuntimeError(f"rested motion has {len(built.joints) - 1} frames, planned {total}")
    return built


def _draw_captions(plan: list[tuple[str, dict]], rng: np.random.Generator,
                   mode: str = DEFAULT_CAPTIONS) -> tuple[list[str], list[str]]:
    """Whole-clip captions and, for a composite, one sub-caption per part."""
    texts = captions.captions_for(plan, rng, mode=mode)
    parts = [captions.part_caption(name, params, rng, mode) for name, params in plan] if len(plan) > 1 else []
    return texts, parts


def _caption(built: Built, texts: list[str], part_texts: list[str]) -> SynthMotion:
    n_feat = len(built.joints) - 1
    subs = [(text, part.start / FPS, min(part.end, n_feat) / FPS) for text, part in zip(part_texts, built.parts)]
    return SynthMotion(built.joints, built.contacts, built.parts, texts, subs)


def text_file(m: SynthMotion) -> str:
    lines = [captions.caption_line(t) for t in m.captions]
    lines += [captions.caption_line(t, a, b) for t, a, b in m.sub_captions]
    return "\n".join(lines) + "\n"
