"""Facing and direction of travel of a body, per frame (yaw about +y; 0 = +z, atan2(x, z)).

One home for the two directions a viewer compares on a walking figure: where the hips and shoulders
face, and where the pelvis goes. The joint-control steering (stablemo.control.heading) turns the
body toward its path with them; the evaluation (stablemo.eval.heading) measures the angle between.
"""

from __future__ import annotations

import math

import torch

from stablemo.motion.skeleton import Skeleton

TRAVEL_WINDOW_S = 0.5  # centred difference of the pelvis over about one stride: a step's sway cancels


def wrap(angle: torch.Tensor) -> torch.Tensor:
    """Angles (radians) wrapped into [-pi, pi)."""
    return torch.remainder(angle + math.pi, 2 * math.pi) - math.pi


def unwrap(angle: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """Angles made continuous along `dim` (each step taken as its wrapped difference)."""
    first = angle.narrow(dim, 0, 1)
    steps = wrap(angle.diff(dim=dim))
    return torch.cat([first, first + steps.cumsum(dim)], dim)


def gaussian_smooth(x: torch.Tensor, sigma: float, dim: int = 1) -> torch.Tensor:
    """Gaussian over `dim` of x (sigma in frames), edges held ('nearest'); sigma <= 0: x itself."""
    if sigma <= 0 or x.shape[dim] < 2:
        return x
    radius = math.ceil(3 * sigma)
    k = torch.exp(-0.5 * (torch.arange(-radius, radius + 1, dtype=x.dtype, device=x.device) / sigma) ** 2)
    k = (k / k.sum()).view(1, 1, -1)
    moved = x.movedim(dim, -1)
    flat = moved.reshape(-1, 1, moved.shape[-1])
    flat = torch.nn.functional.pad(flat, (radius, radius), mode="replicate")
    return torch.nn.functional.conv1d(flat, k).reshape(moved.shape).movedim(-1, dim)


def facing_yaw(joints: torch.Tensor, skel: Skeleton, sigma_frames: float = 0.0) -> torch.Tensor:
    """(..., T) radians: yaw of the body's horizontal forward, y x (hip line + shoulder line), the
    across-vector of the feature extraction's initial facing; smoothed over `sigma_frames`."""
    r_hip, l_hip, r_sdr, l_sdr = skel.face_joints
    across = (joints[..., r_hip, :] - joints[..., l_hip, :]) + (joints[..., r_sdr, :] - joints[..., l_sdr, :])
    forward = torch.stack([across[..., 2], -across[..., 0]], -1)  # (x, z) of y x across
    forward = gaussian_smooth(forward, sigma_frames, dim=-2)
    return torch.atan2(forward[..., 0], forward[..., 1])


def travel(xz: torch.Tensor, lengths: torch.Tensor, fps: float,
           window_s: float = TRAVEL_WINDOW_S) -> tuple[torch.Tensor, torch.Tensor]:
    """Direction (B, T) radians and speed (B, T) units/s of a horizontal path xz (B, T, 2), centred
    over `window_s`; near either end of the valid frames the window is cut to what exists."""
    B, T = xz.shape[:2]
    h = max(1, round(window_s * fps / 2))
    t = torch.arange(T, device=xz.device)[None].expand(B, T)
    last = (lengths.to(xz.device) - 1).clamp(min=0)[:, None]
    lo, hi = (t - h).clamp(min=0), torch.minimum(t + h, last).clamp(min=0)
    lo = torch.minimum(lo, hi)
    pick = lambda i: torch.gather(xz, 1, i[..., None].expand(-1, -1, 2))
    span = (hi - lo).clamp(min=1).to(xz.dtype)[..., None] / fps
    velocity = (pick(hi) - pick(lo)) / span
    return torch.atan2(velocity[..., 0], velocity[..., 1]), velocity.norm(dim=-1)


__all__ = ["TRAVEL_WINDOW_S", "facing_yaw", "gaussian_smooth", "travel", "unwrap", "wrap"]
