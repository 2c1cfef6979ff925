"""HumanML3D (22 joints, y-up, 20 fps) -> UnderPressure's 23-joint skeleton (z-up, 100 Hz).

The retargeting is a fixed, differentiable map, so V23 can also stand in for V22 inside the
cleanup (`UPAdapter`): joint correspondence (by joint name, as in StableMoFusion's
`scripts/train_UnderPressure_model.py`; UP's spine_4 is the midpoint of spine_3 and
the neck), (x, y, z) -> (x, -z, y), a per-sequence scale from the leg length, a height offset that
puts the lowest toe at UP's toe height, linear resampling 20 -> 100 Hz, and back to 20 Hz by
taking every 5th output frame.

The commands (convert joints, distil a V22 from a V23) are footskate.distill's.
"""

from __future__ import annotations

import torch
from torch import nn

from footskate.errors import FootskateError

# HumanML3D joint index -> UnderPressure joint index (UP's 4 = spine_4 has no counterpart).
HML_TO_UP = (0, 19, 15, 1, 20, 16, 2, 21, 17, 3, 22, 18, 5, 11, 7, 6, 12, 8, 13, 9, 14, 10)
UP_LEG = 0.84       # m, pelvis height minus ankle height of UP's rest skeleton (0.93 - 0.09)
UP_TOE_HEIGHT = 0.015
UP_FPS, HML_FPS = 100.0, 20.0


def _valid(lengths: torch.Tensor | None, b: int, t: int, device) -> torch.Tensor:
    if lengths is None:
        return torch.ones(b, t, dtype=torch.bool, device=device)
    return torch.arange(t, device=device)[None, :] < lengths.to(device)[:, None]


def to_up_skeleton(joints: torch.Tensor, lengths: torch.Tensor | None = None) -> torch.Tensor:
    """(B, T, 22, 3) HumanML3D y-up metres -> (B, T, 23, 3) UP z-up metres, same frame rate."""
    if joints.shape[-2:] != (22, 3):
        raise FootskateError(f"joints: expected (..., 22, 3) HumanML3D positions, got {tuple(joints.shape)}")
    b, t = joints.shape[:2]
    valid = _valid(lengths, b, t, joints.device).to(joints.dtype)
    count = valid.sum(1).clamp(min=1)
    leg = ((joints[:, :, [4, 5]] - joints[:, :, [1, 2]]).norm(dim=-1)
           + (joints[:, :, [7, 8]] - joints[:, :, [4, 5]]).norm(dim=-1)).mean(-1)        # (B, T)
    scale = UP_LEG / ((leg * valid).sum(1) / count).clamp(min=1e-3)                     # (B,)
    toe_y = torch.where(valid.bool(), joints[:, :, [10, 11], 1].amin(-1), torch.full_like(leg, float("inf")))
    lift = UP_TOE_HEIGHT - scale * toe_y.amin(1)                                         # (B,)
    zup = torch.stack([joints[..., 0], -joints[..., 2], joints[..., 1]], -1) * scale[:, None, None, None]
    zup = zup + torch.stack([torch.zeros_like(lift), torch.zeros_like(lift), lift], -1)[:, None, None]
    up = zup.new_zeros(b, t, 23, 3)
    up[:, :, list(HML_TO_UP)] = zup
    up[:, :, 4] = 0.5 * (up[:, :, 3] + up[:, :, 5])
    return up


def resample(x: torch.Tensor, factor: int, lengths: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Linear upsampling along dim 1 by an integer factor: T frames -> (T-1)·factor + 1."""
    b, t = x.shape[:2]
    lengths = lengths if lengths is not None else torch.full((b,), t, dtype=torch.long)
    pos = torch.arange((t - 1) * factor + 1, device=x.device, dtype=x.dtype) / factor
    lo = pos.floor().long().clamp(max=t - 1)
    hi = (lo + 1).clamp(max=t - 1)
    w = (pos - lo.to(x.dtype)).view(1, -1, *([1] * (x.dim() - 2)))
    return x[:, lo] * (1 - w) + x[:, hi] * w, (lengths - 1) * factor + 1


class UPAdapter(nn.Module):
    """A V23 that takes HumanML3D joints at 20 fps: retarget, 100 Hz, V23, back to 20 fps."""

    def __init__(self, v23: nn.Module):  # a footskate.vgrf.VGRFNet of 23 joints
        super().__init__()
        if v23.num_joints != 23:
            raise FootskateError("UPAdapter needs a 23-joint (UnderPressure) vGRF network")
        self.v23 = v23
        self.num_joints = 22
        self.factor = int(UP_FPS / HML_FPS)

    def forward(self, joints: torch.Tensor, lengths: torch.Tensor | None = None) -> torch.Tensor:
        up, up_lengths = resample(to_up_skeleton(joints, lengths), self.factor, lengths)
        forces = self.v23(up, up_lengths if lengths is not None else None)
        return forces[:, :: self.factor]


