"""In-painting inside a sampler (MDM-style replacement): known feature values imposed at every step.

At each step the sampler holds x_t = alpha x0 + sigma eps (VP form). Before the network sees it,
the known entries of x_t are replaced by the known values noised to that exact level,
alpha * known + sigma * noise, and the known entries of the predicted x0 are replaced by the
known values themselves; the final sample's known entries are the known values, exactly.

The noise used for the known part is the sample's own start noise x_T (fixed across steps): the
known part then follows the deterministic (DDIM) path from x_T to the known values, which keeps
deterministic samplers deterministic, draws nothing from the per-sample generators (so a request
with in-painting keeps the same noise stream as one without), and at the top level (alpha ~ 0)
leaves x_T as it is.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class Inpainting:
    """values: (B, T, D) known values in the model's normalised space; mask: (B, T, D) bool (True =
    known); noise: (B, T, D) the start noise x_T. All on the sample's device."""

    values: torch.Tensor
    mask: torch.Tensor
    noise: torch.Tensor

    def __post_init__(self) -> None:
        if not (self.values.shape == self.mask.shape == self.noise.shape and self.values.dim() == 3):
            raise ValueError(f"Inpainting: values {tuple(self.values.shape)}, mask {tuple(self.mask.shape)} and "
                             f"noise {tuple(self.noise.shape)} must be one (B, T, D) shape")
        self.mask = self.mask.bool()

    def noisy(self, x: torch.Tensor, alpha: float, sigma: float) -> torch.Tensor:
        """x_t (B, T, D) with its known entries at the level (alpha, sigma)."""
        known = alpha * self.values.to(x.dtype) + sigma * self.noise.to(x.dtype)
        return torch.where(self.mask, known, x)

    def clean(self, x0: torch.Tensor) -> torch.Tensor:
        """x0 (B, T, D) with its known entries replaced by the known values."""
        return torch.where(self.mask, self.values.to(x0.dtype), x0)


__all__ = ["Inpainting"]
