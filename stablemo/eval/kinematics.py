"""Kinematic measures of motions: what the eye sees and FID does not.

Every measure takes global joint positions `joints` (B, T, J, 3) in the skeleton's units (y up, floor
at y = 0; HumanML3D metres, KIT-ML millimetres), `lengths` (B,) valid frames per motion (padding is
ignored) and the skeleton, and returns one number per motion (B,) in centimetres, cm/s, m/s² or a
share of frames, whatever the skeleton's unit:

- bone_change    the largest (max − min) length of any bone over the motion's frames (cm); a rigid body: 0
- floor_p1       the 1st percentile over frames of the lowest foot joint's height (cm; negative: below the floor)
- below_floor    the share of frames whose lowest foot joint is more than BELOW_FLOOR_M under the floor
- stance_height  the median height of the lowest foot joint over stance frames (a foot joint in contact), cm
- stance_speed   the mean horizontal speed of foot joints in contact, over frame pairs in contact (cm/s)
- foot_acc       the feet's mean |second difference| (stablemo.skating.metrics.foot_acceleration), m/s²
- airborne       the share of frames whose lowest foot joint is more than AIRBORNE_M above its local ground

"Foot joints" are the skeleton's contact joints (feet_left + feet_right: HumanML3D's ankles and toes,
KIT's metatarsals and toes). Contacts come from footskate's low-and-slow rule (contacts_from_heights:
lower than 5 cm and slower than 0.93 m/s), the height taken above the joint's local ground (its
20th percentile within 1 s; local_ground). Being relative to the motion, it keeps a lifted, sunk or
drifting motion's stance frames, so the offset shows in stance_height rather than as flight.
Measures undefined for a motion (no stance frame) are NaN for it. docs/evaluation.md lists the
values measured on ground-truth motions.
"""

from __future__ import annotations

import numpy as np
import torch

from footskate.contacts import HEURISTIC_MARGIN, HEURISTIC_SPEED, contacts_from_heights
from stablemo.errors import StableMoError
from stablemo.motion.plausible import scale
from stablemo.motion.rigid import bone_lengths_of
from stablemo.motion.skeleton import Skeleton, get_skeleton
from stablemo.skating import metrics as skating_metrics

# A foot joint this far under the floor is visibly inside it (a mocap floor is level to ~1 cm).
BELOW_FLOOR_M = 0.01
# Both feet this far above the motion's local ground: off the floor (a walk's stance toe stays within
# ~1 cm of it; a synthetic jump's flight lifts the toes ~20 cm).
AIRBORNE_M = 0.05
# The local ground of a height: its LOCAL_GROUND_QUANTILE over the frames within LOCAL_GROUND_S either
# side. Longer than any flight (a jump's is under 0.5 s), shorter than a motion: a body that floats
# between two jumps, or drifts up over its length, is in contact there at its own height, so the
# floating shows in stance_height instead of reading as flight. A low quantile, not the minimum: a
# demo teacher's jump dipped its feet 4-7 cm for a frame or two before each take-off, and a minimum
# would stand the whole second around such a dip on it.
LOCAL_GROUND_S = 1.0
LOCAL_GROUND_QUANTILE = 0.2
FLOOR_QUANTILE = 0.01  # floor_p1
MEASURES = ("bone_change", "floor_p1", "below_floor", "stance_height", "stance_speed", "foot_acc", "airborne")


def prepare(joints, lengths, skeleton: Skeleton | str) -> tuple[torch.Tensor, torch.Tensor, Skeleton]:
    """joints -> float64 CPU tensor (B, T, J, 3), lengths -> long (B,), the Skeleton; bad shapes,
    lengths or non-finite positions are one StableMoError line."""
    skel = get_skeleton(skeleton)
    j = (joints if torch.is_tensor(joints) else torch.as_tensor(np.asarray(joints))).detach().to("cpu", torch.float64)
    if j.ndim != 4 or tuple(j.shape[2:]) != (skel.num_joints, 3):
        raise StableMoError(f"joints: expected (B, T, {skel.num_joints}, 3) for {skel.name}, got {tuple(j.shape)}")
    n = torch.as_tensor(np.asarray(lengths) if not torch.is_tensor(lengths) else lengths).reshape(-1).long().cpu()
    if n.numel() != j.shape[0] or bool(((n < 1) | (n > j.shape[1])).any()):
        raise StableMoError(f"lengths: expected {j.shape[0]} values in [1, {j.shape[1]}], got {n.tolist()}")
    valid = valid_mask(n, j.shape[1])
    if not bool(torch.isfinite(j[valid]).all()):
        raise StableMoError("joints: NaN or Inf on valid frames")
    return torch.where(valid[..., None, None], j, torch.zeros((), dtype=j.dtype)), n, skel  # padding: 0


def valid_mask(lengths: torch.Tensor, frames: int) -> torch.Tensor:
    """(B,) lengths -> (B, frames) bool, True on each motion's valid prefix."""
    return torch.arange(frames)[None, :] < lengths[:, None]


def _cm(skel: Skeleton) -> float:
    """Centimetres per skeleton unit."""
    return 100.0 / scale(skel)


def _masked_quantile(x: torch.Tensor, keep: torch.Tensor, q: float) -> torch.Tensor:
    """Quantile over dim 1 of x (B, T) on the frames where keep (B, T); NaN for a row with none."""
    return torch.nanquantile(torch.where(keep, x, torch.full_like(x, float("nan"))), q, dim=1)


def _foot_joints(skel: Skeleton) -> list[int]:
    return list(skel.contact_joints)


def local_ground(height: torch.Tensor, lengths: torch.Tensor, fps: float) -> torch.Tensor:
    """height (B, T, ...) -> its LOCAL_GROUND_QUANTILE over the valid frames within LOCAL_GROUND_S of
    each frame, same shape (NaN on padding)."""
    radius = max(1, round(LOCAL_GROUND_S * fps))
    valid = valid_mask(lengths, height.shape[1]).reshape(height.shape[:2] + (1,) * (height.ndim - 2))
    x = torch.where(valid, height, torch.full_like(height, float("nan"))).movedim(1, -1)  # (B, ..., T)
    x = torch.nn.functional.pad(x, (radius, radius), value=float("nan"))
    windows = x.unfold(-1, 2 * radius + 1, 1)  # (B, ..., T, 2 radius + 1)
    return torch.nanquantile(windows, LOCAL_GROUND_QUANTILE, dim=-1).movedim(-1, 1)


def lowest_foot_height(j: torch.Tensor, skeleton: Skeleton | str) -> torch.Tensor:
    """(B, T, J, 3) -> (B, T): the height of the lowest foot joint (skeleton units)."""
    return j[:, :, _foot_joints(get_skeleton(skeleton)), 1].amin(-1)


def end_effectors(skeleton: Skeleton | str) -> list[int]:
    """The joints no bone leaves from: feet (toes), hands (wrists) and head on both skeletons."""
    skel = get_skeleton(skeleton)
    return [i for i in range(skel.num_joints) if i not in skel.parents]


def end_effector_groups(skeleton: Skeleton | str) -> dict[str, list[int]]:
    """End effectors by body part, from the chains: feet end a chain at a contact joint, the head
    ends the other chain that starts at the root, hands end the chains that start above it."""
    skel = get_skeleton(skeleton)
    groups: dict[str, list[int]] = {"feet": [], "hands": [], "head": []}
    for chain in skel.kinematic_chains:
        part = "feet" if chain[-1] in skel.contact_joints else "head" if chain[0] == 0 else "hands"
        groups[part].append(chain[-1])
    return {k: sorted(v) for k, v in groups.items()}


# ----------------------------------------------------------------------------- the measures


def bone_change(joints, lengths, skeleton) -> np.ndarray:
    """(B,) cm: max over bones of (max − min) of the bone's length over valid frames."""
    j, n, skel = prepare(joints, lengths, skeleton)
    valid = valid_mask(n, j.shape[1])[..., None]  # (B, T, 1)
    bone = bone_lengths_of(j, skel)[..., 1:]  # (B, T, J-1)
    longest = torch.where(valid, bone, torch.full_like(bone, -float("inf"))).amax(1)
    shortest = torch.where(valid, bone, torch.full_like(bone, float("inf"))).amin(1)
    return ((longest - shortest).amax(-1) * _cm(skel)).numpy()


def floor_penetration(joints, lengths, skeleton) -> dict[str, np.ndarray]:
    """floor_p1 (B,) cm: 1st percentile of the lowest foot joint's height; below_floor (B,): share of
    frames with it more than BELOW_FLOOR_M under the floor."""
    j, n, skel = prepare(joints, lengths, skeleton)
    valid = valid_mask(n, j.shape[1])
    low = lowest_foot_height(j, skel)  # (B, T)
    below = (low < -BELOW_FLOOR_M * scale(skel)) & valid
    return {"floor_p1": (_masked_quantile(low, valid, FLOOR_QUANTILE) * _cm(skel)).numpy(),
            "below_floor": (below.sum(1).double() / n.double()).numpy()}


def foot_contacts(joints, lengths, skeleton) -> torch.Tensor:
    """(B, T, 4) bool contacts of the contact joints (feet_left + feet_right), False on padding:
    footskate's low-and-slow rule with its metre thresholds in the skeleton's unit, "low" measured
    from each joint's local ground (local_ground) rather than its lowest point in the whole motion."""
    j, n, skel = prepare(joints, lengths, skeleton)
    per_metre = scale(skel)
    feet = j[:, :, _foot_joints(skel)].clone()  # (B, T, 4, 3)
    feet[..., 1] = torch.nan_to_num(feet[..., 1] - local_ground(feet[..., 1], n, skel.fps))  # padding: 0
    contacts = contacts_from_heights(feet, skel.fps, 1, n, height=HEURISTIC_MARGIN * per_metre,
                                     speed=HEURISTIC_SPEED * per_metre, relative=False)
    return contacts & valid_mask(n, j.shape[1])[..., None]


def stance_height(joints, lengths, skeleton, contacts: torch.Tensor | None = None) -> np.ndarray:
    """(B,) cm: median of the lowest foot joint's height over frames with a foot joint in contact
    (NaN for a motion without any). `contacts` (B, T, 4): foot_contacts' unless given."""
    j, n, skel = prepare(joints, lengths, skeleton)
    c = foot_contacts(j, n, skel) if contacts is None else contacts
    return (_masked_quantile(lowest_foot_height(j, skel), c.any(-1), 0.5) * _cm(skel)).numpy()


def stance_speed_sums(joints: torch.Tensor, contacts: torch.Tensor, lengths: torch.Tensor, feet,
                      fps: float) -> tuple[torch.Tensor, torch.Tensor]:
    """The one definition of stance-foot speed: per motion, the summed horizontal speed (units/s) of
    the `feet` joints over frame pairs where the joint is in contact at both frames, and the pair
    count. joints (B, T, J, 3), contacts (B, T, len(feet)) bool, lengths (B,)."""
    feet_xz = joints[:, :, list(feet)][..., [0, 2]].double()  # (B, T, F, 2)
    speed = (feet_xz[:, 1:] - feet_xz[:, :-1]).norm(dim=-1) * fps  # (B, T-1, F)
    pairs = contacts[:, 1:] & contacts[:, :-1] & valid_mask(lengths - 1, joints.shape[1] - 1)[..., None]
    return (speed * pairs).sum((1, 2)), pairs.sum((1, 2)).double()


def stance_speed(joints, lengths, skeleton, contacts: torch.Tensor | None = None) -> np.ndarray:
    """(B,) cm/s: mean horizontal speed of the foot joints over frame pairs in contact (NaN without any)."""
    j, n, skel = prepare(joints, lengths, skeleton)
    c = foot_contacts(j, n, skel) if contacts is None else contacts
    total, count = stance_speed_sums(j, c, n, _foot_joints(skel), skel.fps)
    return (total / count * _cm(skel)).numpy()  # 0/0 = NaN: no pair in contact


def standing_foot_speed(joints, lengths, skeleton) -> np.ndarray:
    """(B,) cm/s: median, over valid frame pairs i -> i+1 where the body is not airborne (its lowest
    foot joint within AIRBORNE_M of its local ground at frame i), of the horizontal speed of the foot
    joint that is lowest at frame i (NaN for a motion without such a pair).

    No contact detection, so no speed bound: stance_speed counts a foot only while it is slower than
    footskate's 0.93 m/s, and a foot dragged faster than that drops out of it instead of counting as
    a slide. Tried on 2026-12-06 (docs/control.md), a change to the finishing step's anchors
    lowered stance_speed along drawn paths to 0.7-1.1x the free walk's while this measure rose from
    58-68 to 79-82 cm/s (the walk's own speed: 73)."""
    j, n, skel = prepare(joints, lengths, skeleton)
    feet = j[:, :, _foot_joints(skel)]  # (B, T, F, 3)
    lowest, low = feet[..., 1].min(-1)  # (B, T): the lowest foot joint's height and which one it is
    ground = local_ground(lowest, n, skel.fps)
    step = (feet[:, 1:, :, [0, 2]] - feet[:, :-1, :, [0, 2]]).norm(dim=-1) * skel.fps  # (B, T-1, F)
    speed = torch.gather(step, 2, low[:, :-1, None])[..., 0]  # (B, T-1)
    keep = (valid_mask(n - 1, j.shape[1] - 1)
            & (torch.nan_to_num(lowest - ground, nan=float("inf"))[:, :-1] <= AIRBORNE_M * scale(skel)))
    return (_masked_quantile(speed, keep, 0.5) * _cm(skel)).numpy()


def foot_acceleration(joints, lengths, skeleton) -> np.ndarray:
    """(B,) m/s²: stablemo.skating.metrics.foot_acceleration of the foot joints, in m/s² on any skeleton."""
    j, n, skel = prepare(joints, lengths, skeleton)
    return skating_metrics.foot_acceleration(j, lengths=n, feet=_foot_joints(skel), fps=skel.fps) / scale(skel)


def airborne_share(joints, lengths, skeleton) -> np.ndarray:
    """(B,): share of valid frames whose lowest foot joint is more than AIRBORNE_M above its local
    ground (local_ground), so a floor offset or a body floating between jumps is not a flight, a jump is."""
    j, n, skel = prepare(joints, lengths, skeleton)
    valid = valid_mask(n, j.shape[1])
    low = lowest_foot_height(j, skel)
    up = (low - local_ground(low, n, skel.fps) > AIRBORNE_M * scale(skel)) & valid
    return (up.sum(1).double() / n.double()).numpy()


def displacement(a, b, lengths, skeleton, joint_ids=None) -> np.ndarray:
    """(B,) cm: mean distance between two versions of the same motions (e.g. raw network output and
    what the user receives) over valid frames and `joint_ids` (default: the end effectors)."""
    ja, n, skel = prepare(a, lengths, skeleton)
    jb, _, _ = prepare(b, lengths, skel)
    if ja.shape != jb.shape:
        raise StableMoError(f"joints: the two versions differ in shape, {tuple(ja.shape)} vs {tuple(jb.shape)}")
    ids = end_effectors(skel) if joint_ids is None else list(joint_ids)
    dist = (ja[:, :, ids] - jb[:, :, ids]).norm(dim=-1).mean(-1)  # (B, T)
    return ((dist * valid_mask(n, ja.shape[1])).sum(1) / n.double() * _cm(skel)).numpy()


def measure(joints, lengths, skeleton) -> dict[str, np.ndarray]:
    """Every measure of MEASURES, (B,) each, the contacts detected once."""
    j, n, skel = prepare(joints, lengths, skeleton)
    contacts = foot_contacts(j, n, skel)
    return {"bone_change": bone_change(j, n, skel), **floor_penetration(j, n, skel),
            "stance_height": stance_height(j, n, skel, contacts), "stance_speed": stance_speed(j, n, skel, contacts),
            "foot_acc": foot_acceleration(j, n, skel), "airborne": airborne_share(j, n, skel)}


def summarise(per_motion: dict[str, np.ndarray]) -> dict[str, float]:
    """Mean over motions of each measure, the motions where it is undefined (NaN) left out; a measure
    undefined for every motion is left out of the result."""
    return {k: float(np.nanmean(v)) for k, v in per_motion.items() if np.isfinite(v).any()}
