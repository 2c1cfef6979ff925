"""A drawn path's timing: walked at the pace of a reference motion (the one on screen).

A path drawn on the floor is a shape with no timing of its own. Walked at one constant speed from
frame 0 it drags a body whose text starts and ends standing (the demo models' walks idle for the
first and last second or so): the pelvis moves while the legs stand, and the stance feet slide.
Timed by a reference motion's own progress along its pelvis path instead, the drawn path is
walked where that motion walks and waits where it stands, at its pace scaled to the path's length
(the 1-step student, "a person walks forward", arcs, S-curves and out-and-back paths: stance feet
1.0-1.3x the free walk's speed, against 2.8-3.0x at a constant speed; docs/control.md).

The page (stablemo/serve/static/app.js, `pathTargets`) does the same with the motion on screen;
tests/test_serve_browser.py holds the two to the same numbers.
"""

from __future__ import annotations

import numpy as np

# the reference's per-frame steps are averaged over this many frames first, so a gait's sway does
# not make the pace flicker from frame to frame
SMOOTH_FRAMES = 5
# a reference that moves less than this (metres) stands: the path is walked at a constant speed
STILL_M = 0.2


def _moving_average(values: np.ndarray, k: int) -> np.ndarray:
    """values (N, ...) averaged over k neighbouring rows (the edge rows repeated), same shape."""
    pad = [(k // 2, k - 1 - k // 2)] + [(0, 0)] * (values.ndim - 1)
    padded = np.pad(values, pad, mode="edge")
    return np.stack([padded[i:i + len(values)] for i in range(k)]).mean(0)


def progress(reference_xz: np.ndarray, frames: int, per_metre: float = 1.0) -> np.ndarray:
    """(frames,) share of its pelvis path that a reference motion (T, 2) horizontal pelvis has
    walked at each of `frames` frames spread over its duration: from 0 to 1, never decreasing;
    a constant-speed ramp when it stands (moves less than STILL_M)."""
    ref = np.asarray(reference_xz, np.float64)
    ramp = np.linspace(0.0, 1.0, frames) if frames > 1 else np.zeros(frames)
    if len(ref) < 2:
        return ramp
    step = np.linalg.norm(np.diff(ref, axis=0), axis=-1)  # (T-1,)
    k = min(SMOOTH_FRAMES, len(step))
    step = _moving_average(step, k)
    walked = np.concatenate([[0.0], np.cumsum(step)])  # (T,)
    if walked[-1] < STILL_M * per_metre:
        return ramp
    # frame f of the new motion sits at the same share of the duration in the reference
    at = ramp * (len(ref) - 1)
    return np.interp(at, np.arange(len(ref)), walked / walked[-1])


def timed_path(path_xz: np.ndarray, reference_xz: np.ndarray, frames: int, per_metre: float = 1.0) -> np.ndarray:
    """(frames, 2) points of a drawn path (N, 2) (a polyline from its start) walked as the
    reference motion's pelvis (T, 2) walks its own: at frame f, the point `progress` of the way
    along the path by arc length."""
    pts = np.asarray(path_xz, np.float64)
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=-1))])
    s = progress(reference_xz, frames, per_metre) * along[-1]
    return np.stack([np.interp(s, along, pts[:, 0]), np.interp(s, along, pts[:, 1])], -1)


def path_on_reference(shape_xz: np.ndarray, reference_xz: np.ndarray, per_metre: float = 1.0,
                      smooth_frames: int = 0) -> np.ndarray:
    """(n, 2) the shape of a pelvis path (n, 2) walked as a reference pelvis (n, 2) walks: the shape,
    optionally smoothed over `smooth_frames` (a gait cycle: the sway a drawn path has not), scaled to
    the reference's own length, started at its start and timed by its progress (`timed_path`). So a
    clip's path becomes one the reference motion's legs can walk at their own pace -- the hint a
    ControlNet trained against its base's own output needs (ControlNetTraining recon_target
    "base"). A shape that does not move gives the reference itself."""
    shape = np.asarray(shape_xz, np.float64)
    ref = np.asarray(reference_xz, np.float64)
    n = len(ref)
    if smooth_frames > 1 and len(shape) > 1:
        shape = _moving_average(shape, min(smooth_frames, len(shape)))
    shape_len = float(np.linalg.norm(np.diff(shape, axis=0), axis=-1).sum()) if len(shape) > 1 else 0.0
    ref_len = float(np.linalg.norm(np.diff(ref, axis=0), axis=-1).sum()) if n > 1 else 0.0
    if shape_len < 1e-6 * per_metre:
        return ref.copy()
    scaled = (shape - shape[0]) * (ref_len / shape_len) + ref[0]
    return timed_path(scaled, ref, n, per_metre)


__all__ = ["path_on_reference", "progress", "timed_path"]
