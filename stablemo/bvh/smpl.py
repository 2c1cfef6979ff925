"""An SMPL-order pose file (.npz) for users who drive an SMPL body: no body-model files needed.

Keys (T frames, float32 unless said):
    poses          (T, 72)  axis-angle per SMPL joint (24 × 3): global_orient then body_pose
    global_orient  (T, 3)   the pelvis rotation in the world (y up, the motion's own frame)
    body_pose      (T, 69)  joints 1..23, each relative to its parent
    root_position  (T, 3)   the pelvis position in metres. SMPL's `transl` moves the model, whose
                            rest pelvis is not at the origin: transl = root_position - J[0] of
                            your body model at rest
    rest_offsets   (24, 3)  the rest pose the rotations are relative to (parent -> joint, metres)
    joint_names    (24,)    SMPL joint names; mocap_framerate: frames per second (float64)

The 22 HumanML3D joints are SMPL's first 22; the hands (22, 23) get the identity. Rotations are
relative to a T-pose: arms straight out, legs and spine straight, feet forward, hips and collars
from the motion itself. SMPL's own template leans some bones by a few degrees against that (most:
the foot, whose template points forward and down); a body posed with these rotations places the
joints within those angles of the motion's, while our BVH is exact.
"""

from __future__ import annotations

import os

import numpy as np
from scipy.spatial.transform import Rotation

from stablemo.bvh.rig import Animation
from stablemo.errors import StableMoError

SMPL_NAMES = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle",
    "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head",
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
    "left_hand", "right_hand",
)
SMPL_PARENTS = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21)
HAND_LENGTH = 0.08  # metres, wrist -> hand joint in the rest pose (a placeholder: the pose ignores it)


def smpl_arrays(anim: Animation) -> dict[str, np.ndarray]:
    """The npz's arrays for an animation of the HumanML3D rig in metres."""
    rig = anim.rig
    if rig.num_joints != 22:
        raise StableMoError(f"SMPL order needs the 22-joint HumanML3D skeleton, this motion has {rig.num_joints} joints")
    t = anim.num_frames
    quats = np.zeros((t, 24, 4))
    quats[..., 0] = 1.0
    quats[:, :22] = anim.rotations
    rotvec = Rotation.from_quat(quats.reshape(-1, 4)[:, [1, 2, 3, 0]]).as_rotvec().reshape(t, 72)
    rest = np.zeros((24, 3))
    rest[:22] = rig.offsets
    rest[22], rest[23] = (HAND_LENGTH, 0.0, 0.0), (-HAND_LENGTH, 0.0, 0.0)
    return {
        "poses": rotvec.astype(np.float32),
        "global_orient": rotvec[:, :3].astype(np.float32),
        "body_pose": rotvec[:, 3:].astype(np.float32),
        "root_position": anim.root.astype(np.float32),
        "rest_offsets": rest.astype(np.float32),
        "joint_names": np.array(SMPL_NAMES),
        "mocap_framerate": np.float64(anim.fps),
    }


def write_smpl_npz(path: str | os.PathLike, anim: Animation) -> None:
    from stablemo.io import atomic_open

    arrays = smpl_arrays(anim)
    with atomic_open(path) as f:
        np.savez(f, **arrays)
