"""What a human body and a motion file can plausibly hold, stated once.

A value outside these bounds is a wrong unit (KIT-ML joints are millimetres, HumanML3D's metres), a
typo or a hostile input, never a motion: it is named in one line before any compute, instead of a
pelvis flying at 900 m, a render that draws a floor grid a thousand kilometres wide, or a timeline
that allocates memory until it is killed. Bounds are in metres and seconds; `scale` converts them
to a skeleton's unit. The callers are the checks where each value is defined (control targets,
timelines, renders, bundle statistics, BVH files), so the CLI, the Python API and the server share
them.
"""

from __future__ import annotations

import numpy as np

from stablemo.errors import StableMoError
from stablemo.motion.skeleton import Skeleton, get_skeleton

# The largest extent of a person's joints in one frame, lying or standing (a child crouching
# spans ~0.5 m, an adult with raised arms ~2.3 m).
BODY_SPAN_M = (0.2, 5.0)
# Faster than any human moves: the fastest measured sprint peaks near 12.4 m/s (Berlin 2009, 100 m
# split times). A root or target that must travel faster than this between frames is not a motion.
MAX_SPEED_M_S = 15.0
# The fastest pace a generated body keeps along a path for seconds: a jog. The demo models' data
# (data/synth, 2000 clips) moves its root at most 3.7 m/s in any frame and at most 2.0 m/s averaged
# over a clip; a path asking more is met by sliding the pelvis along it, not by walking or running.
FOLLOW_SPEED_M_S = 3.0
# Height of a joint above the floor: a little below it (sloppy floors in mocap), up to a hand at
# the top of a high jump.
HEIGHT_RANGE_M = (-1.0, 4.0)
# The root (pelvis) is never this close to the floor, even lying down (its centre is ~10 cm up):
# root targets that all stay below it are in too small a unit (KIT millimetres given as metres).
MIN_ROOT_HEIGHT_M = 0.05
# How far a joint can be from the root's position (arm span plus a lean), which a target at frame
# t may add to the distance the root can travel in t frames.
REACH_M = 2.5
# Motion features, statistics: |x| of a few units in normalised data, up to a few metres
# (thousands of millimetres) raw; 1e4 is far beyond any real motion, yet finite values as large as
# 3e38 pass a finiteness check and overflow once normalised or multiplied by a Std.
MAX_ABS_FEATURE = 1e4
# One timeline's length: ten minutes is far beyond any prompt list a user types, and bounds its
# memory (frames x features) and compute before anything is allocated.
MAX_TIMELINE_SECONDS = 600.0
# Frame rates of motion files: motion capture runs at up to a few hundred Hz; below 1 fps a file is
# not an animation. Bounds the frame grid a resampler builds from a file's Frame Time.
FPS_RANGE = (1.0, 1000.0)
# Joints in a BVH hierarchy: a full-body rig with fingers, face and twist bones has a few hundred.
MAX_BVH_JOINTS = 1024


def scale(skeleton: Skeleton | str) -> float:
    """Skeleton units per metre (HumanML3D metres: 1; KIT-ML millimetres: 1000)."""
    return get_skeleton(skeleton).per_metre


def _unit_hint(skel: Skeleton, values_m: np.ndarray, fits) -> str:
    """' (they look like millimetres; ...)' when the values would fit in the other unit."""
    if skel.units == "m" and fits(values_m / 1000.0):
        return f"; they look like millimetres, and {skel.name} positions are metres"
    if skel.units == "mm" and fits(values_m * 1000.0):
        return f"; they look like metres, and {skel.name} positions are millimetres"
    return ""


def check_targets(positions: np.ndarray, mask: np.ndarray, skeleton: Skeleton | str, what: str) -> None:
    """Joint targets (T, J, 3) under a (T, J) mask, in the skeleton's unit, in the motion's own frame
    (the root starts at the origin): each at a plausible height, and no farther from the origin than
    a body can reach after running at MAX_SPEED_M_S since frame 0."""
    skel = get_skeleton(skeleton)
    frames, joints = np.nonzero(mask)
    if len(frames) == 0:
        return
    pts = np.asarray(positions, np.float64)[frames, joints] / scale(skel)  # (N, 3) metres
    reach = MAX_SPEED_M_S * frames / skel.fps + REACH_M                     # (N,) metres

    def fits(p: np.ndarray) -> np.ndarray:  # (N, 3) metres -> (N,) bool
        return ((p[:, 1] >= HEIGHT_RANGE_M[0]) & (p[:, 1] <= HEIGHT_RANGE_M[1])
                & (np.hypot(p[:, 0], p[:, 2]) <= reach))

    ok = fits(pts)
    roots = joints == 0
    if roots.any() and pts[roots, 1].max() < MIN_ROOT_HEIGHT_M and ok.all():
        k = int(np.argmax(np.where(roots, pts[:, 1], -np.inf)))
        hint = _unit_hint(skel, pts[roots], lambda p: bool(p[:, 1].max() >= MIN_ROOT_HEIGHT_M))
        raise StableMoError(
            f"{what}: every target of {skel.joint_names[0]} is below {MIN_ROOT_HEIGHT_M * scale(skel):g} {skel.units} "
            f"(highest {pts[k, 1] * scale(skel):.3g} {skel.units} at frame {int(frames[k])}): a pelvis is never that "
            f"close to the floor{hint}")
    if ok.all():
        return
    k = int(np.argmin(ok))
    t, j = int(frames[k]), int(joints[k])
    x, y, z = pts[k]
    unit = scale(skel)
    hint = _unit_hint(skel, pts, lambda p: bool(fits(p).all()))
    raise StableMoError(
        f"{what}: the target of {skel.joint_names[j]} at frame {t} is at x={x * unit:.4g}, y={y * unit:.4g}, "
        f"z={z * unit:.4g} {skel.units}: a body starting at the origin cannot be there (heights "
        f"{HEIGHT_RANGE_M[0]:g} to {HEIGHT_RANGE_M[1]:g} m, at most {reach[k]:.3g} m from the origin at that "
        f"frame, moving at most {MAX_SPEED_M_S:g} m/s){hint}")


def target_pace(frames: np.ndarray, joints: np.ndarray, points: np.ndarray, skeleton: Skeleton | str,
                bone_lengths: np.ndarray | None = None) -> float:
    """The pace (m/s, on the floor) a body must keep to meet joint targets: frames (N,), joints (N,)
    and points (N, 3) in the skeleton's unit, in the motion's own frame (the root starts at the
    origin at frame 0). The largest of: between consecutive targets of one joint, their distance
    over their time apart; from the start, a target's distance from the origin less the joint's
    reach from the pelvis (the bones between them; bone_lengths (J,) default the skeleton's), over
    its time. 0 when nothing is asked of the body's travel."""
    skel = get_skeleton(skeleton)
    lengths = np.asarray(skel.bone_lengths if bone_lengths is None else bone_lengths, np.float64) / scale(skel)
    reach = np.zeros(skel.num_joints)
    for j in range(1, skel.num_joints):  # parents come before their children
        reach[j] = reach[skel.parents[j]] + lengths[j]
    frames, joints = np.asarray(frames, np.int64), np.asarray(joints, np.int64)
    xz = np.asarray(points, np.float64)[:, [0, 2]] / scale(skel)  # (N, 2) metres
    pace = 0.0
    late = frames > 0
    if late.any():
        away = np.maximum(np.linalg.norm(xz[late], axis=-1) - reach[joints[late]], 0.0)
        pace = float((away / (frames[late] / skel.fps)).max())
    for j in np.unique(joints):
        order = np.argsort(frames[joints == j])
        f, p = frames[joints == j][order], xz[joints == j][order]
        if len(f) > 1:
            pace = max(pace, float((np.linalg.norm(np.diff(p, axis=0), axis=-1) / (np.diff(f) / skel.fps)).max()))
    return pace


def check_joints_extent(joints: np.ndarray, skeleton: Skeleton | str, fps: float, what: str) -> None:
    """Joints (T, J, 3) in the skeleton's unit: no frame's body is larger than a person (a unit
    1000x too large), and the horizontal extent over the motion is no more than a body covers at
    MAX_SPEED_M_S. A body too small to be a person is not refused here: it costs nothing to draw,
    and an untrained or diverging model makes such bodies, which a user should see."""
    skel = get_skeleton(skeleton)
    arr = np.asarray(joints, np.float64) / scale(skel)                       # (T, J, 3) metres
    span = float(np.linalg.norm(arr.max(1) - arr.min(1), axis=-1).max())     # largest body extent of a frame
    xz = arr[..., [0, 2]].reshape(-1, 2)
    extent = float(np.linalg.norm(xz.max(0) - xz.min(0)))
    limit = MAX_SPEED_M_S * max(len(arr) - 1, 0) / fps + 2 * REACH_M
    if span <= BODY_SPAN_M[1] and extent <= limit:
        return
    unit = "millimetres" if skel.units == "mm" else "metres"
    if span > BODY_SPAN_M[1]:
        raise StableMoError(f"{what}: the body spans {span:.3g} m read as {unit}, the unit of {skel.name} joints "
                            f"(a person spans {BODY_SPAN_M[0]:g}-{BODY_SPAN_M[1]:g} m); convert the joints or pick "
                            "the skeleton")
    raise StableMoError(f"{what}: the joints cover {extent:.4g} m in {len(arr) / fps:.3g} s, faster than a body "
                        f"moves (at most {MAX_SPEED_M_S:g} m/s): a broken motion, not one to draw")


def check_feature_stats(values: np.ndarray, what: str) -> None:
    """Mean/Std vectors: |x| <= MAX_ABS_FEATURE (finite values as large as 3e38 overflow downstream)."""
    big = np.abs(np.asarray(values, np.float64)) > MAX_ABS_FEATURE
    if big.any():
        dim = int(np.argmax(big))
        raise StableMoError(f"{what}: {int(big.sum())} value(s) with |x| > {MAX_ABS_FEATURE:g} (dim {dim} is "
                            f"{float(np.asarray(values).reshape(-1)[dim]):g}): outside the range of motion features")


def check_fps(fps: float, what: str) -> float:
    """A frame rate within FPS_RANGE (finite, positive)."""
    if not (isinstance(fps, (int, float)) and FPS_RANGE[0] <= fps <= FPS_RANGE[1]):
        raise StableMoError(f"{what}: {fps:g} fps is outside {FPS_RANGE[0]:g}-{FPS_RANGE[1]:g} fps"
                            if isinstance(fps, (int, float)) else f"{what}: {fps!r} is not a frame rate")
    return float(fps)


__all__ = ["BODY_SPAN_M", "FOLLOW_SPEED_M_S", "FPS_RANGE", "HEIGHT_RANGE_M", "MAX_ABS_FEATURE", "MAX_BVH_JOINTS", "MAX_SPEED_M_S",
           "MAX_TIMELINE_SECONDS", "MIN_ROOT_HEIGHT_M", "REACH_M", "check_feature_stats", "check_fps", "check_joints_extent",
           "check_targets", "scale", "target_pace"]
