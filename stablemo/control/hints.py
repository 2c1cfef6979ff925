"""The ControlNet's hint: global joint targets as a per-frame input, and the training draws of hints.

A hint is (B, T, 4 J): the target positions (dataset units divided by `scale`, zero where there
is no target) and the (frame, joint) mask as 0/1, side by side. With `path=True` it is (B, T, 12 J):
8 more channels per joint describe the targets' path where neighbouring frames are targets too --
its velocity (3), that velocity's mask, its ground speed, its ground direction (2) and its turning
rate. Those are what the root's feature channels hold (HumanML3D's root features are a rotation
velocity, a velocity in the body's frame and a height), so the network reads them off locally
instead of differentiating positions itself, and a dense path needs no long receptive field to
tell the direction of travel from the turning. Training hints follow MotionLCM
(which follows OmniControl, Xie et al. 2024): per sample one joint from {pelvis, left foot, right foot, head, left
wrist, right wrist} and a random set of frames; the targets are the clip's own joints.
"""

from __future__ import annotations

import torch

from stablemo.motion.extract_torch import known_neighbours

# HumanML3D joint indices: pelvis 0, left foot 10, right foot 11, head 15, left wrist 20, right wrist 21
TRAIN_JOINTS = (0, 10, 11, 15, 20, 21)


# per-frame differences times 20: m/s (and rad/s) at HumanML3D's 20 fps, of order 1 like the positions
PATH_SCALE = 20.0
PATH_CHANNELS = 8  # per joint: velocity (3), its mask, ground speed, ground direction (2), turning rate
MOVING_SPEED = 0.05  # m/s (in PATH_SCALE units): below it a path has no direction


def hint_channels(joints: int, path: bool) -> int:
    """The hint's width: 4 J, or 12 J with the path channels."""
    return (4 + PATH_CHANNELS * bool(path)) * joints


def hint_input(targets: torch.Tensor, mask: torch.Tensor, scale: float = 1.0, path: bool = False) -> torch.Tensor:
    """targets (B, T, J, 3), mask (B, T, J) bool -> hint (B, T, 4 J) float32, or (B, T, 12 J) with
    the path channels. Channels [3 J, 4 J) are always the mask (the ControlNet's gate reads them)."""
    m = mask.to(torch.float32)
    pos = torch.where(mask[..., None], targets.to(torch.float32) / scale, torch.zeros((), device=targets.device))
    parts = [pos.flatten(2), m]
    if path:
        parts.append(path_features(pos, mask).flatten(2))
    return torch.cat(parts, dim=-1)


def toward_next_target(pos: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """One joint's targets pos (B, T, 2) on the floor (zero off the mask), mask (B, T) bool -> the
    direction (B, T, 2) and speed (B, T) of the chord from the last target at or before frame t (the
    origin, where the motion starts, before the first) to the first target after t: a unit vector,
    and the chord's length over its frames in PATH_SCALE units (m/s); both zero where no target
    follows or the chord moves slower than MOVING_SPEED. Dense targets give each frame its step;
    sparse ones the straight line between them, walked evenly."""
    B, T = mask.shape
    last, upcoming = known_neighbours(mask)  # (B, T): last target <= t (-1: none yet), first >= t
    following = torch.cat([upcoming[:, 1:], torch.full_like(upcoming[:, :1], T)], 1)  # first target > t, T: none
    start = torch.where((last >= 0)[..., None], pos.gather(1, last.clamp(min=0)[..., None].expand(B, T, 2)),
                        torch.zeros_like(pos))
    end = pos.gather(1, following.clamp(max=T - 1)[..., None].expand(B, T, 2))
    chord = end - start  # (B, T, 2)
    size = chord.norm(dim=-1)
    span = (following - last.clamp(min=0)).clamp(min=1)  # frames the chord is walked over
    speed = size * PATH_SCALE / span
    moving = (following < T) & (speed > MOVING_SPEED)
    direction = torch.where(moving[..., None], chord / size.clamp(min=1e-9)[..., None], torch.zeros_like(chord))
    return direction, torch.where(moving, speed, torch.zeros_like(speed))


def path_features(pos: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """pos (B, T, J, 3) targets (zero off the mask), mask (B, T, J) -> (B, T, J, 8), zero where a
    target has no target neighbour. Velocity: central difference where both neighbours are targets,
    one-sided where one is; direction and turning only where the path moves (> MOVING_SPEED)."""
    zero = torch.zeros_like(mask[:, :1])
    prev_ok = torch.cat([zero, mask[:, :-1]], 1) & mask  # (B, T, J): frame t-1 is a target too
    next_ok = torch.cat([mask[:, 1:], zero], 1) & mask
    p_prev = torch.cat([pos[:, :1], pos[:, :-1]], 1)
    p_next = torch.cat([pos[:, 1:], pos[:, -1:]], 1)
    central = (p_next - p_prev) / 2
    vel = torch.where((prev_ok & next_ok)[..., None], central,
                      torch.where(next_ok[..., None], p_next - pos,
                                  torch.where(prev_ok[..., None], pos - p_prev, torch.zeros_like(pos))))
    vel = vel * PATH_SCALE
    has_vel = prev_ok | next_ok
    ground = vel[..., [0, 2]]  # (B, T, J, 2): x, z
    speed = ground.norm(dim=-1)
    moving = has_vel & (speed > MOVING_SPEED)
    direction = torch.where(moving[..., None], ground / speed.clamp(min=MOVING_SPEED)[..., None], torch.zeros_like(ground))
    # turning: the signed angle from the direction one frame back to the one a frame ahead, per frame
    d_prev = torch.cat([direction[:, :1], direction[:, :-1]], 1)
    d_next = torch.cat([direction[:, 1:], direction[:, -1:]], 1)
    m_prev = torch.cat([zero, moving[:, :-1]], 1)
    m_next = torch.cat([moving[:, 1:], zero], 1)
    both = moving & m_prev & m_next
    sin = d_prev[..., 1] * d_next[..., 0] - d_prev[..., 0] * d_next[..., 1]
    cos = (d_prev * d_next).sum(-1)
    turning = torch.where(both, torch.atan2(sin, cos) / 2 * PATH_SCALE, torch.zeros_like(speed))
    # vel (so speed) is already zero where there is no velocity
    return torch.cat([vel, has_vel[..., None].float(), speed[..., None], direction, turning[..., None]], dim=-1)


def sample_hint_mask(motion_mask: torch.Tensor, joints: int, generator: torch.Generator,
                     choices: tuple[int, ...] = TRAIN_JOINTS, dense_prob: float = 0.25,
                     empty_prob: float = 0.0) -> torch.Tensor:
    """Which (frame, joint) entries of each clip are hints: (B, T, J) bool.

    Per sample: with `empty_prob` no hint (such a sample gets no injection, so it teaches nothing:
    the per-sample gate in network.py; kept for ablations); else one joint
    from `choices`, and with `dense_prob` all its valid frames, otherwise each valid frame kept
    with a probability drawn log-uniformly between 1 / length and 1 (from one keyframe to nearly
    dense), at least one frame. Draws come from `generator` only (CPU), so a resumed run repeats them.
    """
    B, T = motion_mask.shape
    valid = motion_mask.cpu()
    lengths = valid.sum(1).clamp(min=1).to(torch.float32)
    joint = torch.tensor(choices)[torch.randint(0, len(choices), (B,), generator=generator)]
    u = torch.rand(B, generator=generator)
    density = torch.exp(torch.log(1.0 / lengths) * torch.rand(B, generator=generator))  # (B,) in [1/n, 1]
    dense = u < dense_prob
    empty = u > 1.0 - empty_prob
    keep = (torch.rand(B, T, generator=generator) < density[:, None]) | dense[:, None]
    keep &= valid
    # at least one frame: a random valid frame of each sample
    first = (torch.rand(B, generator=generator) * lengths).long()
    keep[torch.arange(B), first] = True
    keep &= valid & ~empty[:, None]
    out = torch.zeros(B, T, joints, dtype=torch.bool)
    out[torch.arange(B), :, joint] = keep
    return out.to(motion_mask.device)


__all__ = ["PATH_CHANNELS", "PATH_SCALE", "TRAIN_JOINTS", "hint_channels", "hint_input", "path_features", "sample_hint_mask",
           "toward_next_target"]
