"""The batched torch extraction (stablemo.motion.extract_torch) against the numpy reference, and the
foot-skate hook's path staying in torch."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from test_motion import random_motion

from stablemo.errors import StableMoError
from stablemo.motion import HUMANML3D, KIT, canonicalize_joints, features_to_joints
from stablemo.motion.extract_torch import (
    canonicalize_joints_batched,
    joints_to_features_batched,
)
from stablemo.motion.features import joints_to_features_f64
from stablemo.motion.quaternion import qrot_np

SAMPLE = Path(__file__).resolve().parents[2] / "shared/data/humanml3d-sample"
TOL = 1e-9  # float64; KIT is in millimetres, its values ~1e3 (measured errors ~1e-12 there)
# A real clip turned by 180 degrees faces away from +z: the root rotation is the quaternion between
# nearly opposite vectors, whose tiny cross product carries the rounding of either implementation
# (7.3e-8 measured on this AMD EPYC; the earlier Intel machines passed 1e-9): 1e5 below the features' scale.
TOL_OPPOSITE = 1e-6


def _real_clip() -> np.ndarray:
    """HumanML3D clip 012314 as joints (T, 22, 3): the dataset's joints, else the ones recovered
    from the official extraction's features; skip when the sample folder is absent."""
    if (SAMPLE / "new_joints/012314.npy").is_file():
        return np.load(SAMPLE / "new_joints/012314.npy").astype(np.float64)
    if (SAMPLE / "features_from_new_joints.npy").is_file():
        return features_to_joints(np.load(SAMPLE / "features_from_new_joints.npy").astype(np.float64))
    pytest.skip(f"{SAMPLE} absent")


def _yaw(joints: np.ndarray, degrees: float) -> np.ndarray:
    """Rotate joints (..., J, 3) about the up axis (y)."""
    half = np.deg2rad(degrees) / 2
    q = np.array([np.cos(half), 0.0, np.sin(half), 0.0])
    return qrot_np(np.broadcast_to(q, joints.shape[:-1] + (4,)), joints)


def _pad(motions: list[np.ndarray], fill: float = np.nan) -> tuple[torch.Tensor, list[int]]:
    """(T_i, J, 3) motions -> (B, T, J, 3) with `fill` past each length (NaN: padding must not be read)."""
    t = max(len(m) for m in motions)
    out = np.full((len(motions), t) + motions[0].shape[1:], fill)
    for i, m in enumerate(motions):
        out[i, : len(m)] = m
    return torch.from_numpy(out), [len(m) for m in motions]


def _check_batch(motions: list[np.ndarray], skel, fill: float = np.nan, tol: float = TOL) -> None:
    """Batched torch == numpy per sample (features and canonical joints, refit on and off); rows
    and frames past a sample's end are zero."""
    batch, lengths = _pad(motions, fill)
    for refit in (True, False):
        feats = joints_to_features_batched(batch, lengths, skel, refit=refit)   # (B, T-1, D)
        canon = canonicalize_joints_batched(batch, lengths, skel, refit=refit)  # (B, T, J, 3)
        assert feats.dtype == canon.dtype == torch.float64
        for i, (m, n) in enumerate(zip(motions, lengths)):
            ref = joints_to_features_f64(m, skel, refit=refit)                   # (n-1, D)
            assert np.abs(feats[i, : n - 1].numpy() - ref).max() <= tol, (i, refit)
            assert np.abs(canon[i, :n].numpy() - canonicalize_joints(m, skel, refit=refit)).max() <= tol
            assert (feats[i, n - 1 :] == 0).all() and (canon[i, n:] == 0).all()


def test_real_clip_at_four_headings_and_lengths():
    clip = _real_clip()  # (T, 22, 3)
    # each heading with another length: padding, the floor and the facing smoothing per sample
    motions = [_yaw(clip, deg)[: len(clip) - 23 * k] + np.array([0.3 * k, 0.0, -0.2 * k])
               for k, deg in enumerate((0, 90, 180, 270))]
    _check_batch(motions, HUMANML3D, tol=TOL_OPPOSITE)


def test_synthetic_motions_batched_with_padding():
    from stablemo.data.synth import generate_motion
    from stablemo.data.synth.writer import motion_rng

    motions = [generate_motion(motion_rng(0, i)).joints.astype(np.float64) for i in range(4)]
    assert len({len(m) for m in motions}) > 1
    _check_batch(motions, HUMANML3D)
    # padding content never matters: NaN, zeros, or another motion's frames give the same result
    batch, lengths = _pad(motions, np.nan)
    zeros, _ = _pad(motions, 0.0)
    a = joints_to_features_batched(batch, lengths)
    assert torch.equal(a, joints_to_features_batched(zeros, lengths))
    for heading in (90, 180, 270):
        _check_batch([_yaw(m, heading) for m in motions[:2]], HUMANML3D, fill=0.0)


def test_random_motions_both_skeletons():
    rng = np.random.default_rng(7)
    for skel, fps in ((HUMANML3D, 20.0), (KIT, 12.5)):
        motions = [random_motion(rng, n, skel, fps).astype(np.float64) for n in (60, 2, 97, 41)]
        _check_batch(motions, skel)
        _check_batch([_yaw(m, 180) for m in motions], skel, fill=1e6)


def test_consistent_features_and_standard_joints_equal_per_sample_numpy():
    """The foot-skate path's helpers (batched, torch) against the per-sample numpy algorithm they
    replace: one frame extrapolated at constant velocity, then each sample extracted alone."""
    from stablemo.skating.cleanup import joints_to_consistent_features, standard_joints

    rng = np.random.default_rng(3)
    motions = [random_motion(rng, n) for n in (50, 1, 2, 33)]  # float32, as the cleanup returns them
    batch = np.zeros((4, 50, 22, 3), np.float32)
    for i, m in enumerate(motions):
        batch[i, : len(m)] = m
    lengths = [len(m) for m in motions]
    feats = joints_to_consistent_features(torch.from_numpy(batch), lengths, refit=False)   # (4, 50, 263)
    std = standard_joints(torch.from_numpy(batch), torch.tensor(lengths))                    # (4, 50, 22, 3)
    assert torch.is_tensor(feats) and feats.dtype == torch.float32 and std.dtype == torch.float32
    np.testing.assert_array_equal(joints_to_consistent_features(batch, lengths), feats.numpy())  # numpy in, out
    for i, n in enumerate(lengths):
        j = motions[i].astype(np.float64)
        ext = np.concatenate([j, j[-1:] + (j[-1:] - j[-2:-1] if n > 1 else 0.0)], 0)  # (n+1, 22, 3)
        ref = joints_to_features_f64(ext, HUMANML3D, refit=False)
        np.testing.assert_allclose(feats[i, :n].numpy(), ref, rtol=1e-6, atol=1e-6)  # float32 out
        np.testing.assert_allclose(std[i, :n].numpy(), canonicalize_joints(ext, HUMANML3D)[:n], rtol=1e-6, atol=1e-6)
        assert (feats[i, n:] == 0).all() and (std[i, n:] == 0).all()


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cuda_equals_cpu():
    rng = np.random.default_rng(1)
    batch, lengths = _pad([random_motion(rng, n).astype(np.float64) for n in (80, 45)])
    cpu = joints_to_features_batched(batch, lengths)
    gpu = joints_to_features_batched(batch.cuda(), torch.tensor(lengths).cuda())
    assert gpu.device.type == "cuda" and (gpu.cpu() - cpu).abs().max() <= TOL


def test_errors_are_named():
    rng = np.random.default_rng(2)
    batch, lengths = _pad([random_motion(rng, 30).astype(np.float64)])
    with pytest.raises(StableMoError, match="lengths"):
        joints_to_features_batched(batch, [31])
    with pytest.raises(StableMoError, match="lengths"):
        joints_to_features_batched(batch, [1])
    with pytest.raises(StableMoError, match="shape"):
        joints_to_features_batched(batch[..., :2], lengths)
    bad = batch.clone()
    bad[0, 3, 5] = float("nan")
    with pytest.raises(StableMoError, match="NaN"):
        joints_to_features_batched(bad, lengths)
    flat = batch.clone()
    flat[0, 0, :, 0::2] = 0.0  # frame 0 squashed onto the up axis: hips and shoulders give no facing
    with pytest.raises(StableMoError, match="facing"):
        canonicalize_joints_batched(flat, lengths)


def test_footskate_hook_path_uses_no_numpy(monkeypatch):
    """FootskateHook on a StepState: no numpy conversion and no numpy extraction on its path, and
    the batched result equals cleaning each sample alone."""
    import stablemo.motion.features as numpy_features
    from stablemo.data.synth import generate_motion
    from stablemo.data.synth.writer import motion_rng
    from stablemo.diffusion.hooks import StepState
    from stablemo.skating.cleanup import joints_to_consistent_features
    from stablemo.skating.hook import FootskateHook

    motions = [generate_motion(motion_rng(1, i)).joints[:n] for i, n in enumerate((48, 30))]
    batch, lengths = _pad(motions, 0.0)
    feats = joints_to_consistent_features(batch.float(), lengths, refit=True)  # (2, 48, 263)
    mean, std = feats[0].mean(0), feats[0].std(0) + 0.1

    class Pipe:  # the two things the hook needs from a pipeline
        skeleton, fps = "humanml3d", 20.0
        normalize = staticmethod(lambda f: (f - mean) / std)
        denormalize = staticmethod(lambda x: x * std + mean)

    mask = torch.arange(48)[None, :] < torch.tensor(lengths)[:, None]
    x0 = torch.where(mask[..., None], Pipe.normalize(feats), torch.zeros(()))
    hook = FootskateHook(Pipe, vgrf=None, iters=20, steps=[-1])

    def forbidden(*args, **kwargs):
        raise AssertionError("numpy on the hook's path")

    with monkeypatch.context() as m:
        m.setattr(torch.Tensor, "numpy", forbidden)
        m.setattr(torch, "from_numpy", forbidden)
        for name in ("joints_to_features_f64", "canonicalize_joints", "uniform_skeleton", "facing_rotations"):
            m.setattr(numpy_features, name, forbidden)
        out = hook(StepState(9, 10, 0, x0.clone(), mask, lengths))
    assert out.shape == x0.shape and (out[1, 30:] == 0).all() and torch.isfinite(out).all()
    assert hook.calls[0]["anchored_ranges"] > 0
    for i, n in enumerate(lengths):  # one sample alone gives the same cleaned motion
        alone = hook(StepState(9, 10, 0, x0[i : i + 1, :n].clone(), mask[i : i + 1, :n], [n]))
        assert (alone[0] - out[i, :n]).abs().max() < 1e-4
