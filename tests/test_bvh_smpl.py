"""The AMASS-style SMPL-X pose file (`stablemo bvh x.npy --out x.npz`): AMASS's keys and shapes, z up
by default (y with --up y), and rotations that pose our T-pose (or any body of the same bone
directions) onto the motion."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_bvh import errors

from stablemo.bench.motions import heading, synth_joints
from stablemo.bvh import export_motion
from stablemo.bvh.smpl import SMPL_NAMES, SMPL_PARENTS, Y_TO_Z_UP, write_smpl_npz
from stablemo.cli.bvh import main
from stablemo.errors import StableMoError
from stablemo.motion import HUMANML3D
from stablemo.motion.quaternion import qmul_np, qrot_np

KEYS = {"poses", "root_orient", "pose_body", "pose_jaw", "pose_eye", "pose_hand", "trans", "betas", "gender",
        "surface_model_type", "mocap_framerate", "mocap_frame_rate", "up", "rest_offsets", "joint_names"}


def write_npz(tmp_path, joints: np.ndarray, *flags: str) -> dict[str, np.ndarray]:
    np.save(tmp_path / "m.npy", joints.astype(np.float32))
    assert main([str(tmp_path / "m.npy"), "--out", str(tmp_path / "m.npz"), *flags]) == 0
    with np.load(tmp_path / "m.npz", allow_pickle=False) as d:  # no object arrays: plain numpy reads it
        return {k: d[k] for k in d.files}


def pose(d: dict, rest: np.ndarray) -> np.ndarray:
    """Our own SMPL forward kinematics of the body joints: `rest` (22, 3) parent -> joint offsets
    in the body's frame, posed by the file's axis-angles and placed at `trans`. -> (T, 22, 3)."""
    t = len(d["trans"])
    local = Rotation.from_rotvec(d["poses"].reshape(t, 55, 3)[:, :22].reshape(-1, 3).astype(np.float64))
    local = local.as_quat()[:, [3, 0, 1, 2]].reshape(t, 22, 4)
    world, pos = np.zeros_like(local), np.zeros((t, 22, 3))
    for j, p in enumerate(SMPL_PARENTS):
        if p < 0:
            world[:, j], pos[:, j] = local[:, j], d["trans"]
        else:
            world[:, j] = qmul_np(world[:, p], local[:, j])
            pos[:, j] = pos[:, p] + qrot_np(world[:, p], np.broadcast_to(rest[j], (t, 3)))
    return pos


def bone_directions(joints: np.ndarray) -> np.ndarray:
    parents = np.array(HUMANML3D.parents)
    bones = joints[:, 1:] - joints[:, parents[1:]]
    return bones / np.linalg.norm(bones, axis=-1, keepdims=True)  # (T, J-1, 3)


def test_keys_and_shapes_follow_amass_and_the_smplx_addon(tmp_path):
    joints = heading(synth_joints("jump", 31), 30)
    d = write_npz(tmp_path, joints)
    t = len(joints)
    assert set(d) == KEYS
    # what the SMPL-X Blender add-on's "Add Animation" requires: these five keys, and a pose for each
    # of SMPL-X's 55 joints
    assert {"trans", "gender", "betas", "poses"} <= set(d) and "mocap_framerate" in d
    assert d["poses"].shape == (t, 165) and d["poses"].shape[1] // 3 == 55
    shapes = {"root_orient": (t, 3), "pose_body": (t, 63), "pose_jaw": (t, 3), "pose_eye": (t, 6),
              "pose_hand": (t, 90), "trans": (t, 3), "betas": (16,), "rest_offsets": (22, 3), "joint_names": (22,)}
    assert {k: d[k].shape for k in shapes} == shapes
    assert all(d[k].dtype == np.float32 for k in shapes if k != "joint_names")
    parts = np.concatenate([d[k] for k in ("root_orient", "pose_body", "pose_jaw", "pose_eye", "pose_hand")], axis=1)
    assert np.array_equal(parts, d["poses"])
    assert not d["poses"][:, 66:].any() and not d["betas"].any()  # no fingers, face or shape
    assert np.abs(d["pose_body"]).max() > 0.1  # the body does move
    assert str(d["gender"]) == "neutral" and str(d["surface_model_type"]) == "smplx" and str(d["up"]) == "z"
    assert float(d["mocap_framerate"]) == float(d["mocap_frame_rate"]) == 20.0
    assert tuple(d["joint_names"]) == SMPL_NAMES


def test_z_up_by_default_and_y_up_on_request(tmp_path):
    joints = synth_joints("walk", 32)  # walks forward: +z in the motion's frame
    d = write_npz(tmp_path, joints)
    pelvis = joints[:, 0]
    assert np.allclose(d["trans"], np.stack([-pelvis[:, 0], pelvis[:, 2], pelvis[:, 1]], axis=1), atol=1e-6)
    assert d["trans"][:, 2].min() > 0.7  # the pelvis is ~0.9 m above the floor: z is up
    assert d["trans"][-1, 1] - d["trans"][0, 1] > 0.5  # walking forward goes along +y
    posed = pose(d, d["rest_offsets"])
    assert errors(posed, joints @ Y_TO_Z_UP.T).max() < 1e-4  # float32 file
    assert posed[..., 2].min() == pytest.approx(joints[..., 1].min(), abs=1e-4)  # the floor is z = its height

    y = write_npz(tmp_path, joints, "--up", "y")
    assert str(y["up"]) == "y" and np.allclose(y["trans"], pelvis, atol=1e-6)
    assert errors(pose(y, y["rest_offsets"]), joints).max() < 1e-4
    assert np.array_equal(y["pose_body"], d["pose_body"])  # only the root's rotation and position turn


@pytest.mark.parametrize("degrees", [0, 90, 180, 270])
def test_rotations_give_the_bone_directions_to_any_body_of_our_t_pose(tmp_path, degrees):
    joints = heading(synth_joints("turn", 33, angle=270), degrees)
    d = write_npz(tmp_path, joints)
    # a body of other proportions in the same T-pose (every bone its own length, same direction):
    # posed by the file, its bones point where the motion's do
    rng = np.random.default_rng(degrees)
    other = d["rest_offsets"].astype(np.float64) * rng.uniform(0.7, 1.4, size=(22, 1))
    directions = bone_directions(pose(d, other))
    target = bone_directions(joints @ Y_TO_Z_UP.T)
    angle = np.degrees(np.arccos(np.clip((directions * target).sum(-1), -1.0, 1.0)))
    assert angle.max() < 0.05, angle.max()
    # the T-pose: legs and spine straight along the skeleton's raw directions, arms straight out
    rest = d["rest_offsets"] / np.maximum(np.linalg.norm(d["rest_offsets"], axis=-1, keepdims=True), 1e-9)
    assert np.allclose(rest[[4, 7]], [0, -1, 0], atol=1e-6) and np.allclose(rest[[18, 20]], [1, 0, 0], atol=1e-6)
    assert np.allclose(rest[[19, 21]], [-1, 0, 0], atol=1e-6)


def test_the_body_below_the_root_does_not_depend_on_the_heading(tmp_path):
    joints = synth_joints("walk", 34)
    base = write_npz(tmp_path, joints)
    for degrees in (90, 180, 270):
        turned = write_npz(tmp_path, heading(joints, degrees))
        assert np.abs(turned["pose_body"] - base["pose_body"]).max() < 1e-4
        assert np.abs(turned["root_orient"] - base["root_orient"]).max() > 0.5


def test_resampled_and_from_the_python_api(tmp_path):
    joints = synth_joints("jump", 35)
    d = write_npz(tmp_path, joints, "--fps", "30")
    assert float(d["mocap_framerate"]) == 30.0 and len(d["poses"]) == (len(joints) - 1) * 3 // 2 + 1
    export = export_motion(joints)
    write_smpl_npz(tmp_path / "api.npz", export.anim, up="y")
    with np.load(tmp_path / "api.npz", allow_pickle=False) as api:
        assert str(api["up"]) == "y" and api["poses"].shape == (len(joints), 165)
    with pytest.raises(StableMoError, match="up='Z': choose z"):
        write_smpl_npz(tmp_path / "bad.npz", export.anim, up="Z")
    assert not (tmp_path / "bad.npz").exists()
