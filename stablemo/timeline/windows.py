"""Generating one window of a longer motion, conditioned on the frames already made, and carrying the
global root frame across windows.

A window starts with `prefix` frames copied from the end of the motion so far (their features are
frame-local: velocities in the facing frame, root-relative joints, height), in-painted inside the
sampler, and continues with new frames for its text. Because nothing in a feature row is global,
the copied rows continue the motion exactly once the root is integrated over the concatenation;
`RootFrame` does that integration window by window for streaming (no full-history recovery).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from stablemo.motion.features import features_to_joints
from stablemo.motion.quaternion import qinv, qrot

DEFAULT_OVERLAP_S = 0.5  # the three chosen on held-apart prompts by scripts/long_motion/report.py (docs/long_motion.md)
DEFAULT_BLEND_S = 0.0
DEFAULT_SETTLE_S = 1.0


@dataclass(frozen=True)
class Window:
    """One generated window: its text, the global frame of its first row, its generated length, how
    many rows were copied from the motion (prefix), of which the last `blend` were cross-faded, and
    the global frames [new_start, new_end) it added; share: the part of its text's span those are
    (1 unless a span longer than a window is split over several)."""

    text: str
    start: int
    length: int
    prefix: int
    blend: int
    new_start: int
    new_end: int
    share: float = 1.0

    @property
    def new_frames(self) -> tuple[int, int]:
        """[start, end) of the new frames within the window's own rows."""
        return self.prefix, self.prefix + self.new_end - self.new_start


def plan_windows(frames: Sequence[tuple[int, int]], texts: Sequence[str], min_length: int, max_length: int,
                 overlap: int, blend: int) -> list[Window]:
    """Windows covering the segments' frames [a, b) in order. Each after the first starts with the
    last `overlap` frames made (its prefix, the last `blend` of them cross-faded); a segment longer
    than a window is split evenly over the windows it needs; a window shorter than `min_length` is
    generated at `min_length` and cut (stablemo.timeline.compose)."""
    windows: list[Window] = []
    produced = 0
    for (a, b), text in zip(frames, texts):
        while produced < b:
            prefix = min(overlap, produced)
            cap = max_length - prefix
            remaining = b - produced
            # split what is left of the segment evenly over the windows it needs (no 3-frame tail window)
            pieces = math.ceil(remaining / cap)
            new = math.ceil(remaining / pieces)
            length = max(min_length, prefix + new)
            windows.append(Window(text, produced - prefix, length, prefix, min(blend, prefix), produced, produced + new,
                                  new / (b - a)))
            produced += new
    return windows


@dataclass(frozen=True)
class Sampling:
    """Sampler settings shared by every window (None = the bundle's inference config)."""

    steps: int | None = None
    sampler: str | None = None
    cfg: float | None = None
    dtype: object = None
    hooks: Sequence = ()


def generate_window(pipe, text: str, length: int, seed: int, context: np.ndarray | None, hard: int,
                    sampling: Sampling, control=None, turn=None) -> np.ndarray:
    """Features (length, D) of one window whose first `hard` frames are `context[:hard]` exactly
    (context: (k, D) de-normalised, k >= hard; frames hard..k are left free for blending); turn: a
    stablemo.control.Turn over the window's rows, or None."""
    from stablemo.control import Inpaint

    inpaint = None
    if context is not None and hard > 0:
        feats = np.zeros((hard, context.shape[1]), np.float32)
        feats[:] = context[:hard]
        inpaint = [Inpaint(feats, np.ones(hard, bool))]
    result = pipe.generate([text], length, seed=seed, steps=sampling.steps, sampler=sampling.sampler,
                           cfg=sampling.cfg, dtype=sampling.dtype, hooks=list(sampling.hooks), inpaint=inpaint,
                           control=None if control is None else [control], finish=False,
                           turns=None if turn is None else [turn])
    return result.feature_list()[0]


def hand_over(motion: np.ndarray, w: Window, feats: np.ndarray, settle_frames: int, skeleton: str) -> None:
    """Write window w's generated features (w.length, D) into the motion so far (N, D), in place: its
    last `blend` prefix rows cross-faded from the old rows, its new rows [new_start, new_end) with the
    jump at their start settled over `settle_frames` (`settle`; a first window is copied as made)."""
    if w.blend:
        old = motion[w.new_start - w.blend:w.new_start]
        motion[w.new_start - w.blend:w.new_start] = crossfade(old, feats[w.prefix - w.blend:w.prefix])
    new = feats[w.prefix:w.prefix + w.new_end - w.new_start]
    motion[w.new_start:w.new_end] = settle(motion[:w.new_start], new, settle_frames, skeleton) if w.prefix else new


def crossfade(old: np.ndarray, new: np.ndarray) -> np.ndarray:
    """(r, D) rows going from `old` to `new`: weight of new = (i + 1) / (r + 1), so the rows before
    (all old) and after (all new) continue with equal steps."""
    r = len(old)
    w = (np.arange(1, r + 1, dtype=np.float32) / (r + 1))[:, None]
    return ((1.0 - w) * old + w * new).astype(np.float32)


def settle(before: np.ndarray, new: np.ndarray, frames: int, skeleton: str) -> np.ndarray:
    """new rows (m, D) with the jump at their start faded out over `frames` rows (inertialization):
    the offset between where the last two rows before (`before`, (>= 2, D)) head, linearly
    extrapolated, and the first new row is added to the new rows with a weight falling from 1 to 0
    along a half cosine (flat at both ends, so no velocity kink is added). Replacement in-painting
    leaves such a jump where the kept prefix ends (measured in docs/long_motion.md); foot contacts
    are labels, not positions, and are left as they are, and so is the root's yaw velocity: an
    offset faded out there is a turn taken away from the new text (the demo student's "turns
    right" after a walk turned the body 141 degrees where it turns 176 alone; 169 without it,
    scripts/long_motion/stream_prompts.py), while a body may start turning at once."""
    if frames <= 0 or len(before) < 2 or len(new) == 0:
        return new
    from stablemo.motion.features import feature_slices

    offset = (2.0 * before[-1] - before[-2]) - new[0]  # (D,)
    columns = feature_slices(skeleton)
    offset[columns["contacts"]] = 0.0
    offset[columns["root_rot_vel"]] = 0.0
    h = min(frames, len(new))
    weight = 0.5 * (1.0 + np.cos(np.pi * np.arange(h) / frames))  # (h,) 1 at the join, -> 0
    out = new.copy()
    out[:h] += (weight[:, None] * offset[None, :]).astype(np.float32)
    return out


def yaw_angles(features: np.ndarray) -> np.ndarray:
    """(T,) root yaw angle of each frame relative to frame 0, as recover_root integrates it (float64)."""
    rot_vel = features[:, 0].astype(np.float64)
    return np.concatenate([[0.0], np.cumsum(rot_vel[:-1])])


class RootFrame:
    """The global yaw and planar position of one frame of a growing motion: joints recovered from a
    window that starts at that frame are rotated and moved into the motion's frame (float64, so 10
    minutes of windows do not accumulate float32 error)."""

    def __init__(self, skeleton: str):
        self.skeleton = skeleton
        self.angle = 0.0  # yaw of the window's first frame, in recover_root's convention
        self.xz = np.zeros(2)

    def _quat(self) -> torch.Tensor:
        return torch.tensor([np.cos(self.angle), 0.0, np.sin(self.angle), 0.0], dtype=torch.float64)

    def joints(self, features: np.ndarray) -> np.ndarray:
        """Joints (T, J, 3) in the global frame of features (T, D) starting at this frame."""
        return self.place(features_to_joints(torch.from_numpy(features.astype(np.float64)), self.skeleton).numpy())

    def place(self, points: np.ndarray) -> np.ndarray:
        """Points (..., 3) in the frame of a window starting at this frame -> the global frame (float64)."""
        rel = torch.from_numpy(np.asarray(points, dtype=np.float64))
        out = qrot(qinv(self._quat()).expand(*rel.shape[:-1], 4), rel)
        out[..., 0] += self.xz[0]
        out[..., 2] += self.xz[1]
        return out.numpy()

    def advance(self, features: np.ndarray, joints: np.ndarray, frame: int) -> None:
        """Move to `frame` of the window (features and its global joints from `joints`); frame may be
        len(features), the frame just after the window (a stream without context)."""
        if frame == len(features):  # the next root position follows from the last row's velocities alone
            features = np.concatenate([features, features[-1:]])
            joints = self.joints(features)
        self.angle += float(yaw_angles(features)[frame])
        self.xz = joints[frame, 0, [0, 2]].astype(np.float64)


__all__ = ["DEFAULT_BLEND_S", "DEFAULT_OVERLAP_S", "DEFAULT_SETTLE_S", "RootFrame", "Sampling", "Window", "crossfade",
           "generate_window", "hand_over", "plan_windows", "settle", "yaw_angles"]
