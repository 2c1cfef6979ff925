"""Seam measures: are the joins of a long motion visible?

Acceleration = the second difference of a joint's global position times fps^2 (m/s^2), per frame
t (from frames t-1, t, t+1). For the root (pelvis) and the feet (both ankles and toes, the largest
of the four), a join at frame b is judged by the largest acceleration over frames b-2..b+1 (every
second difference that mixes rows of both windows). It is compared with
- the data's 99th percentile (all frames of the clips of a dataset folder), and
- the motion's own inside 99th percentile (frames at least `margin` from any join).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from stablemo.motion.skeleton import get_skeleton

SEAM_HALF = 2  # frames b-2..b+1 hold every second difference that mixes the two windows
INSIDE_MARGIN = 5


def _feet(skeleton: str) -> list[int]:
    skel = get_skeleton(skeleton)
    names = [n.lower() for n in skel.joint_names]
    feet = [i for i, n in enumerate(names) if "ankle" in n or "foot" in n or "toe" in n]
    return feet or list(skel.foot_joints)


def accelerations(joints: np.ndarray, fps: float, skeleton: str = "humanml3d") -> dict[str, np.ndarray]:
    """joints (T, J, 3) -> {'root': (T,), 'foot': (T,)} acceleration magnitudes in m/s^2; frame 0 and
    T-1 (no second difference) are 0."""
    x = np.asarray(joints, np.float64)
    acc = np.zeros(x.shape[:2])
    acc[1:-1] = np.linalg.norm(x[2:] - 2 * x[1:-1] + x[:-2], axis=-1) * fps ** 2  # (T-2, J)
    return {"root": acc[:, 0], "foot": acc[:, _feet(skeleton)].max(-1)}


def seam_report(joints: np.ndarray, joins: Sequence[int | tuple[int, int]], fps: float,
                skeleton: str = "humanml3d", margin: int = INSIDE_MARGIN) -> dict:
    """Per join: root and foot acceleration peaks; the inside 99th percentiles. A join is a frame b,
    or a span (a, b) of rows mixing two windows (a cross-fade): then frames a-2..b+1 are its seam."""
    acc = accelerations(joints, fps, skeleton)
    T = len(joints)
    spans = [(j, j) if isinstance(j, (int, np.integer)) else (int(j[0]), int(j[1])) for j in joins]
    near = np.zeros(T, bool)
    for a, b in spans:
        near[max(0, a - margin):b + margin] = True
    inside = ~near
    inside[[0, T - 1]] = False
    out = {"joins": [], "inside_p99": {k: float(np.percentile(v[inside], 99)) for k, v in acc.items()}}
    for a, b in spans:
        sl = slice(max(1, a - SEAM_HALF), min(T - 1, b + SEAM_HALF))
        out["joins"].append({"frame": int(b), **{k: float(v[sl].max()) for k, v in acc.items()}})
    return out


def data_percentiles(data_dir: str | Path, skeleton: str = "humanml3d", fps: float = 20.0, q: float = 99.0,
                     limit: int | None = None) -> dict[str, float]:
    """The q-th percentile of root and foot acceleration over every frame of a dataset folder's
    clips (new_joint_vecs/*.npy, recovered to joints)."""
    import torch

    from stablemo.motion.features import features_to_joints

    files = sorted(Path(data_dir, "new_joint_vecs").glob("*.npy"))[:limit]
    values: dict[str, list] = {"root": [], "foot": []}
    for f in files:
        feats = np.load(f, allow_pickle=False)
        if len(feats) < 3:
            continue
        joints = features_to_joints(torch.from_numpy(feats.astype(np.float64)), skeleton).numpy()
        for k, v in accelerations(joints, fps, skeleton).items():
            values[k].append(v[1:-1])
    return {k: float(np.percentile(np.concatenate(v), q)) for k, v in values.items()}


__all__ = ["accelerations", "data_percentiles", "seam_report"]
