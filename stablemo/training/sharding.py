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

Unsharded runs (DDP, one process) group their gradient sums as sharded runs do (group_unit_gradients):
FSDP2 passes every call of a unit through one autograd node on the call's inputs, so a tensor that
feeds a unit at several places (the UNet's skip connections: a down stage's output enters the next
block's convolution and its residual sum, and the up stage's concatenation) has the unit's share
summed first, then added to the rest. Without the same node the sum is associated otherwise: the
UNet's gradients differed in the last bits and Adam lifted that to 8.3e-6 in the weights after 4
steps (the DiT and RetNet, whose block inputs have one consumer, were equal). With it, a sharded and
an unsharded run compute the same floating-point sums.

Checkpoints are full (unsharded) files written by rank 0 through the run's CheckpointIO (atomic),
the same layout as an unsharded run's: a checkpoint written by N sharded processes loads in one
unsharded process (`stablemo export`, a DDP or single-process resume) and the other way round.
The EMA keeps its shadow sharded like the weights and is gathered into the checkpoint.
"""

from __future__ import annotations

import dataclasses
import types
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


class UnitInputs(torch.autograd.Function):
    """Identity on the gradient-requiring inputs of one call of a unit: the node FSDP2 puts there
    (its RegisterPostBackwardFunction, whose backward starts the unit's reduce-scatter), without
    the communication. Each input's gradients from inside the call are summed in this node's
    buffer, then added to the input's other gradients as one term."""

    @staticmethod
    def forward(*inputs: torch.Tensor):
        return inputs

    @staticmethod
    def setup_context(ctx, inputs, output) -> None:
        pass

    @staticmethod
    def backward(ctx, *grads: torch.Tensor):
        return grads


def _grad_tensors(value, found: list[torch.Tensor]) -> None:
    """The tensors that require gradients in nested arguments, in FSDP2's order (torch 2.13's
    collect_grad_tensors: named tuples, dataclasses, dicts, lists and tuples)."""
    if isinstance(value, torch.Tensor):
        if value.requires_grad:
            found.append(value)
    elif isinstance(value, tuple) and hasattr(value, "_fields"):
        for item in value:
            _grad_tensors(item, found)
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        for field in dataclasses.fields(value):
            _grad_tensors(getattr(value, field.name), found)
    elif isinstance(value, dict):
        for item in value.values():
            _grad_tensors(item, found)
    elif isinstance(value, (list, tuple)):
        for item in value:
            _grad_tensors(item, found)


def _put_back(value, new):
    """`value` with each gradient-requiring tensor replaced by next(new), in _grad_tensors' order."""
    if isinstance(value, torch.Tensor):
        return next(new) if value.requires_grad else value
    if isinstance(value, tuple) and hasattr(value, "_fields"):
        return type(value)(*(_put_back(item, new) for item in value))
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return dataclasses.replace(value, **{f.name: _put_back(getattr(value, f.name), new)
                                             for f in dataclasses.fields(value) if f.init})
    if isinstance(value, dict):
        return type(value)((k, _put_back(item, new)) for k, item in value.items())
    if isinstance(value, (list, tuple)):
        return type(value)(_put_back(item, new) for item in value)
    return value


def _through_unit_inputs(name: str):
    """A method calling the class's `name` with its gradient-requiring arguments passed through
    UnitInputs first (bound to each module: a deep copy of the module calls its own class's method)."""

    def call(self, *args, **kwargs):
        if torch.is_grad_enabled():
            tensors: list[torch.Tensor] = []
            _grad_tensors((args, kwargs), tensors)
            if tensors:
                args, kwargs = _put_back((args, kwargs), iter(UnitInputs.apply(*tensors)))
        return getattr(type(self), name)(self, *args, **kwargs)

    return call


def group_unit_gradients(model: nn.Module) -> bool:
    """Give an unsharded MotionDiffusionModel FSDP2's node on the inputs of every unit call (its
    forward and the methods SHARD_UNITS names; the root: forward and ROOT_METHODS), so that its
    gradients are the sharded network's to the bit (see the module docstring). False for a network
    without a sharding policy (it cannot be sharded, so there is nothing to match). Idempotent."""
    from stablemo.nets.model import MotionDiffusionModel

    if not isinstance(model, MotionDiffusionModel):
        return False
    try:
        units = shard_units(model)
    except StableMoError:
        return False
    for module, names in [*((m, ("forward", *u.methods)) for m, u in units), (model, ("forward", *ROOT_METHODS))]:
        for name in names:
            if name in vars(module):  # already grouped (or patched by someone else): leave it
                continue
            setattr(module, name, types.MethodType(_through_unit_inputs(name), module))
    return True


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
    """DiffusionModule.configure_model: shard under FullShardStrategy; under any other strategy,
    group the network's gradient sums as a sharded run's (group_unit_gradients), so that the same
    steps sharded and unsharded give the same weights."""
    trainer = module._trainer
    strategy = getattr(trainer, "strategy", None) if trainer is not None else None
    if isinstance(strategy, FullShardStrategy):
        strategy.shard(module)
    elif strategy is not None:
        group_unit_gradients(module.model)
