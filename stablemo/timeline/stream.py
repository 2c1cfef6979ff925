"""Streaming: successive chunks of one continuing motion, each conditioned on the frames already
produced (their last `context` frames in-painted as the window's prefix), the text free to change
between chunks.

    for chunk in pipe.stream("a person walks forward", chunk_seconds=2, max_chunks=30):
        send(chunk.joints)                      # (40, 22, 3), in the stream's one global frame

`texts_or_callback` is a prompt (the same text for every chunk), a list of prompts (one per chunk,
the stream ends after the last), or a callable `(index, previous chunk or None) -> prompt or None`
(None ends the stream), which is how an interactive page changes the text while it plays.
Each chunk's joints are placed in the stream's global frame by `RootFrame` (the window's own
recovery, rotated and moved to where its first frame stands), so a chunk costs the same at minute
ten as at the start.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from stablemo.checks import check_seed
from stablemo.errors import StableMoError
from stablemo.motion.features import feature_slices
from stablemo.timeline.compose import DEFAULT_OVERLAP_S, DEFAULT_SETTLE_S
from stablemo.timeline.windows import RootFrame, Sampling, generate_window, settle

DEFAULT_CONTEXT_S = DEFAULT_OVERLAP_S  # the timeline's measured choices (docs/long_motion.md)
# The shortest chunk (0.25 s at 20 fps). Every chunk computes a whole window of at least the
# model's min_length frames (40 for the demo models), so shorter chunks cost more than 8 windows per
# frame streamed, and a hostile chunk_seconds (1e-9) must not turn a bounded length into billions
# of chunks: with this floor a 300 s stream is at most 1200 chunks.
MIN_CHUNK_FRAMES = 5


@dataclass
class Chunk:
    """index: 0, 1, ...; start: global frame of its first row; features (n, D) de-normalised;
    joints (n, J, 3) in the stream's global frame, both finished (the rigid body on the floor,
    stablemo.inference.finish); window: frames generated for it (context + new)."""

    index: int
    text: str
    start: int
    features: np.ndarray
    joints: np.ndarray
    window: int
    raw_features: np.ndarray | None = None  # (n, D) the network's rows before the finishing step


TextSource = str | Sequence[str] | Callable[[int, "Chunk | None"], "str | None"]


def _text_source(texts_or_callback: TextSource) -> Callable[[int, Chunk | None], str | None]:
    if isinstance(texts_or_callback, str):
        text = texts_or_callback
        return lambda i, prev: text
    if callable(texts_or_callback):
        return texts_or_callback
    try:
        texts = list(texts_or_callback)
    except TypeError:
        raise StableMoError(f"texts_or_callback: expected a prompt, a list of prompts or a callable, "
                            f"got {type(texts_or_callback).__name__}") from None
    if not texts:
        raise StableMoError("texts_or_callback: the list of prompts is empty")
    return lambda i, prev: texts[i] if i < len(texts) else None


def _seconds_to_frames(pipe, seconds, name: str, low: int) -> int:
    if isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or not math.isfinite(seconds):
        raise StableMoError(f"{name}: must be a finite number of seconds, got {seconds!r}")
    frames = round(seconds * pipe.fps)
    if frames < low:
        raise StableMoError(f"{name}: {seconds:g} s is {frames} frames at {pipe.fps:g} fps; at least {low} needed")
    return frames


def chunk_length(pipe, chunk_seconds) -> int:
    """A chunk's frames, checked: at least MIN_CHUNK_FRAMES."""
    return _seconds_to_frames(pipe, chunk_seconds, "chunk_seconds", MIN_CHUNK_FRAMES)


def chunk_frames(pipe, chunk_seconds, context_seconds=DEFAULT_CONTEXT_S) -> tuple[int, int]:
    """(chunk frames n, context frames k) of a stream, checked against the model: n >=
    MIN_CHUNK_FRAMES and a window of k + n frames within the model's maximum. The one check of
    these lengths, for Pipeline.stream and the server (which calls it before counting chunks)."""
    n = chunk_length(pipe, chunk_seconds)
    k = _seconds_to_frames(pipe, context_seconds, "context_seconds", 0)
    if k + n > pipe.max_length:
        raise StableMoError(f"chunk_seconds + context_seconds: {n + k} frames exceed this model's maximum "
                            f"window of {pipe.max_length} frames ({pipe.max_length / pipe.fps:g} s)")
    return n, k


def stream(pipe, texts_or_callback: TextSource, chunk_seconds: float = 2.0, seed: int = 0,
           context_seconds: float = DEFAULT_CONTEXT_S, settle_s: float = DEFAULT_SETTLE_S, max_chunks: int | None = None, steps: int | None = None,
           sampler: str | None = None, cfg: float | None = None, dtype=None, hooks: Sequence = (),
           control: Callable | None = None) -> Iterator[Chunk]:
    """Yield chunks of `chunk_seconds` (see the module docstring); chunk i uses seed + i.

    control: optional `(index, window_length, context_frames) -> JointControl or None`, joint targets
    for a chunk's window in the window's own frame (its first frame at the origin facing +z). Every
    argument is checked here, before the first chunk is generated."""
    n, k = chunk_frames(pipe, chunk_seconds, context_seconds)
    h = _seconds_to_frames(pipe, settle_s, "settle_s", 0)
    if max_chunks is not None and (isinstance(max_chunks, bool) or not isinstance(max_chunks, int) or max_chunks < 1):
        raise StableMoError(f"max_chunks: must be a positive integer or None, got {max_chunks!r}")
    check_seed("seed", seed, count=max_chunks or 1)  # chunk i uses seed + i
    next_text = _text_source(texts_or_callback)
    sampling = Sampling(steps, sampler, cfg, dtype, tuple(hooks))
    return _chunks(pipe, next_text, n, k, h, seed, max_chunks, sampling, control)


def _chunks(pipe, next_text, n: int, k: int, h: int, seed: int, max_chunks, sampling: Sampling,
            control) -> Iterator[Chunk]:
    frame = RootFrame(pipe.skeleton)  # the global frame of the window's first row
    context = None  # (<=k, D) the last rows produced
    lead = None  # without context: (features (1, D), global joints (1, J, 3)) of the last row produced
    contacts = feature_slices(pipe.skeleton)["contacts"]
    produced, prev, index = 0, None, 0
    while max_chunks is None or index < max_chunks:
        text = next_text(index, prev)
        if text is None:
            return
        if not isinstance(text, str) or not text.strip():
            raise StableMoError(f"texts_or_callback: chunk {index}: expected a non-empty prompt, got {text!r}")
        p = 0 if context is None else len(context)
        length = max(pipe.min_length, p + n)
        spec = control(index, length, p) if control is not None else None
        feats = generate_window(pipe, text, length, seed + index, context, p, sampling, spec)[:p + n]
        if p:
            feats[p:] = settle(feats[:p], feats[p:], h, pipe.skeleton)
        joints = frame.joints(feats)  # (p + n, J, 3) global
        # finished with its context, so the floor and the velocities continue across the join; without
        # context the last row produced stands in front: features_of reads a row's turn against the
        # row before it, and a first row of its own would carry the stream's whole heading
        targets = _global_targets(pipe, spec, frame, length, p + n)
        rows, placed, q = feats, joints, p
        if not p and lead is not None:
            rows, placed, q = np.concatenate([lead[0], feats]), np.concatenate([lead[1], joints]), 1
            targets = _lead_free(targets)
        body = pipe.finish.joints(torch.from_numpy(placed)[None], [q + n], targets,
                                  torch.from_numpy(rows[None, :, contacts]))
        done = pipe.finish.features_of(body, [q + n])[0, q:].float().numpy()  # (n, D)
        chunk = Chunk(index, text, produced, done, body[0, q:].float().numpy(), length, feats[p:])
        if not (np.isfinite(chunk.features).all() and np.isfinite(chunk.joints).all()):
            raise StableMoError(f"stream: chunk {index} ({text!r}) is not finite")
        # the next window starts k rows before the end of this one
        start = max(0, p + n - k)
        frame.advance(feats, joints, start)
        context = feats[start:] if k else None
        lead = None if k else (feats[-1:], joints[-1:])
        produced += n
        prev = chunk
        index += 1
        yield chunk


def _lead_free(targets):
    """Targets (1, T, ...) with one free frame in front (the lead row the finishing step is given)."""
    if targets is None:
        return None
    from stablemo.control.spec import ControlTargets

    return ControlTargets(torch.cat([torch.zeros_like(targets.targets[:, :1]), targets.targets], 1),
                          torch.cat([torch.zeros_like(targets.mask[:, :1]), targets.mask], 1))


def _global_targets(pipe, spec, frame: RootFrame, length: int, frames: int):
    """A window's joint control (in the window's frame) as targets in the stream's global frame for
    the finishing step, cut to the frames kept; None without control."""
    if spec is None:
        return None
    from stablemo.control.spec import ControlTargets

    pos, keep = spec.resolve(length, pipe.skeleton, "control")
    pos, keep = frame.place(pos[:frames]), keep[:frames]
    return ControlTargets(torch.from_numpy(pos)[None], torch.from_numpy(keep)[None])


__all__ = ["MIN_CHUNK_FRAMES", "Chunk", "chunk_frames", "chunk_length", "stream"]
