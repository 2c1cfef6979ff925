"""Run the behaviour suite: generate every prompt at every length with every seed, score the joints.

A generator is a function (prompts, frames, seeds) -> list of (T, 22, 3) joint arrays, one per
item, where a frame count of None means "no length given". `pipeline_generator` asks a stablemo.Pipeline (all
motions of one length in one batched request),
`truth_generator` the synthetic generator itself (the checks' own validation). Lengths are tokens:
`default` (no length given: a pipeline's length predictor chooses, or its default length),
`natural` (the prompt's length as the synthetic generator makes it) or seconds (`9.8`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import numpy as np

from stablemo.errors import StableMoError
from stablemo.eval.behaviour.checks import score
from stablemo.eval.behaviour.retrieval import top3_hits
from stablemo.eval.behaviour.summary import summarize
from stablemo.eval.behaviour.table import Prompt
from stablemo.eval.behaviour.truth import natural_frames, truth_joints

DEFAULT_LENGTHS = ("default", "natural", "9.8")  # 9.8 s: HumanML3D's longest, more than any action needs
DEFAULT_SEEDS = 4
Generator = Callable[[list[Prompt], list, list[int]], list[np.ndarray]]


def parse_lengths(tokens: Sequence[str], what: str = "--lengths") -> list[str]:
    """Length tokens checked: `default`, `natural` or positive seconds; one line naming `what` otherwise."""
    out = []
    for token in tokens:
        token = str(token).strip()
        if token not in ("default", "natural"):
            try:
                seconds = float(token)
            except ValueError:
                raise StableMoError(f"{what}: {token!r} is not 'default', 'natural' or a length in seconds") from None
            if not np.isfinite(seconds) or seconds <= 0:
                raise StableMoError(f"{what}: {token!r} must be a positive number of seconds")
            token = f"{seconds:g}"
        if token in out:
            raise StableMoError(f"{what}: {token!r} is given twice")
        out.append(token)
    if not out:
        raise StableMoError(f"{what}: give at least one length")
    return out


def frames_for(token: str, prompt: Prompt, fps: float, low: int, high: int) -> int | None:
    """The frame count a length token asks for this prompt (None: no length given); natural lengths
    are clamped to the model's range [low, high], explicit seconds must lie in it."""
    if token == "default":
        return None
    if token == "natural":
        return int(min(max(natural_frames(prompt), low), high))
    frames = round(float(token) * fps)
    if not low <= frames <= high:
        raise StableMoError(f"--lengths: {token} s is {frames} frames, outside the model's range "
                            f"[{low}, {high}] ({low / fps:g}-{high / fps:g} s)")
    return frames


def pipeline_generator(pipe, batch_size: int = 64, **request_fields) -> Generator:
    """Generation through a stablemo.Pipeline; a length of None is passed on as none: the length the
    pipeline gives the text (its bundle's length predictor, else its default length)."""
    from stablemo.inference.pipeline import Request

    def generate(prompts, frames, seeds):
        out = pipe.generate(Request([p.text for p in prompts], list(frames), seed=list(seeds), batch_size=batch_size, **request_fields))
        return out.joint_list()

    return generate


def truth_generator(default_frames: int) -> Generator:
    """The synthetic generator's own motion of each prompt; no length given: `default_frames`
    (or the actions' own length where they need more)."""

    def generate(prompts, frames, seeds):
        return [truth_joints(p, s, default_frames if n is None else n) for p, n, s in zip(prompts, frames, seeds)]

    return generate


def run_suite(generate: Generator, prompts: list[Prompt], lengths: Sequence[str], seeds: Sequence[int],
              fps: float, low: int, high: int, progress: Callable[[str], None] | None = None,
              evaluator=None) -> dict:
    """Every prompt x length x seed: generated (one call per length), scored. Returns {prompts: text,
    split, actions, tests of each; rows: one per motion (its prompt's index), in prompt, length, seed
    order; summary; seconds}. With a text-motion `evaluator`, each row also says whether the motion
    is a top-3 retrieval hit (`r3`, stablemo.eval.behaviour.retrieval; None where a seed's prompts
    are fewer than a batch)."""
    frames = {(token, i): frames_for(token, p, fps, low, high) for token in lengths for i, p in enumerate(prompts)}
    started, generating, by_key = time.perf_counter(), 0.0, {}
    for token in lengths:
        items = [(i, s) for i in range(len(prompts)) for s in seeds]
        t0 = time.perf_counter()
        joints = generate([prompts[i] for i, _ in items], [frames[token, i] for i, _ in items],
                          [int(s) for _, s in items])
        generating += time.perf_counter() - t0
        hits = [None] * len(items)
        if evaluator is not None:  # batches of distinct prompts: one group per seed
            groups = [[k for k, (_, s) in enumerate(items) if s == seed] for seed in seeds]
            hits = top3_hits(evaluator, [prompts[i].text for i, _ in items], joints, groups)
        for (i, seed), j, hit in zip(items, joints, hits):
            verdicts = score(prompts[i], j, fps)
            by_key[i, token, seed] = {
                "prompt": i, "split": prompts[i].split, "length": token,
                "frames": len(j), "seed": int(seed), "passed": all(v.passed for v in verdicts.values()),
                "attributes": {k: {"passed": v.passed, "measured": v.measured} for k, v in verdicts.items()}}
            if evaluator is not None:
                by_key[i, token, seed]["r3"] = hit
        if progress:
            progress(f"length {token}: {len(items)} motions scored ({time.perf_counter() - started:.0f} s)")
    rows = [by_key[i, token, s] for i in range(len(prompts)) for token in lengths for s in seeds]
    table = [{"text": p.text, "split": p.split, "actions": p.actions, "tests": p.tests} for p in prompts]
    return {"prompts": table, "rows": rows, "summary": summarize(rows),
            "seconds": {"total": time.perf_counter() - started, "generating": generating}}


__all__ = ["DEFAULT_LENGTHS", "DEFAULT_SEEDS", "frames_for", "parse_lengths", "pipeline_generator", "run_suite",
           "truth_generator"]
