"""The per-request conditioning every denoiser takes: made once by `prepare`, read at every step.

Sampling calls a denoiser 1-1000 times with one fixed text, motion mask and (for a consistency
student) guidance scale. Everything that depends on those alone -- text summaries for
cross-attention, the pooled text embedding, masks at each resolution, and, when the sampler's
timesteps are known in advance, the timestep embeddings of all its steps -- is computed once by

    ctx = denoiser.prepare(text, text_mask, motion_mask, time_cond=None, timesteps=())

and each step is then `denoiser(x_t, t, ctx)`. Training prepares a fresh context per batch (with
autograd recording, so gradients flow through it); the result is the same computation, reordered.
Each denoiser extends `Conditioning` with its own typed fields.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from stablemo.errors import StableMoError


@dataclass
class Conditioning:
    """motion_mask: (B, T) bool; time_cond: (B, F) features added to the timestep features before
    the time MLP (a consistency student's guidance scale) or None; timesteps: the sampler's
    timesteps in the order it visits them, () when not announced."""

    motion_mask: torch.Tensor
    time_cond: torch.Tensor | None
    timesteps: tuple[int, ...]

    def planned_index(self, t: torch.Tensor) -> int | None:
        """Index of this step in `timesteps` when the whole batch is at one planned timestep."""
        if not self.timesteps:
            return None
        t0 = int(t[0])
        if t0 not in self.timesteps or not bool((t == t0).all()):
            return None
        return self.timesteps.index(t0)


def check_conditioning(text, text_mask, motion_mask, text_dim: int) -> None:
    """One clear error for the conditioning's shape mistakes (prepare)."""
    B = text.shape[0] if text.dim() == 3 else None
    if text.dim() != 3 or text.shape[-1] != text_dim:
        raise StableMoError(f"text: expected shape (B, L, {text_dim}), got {tuple(text.shape)}")
    if text_mask.shape != text.shape[:2] or text_mask.dtype != torch.bool:
        raise StableMoError(f"text_mask: expected bool {tuple(text.shape[:2])}, got {text_mask.dtype} {tuple(text_mask.shape)}")
    if motion_mask.dim() != 2 or motion_mask.shape[0] != B or motion_mask.dtype != torch.bool:
        raise StableMoError(f"motion_mask: expected bool ({B}, T), got {motion_mask.dtype} {tuple(motion_mask.shape)}")


def check_step(x, t, ctx: Conditioning, input_dim: int, length_multiple: int) -> None:
    """One clear error for a step's shape mistakes (forward)."""
    if x.dim() != 3 or x.shape[-1] != input_dim:
        raise StableMoError(f"x: expected shape (B, T, {input_dim}), got {tuple(x.shape)}")
    B, T, _ = x.shape
    if T % length_multiple != 0:
        raise StableMoError(f"x: length {T} is not a multiple of {length_multiple}; pad the batch")
    if t.shape != (B,):
        raise StableMoError(f"t: expected shape ({B},), got {tuple(t.shape)}")
    if tuple(ctx.motion_mask.shape) != (B, T):
        raise StableMoError(f"motion_mask: expected bool ({B}, {T}), got {ctx.motion_mask.dtype} {tuple(ctx.motion_mask.shape)}")
