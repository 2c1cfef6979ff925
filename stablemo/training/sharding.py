"""Fully sharded data parallel training (FSDP2) of a DiffusionModule: `stablemo fit --trainer.strategy=fsdp`.

Each process holds 1/N of every weight, gradient, Adam moment and EMA entry (N = all processes of
all nodes); a unit's full weights exist only while it runs (all-gathered before its forward and
again before its backward, freed after), and its gradients are reduce-scattered back to the shards.

Built on torch's FSDP2 (`torch.distributed.fsdp.fully_shard`, DTensor parameters) through Lightning's
ModelParallelStrategy, not on Lightning's "fsdp" strategy (FSDP1): in torch 2.13 FSDP1 refuses a
CPU-only machine ("FSDP needs a non-CPU accelerator device"), and forced onto the CPU with gloo it
crashed in its first all-gather, while FSDP2 trains on CPU processes with gloo as on GPUs with
NCCL. So the same code path is tested here and runs on a cluster.

What is a unit is stated per network in SHARD_UNITS below: the blocks (a UNet's residual blocks, a
DiT's or RetNet's transformer blocks, the text transformer's layers) and the cross-attentions, each
with the methods other than `forward` through which the network reads its weights from outside it
(the UNet's `adagn`, the cross-attention's per-request `context`); FSDP2 all-gathers for those calls
too. Whatever no unit holds (embeddings, heads) is sharded with the whole network, the root unit.

Checkpoints are full (unsharded) files written by rank 0 through the run's CheckpointIO (atomic),
the same layout as an unsharded run's: a checkpoint written by N sharded processes loads in one
unsharded process (`stablemo export`, a DDP or single-process resume) and the other way round.
The EMA keeps its shadow sharded like the weights and is gathered into the checkpoint.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import timedelta

import torch
from lightning.pytorch.strategies import ModelParallelStrategy
from torch import nn

from stablemo.errors import StableMoError
from stablemo.nets.dit import DiT, DiTBlock
from stablemo.nets.layers import LinearCrossAttention
from stablemo.nets.retnet import RetNet, RetNetBlock
from stablemo.nets.unet import CondUNet1D, ResBlock1D
from stablemo.text.conditioner import TextConditioner
from stablemo.training.ema import EMA

DTYPES = {"float32": torch.float32, "bfloat16": torch.bfloat16, "float16": torch.float16}


@dataclass(frozen=True)
class ShardUnit:
    """Modules of type `block` (subclasses included, e.g. the fast training layers) are sharded
    as one unit; `methods`: their methods, besides forward, that others call to read its weights."""

    block: type[nn.Module]
    methods: tuple[str, ...] = ()


CROSS_ATTENTION = ShardUnit(LinearCrossAttention, ("context",))  # context: once per request, in `prepare`
# network class -> its units. A network missing here cannot be sharded (one error line says so).
SHARD_UNITS: dict[type[nn.Module], tuple[ShardUnit, ...]] = {
    CondUNet1D: (ShardUnit(ResBlock1D, ("adagn",)), CROSS_ATTENTION),  # adagn: every block's, per step
    DiT: (ShardUnit(DiTBlock), CROSS_ATTENTION),
    RetNet: (ShardUnit(RetNetBlock), CROSS_ATTENTION),
    TextConditioner: (ShardUnit(nn.TransformerEncoderLayer),),
}
# the root unit (MotionDiffusionModel): its text encoder is called apart from its forward
ROOT_METHODS = ("encode_text",)


def units_of(network: nn.Module) -> tuple[ShardUnit, ...]:
    for cls, units in SHARD_UNITS.items():
        if isinstance(network, cls):
            return units
    raise StableMoError(f"--trainer.strategy=fsdp: {type(network).__name__} has no sharding policy "
                        "(stablemo.training.sharding.SHARD_UNITS); train it with ddp")


def shard_units(model: nn.Module) -> list[tuple[nn.Module, ShardUnit]]:
    """The (module, unit) pairs of a MotionDiffusionModel, children before the blocks that hold them
    (fully_shard is applied bottom-up)."""
    units = units_of(model.denoiser) + units_of(model.text)
    found = []
    for module in reversed(list(model.modules())):  # reversed pre-order: every child before its parent
        unit = next((u for u in units if isinstance(module, u.block)), None)
        if unit is not None:
            found.append((module, unit))
    return found


def shard_model(model: nn.Module, mesh, param_dtype: torch.dtype | None = None) -> int:
    """fully_shard every unit of `model` (a MotionDiffusionModel), then the model itself as the root,
    over the 1-D data-parallel `mesh`. Returns the number of units (root included)."""
    from torch.distributed.fsdp import (
        MixedPrecisionPolicy,
        fully_shard,
        register_fsdp_forward_method,
    )

    # param_dtype: the dtype units are gathered and computed in; gradients are reduced in float32
    # and the sharded (master) weights stay float32 whatever it is
    policy = MixedPrecisionPolicy(param_dtype=param_dtype, reduce_dtype=torch.float32 if param_dtype else None)
    units = shard_units(model)
    for module, unit in units:
        fully_shard(module, mesh=mesh, mp_policy=policy)
        for name in unit.methods:
            register_fsdp_forward_method(module, name)
    fully_shard(model, mesh=mesh, mp_policy=policy)
    for name in ROOT_METHODS:
        register_fsdp_forward_method(model, name)
    return len(units) + 1


def is_sharded(model: nn.Module) -> bool:
    from torch.distributed.tensor import DTensor

    return any(isinstance(p, DTensor) for p in model.parameters())


class FullShardStrategy(ModelParallelStrategy):
    """FSDP2 full sharding over every process of every node (no tensor parallelism), full checkpoints.

    Args:
        param_dtype: "bfloat16" (or "float16") gathers and computes the units in that dtype, with
            float32 sharded master weights, Adam state and gradient reduction; None: float32
            throughout (the trainer's `precision` may still autocast).
        save_distributed_checkpoint: False (default) writes one full checkpoint file on rank 0;
            True, one shard per process in a folder (torch.distributed.checkpoint), which only a
            run of this strategy can resume and `stablemo export` cannot read.
        process_group_backend: "gloo" on CPUs, "nccl" on GPUs when None.
    """

    def __init__(self, param_dtype: str | None = None, save_distributed_checkpoint: bool = False,
                 process_group_backend: str | None = None, timeout: timedelta | None = None) -> None:
        if param_dtype is not None and param_dtype not in DTYPES:
            raise StableMoError(f"--trainer.strategy.param_dtype: expected one of {sorted(DTYPES)} or null, "
                                f"got {param_dtype!r}")
        kwargs = {} if timeout is None else {"timeout": timeout}
        super().__init__(data_parallel_size="auto", tensor_parallel_size=1,
                         save_distributed_checkpoint=save_distributed_checkpoint,
                         process_group_backend=process_group_backend, **kwargs)
        self.param_dtype = None if param_dtype is None else DTYPES[param_dtype]

    def setup_environment(self) -> None:
        # every process is a data-parallel shard holder: the mesh is 1-D over the whole world
        self._data_parallel_size = self.num_nodes * self.num_processes
        super().setup_environment()

    def shard(self, module) -> None:
        """Shard a DiffusionModule's network (its configure_model hook calls this once the processes
        are up) and start its EMA again from the sharded weights (the same values, 1/N per process)."""
        if is_sharded(module.model):
            return  # configure_model runs again for a second trainer entry point (validate after fit)
        shard_model(module.model, self.device_mesh["data_parallel"], self.param_dtype)
        ema = module.ema
        if ema.num_updates:
            raise StableMoError("--trainer.strategy=fsdp: the model was already trained in this process; "
                                "start a fresh process (resuming from a checkpoint is fine)")
        module.ema = EMA(module.model, decay=ema.decay, warmup=ema.warmup)


def configure_sharding(module) -> None:
    """DiffusionModule.configure_model: shard under FullShardStrategy, nothing under any other."""
    trainer = module._trainer
    strategy = getattr(trainer, "strategy", None) if trainer is not None else None
    if isinstance(strategy, FullShardStrategy):
        strategy.shard(module)
