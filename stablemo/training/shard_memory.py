"""Bytes per GPU of a network trained with FullShardStrategy (FSDP2 full sharding), from its
parameters alone: count them on the meta device, no weight is allocated.

Per process, for the whole run (sharded: each process holds its rows of every tensor, FSDP2 splits
dim 0 into N equal chunks, the last ones padded, so rank 0 holds the most):
    master weights float32 4 B, gradients float32 4 B, Adam's two moments float32 8 B, EMA float32 4 B
While a unit runs (gathered, freed after it):
    its weights in param_dtype, for it and the next unit (FSDP2 prefetches one): 2 units x 2 B (bf16),
    its gradients in param_dtype and their float32 copy for the reduce-scatter: (2 + 4) B per parameter,
    the root unit's weights (embeddings, heads), kept gathered from the forward to its backward.
Activations are not counted: they depend on batch size and clip length.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from torch import nn

from stablemo.training.sharding import shard_units

SHARDED_BYTES = {"weights": 4, "gradients": 4, "adam": 8, "ema": 4}  # per parameter, float32
GATHERED_BYTES = 2  # bf16 (param_dtype) per parameter of a gathered unit
GRADIENT_BYTES = 2 + 4  # a unit's bf16 gradient and its float32 copy for the reduce-scatter
GIB = 1024 ** 3


def own_parameters(module: nn.Module, units: set[int]) -> int:
    """Parameters a unit gathers itself: its own, not those of units nested in it."""
    count = sum(p.numel() for p in module.parameters(recurse=False))
    for child in module.children():
        if id(child) not in units:
            count += own_parameters(child, units)
    return count


def shard_rows(module: nn.Module, world_size: int) -> int:
    """Elements rank 0 holds of every parameter of `module` (dim 0 split in world_size chunks)."""
    total = 0
    for p in module.parameters():
        rows = p.shape[0] if p.dim() else 1
        total += math.ceil(rows / world_size) * (p.numel() // max(rows, 1))
    return total


@dataclass(frozen=True)
class ShardedMemory:
    parameters: int
    world_size: int
    per_gpu_shard: int  # parameters held by rank 0
    largest_unit: int  # parameters the biggest unit gathers
    root_unit: int  # parameters of the root unit (outside every block)

    @property
    def sharded(self) -> dict[str, int]:
        return {name: size * self.per_gpu_shard for name, size in SHARDED_BYTES.items()}

    @property
    def gathered(self) -> int:
        return (2 * GATHERED_BYTES + GRADIENT_BYTES) * self.largest_unit + GATHERED_BYTES * self.root_unit

    @property
    def total(self) -> int:
        return sum(self.sharded.values()) + self.gathered

    def lines(self) -> list[str]:
        """The table a config states, in GiB."""
        rows = [f"{name}: {value / GIB:.2f} GiB" for name, value in self.sharded.items()]
        rows.append(f"gathered units: {self.gathered / GIB:.2f} GiB")
        rows.append(f"total per GPU: {self.total / GIB:.2f} GiB + activations")
        return rows


def sharded_memory(model: nn.Module, world_size: int) -> ShardedMemory:
    """The bytes per GPU of `model` (a MotionDiffusionModel, on any device, meta included)."""
    pairs = shard_units(model)
    unit_ids = {id(module) for module, _ in pairs}
    largest = max((own_parameters(module, unit_ids) for module, _ in pairs), default=0)
    return ShardedMemory(parameters=sum(p.numel() for p in model.parameters()), world_size=world_size,
                         per_gpu_shard=shard_rows(model, world_size), largest_unit=largest,
                         root_unit=own_parameters(model, unit_ids))
