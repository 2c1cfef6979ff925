"""The "consistency" bundle kind: a 1-4-step student with its guidance scale embedded."""

from __future__ import annotations

from torch import nn

from stablemo.diffusion.samplers import Sampler
from stablemo.diffusion.schedule import NoiseSchedule
from stablemo.errors import StableMoError


class ConsistencyKind:
    def build_model(self, config: dict, source: str) -> nn.Module:
        from stablemo.distill.student import ConsistencyStudent

        if not isinstance(config.get("consistency"), dict):
            raise StableMoError(f"{source}: a consistency bundle needs a 'consistency' section")
        return ConsistencyStudent(config["model"], w_dim=config["consistency"].get("w_dim", 256))

    def samplers(self, config: dict, schedule: NoiseSchedule) -> dict[str, Sampler]:
        from stablemo.distill.sampling import consistency_samplers

        return consistency_samplers(config["consistency"], schedule)

    def make_denoiser(self, pipeline, text, text_mask, motion_mask, cfg, dtype, timesteps, control=None):
        from stablemo.distill.student import StudentDenoiser

        # guidance is embedded in the student: LCM's w = cfg - 1
        return StudentDenoiser(pipeline.model, text, text_mask, motion_mask, w=cfg - 1.0, dtype=dtype,
                               timesteps=timesteps)
