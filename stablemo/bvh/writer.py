"""Motion (features or joints) -> BVH: the functions behind `stablemo bvh`, `generate --format bvh`
and the server's download (see stablemo/bvh/__init__.py).

`export_motion` is the one path: the rig and its rotations at the motion's rate, the file's fit to
the motion measured there (stablemo.bvh.fit), then the resampling to the output rate. `bvh_text`
and `write_bvh` are its two common uses.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stablemo.bvh.fit import Fit, measure_fit
from stablemo.bvh.resample import resample
from stablemo.bvh.rig import Animation, forward_kinematics, joints_to_animation
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


def check_bone_lengths(bone_lengths, skeleton: Skeleton | str, what: str = "bone_lengths") -> np.ndarray | None:
    """A body's bone lengths (J,) parent -> joint (root first, any value), in the skeleton's units
    (HumanML3D metres, KIT millimetres), as float64; None stays None (the motion's own lengths)."""
    if bone_lengths is None:
        return None
    skel = get_skeleton(skeleton)
    if hasattr(bone_lengths, "detach"):
        bone_lengths = bone_lengths.detach().cpu().numpy()
    try:
        lengths = np.asarray(bone_lengths, dtype=np.float64)
    except (TypeError, ValueError):
        lengths = np.zeros(0)
    if lengths.shape != (skel.num_joints,) or not np.all(np.isfinite(lengths)) or np.any(lengths[1:] <= 0):
        raise StableMoError(f"{what}: expected {skel.num_joints} finite lengths (parent -> joint, the root's "
                            f"first), > 0 after the root's, in {skel.units} for skeleton {skel.name}")
    return lengths


def motion_to_animation(motion, *, skeleton: Skeleton | str | None = None, fps: float | None = None,
                        source_fps: float | None = None, units: str = "m", stretch: bool = False,
                        bone_lengths=None) -> Animation:
    """The BVH animation of a motion: joints (or features, recovered to joints) -> T-pose rig +
    local rotations (stablemo.bvh.rig), scaled to `units`, resampled to `fps` (default: the
    source rate, 20 for HumanML3D, 12.5 for KIT). stretch: per-joint translations so that every
    joint is exact even where the motion's bones change length. bone_lengths: the body's (J,)
    (see check_bone_lengths); default each bone's median length over the motion."""
    return export_motion(motion, skeleton=skeleton, fps=fps, source_fps=source_fps, units=units, stretch=stretch,
                         bone_lengths=bone_lengths, measure=False).anim


@dataclass(frozen=True)
class Export:
    """A motion as a rig in motion, ready to write: `anim` at the output rate and units, and `fit`,
    how far the file's joints are from the motion's (None when not measured)."""

    anim: Animation
    fit: Fit | None

    def bvh(self) -> str:
        return format_bvh(self.anim)


def export_motion(motion, *, skeleton: Skeleton | str | None = None, fps: float | None = None,
                  source_fps: float | None = None, units: str = "m", stretch: bool = False,
                  bone_lengths=None, measure: bool = True) -> Export:
    """Everything checked, then the rig at the source rate, its fit to the motion (measure=True),
    and the resampling to `fps`. Keyword arguments as motion_to_animation."""
    if units not in UNITS:
        raise StableMoError(f"units={units!r}: choose one of {', '.join(UNITS)}")
    for name, rate in (("fps", fps), ("source_fps", source_fps)):
        if rate is not None and not (np.ndim(rate) == 0 and np.isreal(rate) and np.isfinite(rate) and rate > 0):
            raise StableMoError(f"{name}={rate!r}: must be a positive number")
    joints, skel = motion_joints(motion, skeleton)
    lengths = check_bone_lengths(bone_lengths, skel)
    per_metre = 1000.0 if skel.units == "mm" else 1.0  # skeleton units per metre
    scale = UNITS[units] / per_metre
    src = float(source_fps) if source_fps is not None else skel.fps
    anim = joints_to_animation(joints * scale, skel, src, stretch, None if lengths is None else lengths * scale)
    fit = measure_fit(forward_kinematics(anim) / UNITS[units], joints / per_metre, anim.rig.names) if measure else None
    return Export(resample(anim, float(fps)) if fps is not None else anim, fit)


def bvh_text(motion, **kwargs) -> str:
    """The BVH file's text for a motion; keyword arguments as motion_to_animation. For the file's
    distance from the motion as well, `export_motion(motion, **kwargs)` gives `.bvh()` and `.fit`."""
    return export_motion(motion, measure=False, **kwargs).bvh()


def write_bvh(path: str | os.PathLike, motion, **kwargs) -> Fit:
    """Write a motion as BVH (atomically); keyword arguments as motion_to_animation. Returns how far
    the file's joints are from the motion's (`fit.warning(path)` is a line to show, or None)."""
    from stablemo.io import write_text

    export = export_motion(motion, **kwargs)
    write_text(Path(path), export.bvh())
    return export.fit
