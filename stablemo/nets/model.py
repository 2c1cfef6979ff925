"""MotionDiffusionModel: text conditioner + denoiser, the trainable network a bundle holds."""

from __future__ import annotations

import torch
from torch import nn

from stablemo.errors import StableMoError
from stablemo.nets import build_denoiser
from stablemo.text import TextConditioner


class MotionDiffusionModel(nn.Module):
    """denoiser: {"name": "unet"|"dit"|"retnet", "input_dim": D, **kwargs}; text: TextConditioner kwargs.

    ``text_dim`` of the denoiser defaults to the conditioner's ``latent_dim`` and must match it.
    ``state_dict()`` holds trainable weights only (the frozen text encoder lives outside it).
    """

    def __init__(self, denoiser: dict, text: dict | None = None):
        super().__init__()
        if not isinstance(denoiser, dict) or "name" not in denoiser:
            raise StableMoError("denoiser: expected a dict with a 'name' key (unet, dit, retnet)")
        self.text = TextConditioner(**dict(text or {}))
        config = dict(denoiser)
        name = config.pop("name")
        config.setdefault("text_dim", self.text.latent_dim)
        if config["text_dim"] != self.text.latent_dim:
            raise StableMoError(
                f"denoiser.text_dim: {config['text_dim']} differs from text.latent_dim {self.text.latent_dim}")
        self.denoiser = build_denoiser(name, **config)

    @property
    def length_multiple(self) -> int:
        return int(self.denoiser.length_multiple)

    def encode_text(self, texts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        """texts -> (text (B, L, latent_dim), text_mask (B, L) bool)."""
        return self.text(texts)

    @property
    def time_feature_dim(self) -> int:
        """Width of the sinusoidal timestep features that `time_cond` is added to."""
        return int(self.denoiser.time_embed.dim)

    def prepare(self, text, text_mask, motion_mask, time_cond=None, timesteps=()):
        """The denoiser's per-request conditioning (stablemo.nets.conditioning): text (B, L, C) and
        text_mask (B, L) from `encode_text`, motion_mask (B, T); timesteps: the sampler's plan."""
        return self.denoiser.prepare(text, text_mask, motion_mask, time_cond=time_cond, timesteps=timesteps)

    def denoise(self, x, t, ctx):
        """One step: x (B, T, D), t (B,), ctx from `prepare` -> (B, T, D)."""
        return self.denoiser(x, t, ctx)

    def forward(self, x, t, text, text_mask, motion_mask, time_cond=None):
        """One call with its own conditioning (training): time_cond, optional (B, time_feature_dim),
        is added to the timestep features (distillation)."""
        return self.denoiser(x, t, self.prepare(text, text_mask, motion_mask, time_cond))
