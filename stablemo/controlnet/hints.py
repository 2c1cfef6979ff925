"""The ControlNet's hint: global joint targets as a per-frame input, and the training draws of hints.

A hint is (B, T, 4 J): the target positions (dataset units divided by `scale`, zero where there
is no target) and the (frame, joint) mask as 0/1, side by side. Training hints follow MotionLCM
(facts-distillation §4): per sample one joint from {pelvis, left foot, right foot, head, left
wrist, right wrist} and a random set of frames; the targets are the clip's own joints.
"""

from __future__ import annotations

import torch

# HumanML3D joint indices: pelvis 0, left foot 10, right foot 11, head 15, left wrist 20, right wrist 21
TRAIN_JOINTS = (0, 10, 11, 15, 20, 21)


def hint_input(targets: torch.Tensor, mask: torch.Tensor, scale: float = 1.0) -> torch.Tensor:
    """targets (B, T, J, 3), mask (B, T, J) bool -> hint (B, T, 4 J) float32."""
    m = mask.to(torch.float32)
    pos = torch.where(mask[..., None], targets.to(torch.float32) / scale, torch.zeros((), device=targets.device))
    return torch.cat([pos.flatten(2), m], dim=-1)


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


__all__ = ["TRAIN_JOINTS", "hint_input", "sample_hint_mask"]
