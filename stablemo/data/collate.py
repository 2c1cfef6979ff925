"""Batches of variable-length motions: zero padding (in normalised space) and a frame mask."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from stablemo.errors import StableMoError


def padded_length(max_length: int, pad_multiple: int, min_length: int = 0) -> int:
    """Smallest multiple of pad_multiple that holds max(max_length, min_length) frames."""
    if pad_multiple < 1:
        raise StableMoError(f"pad_multiple={pad_multiple}: must be >= 1")
    return max(1, math.ceil(max(max_length, min_length) / pad_multiple)) * pad_multiple


def pad_motions(
    motions: list[torch.Tensor] | list[np.ndarray], pad_multiple: int = 1, min_length: int = 0
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """[(T_i, D)] -> motion (B, T, D) zero-padded, mask (B, T) bool, length (B,) int64;
    T is the longest T_i rounded up to a multiple of pad_multiple.

    CPU inputs are padded with numpy: many small torch copies are ~10x slower on a busy CPU
    (intra-op thread hand-offs). Other tensors keep their dtype and device.
    """
    if not len(motions):
        raise StableMoError("pad_motions: empty batch")
    lengths = torch.tensor([len(m) for m in motions], dtype=torch.int64)
    total = padded_length(int(lengths.max()), pad_multiple, min_length)
    dim = motions[0].shape[-1]
    if all(isinstance(m, torch.Tensor) and m.device.type == "cpu" and not m.requires_grad for m in motions):
        motions = [m.numpy() for m in motions]  # zero-copy views
    if all(isinstance(m, np.ndarray) for m in motions):
        padded = np.zeros((len(motions), total, dim), dtype=motions[0].dtype)
        for row, m in enumerate(motions):
            padded[row, : len(m)] = m
        out = torch.from_numpy(padded)
    else:
        out = motions[0].new_zeros((len(motions), total, dim))
        for row, m in enumerate(motions):
            out[row, : len(m)] = m
    mask = torch.arange(total)[None, :] < lengths[:, None]
    return out, mask, lengths


@dataclass
class Collate:
    """collate_fn for MotionDataset items -> {motion, mask, length, text, tokens, id}."""

    pad_multiple: int = 16
    min_length: int = 0  # pad at least this far (e.g. max_length for fixed-size batches)

    def __call__(self, items: list[dict]) -> dict:
        motion, mask, length = pad_motions([it["motion"] for it in items], self.pad_multiple, self.min_length)
        return {
            "motion": motion,
            "mask": mask,
            "length": length,
            "text": [it["text"] for it in items],
            "tokens": [it["tokens"] for it in items],
            "id": [it["id"] for it in items],
        }
