"""A DataLoader whose position inside an epoch travels in Lightning checkpoints.

Lightning saves and restores any train loader that has `state_dict`/`load_state_dict`. The order
of an epoch depends only on (seed, epoch) (EpochSampler), so resuming mid-epoch means replaying
that epoch's batch stream and dropping the batches already trained on. Without this, a resumed
run would start its epoch from the first batch again and see some clips twice.

The count is exact because Lightning does not prefetch from loaders with a length.
"""

from __future__ import annotations

from typing import Any, Iterator

from torch.utils.data import DataLoader


class ResumableLoader(DataLoader):
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._served = 0  # batches handed out by the current iteration
        self._epoch: int | None = None  # sampler epoch of the current iteration
        self._resume: dict | None = None

    def _sampler_epoch(self) -> int | None:
        epoch = getattr(self.sampler, "epoch", None)
        if epoch is None and self.batch_sampler is not None:
            epoch = getattr(getattr(self.batch_sampler, "sampler", None), "epoch", None)
        return None if epoch is None else int(epoch)

    def state_dict(self) -> dict:
        return {"epoch": self._epoch, "batches": self._served}

    def load_state_dict(self, state: dict) -> None:
        self._resume = dict(state)

    def __iter__(self) -> Iterator:
        resume, self._resume = self._resume, None
        return self._iterate(resume)

    def _iterate(self, resume: dict | None) -> Iterator:
        # A generator: this body runs at the first next(), i.e. after Lightning's set_epoch.
        self._epoch = self._sampler_epoch()
        skip = 0
        if resume is not None and resume.get("epoch") == self._epoch:
            skip = int(resume.get("batches", 0))
        self._served = 0
        sampler = self.batch_sampler.sampler if self.batch_sampler is not None else self.sampler
        if skip and hasattr(sampler, "start_at") and self.batch_size:
            # a sampler that can start mid-epoch (ShardSampler): nothing before the position is read
            sampler.start_at(skip * self.batch_size)
            self._served, skip = skip, 0
        for batch in super().__iter__():
            self._served += 1
            if self._served > skip:
                yield batch
