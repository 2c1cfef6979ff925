"""Building blocks shared by the denoisers.

Padding invariance (ARCHITECTURE.md) rests on two rules that every layer here follows:

1. Padded positions are set to exactly zero (with `torch.where`, so NaN/inf padding cannot leak
   through `0 * nan`) after every operator that mixes time steps or could make them non-zero,
   before the next temporal operator. A convolution then sees zeros past the last valid frame,
   which is exactly what its own zero padding shows at the end of a shorter tensor.
2. Statistics (norms, attention normalisers, pooling) are taken over valid positions only.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from stablemo.errors import StableMoError

# ----------------------------------------------------------------------------- masking helpers


def zero_pad_btc(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """x: (B, T, C), mask: (B, T) bool -> x with padded rows exactly zero."""
    return torch.where(mask[:, :, None], x, 0.0)  # a Python scalar: no tensor to build, x's dtype kept


def zero_pad_bct(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """x: (B, C, T), mask: (B, T) bool -> x with padded columns exactly zero."""
    return torch.where(mask[:, None, :], x, 0.0)


def downsample_mask(mask: torch.Tensor) -> torch.Tensor:
    """Mask after a stride-2 down-sampling: output frame j is valid iff input frame 2j is.

    For a prefix mask of length n this is a prefix of length ceil(n / 2), independent of the
    total padded length.
    """
    return mask[:, ::2]


def masked_mean(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """x: (B, L, C), mask: (B, L) -> (B, C) mean over valid rows (zero when none is valid)."""
    x = zero_pad_btc(x, mask)
    count = mask.sum(dim=1, keepdim=True).clamp(min=1).to(x.dtype)
    return x.sum(dim=1) / count


# ----------------------------------------------------------------------------- timestep embedding


def sinusoidal_embedding(positions: torch.Tensor, dim: int, max_period: float = 10000.0) -> torch.Tensor:
    """positions: (N,) float or int -> (N, dim) float32, [cos | sin] halves (as Stable Diffusion)."""
    half = dim // 2
    freqs = torch.exp(-math.log(max_period) * torch.arange(half, dtype=torch.float32, device=positions.device) / half)
    args = positions.float()[:, None] * freqs[None]
    emb = torch.cat([torch.cos(args), torch.sin(args)], dim=-1)
    if dim % 2:
        emb = F.pad(emb, (0, 1))
    return emb


def interleaved_sinusoidal_embedding(positions: torch.Tensor, dim: int) -> torch.Tensor:
    """positions: (N,) -> (N, dim) float32, sin and cos interleaved (features 2i, 2i+1), computed with
    the float32 operations of the published StableMoFusion T2MUnet's table (bit-equal to it for
    steps 0-999 at dim 512; the same values as `sinusoidal_embedding`, in another order)."""
    freqs = torch.exp(torch.arange(0, dim, 2, dtype=torch.float32, device=positions.device) * (-math.log(10000.0) / dim))
    args = positions.float()[:, None] * freqs[None]  # (N, dim / 2)
    return torch.stack([torch.sin(args), torch.cos(args)], dim=-1).reshape(len(positions), dim)


class TimestepEmbedder(nn.Module):
    """Sinusoidal encoding of the diffusion step followed by two linear layers.

    variant ``"stablemo"``: [cos | sin] features, Linear(dim, out) -> SiLU -> Linear (Stable
    Diffusion). ``"official"``: the published StableMoFusion T2MUnet's, interleaved sin/cos
    features, Linear(dim, 4 dim) -> Mish -> Linear(4 dim, out) (stablemo.official imports it).
    """

    def __init__(self, dim: int, out_dim: int | None = None, variant: str = "stablemo"):
        super().__init__()
        if variant not in ("stablemo", "official"):
            raise StableMoError(f"time embedding variant: expected 'stablemo' or 'official', got {variant!r}")
        out_dim = out_dim or dim
        self.dim, self.variant = dim, variant
        if variant == "official":
            self.mlp = nn.Sequential(nn.Linear(dim, 4 * dim), nn.Mish(), nn.Linear(4 * dim, out_dim))
        else:
            self.mlp = nn.Sequential(nn.Linear(dim, out_dim), nn.SiLU(), nn.Linear(out_dim, out_dim))

    def forward(self, t: torch.Tensor, extra: torch.Tensor | None = None) -> torch.Tensor:
        """t: (B,) -> (B, out_dim). extra: (B, dim) features added to the sinusoidal encoding before
        the MLP (a consistency student's guidance-scale embedding, stablemo.distill)."""
        if self.variant == "official":
            emb = interleaved_sinusoidal_embedding(t, self.dim)
        else:
            emb = sinusoidal_embedding(t, self.dim)
        if extra is not None:
            emb = emb + extra.to(emb.dtype)
        return self.mlp(emb.to(self.mlp[0].weight.dtype))


# ----------------------------------------------------------------------------- norms


class MaskedGroupNorm(nn.Module):
    """GroupNorm for (B, C, T) with two modes.

    - ``"group"``: the standard GroupNorm (statistics over the channels of a group *and* time), but
      with mean/variance taken over valid frames only, so padding cannot shift them.
    - ``"frame"``: the StableMoFusion "GroupNorm tweak": each frame is normalised on its own over
      its channel groups; nothing crosses time at all.

    Statistics are computed in float32 whatever the input precision.
    """

    def __init__(self, num_groups: int, channels: int, mode: str = "frame", eps: float = 1e-5):
        super().__init__()
        if mode not in ("group", "frame"):
            raise StableMoError(f"norm: expected 'group' or 'frame', got {mode!r}")
        if channels % num_groups:
            raise StableMoError(f"norm: {channels} channels are not divisible into {num_groups} groups")
        self.mode, self.num_groups, self.eps = mode, num_groups, eps
        self.weight = nn.Parameter(torch.ones(channels))
        self.bias = nn.Parameter(torch.zeros(channels))

    def forward(self, x: torch.Tensor, mask: torch.Tensor, scale: torch.Tensor | None = None,
                shift: torch.Tensor | None = None) -> torch.Tensor:
        """x: (B, C, T); optional AdaGN modulation scale, shift: (B, C, 1) applied after the affine,
        norm(x) * weight * scale + bias * scale + shift, folded into the affine's single pass."""
        B, C, T = x.shape
        dtype = torch.promote_types(x.dtype, torch.float32)  # at least float32 statistics
        weight, bias = self.weight.to(dtype)[:, None], self.bias.to(dtype)[:, None]  # (C, 1)
        if scale is not None:
            weight, bias = weight * scale, torch.addcmul(shift, bias, scale)  # (B, C, 1)
        if self.mode == "frame":
            # per-frame statistics over a channel group = layer_norm over that group's channels: one
            # fused pass over (B, T, G, C/G) frames
            G = self.num_groups
            frames = x.to(dtype).transpose(1, 2).reshape(B, T, G, C // G)
            y = F.layer_norm(frames, (C // G,), eps=self.eps).reshape(B, T, C)
            y = torch.addcmul(bias.transpose(-1, -2), y, weight.transpose(-1, -2))
            return y.transpose(1, 2).to(x.dtype)
        g = x.to(dtype).reshape(B, self.num_groups, C // self.num_groups, T)
        m = mask[:, None, None, :]  # (B, 1, 1, T)
        count = (mask.sum(dim=1).float() * (C // self.num_groups)).clamp(min=1)[:, None, None, None]
        g0 = torch.where(m, g, torch.zeros((), dtype=dtype, device=x.device))
        mean = g0.sum(dim=(2, 3), keepdim=True) / count.to(dtype)
        centred = torch.where(m, g - mean, torch.zeros((), dtype=dtype, device=x.device))
        var = centred.pow(2).sum(dim=(2, 3), keepdim=True) / count.to(dtype)
        y = ((g - mean) * torch.rsqrt(var + self.eps)).reshape(B, C, T)
        return torch.addcmul(bias, y, weight).to(x.dtype)


# ----------------------------------------------------------------------------- attention


class LinearCrossAttention(nn.Module):
    """Residual linear multi-head cross-attention from motion frames to text tokens.

    Efficient attention (as MotionDiffuse uses it): queries are soft-maxed over each head's
    features, keys over the (valid) text tokens, so the text is summarised into one (d x d)
    context per head and each frame reads it with its own query: cost O(T + L), and every frame's
    output depends only on that frame and the text -- no leak across time.

    The per-head contexts depend on the text alone: `context(text, text_mask)` makes them, once per
    request when sampling (the denoisers' `prepare`), and `forward(x, context)` reads them:
    x: (B, T, C), context: (B, H, d, d) -> x + attn(x, text): (B, T, C).
    """

    def __init__(self, dim: int, text_dim: int, num_heads: int = 8, dropout: float = 0.0, out_proj: bool = True):
        super().__init__()
        if dim % num_heads:
            raise StableMoError(f"num_heads: {dim} channels are not divisible by {num_heads} heads")
        self.num_heads = num_heads
        self.norm = nn.LayerNorm(dim)
        self.text_norm = nn.LayerNorm(text_dim)
        self.query = nn.Linear(dim, dim)
        self.key = nn.Linear(text_dim, dim)
        self.value = nn.Linear(text_dim, dim)
        # out_proj=False: the published StableMoFusion attention adds the heads' read unprojected;
        # a text with no valid token then adds exactly zero (its CFG "no cross-attention" pass)
        self.out = nn.Linear(dim, dim) if out_proj else nn.Identity()
        self.dropout = nn.Dropout(dropout)

    def context(self, text: torch.Tensor, text_mask: torch.Tensor) -> torch.Tensor:
        """The text summarised per head: (B, L, text_dim) -> (B, H, d, d)."""
        B, H = text.shape[0], self.num_heads
        d = self.query.out_features // H
        text = self.text_norm(zero_pad_btc(text, text_mask))
        k_logits = self.key(text).reshape(B, -1, H, d)
        k_logits = k_logits.masked_fill(~text_mask[:, :, None, None], torch.finfo(k_logits.dtype).min)
        k = k_logits.softmax(dim=1)
        valid = text_mask[:, :, None, None]
        k = torch.where(valid, k, torch.zeros((), dtype=k.dtype, device=k.device))  # no valid token -> no context
        v = self.value(text).reshape(B, -1, H, d)
        v = torch.where(valid, v, torch.zeros((), dtype=v.dtype, device=v.device))
        return torch.einsum("blhd,blhe->bhde", k, v)

    def forward(self, x: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
        y = self.read(self.query(self.norm(x)), context)
        return x + self.dropout(self.out(y))

    def read(self, q_logits: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
        """Each frame reads the text: q_logits (B, T, C), context (B, H, d, d) -> (B, T, C), head h
        of a frame = softmax over that head's query features @ context[h]."""
        B, T, C = q_logits.shape
        q = q_logits.reshape(B, T, self.num_heads, C // self.num_heads).softmax(dim=-1)
        return torch.einsum("bthd,bhde->bthe", q, context.to(q.dtype)).reshape(B, T, C)


def key_padding_attention(q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, key_mask: torch.Tensor,
                          dropout_p: float = 0.0) -> torch.Tensor:
    """Softmax attention where masked keys get exactly zero weight.

    q, k, v: (B, H, S, d); key_mask: (B, S) bool (at least one valid key per row) -> (B, H, S, d).
    """
    attn_mask = key_mask[:, None, None, :]
    return F.scaled_dot_product_attention(q, k, v, attn_mask=attn_mask, dropout_p=dropout_p)


class SelfAttention(nn.Module):
    """Multi-head self-attention over a masked token sequence. x: (B, S, C), mask: (B, S)."""

    def __init__(self, dim: int, num_heads: int, dropout: float = 0.0):
        super().__init__()
        if dim % num_heads:
            raise StableMoError(f"num_heads: {dim} channels are not divisible by {num_heads} heads")
        self.num_heads, self.dropout = num_heads, dropout
        self.qkv = nn.Linear(dim, 3 * dim)
        self.out = nn.Linear(dim, dim)

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        B, S, C = x.shape
        q, k, v = self.qkv(x).reshape(B, S, 3, self.num_heads, C // self.num_heads).permute(2, 0, 3, 1, 4)
        y = key_padding_attention(q, k, v, mask, self.dropout if self.training else 0.0)
        return self.out(y.transpose(1, 2).reshape(B, S, C))


class FeedForward(nn.Sequential):
    def __init__(self, dim: int, hidden: int, dropout: float = 0.0):
        super().__init__(nn.Linear(dim, hidden), nn.GELU(), nn.Dropout(dropout), nn.Linear(hidden, dim))


def modulate(x: torch.Tensor, shift: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """adaLN / AdaGN modulation x * (1 + scale) + shift, with (B, C) shift/scale over (B, S, C)."""
    return x * (1 + scale[:, None, :]) + shift[:, None, :]
