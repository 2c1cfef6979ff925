"""The finishing step's compiled kernel (stablemo.fast.motion, motion_kernels.cpp): the feature
columns of a joint-major motion, the same numbers as the PyTorch twin (extract_torch.body_columns)."""

import numpy as np
import pytest
import torch

from stablemo.fast import kernels as fused
from stablemo.fast import motion as fast_motion
from stablemo.inference.finish import Finish
from stablemo.motion import extract_torch
from stablemo.motion.features import features_to_joints, joints_to_features
from stablemo.motion.skeleton import HUMANML3D, KIT


@pytest.fixture
def kernels(monkeypatch):
    built = fused.motion_kernels()
    if built is None:
        pytest.skip("the fused CPU kernels cannot be built here (no compiler or ninja)")
    monkeypatch.setattr(fast_motion, "MIN_FUSED_FRAMES", 0)  # the small batches below use it too
    return built


def motion(skel, batch: int, frames: int, dtype) -> tuple[torch.Tensor, torch.Tensor]:
    """Joint-major joints (J, 3, B, T) of rubbery random poses around the rest pose, and yaw-only root
    rotations (B, T, 4), with the cases that take the twin's side branches: a zero-length bone and a
    bone pointing against its rest direction (qbetween's half turn)."""
    g = torch.Generator().manual_seed(0)
    rest = torch.tensor([list(o) for o in skel.raw_offsets], dtype=dtype)  # (J, 3) unit rest directions
    steps = rest[:, :, None, None] * 0.2 + 0.05 * torch.randn(skel.num_joints, 3, batch, frames, generator=g, dtype=dtype)
    x = torch.zeros_like(steps)
    for chain in skel.kinematic_chains:
        for p, c in zip(chain[:-1], chain[1:]):
            x[c] = x[p] + steps[c]
    x = x + torch.randn(3, batch, frames, generator=g, dtype=dtype)[None]
    c, p = skel.kinematic_chains[0][2], skel.kinematic_chains[0][1]
    x[c, :, 0, 3] = x[p, :, 0, 3]  # a zero bone
    x[c, :, 0, 5] = x[p, :, 0, 5] - 0.2 * rest[c]  # a bone turned fully round
    angle = torch.cumsum(0.1 * torch.randn(batch, frames, generator=g, dtype=dtype), 1)
    zeros = torch.zeros_like(angle)
    r = torch.stack([torch.cos(angle), zeros, torch.sin(angle), zeros], -1)
    return x.contiguous(), r


@pytest.mark.parametrize("skel", [HUMANML3D, KIT], ids=["humanml3d", "kit"])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_kernel_gives_the_pytorch_twins_numbers(kernels, skel, dtype):
    x, r = motion(skel, 3, 17, dtype)
    lead = torch.randn(3, 16, 3, dtype=dtype)
    n = torch.tensor([16, 9, 2])
    root = torch.randn(3, 16, 3, dtype=dtype)
    feats, joints = fast_motion.finish_rows(x, r, lead, n, root, skel)
    twin = extract_torch.body_columns(x, r, skel)
    assert feats.shape == (3, 16, skel.feature_dim) and joints.shape == (3, 16, skel.num_joints, 3)
    assert feats.dtype == joints.dtype == dtype and torch.isfinite(twin).all()
    for i, m in enumerate(n.tolist()):
        assert torch.equal(feats[i, :m, :3], lead[i, :m])
        assert (feats[i, :m, 3:] - twin[i, :m]).abs().max() <= (1e-6 if dtype == torch.float32 else 1e-14)
        ric = slice(4, 4 + 3 * (skel.num_joints - 1))
        assert torch.equal(feats[i, :m, ric], twin[i, :m, ric.start - 3:ric.stop - 3])
        assert (feats[i, m:] == 0).all() and (joints[i, m:] == 0).all()
    # the joints are the features' recovery to the bit, given the root rotation and path the leading
    # columns recover to (as the finishing step gives them)
    from stablemo.motion.features import recover_root

    rows = torch.zeros(3, 16, skel.feature_dim, dtype=dtype)
    rows[..., :3] = 0.1 * lead
    q, path = recover_root(rows)
    r = torch.cat([q, q[:, -1:]], 1)
    feats, joints = fast_motion.finish_rows(x, r, rows[..., :3], torch.tensor([16, 16, 16]), path, skel)
    assert torch.equal(features_to_joints(feats, skel), joints)


def test_finish_with_the_kernel_is_finish_without(kernels, monkeypatch):
    from stablemo.data.synth import actions
    from stablemo.data.synth.compose import build

    rng = np.random.default_rng(0)
    clips = [build([(a, actions.sample_params(a, rng))]).joints for a in ("walk", "jump")]
    clips = [c[:min(len(c) for c in clips)] for c in clips]
    clips = [c + 0.03 * np.sin(np.arange(len(c))[:, None, None] * rng.uniform(0.1, 0.3, (1, 22, 3))) for c in clips]
    feats = torch.from_numpy(np.stack([joints_to_features(c, "humanml3d", refit=False) for c in clips])).float()
    lengths = [feats.shape[1], feats.shape[1] - 7]
    feats[1, lengths[1]:] = 0
    finish = Finish.from_config({}, "humanml3d", 20.0)
    with_kernel = finish(feats, lengths)
    monkeypatch.setattr(fast_motion, "motion_kernels", lambda: None)
    without = finish(feats, lengths)
    for a, b in zip(with_kernel, without):
        assert (a - b).abs().max() <= 1e-5
    assert torch.equal(features_to_joints(with_kernel[0][0]), with_kernel[1][0])  # still the features' recovery


def test_small_batches_never_build_the_kernel(monkeypatch):
    def refuse():
        raise AssertionError("built the kernel for a single prompt")

    monkeypatch.setattr(fast_motion, "motion_kernels", refuse)
    x, r = motion(HUMANML3D, 1, 196, torch.float32)  # one prompt of 196 frames (the demo's)
    assert x.shape[2] * x.shape[3] < fast_motion.MIN_FUSED_FRAMES
    lead, root = torch.zeros(1, 195, 3), torch.zeros(1, 195, 3)
    assert fast_motion.finish_rows(x, r, lead, torch.tensor([195]), root, HUMANML3D) is None  # PyTorch's turn
    # the whole step on one prompt: neither compiled pass is asked for
    feats = torch.from_numpy(joints_to_features(x[..., 0, :].permute(2, 0, 1).double().numpy(), "humanml3d",
                                                refit=False)).float()[None]
    out_f, out_j = Finish.from_config({}, "humanml3d", 20.0)(feats, [feats.shape[1]])
    assert torch.isfinite(out_f).all() and torch.isfinite(out_j).all()


@pytest.mark.parametrize("skel", [HUMANML3D, KIT], ids=["humanml3d", "kit"])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("held", [False, True])
def test_compiled_placement_is_the_rigid_rebuilds(kernels, skel, dtype, held):
    from stablemo.motion.rigid import rigid_joint_major

    x, _ = motion(skel, 3, 17, dtype)
    g = torch.Generator().manual_seed(2)
    hold = torch.rand(3, 17, skel.num_joints, generator=g, dtype=dtype) if held else None
    ends = x + 0.05 * torch.randn(x.shape, generator=g, dtype=dtype) if held else None
    lengths = [17, 12, 5]
    twin = rigid_joint_major(x, skel, None, lengths, hold, ends)
    calls = []

    def place(*args):
        calls.append(1)
        return fast_motion.place_body(*args)

    fast = rigid_joint_major(x, skel, None, lengths, hold, ends, place=place)
    assert calls and fast.shape == twin.shape and fast.dtype == dtype
    scale = twin.abs().max()  # KIT's joints are in millimetres
    # float32: a few ulps of the scale (2.2e-6 on an AMD EPYC box, whose vector units round otherwise)
    assert (fast - twin).abs().max() <= (4e-6 if dtype == torch.float32 else 1e-14) * scale
    assert (fast - x).abs().max() > 1e-3 * scale  # (the rebuild did move the rubbery joints)
