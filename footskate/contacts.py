"""Foot contacts: from vGRFs (UnderPressure's rule, windows rescaled to the frame rate) or from a
height/velocity heuristic.

Contact layout everywhere in footskate: (..., F, 4) bool in joint order [L_heel, L_toe, R_heel,
R_toe] (= the skeleton's feet_left + feet_right). `contacts_from_forces` also returns UP's
(..., F, 2 parts [front, back], 2 feet [L, R]) layout through `parts_to_joints`'s inverse.

All filters take optional `lengths` (N,) so that batched sequences are filtered exactly as if
each were alone: "replicate" padding repeats each sample's own last valid frame.
"""

from __future__ import annotations

import torch

from footskate.errors import FootskateError

UP_FPS = 100.0
SMOOTH_SIGMA_S = 1.667 / UP_FPS   # Gaussian σ, seconds (1.667 frames at 100 Hz)
SMOOTH_TAPS_S = 5 / UP_FPS        # kernel support, seconds
MAJORITY_S = 11 / UP_FPS          # majority-filter window, seconds
FOOT_THRESHOLD = 0.10             # body weights, per foot
PART_THRESHOLD = 0.05             # body weights, per part (front/back) after rescaling
FRONT_CELLS = slice(8, 16)        # ball/toes -> toe joint
BACK_CELLS = slice(0, 4)          # heel -> ankle joint
HEURISTIC_HEIGHT = 0.11423        # metres, absolute (UnderPressure's skeleton)
HEURISTIC_MARGIN = 0.05           # metres above the joint's own lowest point (relative mode)
HEURISTIC_SPEED = 0.9325          # m/s (0.009325 m per frame at 100 Hz)


def _odd_window(seconds: float, fps: float) -> int:
    """Window covering `seconds` at `fps`, odd and >= 1."""
    n = max(1, int(round(seconds * fps)))
    return n if n % 2 else n + 1


def shifted(x: torch.Tensor, offset: int, lengths: torch.Tensor | None) -> torch.Tensor:
    """x (N, F, ...) shifted by `offset` frames along dim 1 with replicate padding at each sample's ends."""
    n, frames = x.shape[:2]
    t = torch.arange(frames, device=x.device) + offset
    last = (lengths.to(x.device) - 1).clamp(min=0) if lengths is not None else torch.full((n,), frames - 1, device=x.device)
    idx = torch.minimum(t.clamp(min=0)[None, :], last[:, None])  # (N, F)
    idx = idx.view(n, frames, *([1] * (x.dim() - 2))).expand_as(x)
    return torch.gather(x, 1, idx)


def _flatten(x: torch.Tensor, event_dims: int) -> tuple[torch.Tensor, tuple]:
    """(..., F, *event) -> (N, F, *event) for batched filtering."""
    lead = x.shape[: x.dim() - event_dims - 1]
    return x.reshape(-1, *x.shape[len(lead):]), lead


def temporal_filter(x: torch.Tensor, weights: torch.Tensor, lengths: torch.Tensor | None = None) -> torch.Tensor:
    """Centred FIR filter along dim 1 of x (N, F, ...) with replicate padding; `weights` odd length."""
    radius = weights.numel() // 2
    out = torch.zeros_like(x)
    for k, w in enumerate(weights.tolist()):  # a handful of taps, not a loop over samples
        out = out + w * shifted(x, k - radius, lengths)
    return out


def gaussian_kernel(fps: float) -> torch.Tensor:
    sigma = SMOOTH_SIGMA_S * fps
    taps = _odd_window(SMOOTH_TAPS_S, fps)
    r = taps // 2
    k = torch.exp(-0.5 * (torch.arange(-r, r + 1, dtype=torch.float64) / sigma) ** 2)
    return (k / k.sum()).float()


def majority_filter(contacts: torch.Tensor, window: int, lengths: torch.Tensor | None = None,
                    max_iters: int = 100) -> torch.Tensor:
    """Iterated centred box-majority filter (mean > ½) over dim 1 of (N, F, ...) bool, until stable."""
    if window <= 1:
        return contacts
    box = torch.full((window,), 1.0 / window)
    c = contacts
    for _ in range(max_iters):  # converges in a few sweeps; the loop is over sweeps, not samples
        new = temporal_filter(c.float(), box, lengths) > 0.5
        if torch.equal(new, c):
            break
        c = new
    return c


def parts_to_joints(parts: torch.Tensor) -> torch.Tensor:
    """(..., F, 2 [front, back], 2 [L, R]) -> (..., F, 4) in [L_heel, L_toe, R_heel, R_toe] order."""
    return torch.stack([parts[..., 1, 0], parts[..., 0, 0], parts[..., 1, 1], parts[..., 0, 1]], dim=-1)


def contacts_from_forces(forces: torch.Tensor, fps: float, lengths: torch.Tensor | None = None,
                         foot_threshold: float = FOOT_THRESHOLD, part_threshold: float = PART_THRESHOLD,
                         joint_order: bool = True) -> torch.Tensor:
    """vGRFs (..., F, 2, 16) in body weights -> contacts, bool.

    Returns (..., F, 4) [L_heel, L_toe, R_heel, R_toe] (or UP's (..., F, 2, 2) if not joint_order).
    Smoothing and majority windows are defined in seconds (UP's 100 Hz frames) and rescaled to fps.
    """
    if forces.shape[-2:] != (2, 16):
        raise FootskateError(f"forces: expected (..., F, 2, 16), got {tuple(forces.shape)}")
    x, lead = _flatten(forces.float(), 2)
    x = temporal_filter(x, gaussian_kernel(fps).to(x.device), lengths)
    foot = x.sum(-1)                                       # (N, F, 2)
    front, back = x[..., FRONT_CELLS].sum(-1), x[..., BACK_CELLS].sum(-1)
    scale = torch.nan_to_num(foot / (front + back), nan=0.0, posinf=0.0, neginf=0.0)
    parts = torch.stack([front * scale, back * scale], dim=-2)  # (N, F, 2 parts, 2 feet)
    contacts = (foot[..., None, :] >= foot_threshold) & (parts >= part_threshold)
    contacts = majority_filter(contacts, _odd_window(MAJORITY_S, fps), lengths)
    contacts = contacts.reshape(*lead, *contacts.shape[1:])
    return parts_to_joints(contacts) if joint_order else contacts


def span_floor(h: torch.Tensor, fps: float, lengths: torch.Tensor | None, span_s: float = 0.2) -> tuple[torch.Tensor, torch.Tensor]:
    """h (N, F, K) heights -> (span means (N, F, K), floor (N, 1, K)): each frame's mean height over
    a centred `span_s` window, and the lowest such mean over each sample's valid frames — the lowest
    level a joint holds for a span. A raw minimum sinks with per-frame noise (5 mm jitter: ~1 cm)
    and with single frames that dip through the floor (a generated toe at a jump's take-off)."""
    half = max(1, round(span_s * fps / 2))
    mean = temporal_filter(h, torch.full((2 * half + 1,), 1.0 / (2 * half + 1)), lengths)
    frames = h.shape[1]
    valid = torch.arange(frames, device=h.device)[None, :, None] < (
        lengths.to(h.device)[:, None, None] if lengths is not None else frames)
    return mean, torch.where(valid, mean, torch.full_like(mean, float("inf"))).amin(1, keepdim=True)


def contacts_from_heights(feet: torch.Tensor, fps: float, up_axis: int = 1, lengths: torch.Tensor | None = None,
                          height: float = HEURISTIC_MARGIN, speed: float = HEURISTIC_SPEED,
                          relative: bool = True) -> torch.Tensor:
    """Heuristic: feet (..., F, 4, 3) positions -> (..., F, 4) contacts (low and slow).

    `relative` (default): a joint is low when it is within `height` of its own lowest point in
    the sequence (a toe touches down at ~1 cm, an ankle at ~5-9 cm, so one absolute threshold
    either misses heels or keeps swinging toes); otherwise below `height` absolutely (UnderPressure
    uses 0.114 m with its skeleton). The displacement threshold is a speed, so it holds at any
    frame rate; frame t uses the displacement t -> t+1 (the last valid frame repeats the previous one).
    """
    x, lead = _flatten(feet.float(), 2)
    nxt = shifted(x, 1, lengths)
    disp = (nxt - x).norm(dim=-1)                          # (N, F, 4)
    prev_disp = (x - shifted(x, -1, lengths)).norm(dim=-1)
    frames = x.shape[1]
    last = (lengths.to(x.device) - 1) if lengths is not None else torch.full((x.shape[0],), frames - 1, device=x.device)
    idx = torch.arange(frames, device=x.device)[None, :]
    is_last = idx == last[:, None]
    disp = torch.where(is_last[..., None], prev_disp, disp)
    h = x[..., up_axis]
    if relative:
        valid = (idx <= last[:, None])[..., None]
        floor = torch.where(valid, h, torch.full_like(h, float("inf"))).amin(1, keepdim=True)
        h = h - floor
    contacts = (h < height) & (disp * fps < speed)
    return contacts.reshape(*lead, *contacts.shape[1:])


def long_runs(contacts: torch.Tensor, frames: int, lengths: torch.Tensor | None = None) -> torch.Tensor:
    """(N, F, K) bool -> the frames inside runs of at least `frames` consecutive True (within each
    sample's valid length; padding never extends a run)."""
    n, f, k = contacts.shape
    if lengths is not None:
        contacts = contacts & (torch.arange(f, device=contacts.device)[None, :] < lengths.to(contacts.device)[:, None])[..., None]
    if frames <= 1:
        return contacts.clone()
    if f < frames:
        return torch.zeros_like(contacts)
    x = contacts.float().transpose(1, 2).reshape(n * k, 1, f)
    full = (torch.nn.functional.avg_pool1d(x, frames, stride=1) > 1 - 0.5 / frames).float()  # window t..t+frames-1 all True
    out = torch.nn.functional.max_pool1d(torch.nn.functional.pad(full, (frames - 1, frames - 1)), frames, stride=1)
    return (out > 0.5).reshape(n, k, f).transpose(1, 2)


def contacts_at_rest(feet: torch.Tensor, fps: float, up_axis: int, lengths: torch.Tensor | None, height: float,
                     speed: float, seconds: float, span_s: float = 0.2) -> torch.Tensor:
    """feet (N, F, 4, 3) -> (N, F, 4): frames inside runs of at least `seconds` in which the joint is
    at rest near the floor, both measured over a centred span of `span_s` rather than frame to
    frame, so that per-frame jitter (a few mm of capture or generation noise) reads neither as
    motion nor as height:
    - at rest: its displacement across the span is under `speed` x `span_s`;
    - near the floor: its mean height over the span is within `height` of the lowest such mean in
      the sequence (the lowest level the joint holds for a span; a raw minimum sinks with the noise,
      5 mm jitter lowered it by ~1 cm on the real clip, and a resting joint then left the gate)."""
    half = max(1, round(span_s * fps / 2))
    x, lead = _flatten(feet.float(), 2)
    disp = (shifted(x, half, lengths) - shifted(x, -half, lengths)).norm(dim=-1)       # (N, F, 4)
    h, floor = span_floor(x[..., up_axis], fps, lengths, span_s)                          # span means, (N, 1, 4)
    still = (h - floor < height) & (disp * fps / (2 * half) < speed)
    return long_runs(still, max(2, round(seconds * fps)), lengths).reshape(*lead, *still.shape[1:])


def contact_ranges_count(contacts: torch.Tensor) -> int:
    """Number of contiguous contact ranges in a (..., F, K) bool tensor (for logs and tests)."""
    c = contacts.transpose(-1, -2).reshape(-1, contacts.shape[-2])
    starts = c & ~torch.nn.functional.pad(c, (1, 0))[..., :-1]
    return int(starts.sum())


__all__ = ["contacts_at_rest", "contacts_from_forces", "contacts_from_heights", "long_runs", "majority_filter",
           "span_floor", "temporal_filter", "gaussian_kernel", "parts_to_joints", "contact_ranges_count"]
