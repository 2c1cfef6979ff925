"""Where the body faces against where it travels: the check a viewer makes of a followed path.

A path can be met to the centimetre by a body that walks it sideways or backwards (the joint errors
of stablemo.eval.control cannot see that). Per frame (stablemo.motion.heading): the facing of the
hips and shoulders, smoothed over FACING_SMOOTH_S against the gait's sway; the travel of the pelvis
over a centred half-second window; moving frames are those faster than MOVING_SPEED_M_S (standing
has no direction of travel). The angle between them is 0 for a forward walk, 180° for a backward
walk, 90° for side steps: exactly so on every synthetic walk, backward walk, side step, jog, run and
circle (tests/test_heading.py). Batched over motions; padding never votes.
"""

from __future__ import annotations

import numpy as np
import torch

from stablemo.eval.kinematics import prepare, valid_mask
from stablemo.motion.heading import facing_yaw, travel, wrap
from stablemo.motion.plausible import scale

FACING_SMOOTH_S = 0.25
MOVING_SPEED_M_S = 0.3  # below a slow walk (~0.6 m/s)
BACKWARD_DEG = 135.0  # facing more than this away from travel: walking backwards
SIDEWAYS_DEG = 45.0  # between this and BACKWARD_DEG: walking sideways


def facing_vs_travel(joints, lengths, skeleton) -> dict[str, torch.Tensor]:
    """Per frame: `angle` (B, T) degrees in [0, 180] between facing and travel, `signed` (B, T)
    degrees (travel yaw minus facing yaw), `moving` (B, T) bool (valid frames faster than
    MOVING_SPEED_M_S)."""
    j, n, skel = prepare(joints, lengths, skeleton)
    face = facing_yaw(j, skel, FACING_SMOOTH_S * skel.fps)
    way, speed = travel(j[:, :, 0][..., [0, 2]], n, skel.fps)
    deg = torch.rad2deg(wrap(way - face))
    moving = (speed > MOVING_SPEED_M_S * scale(skel)) & valid_mask(n, j.shape[1])
    return {"angle": deg.abs(), "signed": deg, "moving": moving}


def heading_measures(joints, lengths, skeleton, reference=None) -> dict[str, np.ndarray]:
    """(B,) per motion: `facing_deg` the median facing-vs-travel angle over moving frames (NaN when
    the motion never moves), `backward` / `sideways` the share of moving frames walked backwards
    (> BACKWARD_DEG) / sideways (SIDEWAYS_DEG..BACKWARD_DEG). With `reference` joints (the motions
    whose path was followed, same shapes), only frames where the reference walks forward count:
    backwards/sideways *without being asked*."""
    ft = facing_vs_travel(joints, lengths, skeleton)
    angle, moving = ft["angle"], ft["moving"]
    if reference is not None:
        ref = facing_vs_travel(reference, lengths, skeleton)
        moving = moving & ref["moving"] & (ref["angle"] < SIDEWAYS_DEG)
    count = moving.sum(1).double()
    back = ((angle > BACKWARD_DEG) & moving).sum(1) / count
    side = ((angle > SIDEWAYS_DEG) & (angle <= BACKWARD_DEG) & moving).sum(1) / count
    med = torch.stack([a[m].median() if m.any() else torch.tensor(float("nan"), dtype=a.dtype)
                       for a, m in zip(angle, moving)])
    return {"facing_deg": med.numpy(), "backward": back.numpy(), "sideways": side.numpy()}


def facing_error(joints, reference, lengths, skeleton) -> np.ndarray:
    """(B,) degrees: per motion, the median over frames where both move of the difference between
    the generated and the reference motion's signed facing-vs-travel angles: 0 when the body walks
    its path the way the motion the path came from did (forward, backwards or sideways alike);
    NaN where they never move together."""
    gen = facing_vs_travel(joints, lengths, skeleton)
    ref = facing_vs_travel(reference, lengths, skeleton)
    both = gen["moving"] & ref["moving"]
    diff = torch.rad2deg(wrap(torch.deg2rad(gen["signed"] - ref["signed"]))).abs()
    return torch.stack([d[m].median() if m.any() else torch.tensor(float("nan"), dtype=d.dtype)
                        for d, m in zip(diff, both)]).numpy()


__all__ = ["facing_error", "facing_vs_travel", "heading_measures"]
