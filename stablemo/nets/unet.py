"""CondUNet1D: the StableMoFusion motion denoiser (paper §4.1.1).

A Conv1D UNet over time with four resolution stages (three stride-2 down-samplings: the length
goes from N to N/8 as the paper's text says, so T must be a multiple of 8; ``length_multiple`` is
2^(len(channel_mults) - 1)), two residual blocks per stage on the way down and on the way up, skip
connections between matching stages, and a zero-initialised output convolution.

Each residual block: conv -> norm -> AdaGN (x * (1 + scale) + shift from the timestep embedding,
plus the pooled text embedding) -> Mish -> dropout -> conv -> norm -> Mish, plus a 1x1 residual.
Ablation switches (paper Table 4):
- ``cross_attention``: residual linear multi-head cross-attention to the text tokens after every
  residual block ("+ cross-attention"); without it the text enters only through AdaGN (baseline).
- ``norm``: ``"group"`` = GroupNorm over channel groups and time (baseline), ``"frame"`` = the
  GroupNorm tweak (each frame over its channel groups).

Both norms are exactly padding invariant here: the "group" norm takes its statistics over valid
frames only (the published baseline does not, which is the leak the tweak fixes there).
"""

from __future__ import annotations

from typing import Sequence

import torch
from torch import nn

from stablemo.errors import StableMoError
from stablemo.nets.layers import (
    PLANNED_TIMESTEPS,
    LinearCrossAttention,
    MaskedGroupNorm,
    cat_channels,
    memoized,
    TimestepEmbedder,
    check_inputs,
    downsample_mask,
    masked_mean,
    zero_pad_bct,
    zero_pad_bct_,
)


class ResBlock1D(nn.Module):
    """Residual Conv1D block with AdaGN. x: (B, C_in, T) zero on padding -> (B, C_out, T)."""

    def __init__(self, in_ch: int, out_ch: int, emb_dim: int, kernel_size: int, num_groups: int,
                 norm: str, dropout: float):
        super().__init__()
        pad = kernel_size // 2
        self.conv1 = nn.Conv1d(in_ch, out_ch, kernel_size, padding=pad)
        self.norm1 = MaskedGroupNorm(num_groups, out_ch, norm)
        self.emb = nn.Sequential(nn.Mish(), nn.Linear(emb_dim, 2 * out_ch))
        self.dropout = nn.Dropout(dropout)
        self.conv2 = nn.Conv1d(out_ch, out_ch, kernel_size, padding=pad)
        self.norm2 = MaskedGroupNorm(num_groups, out_ch, norm)
        self.skip = nn.Conv1d(in_ch, out_ch, 1) if in_ch != out_ch else nn.Identity()
        self.act = nn.Mish()  # a module, so stablemo.diffusion.accelerate can swap in its fast Mish

    def forward(self, x: torch.Tensor, emb: torch.Tensor, mask: torch.Tensor, memo: dict | None = None) -> torch.Tensor:
        scale, shift = self.adagn(emb, memo)
        h = self.norm1.forward_act(self.conv1(x), mask, self.act, 1 + scale, shift)  # AdaGN: norm(h) (1 + scale) + shift
        # padded frames are zero before the dropout, which keeps them zero
        return self.norm2.forward_act(self.conv2(self.dropout(h)), mask, self.act, residual=self.skip(x))

    def adagn(self, emb: torch.Tensor, memo: dict | None) -> tuple[torch.Tensor, torch.Tensor]:
        """AdaGN's (scale, shift), (B, C_out, 1) each. In a planned request (CondUNet1D puts the
        embeddings of all its steps in the memo) the projection runs once, for every step: its
        weight is then read from memory once per request instead of once per step."""
        step = memo.get(ADAGN_STEP) if memo is not None and not torch.is_grad_enabled() else None
        if step is None:
            return self.emb(emb)[:, :, None].chunk(2, dim=1)
        planned, emb_all, index = step  # emb_all: (S, B, emb_dim)
        table = memoized(memo, (self, planned), lambda: self.emb(emb_all))  # (S, B, 2 C_out)
        return table[index][:, :, None].chunk(2, dim=1)


class CrossAttention1D(nn.Module):
    """LinearCrossAttention applied to (B, C, T) feature maps."""

    def __init__(self, channels: int, text_dim: int, num_heads: int, dropout: float):
        super().__init__()
        self.attn = LinearCrossAttention(channels, text_dim, num_heads, dropout)

    def forward(self, x, text, text_mask, mask, memo=None):
        y = self.attn(x.transpose(1, 2), text, text_mask, memo).transpose(1, 2)
        return zero_pad_bct_(y, mask)


class Stage(nn.Module):
    """Two residual blocks, each optionally followed by cross-attention."""

    def __init__(self, in_ch, out_ch, emb_dim, text_dim, *, kernel_size, num_groups, norm, dropout,
                 cross_attention, num_heads):
        super().__init__()
        self.blocks = nn.ModuleList([
            ResBlock1D(in_ch, out_ch, emb_dim, kernel_size, num_groups, norm, dropout),
            ResBlock1D(out_ch, out_ch, emb_dim, kernel_size, num_groups, norm, dropout),
        ])
        self.attns = nn.ModuleList(
            [CrossAttention1D(out_ch, text_dim, num_heads, dropout) for _ in range(2)] if cross_attention else []
        )

    def forward(self, x, emb, text, text_mask, mask, memo=None):
        for i, block in enumerate(self.blocks):
            x = block(x, emb, mask, memo)
            if self.attns:
                x = self.attns[i](x, text, text_mask, mask, memo)
        return x


# memo key: (planned timesteps, their AdaGN embeddings (S, B, time_dim), this step's index) or None
ADAGN_STEP = "adagn step"
MAX_PLANNED_STEPS = 64  # a table per block of S x B rows: not for 1000-step DDPM


class CondUNet1D(nn.Module):
    """x: (B, T, input_dim), t: (B,), text: (B, L, text_dim) -> (B, T, input_dim).

    memo: an optional dict kept by the caller for one fixed text (see layers.memoized).
    """

    def __init__(
        self,
        input_dim: int,
        text_dim: int = 256,
        base_channels: int = 512,
        channel_mults: Sequence[int] = (2, 2, 2, 2),
        time_dim: int = 512,
        kernel_size: int = 5,
        num_groups: int = 8,
        num_heads: int = 8,
        dropout: float = 0.1,
        cross_attention: bool = True,
        norm: str = "frame",
    ):
        super().__init__()
        if len(channel_mults) < 1:
            raise StableMoError("channel_mults: need at least one stage")
        if kernel_size % 2 == 0:
            raise StableMoError(f"kernel_size: must be odd to keep the length, got {kernel_size}")
        self.input_dim, self.text_dim = input_dim, text_dim
        self.length_multiple = 2 ** (len(channel_mults) - 1)
        dims = [input_dim] + [base_channels * m for m in channel_mults]
        common = dict(kernel_size=kernel_size, num_groups=num_groups, norm=norm, dropout=dropout,
                      cross_attention=cross_attention, num_heads=num_heads)

        self.time_embed = TimestepEmbedder(time_dim)
        self.text_embed = nn.Linear(text_dim, time_dim)  # pooled text joins the AdaGN embedding

        n = len(channel_mults)
        self.down = nn.ModuleList(Stage(dims[i], dims[i + 1], time_dim, text_dim, **common) for i in range(n))
        self.downsample = nn.ModuleList(nn.Conv1d(dims[i + 1], dims[i + 1], 3, stride=2, padding=1) for i in range(n - 1))
        self.mid = Stage(dims[-1], dims[-1], time_dim, text_dim, **common)
        # up stage i (run from i = n-1 down to 0) concatenates the skip of down stage i
        up, upsample, ch = [], [], dims[-1]
        for i in reversed(range(n)):
            up.append(Stage(ch + dims[i + 1], dims[i + 1], time_dim, text_dim, **common))
            ch = dims[i + 1]
            if i > 0:
                upsample.append(nn.ConvTranspose1d(ch, ch, 4, stride=2, padding=1))
        self.up = nn.ModuleList(up)
        self.upsample = nn.ModuleList(upsample)
        self.final_conv = nn.Conv1d(ch, ch, kernel_size, padding=kernel_size // 2)
        self.final_norm = MaskedGroupNorm(num_groups, ch, norm)
        self.final_act = nn.Mish()
        self.out = nn.Conv1d(ch, input_dim, 1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def _planned_step(self, memo: dict, t: torch.Tensor, time_cond, pooled: torch.Tensor):
        """This step's place in the request's planned timesteps (see ResBlock1D.adagn), or None
        when there is no plan or t is not one of its steps or not shared by the batch."""
        planned = memo.get(PLANNED_TIMESTEPS)
        if (planned is None or time_cond is not None or len(planned) > MAX_PLANNED_STEPS
                or int(t[0]) not in planned or not bool((t == t[0]).all())):
            return None
        B = t.shape[0]

        def embed_all():  # (S, B, time_dim): every planned step's embedding, in one pass
            steps = torch.tensor(planned, dtype=t.dtype, device=t.device).repeat_interleave(B)
            return self.time_embed(steps).view(len(planned), B, -1) + pooled

        return planned, memoized(memo, (self, planned), embed_all), planned.index(int(t[0]))

    def forward(self, x, t, text, text_mask, motion_mask, time_cond=None, memo=None):
        check_inputs(x, t, text, text_mask, motion_mask, self.input_dim, self.text_dim, self.length_multiple)
        pooled = memoized(memo, self, lambda: self.text_embed(masked_mean(text, text_mask)))  # (B, time_dim)
        step = None
        if memo is not None and not torch.is_grad_enabled():  # (with autograd nothing is memoized)
            memo[ADAGN_STEP] = step = self._planned_step(memo, t, time_cond, pooled)
        if step is not None:  # this step's row of the planned embeddings: no time MLP per step
            emb = step[1][step[2]]
        else:
            emb = self.time_embed(t, time_cond) + pooled  # (B, time_dim)
        mask = motion_mask
        h = zero_pad_bct(x.transpose(1, 2), mask)  # (B, D, T)
        skips, masks = [], []
        for i, stage in enumerate(self.down):
            h = stage(h, emb, text, text_mask, mask, memo)
            skips.append(h)
            masks.append(mask)
            if i < len(self.downsample):
                mask = downsample_mask(mask)
                h = zero_pad_bct_(self.downsample[i](h), mask)
        h = self.mid(h, emb, text, text_mask, mask, memo)
        for j, stage in enumerate(self.up):
            mask = masks.pop()
            h = stage(cat_channels(h, skips.pop()), emb, text, text_mask, mask, memo)
            if j < len(self.upsample):
                h = zero_pad_bct_(self.upsample[j](h), masks[-1])
        h = self.final_norm.forward_act(self.final_conv(h), mask, self.final_act)
        return zero_pad_bct_(self.out(h), mask).transpose(1, 2)
