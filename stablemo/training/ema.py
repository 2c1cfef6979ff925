"""Exponential moving average of a model's weights (paper §4.2.1), with a warm-up.

v_n = β_n · v_{n-1} + (1 − β_n) · θ_n, where β_n = min(decay, (1 + n) / (warmup + n)) after the
n-th optimiser step (n = 0, 1, …). Early on β_n is small, so the average forgets the random
initialisation quickly instead of dragging it along for ~1/(1 − decay) steps; `warmup <= 1` turns
the warm-up off (β_n = decay throughout).

The shadow holds exactly the tensors of `model.state_dict()` (trainable weights only for
MotionDiffusionModel, so a frozen text encoder is never duplicated). It is a plain object rather
than module buffers on purpose: DDP would otherwise broadcast the whole shadow on every forward.

Under sharded training (stablemo.training.sharding) the weights are DTensors holding 1/N of each
tensor per process, and so is the shadow built from them: each process averages its own shard.
`state_dict` gathers the full tensors (a collective: every process calls it, as Lightning does when
it saves) and `load_state_dict` keeps each process's shard of full tensors, so checkpoints hold the
same full EMA whether the run was sharded or not.
"""

from __future__ import annotations

import contextlib
from typing import Iterator

import torch
from torch import nn

from stablemo.errors import StableMoError


class EMA:
    def __init__(self, model: nn.Module, decay: float = 0.9999, warmup: float = 10.0) -> None:
        if not 0.0 <= decay < 1.0:
            raise StableMoError(f"ema_decay: must be in [0, 1), got {decay}")
        if warmup < 0:
            raise StableMoError(f"ema_warmup: must be >= 0, got {warmup}")
        self.decay = float(decay)
        self.warmup = float(warmup)
        self.num_updates = 0
        # float32 master copy, whatever precision the training weights use
        self.shadow: dict[str, torch.Tensor] = {
            name: value.detach().clone().float() if value.is_floating_point() else value.detach().clone()
            for name, value in model.state_dict().items()
        }

    def current_decay(self) -> float:
        """β for the next update."""
        n = self.num_updates
        if self.warmup <= 1.0:
            return self.decay
        return min(self.decay, (1.0 + n) / (self.warmup + n))

    @torch.no_grad()
    def update(self, model: nn.Module) -> None:
        beta = self.current_decay()
        for name, value in model.state_dict().items():
            avg = self.shadow[name]
            if avg.device != value.device:
                avg = self.shadow[name] = avg.to(value.device)
            if avg.is_floating_point():
                avg.lerp_(value.detach().float(), 1.0 - beta)
            else:  # integer buffers (counters) are copied, not averaged
                avg.copy_(value)
        self.num_updates += 1

    @torch.no_grad()
    def copy_to(self, model: nn.Module) -> None:
        live = model.state_dict()
        model.load_state_dict({k: v.to(device=live[k].device, dtype=live[k].dtype) for k, v in self.shadow.items()})

    @contextlib.contextmanager
    def swapped_into(self, model: nn.Module) -> Iterator[nn.Module]:
        """Temporarily load the averaged weights into `model`; the live weights come back afterwards,
        even if the body raises."""
        live = {k: v.detach().clone() for k, v in model.state_dict().items()}
        self.copy_to(model)
        try:
            yield model
        finally:
            model.load_state_dict(live)

    def state_dict(self) -> dict:
        return {
            "decay": self.decay,
            "warmup": self.warmup,
            "num_updates": self.num_updates,
            "shadow": {k: _full(v).detach().cpu() for k, v in self.shadow.items()},
        }

    def load_state_dict(self, state: dict) -> None:
        missing = set(self.shadow) - set(state["shadow"])
        unexpected = set(state["shadow"]) - set(self.shadow)
        if missing or unexpected:
            raise StableMoError(
                f"EMA state does not match the model (missing {sorted(missing)[:5]}, unexpected {sorted(unexpected)[:5]})"
            )
        self.num_updates = int(state["num_updates"])
        for k, v in state["shadow"].items():
            like = self.shadow[k]
            v = v.to(device=like.device, dtype=like.dtype)
            self.shadow[k] = _shard_like(v, like) if hasattr(like, "placements") else v.clone()


def _full(value: torch.Tensor) -> torch.Tensor:
    """The whole tensor of a sharded DTensor (gathered from every process); a plain tensor as it is."""
    return value.full_tensor() if hasattr(value, "full_tensor") else value


def _shard_like(full: torch.Tensor, like) -> torch.Tensor:
    """This process's shard of `full`, laid out as the DTensor `like` (every process holds `full`:
    no communication)."""
    from torch.distributed.tensor import distribute_tensor

    return distribute_tensor(full, like.device_mesh, like.placements, src_data_rank=None)
