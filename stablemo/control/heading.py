"""A followed path steers the body: the root turns toward the path's direction of travel.

Path guidance (stablemo.control.guidance.project_root) and a ControlNet move the pelvis along a
path, but the root's rotation is the network's: on a curve or a path that leaves sideways the body
walks it sideways or backwards (a moonwalk), with the joint errors at zero. Here the root's yaw is
re-steered at every sampler step, keeping the path exactly:

1. The gait's own angle between travel and facing, from the network's predicted x0: the root's
   velocities are stored in the body's facing frame (HumanML3D features, cols 1-2), so their sum
   over the motion points where the body walks relative to where it faces. Forward walking gives
   0, "walks backwards" 180, side steps +-90. It is snapped to the nearest of those four gaits, so
   what the text asks decides (and a forward walk pushed sideways by its path is not taken for a
   side step at a few degrees off). Where the network hardly travels on its own (slower than
   STILL_M_S over the motion: it stands, or cannot do the gait asked) the gait comes from the
   text's words when they name one (gait_from_text: backwards, side steps to a side), else forward.
2. The wanted facing per frame: the path's direction of travel (a centred half-second difference,
   stablemo.motion.heading.travel) minus that gait angle. Where the path is slower than a slow walk
   the network's own facing is kept (standing has no direction of travel), blending in between.
3. The yaw correction is smoothed over time (no snap at a path's kink) and ramps in over the
   motion's first RAMP_S: frame 0 faces +z by the representation's definition, so a path that
   starts elsewhere is begun by turning toward it.
4. The root's velocities are rewritten in the new facing from the same global steps: the path is
   unchanged to float precision, the body (stored relative to the root) turns with the root.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import torch

from stablemo.diffusion.hooks import StepState
from stablemo.motion.features import recover_root
from stablemo.motion.heading import gaussian_smooth, travel, unwrap, wrap
from stablemo.motion.quaternion import qrot
from stablemo.motion.skeleton import get_skeleton

STILL_M_S = 0.15  # path slower than this: the network's facing is kept
WALKING_M_S = 0.4  # path faster than this: the facing follows the path fully
SMOOTH_S = 0.2  # Gaussian sigma of the yaw correction over time
RAMP_S = 0.5  # the correction ramps in from frame 0, which faces +z by definition


_SIDEWAYS = re.compile(r"\b(side[- ]?steps?|side[- ]?stepping|sideways|shuffles? (to|towards))\b[^.,;]*?\b(left|right)\b")
_BACKWARD = re.compile(r"\b(backwards?|moonwalk(s|ing)?|walks? back(?! and forth)|steps? back|reverses?)\b")


def gait_from_text(text: str) -> float | None:
    """The gait a text names, as the angle of travel to facing in radians (left of the body is
    +x: side steps to the left +pi/2, to the right -pi/2; backwards pi), or None when it names
    none (a forward walk, or no walk)."""
    low = text.lower()
    side = _SIDEWAYS.search(low)
    if side:
        return math.pi / 2 if side.group(3) == "left" else -math.pi / 2
    if _BACKWARD.search(low):
        return math.pi
    return None


def named_gaits(texts) -> torch.Tensor:
    """(B,) gait_from_text of each text, NaN where a text names none."""
    return torch.tensor([math.nan if (g := gait_from_text(t)) is None else g for t in texts])


def text_gait(named: torch.Tensor | None, batch: int, device) -> torch.Tensor:
    """(B,) radians: the texts' gaits (named, NaN for none) where they name one, else forward (0)."""
    if named is None:
        return torch.zeros(batch, device=device)
    return torch.nan_to_num(named.to(device).float(), nan=0.0)


def gait_angle(features: torch.Tensor, lengths: torch.Tensor, fps: float = 20.0, per_metre: float = 1.0,
               named: torch.Tensor | None = None) -> torch.Tensor:
    """(B,) radians: where the body walks relative to where it faces (0 forward, pi backwards,
    +-pi/2 sideways), snapped to those four, from the root's facing-frame velocities of features
    (B, T, D) de-normalised over each motion's valid steps. named: (B,) the texts' gaits
    (gait_from_text, NaN for none), used where the network travels slower than STILL_M_S."""
    T = features.shape[1]
    steps = (torch.arange(T - 1, device=features.device)[None] < (lengths[:, None] - 1)).to(features.dtype)
    local = (features[:, :-1, 1:3] * steps[..., None]).sum(1)  # (B, 2): x (sideways), z (forward)
    angle = torch.round(torch.atan2(local[:, 0], local[:, 1]) / (math.pi / 2)) * (math.pi / 2)
    speed = local.norm(dim=-1) * fps / ((lengths - 1).clamp(min=1).to(features.dtype) * per_metre)
    fallback = torch.zeros_like(angle) if named is None else torch.nan_to_num(named.to(angle), nan=0.0)
    return torch.where(speed < STILL_M_S, fallback, angle)


def _yaw_to_angle(yaw: torch.Tensor) -> torch.Tensor:
    # recover_root's quaternion (cos a, 0, sin a, 0) turns the world by 2a about y: the facing's
    # yaw (atan2(x, z)) is -2a
    return -0.5 * yaw


def steer_heading(features: torch.Tensor, lengths: torch.Tensor, fps: float, per_metre: float = 1.0,
                  steer: torch.Tensor | None = None, gait: torch.Tensor | None = None) -> torch.Tensor:
    """Features (B, T, D) de-normalised whose root faces its own path's direction of travel (see
    the module docstring), the path kept; steer: (B,) bool, the samples to steer (default all);
    gait: (B,) radians, the walk's angle to the facing (default gait_angle of `features`; give the
    network's own when `features` has had its path moved already). Samples not steered come back
    unchanged."""
    _B, T, _ = features.shape
    if T < 3:
        return features
    _q, pos = recover_root(features)  # (B, T, 4), (B, T, 3)
    angle = torch.cat([torch.zeros_like(features[:, :1, 0]), features[:, :-1, 0].cumsum(1)], 1)  # (B, T)
    yaw = -2.0 * angle
    way, speed = travel(pos[..., [0, 2]], lengths, fps)
    gait = gait_angle(features, lengths, fps, per_metre) if gait is None else gait
    wanted = way - gait[:, None]
    weight = ((speed / per_metre - STILL_M_S) / (WALKING_M_S - STILL_M_S)).clamp(0, 1)
    weight = weight * weight * (3 - 2 * weight)  # smoothstep
    frames = torch.arange(T, device=features.device, dtype=features.dtype)
    ramp = (frames / max(RAMP_S * fps, 1.0)).clamp(max=1.0)[None]
    # blend the wanted and the network's facing as unit vectors (no angle wraps), smooth over time,
    # then the correction unwrapped along the motion: it starts within half a turn and never jumps
    want = torch.stack([torch.sin(wanted), torch.cos(wanted)], -1)
    own = torch.stack([torch.sin(yaw), torch.cos(yaw)], -1)
    goal = gaussian_smooth(weight[..., None] * want + (1 - weight[..., None]) * own, SMOOTH_S * fps, dim=1)
    correction = unwrap(wrap(torch.atan2(goal[..., 0], goal[..., 1]) - yaw), dim=1) * ramp
    new_yaw = yaw + correction
    new_angle = _yaw_to_angle(new_yaw)
    new_q = torch.stack([torch.cos(new_angle), torch.zeros_like(new_angle), torch.sin(new_angle),
                         torch.zeros_like(new_angle)], -1)
    step = pos[:, 1:] - pos[:, :-1]  # (B, T-1, 3) global steps, kept
    step = step * torch.tensor([1.0, 0.0, 1.0], device=features.device, dtype=features.dtype)
    local = qrot(new_q[:, 1:], step)  # velocity k-1 in the facing frame of k (as recover_root reads it)
    out = features.clone()
    out[:, :-1, 0] = new_angle[:, 1:] - new_angle[:, :-1]
    out[:, :-1, 1] = local[..., 0]
    out[:, :-1, 2] = local[..., 2]
    if steer is None:
        return out
    return torch.where(steer[:, None, None], out, features)


@dataclass
class FaceTravel:
    """A sample hook: the root of each `steer` sample faces its path's direction of travel at every
    step (steer_heading); for a ControlNet, whose hint moves the pelvis and leaves the facing to the
    network. The network's x0 already walks where the hint pulls it (a path behind the body comes
    out as a backward walk), so its own gait is not asked: the gait is the text's (named: (B,)
    gait_from_text, NaN for none: forward). mean/std: (D,) the model's feature statistics; steer:
    (B,) bool."""

    mean: torch.Tensor
    std: torch.Tensor
    skeleton: object
    steer: torch.Tensor
    named: torch.Tensor | None = None

    def active(self, step: int, steps: int) -> bool:
        return True

    def __call__(self, state: StepState) -> torch.Tensor:
        x0 = state.x0
        dev = x0.device
        skel = get_skeleton(self.skeleton)
        mean, std = self.mean.to(dev).float(), self.std.to(dev).float()
        lengths = torch.tensor(state.lengths, device=dev)
        feats = x0.float() * std + mean
        gait = text_gait(self.named, x0.shape[0], dev)
        feats = steer_heading(feats, lengths, skel.fps, skel.per_metre, self.steer.to(dev), gait)
        return ((feats - mean) / std).to(x0.dtype)


__all__ = ["FaceTravel", "gait_angle", "gait_from_text", "named_gaits", "steer_heading"]
