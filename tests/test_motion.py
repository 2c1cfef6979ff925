"""Motion representation: skeletons, extraction vs the official clip, recovery, round trips, gradients."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from stablemo.errors import StableMoError
from stablemo.motion import (
    HUMANML3D,
    KIT,
    canonicalize_joints,
    feature_slices,
    features_to_joints,
    get_skeleton,
    joints_to_features,
)
from stablemo.motion.quaternion import (
    qbetween_np,
    qmul_np,
    qrot_np,
    quat_to_matrix_np,
    rot6d_to_matrix,
)

SAMPLE = Path(__file__).resolve().parents[2] / "shared/data/humanml3d-sample"
CLIP = "012314"


# --------------------------------------------------------------------------- random plausible motion


def _axis_angle_to_quat(axis_angle: np.ndarray) -> np.ndarray:
    angle = np.linalg.norm(axis_angle, axis=-1, keepdims=True)
    axis = axis_angle / np.maximum(angle, 1e-12)
    return np.concatenate([np.cos(angle / 2), np.sin(angle / 2) * axis], axis=-1)


def _smooth_noise(rng: np.random.Generator, t: np.ndarray, dims: tuple[int, ...], max_freq: float) -> np.ndarray:
    """Sum of a few random sinusoids per channel: smooth signals with values ~[-1, 1]."""
    out = np.zeros((len(t), *dims))
    for _ in range(3):
        freq = rng.uniform(0.2, max_freq, size=dims)
        phase = rng.uniform(0, 2 * np.pi, size=dims)
        out += np.sin(2 * np.pi * freq * t.reshape(-1, *([1] * len(dims))) + phase) / 3
    return out


def random_motion(rng: np.random.Generator, num_frames: int = 120, skeleton=HUMANML3D, fps: float = 20.0) -> np.ndarray:
    """(T, J, 3) joints by FK on the skeleton: smooth random joint rotations (up to ~70°), a random
    heading with fast turns (including full turns), a wandering root path, and jumps; then a random
    global scale, yaw and offset, so extraction has something to undo."""
    skel = skeleton
    t = np.arange(num_frames) / fps
    j = skel.num_joints
    # local joint rotations, axis-angle with magnitude up to ~1.2 rad
    local = _axis_angle_to_quat(1.2 * _smooth_noise(rng, t, (j, 3), 2.0) * rng.uniform(0.3, 1.0))
    # heading: smooth wander plus, half the time, a fast turn of up to 1.5 turns in ~1 s
    heading = 1.5 * _smooth_noise(rng, t, (), 0.5) + rng.uniform(-np.pi, np.pi)
    if rng.random() < 0.7:
        centre, width = rng.uniform(0.2, 0.8) * t[-1], rng.uniform(0.3, 1.0)
        heading = heading + rng.uniform(-3 * np.pi, 3 * np.pi) / (1 + np.exp(-(t - centre) / (width / 6)))
    yaw = _axis_angle_to_quat(heading[:, None] * np.array([0.0, 1.0, 0.0]))
    root_rot = qmul_np(yaw, local[:, 0])
    speed = rng.uniform(0.0, 2.5) * (1 + 0.5 * _smooth_noise(rng, t, (), 0.5))
    direction = np.stack([np.sin(heading), np.zeros_like(heading), np.cos(heading)], -1)
    root = np.cumsum(speed[:, None] * direction / fps, axis=0)
    root[:, 1] = 0.95 + 0.05 * _smooth_noise(rng, t, (), 1.0)
    for _ in range(rng.integers(0, 3)):  # jumps: parabolic flights of 0.3–0.6 s
        start, dur, height = rng.uniform(0, max(t[-1] - 0.6, 0.0)), rng.uniform(0.3, 0.6), rng.uniform(0.2, 0.6)
        phase = (t - start) / dur
        root[:, 1] += np.where((phase > 0) & (phase < 1), 4 * height * phase * (1 - phase), 0.0)

    scale = rng.uniform(0.8, 1.25) * (1000.0 if skel.units == "mm" else 1.0)
    offsets = skel.target_offsets / (1000.0 if skel.units == "mm" else 1.0)
    joints = np.zeros((num_frames, j, 3))
    joints[:, 0] = root
    for chain in skel.kinematic_chains:
        acc = root_rot
        for parent, child in zip(chain[:-1], chain[1:]):
            acc = qmul_np(acc, local[:, child])
            joints[:, child] = joints[:, parent] + qrot_np(acc, np.broadcast_to(offsets[child], (num_frames, 3)))
    joints *= scale
    spin = _axis_angle_to_quat(np.array([0.0, rng.uniform(-np.pi, np.pi), 0.0]))
    joints = qrot_np(np.broadcast_to(spin, joints.shape[:-1] + (4,)), joints) + rng.normal(0, 2, 3) * scale
    return joints.astype(np.float32)


# --------------------------------------------------------------------------- skeletons


@pytest.mark.parametrize("skel, joints, dim", [(HUMANML3D, 22, 263), (KIT, 21, 251)])
def test_skeleton_shapes_and_tree(skel, joints, dim):
    assert skel.num_joints == joints and skel.feature_dim == dim
    assert skel.raw_offsets.shape == (joints, 3) and skel.bone_lengths.shape == (joints,)
    assert skel.parents[0] == -1
    # every non-root joint has a parent placed before it in chain order, and a unit raw direction
    assert np.allclose(np.linalg.norm(skel.raw_offsets[1:], axis=1), 1.0)
    assert np.all(skel.bone_lengths[1:] > 0)
    slices = feature_slices(skel)
    assert slices["contacts"].stop == dim and slices["ric"] == slice(4, 4 + 3 * (joints - 1))
    assert get_skeleton(skel.name) is skel


def test_humanml3d_facts():
    s = HUMANML3D
    assert s.parents == (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19)
    assert s.contact_joints == (7, 10, 8, 11) and s.face_joints == (2, 1, 17, 16) and s.leg_bones == (5, 8)
    assert s.contact_threshold == 0.002 and s.fps == 20
    # the sheet's 4-decimal lengths agree with our more precise ones
    sheet = [.1031, .1099, .1316, .3936, .3902, .1432, .4324, .4256, .0574, .1434, .1494, .2194, .1375,
             .1434, .1030, .1316, .1230, .2568, .2631, .2660, .2699]
    assert np.allclose(s.bone_lengths[1:], sheet, atol=5e-5)
    assert feature_slices(s) == {
        "root_rot_vel": slice(0, 1), "root_lin_vel": slice(1, 3), "root_y": slice(3, 4), "ric": slice(4, 67),
        "rot6d": slice(67, 193), "local_vel": slice(193, 259), "contacts": slice(259, 263),
    }
    assert KIT.parents[5] == 3 and KIT.parents[11] == 0 and KIT.contact_joints == (19, 20, 14, 15)
    with pytest.raises(StableMoError):
        get_skeleton("smplx")


def test_qbetween_handles_opposite_directions():
    a = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.3, 0.2, -0.9]])
    b = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 2.0], [-0.3, -0.2, 0.9]])
    q = qbetween_np(a, b)
    assert np.all(np.isfinite(q))
    rotated = qrot_np(q, a)
    unit = lambda v: v / np.linalg.norm(v, axis=-1, keepdims=True)  # noqa: E731
    assert np.allclose(unit(rotated), unit(b), atol=1e-9)


def test_rot6d_to_matrix_inverts_quat_to_rot6d():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(50, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    m = quat_to_matrix_np(q)
    d6 = np.concatenate([m[..., :, 0], m[..., :, 1]], -1)
    assert torch.allclose(rot6d_to_matrix(torch.from_numpy(d6)), torch.from_numpy(m), atol=1e-12)


# --------------------------------------------------------------------------- the official clip


def _sample(name: str) -> np.ndarray:
    path = SAMPLE / name
    if not path.exists():
        pytest.skip(f"{path} absent")
    return np.load(path)


def test_extraction_reproduces_official_features():
    joints = _sample(f"new_joints/{CLIP}.npy")
    expected = _sample("features_from_new_joints.npy")
    feats = joints_to_features(joints, HUMANML3D)
    assert feats.shape == expected.shape == (169, 263) and feats.dtype == np.float32
    sl = feature_slices(HUMANML3D)
    err = np.abs(feats - expected)
    for key in ("root_rot_vel", "root_lin_vel", "root_y", "ric", "local_vel"):
        assert err[:, sl[key]].max() < 2e-5, key
    assert err[:, sl["rot6d"]].max() < 1e-3
    np.testing.assert_array_equal(feats[:, sl["contacts"]], expected[:, sl["contacts"]])
    # and, per the sample's README, the dataset's own features agree on the early rows
    dataset = _sample(f"new_joint_vecs/{CLIP}.npy")
    assert np.abs(feats[:90] - dataset[:90]).max() < 1e-4


def test_recovery_reproduces_official_joints():
    feats = _sample(f"new_joint_vecs/{CLIP}.npy")
    joints = _sample(f"new_joints/{CLIP}.npy")
    rec = features_to_joints(torch.from_numpy(feats), HUMANML3D)
    assert rec.shape == (170, 22, 3)
    assert (rec - torch.from_numpy(joints)).abs().max().item() < 1e-5
    rec_np = features_to_joints(feats, "humanml3d")  # numpy in, numpy out
    assert isinstance(rec_np, np.ndarray) and np.abs(rec_np - joints).max() < 1e-5


def test_official_joints_are_already_canonical():
    joints = _sample(f"new_joints/{CLIP}.npy")
    assert np.abs(canonicalize_joints(joints, HUMANML3D) - joints).max() < 1e-5


# --------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("seed", range(8))
def test_round_trip_random_motion(seed):
    rng = np.random.default_rng(seed)
    joints = random_motion(rng, num_frames=int(rng.integers(40, 197)))
    feats = joints_to_features(joints, HUMANML3D)
    rec = features_to_joints(torch.from_numpy(feats), HUMANML3D).numpy()
    target = canonicalize_joints(joints, HUMANML3D)[:-1]
    assert np.abs(rec - target).max() < 1e-4
    # canonical form: floor at 0, start at origin facing +z, target bone lengths
    assert abs(target[..., 1].min()) < 1e-9 and np.allclose(target[0, 0, [0, 2]], 0, atol=1e-9)
    parents = np.array(HUMANML3D.parents[1:])
    lengths = np.linalg.norm(target[:, 1:] - target[:, parents], axis=-1)
    assert np.allclose(lengths, HUMANML3D.bone_lengths[1:], atol=1e-9)


def test_extraction_without_refit_keeps_bone_lengths_and_floor():
    # a generated motion's own skeleton (bones 10 % longer, wobbling per frame) and a raised floor
    rng = np.random.default_rng(5)
    joints = random_motion(rng, num_frames=80)
    parents = np.array(HUMANML3D.parents)
    wobble = 1.1 + 0.05 * np.sin(np.arange(80))[:, None, None]
    bones = (joints[:, 1:] - joints[:, parents[1:]]) * wobble
    odd = joints.copy()
    for j in range(1, 22):
        odd[:, j] = odd[:, parents[j]] + bones[:, j - 1]
    odd[..., 1] += 0.07
    rec = features_to_joints(joints_to_features(odd, HUMANML3D, refit=False).astype(np.float64), HUMANML3D)
    placed = canonicalize_joints(odd, HUMANML3D, refit=False)[:-1]
    assert np.abs(rec - placed).max() < 1e-4
    # the placement is rigid: heights, bone lengths and pairwise distances are the motion's own
    assert np.allclose(placed[..., 1], odd[:-1, :, 1], atol=1e-9)
    own = np.linalg.norm(odd[:-1, 1:] - odd[:-1, parents[1:]], axis=-1)
    assert np.allclose(np.linalg.norm(rec[:, 1:] - rec[:, parents[1:]], axis=-1), own, atol=1e-4)
    # with the default refit the same motion lands on the standard skeleton and floor instead
    std = canonicalize_joints(odd, HUMANML3D)
    assert abs(std[..., 1].min()) < 1e-9
    assert np.allclose(np.linalg.norm(std[:, 1:] - std[:, parents[1:]], axis=-1), HUMANML3D.bone_lengths[1:])


def test_round_trip_survives_full_turns_past_180_degrees():
    # spinning on the spot, 3 full turns in 3 s: facing crosses ±180° relative to frame 0 repeatedly
    rng = np.random.default_rng(11)
    base = random_motion(rng, num_frames=60)
    angle = np.linspace(0, 6 * np.pi, 60)
    quat = np.stack([np.cos(angle / 2), 0 * angle, np.sin(angle / 2), 0 * angle], -1)
    centred = base - base[:, :1] * np.array([1, 0, 1])
    joints = qrot_np(np.broadcast_to(quat[:, None], centred.shape[:-1] + (4,)), centred)
    feats = joints_to_features(joints, HUMANML3D)
    rec = features_to_joints(feats.astype(np.float64), HUMANML3D)
    assert np.abs(rec - canonicalize_joints(joints, HUMANML3D)[:-1]).max() < 1e-4


def test_batched_extraction_matches_single():
    rng = np.random.default_rng(3)
    batch = np.stack([random_motion(rng, num_frames=50) for _ in range(3)])
    feats = joints_to_features(batch, HUMANML3D)
    assert feats.shape == (3, 49, 263)
    for i in range(3):
        np.testing.assert_allclose(feats[i], joints_to_features(batch[i], HUMANML3D), atol=1e-6)
    rec = features_to_joints(torch.from_numpy(feats)[None], HUMANML3D)  # extra leading dim
    assert rec.shape == (1, 3, 49, 22, 3)


def test_round_trip_kit():
    rng = np.random.default_rng(5)
    joints = random_motion(rng, num_frames=80, skeleton=KIT, fps=12.5)
    feats = joints_to_features(joints, KIT)
    assert feats.shape == (79, 251)
    rec = features_to_joints(torch.from_numpy(feats), KIT).numpy()
    # millimetres: 1e-4 m = 0.1 mm
    assert np.abs(rec - canonicalize_joints(joints, KIT)[:-1]).max() < 0.1


def test_contacts_follow_squared_displacement():
    rng = np.random.default_rng(1)
    joints = random_motion(rng, num_frames=60)
    feats = joints_to_features(joints, HUMANML3D)
    contacts = feats[:, feature_slices(HUMANML3D)["contacts"]]
    x = canonicalize_joints(joints, HUMANML3D)
    disp2 = ((x[1:, [7, 10, 8, 11]] - x[:-1, [7, 10, 8, 11]]) ** 2).sum(-1)
    np.testing.assert_array_equal(contacts, (disp2 < 0.002).astype(np.float32))
    # threshold on squared displacement: a pose at target scale sliding 0.04 m/frame (0.0016 m²)
    # is in contact, at 0.05 m/frame (0.0025 m²) it is not
    pose = canonicalize_joints(joints, HUMANML3D)[0]
    for step, expected in ((0.04, 1.0), (0.05, 0.0)):
        slide = pose[None] + step * np.arange(10)[:, None, None] * np.array([0.0, 0.0, 1.0])
        c = joints_to_features(slide, HUMANML3D)[:, -4:]
        assert np.all(c == expected), step


# --------------------------------------------------------------------------- gradients


def test_gradients_reach_every_position_feature():
    rng = np.random.default_rng(2)
    feats = torch.tensor(joints_to_features(random_motion(rng, num_frames=30), HUMANML3D), requires_grad=True)
    joints = features_to_joints(feats, HUMANML3D)
    weights = torch.randn(joints.shape, generator=torch.Generator().manual_seed(0))
    (joints * weights).sum().backward()
    grad = feats.grad
    sl = feature_slices(HUMANML3D)
    # the last row's velocities move no recovered frame; every other position feature does
    assert torch.all(grad[:-1, sl["root_rot_vel"]].abs() > 0)
    assert torch.all(grad[:-1, sl["root_lin_vel"]].abs() > 0)
    assert torch.all(grad[:, sl["root_y"]].abs() > 0)
    assert torch.all(grad[:, sl["ric"]].abs() > 0)
    for key in ("rot6d", "local_vel", "contacts"):
        assert torch.all(grad[:, sl[key]] == 0)


def test_gradcheck_small():
    rng = np.random.default_rng(4)
    feats = joints_to_features(random_motion(rng, num_frames=6), HUMANML3D).astype(np.float64)
    x = torch.tensor(feats[None], requires_grad=True)
    assert torch.autograd.gradcheck(lambda f: features_to_joints(f, HUMANML3D), (x,), eps=1e-6, atol=1e-5)


# --------------------------------------------------------------------------- bad input


def test_bad_shapes_raise_clear_errors():
    with pytest.raises(StableMoError, match="joints"):
        joints_to_features(np.zeros((10, 21, 3)), HUMANML3D)
    with pytest.raises(StableMoError, match="at least 2 frames"):
        joints_to_features(np.zeros((1, 22, 3)), HUMANML3D)
    bad = random_motion(np.random.default_rng(0), 10)
    bad[3, 4, 1] = np.nan
    with pytest.raises(StableMoError, match="NaN"):
        joints_to_features(bad, HUMANML3D)
    with pytest.raises(StableMoError, match="263"):
        features_to_joints(torch.zeros(10, 251), HUMANML3D)


def test_degenerate_facing_frame_is_tolerated_and_torch_input_accepted():
    # one frame whose hip and shoulder lines cancel exactly: the reference would produce NaN in the
    # smoothed facing; that frame simply does not vote in the average
    rng = np.random.default_rng(9)
    joints = random_motion(rng, num_frames=40).astype(np.float64)
    x = canonicalize_joints(joints, HUMANML3D)
    # move the right shoulder so that (L_hip − R_hip) + (R_sh − L_sh) = 0 at frame 20
    x[20, 17] = x[20, 16] - (x[20, 1] - x[20, 2])
    from stablemo.motion.features import facing_rotations

    r = facing_rotations(x, HUMANML3D)
    assert np.all(np.isfinite(r)) and np.allclose(np.linalg.norm(r, axis=-1), 1.0)
    feats = joints_to_features(torch.from_numpy(x), HUMANML3D)
    assert np.all(np.isfinite(feats))
    rec = features_to_joints(feats.astype(np.float64), HUMANML3D)
    assert np.abs(rec - canonicalize_joints(x, HUMANML3D)[:-1]).max() < 1e-4
    with pytest.raises(StableMoError, match="facing"):
        joints_to_features(np.zeros((5, 22, 3)) + np.arange(22)[None, :, None] * [0, 1.0, 0], HUMANML3D)
