"""Callbacks the multi-process tests add to `stablemo fit` runs through their config (tests/ is on the
PYTHONPATH of those processes): what each rank holds at the end, and a hard kill at a chosen step."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import torch
from lightning.pytorch import Callback


class SaveRankWeights(Callback):
    """At the end of training every rank writes its own weights and EMA to <dirpath>/rank<R>.pt, so a
    test can compare what the ranks hold (a checkpoint is written by rank 0 alone)."""

    def __init__(self, dirpath: str) -> None:
        self.dirpath = dirpath

    def on_train_end(self, trainer, pl_module) -> None:
        weights = {k: v.detach().cpu().clone() for k, v in pl_module.model.state_dict().items()}
        ema = pl_module.ema.state_dict()  # a collective under FSDP: every rank calls it
        if any(hasattr(v, "full_tensor") for v in weights.values()):
            weights = {k: v.full_tensor() if hasattr(v, "full_tensor") else v for k, v in weights.items()}
        Path(self.dirpath).mkdir(parents=True, exist_ok=True)
        torch.save({"step": trainer.global_step, "weights": weights, "ema": ema["shadow"]},
                   Path(self.dirpath) / f"rank{trainer.global_rank}.pt")


class KillAt(Callback):
    """SIGKILL this process (no clean-up, no checkpoint) on rank `rank` right before the optimiser
    step of global step `step`, i.e. mid-step: gradients reduced, weights not yet updated."""

    def __init__(self, step: int, rank: int) -> None:
        self.step, self.rank = step, rank

    def on_before_optimizer_step(self, trainer, pl_module, optimizer) -> None:
        if trainer.global_step == self.step and trainer.global_rank == self.rank:
            os.kill(os.getpid(), signal.SIGKILL)
