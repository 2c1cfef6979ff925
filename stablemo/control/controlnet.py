"""A motion ControlNet for every denoiser (MotionLCM's control, Dai et al. 2024 Sec. 3.3, in motion space).

- `HintEncoder`: per-frame hint (masked global joint positions + the mask, (B, T, 4 J), and with
  `path=True` the targets' path channels, (B, T, 12 J): hints.py) ->
  convolutions over time -> a zero-initialised 1x1 projection to the feature width. In motion
  space the hint already has a time axis, so MotionLCM's trajectory transformer with its global
  token (needed for MLD's time-less latent) is not needed.
- `UNetControlNet` (CondUNet1D): a trainable copy of the frozen UNet's encoder half (time/text
  embeddings, down stages, down-samplings, middle stage), fed x_t plus the encoded hint, and one
  zero-initialised 1x1 convolution per down stage and for the middle stage. Their outputs are
  added to the frozen network's skip features and middle output.
- `TokenControlNet` (DiT, RetNet): a trainable copy of the input embedding and of the first half
  of the blocks, its frame tokens plus the encoded hint, and one zero-initialised linear layer per
  copied block; their outputs are added to the frame tokens the frozen blocks put out (the
  ControlNet-Transformer form: the transformers have no skips to inject into).
- `root_only` (UNet): a copy of the first stage only (with the time and text embeddings), whose
  zero-initialised 1x1 convolutions set the root's feature channels (a rotation velocity, a
  velocity in the body's frame, a height: where the body goes) and nothing else. Its rotation
  output is a facing per frame, a vector on the floor ((0, 1): the base's own), whose turn from
  one frame to the next is added to the rotation velocity (`heading_scale`: normalised
  rotation-velocity units per radian), so that facing a path's direction is a per-frame reading
  of the hint's direction channels (a vector too: no angle to wrap) rather than a sum over every
  earlier frame, which a network with a short receptive field cannot keep (tried first: it walked
  the right gait in the wrong direction, 1.3-2.3 m off the path on mean). With `floor_steps` its
  velocity is likewise a step on the floor, turned into the body's frame by its own heading
  (`FloorSteps`): the path is then the sum of per-frame readings of the hint's velocity, not of
  velocities that only sum to the path once turned by a heading summed over every earlier frame
  (without it the path drifted 26-101 cm from its hint on mean). With `toward_targets` too, each
  step starts as the base's own step length along the line to the pelvis's next target
  (`hints.toward_next_target`), and the output also reads that line's velocity: a step left in the
  base's direction had to be turned by the network, which fell short on paths setting off away
  from where the base walks (20-70 cm off). The frozen network
  runs unchanged, so the body is its base's as generated: the legs keep their gait and the contact
  channels their phase, and the finishing step plants the feet as for a free motion. A full
  ControlNet trained from t = 999 against the clip learns the average over gait phases, the legs
  blurred and the contact channels flat, and its stance feet slid 2-2.6x the free walk's (issue #41).
- `make_controlnet(denoiser, ...)` picks the form; each has `prepare`, `residuals` and `run_base`
  (the frozen network's forward with the residuals added, through the network's named steps).
- `ControlledModel`: the frozen base (a MotionDiffusionModel or a ConsistencyStudent) and its
  ControlNet, with the base's `prepare`/`denoise` contract plus a hint.

At initialisation every injection is exactly zero, so a controlled model is its base (with
`toward_targets`, its base's steps pointed at the targets: the base's gait and pace). A sample
whose hint has no target gets no injection at all (a per-sample gate), so a free prompt served by a
controlled bundle is exactly its base's motion, and a batch mixing free and controlled prompts
gives each the motion it would get alone. Every operator masks padded frames, so the controlled
model stays exactly padding invariant.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from stablemo.control.hints import PATH_SCALE, hint_channels, toward_next_target
from stablemo.errors import StableMoError
from stablemo.motion.quaternion import qinv, qrot
from stablemo.nets.conditioning import Conditioning, check_conditioning
from stablemo.nets.dit import DiT
from stablemo.nets.layers import masked_mean, zero_pad_bct, zero_pad_btc
from stablemo.nets.retnet import RetNet
from stablemo.nets.unet import CondUNet1D, UNetConditioning

# HumanML3D and KIT features start with the root's: rotation velocity (1), velocity in the body's
# frame (x, z), height -- what a root_only ControlNet sets
ROOT_CHANNELS = 4


def _zeroed(layer: nn.Module) -> nn.Module:
    """A zero-initialised injection (weight and bias): the controlled model starts as its base."""
    nn.init.zeros_(layer.weight)
    nn.init.zeros_(layer.bias)
    return layer


class HintEncoder(nn.Module):
    """hint (B, T, hint_dim), motion_mask (B, T) -> (B, out_dim, T), zero on padding (and, at
    initialisation, everywhere: the last layer is a zero 1x1 convolution)."""

    def __init__(self, hint_dim: int, out_dim: int, channels: int = 64, layers: int = 3, kernel_size: int = 3):
        super().__init__()
        dims = [hint_dim] + [channels] * layers
        self.convs = nn.ModuleList(nn.Conv1d(dims[i], dims[i + 1], kernel_size, padding=kernel_size // 2)
                                   for i in range(layers))
        self.out = _zeroed(nn.Conv1d(channels, out_dim, 1))

    def features(self, hint: torch.Tensor, motion_mask: torch.Tensor) -> torch.Tensor:
        """The hidden features before the projection: (B, channels, T), zero on padding."""
        h = zero_pad_bct(hint.transpose(1, 2), motion_mask)  # (B, hint_dim, T)
        for conv in self.convs:  # padded frames zero before every temporal convolution
            h = zero_pad_bct(F.mish(conv(h)), motion_mask)
        return h

    def forward(self, hint: torch.Tensor, motion_mask: torch.Tensor) -> torch.Tensor:
        return zero_pad_bct(self.out(self.features(hint, motion_mask)), motion_mask)


def _encoder_copy(unet: CondUNet1D) -> CondUNet1D:
    """A trainable copy of `unet` with its decoder removed: its `stages()` are then the down stages
    and the middle, so its own `prepare`/`step_adagn` cover exactly the encoder half. It trains
    (dropout on) even when the base was frozen in eval mode."""
    enc = copy.deepcopy(unet)
    enc.up, enc.upsample = nn.ModuleList(), nn.ModuleList()
    enc.final_conv = enc.final_norm = None
    enc.out = nn.Identity()
    return enc.requires_grad_(True).train()


class _FirstStageCopy(nn.Module):
    """A trainable copy of a CondUNet1D's time and text embeddings and its first down stage, with
    the network's `prepare`/`step_adagn` contract for that one stage (a root_only ControlNet's
    copy: full resolution, no down-sampling)."""

    def __init__(self, unet: CondUNet1D):
        super().__init__()
        self.text_dim = unet.text_dim
        self.time_embed = copy.deepcopy(unet.time_embed)
        self.text_embed = copy.deepcopy(unet.text_embed)
        self.stage = copy.deepcopy(unet.down[0])
        self.requires_grad_(True).train()

    def prepare(self, text, text_mask, motion_mask, time_cond=None, timesteps=()) -> UNetConditioning:
        check_conditioning(text, text_mask, motion_mask, self.text_dim)
        pooled = None if self.text_embed is None else self.text_embed(masked_mean(text, text_mask))  # (B, time_dim)
        contexts = [[attn.attn.context(text, text_mask) for attn in self.stage.attns]]
        return UNetConditioning(motion_mask, time_cond, (), [motion_mask], pooled, contexts, None)

    def step_adagn(self, t: torch.Tensor, ctx: UNetConditioning) -> list[list[torch.Tensor]]:
        emb = self.time_embed(t, ctx.time_cond)  # (B, time_dim)
        if ctx.pooled is not None:
            emb = emb + ctx.pooled
        return [[block.adagn(emb) for block in self.stage.blocks]]


@dataclass
class Residuals:
    """What a ControlNet adds to its frozen network at one step: `inner`, one tensor per injection
    point inside the network (UNet: each skip (B, C_i, T_i), then the middle; DiT/RetNet: each copied
    block's frame tokens (B, T, C)), `output` (B, T, D) added to its output and `output_scale`
    (B, T, D) scaling it first (out * (1 + scale) + output: where the hint determines a channel the
    ControlNet can replace the base's value instead of correcting it blind), each or None."""

    inner: list[torch.Tensor]
    output: torch.Tensor | None = None
    output_scale: torch.Tensor | None = None
    steps: FloorSteps | None = None

    def apply_output(self, out: torch.Tensor) -> torch.Tensor:
        """The network's output (B, T, D) with the output injection: out * (1 + output_scale) + output,
        then (with `steps`) the root's velocity from its steps on the floor."""
        base = out
        if self.output_scale is not None:
            out = out + out * self.output_scale
        out = out if self.output is None else out + self.output
        return out if self.steps is None else self.steps.apply(base, out)


@dataclass
class FloorSteps:
    """A root_only ControlNet's velocity as the root's step on the floor (world frame, from frame t
    to t + 1), so that the path, the sum of the steps, is a per-frame reading of the hint's
    velocity channels whatever the body's facing (a velocity in the body's frame must be turned by
    the facing summed over every earlier frame: the first root_only ControlNet's path drifted
    26-101 cm from its hint on mean, issue #41). The step is the base's own, turned onto the
    floor by the base's heading, times (1 + scale) plus shift ((B, T, 2) each, (x, z), zero at
    initialisation: the base's velocity back), in PATH_SCALE units (m/s at 20 fps, as the hint's
    velocity channels); it is turned into the body's frame by the output's heading (the one the
    recovery will use, stablemo.motion.features.recover_root). gate (B, 1, 1), mask (B, T): where
    it applies; mean/std (3,): the model's statistics of the root's first three channels; toward
    (B, T, 2) or None: a unit direction to the next target per frame (zero where none), along
    which the base's step is laid at its own length before scale (then along and across that
    line) and shift act."""

    shift: torch.Tensor
    scale: torch.Tensor
    gate: torch.Tensor
    mask: torch.Tensor
    mean: torch.Tensor
    std: torch.Tensor
    toward: torch.Tensor | None = None  # (B, T, 2) unit direction to the next target, zero where none

    def _headings(self, out: torch.Tensor) -> torch.Tensor:
        """(B, T, 4) recover_root's yaw quaternion of frame t + 1, the one velocity t is seen from
        (its angle: the sum of rotation velocities 0..t)."""
        angle = torch.cumsum(out[..., 0] * self.std[0].to(out) + self.mean[0].to(out), 1)
        zero = torch.zeros_like(angle)
        return torch.stack([torch.cos(angle), zero, torch.sin(angle), zero], -1)

    def apply(self, base: torch.Tensor, out: torch.Tensor) -> torch.Tensor:
        """base, out (B, T, D) normalised: the network's output, and with the other injections ->
        out with channels 1, 2 (the body-frame velocity) from the steps, on gated valid frames. In float32
        whatever the network's precision: the heading is a sum over every earlier frame."""
        dtype, base, out = out.dtype, base.float(), out.float()
        mean, std = self.mean[1:3].to(out), self.std[1:3].to(out)
        v = (base[..., 1:3] * std + mean) * PATH_SCALE  # (B, T, 2) the base's velocity, body frame
        own = qrot(qinv(self._headings(base)), _on_floor(v))[..., 0::2]  # (B, T, 2) its step on the floor
        if self.toward is None:
            step = own * (1 + self.scale.float()) + self.shift.float()
        else:
            # the base's step at its own length, pointed at the next target where there is one;
            # scale then changes the pace along that line (0) and steps across it (1)
            length = own.norm(dim=-1, keepdim=True)  # (B, T, 1)
            known = self.toward.float().norm(dim=-1, keepdim=True) > 0.5
            u = torch.where(known, self.toward.float(), own / length.clamp(min=1e-6))  # (B, T, 2)
            across = torch.stack([u[..., 1], -u[..., 0]], -1)
            scale = self.scale.float()
            step = length * ((1 + scale[..., :1]) * u + scale[..., 1:] * across) + self.shift.float()
        step = step / PATH_SCALE  # (B, T, 2) dataset units per frame
        local = qrot(self._headings(out), _on_floor(step))[..., 0::2]  # (B, T, 2) seen from the output's heading
        use = (self.mask[..., None] & (self.gate > 0)).expand_as(local)
        return torch.cat([out[..., :1], torch.where(use, (local - mean) / std, out[..., 1:3]), out[..., 3:]], -1).to(dtype)


def _on_floor(xz: torch.Tensor) -> torch.Tensor:
    """(..., 2) x, z -> (..., 3) x, 0, z."""
    return torch.stack([xz[..., 0], torch.zeros_like(xz[..., 0]), xz[..., 1]], -1)


@dataclass
class ControlConditioning(Conditioning):
    """A controlled step's per-request inputs: the frozen network's context, the copy's, the
    encoded hint (B, D, T) (constant over the steps of a request, so encoded once) and the gate
    (B, 1, 1): 1 where the sample has at least one target, else 0 (no injection)."""

    base: Conditioning
    copy: Conditioning | None  # None (and hint None): no sample has a target, the base runs alone
    hint: torch.Tensor | None
    gate: torch.Tensor


class _ControlNetBase(nn.Module):
    """What both forms share: the hint encoder, the hint check and the per-sample gate. Subclasses
    set `self.encoder` (the trainable copy, with the base's `prepare`)."""

    encoder: nn.Module

    def __init__(self, joints: int, hint_width: int, channels: int, layers: int, path: bool):
        super().__init__()
        self.joints, self.path = int(joints), bool(path)
        self.hint_width = hint_channels(self.joints, self.path)
        self.hint_encoder = HintEncoder(self.hint_width, hint_width, channels, layers)

    def prepare(self, text, text_mask, motion_mask, time_cond, timesteps,
                hint) -> tuple[Conditioning, torch.Tensor, torch.Tensor]:
        """(the copy's context, the encoded hint (B, C, T), the gate (B, 1, 1)); hint: (B, T, 4 J) or
        (B, T, 12 J) with the path channels. At inference, a batch without any target gets (None,
        None, zeros): the base runs alone (the gate would multiply every injection by 0)."""
        if hint.shape != (*motion_mask.shape, self.hint_width):
            raise StableMoError(f"hint: expected shape {(*motion_mask.shape, self.hint_width)}, got {tuple(hint.shape)}")
        targets = hint[..., 3 * self.joints:] * motion_mask[..., None]  # (B, T, J): the mask channels on valid frames
        gate = (targets.flatten(1) > 0).any(1).to(text.dtype)[:, None, None]  # (B, 1, 1)
        if not self.training and not bool(gate.any()):
            return None, None, gate  # no sample has a target: nothing to inject, the copy need not run
        ctx = self.encoder.prepare(text, text_mask, motion_mask, time_cond, timesteps)
        return ctx, self.encode_hint(hint.to(text.dtype), motion_mask), gate

    def encode_hint(self, hint: torch.Tensor, motion_mask: torch.Tensor) -> torch.Tensor:
        """What a request's steps read of the hint (B, C, T): the encoded hint."""
        return self.hint_encoder(hint, motion_mask)


class UNetControlNet(_ControlNetBase):
    """unet: the frozen network to control (its encoder half is copied now, with its weights);
    joints: J of the skeleton; channels/layers: the hint encoder's; path: the hint carries the
    targets' path channels (hints.py); output: one more zero-initialised 1x1 convolution, from the
    copy's full-resolution features straight onto the network's output, so the hint can set output
    channels (the root's) by a near-linear path instead of only through the frozen decoder;
    output_scale: one more, scaling the network's output per frame and channel before that shift
    (zero-initialised too), so the injection can replace the base's value of a channel the hint
    determines rather than add to a value it cannot see (the base's output at t = 999 depends on the
    noise); root_only: the first stage's copy and the output injections onto the root's channels
    only, nothing inside the network, the rotation as a facing vector's turns times heading_scale
    (see the module docstring; output and output_scale both on)."""

    def __init__(self, unet: CondUNet1D, joints: int, channels: int = 64, layers: int = 3, path: bool = False,
                 output: bool = False, output_scale: bool = False, root_only: bool = False,
                 heading_scale: float | None = None, floor_steps: dict | None = None, toward_targets: bool = False):
        super().__init__(joints, unet.input_dim, channels, layers, path)
        self.root_only = bool(root_only)
        if self.root_only != (heading_scale is not None) or (root_only and not float(heading_scale) > 0):
            raise StableMoError("controlnet.control: root_only needs heading_scale > 0 (normalised rotation-velocity "
                                "units per radian: 1 / the base's rotation-velocity std) and nothing else does; "
                                f"got root_only {root_only}, heading_scale {heading_scale}")
        self.heading_scale = None if heading_scale is None else float(heading_scale)
        self.floor_steps = None
        if floor_steps is not None:
            self.floor_steps = _root_stats(floor_steps, root_only)
        if toward_targets and self.floor_steps is None:
            raise StableMoError("controlnet.control: toward_targets points the root's steps on the floor; it needs floor_steps")
        self.toward_targets = bool(toward_targets)
        widths = [stage.blocks[-1].conv2.out_channels for stage in unet.down]
        self.input_dim = unet.input_dim
        if self.root_only:
            if not (output and output_scale):
                raise StableMoError("controlnet.control: root_only sets the root's channels through the output "
                                    "injections; give it output: true and output_scale: true")
            self.encoder = _FirstStageCopy(unet)
            # the base never sees the hint here (the zero out_conv keeps the start exact), so the
            # copy may see it from the first step: a zero projection would also hold back its gradient
            nn.init.kaiming_uniform_(self.hint_encoder.out.weight, a=5 ** 0.5)
            # and the output reads the hint itself and its features too, straight (the facing is a
            # per-frame reading of its direction channels, a linear one from the hint; through the
            # copy it competes with x_t's noise)
            # (toward_targets: and the chord to the pelvis's next target, its velocity and whether there is one)
            self.hint_out = _zeroed(nn.Conv1d(channels + self.hint_width + 3 * self.toward_targets, ROOT_CHANNELS + 1, 1))
            self.skip_convs, self.mid_conv = nn.ModuleList(), None
            out_dim = ROOT_CHANNELS + 1  # the facing vector in place of the rotation: one more
        else:
            self.encoder = _encoder_copy(unet)
            self.skip_convs = nn.ModuleList(_zeroed(nn.Conv1d(c, c, 1)) for c in widths)
            self.mid_conv = _zeroed(nn.Conv1d(widths[-1], widths[-1], 1))
            out_dim = unet.input_dim
        self.out_conv = _zeroed(nn.Conv1d(widths[0], out_dim, 1)) if output else None
        self.out_scale_conv = _zeroed(nn.Conv1d(widths[0], ROOT_CHANNELS if root_only else out_dim, 1)) if output_scale else None

    def encode_hint(self, hint: torch.Tensor, motion_mask: torch.Tensor) -> torch.Tensor:
        """The encoded hint (B, D, T); root_only: the hint encoder's features and the hint itself
        (B, channels + hint width, T): the copy's input projection reads the first, the output both."""
        if self.root_only:
            raw = zero_pad_bct(hint.transpose(1, 2), motion_mask)
            return torch.cat([self.hint_encoder.features(hint, motion_mask), raw], 1)
        return self.hint_encoder(hint, motion_mask)

    def residuals(self, x: torch.Tensor, t: torch.Tensor, ctx: Conditioning, hint: torch.Tensor,
                  gate: torch.Tensor) -> Residuals:
        """The injections: one (B, C_i, T_i) per down stage (into its skip), then the middle's, and
        (with `output`) the output's (B, T, D); each times the gate (B, 1, 1), so a sample without
        targets gets exact zeros."""
        if self.root_only:
            return self._root_residuals(x, t, ctx, hint, gate)
        enc = self.encoder
        adagn = enc.step_adagn(t, ctx)
        h = zero_pad_bct(x.transpose(1, 2), ctx.masks[0]) + hint  # (B, D, T)
        out, to_output, scale = [], None, None
        for i, stage in enumerate(enc.down):
            h = stage(h, adagn[i], ctx.text_contexts[i], ctx.masks[i])
            out.append(zero_pad_bct(self.skip_convs[i](h), ctx.masks[i]) * gate)
            if i == 0:
                to_output = _frames_out(self.out_conv, h, ctx.masks[0], gate)
                scale = _frames_out(self.out_scale_conv, h, ctx.masks[0], gate)
            if i < len(enc.downsample):
                h = enc.resample(enc.downsample[i], h, ctx.masks[i + 1])
        n = len(enc.down)
        h = enc.mid(h, adagn[n], ctx.text_contexts[n], ctx.masks[-1])
        out.append(zero_pad_bct(self.mid_conv(h), ctx.masks[-1]) * gate)
        return Residuals(out, to_output, scale)

    def _root_residuals(self, x: torch.Tensor, t: torch.Tensor, ctx: Conditioning, hint: torch.Tensor,
                        gate: torch.Tensor) -> Residuals:
        """root_only: no inner injection; the output's shift and scale (B, T, D), zero but on the
        root's channels, times the gate. hint: encode_hint's (B, channels + hint width, T)."""
        mask = ctx.masks[0]
        features = hint[:, :self.hint_encoder.out.in_channels]  # (B, channels, T)
        toward = None
        if self.toward_targets:  # the pelvis's targets, read off the raw hint: x, z and the mask
            raw = hint[:, features.shape[1]:].float()  # (B, hint width, T); float32: a chord spans many frames
            toward, speed = toward_next_target(raw[:, [0, 2]].transpose(1, 2), raw[:, 3 * self.joints] > 0.5)
            chord = torch.cat([toward * speed[..., None], (speed > 0)[..., None].float()], -1)  # (B, T, 3)
            hint = torch.cat([hint, zero_pad_bct(chord.transpose(1, 2).to(hint.dtype), mask)], 1)
        h = zero_pad_bct(x.transpose(1, 2), mask) + zero_pad_bct(self.hint_encoder.out(features), mask)
        h = self.encoder.stage(h, self.encoder.step_adagn(t, ctx)[0], ctx.text_contexts[0], mask)
        out = _frames_out(self.out_conv, h, mask, gate) + _frames_out(self.hint_out, hint, mask, gate)  # (B, T, 5)
        # channels 0, 1: a facing vector (x, z), (0, 1) at rest; the rotation velocity of frame t
        # turns frame t into frame t + 1, so it gains the facing's turn from t to t + 1 (rad; none
        # on the last valid frame)
        face = torch.stack([out[..., 0], 1.0 + out[..., 1]], -1)  # (B, T, 2)
        follows = F.pad(mask[:, 1:], (0, 1))  # (B, T): frame t + 1 is valid
        after = torch.where(follows[..., None], F.pad(face[:, 1:], (0, 0, 0, 1)), face)
        turn = torch.atan2(face[..., 0] * after[..., 1] - face[..., 1] * after[..., 0], (face * after).sum(-1))  # (B, T)
        shift = torch.cat([(turn * self.heading_scale)[..., None], out[..., 2:]], -1)  # (B, T, 4)
        scale = _frames_out(self.out_scale_conv, h, mask, gate)  # (B, T, 4)
        steps = None
        if self.floor_steps is not None:  # the velocity's shift and scale act on the step on the floor
            steps = FloorSteps(shift[..., 1:3], scale[..., 1:3], gate, mask, *self.floor_steps, toward=toward)
            keep = torch.tensor([1.0, 0.0, 0.0, 1.0], device=shift.device, dtype=shift.dtype)
            shift, scale = shift * keep, scale * keep
        pad = (0, self.input_dim - ROOT_CHANNELS)
        return Residuals([], F.pad(shift, pad), F.pad(scale, pad), steps)

    @staticmethod
    def run_base(unet: CondUNet1D, x: torch.Tensor, t: torch.Tensor, ctx: Conditioning,
                 residuals: Residuals) -> torch.Tensor:
        """CondUNet1D.forward with the residuals added to each skip, to the middle output and to
        the output (the same named steps, so a fast network keeps its fused pieces); no inner
        residuals (root_only): the network as it is, then the output's. x: (B, T, D)."""
        if not residuals.inner:
            return residuals.apply_output(unet(x, t, ctx))
        inner = residuals.inner
        adagn = unet.step_adagn(t, ctx)
        n = len(unet.down)
        x_in = h = zero_pad_bct(x.transpose(1, 2), ctx.masks[0])
        skips = []
        for i, stage in enumerate(unet.down):
            h = stage(h, adagn[i], ctx.text_contexts[i], ctx.masks[i])
            skips.append(h + inner[i])
            if i < len(unet.downsample):
                h = unet.resample(unet.downsample[i], h, ctx.masks[i + 1])
        h = unet.mid(h, adagn[n], ctx.text_contexts[n], ctx.masks[-1]) + inner[n]
        for j, stage in enumerate(unet.up):
            level = n - 1 - j
            if unet.upsample_first:
                h = unet.resample(unet.upsample[j], h, ctx.masks[level])
            h = stage(unet.merge_skip(h, skips.pop()), adagn[n + 1 + j], ctx.text_contexts[n + 1 + j], ctx.masks[level])
            if not unet.upsample_first and j < len(unet.upsample):
                h = unet.resample(unet.upsample[j], h, ctx.masks[level - 1])
        return residuals.apply_output(unet.output(h, x_in, adagn, ctx))  # (B, T, D)


def _root_stats(floor_steps: dict, root_only: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """control.floor_steps {mean: [3], std: [3]} (the base's statistics of the root's first three
    channels) -> (mean, std) tensors, checked."""
    what = "controlnet.control.floor_steps"
    if not root_only:
        raise StableMoError(f"{what}: only a root_only ControlNet predicts the root's steps on the floor")
    if not isinstance(floor_steps, dict) or set(floor_steps) != {"mean", "std"}:
        raise StableMoError(f"{what}: expected {{mean: [3 numbers], std: [3 numbers]}}, got {floor_steps!r}")
    try:
        mean, std = (torch.tensor([float(v) for v in floor_steps[k]]) for k in ("mean", "std"))
    except (TypeError, ValueError):
        raise StableMoError(f"{what}: mean and std must be lists of 3 numbers, got {floor_steps!r}") from None
    if mean.shape != (3,) or std.shape != (3,) or not bool(torch.isfinite(mean).all()) or not bool((std > 0).all()):
        raise StableMoError(f"{what}: mean and std must be 3 finite numbers, std > 0, got {floor_steps!r}")
    return mean, std


def _block_copy(net: nn.Module, blocks: int) -> nn.Module:
    """A trainable copy of a DiT/RetNet keeping its input embedding and its first `blocks` blocks
    (its own `prepare` then plans just those blocks' text contexts); no read-out."""
    enc = copy.deepcopy(net)
    enc.blocks = enc.blocks[:blocks]
    enc.final_norm = enc.out = None
    if hasattr(enc, "final_ada"):
        enc.final_ada = None
    return enc.requires_grad_(True).train()


class TokenControlNet(_ControlNetBase):
    """net: the frozen DiT or RetNet (its embedding and first `blocks` blocks, default half, are
    copied now); joints, channels, layers, path, output as for the UNet (output: from the last
    copied block's frame tokens). The hint is added to the copy's frame tokens; residual i goes onto
    the frame tokens of the frozen block i's output."""

    def __init__(self, net: nn.Module, joints: int, channels: int = 64, layers: int = 3, path: bool = False,
                 output: bool = False, output_scale: bool = False, blocks: int | None = None):
        super().__init__(joints, net.latent_dim, channels, layers, path)
        n = len(net.blocks)
        blocks = (n + 1) // 2 if blocks is None else int(blocks)
        if not 1 <= blocks <= n:
            raise StableMoError(f"controlnet.blocks: need 1..{n} for this network, got {blocks}")
        self.encoder = _block_copy(net, blocks)
        self.block_out = nn.ModuleList(_zeroed(nn.Linear(net.latent_dim, net.latent_dim)) for _ in range(blocks))
        self.out_linear = _zeroed(nn.Linear(net.latent_dim, net.input_dim)) if output else None
        self.out_scale_linear = _zeroed(nn.Linear(net.latent_dim, net.input_dim)) if output_scale else None

    def residuals(self, x: torch.Tensor, t: torch.Tensor, ctx: Conditioning, hint: torch.Tensor,
                  gate: torch.Tensor) -> Residuals:
        """One (B, T, C) per copied block and (with `output`) the output's (B, T, D), times the
        gate; hint: (B, C, T) encoded."""
        enc, mask = self.encoder, ctx.motion_mask
        h, layout = enc.embed(x, t, ctx)
        h = _add_to_frames(h, hint.transpose(1, 2))
        out = []
        for i in range(len(enc.blocks)):
            h = enc.block(i, h, layout, ctx)
            out.append(zero_pad_btc(self.block_out[i](h[:, -mask.shape[1]:]), mask) * gate)
        frames = h[:, -mask.shape[1]:]
        to_output, scale = (None if layer is None else zero_pad_btc(layer(frames), mask) * gate
                            for layer in (self.out_linear, self.out_scale_linear))
        return Residuals(out, to_output, scale)

    @staticmethod
    def run_base(net: nn.Module, x: torch.Tensor, t: torch.Tensor, ctx: Conditioning,
                 residuals: Residuals) -> torch.Tensor:
        """The frozen network's forward with residual i added to block i's frame tokens and the
        output residual to its output. x: (B, T, D)."""
        h, layout = net.embed(x, t, ctx)
        for i in range(len(net.blocks)):
            h = net.block(i, h, layout, ctx)
            if i < len(residuals.inner):
                h = _add_to_frames(h, residuals.inner[i])
        return residuals.apply_output(net.readout(h, layout, ctx))


def _frames_out(conv: nn.Module | None, h: torch.Tensor, mask: torch.Tensor, gate: torch.Tensor) -> torch.Tensor | None:
    """An output injection from full-resolution features h (B, C, T): conv(h), zero on padding,
    times the gate, as (B, T, D); None without the layer."""
    return None if conv is None else (zero_pad_bct(conv(h), mask) * gate).transpose(1, 2)


def _add_to_frames(h: torch.Tensor, frames: torch.Tensor) -> torch.Tensor:
    """h: (B, S, C) tokens whose last T are the frames; frames: (B, T, C) added to those."""
    T = frames.shape[1]
    return torch.cat([h[:, :-T], h[:, -T:] + frames], dim=1) if h.shape[1] > T else h + frames


def make_controlnet(denoiser: nn.Module, joints: int, **control) -> _ControlNetBase:
    """The ControlNet form for `denoiser` (a CondUNet1D, DiT or RetNet), with its copy made now;
    control: channels, layers, path, output, output_scale (and root_only, heading_scale, floor_steps,
    toward_targets for a UNet,
    blocks for a DiT/RetNet)."""
    if isinstance(denoiser, CondUNet1D):
        form, known = UNetControlNet, {"channels", "layers", "path", "output", "output_scale", "root_only",
                                       "heading_scale", "floor_steps", "toward_targets"}
    elif isinstance(denoiser, (DiT, RetNet)):
        form, known = TokenControlNet, {"channels", "layers", "path", "output", "output_scale", "blocks"}
    else:
        raise StableMoError(f"controlnet: a {type(denoiser).__name__} denoiser cannot be controlled "
                            "(supported: unet, dit, retnet)")
    unknown = sorted(set(control) - known)
    if unknown:
        raise StableMoError(f"controlnet.control: unknown key(s) {unknown} for a {type(denoiser).__name__} "
                            f"(known: {sorted(known)})")
    return form(denoiser, joints, **control)


class ControlledModel(nn.Module):
    """A frozen base model plus its ControlNet.

    base: a MotionDiffusionModel ("diffusion") or a ConsistencyStudent ("consistency"); control:
    the ControlNet's kwargs (make_controlnet); joints: J. `prepare(text, text_mask, motion_mask,
    cond, timesteps, hint)` takes the base's own condition (`time_cond` for a diffusion model, the
    guidance w (B,) for a student) and the hint (B, T, 4 J or 12 J); `denoise(x, t, ctx)` as the base's.
    """

    def __init__(self, base: nn.Module, base_kind: str, joints: int, control: dict | None = None):
        super().__init__()
        if base_kind not in ("diffusion", "consistency"):
            raise StableMoError(f"controlnet.base_kind: expected 'diffusion' or 'consistency', got {base_kind!r}")
        self.base, self.base_kind = base, base_kind
        self.control = make_controlnet(self.denoiser, joints, **dict(control or {}))

    @property
    def net(self) -> nn.Module:
        """The base's MotionDiffusionModel (a student wraps its teacher's network)."""
        return self.base.model if self.base_kind == "consistency" else self.base

    @property
    def denoiser(self) -> nn.Module:
        return self.net.denoiser

    @property
    def length_multiple(self) -> int:
        return self.net.length_multiple

    @property
    def joints(self) -> int:
        return self.control.joints

    def encode_text(self, texts: list[str]):
        return self.base.encode_text(texts)

    def time_cond(self, cond: torch.Tensor | None) -> torch.Tensor | None:
        """The features added to the timestep's: a student's embedded guidance w, else cond itself."""
        return self.base.guidance_features(cond) if self.base_kind == "consistency" and cond is not None else cond

    def prepare(self, text, text_mask, motion_mask, cond=None, timesteps=(), hint=None) -> ControlConditioning:
        """hint None: the empty hint (no targets), as for a prompt without control."""
        if hint is None:
            hint = torch.zeros(*motion_mask.shape, self.control.hint_width, device=motion_mask.device)
        time_cond = self.time_cond(cond)
        base = self.net.prepare(text, text_mask, motion_mask, time_cond, timesteps)
        copy_ctx, encoded, gate = self.control.prepare(text, text_mask, motion_mask, time_cond, timesteps, hint)
        return ControlConditioning(motion_mask, time_cond, base.timesteps, base, copy_ctx, encoded, gate)

    def base_forward(self, x, t, text, text_mask, motion_mask, cond=None) -> torch.Tensor:
        """The frozen base alone, as a request without targets gets it (training's recon_target
        "base" reconstructs it)."""
        return self.net.denoise(x, t, self.net.prepare(text, text_mask, motion_mask, self.time_cond(cond), ()))

    def denoise(self, x, t, ctx: ControlConditioning) -> torch.Tensor:
        if ctx.copy is None:  # no targets in the batch (a free prompt): the base alone, at its cost
            return self.net.denoise(x, t, ctx.base)
        residuals = self.control.residuals(x, t, ctx.copy, ctx.hint, ctx.gate)
        return self.control.run_base(self.denoiser, x, t, ctx.base, residuals)

    def forward(self, x, t, text, text_mask, motion_mask, hint, cond=None) -> torch.Tensor:
        """One call with its own conditioning (training)."""
        return self.denoise(x, t, self.prepare(text, text_mask, motion_mask, cond, (), hint))
