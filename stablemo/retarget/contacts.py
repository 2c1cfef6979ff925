"""Planted feet: contacts from the source's ankles and toes (low and slow, footskate's heuristic),
and for each contact the mean place of the joint over it, faded in and out over a short ramp outside
the contact so that what is held never jumps (stablemo.retarget.solve freezes the scaling there).
"""

from __future__ import annotations

import numpy as np
import torch

from footskate.contacts import contacts_from_heights


def source_contacts(feet_m: np.ndarray, fps: float, height_m: float, speed_m_s: float) -> np.ndarray:
    """feet_m (T, K, 3) metres, y up -> (T, K) bool: within `height_m` of the joint's own lowest
    point in the motion and moving slower than `speed_m_s`."""
    c = contacts_from_heights(torch.from_numpy(np.ascontiguousarray(feet_m, dtype=np.float32))[None], fps,
                              height=height_m, speed=speed_m_s)
    return c[0].numpy()


def hold(points: np.ndarray, contact: np.ndarray, ramp: int) -> tuple[np.ndarray, np.ndarray]:
    """points (T, 3), contact (T,) -> (weight (T,), held point (T, 3)).

    Each run of contact frames holds the mean of its points; the weight is 1 inside a run and falls
    linearly to 0 over `ramp` frames on either side (the nearest run wins between two)."""
    t = len(points)
    edges = np.diff(np.concatenate([[0], contact.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1  # (R,) inclusive
    if len(starts) == 0:
        return np.zeros(t), points.copy()
    frames = np.arange(t)[:, None]  # (T, 1)
    gap = np.maximum(starts[None] - frames, 0) + np.maximum(frames - ends[None], 0)  # (T, R) frames outside each run
    weight = np.clip(1.0 - gap / (ramp + 1.0), 0.0, 1.0)
    nearest = np.argmin(gap, axis=1)  # (T,)
    csum = np.concatenate([np.zeros((1, 3)), np.cumsum(points, axis=0)])
    means = (csum[ends + 1] - csum[starts]) / (ends - starts + 1)[:, None]  # (R, 3)
    return weight[np.arange(t), nearest], means[nearest]
