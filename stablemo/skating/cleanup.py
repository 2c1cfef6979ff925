"""StableMo side of foot-skate cleanup: consistent features from cleaned joints, the vGRF model for a skeleton (the command is stablemo.cli.footskate).

`footskate` works on joint positions and never imports stablemo; this module converts between
features and joints (stablemo.motion), so that a cleaned motion's features are *all* re-derived
from the corrected positions (root, rotations, velocities, contact bits), not patched.

The correction inside denoising (StableMoFusion*) is a sample hook: stablemo.skating.hook.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from stablemo.errors import StableMoError
from stablemo.motion import features_to_joints, get_skeleton
from stablemo.motion.extract_torch import (
    canonicalize_joints_batched,
    joints_to_features_batched,
    valid_lengths,
)


def joints_to_consistent_features(joints, lengths, skeleton="humanml3d", refit: bool = False):
    """joints (B, T, J, 3) -> float32 features (B, T, D), zero on padding; each sample keeps its length.
    A tensor gives a tensor on its device (the sampling hook's path, no host round trip); a numpy
    array gives a numpy array.

    refit=False (the default here) keeps the motion's own bone lengths and floor, so recovering
    joints from the features gives the corrected positions back exactly (up to the rigid placement
    of frame 0). Refitting the standard skeleton and floor, as the dataset extraction does for raw
    mocap, would move the anchored feet of a generated motion whose bone lengths vary per frame.

    The extraction turns T positions into T-1 feature rows, so one frame is extrapolated at a
    constant velocity first. The batched extraction places each sample (floor, facing smoothing)
    from its own valid frames only, exactly as extracting the samples one at a time would.
    """
    x, as_numpy = _as_tensor(joints)
    skel = get_skeleton(skeleton)
    ext, n = _with_next_frame(x.to(torch.float64), _lengths(lengths, x))  # (B, T+1, J, 3), (B,)
    out = joints_to_features_batched(ext, n, skel, refit=refit).float()  # (B, T, D)
    return out.numpy() if as_numpy else out


def _as_tensor(a) -> tuple[torch.Tensor, bool]:
    return (a, False) if torch.is_tensor(a) else (torch.from_numpy(np.array(a)), True)  # a copy: writable


def _lengths(lengths, x: torch.Tensor) -> torch.Tensor:
    """lengths (B,) as a long tensor on x's device, each in [1, T] (one frame is extrapolated)."""
    return valid_lengths(lengths, x.shape[0], x.shape[1], x.device, min_frames=1)


def _with_next_frame(x: torch.Tensor, n: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """x (B, T, J, 3), lengths n (B,) -> (B, T+1, J, 3), n + 1: each sample gets one frame more at
    constant velocity (the extraction eats one), at frame n[b]; a one-frame sample repeats its frame.
    Frames past it repeat it (padding that the batched extraction ignores)."""
    b, t = x.shape[:2]
    frames = torch.arange(t + 1, device=x.device)[None, :]  # (1, T+1)
    idx = torch.minimum(frames, n[:, None] - 1)  # (B, T+1): valid frames, then the last one repeated
    x = torch.gather(x, 1, idx[..., None, None].expand(b, t + 1, *x.shape[2:]))
    pick = lambda i: torch.gather(x, 1, i.view(b, 1, 1, 1).expand(b, 1, *x.shape[2:]))  # (B, 1, J, 3)
    last, prev = pick(n - 1), pick((n - 2).clamp(min=0))
    return torch.where((frames >= n[:, None])[..., None, None], last + (last - prev), x), n + 1


def standard_joints(joints, lengths, skeleton="humanml3d"):
    """joints (B, T, J, 3) -> the same motions on the standard skeleton and floor, placed as the
    extraction places them (exactly what recovering joints from refitted features gives), float32,
    zero on padding. Tensor in, tensor out on its device; numpy in, numpy out."""
    x, as_numpy = _as_tensor(joints)
    n = _lengths(lengths, x)
    ext, n1 = _with_next_frame(x.to(torch.float64), n)  # the floor also sees the extrapolated frame
    out = canonicalize_joints_batched(ext, n1, skeleton)[:, : x.shape[1]]  # (B, T, J, 3)
    keep = torch.arange(x.shape[1], device=x.device)[None, :] < n[:, None]
    out = torch.where(keep[..., None, None], out, torch.zeros((), dtype=out.dtype, device=out.device)).float()
    return out.numpy() if as_numpy else out


class StableMoCodec:
    """footskate.command.FeatureCodec backed by stablemo.motion."""

    def __init__(self, skeleton: str = "humanml3d"):
        self.skeleton = get_skeleton(skeleton)
        self.feature_dim = self.skeleton.feature_dim

    def to_joints(self, features: np.ndarray) -> np.ndarray:
        return features_to_joints(np.asarray(features, dtype=np.float32), self.skeleton)

    def to_features(self, joints: np.ndarray, lengths) -> np.ndarray:
        return joints_to_consistent_features(joints, lengths, self.skeleton)


def topology(skeleton):
    from footskate.skeletons import TOPOLOGIES

    name = get_skeleton(skeleton).name
    if name not in TOPOLOGIES:
        raise StableMoError(f"skeleton: foot-skate cleanup does not know skeleton {name!r}")
    return TOPOLOGIES[name]


def check_footskate_options(footskate: bool, weights, flags: bool = False) -> None:
    """vGRF weights only mean something with the foot-skate correction on: given without it, they
    would be silently ignored. flags: name the CLI options, else the keyword arguments."""
    if weights is not None and not footskate:
        if flags:
            raise StableMoError("--footskate-weights: only used with --footskate; add --footskate "
                                "(or drop --footskate-weights)")
        raise StableMoError("footskate_weights: only used with footskate=True; pass footskate=True "
                            "(or drop footskate_weights)")


def load_vgrf_model(weights: str | Path | None, skeleton="humanml3d"):
    """vGRF model for a skeleton: `weights` (ours or a user's UnderPressure .tar), else the shipped V22, else None."""
    from footskate.errors import FootskateError
    from footskate.vgrf import resolve_vgrf

    try:
        return resolve_vgrf(None if weights is None else str(weights), topology(skeleton))
    except FootskateError as err:
        raise StableMoError(str(err)) from None


def clean_features(features, lengths, skeleton="humanml3d", vgrf=None, config=None, standardize: bool = True):
    """De-normalised features (B, T, D) -> (cleaned features (B, T, D), cleaned joints (B, T, J, 3), info).

    A tensor stays on its device end to end (features -> joints -> standard skeleton -> cleanup ->
    features, all batched torch; `vgrf` must live there too) and tensors come back; numpy in gives
    numpy out. standardize: first put each motion on the standard skeleton and floor (the
    dataset's own extraction), then clean, then derive features without refitting, so the features
    reproduce the cleaned joints exactly. On the demo model's generations this order beats cleaning
    the raw joints and refitting afterwards (which moves anchored feet again):
    scripts/footskate/report.py.
    """
    from footskate.cleanup import CleanupConfig, anchor_drift, cleanup
    from footskate.errors import FootskateError

    topo = topology(skeleton)
    skel = get_skeleton(skeleton)
    feats, as_numpy = _as_tensor(features)
    feats = feats.float()                                                  # (B, T, D)
    n = _lengths(lengths, feats)                                           # (B,) on the device
    joints = features_to_joints(feats, skel).detach()                      # (B, T, J, 3)
    if standardize:
        joints = standard_joints(joints, n, skel)
    cfg = config or CleanupConfig(fps=skel.fps, up_axis=topo.up_axis)
    try:
        res = cleanup(joints * topo.unit, topo.parents, topo.feet, lengths=n, vgrf=vgrf, config=cfg)
    except FootskateError as err:
        raise StableMoError(f"footskate: {err}") from None
    drift = anchor_drift(res.joints, res, topo.feet, topo.up_axis)  # (B, T, 4) metres, NaN off-range
    drift = drift[~drift.isnan()]
    res.info["anchor_drift"] = {"mean": float(drift.mean()) if drift.numel() else 0.0,
                                "p95": float(drift.quantile(0.95)) if drift.numel() else 0.0}
    mask = torch.arange(joints.shape[1], device=joints.device)[None, :] < n[:, None]  # (B, T)
    out_joints = torch.where(mask[..., None, None], res.joints / topo.unit,
                             torch.zeros((), device=joints.device)).float()  # (B, T, J, 3)
    cleaned = joints_to_consistent_features(out_joints, n, skel)          # (B, T, D)
    if as_numpy:
        return cleaned.numpy(), out_joints.numpy(), res.info
    return cleaned, out_joints, res.info


