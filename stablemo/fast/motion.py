"""The finishing step's feature columns with the compiled kernel (motion_kernels.cpp, built on first
use by stablemo.fast.kernels): stablemo.motion.extract_torch.body_columns in one pass per frame,
equal to float rounding (tests/test_fast_motion.py). Batches of at least MIN_FUSED_FRAMES frames
use it (a benchmark's or an evaluation's; a single prompt, the demo's, never builds it); the PyTorch
twin runs for smaller ones, where the kernel cannot be built (no compiler, STABLEMO_FUSED_KERNELS=0)
and off the CPU."""

from __future__ import annotations

import functools

import numpy as np
import torch

from stablemo.fast.kernels import motion_kernels
from stablemo.motion import extract_torch
from stablemo.motion.skeleton import Skeleton, get_skeleton


# frames (batch x frames) from which the kernel is worth its one-off build (~30 s): on one core the
# PyTorch twin takes ~0.4 ms per 200 frames, the kernel ~0.08 ms (32 x 197 frames: 12-20 ms, 2.5 ms)
MIN_FUSED_FRAMES = 2048


@functools.lru_cache(maxsize=None)
def _tables(skel: Skeleton, dtype: torch.dtype) -> tuple[torch.Tensor, ...]:
    """The skeleton as the kernel reads it: parents (J,), rest directions (J, 3), the rotation each
    bone's is relative to (J-1,), contact joints (K,)."""
    parents = torch.tensor([max(p, 0) for p in skel.parents], dtype=torch.long)
    raw = torch.tensor(np.array(skel.raw_offsets), dtype=dtype)
    before = torch.tensor(extract_torch.rotation_before(skel), dtype=torch.long)
    return parents, raw, before, torch.tensor(list(skel.contact_joints), dtype=torch.long)


def body_columns(x: torch.Tensor, r: torch.Tensor, skeleton: Skeleton | str) -> torch.Tensor:
    """extract_torch.body_columns: joint-major joints x (J, 3, B, T), root rotations r (B, T, 4)
    -> (B, T-1, D-3)."""
    skel = get_skeleton(skeleton)
    fused = (x.device.type == "cpu" and x.dtype in (torch.float32, torch.float64) and not x.requires_grad
             and x.shape[2] * x.shape[3] >= MIN_FUSED_FRAMES)
    module = motion_kernels() if fused else None
    if module is None:
        return extract_torch.body_columns(x, r, skel)
    return module.body_columns(x.contiguous(), r.to(x.dtype).contiguous(), *_tables(skel, x.dtype),
                               float(skel.contact_threshold))


__all__ = ["body_columns"]
