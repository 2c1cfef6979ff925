"""The arithmetic of consistency distillation in motion space, as small named functions.

Notation (LCM, Luo et al. 2023; MotionLCM): abar_t is the cumulative alpha product of the teacher's DDPM
schedule, alpha_t = sqrt(abar_t), sigma_t = sqrt(1 - abar_t), T = 1000 training steps, N DDIM grid
steps, skip k = T / N. Timestep tensors are integer (B,); motion tensors are (B, T, D).

Two consistency functions share one network x0-estimate:
- LCM (MotionLCM):   f(x_t, t) = c_skip(t) x_t + c_out(t) x0_hat            (boundary: f(x, 0) = x)
- PCM (MotionPCM):   f(x_t, t) = DDIM jump of x_t to the lower edge s_m of t's phase using x0_hat
                      (boundary: f(x, s_m) = x exactly; the lowest edge is clean data, sigma = 0)
"""

from __future__ import annotations

import math

import numpy as np
import torch

from stablemo.diffusion.schedule import NoiseSchedule
from stablemo.errors import StableMoError

CLEAN = -1  # timestep index standing for clean data (alpha = 1, sigma = 0): the lowest PCM edge


# ----------------------------------------------------------------------------- grids


def ddim_grid(num_train_timesteps: int, ddim_steps: int) -> list[int]:
    """LCM's DDIM grid tau_i = (i + 1) k - 1, i = 0 … N-1 (for T = 1000, N = 50: 19, 39, …, 999)."""
    if ddim_steps < 1 or num_train_timesteps % ddim_steps:
        raise StableMoError(f"ddim_steps: must divide {num_train_timesteps}, got {ddim_steps}")
    k = num_train_timesteps // ddim_steps
    return [(i + 1) * k - 1 for i in range(ddim_steps)]


def phase_edges(num_train_timesteps: int, ddim_steps: int, phases: int) -> list[int]:
    """PCM phase edges on the DDIM grid, ascending: [CLEAN, s_1, …, s_{M-1}, T-1].

    E = floor(linspace(0, N, M, endpoint=False)); edge e sits at tau_{E_e - 1}; the bottom edge is
    clean data. For N = 50, M = 4: [CLEAN, 239, 499, 739, 999].
    """
    if not 1 <= phases <= ddim_steps:
        raise StableMoError(f"phases: must lie in [1, ddim_steps={ddim_steps}], got {phases}")
    grid = ddim_grid(num_train_timesteps, ddim_steps)
    marks = np.floor(np.linspace(0, ddim_steps, phases, endpoint=False)).astype(int)
    edges = [CLEAN] + [grid[m - 1] for m in marks[1:]]
    return edges + [num_train_timesteps - 1]


def lower_edge(t: torch.Tensor, edges: list[int]) -> torch.Tensor:
    """For timesteps t (B,), the lower edge of their phase: the largest edge strictly below t."""
    table = torch.tensor(edges, device=t.device)
    index = (table[None, :] < t[:, None]).sum(dim=1) - 1  # (B,)
    return table[index.clamp(min=0)]


# ----------------------------------------------------------------------------- schedule values


def alpha_sigma(schedule: NoiseSchedule, t: torch.Tensor, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """alpha_t, sigma_t for integer t (B,) broadcast against `like` (B, ...); t = CLEAN gives (1, 0)."""
    abar = schedule.alphas_cumprod.to(device=t.device, dtype=torch.float64)[t.clamp(min=0)]
    abar = torch.where(t == CLEAN, torch.ones_like(abar), abar)
    shape = (-1,) + (1,) * (like.dim() - 1)
    alpha = abar.sqrt().to(like.dtype).reshape(shape)
    sigma = (1 - abar).clamp(min=0).sqrt().to(like.dtype).reshape(shape)
    return alpha, sigma


def ddim_jump(schedule: NoiseSchedule, x_t: torch.Tensor, x0: torch.Tensor, t: torch.Tensor, t_to: torch.Tensor) -> torch.Tensor:
    """Deterministic DDIM move of x_t (at t) to t_to given an x0 estimate, in the ratio form

    x_{t'} = alpha_{t'} x0 + (sigma_{t'} / sigma_t) (x_t - alpha_t x0)

    which never divides by a small alpha (well conditioned where the epsilon form is not) and
    returns x_t unchanged when t' = t.
    """
    a_t, s_t = alpha_sigma(schedule, t, x_t)
    a_to, s_to = alpha_sigma(schedule, t_to, x_t)
    ratio = torch.where(s_t > 0, s_to / s_t.clamp(min=1e-12), torch.zeros_like(s_t))
    return a_to * x0 + ratio * (x_t - a_t * x0)


def renoise(schedule: NoiseSchedule, x0: torch.Tensor, t: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
    """Forward-process sample at t from a clean estimate (LCM multi-step sampling)."""
    alpha, sigma = alpha_sigma(schedule, t, x0)
    return alpha * x0 + sigma * noise


def boundary_scalings(t: torch.Tensor, sigma_data: float = 0.5, timestep_scale: float = 10.0) -> tuple[torch.Tensor, torch.Tensor]:
    """LCM's c_skip, c_out on the integer timestep (B,): c_skip(0) = 1, c_out(0) = 0."""
    st = timestep_scale * t.double().clamp(min=0)
    c_skip = sigma_data**2 / (st**2 + sigma_data**2)
    c_out = st / (st**2 + sigma_data**2).sqrt()
    return c_skip, c_out


def lcm_consistency(x_t: torch.Tensor, x0: torch.Tensor, t: torch.Tensor, sigma_data: float = 0.5,
                    timestep_scale: float = 10.0) -> torch.Tensor:
    """f(x_t, t) = c_skip(t) x_t + c_out(t) x0_hat."""
    c_skip, c_out = boundary_scalings(t, sigma_data, timestep_scale)
    shape = (-1,) + (1,) * (x_t.dim() - 1)
    return c_skip.to(x_t.dtype).reshape(shape) * x_t + c_out.to(x_t.dtype).reshape(shape) * x0


# ----------------------------------------------------------------------------- guidance


def guidance_embedding(w: torch.Tensor, dim: int = 256) -> torch.Tensor:
    """Sinusoidal features of 1000 w (LCM's w-embedding input): w (B,) -> (B, dim) float32."""
    half = dim // 2
    freqs = torch.exp(-math.log(10000.0) * torch.arange(half, dtype=torch.float32, device=w.device) / max(half - 1, 1))
    args = 1000.0 * w.float()[:, None] * freqs[None]
    emb = torch.cat([torch.sin(args), torch.cos(args)], dim=-1)
    return torch.nn.functional.pad(emb, (0, dim % 2))


def cfg_x0(x0_cond: torch.Tensor, x0_uncond: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """LCM convention: effective scale 1 + w, x0^w = x0_c + w (x0_c - x0_u); w: (B,)."""
    w = w.to(x0_cond.dtype).reshape((-1,) + (1,) * (x0_cond.dim() - 1))
    return x0_cond + w * (x0_cond - x0_uncond)


# ----------------------------------------------------------------------------- loss


def masked_pseudo_huber(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor, c: float) -> torch.Tensor:
    """mean over valid frames and features of sqrt((pred - target)^2 + c^2) - c.

    pred/target: (B, T, D), mask: (B, T) bool -> scalar. Padded frames contribute nothing.
    """
    err = ((pred.float() - target.float()).square() + c * c).sqrt() - c  # (B, T, D)
    per_frame = err.mean(dim=-1)  # (B, T)
    valid = mask.float()
    return (per_frame * valid).sum() / valid.sum().clamp(min=1.0)
