"""Model kinds: what the pipeline needs to know of each kind of trained bundle.

A bundle's `config.json` names its kind. The kind supplies the network built from the config, the
table of samplers it can run, and the denoiser a request samples with:

    diffusion     a text-conditioned diffusion model, sampled with classifier-free guidance
    consistency   a 1-4-step student with its guidance scale embedded (one conditional pass)
    controlnet    a frozen base of either kind plus its ControlNet: it binds the request's joint
                  targets to the network as a hint and delegates everything else to its base kind

A kind is given what one request needs (`DenoiserInputs`), never the pipeline. Adding a kind is
one class and one line in MODEL_KINDS; the pipeline has no branch on the kind.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol

import torch
from torch import nn

from stablemo.control.spec import ControlTargets
from stablemo.diffusion.samplers import SAMPLER_TABLE, Sampler
from stablemo.diffusion.schedule import NoiseSchedule
from stablemo.errors import StableMoError

Denoise = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


@dataclass
class DenoiserInputs:
    """One request as a kind sees it.

    model: the bundle's network; config: its config.json; text (B, L, C) and text_mask (B, L): the
    encoded prompts; motion_mask (B, T); cfg: the guidance scale; dtype: the network's precision
    (None: as loaded); timesteps: the sampler's planned steps (for `prepare`); null_condition(B):
    the empty prompt's (text, mask) for classifier-free guidance (encoded once by the pipeline);
    control: the batch's joint targets (None: no prompt has any).
    """

    model: nn.Module
    config: dict
    text: torch.Tensor
    text_mask: torch.Tensor
    motion_mask: torch.Tensor
    cfg: float
    dtype: torch.dtype | None
    timesteps: list
    null_condition: Callable[[int], tuple[torch.Tensor, torch.Tensor]]
    control: ControlTargets | None = None


class ModelKind(Protocol):
    # the network itself reads the request's joint targets (a ControlNet's hint): its predicted x0
    # already walks where the targets pull it, so it cannot say which gait the text asked for
    reads_control: bool

    def build_model(self, config: dict, source: str) -> nn.Module:
        """The untrained network for a bundle config (`source` names the file in errors)."""

    def samplers(self, config: dict, schedule: NoiseSchedule) -> dict[str, Sampler]:
        """name -> Sampler this kind can run."""

    def make_denoiser(self, inputs: DenoiserInputs) -> Denoise:
        """`denoise(x_t, t)` for one request."""


class DiffusionKind:
    """A text-conditioned diffusion model (MotionDiffusionModel) sampled with classifier-free guidance."""

    reads_control = False

    def build_model(self, config: dict, source: str) -> nn.Module:
        from stablemo.nets.model import MotionDiffusionModel

        return MotionDiffusionModel(**config["model"])

    def samplers(self, config: dict, schedule: NoiseSchedule) -> dict[str, Sampler]:
        return SAMPLER_TABLE

    def make_denoiser(self, inputs: DenoiserInputs) -> Denoise:
        from stablemo.diffusion.guidance import CFGDenoiser

        null_text, null_mask = inputs.null_condition(inputs.text.shape[0])
        return CFGDenoiser(inputs.model, inputs.text, inputs.text_mask, null_text, null_mask, inputs.motion_mask,
                           scale=inputs.cfg, dtype=inputs.dtype, timesteps=inputs.timesteps)


class ConsistencyKind:
    """A 1-4-step consistency student (LCM/PCM) with its guidance scale embedded."""

    reads_control = False

    def build_model(self, config: dict, source: str) -> nn.Module:
        from stablemo.distill.student import ConsistencyStudent

        if not isinstance(config.get("consistency"), dict):
            raise StableMoError(f"{source}: a consistency bundle needs a 'consistency' section")
        return ConsistencyStudent(config["model"], w_dim=config["consistency"].get("w_dim", 256))

    def samplers(self, config: dict, schedule: NoiseSchedule) -> dict[str, Sampler]:
        from stablemo.distill.sampling import consistency_samplers

        return consistency_samplers(config["consistency"], schedule)

    def make_denoiser(self, inputs: DenoiserInputs) -> Denoise:
        from stablemo.distill.student import StudentDenoiser

        # guidance is embedded in the student: LCM's w = cfg - 1
        return StudentDenoiser(inputs.model, inputs.text, inputs.text_mask, inputs.motion_mask, w=inputs.cfg - 1.0,
                               dtype=inputs.dtype, timesteps=inputs.timesteps)


def _controlnet_section(config: dict, source: str) -> dict:
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
    """A frozen base (diffusion model or consistency student) plus its ControlNet. Samplers and the
    denoiser are the base kind's; the request's resolved joint targets become the hint.

    Bundle config: the base bundle's config with `kind: "controlnet"` and a section `controlnet:
    {base_kind, joints, hint_scale, control: {channels, layers, path, output, output_scale[, root_only,
    heading_scale[, floor_steps[, toward_targets]]][, blocks]}}`.
    """

    reads_control = True

    def build_model(self, config: dict, source: str) -> nn.Module:
        from stablemo.control.controlnet import ControlledModel

        section = _controlnet_section(config, source)
        base = model_kind(section["base_kind"], source).build_model(config, source)
        return ControlledModel(base, section["base_kind"], int(section["joints"]), section.get("control"))

    def samplers(self, config: dict, schedule: NoiseSchedule) -> dict[str, Sampler]:
        section = _controlnet_section(config, "config")
        return model_kind(section["base_kind"]).samplers(config, schedule)

    def make_denoiser(self, inputs: DenoiserInputs) -> Denoise:
        from dataclasses import replace

        from stablemo.control.hints import hint_input

        model = inputs.model
        section = _controlnet_section(inputs.config, "config")
        B, T = inputs.motion_mask.shape
        control = inputs.control
        if control is None:  # a free prompt: the empty hint, which the gate turns into no injection (the base)
            control = ControlTargets(torch.zeros(B, T, model.joints, 3), torch.zeros(B, T, model.joints, dtype=torch.bool))
        hint = hint_input(control.targets, control.mask, float(section.get("hint_scale", 1.0)),
                          path=model.control.path).to(inputs.motion_mask.device)
        base = model_kind(model.base_kind)
        return base.make_denoiser(replace(inputs, model=HintedNetwork(model, hint), control=None))


MODEL_KINDS: dict[str, type] = {
    "diffusion": DiffusionKind,
    "consistency": ConsistencyKind,
    "controlnet": ControlNetKind,
}


def model_kind(name: str, source: str = "kind") -> ModelKind:
    if name not in MODEL_KINDS:
        raise StableMoError(f"{source}: bundle kind {name!r} is not supported (known: {sorted(MODEL_KINDS)})")
    return MODEL_KINDS[name]()
