"""The "controlnet" bundle kind: a frozen base (diffusion model or consistency student) plus its
ControlNet. Samplers are the base kind's; the request's resolved joint targets become the hint.

Bundle config: the base bundle's config with `kind: "controlnet"` and a section
`controlnet: {base_kind, joints, hint_scale, control: {channels, layers, path, output, output_scale[, blocks]}}`.
"""

from __future__ import annotations

import torch
from torch import nn

from stablemo.diffusion.samplers import Sampler
from stablemo.diffusion.schedule import NoiseSchedule
from stablemo.errors import StableMoError
from stablemo.inference.kinds import ControlTargets, model_kind


def _section(config: dict, source: str) -> dict:
    section = config.get("controlnet")
    if not isinstance(section, dict) or section.get("base_kind") not in ("diffusion", "consistency"):
        raise StableMoError(f"{source}: a controlnet bundle needs a 'controlnet' section with base_kind "
                            "'diffusion' or 'consistency'")
    return section


class HintedNetwork:
    """The controlled model seen as its base network (`prepare(text, text_mask, motion_mask, cond,
    timesteps)`, `denoise`), with one request's hint (B, T, 4 J or 12 J) bound; a batch that doubled for
    classifier-free guidance (cond + uncond) gets the hint on both halves."""

    def __init__(self, model: nn.Module, hint: torch.Tensor):
        self.model, self.hint = model, hint

    def prepare(self, text, text_mask, motion_mask, cond=None, timesteps=()):
        repeat = motion_mask.shape[0] // self.hint.shape[0]
        hint = self.hint.repeat(repeat, 1, 1) if repeat > 1 else self.hint
        return self.model.prepare(text, text_mask, motion_mask, cond, timesteps, hint=hint)

    def denoise(self, x, t, ctx):
        return self.model.denoise(x, t, ctx)


class ControlNetKind:
    def build_model(self, config: dict, source: str) -> nn.Module:
        from stablemo.control.controlnet import ControlledModel

        section = _section(config, source)
        base = model_kind(section["base_kind"], source).build_model(config, source)
        return ControlledModel(base, section["base_kind"], int(section["joints"]), section.get("control"))

    def samplers(self, config: dict, schedule: NoiseSchedule) -> dict[str, Sampler]:
        section = _section(config, "config")
        return model_kind(section["base_kind"]).samplers(config, schedule)

    def make_denoiser(self, pipeline, text, text_mask, motion_mask, cfg, dtype, timesteps,
                      control: ControlTargets | None = None):
        from stablemo.control.hints import hint_input

        model = pipeline.model
        section = _section(pipeline.config, "config")
        B, T = motion_mask.shape
        if control is None:  # a free prompt: the empty hint, which the gate turns into no injection (the base)
            control = ControlTargets(torch.zeros(B, T, model.joints, 3), torch.zeros(B, T, model.joints, dtype=torch.bool))
        hint = hint_input(control.targets, control.mask, float(section.get("hint_scale", 1.0)),
                          path=model.control.path).to(motion_mask.device)
        network = HintedNetwork(model, hint)
        if model.base_kind == "consistency":
            from stablemo.distill.student import StudentDenoiser

            return StudentDenoiser(network, text, text_mask, motion_mask, w=cfg - 1.0, dtype=dtype, timesteps=timesteps)
        from stablemo.diffusion.guidance import CFGDenoiser

        null_text, null_mask = pipeline.null_condition(B)
        return CFGDenoiser(network, text, text_mask, null_text, null_mask, motion_mask, scale=cfg, dtype=dtype,
                           timesteps=timesteps)
