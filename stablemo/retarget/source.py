"""The motion to retarget, as world joint positions with humanoid roles: a StableMo motion
(features or joints, HumanML3D or KIT) or a BVH file (any rig whose names stablemo.retarget.names
reads; a z-up file is turned y up). The floor where the motion has it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stablemo.errors import StableMoError
from stablemo.retarget.frames import up_axes
from stablemo.retarget.names import Roles, find_roles

# joint indices of our skeletons' roles (stablemo/motion/skeleton.py)
SKELETON_ROLES = {
    "humanml3d": Roles(0, (3, 6, 9), (12,), 15, {
        "Left": {"UpperLeg": 1, "LowerLeg": 4, "Foot": 7, "Toes": 10, "Shoulder": 13, "UpperArm": 16,
                 "LowerArm": 18, "Hand": 20},
        "Right": {"UpperLeg": 2, "LowerLeg": 5, "Foot": 8, "Toes": 11, "Shoulder": 14, "UpperArm": 17,
                  "LowerArm": 19, "Hand": 21}}),
    # KIT has no clavicle and no neck joint: BLN (3) is the chest the arms hang from, BUN (4) the head
    "kit": Roles(0, (1, 2, 3), (), 4, {
        "Left": {"UpperLeg": 16, "LowerLeg": 17, "Foot": 18, "Toes": 19, "UpperArm": 8, "LowerArm": 9, "Hand": 10},
        "Right": {"UpperLeg": 11, "LowerLeg": 12, "Foot": 13, "Toes": 14, "UpperArm": 5, "LowerArm": 6, "Hand": 7}}),
}


@dataclass(frozen=True)
class Source:
    """positions (T, J, 3) world joints in the source's units, `per_metre` of those units per metre,
    roles, fps, names (J,) for messages. A BVH motion also gives its joints' turns: orient
    (T, J, 3, 3) each joint's world rotation from its rest (y up), and the rest pose they turn from:
    rest (J, 3) and ends {joint: (3,) where its bone points at rest} (its first child or End Site),
    so hands and head turn as the file's do (a HumanML3D motion has no hand or head turn to give)."""

    positions: np.ndarray
    roles: Roles
    fps: float
    per_metre: float
    names: tuple[str, ...]
    orient: np.ndarray | None = None
    rest: np.ndarray | None = None
    ends: dict | None = None

    def leg_length(self) -> float:
        """Median over frames of thigh + shin, both sides averaged (the source's units)."""
        return leg_length(self.positions, self.roles)


def leg_length(positions: np.ndarray, roles: Roles) -> float:
    """positions (T, J, 3) or (J, 3) -> median thigh + shin length, averaged over the two sides."""
    x = positions if positions.ndim == 3 else positions[None]
    total = []
    for side in roles.sides.values():
        hip, knee, ankle = side["UpperLeg"], side["LowerLeg"], side["Foot"]
        total.append(np.linalg.norm(x[:, knee] - x[:, hip], axis=-1) + np.linalg.norm(x[:, ankle] - x[:, knee], axis=-1))
    return float(np.median(np.mean(total, axis=0)))


def guess_per_metre(leg: float) -> float:
    """Units per metre of a rig or motion from its leg (thigh + shin ~0.8 m for an adult): 1, 100 or 1000."""
    ratio = leg / 0.8
    return float(min((1.0, 10.0, 100.0, 1000.0), key=lambda u: abs(np.log10(ratio / u))))


def motion_source(motion, what: str = "motion", skeleton=None, fps: float | None = None) -> Source:
    """A StableMo motion (features (T, 263)/(T, 251) or joints (T, J, 3), numpy or torch)."""
    from stablemo.bvh.names import bvh_names
    from stablemo.bvh.writer import motion_joints

    joints, skel = motion_joints(motion, skeleton, what)
    if len(joints) < 2:
        raise StableMoError(f"{what}: one frame; a motion to retarget needs at least two")
    return Source(joints, SKELETON_ROLES[skel.name], float(fps or skel.fps), skel.per_metre, bvh_names(skel))


def bvh_source(path: str | Path, role_map: dict | None = None) -> Source:
    """A BVH motion: its forward kinematics, roles from its joint names."""
    from stablemo.bvh.rig import forward_kinematics
    from stablemo.bvh.text import read_bvh

    anim = read_bvh(path)
    if anim.num_frames < 2:
        raise StableMoError(f"{path}: one frame; a motion to retarget needs at least two")
    joints = forward_kinematics(anim)
    rig = anim.rig
    rest = np.zeros((rig.num_joints, 3))
    for j, p in enumerate(rig.parents):
        rest[j] = rig.offsets[j] + (rest[p] if p >= 0 else 0.0)
    roles = find_roles(rig.names, rig.parents, rest, str(path), role_map, flag="--source-map")
    axes = up_axes(rest, roles, str(path))  # a z-up file (Blender's export) is read y up
    orient = world_rotations(anim.rotations, rig.parents)  # (T, J, 3, 3) file axes
    ends = {}
    for j in range(rig.num_joints):
        kids = rig.children(j)
        end = rig.offsets[kids[0]] if kids else rig.end_sites.get(j)
        if end is not None and np.linalg.norm(end) > 0:
            ends[j] = end @ axes
    return Source(joints @ axes, roles, anim.fps, guess_per_metre(leg_length(rest, roles)), rig.names,
                  axes.T @ orient @ axes, rest @ axes, ends)


def world_rotations(local: np.ndarray, parents) -> np.ndarray:
    """Local rotations (T, J, 4) w-first -> world rotation matrices (T, J, 3, 3), parents first."""
    from scipy.spatial.transform import Rotation

    mats = Rotation.from_quat(local.reshape(-1, 4)[:, [1, 2, 3, 0]]).as_matrix().reshape(local.shape[:2] + (3, 3))
    out = np.empty_like(mats)
    for j, p in enumerate(parents):
        out[:, j] = mats[:, j] if p < 0 else out[:, p] @ mats[:, j]
    return out


def read_source(path: str | Path, role_map: dict | None = None) -> Source:
    """MOTION of `stablemo retarget`: a .npy (features or joints) or a .bvh."""
    path = Path(path)
    if path.suffix.lower() == ".bvh":
        return bvh_source(path, role_map)
    if path.suffix.lower() != ".npy":
        raise StableMoError(f"{path}: expected a StableMo motion (.features.npy / .joints.npy) or a .bvh")
    from stablemo.io import load_npy

    return motion_source(load_npy(path), str(path))
