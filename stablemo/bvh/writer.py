"""Motion (features or joints) -> BVH: the function behind `stablemo bvh`, `generate --format bvh`
and anyone writing a download (see stablemo/bvh/__init__.py)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from stablemo.bvh.resample import resample
from stablemo.bvh.rig import Animation, joints_to_animation
from stablemo.bvh.text import format_bvh
from stablemo.errors import StableMoError
from stablemo.motion import features_to_joints, get_skeleton, skeleton_for_shape
from stablemo.motion.skeleton import Skeleton

UNITS = {"m": 1.0, "cm": 100.0, "mm": 1000.0}  # per metre


def motion_joints(motion, skeleton: Skeleton | str | None = None, what: str = "motion") -> tuple[np.ndarray, Skeleton]:
    """Features (T, D) or joints (T, J, 3) (numpy or torch) -> joints (T, J, 3) float64 and the skeleton."""
    if hasattr(motion, "detach"):
        motion = motion.detach().cpu().numpy()
    arr = np.asarray(motion)
    if not np.issubdtype(arr.dtype, np.number):
        raise StableMoError(f"{what}: expected a numeric array, got dtype {arr.dtype}")
    skel = get_skeleton(skeleton) if skeleton is not None else skeleton_for_shape(arr.shape)
    is_features = skel is not None and arr.ndim == 2 and arr.shape[1] == skel.feature_dim
    is_joints = skel is not None and arr.ndim == 3 and arr.shape[1:] == (skel.num_joints, 3)
    if not (is_features or is_joints):
        raise StableMoError(
            f"{what}: shape {arr.shape} is neither features (T, 263) / (T, 251) nor joints (T, 22, 3) / (T, 21, 3)"
            + (f" of skeleton {skel.name}" if skeleton is not None else ""))
    if len(arr) < 1:
        raise StableMoError(f"{what}: no frames")
    if not np.all(np.isfinite(arr)):
        raise StableMoError(f"{what}: contains NaN or Inf")
    joints = features_to_joints(arr.astype(np.float64), skel) if is_features else arr.astype(np.float64)
    return joints, skel


def motion_to_animation(motion, *, skeleton: Skeleton | str | None = None, fps: float | None = None,
                        source_fps: float | None = None, units: str = "m", stretch: bool = False) -> Animation:
    """The BVH animation of a motion: joints (or features, recovered to joints) -> T-pose rig +
    local rotations (stablemo.bvh.rig), scaled to `units`, resampled to `fps` (default: the
    source rate, 20 for HumanML3D, 12.5 for KIT). stretch: per-joint translations so that every
    joint is exact even where the motion's bones change length (generated motions)."""
    joints, skel = motion_joints(motion, skeleton)
    if units not in UNITS:
        raise StableMoError(f"units={units!r}: choose one of {', '.join(UNITS)}")
    scale = UNITS[units] / (1000.0 if skel.units == "mm" else 1.0)
    src = float(source_fps) if source_fps is not None else skel.fps
    anim = joints_to_animation(joints * scale, skel, src, stretch)
    return resample(anim, float(fps)) if fps is not None else anim


def bvh_text(motion, **kwargs) -> str:
    """The BVH file's text for a motion; keyword arguments as motion_to_animation."""
    return format_bvh(motion_to_animation(motion, **kwargs))


def write_bvh(path: str | os.PathLike, motion, **kwargs) -> Path:
    """Write a motion as BVH (atomically); keyword arguments as motion_to_animation."""
    from stablemo.io import write_text

    text = bvh_text(motion, **kwargs)
    write_text(Path(path), text)
    return Path(path)
