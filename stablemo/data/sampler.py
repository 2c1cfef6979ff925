"""Index order that depends only on (seed, epoch): resumable, identical across runs and workers."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from torch.utils.data import Sampler


class EpochSampler(Sampler):
    """Yields (index, epoch) pairs; MotionDataset seeds each item's randomness from them.

    shuffle: a permutation drawn from (seed, epoch). per_epoch=False pins the epoch at 0 so that
    validation sees the same crops and captions every time. Lightning calls set_epoch (also through
    its distributed wrapper) at the start of every epoch, including after a resume.
    """

    def __init__(self, size: int, seed: int = 0, shuffle: bool = True, per_epoch: bool = True):
        self.size, self.seed, self.shuffle, self.per_epoch = int(size), int(seed), shuffle, per_epoch
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        if self.per_epoch:
            self.epoch = int(epoch)

    def order(self) -> np.ndarray:
        if not self.shuffle:
            return np.arange(self.size)
        # The constant 0 separates this stream from the per-item streams (see dataset.py).
        return np.random.default_rng([self.seed, self.epoch, 0, 0]).permutation(self.size)

    def __iter__(self) -> Iterator[tuple[int, int]]:
        epoch = self.epoch
        return iter([(int(i), epoch) for i in self.order()])

    def __len__(self) -> int:
        return self.size
