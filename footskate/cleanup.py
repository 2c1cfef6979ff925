"""Batched foot-skate cleanup: the optimisation of StableMoFusion Eq. 6 over a padded batch.

L = w_q L_pose + w_f L_foot + w_t L_trajectory + w_v L_vGRF (+ a small smoothness term on the
correction). Variables are the root trajectory and, per frame, the global direction of every
bone; positions come from forward kinematics with each bone keeping its input length, so bone
lengths are exact by construction. Contact ranges are found per (sample, foot joint) with segment
ids from cumulative sums, so the whole batch (any mix of lengths) is one set of tensor ops: no
Python loop over samples or ranges. Each sample's loss is normalised by its own length and the
batch loss is their sum, so a sample's result does not depend on its batch-mates.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import torch

from footskate.contacts import (
    PART_THRESHOLD,
    contacts_at_rest,
    contacts_from_forces,
    contacts_from_heights,
)
from footskate.errors import FootskateError
from footskate.vgrf import VGRFNet, msle

GATE_MARGIN = 0.05   # m; see CleanupConfig.gate_margin
GATE_FORCE = 0.25    # body weights; see CleanupConfig.gate_force (a network's own calibrated value comes first)
GAP_FILL_S = 0.15    # seconds; the longest mid-stance force dip the gated decision fills (3 frames at 20 fps)
GATE_BRIDGE = 0.3    # seconds; see CleanupConfig.gate_bridge (0: off)
GATE_SUPPORT = 0.0   # body weights; see CleanupConfig.gate_support (0: off)
GATE_REST = 0.75     # seconds; see CleanupConfig.gate_rest (0: off)
REST_SPEED = 0.2     # m/s: a still foot (a planted joint of clean mocap moves 0.0-0.2 m/s)


@dataclass
class CleanupConfig:
    iters: int = 100
    lr: float = 1e-2
    lr_root: float = 1e-3       # metres per step; small so that the legs, not the root, absorb the anchoring
    fps: float = 20.0
    up_axis: int = 1
    w_pose: float = 1.0          # keep bone directions (the pose) close to the input
    w_norm: float = 1.0          # keep the direction parameters near unit length (UP's quaternion-norm term)
    w_trajectory: float = 100.0  # keep root velocities (per frame, metres)
    w_foot: float = 1000.0       # anchor contact joints at their range targets (metres²)
    w_vgrf: float = 0.05         # keep the predicted vGRFs (MSLE)
    w_smooth: float = 100.0      # penalise acceleration of the correction (no pops at range borders)
    w_clearance: float = 1000.0  # outside contact ranges, feet may rise but not sink below their input height; none below the floor
    # between anchored ranges, feet follow the input shifted by the anchors' horizontal corrections
    # interpolated across the swing. Off by default: on synthetic injected sliding 1000 keeps the
    # feet's acceleration below the input's (walk 3.97 -> 3.84, run 6.50 -> 6.50 m/s²; without it
    # 4.08 / 7.03), but on the real clip's accumulating-drift test it leaves more skating (GMD ratio
    # 0.256 -> 0.229 instead of 0.195; docs/footskate.md)
    w_swing: float = 0.0
    # one-sided: penalise the feet's squared acceleration where it exceeds the input's (jitter the
    # cleanup would add), leaving the input's own accelerations alone
    w_accel: float = 300.0
    ramp_seconds: float = 0.1    # contact weights ramp over this much at each end of a range (2 frames at 20 fps)
    min_range: int = 2           # ranges shorter than this get no anchoring (a 1-frame contact cannot slide)
    max_offset: float = 0.25     # m; no frame is anchored further than this (horizontally) from its range target
    # a range whose joint strays further than max_offset from its middle is first cut down to the
    # frames around its middle up to the first one that far, if that cuts at most `trim_seconds`
    # (lift-off or touch-down frames the detector ran into, or a weight shift: the foot leaving,
    # not sliding); a range that would lose more (a long drifting contact) is left unanchored, as
    # every straying range was before session 13 (0: never trim). On the real clip with injected
    # sliding (hand-labelled stances, 4 draws, drift 0.7 m/s) whole-range rejection left 17 of 99
    # ranges unanchored and removed 62 % of the stance-foot speed, 0.3 s 80 % (unlimited trimming
    # 80.5 %, but on the accumulating-drift test it raised the skating ratio of 4 of 24 clips,
    # 0.3 s of none; both before gate_bridge, which adds 1.4 points); the synthetic validation
    # motions are unchanged (their ranges never stray)
    trim_seconds: float = 0.3
    # m; the root (and with it the upper body, which moves rigidly with it) is displaced by at most
    # this much in any frame: its displacement is a radial tanh squash of the free parameter, so
    # the bound holds by construction. Unbounded, single frames moved 4.9-5.9 cm on the benchmark's
    # walk/run/side step (the root taking up an overshoot the legs could also absorb); issue #22's
    # target is < 3 cm. inf: unbounded
    max_root_shift: float = 0.025
    sink: float = float("inf")   # m; an anchor pulls its joint down by at most this much below the input's height
    # m above the floor (y = 0) at which a planted foot's lowest joint (ankle or toe) stands: every
    # range's anchor puts it there, whatever height the input holds the foot at. Measured on the
    # data, not chosen: on the demo model's training data (`stablemo data synth`, seed 0, 150 clips,
    # 26,712 planted foot-frames) it is 0.00 cm (median and p95); on the real HumanML3D clip 012314
    # (hand-labelled stances) its median is 0.79 cm (right foot) and 1.52 cm (left), its minimum
    # 0.00 / 0.76 cm (the dataset puts its floor at the clip's lowest joint)
    planted_height: float = 0.0
    # first place each motion on the floor its planted feet define (`floor_offset`: one vertical
    # shift of the whole motion, the median height of its flat-planted feet). The dataset's
    # placement, which clean_features applies, puts the floor at a motion's lowest joint of any
    # frame, so one generated frame that dips through the floor lifts every stance: the demo
    # model's "a person jumps forward twice" (seed 3) lands 4.6 cm through it once, and its
    # stances then stood 3-6 cm up. Without the shift the legs alone (the root moves at most
    # max_root_shift) would bend that far on every stance. False: the anchors alone pull the feet down
    place_on_floor: bool = True
    split_travel: float = float("inf")  # m; contacts along which the joint travels further are cut into pieces (off)
    # refresh the (linearised) vGRF gradient every k iterations: the net dominates the cost (one
    # forward + backward of the 32 x 196 batch ~0.4-0.7 s on one thread). 25 (4 refreshes) and 10
    # gave the same sliding removal, acceleration and F1 on every benchmark type (tuning seed)
    vgrf_every: int = 25
    # contacts when none are given: "gated" (the vGRF network's contacts, kept where the joint is
    # within contact_margin of its own lowest point: the force says when a foot bears weight, the
    # height which joint is down), "vgrf" (the network alone), "heuristic" (height and speed),
    # "auto" (the default: gated if a model is given, else heuristic)
    detect: str = "auto"
    contact_margin: float = 0.05  # heuristic: m above the joint's own lowest point
    contact_speed: float = 0.9325 # heuristic: m/s
    # gated: a foot moving faster than this (3D, m/s) is swinging, whatever the network says.
    # Generated stance feet slide at up to ~1.5 m/s (a quarter of a 3.5 m/s run + 0.7 m/s drift)
    # and a landing foot still moves down; on the real clip 3.0 cuts the network's false contacts
    # on fast low swings (F1 0.882 -> 0.905); 2.0 cut more there but cost running stances
    # (synthetic run 92 -> 88 % sliding removed)
    gate_speed: float = 3.0
    # gated: the height gate (m above the joint's own lowest point) and the per-foot force the
    # network's contacts need (body weights; UnderPressure's rule: 0.10). The force is calibrated
    # per network on synthetic validation motions (seeds 3000 and 4000, 8 per type, sliding
    # injected), never on the benchmark's test seeds or the real clip: scripts/footskate/calibrate.py
    # (V22: 0.25, smallest per-type F1 margin over the rule +0.0051, 0.10: +0.0015; V21: 0.25 on
    # seeds 3000-6000, +0.0040), and `--store` keeps it in the weights' metadata ("gate_force");
    # None takes the network's value, else GATE_FORCE. The height gate stays 5 cm: 3 cm
    # scores higher there but leaves the demo model's generated stances, which sit at different
    # heights, unanchored (see MARGINS in that script)
    gate_margin: float = GATE_MARGIN
    gate_force: float | None = None
    # gated: a second, lower force (body weights, 0 = off) at which the network confirms a contact
    # the height/speed rule sees (a hysteresis: the network alone needs gate_force, the network and
    # the rule together gate_support). scripts/footskate/calibrate.py searches it with gate_force:
    # on the validation motions every support lowered the smallest per-type margin over the rule
    # (0.10 BW: +0.0023, 0.05: +0.0012, 0.02: -0.0014, off: +0.0051; the rule's contacts on sliding
    # feet come back with it), so it is off
    gate_support: float = GATE_SUPPORT
    # gated: a joint that stays at rest (moving < REST_SPEED over 0.2 s spans) within gate_margin of
    # its lowest point for at least this long (seconds, 0 = off) is down whatever load the network
    # gives it (a foot resting on its ball beside a loaded flat foot carries little weight but does
    # not move). scripts/footskate/calibrate.py searches it with gate_force: on the validation
    # motions 0.3, 0.5 and 0.75 s tie with off exactly (smallest per-type margin over the rule
    # +0.0051, every type's F1 the same: their still feet are loaded, their sliding feet never
    # still). It is on because a joint at rest on the floor is in contact (the real clip's left toe
    # stands 15 frames on its ball at 0.04-0.08 BW); the longest of the grid's durations, so that
    # it adds only clear rests
    gate_rest: float = GATE_REST
    # gated: a gap of up to this long (seconds, 0 = off) between two of the network's contacts of
    # a joint is bridged where, on every frame of it, the height/speed rule says the joint is down:
    # the force can dip through a stance for longer than the 0.15 s gap fill (GAP_FILL_S) covers.
    # The real clip's left toe carries 0.07-0.18 BW for 5 frames while its heel rises and the
    # weight passes to the other foot; the demo model's "jumps forward twice" unweights both feet
    # (0.01-0.03 BW) for 4-5 frames in the crouch between jumps while they stand on the floor.
    # Unlike gate_support it only joins contacts, never starts or extends one, so the rule's
    # contacts on sliding feet do not come back: the synthetic validation motions' F1 is identical
    # with it (0.3 or 0.5 s, and also when the gap must keep a light load of 0.02 or 0.05 BW); on
    # the real clip with injected root overshoot the stance-foot speed reduction goes 75 -> 83 %
    gate_bridge: float = GATE_BRIDGE


@dataclass
class CleanupResult:
    joints: torch.Tensor         # (B, T, J, 3) corrected positions (padding copied from the input)
    contacts: torch.Tensor       # (B, T, 4) bool, contact joints used
    targets: torch.Tensor        # (B, T, 4, 3) anchor target per contact frame (NaN elsewhere)
    weights: torch.Tensor        # (B, T, 4) anchoring weight per frame (0 outside anchored ranges)
    info: dict = field(default_factory=dict)


def ramp(x: torch.Tensor) -> torch.Tensor:
    """Smooth step on [0, 1]: 2x² for x <= ½, else 1 - 2(1-x)²."""
    return torch.where(x <= 0.5, 2 * x * x, 1 - 2 * (1 - x) ** 2)


def ancestor_matrix(parents: list[int] | torch.Tensor) -> torch.Tensor:
    """A (J, J-1) with A[j, k] = 1 if bone k (ending at joint k+1) lies on the chain root -> j.

    Joints must be topologically ordered with the root at index 0 (true for HumanML3D/KIT/UP).
    """
    parents = [int(p) for p in parents]
    if parents[0] >= 0 or any(p >= j for j, p in enumerate(parents) if j > 0):
        raise FootskateError("parents: joints must be topologically ordered with the root first")
    j_count = len(parents)
    a = torch.zeros(j_count, j_count - 1)
    for j in range(1, j_count):
        k = j
        while k > 0:
            a[j, k - 1] = 1.0
            k = parents[k]
    return a


def leg_joints(parents: list[int], feet: list[int]) -> list[int]:
    """Joints whose bones the cleanup rotates: the feet and their ancestors, hips excluded
    (depth >= 2), i.e. knee, ankle and toe bones of each leg."""
    def depth(j: int) -> int:
        d = 0
        while parents[j] >= 0:
            j, d = parents[j], d + 1
        return d
    legs = set()
    for f in feet:
        j = f
        while j > 0 and depth(j) >= 2:
            legs.add(j)
            j = parents[j]
    return sorted(legs)


def valid_mask(lengths: torch.Tensor, frames: int) -> torch.Tensor:
    return torch.arange(frames, device=lengths.device)[None, :] < lengths[:, None]


def _fill_padding(x: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
    """x (B, T, ...): frames past each length replaced by the last valid one."""
    b, t = x.shape[:2]
    idx = torch.minimum(torch.arange(t, device=x.device)[None, :], (lengths - 1).clamp(min=0)[:, None])
    return torch.gather(x, 1, idx.view(b, t, *([1] * (x.dim() - 2))).expand_as(x))


def _segments(c: torch.Tensor, starts: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Contact ranges of rows c (R, T) bool, each beginning where `starts` is True: per frame its
    global range id (R, T) (meaningful on contact frames), and per range its start frame, length
    and row (num,) each. Segment ids from cumulative sums, no loop over rows or ranges."""
    per_row = starts.sum(1)
    row_offset = torch.cumsum(per_row, 0) - per_row                         # exclusive cumsum
    seg = torch.cumsum(starts.long(), 1) - 1 + row_offset[:, None]          # global range id per frame
    num = int(per_row.sum())
    frame = torch.arange(c.shape[1], device=c.device).expand_as(c)
    start = torch.zeros(num, dtype=torch.long, device=c.device).scatter_(0, seg[starts], frame[starts])
    length = torch.bincount(seg[c], minlength=num)
    row = torch.repeat_interleave(torch.arange(c.shape[0], device=c.device), per_row)
    return seg, start, length, row


def contact_ranges(contacts: torch.Tensor, positions: torch.Tensor, up_axis: int, ramp_frames: int,
                   min_range: int, max_offset: float = float("inf"),
                   split_travel: float = float("inf"),
                   planted_height: float = 0.0) -> tuple[torch.Tensor, torch.Tensor, dict]:
    """Range targets and ramped weights for every contact frame, vectorised with segment ids.

    contacts (B, T, 4) bool; positions (B, T, 4, 3) of the contact joints [L_heel, L_toe, R_heel,
    R_toe] in the input motion. Returns targets (B, T, 4, 3) — each range's joint position at its
    middle frame, at the height that stands its foot on the floor with its lowest joint at
    `planted_height` — and weights (B, T, 4), ramped in and out over `ramp_frames`, zero outside
    ranges. (Other joint counts K: each joint is its own foot.)
    """
    b, t, k = contacts.shape
    c = contacts.permute(0, 2, 1).reshape(b * k, t)                        # rows = (sample, joint)
    prev = torch.nn.functional.pad(c, (1, 0))[:, :-1]
    starts = c & ~prev
    pos = positions.permute(0, 2, 1, 3).reshape(b * k, t, 3)
    if split_travel < float("inf"):
        # A long "contact" along which the joint travels (a shuffling foot) is cut into pieces of
        # at most `split_travel` metres of horizontal path, each anchored on its own: chunk index =
        # floor(path length since the range start / split_travel), from cumulative sums.
        horiz = [a for a in range(3) if a != up_axis]
        step = torch.nn.functional.pad((pos[:, 1:, horiz] - pos[:, :-1, horiz]).norm(dim=-1), (1, 0))
        path = torch.cumsum(step * c, 1)                                   # path length inside contacts
        run = torch.cumsum(starts.long(), 1)
        run_start_path = torch.zeros_like(path).scatter_reduce(
            1, run.clamp(min=0), torch.where(starts, path, torch.zeros_like(path)), reduce="sum")
        since = path - torch.gather(run_start_path, 1, run)
        chunk = torch.floor(since / split_travel)
        chunk_prev = torch.nn.functional.pad(chunk, (1, 0), value=-1.0)[:, :-1]
        starts = starts | (c & prev & (chunk != chunk_prev))
    seg, start, length, row = _segments(c, starts)
    num = int(start.numel())
    frame = torch.arange(t, device=c.device).expand(b * k, t)
    seg_c = seg[c]
    mid = start + (length - 1) // 2
    target = pos[row, mid].clone()                                          # (num, 3)
    # Height: the one that stands the joint's foot on the floor (y = planted_height at its lowest
    # joint), whatever height the input holds it at. The foot's shape comes from the range's flat
    # frames (both joints of the foot down): the joint's mean height above its foot's lowest joint
    # there; a range without one (a heel or ball alone) moves its lowest height with the foot's.
    y = pos[..., up_axis]                                                   # (B*K, T)
    sole = foot_sole(positions[..., up_axis]).permute(0, 2, 1).reshape(b * k, t)  # rows as pos
    amin = lambda v: torch.full((num,), float("inf"), dtype=positions.dtype, device=c.device).scatter_reduce(
        0, seg_c, v[c], reduce="amin")
    height = foot_on_floor(amin(y), amin(sole), planted_height)
    if k == 4:
        flat = (contacts & contacts[..., [1, 0, 3, 2]]).permute(0, 2, 1).reshape(b * k, t)  # both joints down
        n_flat = torch.bincount(seg[flat], minlength=num)
        above = torch.zeros(num, dtype=positions.dtype, device=c.device).index_add_(0, seg[flat], (y - sole)[flat])
        height = torch.where(n_flat > 0, above / n_flat.clamp(min=1) + planted_height, height)
    target[:, up_axis] = height

    targets = torch.full((b * k, t, 3), float("nan"), dtype=positions.dtype, device=c.device)
    targets[c] = target[seg_c]
    d = torch.minimum(frame[c] - start[seg_c], start[seg_c] + length[seg_c] - 1 - frame[c])
    # Ramps that fit the range: a range shorter than two ramps plus a middle frame (a running
    # stance is 2-5 frames at 20 fps) ramps over (length - 1) // 2 frames each side, so its middle
    # frames are fully anchored; a 2-frame range is anchored at full weight.
    fit = torch.minimum(torch.full_like(length, ramp_frames), (length - 1) // 2)[seg_c]
    w = torch.where(fit > 0, ramp(((d + 1).float() / (fit + 1).float()).clamp(max=1.0)), torch.ones_like(d, dtype=torch.float32))
    # A "contact" whose joint strays more than max_offset (horizontally) from the range target is a
    # mis-detection (a walking foot, not a skating one): anchoring it would wreck the pose.
    horiz = [a for a in range(3) if a != up_axis]
    stray = (pos[c][:, horiz] - target[seg_c][:, horiz]).norm(dim=-1)
    reach = torch.zeros(num, dtype=positions.dtype, device=c.device).scatter_reduce(0, seg_c, stray, reduce="amax")
    keep = (length >= min_range) & (reach <= max_offset)
    w = torch.where(keep[seg_c], w, torch.zeros_like(w))
    weights = torch.zeros(b * k, t, dtype=positions.dtype, device=c.device)
    weights[c] = w.to(positions.dtype)
    info = {"ranges": num, "anchored_ranges": int(keep.sum()), "rejected_ranges": int(((length >= min_range) & ~keep).sum())}
    return (targets.view(b, k, t, 3).permute(0, 2, 1, 3), weights.view(b, k, t).permute(0, 2, 1), info)


def foot_sole(heights: torch.Tensor) -> torch.Tensor:
    """heights (..., 4) of [L_heel, L_toe, R_heel, R_toe] -> (..., 4): per joint, the lowest joint
    of its foot (the foot's sole as the two contact joints see it). Without that layout (K != 4
    joints) each joint is its own foot."""
    if heights.shape[-1] != 4:
        return heights
    return torch.minimum(heights[..., 0::2], heights[..., 1::2]).repeat_interleave(2, dim=-1)


def foot_on_floor(low: torch.Tensor, sole_low: torch.Tensor, planted_height: float) -> torch.Tensor:
    """Anchor height of a contact range without a flat frame: the joint's lowest height over the
    range (`low`) moved with its whole foot so that the foot's lowest joint over the range
    (`sole_low` <= low) stands at `planted_height`, wherever the input holds the foot (lifted by a
    floor set at one sinking frame, or sunk through it)."""
    return low - sole_low + planted_height


def floor_offset(heights: torch.Tensor, weights: torch.Tensor, planted_height: float) -> torch.Tensor:
    """heights (B, T, 4) of the contact joints, anchor weights (B, T, 4) -> (B,): how far each
    motion stands above the floor its planted feet define: the median, over the frames where a
    foot is planted flat (both its joints fully anchored; where a motion has none, one of them),
    of the foot's lowest joint minus planted_height; 0 for a motion with no fully anchored frame.
    A median, not a minimum: a frame dipping through the floor, even inside a stance, does not set
    it."""
    sole = torch.minimum(heights[..., 0::2], heights[..., 1::2]) - planted_height  # (B, T, 2) per foot
    full = weights >= 1
    flat, any_ = full[..., 0::2] & full[..., 1::2], full[..., 0::2] | full[..., 1::2]  # (B, T, 2)
    nan = torch.full_like(sole, float("nan"))
    median = lambda m: torch.where(m, sole, nan).flatten(1).nanmedian(dim=1).values  # (B,), NaN if none
    return torch.nan_to_num(torch.where(flat.flatten(1).any(1), median(flat), median(any_)), nan=0.0)


def trim_ranges(contacts: torch.Tensor, positions: torch.Tensor, up_axis: int, max_offset: float,
                max_trim: int) -> torch.Tensor:
    """contacts (B, T, K) bool, positions (B, T, K, 3) -> contacts with every range cut down to the
    frames around its middle frame up to (not including) the first frame on either side whose joint
    is further than `max_offset` (horizontally) from the middle frame's position, where that cuts
    at most `max_trim` frames from the range (others stay whole). Segment sums, no loop over ranges."""
    b, t, k = contacts.shape
    c = contacts.permute(0, 2, 1).reshape(b * k, t)
    pos = positions.permute(0, 2, 1, 3).reshape(b * k, t, 3)
    seg, start, length, _ = _segments(c, c & ~torch.nn.functional.pad(c, (1, 0))[:, :-1])
    seg_c = seg[c]
    mid = torch.zeros_like(seg)
    mid[c] = (start + (length - 1) // 2)[seg_c]                                          # its range's middle frame
    horiz = [a for a in range(3) if a != up_axis]
    mid_pos = torch.gather(pos, 1, mid[..., None].expand(-1, -1, 3))
    bad = (c & ((pos - mid_pos)[..., horiz].norm(dim=-1) > max_offset)).long()
    before = torch.nn.functional.pad(torch.cumsum(bad, 1), (1, 0))                       # bad frames in [0, i)
    at = lambda i: torch.gather(before, 1, i)
    frame = torch.arange(t, device=c.device).expand(b * k, t)
    lo, hi = torch.minimum(frame, mid), torch.maximum(frame, mid)
    keep = c & (at(hi + 1) - at(lo) == 0)                                                # none between f and mid
    cut = torch.bincount(seg_c, weights=(~keep[c]).float(), minlength=start.numel())     # frames cut per range
    keep[c] = keep[c] | (cut[seg_c] > max_trim)                                          # cut too much: left whole
    return keep.view(b, k, t).permute(0, 2, 1)


def swing_offsets(offsets: torch.Tensor, anchored: torch.Tensor, up_axis: int) -> torch.Tensor:
    """offsets (B, T, K, 3) of anchors from the input, valid where anchored (B, T, K) -> horizontal
    offsets for every frame: linear in time between the nearest anchored frames before and after,
    held before the first and after the last one, zero for a joint with no anchor.

    Anchoring a sliding stance foot and letting the swing snap back to the input's path puts a
    kink in the foot's trajectory at every lift-off and touchdown (measured: more foot acceleration
    than the sliding input); carrying the correction across the swing keeps it smooth.
    """
    b, t, k, _ = offsets.shape
    idx = torch.arange(t, device=offsets.device)[None, :, None].expand(b, t, k)
    prev = torch.cummax(torch.where(anchored, idx, torch.full_like(idx, -1)), dim=1).values
    nxt = torch.flip(torch.cummin(torch.flip(torch.where(anchored, idx, torch.full_like(idx, t)), [1]), dim=1).values, [1])
    has_prev, has_next = prev >= 0, nxt < t
    prev = torch.where(has_prev, prev, nxt).clamp(0, t - 1)
    nxt = torch.where(has_next, nxt, prev).clamp(0, t - 1)
    a = ((idx - prev).to(offsets.dtype) / (nxt - prev).clamp(min=1).to(offsets.dtype)).clamp(0, 1)[..., None]
    pick = lambda i: torch.gather(offsets, 1, i[..., None].expand(b, t, k, 3))
    out = pick(prev) * (1 - a) + pick(nxt) * a
    out = torch.where((has_prev | has_next)[..., None], out, torch.zeros_like(out))
    out[..., up_axis] = 0.0
    return out


def _near(contacts: torch.Tensor, direction: int, lengths: torch.Tensor, frames: int = 3) -> torch.Tensor:
    """(B, T, K) bool: a contact within `frames` frames before (direction -1) or after (+1)."""
    from footskate.contacts import shifted

    out = torch.zeros_like(contacts)
    for k in range(1, frames + 1):  # a few shifts, not a loop over samples
        out = out | shifted(contacts, direction * k, lengths)
    return out


def _bridge(contacts: torch.Tensor, through: torch.Tensor, frames: int, lengths: torch.Tensor) -> torch.Tensor:
    """(B, T, K) bool: the frames of gaps of at most `frames` frames between two contacts whose
    every frame is in `through` (distances to the contact before and after, one shift per frame;
    a gap of g frames gives its frames distances summing to g + 1)."""
    from footskate.contacts import shifted

    far = frames + 1
    before = torch.where(contacts, 0, far)                     # frames since a contact, via `through`
    after = torch.where(contacts, 0, far)
    for _ in range(frames):  # a handful of shifts, not a loop over samples
        before = torch.where(through & ~contacts, torch.minimum(before, shifted(before, -1, lengths) + 1), before)
        after = torch.where(through & ~contacts, torch.minimum(after, shifted(after, 1, lengths) + 1), after)
    return ~contacts & through & (before + after <= frames + 1)


def calibrated_gate_force(vgrf, gate_force: float | None = None) -> float:
    """The gated decision's force threshold: `gate_force` if given, else the one calibrated for
    this network (its weights' metadata "gate_force", scripts/footskate/calibrate.py), else GATE_FORCE."""
    if gate_force is not None:
        return float(gate_force)
    return float((getattr(vgrf, "metadata", None) or {}).get("gate_force", GATE_FORCE))


def detect_contacts(joints: torch.Tensor, lengths: torch.Tensor | None, feet: list[int], fps: float, up_axis: int,
                    vgrf: VGRFNet | None = None, margin: float = 0.05,
                    speed: float = 0.9325, gate: bool = False,
                    gate_speed: float = 3.0, gate_margin: float = GATE_MARGIN,
                    gate_force: float | None = None,
                    gate_support: float = GATE_SUPPORT,
                    gate_rest: float = GATE_REST,
                    gate_bridge: float = GATE_BRIDGE) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Contacts (B, T, 4) from the vGRF network if given (foot force >= `gate_force` body weights
    with `gate`, UnderPressure's 0.10 without; with `gate`: only where the joint is within
    `gate_margin` of its own lowest point and slower than `gate_speed`, and, with `gate_support` > 0,
    also where the height/speed rule says the joint is down and the force reaches `gate_support`,
    and, with `gate_rest` > 0, where the joint stays still that many seconds within `gate_margin`,
    and, with `gate_bridge` > 0, across gaps that short between contacts where the rule says down),
    else the height/speed heuristic (`margin`, `speed`)."""
    if lengths is None:
        lengths = torch.full((joints.shape[0],), joints.shape[1], dtype=torch.long, device=joints.device)
    mask = valid_mask(lengths, joints.shape[1])
    if vgrf is not None:
        with torch.no_grad():
            forces = vgrf(joints, lengths)
        if gate:  # a loose speed limit: a sliding stance foot is exactly what must be caught
            contacts = contacts_from_forces(forces, fps, lengths, foot_threshold=calibrated_gate_force(vgrf, gate_force))
            contacts = contacts & contacts_from_heights(joints[:, :, feet], fps, up_axis, lengths, height=gate_margin,
                                                        speed=gate_speed)
            # The network's force can dip below the threshold for a frame or three mid-stance (the
            # crouch before a jump, when the body's weight is briefly unloaded): such a gap, where
            # the height/speed rule says the joint is down, is filled so that one stance stays one
            # anchored range. The gap is GAP_FILL_S at any frame rate (it was 3 frames, 0.24 s at
            # KIT's 12.5 fps; on the KIT validation motions 2 frames there scored higher on turns
            # and dances; at 20 fps 3 frames stays best of 2-6 on the HumanML3D ones).
            rule = contacts_from_heights(joints[:, :, feet], fps, up_axis, lengths, height=gate_margin, speed=speed)
            if gate_support > 0:  # the rule's contact, confirmed by a lighter load than the network alone needs
                supported = contacts_from_forces(forces, fps, lengths, foot_threshold=gate_support,
                                                 part_threshold=min(PART_THRESHOLD, gate_support / 2))
                contacts = contacts | (rule & supported)
            if gate_rest > 0:  # at rest on the floor, loaded or not
                contacts = contacts | contacts_at_rest(joints[:, :, feet], fps, up_axis, lengths, gate_margin,
                                                       REST_SPEED, gate_rest)
            gap = max(1, round(GAP_FILL_S * fps))
            contacts = contacts | (rule & _near(contacts, -1, lengths, gap) & _near(contacts, 1, lengths, gap))
            if gate_bridge > 0:
                contacts = contacts | _bridge(contacts, rule, round(gate_bridge * fps), lengths)
        else:
            contacts = contacts_from_forces(forces, fps, lengths)
    else:
        forces = None
        contacts = contacts_from_heights(joints[:, :, feet], fps, up_axis, lengths, height=margin, speed=speed)
    return contacts & mask[..., None], forces


def _check(joints: torch.Tensor, parents, feet, lengths) -> torch.Tensor:
    if joints.dim() != 4 or joints.shape[-1] != 3:
        raise FootskateError(f"joints: expected (B, T, J, 3), got {tuple(joints.shape)}")
    if len(parents) != joints.shape[2]:
        raise FootskateError(f"parents: {len(parents)} entries for {joints.shape[2]} joints")
    if len(feet) != 4:
        raise FootskateError("feet: expected 4 joint indices [L_heel, L_toe, R_heel, R_toe]")
    if not torch.isfinite(joints).all():
        raise FootskateError("joints: contains NaN or infinite values")
    b, t = joints.shape[:2]
    if lengths is None:
        return torch.full((b,), t, dtype=torch.long, device=joints.device)
    lengths = torch.as_tensor(lengths, dtype=torch.long, device=joints.device).reshape(-1)
    if lengths.numel() != b or (lengths < 1).any() or (lengths > t).any():
        raise FootskateError(f"lengths: expected {b} values in [1, {t}]")
    return lengths


def cleanup(joints: torch.Tensor, parents, feet, lengths: torch.Tensor | None = None,
            contacts: torch.Tensor | None = None, vgrf: VGRFNet | None = None,
            config: CleanupConfig | None = None) -> CleanupResult:
    """Remove foot skating from a batch of joint positions.

    joints (B, T, J, 3) metres, up axis `config.up_axis`, floor at 0; parents (J,) with root 0;
    feet = joint indices [L_heel, L_toe, R_heel, R_toe]; lengths (B,) valid frames; contacts
    (B, T, 4) bool or None (then detected with `vgrf`, or heuristically without it). The result
    stands every anchored foot on the floor (its lowest joint at `config.planted_height`);
    info["floor_offset"] (B,) is how far each motion was first moved down to get there (metres).
    """
    cfg = config or CleanupConfig()
    lengths = _check(joints, parents, feet, lengths)
    started = time.perf_counter()
    device, dtype = joints.device, torch.float32
    x0 = _fill_padding(joints.detach().to(dtype), lengths)                     # (B, T, J, 3)
    b, t, j_count, _ = x0.shape
    mask = valid_mask(lengths, t)                                              # (B, T)
    maskf = mask.to(dtype)
    n_frames = lengths.to(dtype)                                               # per-sample normaliser
    feet_idx = torch.as_tensor(list(feet), device=device)

    if cfg.detect not in ("auto", "gated", "vgrf", "heuristic"):
        raise FootskateError(f"detect: expected auto, gated, vgrf or heuristic, got {cfg.detect!r}")
    if contacts is None:
        if cfg.detect in ("vgrf", "gated") and vgrf is None:
            raise FootskateError(f"detect: {cfg.detect!r} contact detection needs a vGRF network")
        detector = None if cfg.detect == "heuristic" else vgrf
        contacts, forces0 = detect_contacts(x0, lengths, list(feet), cfg.fps, cfg.up_axis, detector,
                                            cfg.contact_margin, cfg.contact_speed, gate=cfg.detect != "vgrf",
                                            gate_speed=cfg.gate_speed, gate_margin=cfg.gate_margin,
                                            gate_force=cfg.gate_force, gate_support=cfg.gate_support,
                                            gate_rest=cfg.gate_rest, gate_bridge=cfg.gate_bridge)
    else:
        contacts = torch.as_tensor(contacts, device=device).bool()
        if contacts.shape != (b, t, 4):
            raise FootskateError(f"contacts: expected {(b, t, 4)}, got {tuple(contacts.shape)}")
        contacts = contacts & mask[..., None]
        forces0 = None
    ramp_frames = max(1, int(round(cfg.ramp_seconds * cfg.fps)))
    if cfg.trim_seconds > 0 and cfg.max_offset < float("inf"):
        contacts = trim_ranges(contacts, x0[:, :, feet_idx], cfg.up_axis, cfg.max_offset,
                               round(cfg.trim_seconds * cfg.fps))
    targets, weights, info = contact_ranges(contacts, x0[:, :, feet_idx], cfg.up_axis, ramp_frames, cfg.min_range,
                                            cfg.max_offset, cfg.split_travel, cfg.planted_height)
    weights = weights * maskf[..., None]
    targets_filled = torch.nan_to_num(targets)
    # The targets stand every planted foot on the floor. The motion is first moved there as a whole
    # (every joint: a placement, not a pose change) so that the legs only take up what differs
    # between its stances.
    placed = (floor_offset(x0[:, :, feet_idx, cfg.up_axis], weights, cfg.planted_height) if cfg.place_on_floor
              else torch.zeros(b, dtype=dtype, device=device))                  # (B,) metres above the floor
    if bool((placed != 0).any()):
        x0 = x0.clone()
        x0[..., cfg.up_axis] -= placed[:, None, None]
        forces0 = None  # the vGRF term compares with the placed motion's forces (the net sees heights)
    info["floor_offset"] = placed.tolist()
    if cfg.sink < float("inf"):
        # Vertically, a contact frame where the joint is already lifting (heel-off, a range detected
        # a frame wide) keeps its lift: pinning it to the range's lowest height and releasing it at
        # the border put a vertical kink (foot acceleration) at every lift-off. The target height
        # h - min(h - low, sink) is continuous in h.
        h = x0[:, :, feet_idx, cfg.up_axis]
        low = targets_filled[..., cfg.up_axis]
        targets_filled[..., cfg.up_axis] = h - (h - low).clamp(min=0, max=cfg.sink)

    # Parameterisation: root trajectory + the global direction of every leg bone (each keeping its
    # per-frame input length). Bones above the hips move rigidly with the root, which keeps the
    # upper body as generated and makes an iteration cheap. Positions are affine in the leg bone
    # vectors: p = root + rel0 + A[:, legs] @ (len * (unit - unit0)).
    parents = [int(p) for p in parents]
    anc = ancestor_matrix(parents).to(device, dtype)                            # (J, J-1)
    legs = leg_joints(parents, list(feet))
    leg_idx = torch.as_tensor(legs, device=device)
    leg_parent = torch.as_tensor([parents[j] for j in legs], device=device)
    anc_legs = anc[:, leg_idx - 1]                                             # (J, L)
    anc_feet = anc_legs[feet_idx]                                              # (4, L)
    bones0 = x0[:, :, leg_idx] - x0[:, :, leg_parent]                          # (B, T, L, 3)
    bone_len = bones0.norm(dim=-1, keepdim=True)                               # fixed, per frame
    fallback = torch.zeros_like(bones0)
    fallback[..., cfg.up_axis] = 1.0
    dir0 = torch.where(bone_len > 1e-8, bones0 / bone_len.clamp(min=1e-8), fallback)
    root0 = x0[:, :, 0]
    feet0 = x0[:, :, feet_idx]
    normalise = lambda d: d / d.norm(dim=-1, keepdim=True).clamp(min=1e-8)
    unit0 = normalise(dir0)  # same rounding as in the loop, so the correction starts at exactly 0
    norm0 = dir0.norm(dim=-1)  # ≈ 1; measured, not assumed, so every term is exactly 0 at the start

    def bone_delta(direction: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        unit = normalise(direction)
        return unit, bone_len * (unit - unit0)                                 # (B, T, L, 3) each

    def positions(shift: torch.Tensor, delta: torch.Tensor, rows: torch.Tensor, base: torch.Tensor) -> torch.Tensor:
        return base + shift[:, :, None] + torch.einsum("jl,btlc->btjc", rows, delta)

    use_vgrf = vgrf is not None and cfg.w_vgrf > 0
    if use_vgrf:
        for p in vgrf.parameters():
            p.requires_grad_(False)
        if forces0 is None:
            with torch.no_grad():
                forces0 = vgrf(x0, lengths)

    shift_raw = torch.zeros_like(root0, requires_grad=True)                    # root displacement parameter (B, T, 3)

    def root_shift(raw: torch.Tensor) -> torch.Tensor:
        """The root displacement: `raw` squashed radially to a norm below cfg.max_root_shift
        (c tanh(r / c) r̂: the identity near 0, so small corrections are unchanged)."""
        c = cfg.max_root_shift
        if not c < float("inf"):
            return raw
        r = (raw.square().sum(-1, keepdim=True) + 1e-24).sqrt()
        return raw * (c * torch.tanh(r / c) / r)

    direction = dir0.clone().requires_grad_(True)
    # eps well above rounding-level gradients: Adam would otherwise blow float noise up to full steps
    opt = torch.optim.Adam([{"params": [shift_raw], "lr": cfg.lr_root}, {"params": [direction], "lr": cfg.lr}], eps=1e-6)
    pair = (mask[:, 1:] & mask[:, :-1]).to(dtype)                             # valid velocity pairs
    triple = (mask[:, 2:] & mask[:, :-2]).to(dtype)
    # A free joint may rise, not sink below its input height (a swing foot dragged down by the
    # root), except as far as its foot's anchored other joint is pulled down (a flat foot planted
    # by its heel alone keeps its shape), and never below the floor (a generated frame dipping
    # through it, which the placement above took further down).
    pull = torch.where(weights > 0, targets_filled[..., cfg.up_axis] - feet0[..., cfg.up_axis],
                       torch.zeros_like(weights)).clamp(max=0)                # (B, T, 4) downward anchor pulls
    clear_height = (feet0[..., cfg.up_axis] + pull[..., [1, 0, 3, 2]]).clamp(min=cfg.planted_height)  # (B, T, 4)
    # an anchored joint is held at the floor too: its foot's other anchor can pitch it through
    clear_height = torch.where(weights == 0, clear_height, torch.full_like(clear_height, cfg.planted_height))
    swing_goal = feet0 + swing_offsets(targets_filled - feet0, weights > 0, cfg.up_axis)  # (B, T, 4, 3)
    swing_w = (1 - weights).clamp(min=0) * maskf[..., None]                   # (B, T, 4)
    acc_in2 = (feet0[:, 2:] - 2 * feet0[:, 1:-1] + feet0[:, :-2]).square().sum(-1)  # (B, T-2, 4)
    vgrf_grad = None
    has_anchor = bool((weights > 0).any())
    history = []

    for it in range(cfg.iters if has_anchor else 0):
        opt.zero_grad(set_to_none=True)
        unit, delta = bone_delta(direction)
        shift = root_shift(shift_raw)
        feet_pos = positions(shift, delta, anc_feet, feet0)                    # (B, T, 4, 3)
        corr = feet_pos - feet0                                                # the correction at the feet
        acc = corr[:, 2:] - 2 * corr[:, 1:-1] + corr[:, :-2]
        acc_out = feet_pos[:, 2:] - 2 * feet_pos[:, 1:-1] + feet_pos[:, :-2]  # (B, T-2, 4, 3)
        per_sample = {
            "pose": ((unit - unit0).square().sum(-1).mean(-1) * maskf).sum(1) / n_frames,
            "norm": ((direction.norm(dim=-1) - norm0).square().mean(-1) * maskf).sum(1) / n_frames,
            "trajectory": ((shift[:, 1:] - shift[:, :-1]).square().sum(-1) * pair).sum(1) / n_frames,
            "foot": ((feet_pos - targets_filled).square().sum(-1) * weights).sum((1, 2)) / n_frames,
            "smooth": (acc.square().sum(-1).mean(-1) * triple).sum(1) / n_frames,
            "clearance": ((clear_height - feet_pos[..., cfg.up_axis]).clamp(min=0).square()
                          * maskf[..., None]).sum((1, 2)) / n_frames,
            "swing": ((feet_pos - swing_goal).square().sum(-1) * swing_w).sum((1, 2)) / n_frames,
            "accel": ((acc_out.square().sum(-1) - acc_in2).clamp(min=0).mean(-1) * triple).sum(1) / n_frames,
        }
        loss = (cfg.w_pose * per_sample["pose"] + cfg.w_norm * per_sample["norm"]
                + cfg.w_trajectory * per_sample["trajectory"] + cfg.w_foot * per_sample["foot"]
                + cfg.w_smooth * per_sample["smooth"] + cfg.w_clearance * per_sample["clearance"]
                + cfg.w_swing * per_sample["swing"] + cfg.w_accel * per_sample["accel"]).sum()
        if use_vgrf:
            # The vGRF net costs far more than everything else: its gradient w.r.t. positions is
            # refreshed every `vgrf_every` iterations and applied as a linear term in between.
            if it % cfg.vgrf_every == 0:
                with torch.no_grad():
                    p_now = positions(shift, delta, anc_legs, x0)
                p_leaf = p_now.requires_grad_(True)
                err = msle(vgrf(p_leaf, lengths), forces0).mean((-1, -2))        # (B, T)
                l_v = ((err * maskf).sum(1) / n_frames).sum()
                vgrf_grad, = torch.autograd.grad(l_v, p_leaf)
                per_sample_v = (err.detach() * maskf).sum(1) / n_frames
                # chain rule through the affine map, precomputed once per refresh
                g_shift = vgrf_grad.sum(2)                                     # (B, T, 3)
                g_delta = torch.einsum("jl,btjc->btlc", anc_legs, vgrf_grad)   # (B, T, L, 3)
            loss = loss + cfg.w_vgrf * ((g_shift * shift).sum() + (g_delta * delta).sum())
        loss.backward()
        opt.step()
        if it == 0 or it == cfg.iters - 1:
            record = {k: float(v.detach().sum()) for k, v in per_sample.items()}
            if use_vgrf:
                record["vgrf"] = float(per_sample_v.sum())
            history.append(record)

    with torch.no_grad():
        out = positions(root_shift(shift_raw), bone_delta(direction)[1], anc_legs, x0) if has_anchor else x0
        # Bit-exact passthrough where nothing was optimised: untouched samples stay as given.
        out = torch.where(mask[..., None, None], out, joints.detach().to(dtype))
        changed = (weights.sum((1, 2)) > 0)
        out = torch.where(changed[:, None, None, None], out, joints.detach().to(dtype))
    info.update({"seconds": time.perf_counter() - started, "iters": cfg.iters if has_anchor else 0,
                 "loss_first": history[0] if history else {}, "loss_last": history[-1] if history else {},
                 "config": asdict(cfg)})
    return CleanupResult(joints=out.to(joints.dtype), contacts=contacts, targets=targets, weights=weights, info=info)


def anchor_drift(joints: torch.Tensor, result: CleanupResult, feet, up_axis: int = 1) -> torch.Tensor:
    """Per-frame horizontal distance (B, T, 4) of contact joints from their range targets, on the
    frames of anchored ranges (NaN elsewhere)."""
    pos = joints[:, :, list(feet)]
    horiz = [a for a in range(3) if a != up_axis]
    dist = (pos[..., horiz] - result.targets[..., horiz]).norm(dim=-1)
    return torch.where(result.weights > 0, dist, torch.full_like(dist, float("nan")))
