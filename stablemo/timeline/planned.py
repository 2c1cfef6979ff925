"""Prompts generated part by part: the plan of each prompt (its parts in order, their lengths, and
the rest after them), made into one motion per prompt by the timeline's windows.

`plan_prompt` gives each part of a prompt (stablemo.text.plan) the length its own text asks for (the
bundle's length predictor). A length asked for that is longer than anything the training data holds
for those texts (their lengths' `rest_quantile` together) keeps the parts at their own lengths and
fills the rest with `rest_text` (a body standing, as the training clips' idle rest): "a person jumps
in place twice" in 9.8 s jumps twice and stands, where the network alone, asked for 9.8 s, jumped
as often as the length allowed. Any other length is shared out over the parts.

`generate_planned` makes the motions of a batch of plans together: window k of every prompt that has
one is one batched request, continuing that prompt's motion so far by in-painting its last frames
(the timeline's window plan and hand-over, stablemo.timeline.windows), so a batch of plans costs one
request per window of its longest plan. Each window's part turns by the angle its text says
(stablemo.control.turn), over the window's new frames.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from stablemo.checks import MAX_SEED
from stablemo.text.plan import PlanWords, plan_words, split_parts
from stablemo.timeline.windows import DEFAULT_OVERLAP_S, DEFAULT_SETTLE_S, hand_over, plan_windows

WINDOW_SEED_STRIDE = 1_000_003  # window k of a prompt with seed s draws from (s * stride + k): no other prompt's seed


@dataclass(frozen=True)
class PromptPlan:
    """One prompt's parts in order (the rest's text last when it has one) and their frames."""

    texts: tuple[str, ...]
    frames: tuple[int, ...]
    rest: bool

    @property
    def total(self) -> int:
        return sum(self.frames)

    @property
    def spans(self) -> list[tuple[int, int]]:
        """[start, end) frames of each part."""
        ends = np.cumsum(self.frames).tolist()
        return list(zip([0] + ends[:-1], ends))

    def to_dict(self) -> list[dict]:
        return [{"text": t, "start": a, "end": b, "rest": self.rest and i == len(self.texts) - 1}
                for i, (t, (a, b)) in enumerate(zip(self.texts, self.spans))]


def share(total: int, weights: Sequence[int]) -> list[int]:
    """`total` frames shared in proportion to `weights` (largest remainders), each part at least 1."""
    w = np.maximum(np.asarray(weights, dtype=np.float64), 1.0)
    exact = total * w / w.sum()
    out = np.maximum(np.floor(exact).astype(int), 1)
    for i in np.argsort(-(exact - np.floor(exact)), kind="stable")[:max(total - int(out.sum()), 0)]:
        out[i] += 1
    while out.sum() > total and (out > 1).any():  # only when the minimum of 1 was lifted
        out[int(np.argmax(out))] -= 1
    return out.tolist()


def plan_prompt(parts: Sequence[str], modes: Sequence[int], highs: Sequence[int], asked: int | None, fps: float,
                words: PlanWords | None = None, rest: bool = True) -> PromptPlan | None:
    """A prompt's plan: parts with their predicted lengths (`modes`, frames; `highs`: their
    `rest_quantile` lengths); asked: the length asked for (None: the parts' own). None when the
    prompt is one part filling its length (the network reads it whole, as without a plan). rest:
    False shares any length over the parts (a timeline's segment, whose length the user set)."""
    words = words or plan_words()
    texts, frames, standing = list(parts), [int(n) for n in modes], False
    if asked is not None:
        spare = asked - sum(frames)
        if rest and asked > sum(highs) and spare >= round(words.min_rest_s * fps):
            texts.append(words.rest_text)
            frames.append(spare)
            standing = True
        else:
            frames = share(asked, frames)
    if len(texts) == 1:
        return None
    return PromptPlan(tuple(texts), tuple(frames), standing)


def plan_prompts(pipe, texts: Sequence[str], asked: Sequence[int | None],
                 resolved: Sequence[int], rest: bool = True) -> list[PromptPlan | None]:
    """The plan of each prompt (None: generate it whole), from its parts and the pipeline's lengths.
    asked: the lengths asked for (None: the text's own); resolved: the lengths the pipeline gave
    them (without a length predictor, a prompt asked for none shares the default length among its
    parts); rest: as in `plan_prompt`."""
    words = plan_words()
    if pipe.length_predictor is None:
        asked = [r if a is None else a for a, r in zip(asked, resolved)]
    split = [split_parts(t, words) for t in texts]
    # a prompt of one part asked for no length is generated whole: its lengths need not be predicted
    needed = [len(parts) > 1 or (rest and n is not None) for parts, n in zip(split, asked)]
    flat = [p for parts, need in zip(split, needed) if need for p in parts]
    modes, highs = pipe.text_length_range(flat, words.rest_quantile) if flat else ([], [])
    plans, k = [], 0
    for parts, n, need in zip(split, asked, needed):
        if not need:
            plans.append(None)
            continue
        plans.append(plan_prompt(parts, modes[k:k + len(parts)], highs[k:k + len(parts)], n, pipe.fps, words, rest))
        k += len(parts)
    return plans


def window_seed(seed: int, k: int) -> int:
    return seed if k == 0 else (seed * WINDOW_SEED_STRIDE + k) % (MAX_SEED + 1)


def generate_planned(pipe, req, plans: Sequence[PromptPlan | None], lengths: Sequence[int], denoiser=None) -> list[np.ndarray]:
    """De-normalised raw features (N_i, D) of every prompt of a resolved request: a planned prompt
    window by window, the others whole (window 0: the same request they would be alone). lengths:
    each prompt's frames (a plan's total for planned ones)."""
    from stablemo.control import Inpaint
    from stablemo.control.turn import said_turns

    overlap, hold = round(DEFAULT_OVERLAP_S * pipe.fps), round(DEFAULT_SETTLE_S * pipe.fps)
    windows = []
    for text, n, plan in zip(req.texts, lengths, plans):
        if plan is None:
            windows.append(plan_windows([(0, n)], [text], 1, n, 0, 0))  # one window of exactly n frames
        else:
            windows.append(plan_windows(plan.spans, plan.texts, pipe.min_length, pipe.max_length, overlap, 0))
    motions = [np.zeros((n, pipe.mean.shape[0]), np.float32) for n in lengths]
    for k in range(max(len(w) for w in windows)):
        items = [i for i, w in enumerate(windows) if k < len(w)]
        inpaint = []
        for i in items:
            w = windows[i][k]
            inpaint.append(Inpaint(motions[i][w.start:w.new_start].copy(), np.ones(w.prefix, bool)) if w.prefix else None)
        made = [windows[i][k] for i in items]
        step = replace(req, texts=[w.text for w in made], lengths=[w.length for w in made],
                       seed=[window_seed(req.seed[i], k) for i in items],
                       inpaint=inpaint if any(p is not None for p in inpaint) else None,
                       control=None, finish=False, plan=False, progress=False,
                       turns=said_turns([w.text for w in made], [w.new_frames for w in made], [w.share for w in made]))
        out = pipe.generate(step, denoiser=denoiser).feature_list()
        for i, feats in zip(items, out):
            hand_over(motions[i], windows[i][k], feats, hold, pipe.skeleton)
    return motions


__all__ = ["PromptPlan", "generate_planned", "plan_prompt", "plan_prompts", "share", "window_seed"]
