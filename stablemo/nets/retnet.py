"""RetNet for motion (paper §4.1.3): multi-scale gated retention, written for bidirectional use.

Retention (Sun et al. 2023) replaces softmax attention by ``(Q K^T ⊙ D) V`` with a per-head decay
``D[n, m] = γ_h^(n-m)`` for ``n ≥ m`` and 0 otherwise, queries/keys rotated by their position
(relative-position rotation), a per-head GroupNorm and a swish output gate; heads use different
decays (γ_h = 1 - 2^(-5-h)), hence "multi-scale".

Decay choice: **bidirectional**, ``D[n, m] = γ_h^|n-m|``. A denoiser sees the whole noisy
sequence at once and must clean every frame using both what came before and what comes after
(a landing pose constrains the jump that precedes it); nothing is generated left to right, so
the causal mask of language-model RetNet would only hide half the evidence and leave the first
frames nearly unconditioned on the motion. The symmetric decay keeps RetNet's locality prior
(near frames weigh more, at a per-head scale), and the rotation still tells past from future.
Conditioning tokens (timestep, text) sit at distance 0 from every frame (no decay, no rotation),
so how a frame reads them does not depend on how many text tokens a batch is padded to.

- baseline (``cross_attention=False``): like MDM, [timestep token | text tokens | motion tokens]
  go through the retention blocks together.
- ``cross_attention=True``: [timestep token | motion tokens] in retention, and a residual linear
  multi-head cross-attention to the text between retention and the FFN (paper Fig. 3 f).

Padded keys are removed from the decay matrix (and so from both normalisers), and padded tokens
are zeroed after every sublayer: valid outputs are exactly padding invariant. ``length_multiple`` 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from stablemo.errors import StableMoError
from stablemo.nets.conditioning import Conditioning, check_conditioning, check_step
from stablemo.nets.layers import (
    FeedForward,
    LinearCrossAttention,
    TimestepEmbedder,
    zero_pad_btc,
)


def rotate(x: torch.Tensor, positions: torch.Tensor) -> torch.Tensor:
    """Rotate feature pairs of x (B, H, S, d) by angle positions[s] * θ_i (θ_i = 10000^(-2i/d))."""
    d = x.shape[-1]
    theta = torch.exp(-math.log(10000.0) * torch.arange(0, d, 2, device=x.device, dtype=torch.float32) / d)
    angle = positions.float()[:, None] * theta[None]  # (S, d/2)
    cos, sin = angle.cos().to(x.dtype), angle.sin().to(x.dtype)
    x1, x2 = x[..., 0::2], x[..., 1::2]
    return torch.stack([x1 * cos - x2 * sin, x1 * sin + x2 * cos], dim=-1).flatten(-2)


class MultiScaleRetention(nn.Module):
    """Gated multi-scale retention, bidirectional decay.

    x: (B, S, C); mask: (B, S) bool valid tokens; positions: (S,) frame index (0 for conditions);
    is_frame: (S,) bool, False for condition tokens (distance 0 to everything).
    """

    def __init__(self, dim: int, num_heads: int):
        super().__init__()
        if dim % num_heads or (dim // num_heads) % 2:
            raise StableMoError(f"num_heads: latent_dim {dim} must split into {num_heads} heads of even width")
        self.num_heads = num_heads
        self.q = nn.Linear(dim, dim, bias=False)
        self.k = nn.Linear(dim, dim, bias=False)
        self.v = nn.Linear(dim, dim, bias=False)
        self.g = nn.Linear(dim, dim, bias=False)
        self.out = nn.Linear(dim, dim, bias=False)
        self.head_norm = nn.GroupNorm(num_heads, dim)  # applied per token: heads normalised separately
        log_gamma = torch.log1p(-torch.pow(2.0, -5.0 - torch.arange(num_heads, dtype=torch.float64)))
        self.register_buffer("log_gamma", log_gamma.float(), persistent=False)

    def decay(self, mask, positions, is_frame, dtype):
        """(B, H, S, S) decay with padded keys removed, rows scaled by 1/sqrt(row sum)."""
        dist = (positions[:, None] - positions[None, :]).abs().to(dtype)
        dist = torch.where(is_frame[:, None] & is_frame[None, :], dist, torch.zeros((), dtype=dtype, device=dist.device))
        D = torch.exp(self.log_gamma.to(dtype)[:, None, None] * dist[None])  # (H, S, S)
        D = torch.where(mask[:, None, None, :], D[None], torch.zeros((), dtype=dtype, device=D.device))
        return D * torch.rsqrt(D.sum(dim=-1, keepdim=True))

    def forward(self, x, mask, positions, is_frame):
        B, S, C = x.shape
        H = self.num_heads
        heads = lambda y: y.reshape(B, S, H, C // H).transpose(1, 2)  # noqa: E731  (B, H, S, d)
        q = rotate(heads(self.q(x)), positions)
        k = rotate(heads(self.k(x)), positions) * (C // H) ** -0.5
        v = torch.where(mask[:, None, :, None], heads(self.v(x)), torch.zeros((), dtype=x.dtype, device=x.device))
        dtype = torch.promote_types(x.dtype, torch.float32)  # decay and normalisers in >= float32
        scores = (q @ k.transpose(-1, -2)).to(dtype) * self.decay(mask, positions, is_frame, dtype)
        scores = scores / scores.sum(dim=-1, keepdim=True).abs().clamp(min=1)
        o = (scores.to(x.dtype) @ v).transpose(1, 2).reshape(B * S, C)
        o = self.head_norm(o).reshape(B, S, C)
        return self.out(F.silu(self.g(x)) * o)


class RetNetBlock(nn.Module):
    def __init__(self, dim, text_dim, num_heads, ff_dim, dropout, cross_attention):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim)
        self.retention = MultiScaleRetention(dim, num_heads)
        self.cross = LinearCrossAttention(dim, text_dim, num_heads, dropout) if cross_attention else None
        self.norm2 = nn.LayerNorm(dim)
        self.ffn = FeedForward(dim, ff_dim, dropout)
        self.dropout = nn.Dropout(dropout)

    def forward(self, x, mask, positions, is_frame, context):
        x = zero_pad_btc(x + self.dropout(self.retention(self.norm1(x), mask, positions, is_frame)), mask)
        if self.cross is not None:
            x = zero_pad_btc(self.cross(x, context), mask)
        return zero_pad_btc(x + self.dropout(self.ffn(self.norm2(x))), mask)


class RetNet(nn.Module):
    """x: (B, T, input_dim), t: (B,), text: (B, L, text_dim) -> (B, T, input_dim)."""

    def __init__(
        self,
        input_dim: int,
        text_dim: int = 256,
        latent_dim: int = 512,
        num_layers: int = 8,
        num_heads: int = 8,
        ff_dim: int = 2048,
        dropout: float = 0.1,
        cross_attention: bool = True,
    ):
        super().__init__()
        self.input_dim, self.text_dim, self.latent_dim = input_dim, text_dim, latent_dim
        self.cross_attention = cross_attention
        self.length_multiple = 1
        self.motion_in = nn.Linear(input_dim, latent_dim)
        self.time_embed = TimestepEmbedder(latent_dim)
        if not cross_attention:
            self.text_in = nn.Linear(text_dim, latent_dim)
        self.blocks = nn.ModuleList(
            RetNetBlock(latent_dim, text_dim, num_heads, ff_dim, dropout, cross_attention) for _ in range(num_layers))
        self.final_norm = nn.LayerNorm(latent_dim)
        self.out = nn.Linear(latent_dim, input_dim)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def prepare(self, text, text_mask, motion_mask, time_cond=None, timesteps=()) -> "RetNetConditioning":
        """Per-request work: each block's text context, or the projected text tokens (baseline)."""
        check_conditioning(text, text_mask, motion_mask, self.text_dim)
        contexts, tokens = [None] * len(self.blocks), None
        if self.cross_attention:
            contexts = [block.cross.context(text, text_mask) for block in self.blocks]
        else:  # baseline: text tokens join the sequence, as in MDM
            tokens = zero_pad_btc(self.text_in(zero_pad_btc(text, text_mask)), text_mask)
        return RetNetConditioning(motion_mask, time_cond, (), contexts, tokens, text_mask)

    def forward(self, x, t, ctx: "RetNetConditioning"):
        h, seq = self.embed(x, t, ctx)
        for i in range(len(self.blocks)):
            h = self.block(i, h, seq, ctx)
        return self.readout(h, seq, ctx)

    # Named steps of `forward`, so a ControlNet (stablemo.control.controlnet) can run a copy of the first
    # blocks and add to the outputs of the frozen ones. The frame tokens are always the last T of h.

    def embed(self, x, t, ctx: "RetNetConditioning") -> tuple[torch.Tensor, "RetNetSequence"]:
        """x: (B, T, D) -> (the first block's tokens h (B, S, C): [timestep | text |] frames, their layout)."""
        check_step(x, t, ctx, self.input_dim, self.length_multiple)
        motion_mask = ctx.motion_mask
        B, T, _ = x.shape
        tokens = [self.time_embed(t, ctx.time_cond)[:, None]]  # (B, 1, C)
        masks = [torch.ones(B, 1, dtype=torch.bool, device=x.device)]
        if ctx.text_tokens is not None:
            tokens.append(ctx.text_tokens.to(tokens[0].dtype))
            masks.append(ctx.text_mask)
        n_cond = sum(tok.shape[1] for tok in tokens)
        tokens.append(zero_pad_btc(self.motion_in(zero_pad_btc(x, motion_mask)), motion_mask))
        masks.append(motion_mask)
        h, mask = torch.cat(tokens, dim=1), torch.cat(masks, dim=1)
        positions = torch.cat([torch.zeros(n_cond, device=x.device), torch.arange(T, device=x.device).float()])
        is_frame = torch.arange(n_cond + T, device=x.device) >= n_cond
        return h, RetNetSequence(mask, positions, is_frame)

    def block(self, i: int, h: torch.Tensor, seq: "RetNetSequence", ctx: "RetNetConditioning") -> torch.Tensor:
        return self.blocks[i](h, seq.mask, seq.positions, seq.is_frame, ctx.text_contexts[i])

    def readout(self, h: torch.Tensor, seq: "RetNetSequence", ctx: "RetNetConditioning") -> torch.Tensor:
        """The last block's tokens -> the output (B, T, D)."""
        T = ctx.motion_mask.shape[1]
        return zero_pad_btc(self.out(self.final_norm(h[:, -T:])), ctx.motion_mask)


@dataclass
class RetNetSequence:
    """One step's token layout: mask (B, S) valid tokens, positions (S,) frame index (0 for the
    condition tokens), is_frame (S,) bool."""

    mask: torch.Tensor
    positions: torch.Tensor
    is_frame: torch.Tensor


@dataclass
class RetNetConditioning(Conditioning):
    """text_contexts: per block, (B, H, d, d) or None; text_tokens: (B, L, C) projected text
    tokens of the baseline (None with cross-attention); text_mask: (B, L)."""

    text_contexts: list
    text_tokens: torch.Tensor | None
    text_mask: torch.Tensor
