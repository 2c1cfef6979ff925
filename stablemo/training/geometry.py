"""Optional geometric training losses on the joints recovered from features (MDM, Tevet et al. 2023, §3).

With x̂0 the network's clean-motion estimate and x0 the data, both de-normalised and turned into joint
positions by stablemo.motion.features.features_to_joints (FK below):

- positions:    ||FK(x0) - FK(x̂0)||² per joint coordinate (MDM's L_pos);
- velocities:   ||ΔFK(x0) - ΔFK(x̂0)||² of the per-frame displacements Δ (MDM's L_vel);
- foot_contact: ||ΔFK(x̂0)||² of the four contact joints on the frames the ground truth's contact
  channels mark as planted (> 0.5): a planted foot should not move (MDM's L_foot);
- bone_lengths: (|bone(x̂0)| - |bone(x0)|)² per bone and frame: ric features do not tie joints to
  fixed bone lengths, so nothing but this keeps a predicted skeleton from stretching;
- rotations: ||rot6d(x̂0) - IK(FK(x̂0))||², x̂0's own 6D rotation columns against those its joints
  imply (the columns extraction computes from joints, stablemo.motion.extract_torch.rotation_columns,
  seen from x̂0's own root rotation). Zero on extracted data; on a network's output the two can
  disagree, and the finishing step, which writes the columns its joints imply, then changes what an
  evaluator reads (docs/inference.md, "The finishing step"). It compares x̂0 with itself, not with the
  clip, so it is valid in distillation too.

Each term is a per-clip mean over its valid entries (joints × coordinates × valid frames, as MDM's
masked L2 averages), so padding frames contribute nothing and a clip's value does not depend on how
much padding its batch has: recovery runs forward in time (a frame's joints depend only on earlier
frames), so padding cannot leak into the valid frames, and padded entries are selected away rather
than multiplied by zero (an Inf there would make the sum NaN). Displacements count where both
frames are valid. Positions are in metres whatever the skeleton's units (KIT's millimetres
are scaled by 1e-3), so a weight means the same for both datasets; displacements are per frame
(MDM's definition), i.e. per 1/20 s on HumanML3D and 1/12.5 s on KIT.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import torch

from stablemo.errors import StableMoError
from stablemo.motion.extract_torch import rotation_columns
from stablemo.motion.features import feature_slices, features_to_joints, recover_root
from stablemo.motion.skeleton import Skeleton, get_skeleton

# the config's term names, in the order they are computed and logged, with their log names
GEOMETRY_TERMS = {"positions": "loss_pos", "velocities": "loss_vel", "foot_contact": "loss_foot",
                  "bone_lengths": "loss_bone", "rotations": "loss_rot"}
METRES_PER_UNIT = {"m": 1.0, "mm": 1e-3}
# the feature's contact channels are 0/1 labels; the threshold also binarises a smoothed or averaged one
CONTACT_THRESHOLD = 0.5
# keeps the length's gradient finite at a zero-length bone (d sqrt(s)/ds at 0); cancels exactly
# between prediction and ground truth when both bones are equal
_LENGTH_EPS = 1e-12


def geometry_weights(config: Mapping | None) -> dict[str, float]:
    """The non-zero weights of a `model.geometry` config, validated ({} when absent or all zero)."""
    if config is None:
        return {}
    if not isinstance(config, Mapping):
        raise StableMoError(f"model.geometry: expected a mapping of term -> weight "
                            f"({', '.join(GEOMETRY_TERMS)}), got {config!r}")
    for key, value in config.items():
        if key not in GEOMETRY_TERMS:
            raise StableMoError(f"model.geometry.{key}: unknown term (choose from {', '.join(GEOMETRY_TERMS)})")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
            raise StableMoError(f"model.geometry.{key}: the weight must be a finite number >= 0, got {value!r}")
    return {key: float(config[key]) for key in GEOMETRY_TERMS if float(config.get(key, 0.0)) > 0.0}


def _masked_mean(values: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Per-clip mean of values (B, N, ...) over the entries of valid (B, N) rows. -> (B,)"""
    per_row = values.flatten(2).mean(dim=2)  # (B, N)
    kept = torch.where(valid, per_row, torch.zeros_like(per_row))
    return kept.sum(dim=1) / valid.sum(dim=1).clamp(min=1)


class GeometricLoss:
    """The terms named in `weights` for one dataset (its skeleton and model Mean/Std)."""

    def __init__(self, weights: Mapping[str, float], skeleton: Skeleton | str, mean, std) -> None:
        self.weights = geometry_weights(weights)
        self.skeleton = get_skeleton(skeleton)
        if self.skeleton.units not in METRES_PER_UNIT:
            raise StableMoError(f"skeleton {self.skeleton.name}: units {self.skeleton.units!r} not supported by model.geometry")
        self.metres = METRES_PER_UNIT[self.skeleton.units]
        self.mean = torch.as_tensor(mean, dtype=torch.float32)  # (D,)
        self.std = torch.as_tensor(std, dtype=torch.float32)  # (D,)
        if self.mean.shape != (self.skeleton.feature_dim,) or self.std.shape != self.mean.shape:
            raise StableMoError(f"model.geometry: Mean/Std of shape {tuple(self.mean.shape)}/{tuple(self.std.shape)} "
                                f"do not fit skeleton {self.skeleton.name} ({self.skeleton.feature_dim} features)")
        self.contacts = feature_slices(self.skeleton)["contacts"]
        self.rot6d = feature_slices(self.skeleton)["rot6d"]
        self.contact_joints = list(self.skeleton.contact_joints)
        self.children = [j for j, p in enumerate(self.skeleton.parents) if p >= 0]
        self.bone_parents = [self.skeleton.parents[j] for j in self.children]
        self._stats: dict[torch.device, tuple[torch.Tensor, torch.Tensor]] = {}

    def _stats_on(self, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
        if device not in self._stats:
            self._stats[device] = (self.mean.to(device), self.std.to(device))
        return self._stats[device]

    def joints(self, normalised: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Model-space features (B, T, D) -> joints in metres (B, T, J, 3) and raw features (B, T, D)."""
        mean, std = self._stats_on(normalised.device)
        raw = normalised.float() * std + mean
        return features_to_joints(raw, self.skeleton) * self.metres, raw

    def bone_lengths(self, joints: torch.Tensor) -> torch.Tensor:
        """(B, T, J, 3) -> (B, T, J-1) lengths of the bones parent -> child."""
        bones = joints[:, :, self.children] - joints[:, :, self.bone_parents]
        return (bones.square().sum(dim=-1) + _LENGTH_EPS).sqrt()

    def terms(self, pred_x0: torch.Tensor, x0: torch.Tensor, mask: torch.Tensor) -> dict[str, torch.Tensor]:
        """Per-clip unweighted terms {name: (B,)} for the configured names.

        pred_x0, x0: (B, T, D) model-space (normalised) features; mask: (B, T) bool valid frames.
        Computed in float32 outside autocast: joints are cumulative sums over up to 196 frames.
        """
        out: dict[str, torch.Tensor] = {}
        if not self.weights:
            return out
        mask = mask.bool()
        with torch.autocast(device_type=x0.device.type, enabled=False):
            pred_joints, pred_raw = self.joints(pred_x0)  # (B, T, J, 3), (B, T, D)
            with torch.no_grad():
                true_joints, true_raw = self.joints(x0)
            pairs = mask[:, 1:] & mask[:, :-1]  # (B, T-1): displacement i -> i+1 of two valid frames
            pred_step = pred_joints[:, 1:] - pred_joints[:, :-1]  # (B, T-1, J, 3)
            if "positions" in self.weights:
                out["positions"] = _masked_mean((pred_joints - true_joints).square(), mask)
            if "velocities" in self.weights:
                true_step = true_joints[:, 1:] - true_joints[:, :-1]
                out["velocities"] = _masked_mean((pred_step - true_step).square(), pairs)
            if "foot_contact" in self.weights:
                # contact label of frame i covers the displacement i -> i+1 (as extraction labels it)
                planted = true_raw[:, :-1, self.contacts] > CONTACT_THRESHOLD  # (B, T-1, 4)
                feet = pred_step[:, :, self.contact_joints].square()  # (B, T-1, 4, 3)
                out["foot_contact"] = _masked_mean(torch.where(planted[..., None], feet, torch.zeros_like(feet)), pairs)
            if "bone_lengths" in self.weights:
                with torch.no_grad():
                    true_lengths = self.bone_lengths(true_joints)
                out["bone_lengths"] = _masked_mean((self.bone_lengths(pred_joints) - true_lengths).square(), mask)
            if "rotations" in self.weights:
                out["rotations"] = _masked_mean(self.rotation_gap(pred_raw, pred_joints).square(), pairs)
        return out

    def rotation_gap(self, raw: torch.Tensor, joints: torch.Tensor) -> torch.Tensor:
        """De-normalised features raw (B, T, D) and their joints (B, T, J, 3) -> (B, T-1, C): their 6D
        rotation columns less those the joints imply (as extraction computes them, seen from the
        features' own root rotation; rotations do not depend on the joints' units). Row t needs
        frame t+1 (extraction's velocity columns), so the last frame has none."""
        q, _ = recover_root(raw)  # (B, T, 4)
        implied = rotation_columns(joints[:, :-1].permute(2, 3, 0, 1), q[:, :-1].permute(2, 0, 1)[None],
                                   self.skeleton)  # (J-1, 6, B, T-1)
        return raw[:, :-1, self.rot6d] - implied.permute(2, 3, 0, 1).flatten(2)
