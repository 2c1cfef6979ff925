"""StableMo side of foot-skate cleanup: consistent features from cleaned joints, the command.

`footskate` works on joint positions and never imports stablemo; this module converts between
features and joints (stablemo.motion), so that a cleaned motion's features are *all* re-derived
from the corrected positions (root, rotations, velocities, contact bits), not patched.

The correction inside denoising (StableMoFusion*) is a sample hook: stablemo.hooks.footskate.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from stablemo.errors import StableMoError
from stablemo.motion import canonicalize_joints, features_to_joints, get_skeleton, joints_to_features

def joints_to_consistent_features(joints: np.ndarray, lengths: Sequence[int], skeleton="humanml3d",
                                  refit: bool = False) -> np.ndarray:
    """joints (B, T, J, 3) -> features (B, T, D), zero on padding; each sample keeps its length.

    refit=False (the default here) keeps the motion's own bone lengths and floor, so recovering
    joints from the features gives the corrected positions back exactly (up to the rigid placement
    of frame 0). Refitting the standard skeleton and floor, as the dataset extraction does for raw
    mocap, would move the anchored feet of a generated motion whose bone lengths vary per frame.

    The extraction turns T positions into T-1 feature rows, so one frame is extrapolated at a
    constant velocity first. Samples are converted one at a time because the extraction's
    canonicalisation (floor, facing smoothing) must only see the sample's own valid frames.
    """
    skel = get_skeleton(skeleton)
    joints = np.asarray(joints, dtype=np.float64)
    out = np.zeros(joints.shape[:2] + (skel.feature_dim,), dtype=np.float32)
    for b, n in enumerate(int(n) for n in lengths):  # numpy extraction, outside the optimisation loop
        out[b, :n] = joints_to_features(_with_next_frame(joints[b, :n]), skel, refit=refit)
    return out


def _with_next_frame(j: np.ndarray) -> np.ndarray:
    """(n, J, 3) -> (n + 1, J, 3): one frame more at constant velocity (the extraction eats one)."""
    return np.concatenate([j, j[-1:] + (j[-1:] - j[-2:-1] if len(j) > 1 else 0.0)], 0)


def standard_joints(joints: np.ndarray, lengths: Sequence[int], skeleton="humanml3d") -> np.ndarray:
    """joints (B, T, J, 3) -> the same motions on the standard skeleton and floor, placed as the
    extraction places them (exactly what recovering joints from refitted features gives), zero on
    padding."""
    skel = get_skeleton(skeleton)
    joints = np.asarray(joints, dtype=np.float64)
    out = np.zeros(joints.shape, dtype=np.float32)
    for b, n in enumerate(int(n) for n in lengths):  # per sample: the floor is each motion's own
        out[b, :n] = canonicalize_joints(_with_next_frame(joints[b, :n]), skel)[:n]
    return out


class StableMoCodec:
    """footskate.command.FeatureCodec backed by stablemo.motion."""

    def __init__(self, skeleton: str = "humanml3d"):
        self.skeleton = get_skeleton(skeleton)
        self.feature_dim = self.skeleton.feature_dim

    def to_joints(self, features: np.ndarray) -> np.ndarray:
        return features_to_joints(np.asarray(features, dtype=np.float32), self.skeleton)

    def to_features(self, joints: np.ndarray, lengths) -> np.ndarray:
        return joints_to_consistent_features(joints, lengths, self.skeleton)


def _topology(skeleton):
    from footskate.skeletons import TOPOLOGIES

    name = get_skeleton(skeleton).name
    if name not in TOPOLOGIES:
        raise StableMoError(f"skeleton: foot-skate cleanup does not know skeleton {name!r}")
    return TOPOLOGIES[name]


def load_vgrf_model(weights: str | Path | None, skeleton="humanml3d"):
    """vGRF model for a skeleton: `weights` (ours or a user's UnderPressure .tar), else the shipped V22, else None."""
    from footskate.vgrf import resolve_vgrf
    from footskate.errors import FootskateError

    try:
        return resolve_vgrf(None if weights is None else str(weights), _topology(skeleton))
    except FootskateError as err:
        raise StableMoError(str(err)) from None


def clean_features(features: torch.Tensor | np.ndarray, lengths: Sequence[int], skeleton="humanml3d",
                   vgrf=None, config=None, standardize: bool = True) -> tuple[np.ndarray, np.ndarray, dict]:
    """De-normalised features (B, T, D) -> (cleaned features (B, T, D), cleaned joints (B, T, J, 3), info).

    standardize: first put each motion on the standard skeleton and floor (the dataset's own
    extraction), then clean, then derive features without refitting, so the features reproduce the
    cleaned joints exactly. On the demo model's generations this order beats cleaning the raw
    joints and refitting afterwards (which moves anchored feet again): scripts/footskate_report.py.
    """
    from footskate.cleanup import CleanupConfig, anchor_drift, cleanup
    from footskate.errors import FootskateError

    topo = _topology(skeleton)
    skel = get_skeleton(skeleton)
    feats = torch.as_tensor(np.asarray(features) if not torch.is_tensor(features) else features).float().cpu()
    lengths_t = torch.as_tensor(list(lengths), dtype=torch.long)
    joints = features_to_joints(feats, skel).detach()                      # (B, T, J, 3)
    if standardize:
        joints = torch.from_numpy(standard_joints(joints.numpy(), lengths, skel))
    cfg = config or CleanupConfig(fps=skel.fps, up_axis=topo.up_axis)
    try:
        res = cleanup(joints * topo.unit, topo.parents, topo.feet, lengths=lengths_t, vgrf=vgrf, config=cfg)
    except FootskateError as err:
        raise StableMoError(f"footskate: {err}") from None
    drift = anchor_drift(res.joints, res, topo.feet, topo.up_axis)  # (B, T, 4) metres, NaN off-range
    drift = drift[~drift.isnan()]
    res.info["anchor_drift"] = {"mean": float(drift.mean()) if drift.numel() else 0.0,
                                "p95": float(drift.quantile(0.95)) if drift.numel() else 0.0}
    out_joints = (res.joints / topo.unit).numpy()
    mask = (torch.arange(joints.shape[1])[None, :] < lengths_t[:, None]).numpy()
    out_joints = np.where(mask[..., None, None], out_joints, 0.0).astype(np.float32)
    return joints_to_consistent_features(out_joints, lengths, skeleton), out_joints, res.info


def main(argv: list[str]) -> int:
    """`stablemo footskate IN.npy --out OUT.npy [--weights PATH] [--iters N]` (joints or features)."""
    from footskate.command import main as footskate_main
    from footskate.errors import FootskateError

    try:
        return footskate_main(argv, codec_factory=StableMoCodec)
    except FootskateError as err:
        raise StableMoError(str(err)) from None
