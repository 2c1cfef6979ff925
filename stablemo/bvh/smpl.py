"""An AMASS-style SMPL-X pose file (.npz) of a motion, for users who drive an SMPL / SMPL-X body.

No body-model files are needed to write it (we can ship none). Keys (T frames; float32 unless said):

    poses          (T, 165) axis-angle of SMPL-X's 55 joints (pelvis, 21 body joints, jaw, 2 eyes,
                            15 + 15 hand joints): root_orient, pose_body, pose_jaw, pose_eye, pose_hand
    root_orient    (T, 3)   the pelvis rotation in the file's world (see `up`)
    pose_body      (T, 63)  SMPL's joints 1..21, each relative to its parent (SMPL, SMPL-H and SMPL-X
                            share them; an SMPL body_pose (69) is this plus the two hands, zeros)
    pose_hand      (T, 90), pose_jaw (T, 3), pose_eye (T, 6): zeros (a motion has no fingers or face)
    trans          (T, 3)   the pelvis position, metres, in the file's world. A body model's own
                            `transl` is this minus its rest pelvis J0 (docs/bvh.md has the recipe)
    betas          (16,)    zeros: the mean body shape (AMASS stores 16); the motion's proportions are
                            in rest_offsets, not in betas
    gender         "neutral"; surface_model_type "smplx"
    mocap_framerate, mocap_frame_rate   frames per second (float64; AMASS SMPL-H and SMPL-X spellings)
    up             "z" (AMASS) or "y" (the motion's own frame)
    rest_offsets   (22, 3)  the T-pose the rotations are relative to (parent -> joint, metres, in the
                            body's own frame: y up, facing +z, left at +x, as SMPL's template)
    joint_names    (22,)    SMPL's names of the 22 body joints

Why 165 (SMPL-X) and not SMPL-H's 156: the SMPL-X Blender add-on's "Add Animation" poses every one
of SMPL-X's 55 joints from `poses` (a 156-wide file ends in an index error past joint 52), and
AMASS's SMPL-X release stores 165 with the root_orient/pose_body/... keys its loaders read; SMPL
and SMPL-H users take poses[:, :66] (22 body joints), which the three models share.

Up: "z" turns the motion's frame (y up, facing +z) by the inverse of the axis change HumanML3D
applies to AMASS (AMASS (x, y, z) -> (-x, z, y)): z up, facing +y. A clip made from AMASS goes
back to AMASS's frame. "y" keeps the motion's own frame.

The rotations are relative to our T-pose (arms straight out, legs and spine straight, feet
forward, hips and collars from the motion itself), not to SMPL's template, whose bones lean a few
degrees against it (most: the foot, which points forward and down): SMPL's template is not
ours to ship, so the lean is unknowable here. Posing `rest_offsets` with these rotations gives the
motion's joints back (tested); posing an SMPL body places its joints within those angles.
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
)
SMPL_PARENTS = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19)
SMPLX_JOINTS = 55  # pelvis + 21 body + jaw + 2 eyes + 2 × 15 hand joints
NUM_BETAS = 16
# the motion's frame (y up) -> AMASS's (z up): the inverse of HumanML3D's AMASS -> (-x, z, y); its own inverse
Y_TO_Z_UP = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
UP_AXES = ("z", "y")


def check_up(up: str, what: str = "up") -> str:
    if up not in UP_AXES:
        raise StableMoError(f"{what}={up!r}: choose z (AMASS, the default) or y (the motion's own frame)")
    return up


def smpl_arrays(anim: Animation, up: str = "z") -> dict[str, np.ndarray]:
    """The npz's arrays for an animation of the HumanML3D rig in metres."""
    check_up(up)
    rig = anim.rig
    if rig.num_joints != len(SMPL_NAMES):
        raise StableMoError(f"SMPL order needs the 22-joint HumanML3D skeleton, this motion has {rig.num_joints} joints")
    t = anim.num_frames
    turn = np.eye(3) if up == "y" else Y_TO_Z_UP
    local = Rotation.from_quat(anim.rotations.reshape(-1, 4)[:, [1, 2, 3, 0]]).as_rotvec().reshape(t, 22, 3)
    # the root's rotation and position are in the world, which `up` turns; the others are relative to their parent
    root = Rotation.from_matrix(np.broadcast_to(turn, (t, 3, 3))) * Rotation.from_rotvec(local[:, 0])
    poses = np.zeros((t, SMPLX_JOINTS, 3))
    poses[:, 0] = root.as_rotvec()
    poses[:, 1:22] = local[:, 1:]
    poses = poses.reshape(t, SMPLX_JOINTS * 3)
    rate = np.float64(anim.fps)
    return {
        "poses": poses.astype(np.float32),
        "root_orient": poses[:, :3].astype(np.float32),
        "pose_body": poses[:, 3:66].astype(np.float32),
        "pose_jaw": poses[:, 66:69].astype(np.float32),
        "pose_eye": poses[:, 69:75].astype(np.float32),
        "pose_hand": poses[:, 75:].astype(np.float32),
        "trans": (anim.root @ turn.T).astype(np.float32),
        "betas": np.zeros(NUM_BETAS, np.float32),
        "gender": np.array("neutral"),
        "surface_model_type": np.array("smplx"),
        "mocap_framerate": rate,
        "mocap_frame_rate": rate,
        "up": np.array(up),
        "rest_offsets": rig.offsets.astype(np.float32),
        "joint_names": np.array(SMPL_NAMES),
    }


def write_smpl_npz(path: str | os.PathLike, anim: Animation, up: str = "z") -> None:
    from stablemo.io import atomic_open

    arrays = smpl_arrays(anim, up)
    with atomic_open(path) as f:
        np.savez(f, **arrays)
