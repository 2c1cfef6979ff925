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
Ours, off by default: ``input_head`` (residual blocks over [last features | x_t] before the output),
``mid_attention`` (temporal self-attention at the coarsest resolution, so distant frames can
agree: TemporalSelfAttention1D) and ``up_attention`` (the same after chosen up stages: a second
layer at the coarsest resolution, or one at a finer one).

Both norms are exactly padding invariant here: the "group" norm takes its statistics over valid
frames only (the published baseline does not, which is the leak the tweak fixes there).

``variant="official"`` lays the network out as the published StableMoFusion T2MUnet (its
checkpoints import into it, stablemo.official; docs/official.md), with everything else above kept:
- a stride-2 down-sampling after *every* stage (the middle runs at N / 2^n, so T must be a
  multiple of 2^n = 16 for four stages), and on the way up a transposed convolution *before* each
  up stage that also changes the width (C_deeper -> C_stage), then the skip concatenation;
- the output head is the zero-initialised 1x1 convolution alone (no conv -> norm -> Mish);
- no pooled text in the AdaGN embedding: the text enters through cross-attention only;
- cross-attention without an output projection (a text without valid tokens adds exactly zero);
- the timestep embedding of the published code (interleaved sin/cos, a 4x wide Mish MLP).
Masks work as in the default layout, so the variant stays exactly padding invariant.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from stablemo.errors import StableMoError
from stablemo.nets.conditioning import Conditioning, check_conditioning, check_step
from stablemo.nets.layers import (
    LinearCrossAttention,
    MaskedGroupNorm,
    SelfAttention,
    TimestepEmbedder,
    downsample_mask,
    masked_mean,
    sinusoidal_embedding,
    zero_pad_bct,
)

# Planned AdaGN tables hold S x B rows per residual block: for the 10-50 steps of the fast
# samplers, not for 1000-step DDPM (which then embeds each step as it comes).
MAX_PLANNED_STEPS = 64


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

    def adagn(self, emb: torch.Tensor) -> torch.Tensor:
        """AdaGN's projection of the embedding: (..., emb_dim) -> (..., 2 C_out) = [scale | shift]."""
        return self.emb(emb)

    def forward(self, x: torch.Tensor, adagn: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """x: (B, C_in, T); adagn: (B, 2 C_out) from `adagn(emb)`; mask: (B, T)."""
        scale, shift = adagn[:, :, None].chunk(2, dim=1)  # (B, C_out, 1) each
        h = F.mish(self.norm1(self.conv1(x), mask, 1 + scale, shift))  # AdaGN: norm(h) (1 + scale) + shift
        h = zero_pad_bct(h, mask)  # padded frames zero before the dropout and conv2
        return zero_pad_bct(F.mish(self.norm2(self.conv2(self.dropout(h)), mask)) + self.skip(x), mask)


class CrossAttention1D(nn.Module):
    """LinearCrossAttention applied to (B, C, T) feature maps; context: (B, H, d, d)."""

    def __init__(self, channels: int, text_dim: int, num_heads: int, dropout: float, out_proj: bool = True):
        super().__init__()
        self.attn = LinearCrossAttention(channels, text_dim, num_heads, dropout, out_proj)

    def forward(self, x: torch.Tensor, context: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return zero_pad_bct(self.attn(x.transpose(1, 2), context).transpose(1, 2), mask)


class TemporalSelfAttention1D(nn.Module):
    """Residual multi-head self-attention over the valid frames of a (B, C, T) feature map, with
    sinusoidal frame positions added to the attention's input (not to the residual).

    The convolutions see a window of frames and the cross-attention reads the text per frame, so
    nothing else lets distant frames agree on, e.g., how many jumps there are: trained without it
    the demo teacher gets counts right at an action's own length and repeats the action to fill a
    longer one. The output projection starts at zero (the block starts as the identity); padded
    keys get no weight and padded frames stay zero, so the network stays padding invariant."""

    def __init__(self, channels: int, num_heads: int, dropout: float):
        super().__init__()
        self.norm = nn.LayerNorm(channels)
        self.attn = SelfAttention(channels, num_heads, dropout)
        nn.init.zeros_(self.attn.out.weight)
        nn.init.zeros_(self.attn.out.bias)

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """x: (B, C, T) zero on padding; mask: (B, T) -> (B, C, T)."""
        h = x.transpose(1, 2)  # (B, T, C)
        frames = torch.arange(h.shape[1], device=h.device)
        h = self.norm(h) + sinusoidal_embedding(frames, h.shape[2]).to(h.dtype)[None]
        return zero_pad_bct(x + self.attn(h, mask).transpose(1, 2), mask)


class Stage(nn.Module):
    """Two residual blocks, each optionally followed by cross-attention; optionally a temporal
    self-attention after them (`self_attention` heads, 0 = none)."""

    def __init__(self, in_ch, out_ch, emb_dim, text_dim, *, kernel_size, num_groups, norm, dropout,
                 cross_attention, num_heads, out_proj=True, self_attention: int = 0):
        super().__init__()
        self.blocks = nn.ModuleList([
            ResBlock1D(in_ch, out_ch, emb_dim, kernel_size, num_groups, norm, dropout),
            ResBlock1D(out_ch, out_ch, emb_dim, kernel_size, num_groups, norm, dropout),
        ])
        self.attns = nn.ModuleList(
            [CrossAttention1D(out_ch, text_dim, num_heads, dropout, out_proj) for _ in range(2)]
            if cross_attention else []
        )
        self.self_attn = TemporalSelfAttention1D(out_ch, self_attention, dropout) if self_attention else None

    def forward(self, x, adagn: Sequence[torch.Tensor], contexts: Sequence[torch.Tensor], mask):
        """adagn: each block's (B, 2 C_out); contexts: each attention's (B, H, d, d)."""
        for i, block in enumerate(self.blocks):
            x = block(x, adagn[i], mask)
            if self.attns:
                x = self.attns[i](x, contexts[i], mask)
        if self.self_attn is not None:
            x = self.self_attn(x, mask)
        return x


@dataclass
class UNetConditioning(Conditioning):
    """CondUNet1D's per-request inputs. masks: the motion mask at each resolution (B, T / 2^i);
    pooled: (B, time_dim) text embedding added to the timestep's (None in the official layout);
    text_contexts: (B, H, d, d) per cross-attention layer of each stage, in `CondUNet1D.stages()`
    order; adagn: per stage, per block, the (S, B, 2 C) AdaGN projections of the S planned
    timesteps (None: not planned)."""

    masks: list[torch.Tensor]
    pooled: torch.Tensor | None
    text_contexts: list[list[torch.Tensor]]
    adagn: list[list[torch.Tensor]] | None


class CondUNet1D(nn.Module):
    """x: (B, T, input_dim), t: (B,), ctx from `prepare(text (B, L, text_dim), ...)` -> (B, T, input_dim)."""

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
        variant: str = "stablemo",
        input_head: int = 0,
        input_head_kernel: int = 1,
        mid_attention: int = 0,
        up_attention: Sequence[int] = (),
    ):
        super().__init__()
        if len(channel_mults) < 1:
            raise StableMoError("channel_mults: need at least one stage")
        if kernel_size % 2 == 0:
            raise StableMoError(f"kernel_size: must be odd to keep the length, got {kernel_size}")
        if input_head < 0 or (input_head and variant == "official"):
            raise StableMoError(f"input_head: a width >= 0, and 0 in the official layout, got {input_head}")
        if input_head_kernel < 1 or input_head_kernel % 2 == 0:
            raise StableMoError(f"input_head_kernel: must be odd and >= 1, got {input_head_kernel}")
        if mid_attention < 0 or (mid_attention and variant == "official"):
            raise StableMoError(f"mid_attention: a number of heads >= 0, and 0 in the official layout, got {mid_attention}")
        if mid_attention and (base_channels * channel_mults[-1]) % mid_attention:
            raise StableMoError(f"mid_attention: {base_channels * channel_mults[-1]} middle channels are not "
                                f"divisible by {mid_attention} heads")
        up_attention = tuple(up_attention)
        if up_attention and ((variant == "official" and any(up_attention)) or len(up_attention) > len(channel_mults)
                             or any(not isinstance(h, int) or isinstance(h, bool) or h < 0 for h in up_attention)):
            raise StableMoError(f"up_attention: heads >= 0 per up stage (at most {len(channel_mults)}, the first at the "
                                f"coarsest resolution), none in the official layout, got {list(up_attention)}")
        for k, heads in enumerate(up_attention):
            width = base_channels * channel_mults[len(channel_mults) - 1 - k]
            if heads and width % heads:
                raise StableMoError(f"up_attention: up stage {k} has {width} channels, not divisible by {heads} heads")
        if variant not in ("stablemo", "official"):
            raise StableMoError(f"variant: expected 'stablemo' or 'official' (the published T2MUnet's layout), got {variant!r}")
        official = variant == "official"
        self.input_dim, self.text_dim, self.variant = input_dim, text_dim, variant
        n = len(channel_mults)
        n_down = n if official else n - 1
        self.length_multiple = 2 ** n_down
        dims = [input_dim] + [base_channels * m for m in channel_mults]
        common = dict(kernel_size=kernel_size, num_groups=num_groups, norm=norm, dropout=dropout,
                      cross_attention=cross_attention, num_heads=num_heads, out_proj=not official)

        self.time_embed = TimestepEmbedder(time_dim, variant=variant)
        # pooled text joins the AdaGN embedding (not in the published network)
        self.text_embed = None if official else nn.Linear(text_dim, time_dim)

        self.down = nn.ModuleList(Stage(dims[i], dims[i + 1], time_dim, text_dim, **common) for i in range(n))
        self.downsample = nn.ModuleList(nn.Conv1d(dims[i + 1], dims[i + 1], 3, stride=2, padding=1) for i in range(n_down))
        # mid_attention: temporal self-attention at the coarsest resolution (T / length_multiple frames)
        self.mid = Stage(dims[-1], dims[-1], time_dim, text_dim, **common, self_attention=mid_attention)
        # up stage i (run from i = n-1 down to 0) concatenates the skip of down stage i; the
        # default up-samples after a stage (same width), the official layout before it (new width)
        up, upsample, ch = [], [], dims[-1]
        for i in reversed(range(n)):
            if official:
                upsample.append(nn.ConvTranspose1d(ch, dims[i + 1], 4, stride=2, padding=1))
                ch = dims[i + 1]
            # up_attention[k] heads after up stage k (k = n-1-i: the first at the coarsest resolution)
            heads = up_attention[n - 1 - i] if n - 1 - i < len(up_attention) else 0
            up.append(Stage(ch + dims[i + 1], dims[i + 1], time_dim, text_dim, **common, self_attention=heads))
            ch = dims[i + 1]
            if i > 0 and not official:
                upsample.append(nn.ConvTranspose1d(ch, ch, 4, stride=2, padding=1))
        self.up = nn.ModuleList(up)
        self.upsample = nn.ModuleList(upsample)
        self.upsample_first = official
        # the official head is the 1x1 convolution alone
        self.final_conv = None if official else nn.Conv1d(ch, ch, kernel_size, padding=kernel_size // 2)
        self.final_norm = None if official else MaskedGroupNorm(num_groups, ch, norm)
        # the input head: residual blocks over [last features | x_t], so the output is not confined
        # to the span of the top stage's few channels (which the input reaches only through one
        # convolution) and x_t's every dimension reaches it; kernel 1 maps each frame on its own
        # (its errors then differ from frame to frame: jitter), wider kernels see the neighbours
        self.input_stage = None
        if input_head:
            self.input_stage = Stage(ch + input_dim, input_head, time_dim, text_dim,
                                     **dict(common, kernel_size=input_head_kernel, cross_attention=False))
            ch = input_head
        self.out = nn.Conv1d(ch, input_dim, 1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def stages(self) -> list[Stage]:
        """The stages in the order forward runs them (down, middle, up, then the input head's)."""
        return [*self.down, self.mid, *self.up, *([self.input_stage] if self.input_stage is not None else [])]

    def prepare(self, text, text_mask, motion_mask, time_cond=None, timesteps=()) -> UNetConditioning:
        """Per-request work: masks per resolution, pooled text, attention contexts and, for planned
        timesteps, every step's AdaGN projections in one product per block (its weight is then read
        from memory once per request instead of once per step)."""
        check_conditioning(text, text_mask, motion_mask, self.text_dim)
        masks = [motion_mask]
        for _ in self.downsample:
            masks.append(downsample_mask(masks[-1]))
        pooled = None if self.text_embed is None else self.text_embed(masked_mean(text, text_mask))  # (B, time_dim)
        contexts = [[attn.attn.context(text, text_mask) for attn in stage.attns] for stage in self.stages()]
        timesteps = tuple(int(s) for s in timesteps)
        adagn = None
        if timesteps and time_cond is None and len(timesteps) <= MAX_PLANNED_STEPS:
            B = motion_mask.shape[0]
            steps = torch.tensor(timesteps, device=motion_mask.device).repeat_interleave(B)
            emb_all = self.time_embed(steps).view(len(timesteps), B, -1)  # (S, B, time_dim)
            if pooled is not None:
                emb_all = emb_all + pooled
            adagn = [[block.adagn(emb_all) for block in stage.blocks] for stage in self.stages()]
        else:
            timesteps = ()
        return UNetConditioning(motion_mask, time_cond, timesteps, masks, pooled, contexts, adagn)

    def step_adagn(self, t: torch.Tensor, ctx: UNetConditioning) -> list[list[torch.Tensor]]:
        """Every block's (B, 2 C) AdaGN input at this step: a row of the planned tables, or computed."""
        index = ctx.planned_index(t) if ctx.adagn is not None else None
        if index is not None:
            return [[table[index] for table in stage] for stage in ctx.adagn]
        emb = self.time_embed(t, ctx.time_cond)  # (B, time_dim)
        if ctx.pooled is not None:
            emb = emb + ctx.pooled
        return [[block.adagn(emb) for block in stage.blocks] for stage in self.stages()]

    def forward(self, x: torch.Tensor, t: torch.Tensor, ctx: UNetConditioning) -> torch.Tensor:
        check_step(x, t, ctx, self.input_dim, self.length_multiple)
        adagn = self.step_adagn(t, ctx)
        n = len(self.down)
        x_in = h = zero_pad_bct(x.transpose(1, 2), ctx.masks[0])  # (B, D, T)
        skips = []
        for i, stage in enumerate(self.down):
            h = stage(h, adagn[i], ctx.text_contexts[i], ctx.masks[i])
            skips.append(h)
            if i < len(self.downsample):
                h = self.resample(self.downsample[i], h, ctx.masks[i + 1])
        h = self.mid(h, adagn[n], ctx.text_contexts[n], ctx.masks[-1])
        for j, stage in enumerate(self.up):
            level = n - 1 - j  # the resolution of down stage `level`
            if self.upsample_first:
                h = self.resample(self.upsample[j], h, ctx.masks[level])
            h = stage(self.merge_skip(h, skips.pop()), adagn[n + 1 + j], ctx.text_contexts[n + 1 + j],
                      ctx.masks[level])
            if not self.upsample_first and j < len(self.upsample):
                h = self.resample(self.upsample[j], h, ctx.masks[level - 1])
        return self.output(h, x_in, adagn, ctx)

    def output(self, h: torch.Tensor, x_in: torch.Tensor, adagn, ctx: UNetConditioning) -> torch.Tensor:
        """The last features h (B, C, T) and the input as the first stage read it, x_in (B, D, T)
        with padded frames zero -> the output (B, T, D)."""
        if self.input_stage is None:
            return self.head(h, ctx.masks[0]).transpose(1, 2)
        mask = ctx.masks[0]
        z = torch.cat([self.features_head(h, mask), x_in], dim=1)
        z = self.input_stage(z, adagn[-1], ctx.text_contexts[-1], mask)
        return zero_pad_bct(self.out(z), mask).transpose(1, 2)

    def resample(self, conv: nn.Module, h: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """A down- or up-sampling convolution, its padded frames zeroed at the new resolution (mask)."""
        return zero_pad_bct(conv(h), mask)

    def merge_skip(self, h: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        """The up path's input: (B, C1, T), (B, C2, T) -> (B, C1 + C2, T)."""
        return torch.cat([h, skip], dim=1)

    def features_head(self, h: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """conv -> norm -> Mish on the last features (the official layout: none). (B, C, T) -> (B, C, T)."""
        if self.final_conv is not None:
            h = zero_pad_bct(F.mish(self.final_norm(self.final_conv(h), mask)), mask)
        return h

    def head(self, h: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """The output head without an input head: `features_head`, then the zero-initialised 1x1
        conv. (B, C, T) -> (B, D, T)."""
        return zero_pad_bct(self.out(self.features_head(h, mask)), mask)
