"""Put a motion on the floor y = 0: the body's lowest point touches it whenever the body is
supported, never sinks through it, and leaves it in jumps.

A generated motion's floor drifts: the demo models sink their feet 2-6 cm into the ground, more in
some stretches than others, so neither one global shift (HumanML3D's own floor: the clip's lowest
joint) nor clamping every frame to zero (which would glue jumps down) is right. Per frame, the
lowest joint height h(t) is compared with the ground the motion stands on nearby, g(t) = the lowest
h within ±WINDOW_S: frames on the ground (`_on_ground`: low and calm, or floating too long and too
low for a flight) are shifted so that their lowest joint is at 0; every other frame (jumps, hops, a
run's flight phase, a foot's take-off and landing) takes the shift interpolated between the
grounded frames around it, so the body rises and falls as generated. The shift is smoothed over a few frames (generated feet jitter by
millimetres, and moving the whole body with that jitter would show), and finally raised wherever
the body would still be below the floor. Only heights change: the path, the pose and planted feet's
horizontal positions stay exactly as they were.

The lowest point is taken over all joints, so a kneeling, sitting or lying body rests on its knees,
pelvis or back, as HumanML3D's own floor does.
"""

from __future__ import annotations

import torch

from stablemo.motion.extract_torch import fill_padding, known_neighbours, smooth_frames, valid_lengths
from stablemo.motion.skeleton import Skeleton, get_skeleton

# which frames stand on the ground (_on_ground): the lowest joint under LOW_M above the nearby ground
# and slower than RISE_MPS up or down, or raised for at least FLOAT_S but never HIGH_M (floating)
LOW_M, RISE_MPS = 0.03, 0.5
HIGH_M, FLOAT_S = 0.10, 0.4
WINDOW_S = 0.5  # the nearby ground is the lowest point within ± this many seconds
SMOOTH_FRAMES = 1.5  # Gaussian sigma of the shift, frames


def _running_min(h: torch.Tensor, radius: int) -> torch.Tensor:
    """Minimum of h (B, T) over ±radius frames (edges: the frames that exist)."""
    padded = torch.nn.functional.pad(h[:, None], (radius, radius), mode="replicate")[:, 0]
    return padded.unfold(1, 2 * radius + 1, 1).amin(-1)


def _fill_between(values: torch.Tensor, known: torch.Tensor) -> torch.Tensor:
    """values (B, T) where `known`, linearly interpolated in between (held constant past the ends)."""
    b, t = values.shape
    idx = torch.arange(t, device=values.device).expand(b, t)
    prev, nxt = known_neighbours(known)  # last known <= t, first known >= t
    prev_ok, next_ok = prev >= 0, nxt < t
    prev_c, next_c = prev.clamp(0, t - 1), nxt.clamp(0, t - 1)
    v_prev, v_next = values.gather(1, prev_c), values.gather(1, next_c)
    span = (next_c - prev_c).clamp(min=1).to(values.dtype)
    w = ((idx - prev_c).to(values.dtype) / span).clamp(0, 1)
    inside = v_prev + w * (v_next - v_prev)
    return torch.where(prev_ok & next_ok, inside, torch.where(prev_ok, v_prev, v_next))


def _on_ground(rel: torch.Tensor, per_metre: float, fps: float, valid: torch.Tensor) -> torch.Tensor:
    """Frames (B, T) whose lowest joint is on the ground, from its height above the nearby ground
    rel (B, T) (valid (B, T): the motion's own frames): low (under LOW_M) and not rising or falling fast (a take-off or a landing moves
    faster than RISE_MPS), or raised for a stretch too long and too low to be a flight (longer
    than FLOAT_S and never HIGH_M up: a denoiser's feet float like that while it walks; a hop's
    flight lasts about 0.3 s, a jump's clears 10 cm)."""
    b, t = rel.shape
    dh = torch.diff(rel, dim=1).abs() * fps  # (B, T-1) units per second
    pad = torch.zeros(b, 1, dtype=rel.dtype, device=rel.device)
    speed = torch.maximum(torch.cat([pad, dh], 1), torch.cat([dh, pad], 1))
    low = rel < LOW_M * per_metre
    grounded = low & (speed < RISE_MPS * per_metre)
    raised = ~low & valid  # padding never lengthens a stretch: each motion is judged as if alone
    starts = raised & ~torch.cat([torch.zeros_like(raised[:, :1]), raised[:, :-1]], 1)
    span = torch.cumsum(starts.long(), 1) + torch.arange(b, device=rel.device)[:, None] * (t + 1)  # unique ids
    span = torch.where(raised, span, torch.zeros_like(span))  # id 0: not raised
    slots = b * (t + 1) + 1
    top = torch.zeros(slots, dtype=rel.dtype, device=rel.device).scatter_reduce(
        0, span.flatten(), rel.flatten(), reduce="amax", include_self=False)
    size = torch.zeros(slots, dtype=rel.dtype, device=rel.device).scatter_add(
        0, span.flatten(), torch.ones_like(rel).flatten())
    floating = raised & (top[span] < HIGH_M * per_metre) & (size[span] >= FLOAT_S * fps)
    return grounded | floating


def floor_shift(joints: torch.Tensor, lengths, skeleton: Skeleton | str, fps: float | None = None,
                pins: torch.Tensor | None = None, pinned: torch.Tensor | None = None) -> torch.Tensor:
    """The height to add to every joint of each frame: joints (B, T, J, 3) -> shift (B, T), zero on
    padding (lengths (B,) valid frames). pins (B, T) with pinned (B, T) bool: frames whose shift is
    given (a joint target's height, which the user asked for, wins over the floor there)."""
    return lowest_shift(joints[..., 1].amin(-1), lengths, skeleton, fps, pins, pinned)


def lowest_shift(lowest: torch.Tensor, lengths, skeleton: Skeleton | str, fps: float | None = None,
                 pins: torch.Tensor | None = None, pinned: torch.Tensor | None = None) -> torch.Tensor:
    """floor_shift from each frame's lowest joint height lowest (B, T) alone: all the floor reads
    (the finishing step hands it over from its joint-major body)."""
    skel = get_skeleton(skeleton)
    b, t = lowest.shape
    n = valid_lengths(lengths, b, t, lowest.device, min_frames=1)
    fps = float(fps or skel.fps)
    h = fill_padding(lowest, n)  # (B, T) lowest joint, padding as the last valid frame
    ground = _running_min(h, max(1, round(WINDOW_S * fps)))
    valid = torch.arange(t, device=lowest.device)[None, :] < n[:, None]  # (B, T)
    supported = _on_ground(h - ground, skel.per_metre, fps, valid) & valid
    values = -h
    if pinned is not None:
        pinned = pinned & valid
        supported = supported | pinned
        values = torch.where(pinned, pins.to(h.dtype), values)
    shift = _fill_between(values, supported)
    shift = torch.maximum(smooth_frames(shift, SMOOTH_FRAMES), -h)  # smoothed, then never below the floor
    if pinned is not None:
        shift = torch.where(pinned, values, shift)
    return torch.where(valid, shift, torch.zeros((), dtype=shift.dtype, device=shift.device))


def target_pins(heights: torch.Tensor, targets: torch.Tensor, target_mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Joint targets as floor pins: heights (B, T, J) of the joints, targets (B, T, J, 3) with
    target_mask (B, T, J) -> (pins (B, T): the shift that meets the frame's targets' mean height,
    pinned (B, T) bool: frames with targets)."""
    m = target_mask.to(heights.dtype)  # (B, T, J)
    count = m.sum(-1)  # (B, T)
    pins = ((targets[..., 1].to(heights.dtype) - heights) * m).sum(-1) / count.clamp(min=1)
    return pins, count > 0


def place_on_floor(joints: torch.Tensor, lengths, skeleton: Skeleton | str, fps: float | None = None,
                   targets: torch.Tensor | None = None, target_mask: torch.Tensor | None = None) -> torch.Tensor:
    """joints (B, T, J, 3) with each frame raised or lowered onto the floor (see the module doc).
    targets (B, T, J, 3) with target_mask (B, T, J): joint targets; on a frame that has some, the
    shift meets their mean height instead."""
    pins = pinned = None
    if target_mask is not None:
        pins, pinned = target_pins(joints[..., 1], targets, target_mask)
    shift = floor_shift(joints, lengths, skeleton, fps, pins, pinned)  # (B, T)
    up = torch.zeros(3, dtype=joints.dtype, device=joints.device)
    up[1] = 1.0
    return joints + shift[..., None, None] * up


__all__ = ["FLOAT_S", "HIGH_M", "LOW_M", "RISE_MPS", "WINDOW_S", "floor_shift", "lowest_shift", "place_on_floor",
           "target_pins"]
