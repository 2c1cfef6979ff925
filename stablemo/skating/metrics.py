"""Physical plausibility metrics on global joint positions (y up, metres), batched with masks.

Foot-skating ratio: as defined by GMD (Karunratanakul et al., ICCV 2023). Penetration / floating / sliding:
PhysDiff-style ground metrics of the lowest joint. Every function takes joints (B, T, J, 3) and a
validity mask (B, T) bool (or lengths) and scores each sample on its valid frames only, so a batch
of padded motions gives exactly the per-sample results.
"""

from __future__ import annotations

import numpy as np
import torch

from stablemo.errors import StableMoError
from stablemo.motion.skeleton import HUMANML3D

FEET_HUMANML3D = (HUMANML3D.feet_left[1], HUMANML3D.feet_right[1])  # toe joints (left, right)


def _prepare(joints, mask=None, lengths=None) -> tuple[torch.Tensor, torch.Tensor]:
    """joints → float64 tensor (B, T, J, 3); mask (B, T) bool with valid frames a prefix."""
    j = torch.as_tensor(np.asarray(joints) if not torch.is_tensor(joints) else joints).detach()
    j = j.to(torch.float64).cpu()
    if j.ndim == 3:
        j = j[None]
    if j.ndim != 4 or j.shape[-1] != 3:
        raise StableMoError(f"joints: expected (B, T, J, 3), got {tuple(j.shape)}")
    B, T = j.shape[:2]
    if mask is not None and lengths is not None:
        raise StableMoError("give either mask or lengths, not both")
    if lengths is not None:
        lengths = torch.as_tensor(lengths).reshape(-1)
        m = torch.arange(T)[None, :] < lengths[:, None]
    elif mask is not None:
        m = torch.as_tensor(np.asarray(mask) if not torch.is_tensor(mask) else mask).bool().cpu()
        if m.ndim == 1:
            m = m[None]
    else:
        m = torch.ones(B, T, dtype=torch.bool)
    if tuple(m.shape) != (B, T):
        raise StableMoError(f"mask: expected shape {(B, T)}, got {tuple(m.shape)}")
    return j, m


def _box_filter(x: torch.Tensor, size: int) -> torch.Tensor:
    """Centred moving average over the last axis with zero padding (uniform_filter1d, mode constant)."""
    lead = x.shape[:-1]
    flat = x.reshape(-1, 1, x.shape[-1])
    kernel = torch.full((1, 1, size), 1.0 / size, dtype=x.dtype)
    out = torch.nn.functional.conv1d(flat, kernel, padding=size // 2)
    return out.reshape(*lead, -1)


def foot_skating_ratio(joints, mask=None, lengths=None, feet=FEET_HUMANML3D, fps: float = HUMANML3D.fps,
                       height_threshold: float = 0.05, velocity_threshold: float = 0.5,
                       window: int = 5) -> np.ndarray:
    """Fraction of valid frame transitions in which a grounded foot slides; returns (B,).

    v_t = fps·‖Δ(x,z)‖ of each foot between frames t and t+1; v̄ = `window`-frame centred mean of v
    (zero padding beyond the valid transitions); contact_t = y_t < h ∧ y_{t+1} < h;
    skate_t = contact_t ∧ v_t > v_th ∧ v̄_t > v_th, OR over the feet; ratio = Σ skate / (L − 1).
    """
    j, m = _prepare(joints, mask, lengths)
    feet_pos = j[:, :, list(feet)]  # (B, T, F, 3)
    valid = m[:, 1:] & m[:, :-1]  # (B, T-1): both frames of the transition valid
    speed = fps * torch.linalg.norm(feet_pos[:, 1:, :, [0, 2]] - feet_pos[:, :-1, :, [0, 2]], dim=-1)
    speed = speed * valid[..., None]  # (B, T-1, F); zero outside the sample = zero padding
    mean_speed = _box_filter(speed.transpose(1, 2), window).transpose(1, 2)
    height = feet_pos[..., 1]
    contact = (height[:, :-1] < height_threshold) & (height[:, 1:] < height_threshold)
    skate = contact & (speed > velocity_threshold) & (mean_speed > velocity_threshold)
    skate = skate.any(-1) & valid  # (B, T-1)
    transitions = valid.sum(1)
    if (transitions == 0).any():
        raise StableMoError("foot skating: every sample needs at least 2 valid frames")
    return (skate.sum(1).double() / transitions.double()).numpy()


def ground_metrics(joints, mask=None, lengths=None, threshold: float = 0.005) -> dict[str, np.ndarray]:
    """PhysDiff-style ground contact errors of the lowest joint, each (B,), in metres.

    With h_t the lowest joint height (floor at y = 0) on valid frames:
      penetration = mean_t max(0, −h_t − thr)       (how far the body sinks below the floor)
      floating    = mean_t max(0, h_t − thr)        (how far the lowest point hovers above it)
      sliding     = mean over transitions where the lowest joint stays the same and is grounded
                    (|h| ≤ thr in both frames) of its horizontal displacement per frame (0 if none).
    """
    j, m = _prepare(joints, mask, lengths)
    height, lowest = j[..., 1].min(-1)  # (B, T)
    mf = m.double()
    frames = mf.sum(1).clamp(min=1)
    penetration = ((-height - threshold).clamp(min=0) * mf).sum(1) / frames
    floating = ((height - threshold).clamp(min=0) * mf).sum(1) / frames
    idx = lowest[..., None, None].expand(-1, -1, 1, 3)
    low_pos = torch.gather(j, 2, idx)[:, :, 0]  # (B, T, 3)
    grounded = height.abs() <= threshold
    pair = m[:, 1:] & m[:, :-1] & grounded[:, 1:] & grounded[:, :-1] & (lowest[:, 1:] == lowest[:, :-1])
    step = torch.linalg.norm(low_pos[:, 1:, [0, 2]] - low_pos[:, :-1, [0, 2]], dim=-1)
    pf = pair.double()
    sliding = (step * pf).sum(1) / pf.sum(1).clamp(min=1)
    return {"penetration": penetration.numpy(), "floating": floating.numpy(), "sliding": sliding.numpy()}


def foot_second_difference(joints: torch.Tensor, feet, fps: float) -> torch.Tensor:
    """|second difference| of the `feet` joints' coordinates in m/s²: (B, T, J, 3) -> (B, T-2, F, 3).
    The one definition of foot acceleration; callers choose how to average it over valid frames."""
    feet_pos = joints[:, :, list(feet)]
    return (feet_pos[:, 2:] - 2 * feet_pos[:, 1:-1] + feet_pos[:, :-2]).abs() * fps * fps


def foot_acceleration(joints, mask=None, lengths=None, feet=(*HUMANML3D.feet_left, *HUMANML3D.feet_right),
                      fps: float = HUMANML3D.fps) -> np.ndarray:
    """Mean |second difference| of the feet's (ankles and toes) coordinates, m/s², over valid
    frames; (B,). The jitter measure of foot-skate corrections (scripts/footskate/report.py, docs/
    footskate.md) and of joint control: a target reached by a jerk shows here."""
    j, m = _prepare(joints, mask, lengths)
    acc = foot_second_difference(j, feet, fps)  # (B, T-2, F, 3)
    valid = (m[:, 2:] & m[:, 1:-1] & m[:, :-2]).double()  # (B, T-2)
    if (valid.sum(1) == 0).any():
        raise StableMoError("foot acceleration: every sample needs at least 3 valid frames")
    return ((acc.mean((-1, -2)) * valid).sum(1) / valid.sum(1)).numpy()
