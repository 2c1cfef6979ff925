"""1-4 step sampling with a consistency student (same `denoise(x_t, t) -> x0_hat` contract as the samplers).

- LCM: at each chosen timestep apply the consistency function; between steps re-noise the clean
  estimate to the next timestep with fresh noise (MotionLCM's multi-step sampling).
- PCM: deterministic; each step jumps DDIM-style from the current edge to a lower edge, no noise.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import torch

from stablemo.diffusion.inpainting import Inpainting
from stablemo.diffusion.samplers import Sampler
from stablemo.diffusion.schedule import NoiseSchedule
from stablemo.distill.consistency import (
    CLEAN,
    ddim_grid,
    ddim_jump,
    lcm_consistency,
    renoise,
)
from stablemo.errors import StableMoError

Denoise = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
NoiseFn = Callable[[torch.Tensor], torch.Tensor]


def lcm_timesteps(num_train_timesteps: int, ddim_steps: int, steps: int) -> list[int]:
    """LCM's inference timesteps: the DDIM grid, descending, at floor(linspace(0, N, n, endpoint=False)).

    T = 1000, N = 50: 1 step [999]; 2 steps [999, 499]; 4 steps [999, 759, 499, 259].
    """
    if not 1 <= steps <= ddim_steps:
        raise StableMoError(f"steps: must lie in [1, {ddim_steps}] for this student, got {steps}")
    descending = ddim_grid(num_train_timesteps, ddim_steps)[::-1]
    picks = np.floor(np.linspace(0, ddim_steps, steps, endpoint=False)).astype(int)
    return [descending[i] for i in picks]


def pcm_path(edges: list[int], steps: int) -> list[int]:
    """Edges visited from the top, descending, ending at CLEAN; `steps` must divide the phase count.

    With steps = M every phase is one jump (the trained path); fewer steps skip edges.
    """
    phases = len(edges) - 1
    if steps < 1 or phases % steps:
        raise StableMoError(f"steps: a {phases}-phase student samples with a divisor of {phases} steps, got {steps}")
    stride = phases // steps
    return edges[::-1][::stride]


def _level(schedule: NoiseSchedule, t: int) -> tuple[float, float]:
    """(alpha, sigma) of the forward process at integer timestep t (VP form)."""
    abar = float(schedule._abar64[t])
    return abar ** 0.5, (1.0 - abar) ** 0.5


def _predict(denoise, sample, schedule, i: int, t_int: int, callback, inpaint):
    """(sample with the known part imposed at t, x0 estimate after the callback and the known part)."""
    if inpaint is not None:
        sample = inpaint.noisy(sample, *_level(schedule, t_int))
    t = torch.full((sample.shape[0],), t_int, dtype=torch.long, device=sample.device)
    x0 = denoise(sample, t)
    if callback is not None:
        out = callback(i, t_int, x0)
        x0 = x0 if out is None else out
    if inpaint is not None:
        x0 = inpaint.clean(x0)
    return sample, t, x0


def sample_lcm(denoise: Denoise, x: torch.Tensor, schedule: NoiseSchedule, timesteps: list[int], noise: NoiseFn,
               sigma_data: float = 0.5, timestep_scale: float = 10.0, callback=None,
               inpaint: Inpainting | None = None) -> torch.Tensor:
    """x: (B,T,D) standard normal at the first timestep (alpha ~ 0 there, as in MotionLCM)."""
    batch = x.shape[0]
    sample = x
    for i, t_int in enumerate(timesteps):
        sample, t, x0 = _predict(denoise, sample, schedule, i, t_int, callback, inpaint)
        clean = lcm_consistency(sample, x0, t, sigma_data, timestep_scale)
        if inpaint is not None:
            clean = inpaint.clean(clean)
        if i + 1 < len(timesteps):
            t_next = torch.full((batch,), timesteps[i + 1], dtype=torch.long, device=x.device)
            sample = renoise(schedule, clean, t_next, noise(clean))
        else:
            sample = clean
    return sample


def sample_pcm(denoise: Denoise, x: torch.Tensor, schedule: NoiseSchedule, path: list[int], callback=None,
               inpaint: Inpainting | None = None) -> torch.Tensor:
    """Deterministic phased sampling along `path` (descending edges ending at CLEAN)."""
    batch = x.shape[0]
    sample = x
    for i, (t_int, to_int) in enumerate(zip(path[:-1], path[1:])):
        sample, t, x0 = _predict(denoise, sample, schedule, i, t_int, callback, inpaint)
        to = torch.full((batch,), to_int, dtype=torch.long, device=x.device)
        sample = x0 if to_int == CLEAN else ddim_jump(schedule, sample, x0, t, to)
    return sample


def consistency_samplers(config: dict, schedule: NoiseSchedule) -> dict[str, Sampler]:
    """The sampler table of a student bundle (its `consistency` config), in the pipeline's contract:
    sampler(denoise, x_T, schedule, steps, noise=, callback=, prediction_type=, progress=) -> x0,
    where denoise returns the raw network output (converted to x0 here)."""
    mode = config["mode"]
    sigma_data, scale = config.get("sigma_data", 0.5), config.get("timestep_scale", 10.0)

    def x0_of(denoise, prediction_type):
        def predict(x, t):
            return schedule.predict_x0(denoise(x, t), x, t, prediction_type)
        return predict

    def lcm(denoise, x, schedule, steps, noise, callback=None, prediction_type="sample", progress=False, inpaint=None):
        timesteps = lcm_timesteps(schedule.num_train_timesteps, config["ddim_steps"], steps)
        return sample_lcm(x0_of(denoise, prediction_type), x, schedule, timesteps, noise, sigma_data, scale, callback,
                          inpaint)

    def pcm(denoise, x, schedule, steps, noise=None, callback=None, prediction_type="sample", progress=False,
            inpaint=None):
        return sample_pcm(x0_of(denoise, prediction_type), x, schedule, pcm_path(config["edges"], steps), callback,
                          inpaint)

    if mode == "lcm":
        return {"lcm": Sampler(lcm, lambda sched, steps: lcm_timesteps(sched.num_train_timesteps, config["ddim_steps"], steps))}
    return {"pcm": Sampler(pcm, lambda sched, steps: pcm_path(config["edges"], steps)[:-1])}
