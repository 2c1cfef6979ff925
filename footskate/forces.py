"""Force labels from kinematics and contact labels, for training our own vGRF network.

Vertical force on the body = body weight × (1 + a_com / g), a_com the vertical acceleration of
the centre of mass (mean joint position, smoothed); the feet in contact share it by proximity to
the COM's ground projection (closer foot carries more), and within a foot the heel (back cells)
and the ball/toes (front cells) share it the same way. Output matches the network's layout:
(B, T, 2 feet [L, R], 16 cells), body-weight units; cells 0-3 heel, 8-15 front, 4-7 unused.
"""

from __future__ import annotations

import torch

from footskate.contacts import BACK_CELLS, FRONT_CELLS, shifted, temporal_filter

G = 9.81
SMOOTH_SIGMA_S = 0.05      # seconds: COM height smoothing before differentiating twice
PROXIMITY_EPS = 0.05       # metres: keeps proximity weights finite when a foot is under the COM
MAX_FORCE = 4.0            # body weights: clamp finite-difference spikes


def _gaussian(fps: float, sigma_s: float) -> torch.Tensor:
    sigma = max(sigma_s * fps, 1e-3)
    r = max(1, int(round(2 * sigma)))
    k = torch.exp(-0.5 * (torch.arange(-r, r + 1, dtype=torch.float64) / sigma) ** 2)
    return (k / k.sum()).float()


def total_vertical_force(joints: torch.Tensor, fps: float, up_axis: int = 1,
                         lengths: torch.Tensor | None = None) -> torch.Tensor:
    """(B, T, J, 3) -> (B, T) ground reaction force in body weights, 1 + a_com / g, clamped to [0, MAX]."""
    com = joints.mean(-2)[..., up_axis]                                 # (B, T)
    com = temporal_filter(com[..., None], _gaussian(fps, SMOOTH_SIGMA_S), lengths)[..., 0]
    acc = (shifted(com[..., None], 1, lengths) - 2 * com[..., None] + shifted(com[..., None], -1, lengths))[..., 0]
    return (1.0 + acc * fps * fps / G).clamp(0.0, MAX_FORCE)


def _proximity_share(points: torch.Tensor, active: torch.Tensor, centre: torch.Tensor) -> torch.Tensor:
    """points (..., K, 2), active (..., K) bool, centre (..., 2) -> shares (..., K) summing to 1 where any active."""
    dist = (points - centre[..., None, :]).norm(dim=-1)
    w = active.float() / (dist + PROXIMITY_EPS)
    total = w.sum(-1, keepdim=True)
    return torch.where(total > 0, w / total.clamp(min=1e-12), torch.zeros_like(w))


def forces_from_contacts(joints: torch.Tensor, contacts: torch.Tensor, feet, fps: float, up_axis: int = 1,
                         lengths: torch.Tensor | None = None) -> torch.Tensor:
    """joints (B, T, J, 3), contacts (B, T, 4) bool [L_heel, L_toe, R_heel, R_toe] -> (B, T, 2, 16)."""
    joints = joints.float()
    contacts = contacts.bool()
    horiz = [a for a in range(3) if a != up_axis]
    total = total_vertical_force(joints, fps, up_axis, lengths)        # (B, T)
    com = joints.mean(-2)[..., horiz]                                   # (B, T, 2)
    pts = joints[:, :, list(feet)][..., horiz].view(*joints.shape[:2], 2, 2, 2)  # (B, T, foot, [heel, toe], 2)
    c = contacts.view(*contacts.shape[:2], 2, 2)                        # (B, T, foot, [heel, toe])
    foot_active = c.any(-1)                                             # (B, T, 2)
    foot_point = (pts * c[..., None]).sum(-2) / c.sum(-1, keepdim=True).clamp(min=1)
    foot_share = _proximity_share(foot_point, foot_active, com)         # (B, T, 2)
    part_share = _proximity_share(pts, c, com[:, :, None].expand(-1, -1, 2, -1))  # (B, T, 2, 2)
    per_part = total[..., None, None] * foot_share[..., None] * part_share       # (B, T, foot, [heel, toe])
    out = joints.new_zeros(*joints.shape[:2], 2, 16)
    n_back = BACK_CELLS.stop - BACK_CELLS.start
    n_front = FRONT_CELLS.stop - FRONT_CELLS.start
    out[..., BACK_CELLS] = (per_part[..., 0] / n_back)[..., None]
    out[..., FRONT_CELLS] = (per_part[..., 1] / n_front)[..., None]
    return out
