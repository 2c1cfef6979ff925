"""FLOPs of the fast path's own ops, which torch's FlopCounterMode cannot see or does not know.

- the packed-weight linears (MKL's and oneDNN's), given as counter formulas;
- the fused cross-attention read (a C++ call): its per-head products, q (T x d) @ context (d x d)
  per sample and head, counted from each call's shape.
"""

from __future__ import annotations

import contextlib
from typing import Iterator

import torch
from torch import nn

from stablemo.fast.blocks import FusedLinearCrossAttention
from stablemo.fast.gemm import _ONEDNN_PACK


def _packed_linear(x_shape, n_out) -> int:
    rows = 1
    for n in x_shape[:-1]:
        rows *= n
    return 2 * rows * x_shape[-1] * n_out


def counter_formulas() -> dict:
    """custom_mapping for FlopCounterMode: the packed-weight linears, keyed by overload packet."""
    formulas = {}
    if hasattr(torch.ops.mkl, "_mkl_linear"):
        formulas[torch.ops.mkl._mkl_linear] = (
            lambda x_shape, packed_shape, w_shape, *args, out_shape=None, **kwargs: _packed_linear(x_shape, w_shape[0]))
    if _ONEDNN_PACK:  # the packed weight keeps the (out, in) shape of the plain one
        formulas[torch.ops.mkldnn._linear_pointwise] = (
            lambda x_shape, w_shape, *args, out_shape=None, **kwargs: _packed_linear(x_shape, w_shape[0]))
    return formulas


@contextlib.contextmanager
def fused_read_flops(model: nn.Module) -> Iterator[list[int]]:
    """Counts the fused attention reads' FLOPs while active: yields a one-element list holding the total."""
    total = [0]

    def count(module, inputs):
        B, T, C = inputs[0].shape
        total[0] += 2 * B * T * C * (C // module.num_heads)

    hooks = [m.register_forward_pre_hook(count) for m in model.modules() if isinstance(m, FusedLinearCrossAttention)]
    try:
        yield total
    finally:
        for hook in hooks:
            hook.remove()
