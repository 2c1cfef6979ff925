"""The consistency student: the teacher's network plus a zero-initialised guidance-scale embedding.

The student predicts x0 like its teacher, conditioned on (x_t, t, text) and on the guidance scale
w it has absorbed: w enters as sinusoidal features projected by a bias-free linear layer whose
weights start at zero and are added to the timestep features before the time MLP (MotionLCM).
At initialisation the student is therefore exactly its teacher, whatever w. At inference one
forward pass replaces the two of classifier-free guidance.
"""

from __future__ import annotations

import torch
from torch import nn

from stablemo.diffusion.guidance import precision_context
from stablemo.diffusion.schedule import NoiseSchedule
from stablemo.distill.consistency import (
    ddim_jump,
    guidance_embedding,
    lcm_consistency,
    lower_edge,
)
from stablemo.errors import StableMoError
from stablemo.nets.model import MotionDiffusionModel

MODES = ("lcm", "pcm")


class ConsistencyStudent(nn.Module):
    """model: MotionDiffusionModel kwargs; w_dim: size of the sinusoidal w features."""

    def __init__(self, model: dict, w_dim: int = 256) -> None:
        super().__init__()
        self.model = MotionDiffusionModel(**model)
        self.w_dim = w_dim
        self.w_proj = nn.Linear(w_dim, self.model.time_feature_dim, bias=False)
        nn.init.zeros_(self.w_proj.weight)

    @property
    def length_multiple(self) -> int:
        return self.model.length_multiple

    def encode_text(self, texts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        return self.model.encode_text(texts)

    def guidance_features(self, w: torch.Tensor) -> torch.Tensor:
        """w: (B,) guidance (LCM convention, scale 1 + w) -> (B, time_feature_dim) time_cond."""
        return self.w_proj(guidance_embedding(w, self.w_dim).to(self.w_proj.weight.dtype))

    def prepare(self, text, text_mask, motion_mask, w: torch.Tensor, timesteps=()):
        """The teacher network's per-request conditioning with w absorbed (see `forward`)."""
        return self.model.prepare(text, text_mask, motion_mask, self.guidance_features(w), timesteps)

    def denoise(self, x, t, ctx):
        return self.model.denoise(x, t, ctx)

    def forward(self, x, t, w, text, text_mask, motion_mask) -> torch.Tensor:
        """x0 estimate. x: (B,T,D), t: (B,) long, w: (B,) guidance (LCM convention, scale 1 + w)."""
        return self.model(x, t, text, text_mask, motion_mask, time_cond=self.guidance_features(w))


def consistency_fn(mode: str, schedule: NoiseSchedule, edges: list[int] | None, x_t: torch.Tensor,
                   x0: torch.Tensor, t: torch.Tensor, sigma_data: float = 0.5, timestep_scale: float = 10.0):
    """The consistency function f(x_t, t) from the network's x0 estimate (see consistency.py)."""
    if mode == "lcm":
        return lcm_consistency(x_t, x0, t, sigma_data, timestep_scale)
    if mode == "pcm":
        if edges is None:
            raise StableMoError("pcm: phase edges are required")
        return ddim_jump(schedule, x_t, x0, t, lower_edge(t, edges))
    raise StableMoError(f"mode: expected one of {MODES}, got {mode!r}")


class StudentDenoiser:
    """The pipeline's `denoise(x_t, t)` for a student: one conditional forward with w embedded, no CFG pass.

    w follows LCM's convention (guidance scale 1 + w), so a requested CFG scale s maps to w = s - 1.
    The conditioning is prepared once, in the network's precision, for this denoiser's request.
    """

    def __init__(self, student: ConsistencyStudent, text, text_mask, motion_mask, w: float, dtype=None,
                 timesteps=()):
        self.student, self.dtype = student, dtype
        w_batch = torch.full((text.shape[0],), float(w), device=text.device)
        with precision_context(text.device, dtype):
            self.ctx = student.prepare(text, text_mask, motion_mask, w_batch, timesteps)

    def __call__(self, x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        with precision_context(x.device, self.dtype):
            out = self.student.denoise(x, t, self.ctx)
        return out.float()
