"""Training guards: stop on a non-finite loss or gradient before it reaches the weights."""

from __future__ import annotations

import os

import torch
from lightning.pytorch import Callback, LightningModule, Trainer
from lightning.pytorch.callbacks import ModelCheckpoint

from stablemo.errors import StableMoError


class NonFiniteLossError(StableMoError):
    """Training diverged (NaN/Inf loss or gradient); raised before the optimiser step."""


class NonFiniteGuard(Callback):
    """Check the loss and the gradients right before every optimiser step.

    Raising here (rather than in `training_step`) means the check runs after DDP's gradient
    all-reduce, so every rank sees the same NaN and stops together; and it runs before the weights
    change, so no checkpoint written afterwards could contain them — in fact none is written, since
    Lightning saves no checkpoint on an exception.
    """

    def __init__(self, check_gradients: bool = True) -> None:
        self.check_gradients = check_gradients

    def on_before_optimizer_step(self, trainer: Trainer, pl_module: LightningModule, optimizer) -> None:
        problems = []
        loss = getattr(pl_module, "last_train_loss", None)
        if loss is not None and not bool(torch.isfinite(loss).all()):
            problems.append(f"loss = {loss.item()}")
        # fp16 loss scaling produces Inf gradients by design and skips those steps itself
        scaled = getattr(trainer.precision_plugin, "scaler", None) is not None
        if self.check_gradients and not scaled:
            # a sharded run checks each process's own shard (to_local); the decision below is shared
            grads = [(name, _local(p.grad)) for name, p in pl_module.named_parameters() if p.grad is not None]
            # one device sync for all tensors; names are looked up only when something is wrong
            if grads and not bool(torch.stack([g.isfinite().all() for _, g in grads]).all()):
                bad = [name for name, g in grads if not bool(g.isfinite().all())]
                problems.append(f"non-finite gradients in {len(bad)} tensors (first: {bad[0]})")
        diverged = trainer.strategy.reduce_boolean_decision(bool(problems), all=False)
        if not diverged:
            return
        ckpt = last_good_checkpoint(trainer)
        detail = "; ".join(problems) or "on another rank"
        raise NonFiniteLossError(
            f"training diverged at step {trainer.global_step} ({detail}). Stopped before the optimiser step: "
            f"the weights were not updated and no checkpoint was written. Last good checkpoint: {ckpt}. "
            "Resume from it with `--ckpt_path last`, e.g. with a lower --model.lr or a finite dataset."
        )


def _local(tensor: torch.Tensor) -> torch.Tensor:
    """This process's part of a sharded DTensor; a plain tensor as it is."""
    return tensor.to_local() if hasattr(tensor, "to_local") else tensor


def last_good_checkpoint(trainer: Trainer) -> str:
    """The newest checkpoint this run wrote, else the one it resumed from, else "none written yet".

    Right after a resume, before the next save, ModelCheckpoint knows no path of its own (or a stale one
    restored from another folder), but the checkpoint the run started from is a good one.
    """
    written = getattr(trainer.checkpoint_callback, "last_model_path", "") or ""
    if written and os.path.isfile(written):
        return written
    resumed = getattr(trainer, "ckpt_path", None)
    if resumed:
        return f"{resumed} (the checkpoint this run resumed from)"
    return "none written yet"


class FinalStepCheckpoint(ModelCheckpoint):
    """ModelCheckpoint that also writes `last.ckpt` when training ends between two saves.

    Plain ModelCheckpoint saves only every `every_n_train_steps`; a run whose `max_steps` is not a
    multiple would end with `last.ckpt` behind the trained weights, and `--ckpt_path last` would
    silently redo the tail. Not called on an exception (the NaN guard relies on that).

    The final step of a `max_steps` run is saved in `on_train_batch_end`, where the periodic saves
    happen. Saved later, in `on_train_end`, the checkpoint's loop state already counts the epoch as
    finished, so a run resumed from it started the next epoch (another data order) instead of the rest
    of this one: not an exact resume. `on_train_end` remains for runs that end otherwise (max_epochs,
    where the epoch is finished anyway).
    """

    def setup(self, trainer: Trainer, pl_module: LightningModule, stage: str) -> None:
        """At the start of a run, its checkpoint folder resolved: remove the `.partial` temp files
        that hard-killed saves of earlier runs left there (stablemo.training.checkpoint_io)."""
        super().setup(trainer, pl_module, stage)
        if self.dirpath is not None and trainer.is_global_zero:
            from stablemo.training.checkpoint_io import remove_stale_partials

            remove_stale_partials(self.dirpath)

    def on_train_batch_end(self, trainer: Trainer, pl_module: LightningModule, outputs, batch, batch_idx: int) -> None:
        super().on_train_batch_end(trainer, pl_module, outputs, batch, batch_idx)
        final = 0 < trainer.max_steps <= trainer.global_step
        if final and self.save_last and not self._should_skip_saving_checkpoint(trainer):
            self._save_last_checkpoint(trainer, self._monitor_candidates(trainer))

    def on_train_end(self, trainer: Trainer, pl_module: LightningModule) -> None:
        if self.save_last and not self._should_skip_saving_checkpoint(trainer):
            self._save_last_checkpoint(trainer, self._monitor_candidates(trainer))
        super().on_train_end(trainer, pl_module)
