"""A timeline of prompts -> one motion of exactly its length, made of windows of at most the model's
length joined by in-painting.

Each window generates new frames for one segment's text. Every window after the first starts with
the last `overlap` frames of the motion so far: the first `overlap - blend` of them are in-painted
exactly (prefix completion), the last `blend` are generated freely and cross-faded from the old
rows to the new ones (DoubleTake-style blending of the hand-over). Windows are joined in feature
space, where every row is frame-local, and the joints are recovered once for the whole motion, so
the root trajectory and heading continue across windows in one global frame.

A segment longer than a window is split evenly over several windows of its text; a window shorter
than the model's minimum length is generated at the minimum and cut.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from stablemo.checks import check_seed
from stablemo.control.turn import said_turns
from stablemo.errors import StableMoError
from stablemo.motion.features import features_to_joints
from stablemo.timeline.planned import plan_prompts
from stablemo.timeline.spec import Segment, check_segments, segment_frames
from stablemo.timeline.windows import (
    DEFAULT_BLEND_S,
    DEFAULT_OVERLAP_S,
    DEFAULT_SETTLE_S,
    Sampling,
    Window,
    generate_window,
    hand_over,
    plan_windows,
)


@dataclass
class TimelineMotion:
    """features (N, D) de-normalised and joints (N, J, 3) in one global frame, both finished (the
    rigid body on the floor, stablemo.inference.finish); frames: [start, end) of
    each segment; windows: how it was made; joins: global frames where a window's new rows begin."""

    segments: list[Segment]
    frames: list[tuple[int, int]]
    features: np.ndarray
    joints: np.ndarray
    fps: float
    windows: list[Window] = field(default_factory=list)
    raw_features: np.ndarray | None = None  # (N, D) the joined windows before the finishing step

    @property
    def joins(self) -> list[int]:
        return [w.new_start for w in self.windows if w.new_start > 0]

    @property
    def join_spans(self) -> list[tuple[int, int]]:
        """(first, last) global frame of each hand-over: the cross-faded rows, then the first new row."""
        return [(w.new_start - w.blend, w.new_start) for w in self.windows if w.new_start > 0]

    @property
    def boundaries(self) -> list[int]:
        return [a for a, _ in self.frames[1:]]


def _frames(pipe, seconds: float, name: str) -> int:
    if not isinstance(seconds, (int, float)) or isinstance(seconds, bool) or not math.isfinite(seconds) or seconds < 0:
        raise StableMoError(f"{name}: must be a finite number of seconds >= 0, got {seconds!r}")
    return round(seconds * pipe.fps)


@dataclass(frozen=True)
class Plan:
    """A checked timeline and how it is made: its segments, their [start, end) frames, the windows,
    and the frames over which each window's first new row is settled; turns: per window the turn its
    text says over its new frames (stablemo.control.turn), None where it says none; None in all when
    no window says one, or the segments were not planned."""

    segments: list[Segment]
    frames: list[tuple[int, int]]
    windows: list[Window]
    settle: int
    turns: list | None = None


def plan_timeline(pipe, segments: Sequence[Segment | tuple], seed: int = 0, overlap: float = DEFAULT_OVERLAP_S,
                  blend: float = DEFAULT_BLEND_S, settle_s: float = DEFAULT_SETTLE_S,
                  source: str = "segments", plan: bool = True) -> Plan:
    """Every argument of a timeline checked against the model, before anything is generated. plan:
    a segment that says an order is made in its parts, which share the segment's span in proportion
    to their predicted lengths (stablemo.timeline.planned; no standing rest is added: the user set
    the segment's length), its windows made over the parts; the segments stay as given."""
    segments = check_segments(segments, source)
    k, r = _frames(pipe, overlap, "overlap"), _frames(pipe, blend, "blend")
    h = _frames(pipe, settle_s, "settle_s")
    if r > k:
        raise StableMoError(f"blend: {blend:g} s is longer than the overlap ({overlap:g} s)")
    if k > pipe.max_length - 1:
        raise StableMoError(f"overlap: {overlap:g} s ({k} frames) leaves no new frames in a window of at most "
                            f"{pipe.max_length} frames")
    frames = segment_frames(segments, pipe.fps, source)
    spans, texts = list(frames), [s.text for s in segments]  # what the windows are made over
    if plan:
        asked = [b - a for a, b in frames]
        spans, texts = [], []
        # the segment's length is the user's: its parts share it (no standing rest is added)
        for (a, b), seg, part_plan in zip(frames, segments,
                                          plan_prompts(pipe, [s.text for s in segments], asked, asked, rest=False)):
            if part_plan is None:
                spans.append((a, b))
                texts.append(seg.text)
            else:
                spans.extend((a + x, a + y) for x, y in part_plan.spans)
                texts.extend(part_plan.texts)
    windows = plan_windows(spans, texts, pipe.min_length, pipe.max_length, k, r)
    check_seed("seed", seed, count=len(windows))  # window i uses seed + i
    # each window turns by its share of the angle its text says
    turns = None
    if plan:
        turns = said_turns([w.text for w in windows], [w.new_frames for w in windows], [w.share for w in windows])
    return Plan(segments, frames, windows, h, turns)


def compose_windows(pipe, plan: Plan, seed: int, sampling: Sampling, progress: bool = False) -> Iterator[tuple[Window, np.ndarray]]:
    """Generate the plan's windows in order; after each, yield (the window, the motion (N, D)
    de-normalised, raw), whose rows [0, window.new_end) are then final. One array, filled in place."""
    motion = np.zeros((plan.frames[-1][1], pipe.mean.shape[0]), np.float32)  # (N, D)
    for i, w in enumerate(plan.windows):
        context = motion[w.start:w.new_start] if w.prefix else None
        feats = generate_window(pipe, w.text, w.length, seed + i, context, w.prefix - w.blend, sampling,
                                turn=plan.turns[i] if plan.turns else None)
        hand_over(motion, w, feats, plan.settle, pipe.skeleton)
        if progress:
            print(f"  window {i + 1}/{len(plan.windows)}: frames {w.new_start}-{w.new_end} {w.text!r}", flush=True)
        yield w, motion


def generate_timeline(pipe, segments: Sequence[Segment | tuple], seed: int = 0, overlap: float = DEFAULT_OVERLAP_S,
                      blend: float = DEFAULT_BLEND_S, settle_s: float = DEFAULT_SETTLE_S, steps: int | None = None, sampler: str | None = None,
                      cfg: float | None = None, dtype=None, hooks: Sequence = (), source: str = "segments",
                      progress: bool = False, plan: bool = True) -> TimelineMotion:
    """One motion for a timeline. overlap, blend: seconds of each window copied from the motion so
    far, and of those the last seconds cross-faded instead of in-painted (blend <= overlap); settle_s:
    seconds over which the jump where a window's new rows begin is faded out (`settle`); window i
    uses seed + i; the sampler settings default to the bundle's; plan: each segment planned as a
    prompt of its length (`plan_timeline`; False: its text whole over its span)."""
    check_seed("seed", seed)
    made = plan_timeline(pipe, segments, seed, overlap, blend, settle_s, source, plan)
    sampling = Sampling(steps, sampler, cfg, dtype, tuple(hooks))
    for _, motion in compose_windows(pipe, made, seed, sampling, progress):
        pass
    raw = torch.from_numpy(motion)[None]  # (1, N, D): windows are joined raw, finished once as a whole
    if not torch.isfinite(features_to_joints(raw.double(), pipe.skeleton)).all():
        raise StableMoError("timeline: the recovered joints are not finite; nothing was written")
    feats, joints = pipe.finish(raw, [raw.shape[1]])
    return TimelineMotion(made.segments, made.frames, feats[0].numpy(), joints[0].float().numpy(), pipe.fps,
                          made.windows, motion)


__all__ = ["Plan", "TimelineMotion", "compose_windows", "generate_timeline", "plan_timeline"]
