"""What a user asks to keep or to reach, per prompt, checked against the motion it applies to.

- `Inpaint(features (T, D), mask (T, D) or (T,))`: known feature values (the `.features.npy`
  layout, de-normalised) and which entries are known; a (T,) mask keeps whole frames.
- `JointControl(positions (T, J, 3), mask (T, J))`: global joint positions in the dataset's units
  (HumanML3D: metres; KIT-ML: millimetres), y up, in the generator's frame (the motion starts at
  the origin facing +z), and which (frame, joint) entries are targets. Positions where the mask is False are ignored (they may be NaN).

Both may be shorter than the motion (the rest is free); entries past the motion's length that are
asked for are an error, not silently dropped.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from stablemo.errors import StableMoError
from stablemo.motion.plausible import check_targets
from stablemo.motion.skeleton import get_skeleton


def _array(value, what: str, dtype) -> np.ndarray:
    arr = value.detach().cpu().numpy() if torch.is_tensor(value) else np.asarray(value)
    if dtype is bool:
        if arr.dtype != np.bool_:
            if not np.issubdtype(arr.dtype, np.number) or not np.isin(arr, (0, 1)).all():
                raise StableMoError(f"{what}: must be boolean (or 0/1), got {arr.dtype}")
            arr = arr.astype(bool)
        return arr
    if not np.issubdtype(arr.dtype, np.number):
        raise StableMoError(f"{what}: expected numbers, got dtype {arr.dtype}")
    return arr.astype(np.float32)


def _check_length(mask_any_frame: np.ndarray, length: int, what: str) -> None:
    """mask_any_frame: (T_spec,) bool; frames >= length must not be asked for."""
    late = np.flatnonzero(mask_any_frame[length:])
    if late.size:
        raise StableMoError(f"{what}: asks for frame {length + late[0]}, but the motion has {length} frames "
                            f"(frames 0-{length - 1})")


@dataclass
class Inpaint:
    """Known features of one motion: features (T, D) de-normalised; mask (T, D) or (T,) bool."""

    features: object
    mask: object

    def resolve(self, length: int, feature_dim: int, what: str = "inpaint") -> tuple[np.ndarray, np.ndarray]:
        """(values (length, D) float32 with 0 where unknown, mask (length, D) bool)."""
        feats = _array(self.features, f"{what}.features", float)
        mask = _array(self.mask, f"{what}.mask", bool)
        if feats.ndim != 2 or feats.shape[1] != feature_dim:
            raise StableMoError(f"{what}.features: expected shape (T, {feature_dim}), got {feats.shape}")
        if mask.ndim == 1:
            mask = np.repeat(mask[:, None], feature_dim, axis=1)
        if mask.shape != feats.shape:
            raise StableMoError(f"{what}.mask: shape {mask.shape} does not match the features' {feats.shape}")
        if not mask.any():
            raise StableMoError(f"{what}.mask: keeps nothing (all False)")
        _check_length(mask.any(1), length, what)
        if not np.isfinite(feats[mask]).all():
            raise StableMoError(f"{what}.features: NaN or Inf in a kept entry")
        values = np.zeros((length, feature_dim), np.float32)
        keep = np.zeros((length, feature_dim), bool)
        n = min(length, feats.shape[0])
        keep[:n] = mask[:n]
        values[:n] = np.where(mask[:n], feats[:n], 0.0)
        return values, keep


@dataclass
class JointControl:
    """Joint targets of one motion: positions (T, J, 3) metres; mask (T, J) bool."""

    positions: object
    mask: object

    def resolve(self, length: int, skeleton, what: str = "control") -> tuple[np.ndarray, np.ndarray]:
        """(targets (length, J, 3) float32 with 0 where free, mask (length, J) bool)."""
        skel = get_skeleton(skeleton)
        J = skel.num_joints
        pos = _array(self.positions, f"{what}.positions", float)
        mask = _array(self.mask, f"{what}.mask", bool)
        if pos.ndim != 3 or pos.shape[1:] != (J, 3):
            raise StableMoError(f"{what}.positions: expected shape (T, {J}, 3) for the {skel.name} skeleton "
                                f"({J} joints), got {pos.shape}")
        if mask.shape != pos.shape[:2]:
            raise StableMoError(f"{what}.mask: expected shape {pos.shape[:2]} (T, joints) to match the positions, "
                                f"got {mask.shape}")
        if not mask.any():
            raise StableMoError(f"{what}.mask: selects no (frame, joint) target (all False)")
        _check_length(mask.any(1), length, what)
        if not np.isfinite(pos[mask]).all():
            t, j = np.argwhere(mask & ~np.isfinite(pos).all(-1))[0]
            raise StableMoError(f"{what}.positions: NaN or Inf at frame {t}, joint {j} ({skel.joint_names[j]}), "
                                "which the mask selects")
        tolerance = 0.01 if skel.units == "m" else 10.0  # 1 cm
        if mask[0, 0] and np.abs(pos[0, 0, [0, 2]]).max() > tolerance:
            raise StableMoError(f"{what}.positions: the root at frame 0 is at x={pos[0, 0, 0]:.3f}, z={pos[0, 0, 2]:.3f}; "
                                "a motion starts at the origin (x = z = 0): express the targets in the motion's own "
                                "frame (subtract the first pelvis position, see docs/control.md)")
        check_targets(pos, mask, skel, f"{what}.positions")
        targets = np.zeros((length, J, 3), np.float32)
        keep = np.zeros((length, J), bool)
        n = min(length, pos.shape[0])
        keep[:n] = mask[:n]
        targets[:n] = np.where(mask[:n, :, None], pos[:n], 0.0)
        return targets, keep


__all__ = ["Inpaint", "JointControl"]


@dataclass
class ControlTargets:
    """A batch's joint targets as the pipeline resolved them from the requests' JointControl specs:
    targets (B, T, J, 3) in dataset units, zero where free; mask (B, T, J) bool. A kind that reads
    them (a ControlNet) takes them in `make_denoiser(..., control=)`; the others ignore them."""

    targets: torch.Tensor
    mask: torch.Tensor
