"""Streaming a timeline by whole prompts: each prompt's span is generated at once, exactly as
`generate_timeline` makes it (its windows, each in-painted on the motion so far and settled), and
sent out in chunks of `chunk_seconds` as soon as the window holding them is made.

    for chunk in stream_timeline(pipe, read_timeline("docs/data/long_motion/example.txt"), chunk_seconds=2).chunks:
        send(chunk.joints)      # (<= 40, 22, 3) in one global frame; chunk.text: its segment's prompt

A prompt lasting several chunks is therefore one action over its whole span ("turns left, then
walks" over 4 s turns once), where `stream` with one text per chunk would start it again in each.
Chunks never straddle two prompts: a segment is cut into chunks of `chunk_seconds`, the last one
shorter. The raw rows are the composer's to the bit; the finishing step (the rigid body on the
floor) runs once per window, over the window's new rows and the `overlap` rows (at least one) before them, so the
rows of a window are finished together and the floor and velocities continue across windows.
A chunk's features are its window's (`Finish.features_of` of the window's finished joints): each
window's recover to its own joints, but concatenated they drift from the streamed joints (a
heading offset per window: 0.44 m after 2.5 s past one join in a measured case); `whole_features`
gives the features of the whole streamed motion, which recover to its joints exactly.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from stablemo.checks import check_seed
from stablemo.errors import StableMoError
from stablemo.motion.features import feature_slices
from stablemo.motion.skeleton import get_skeleton
from stablemo.timeline.compose import (
    DEFAULT_OVERLAP_S,
    DEFAULT_SETTLE_S,
    Plan,
    compose_windows,
    plan_timeline,
)
from stablemo.timeline.spec import Segment
from stablemo.timeline.stream import Chunk, chunk_length
from stablemo.timeline.windows import RootFrame, Sampling


@dataclass(frozen=True)
class Span:
    """Global frames [start, end) of one chunk, inside segment `segment`."""

    start: int
    end: int
    segment: int


def chunk_spans(frames: Sequence[tuple[int, int]], n: int) -> list[Span]:
    """Each segment's frames [a, b) cut into chunks of n frames from a (the last one shorter)."""
    return [Span(s, min(s + n, b), i) for i, (a, b) in enumerate(frames) for s in range(a, b, n)]


@dataclass
class TimelineStream:
    """A checked timeline stream: its plan, its chunks' spans, and the lazy iterator of Chunks."""

    plan: Plan
    spans: list[Span]
    chunks: Iterator[Chunk]

    @property
    def frames(self) -> int:
        return self.plan.frames[-1][1]


def stream_timeline(pipe, segments: Sequence[Segment | tuple], chunk_seconds: float = 2.0, seed: int = 0,
                    overlap: float = DEFAULT_OVERLAP_S, settle_s: float = DEFAULT_SETTLE_S, steps: int | None = None,
                    sampler: str | None = None, cfg: float | None = None, dtype=None, hooks: Sequence = (),
                    source: str = "segments", plan: bool = True) -> TimelineStream:
    """The timeline's chunks (see the module docstring), computed when pulled; window i uses seed + i
    as in generate_timeline, each segment planned as there (`plan`). Every argument is checked here,
    before the first window."""
    check_seed("seed", seed)
    made = plan_timeline(pipe, segments, seed, overlap, 0.0, settle_s, source, plan)
    spans = chunk_spans(made.frames, chunk_length(pipe, chunk_seconds))
    # rows before a window's new ones that its finishing step sees: the overlap, and at least one,
    # since features_of reads a row's turn against the row before it
    keep = max(1, round(overlap * pipe.fps))
    sampling = Sampling(steps, sampler, cfg, dtype, tuple(hooks))
    return TimelineStream(made, spans, _chunks(pipe, made, spans, seed, sampling, keep))


def _chunks(pipe, plan: Plan, spans: list[Span], seed: int, sampling: Sampling, keep: int) -> Iterator[Chunk]:
    total = plan.frames[-1][1]
    contacts = feature_slices(pipe.skeleton)["contacts"]
    frame = RootFrame(pipe.skeleton)  # stands at global frame `origin`
    origin, sent = 0, 0
    features = np.zeros((total, pipe.mean.shape[0]), np.float32)  # (N, D) finished
    joints = np.zeros((total, get_skeleton(pipe.skeleton).num_joints, 3), np.float32)  # (N, J, 3) finished, global
    for w, motion in compose_windows(pipe, plan, seed, sampling):
        rows = motion[origin:w.new_end]                  # (m, D): `keep` rows before the window's new ones
        placed = frame.joints(rows)                      # (m, J, 3) float64, global
        body = pipe.finish.joints(torch.from_numpy(placed)[None], [len(rows)], None,
                                  torch.from_numpy(rows[None, :, contacts]))
        new = slice(w.new_start - origin, len(rows))
        features[w.new_start:w.new_end] = pipe.finish.features_of(body, [len(rows)])[0, new].float().numpy()
        joints[w.new_start:w.new_end] = body[0, new].float().numpy()
        if not (np.isfinite(features[w.new_start:w.new_end]).all() and np.isfinite(joints[w.new_start:w.new_end]).all()):
            raise StableMoError(f"stream: the window of {w.text!r} (frames {w.new_start}-{w.new_end}) is not finite")
        nxt = max(0, w.new_end - keep)
        frame.advance(rows, placed, nxt - origin)
        origin = nxt
        while sent < len(spans) and spans[sent].end <= w.new_end:
            s = spans[sent]
            yield Chunk(sent, plan.segments[s.segment].text, s.start, features[s.start:s.end].copy(),
                        joints[s.start:s.end].copy(), w.length, motion[s.start:s.end].copy())
            sent += 1


def whole_features(pipe, joints: np.ndarray) -> np.ndarray:
    """Features (N, D) of a whole streamed motion's joints (N, J, 3), in its one global frame:
    recovering them gives the joints back (what a features file of the stream holds)."""
    return pipe.finish.features_of(torch.from_numpy(np.asarray(joints, np.float64))[None], [len(joints)])[0].float().numpy()


__all__ = ["Span", "TimelineStream", "chunk_spans", "stream_timeline", "whole_features"]
