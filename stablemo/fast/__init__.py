"""CPU inference speed-ups that change no result beyond float rounding, kept out of the networks.

`accelerate(model)` replaces, explicitly and in place, each stock layer of `model` that has a fast
version by that version, built from it and holding the very same parameters under the same names
(`state_dict()` keys and values unchanged). The mapping, stock -> fast:

    nn.Conv1d             -> GemmConv1d             one GEMM over unfolded frames (gemm.py)
    nn.ConvTranspose1d    -> GemmConvTranspose1d    one GEMM + col2im
    nn.Linear             -> CachedCastLinear       packed / low-precision cached weights
    nn.Mish               -> FastMish               seven vectorised passes (blocks.py)
    ResBlock1D            -> FastResBlock1D         norm + AdaGN + Mish + residual + padding fused
    CondUNet1D            -> FastCondUNet1D         head fused, frames-major skips, in-place padding
    CrossAttention1D      -> FastCrossAttention1D   padding zeroed in place
    LinearCrossAttention  -> FusedLinearCrossAttention   (>= 256 channels) fused per-head read

The compiled kernels (kernels.py, cpu_kernels.cpp) are used only by layers of >= 256 channels, so
small models (the demo) never build them. Meant for inference: the weight caches assume weights
change only in place (which they detect); with autograd recording every layer computes from its
live parameters, so an accelerated model still trains correctly.
"""

from __future__ import annotations

from typing import Callable

from torch import nn

from stablemo.fast.blocks import (
    FastCondUNet1D,
    FastCrossAttention1D,
    FastMish,
    FastResBlock1D,
    FusedLinearCrossAttention,
)
from stablemo.fast.gemm import (
    MIN_FUSED_CHANNELS,
    CachedCastLinear,
    GemmConv1d,
    GemmConvTranspose1d,
    gemm_backend,
)
from stablemo.nets.layers import LinearCrossAttention
from stablemo.nets.unet import CondUNet1D, CrossAttention1D, ResBlock1D


def _fused_attention(stock: LinearCrossAttention) -> nn.Module:
    if stock.query.out_features < MIN_FUSED_CHANNELS:
        return stock
    return FusedLinearCrossAttention(stock)


# exact stock type -> factory(stock) returning its replacement (or stock itself where none applies)
FAST_LAYERS: dict[type, Callable[[nn.Module], nn.Module]] = {
    nn.Conv1d: GemmConv1d.from_stock,
    nn.ConvTranspose1d: GemmConvTranspose1d.from_stock,
    nn.Linear: CachedCastLinear.from_stock,
    nn.Mish: lambda stock: FastMish(),
    ResBlock1D: FastResBlock1D,
    CondUNet1D: FastCondUNet1D,
    CrossAttention1D: FastCrossAttention1D,
    LinearCrossAttention: _fused_attention,
}


def swap_layers(model: nn.Module, table: dict) -> nn.Module:
    """Replace, children first, every module whose exact type is in `table` by table[type](module);
    returns the model (a replacement when `model` itself is such a layer)."""
    for name, child in list(model.named_children()):
        fast = swap_layers(child, table)
        if fast is not child:
            setattr(model, name, fast)
    factory = table.get(type(model))
    return factory(model) if factory is not None else model


def accelerate(model: nn.Module) -> nn.Module:
    """Replace every layer of `model` listed in FAST_LAYERS by its fast version, children first;
    returns the model (a replacement when `model` itself is such a layer)."""
    return swap_layers(model, FAST_LAYERS)


__all__ = ["FAST_LAYERS", "accelerate", "gemm_backend"]
