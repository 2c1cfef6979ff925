"""Model kinds: what the pipeline needs to know of each kind of trained bundle.

A bundle's `config.json` names its kind ("diffusion", "consistency", ...). The kind supplies the
network built from the config, the table of samplers it can run, and the denoiser a request
samples with (classifier-free guidance for a diffusion model, one conditional pass with the
guidance scale embedded for a consistency student). Adding a kind is one class and one line in
MODEL_KINDS; the pipeline has no branch on the kind.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable, Protocol

import torch
from torch import nn

from stablemo.diffusion.samplers import SAMPLER_TABLE, Sampler
from stablemo.diffusion.schedule import NoiseSchedule
from stablemo.errors import StableMoError

if TYPE_CHECKING:
    from stablemo.inference.pipeline import Pipeline

Denoise = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


@dataclass
class ControlTargets:
    """A batch's joint targets as the pipeline resolved them from the requests' JointControl specs:
    targets (B, T, J, 3) in dataset units, zero where free; mask (B, T, J) bool. A kind that reads
    them (a ControlNet) takes them in `make_denoiser(..., control=)`; the others ignore them."""

    targets: torch.Tensor
    mask: torch.Tensor


class ModelKind(Protocol):
    def build_model(self, config: dict, source: str) -> nn.Module:
        """The untrained network for a bundle config (`source` names the file in errors)."""

    def samplers(self, config: dict, schedule: NoiseSchedule) -> dict[str, Sampler]:
        """name -> Sampler this kind can run."""

    def make_denoiser(self, pipeline: "Pipeline", text: torch.Tensor, text_mask: torch.Tensor,
                      motion_mask: torch.Tensor, cfg: float, dtype: torch.dtype | None,
                      timesteps: list[int], control: ControlTargets | None = None) -> Denoise:
        """`denoise(x_t, t)` for one request: text (B, L, C), text_mask (B, L), motion_mask (B, T);
        control: the batch's joint targets (None: no prompt has any)."""


class DiffusionKind:
    """A text-conditioned diffusion model (MotionDiffusionModel) sampled with classifier-free guidance."""

    def build_model(self, config: dict, source: str) -> nn.Module:
        from stablemo.nets.model import MotionDiffusionModel

        return MotionDiffusionModel(**config["model"])

    def samplers(self, config: dict, schedule: NoiseSchedule) -> dict[str, Sampler]:
        return SAMPLER_TABLE

    def make_denoiser(self, pipeline, text, text_mask, motion_mask, cfg, dtype, timesteps, control=None) -> Denoise:
        from stablemo.diffusion.guidance import CFGDenoiser

        null_text, null_mask = pipeline.null_condition(text.shape[0])
        return CFGDenoiser(pipeline.model, text, text_mask, null_text, null_mask, motion_mask, scale=cfg,
                           dtype=dtype, timesteps=timesteps)


# kind -> (module, class): imports stay lazy, as for stablemo.nets.DENOISERS
MODEL_KINDS: dict[str, tuple[str, str]] = {
    "diffusion": ("stablemo.inference.kinds", "DiffusionKind"),
    "consistency": ("stablemo.inference.kind_consistency", "ConsistencyKind"),
    "controlnet": ("stablemo.inference.kind_controlnet", "ControlNetKind"),
}


def model_kind(name: str, source: str = "kind") -> ModelKind:
    if name not in MODEL_KINDS:
        raise StableMoError(f"{source}: bundle kind {name!r} is not supported (known: {sorted(MODEL_KINDS)})")
    module, cls = MODEL_KINDS[name]
    return getattr(importlib.import_module(module), cls)()
