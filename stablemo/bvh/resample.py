"""Change an animation's frame rate: rotations by slerp, translations linearly."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from stablemo.bvh.rig import Animation
from stablemo.errors import StableMoError


def frame_times(num_frames: int, src_fps: float, dst_fps: float) -> np.ndarray:
    """Output times (seconds) covering the input's span [0, (T-1)/src]: frame 0 stays frame 0."""
    span = (num_frames - 1) / src_fps
    count = math.floor(span * dst_fps + 1e-9) + 1
    return np.arange(count) / dst_fps


def resample(anim: Animation, fps: float) -> Animation:
    """The animation at `fps`. Where an output frame falls on an input frame it is that frame."""
    if not math.isfinite(fps) or fps <= 0:
        raise StableMoError(f"fps={fps}: must be a positive number")
    if abs(fps - anim.fps) < 1e-9 or anim.num_frames < 2:
        return Animation(anim.rig, anim.root, anim.rotations, float(fps) if anim.num_frames < 2 else anim.fps, anim.positions)
    src = np.arange(anim.num_frames) / anim.fps  # (T,)
    dst = frame_times(anim.num_frames, anim.fps, fps)  # (T',)
    dst = np.minimum(dst, src[-1])
    rotations = np.empty((len(dst), anim.rig.num_joints, 4))
    for j in range(anim.rig.num_joints):
        track = Rotation.from_quat(anim.rotations[:, j][:, [1, 2, 3, 0]])
        rotations[:, j] = Slerp(src, track)(dst).as_quat()[:, [3, 0, 1, 2]]

    def lerp(values: np.ndarray) -> np.ndarray:  # (T, ...) -> (T', ...)
        flat = values.reshape(len(values), -1)
        out = np.stack([np.interp(dst, src, flat[:, k]) for k in range(flat.shape[1])], axis=1)
        return out.reshape((len(dst),) + values.shape[1:])

    positions = None if anim.positions is None else lerp(anim.positions)
    from stablemo.bvh.rig import continuous_hemisphere

    return Animation(anim.rig, lerp(anim.root), continuous_hemisphere(rotations), float(fps), positions)
