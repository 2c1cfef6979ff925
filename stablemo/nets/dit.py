"""DiT for motion (paper §4.1.2): transformer blocks with adaLN-Zero timestep modulation.

- baseline (``cross_attention=False``): the text tokens are projected to the latent width and
  concatenated with the motion tokens; self-attention runs over both (masked keys on each side).
- ``cross_attention=True``: self-attention over motion tokens only, and a residual linear
  multi-head cross-attention to the text between self-attention and the MLP (paper Fig. 3 d), so
  the two modalities stay in separate streams.

Motion tokens carry a sinusoidal encoding of their frame index (independent of the total padded
length); text tokens carry the frozen encoder's own positions plus a learned type embedding.
Padded tokens are zeroed after every sublayer and masked as keys, so valid outputs are exactly
padding invariant. ``length_multiple`` is 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from stablemo.errors import StableMoError
from stablemo.nets.conditioning import Conditioning, check_conditioning, check_step
from stablemo.nets.layers import (
    FeedForward,
    LinearCrossAttention,
    SelfAttention,
    TimestepEmbedder,
    modulate,
    sinusoidal_embedding,
    zero_pad_btc,
)


class DiTBlock(nn.Module):
    """adaLN-Zero block. x: (B, S, C), mask: (B, S); emb: (B, C)."""

    def __init__(self, dim: int, text_dim: int, num_heads: int, ff_dim: int, dropout: float, cross_attention: bool):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, elementwise_affine=False, eps=1e-6)
        self.attn = SelfAttention(dim, num_heads, dropout)
        self.cross = LinearCrossAttention(dim, text_dim, num_heads, dropout) if cross_attention else None
        self.norm2 = nn.LayerNorm(dim, elementwise_affine=False, eps=1e-6)
        self.mlp = FeedForward(dim, ff_dim, dropout)
        self.dropout = nn.Dropout(dropout)
        self.ada = nn.Sequential(nn.SiLU(), nn.Linear(dim, 6 * dim))
        nn.init.zeros_(self.ada[1].weight)  # adaLN-Zero: every block starts as the identity
        nn.init.zeros_(self.ada[1].bias)

    def forward(self, x, mask, emb, context):
        """context: the cross-attention's (B, H, d, d) text summary (None without cross-attention)."""
        shift1, scale1, gate1, shift2, scale2, gate2 = self.ada(emb).chunk(6, dim=-1)
        h = self.attn(modulate(self.norm1(x), shift1, scale1), mask)
        x = zero_pad_btc(x + gate1[:, None] * self.dropout(h), mask)
        if self.cross is not None:
            x = zero_pad_btc(self.cross(x, context), mask)
        h = self.mlp(modulate(self.norm2(x), shift2, scale2))
        return zero_pad_btc(x + gate2[:, None] * self.dropout(h), mask)


class DiT(nn.Module):
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
        if latent_dim % num_heads:
            raise StableMoError(f"num_heads: latent_dim {latent_dim} is not divisible by {num_heads}")
        self.input_dim, self.text_dim, self.latent_dim = input_dim, text_dim, latent_dim
        self.cross_attention = cross_attention
        self.length_multiple = 1
        self.motion_in = nn.Linear(input_dim, latent_dim)
        self.time_embed = TimestepEmbedder(latent_dim)
        if not cross_attention:
            self.text_in = nn.Linear(text_dim, latent_dim)
            self.text_type = nn.Parameter(torch.zeros(latent_dim))
        self.blocks = nn.ModuleList(
            DiTBlock(latent_dim, text_dim, num_heads, ff_dim, dropout, cross_attention) for _ in range(num_layers))
        self.final_norm = nn.LayerNorm(latent_dim, elementwise_affine=False, eps=1e-6)
        self.final_ada = nn.Sequential(nn.SiLU(), nn.Linear(latent_dim, 2 * latent_dim))
        self.out = nn.Linear(latent_dim, input_dim)
        for layer in (self.final_ada[1], self.out):
            nn.init.zeros_(layer.weight)
            nn.init.zeros_(layer.bias)

    def prepare(self, text, text_mask, motion_mask, time_cond=None, timesteps=()) -> "DiTConditioning":
        """Per-request work: each block's text context, or the projected text tokens (baseline)."""
        check_conditioning(text, text_mask, motion_mask, self.text_dim)
        contexts, tokens, mask = [None] * len(self.blocks), None, motion_mask
        if self.cross_attention:
            contexts = [block.cross.context(text, text_mask) for block in self.blocks]
        else:  # baseline: [text tokens | motion tokens]
            tokens = zero_pad_btc(self.text_in(zero_pad_btc(text, text_mask)) + self.text_type, text_mask)
            mask = torch.cat([text_mask, motion_mask], dim=1)
        return DiTConditioning(motion_mask, time_cond, (), contexts, tokens, mask)

    def forward(self, x, t, ctx: "DiTConditioning"):
        h, emb = self.embed(x, t, ctx)
        for i in range(len(self.blocks)):
            h = self.block(i, h, emb, ctx)
        return self.readout(h, emb, ctx)

    # Named steps of `forward`, so a ControlNet (stablemo.control.controlnet) can run a copy of the first
    # blocks and add to the outputs of the frozen ones. The frame tokens are always the last T of h.

    def embed(self, x, t, ctx: "DiTConditioning") -> tuple[torch.Tensor, torch.Tensor]:
        """x: (B, T, D) -> (the first block's tokens h (B, S, C), the timestep embedding (B, C))."""
        check_step(x, t, ctx, self.input_dim, self.length_multiple)
        T = x.shape[1]
        emb = self.time_embed(t, ctx.time_cond)  # (B, C)
        h = self.motion_in(zero_pad_btc(x, ctx.motion_mask))
        h = h + sinusoidal_embedding(torch.arange(T, device=x.device), self.latent_dim).to(h.dtype)[None]
        h = zero_pad_btc(h, ctx.motion_mask)
        if ctx.text_tokens is not None:
            h = torch.cat([ctx.text_tokens.to(h.dtype), h], dim=1)
        return h, emb

    def block(self, i: int, h: torch.Tensor, emb: torch.Tensor, ctx: "DiTConditioning") -> torch.Tensor:
        return self.blocks[i](h, ctx.sequence_mask, emb, ctx.text_contexts[i])

    def readout(self, h: torch.Tensor, emb: torch.Tensor, ctx: "DiTConditioning") -> torch.Tensor:
        """The last block's tokens -> the output (B, T, D)."""
        T = ctx.motion_mask.shape[1]
        shift, scale = self.final_ada(emb).chunk(2, dim=-1)
        out = self.out(modulate(self.final_norm(h[:, -T:]), shift, scale))
        return zero_pad_btc(out, ctx.motion_mask)


@dataclass
class DiTConditioning(Conditioning):
    """text_contexts: per block, (B, H, d, d) or None; text_tokens: (B, L, C) projected text
    tokens of the baseline (None with cross-attention); sequence_mask: (B, L + T) or (B, T)."""

    text_contexts: list
    text_tokens: torch.Tensor | None
    sequence_mask: torch.Tensor
