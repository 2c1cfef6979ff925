"""Joint-trajectory control errors (facts-distillation.md §4; OmniControl / MotionLCM convention).

For each controlled entry (sample b, frame t, joint j with hint_mask = 1) the error is
d = ‖Ĵ_{b,t,j} − H_{b,t,j}‖ in metres (global joint positions of the generated motion vs the hint).
  Avg. err  = Σ d / Σ m
  Traj. err = fraction of samples with any controlled d > threshold (samples without hints skipped)
  Loc. err  = fraction of controlled entries with d > threshold
"""

from __future__ import annotations

import numpy as np
import torch

from stablemo.errors import StableMoError


def control_errors(joints, hints, hint_mask, threshold: float = 0.5) -> dict[str, float]:
    """joints, hints: (B, T, J, 3); hint_mask: (B, T, J) or (B, T, J, 3) bool. Returns the three errors."""
    j = torch.as_tensor(np.asarray(joints) if not torch.is_tensor(joints) else joints).detach().double().cpu()
    h = torch.as_tensor(np.asarray(hints) if not torch.is_tensor(hints) else hints).detach().double().cpu()
    m = torch.as_tensor(np.asarray(hint_mask) if not torch.is_tensor(hint_mask) else hint_mask).detach().cpu()
    if j.shape != h.shape or j.ndim != 4 or j.shape[-1] != 3:
        raise StableMoError(f"control: joints {tuple(j.shape)} and hints {tuple(h.shape)} must both be (B, T, J, 3)")
    if m.ndim == 4:
        m = m.bool().any(-1)
    m = m.bool()
    if tuple(m.shape) != tuple(j.shape[:3]):
        raise StableMoError(f"control: hint_mask {tuple(m.shape)} does not match joints {tuple(j.shape[:3])}")
    if not m.any():
        raise StableMoError("control: hint_mask selects no entries")
    d = torch.linalg.norm(j - h, dim=-1)  # (B, T, J)
    far = (d > threshold) & m
    controlled = m.flatten(1).any(1)
    return {
        "avg_err": float((d * m).sum() / m.sum()),
        "traj_err": float(far.flatten(1).any(1)[controlled].double().mean()),
        "loc_err": float(far.sum() / m.sum()),
    }
