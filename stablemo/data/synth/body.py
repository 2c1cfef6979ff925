"""The synthetic body: a 22-joint HumanML3D skeleton posed from a few interpretable curves.

Every bone is placed as `parent + length * unit_direction`, so bone lengths equal the HumanML3D
target lengths exactly in every frame. Legs are solved by analytic two-bone IK from the hip to an
ankle target (so planted feet stay exactly where the gait put them); everything else is forward
kinematics from body-frame directions.

Body frame: x = left, y = up, z = forward. World heading `yaw` rotates the body frame about +y;
yaw = 0 faces +z with the left side at +x (HumanML3D convention), and increasing yaw turns left.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

NUM_JOINTS = 22
PARENTS = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19)
# HumanML3D target bone lengths (parent -> joint), metres.
BONE_LENGTHS = np.array(
    [0.0, .1031, .1099, .1316, .3936, .3902, .1432, .4324, .4256, .0574, .1434, .1494,
     .2194, .1375, .1434, .1030, .1316, .1230, .2568, .2631, .2660, .2699])
LEFT, RIGHT = 0, 1
SIDE_SIGN = (1.0, -1.0)  # body-frame x of the left / right side
HIP = (1, 2)
KNEE = (4, 5)
ANKLE = (7, 8)
TOE = (10, 11)
COLLAR = (13, 14)
SHOULDER = (16, 17)
ELBOW = (18, 19)
WRIST = (20, 21)

FOOT_LENGTH = (BONE_LENGTHS[10], BONE_LENGTHS[11])
FOOT_PITCH = np.deg2rad(20.0)  # a flat foot: toe joint on the floor, ankle above it
ANKLE_FLAT_HEIGHT = tuple(float(l * np.sin(FOOT_PITCH)) for l in FOOT_LENGTH)
THIGH = (BONE_LENGTHS[4], BONE_LENGTHS[5])
SHIN = (BONE_LENGTHS[7], BONE_LENGTHS[8])
LEG_REACH = tuple(0.997 * (a + b) for a, b in zip(THIGH, SHIN))  # never fully straight


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# Rest directions in the body frame (x left, y up, z forward).
_HIP_DIR = (_unit([0.55, -0.835, 0.0]), _unit([-0.55, -0.835, 0.0]))
_SPINE_DIRS = {3: _unit([0, 1, -0.08]), 6: _unit([0, 1, 0.03]), 9: _unit([0, 1, 0.1]),
               12: _unit([0, 0.97, 0.14]), 15: _unit([0, 0.8, 0.6])}
_COLLAR_DIR = (_unit([0.6, 0.8, -0.05]), _unit([-0.6, 0.8, -0.05]))
_SHOULDER_DIR = (_unit([1.0, -0.1, -0.06]), _unit([-1.0, -0.1, -0.06]))
HIP_OFFSET = tuple(BONE_LENGTHS[HIP[s]] * _HIP_DIR[s] for s in (LEFT, RIGHT))

# Arms hang slightly away from the body with the elbows a little bent.
REST_UPPER_ARM = (_unit([0.12, -1.0, -0.03]), _unit([-0.12, -1.0, -0.03]))
REST_FOREARM = (_unit([0.06, -1.0, 0.22]), _unit([-0.06, -1.0, 0.22]))

# Standing pelvis height for straight-ish legs (knees bent ~15 degrees) on flat feet.
STAND_HEIGHT = 0.955
STANCE_HALF_WIDTH = 0.095  # lateral ankle offset from the pelvis when standing
ANKLE_BACK = 0.035  # standing ankles sit slightly behind the pelvis (toes ahead of it)


def rot_y(angle: np.ndarray) -> np.ndarray:
    """(T,) -> (T,3,3) rotation about +y (positive turns +z towards +x: a left turn)."""
    c, s = np.cos(angle), np.sin(angle)
    z, o = np.zeros_like(angle), np.ones_like(angle)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def rot_x(angle: np.ndarray) -> np.ndarray:
    """(T,) -> (T,3,3) rotation about +x (the body's left axis): positive pitches +y towards +z."""
    c, s = np.cos(angle), np.sin(angle)
    z, o = np.zeros_like(angle), np.ones_like(angle)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def rot_z(angle: np.ndarray) -> np.ndarray:
    """(T,) -> (T,3,3) rotation about +z (forward): positive rolls +y towards -x (lean right)."""
    c, s = np.cos(angle), np.sin(angle)
    z, o = np.zeros_like(angle), np.ones_like(angle)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def apply(rot: np.ndarray, v: np.ndarray) -> np.ndarray:
    """rot (T,3,3) @ v (3,) or (T,3) -> (T,3)."""
    if v.ndim == 1:
        return rot @ v
    return np.einsum("tij,tj->ti", rot, v)


def forward_dir(yaw: np.ndarray) -> np.ndarray:
    """(T,) -> (T,3) horizontal facing direction."""
    return np.stack([np.sin(yaw), np.zeros_like(yaw), np.cos(yaw)], -1)


def two_bone_ik(hip: np.ndarray, target: np.ndarray, pole: np.ndarray, upper: float, lower: float,
                reach: float) -> tuple[np.ndarray, np.ndarray]:
    """Knee and ankle for a leg from hip (T,3) towards target (T,3); the knee bends towards pole (T,3).

    Returns (knee, ankle); the ankle equals the target unless it is out of reach (then it lies on
    the hip-target line at `reach`)."""
    d_vec = target - hip
    dist = np.linalg.norm(d_vec, axis=-1, keepdims=True)
    u = d_vec / np.maximum(dist, 1e-9)
    d = np.clip(dist, abs(upper - lower) + 1e-4, reach)
    ankle = hip + u * d
    a = (upper**2 - lower**2 + d**2) / (2 * d)
    h = np.sqrt(np.maximum(upper**2 - a**2, 0.0))
    n = pole - np.sum(pole * u, -1, keepdims=True) * u
    n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-9)
    knee = hip + a * u + h * n
    # Place the shin by its exact length from the knee so |knee-ankle| is exact in float.
    ankle = knee + lower * _unit(ankle - knee)
    return knee, ankle


@dataclass
class Pose:
    """Per-frame body curves (T frames). Angles in radians, positions in metres (world frame)."""

    root: np.ndarray  # (T,3) pelvis position
    yaw: np.ndarray  # (T,) body heading
    torso_pitch: np.ndarray  # (T,) forward bend of the upper body
    torso_roll: np.ndarray  # (T,) sideways lean (+ = towards the right)
    torso_twist: np.ndarray  # (T,) twist of the chest relative to the pelvis (+ = left)
    head_pitch: np.ndarray  # (T,) nod (+ = down)
    upper_arm: list  # [L, R] (T,3) unit directions in the chest frame (yaw + twist)
    forearm: list  # [L, R] (T,3)
    ankle: list  # [L, R] (T,3) ankle targets (world)
    foot_yaw: list  # [L, R] (T,)
    foot_pitch: list  # [L, R] (T,) downward pitch of the ankle->toe bone
    knee_out: np.ndarray = field(default=None)  # (T,) optional outward knee splay (squats)


def neutral_pose(T: int) -> Pose:
    z = np.zeros(T)
    return Pose(
        root=np.tile([0.0, STAND_HEIGHT, 0.0], (T, 1)), yaw=z.copy(), torso_pitch=z.copy(),
        torso_roll=z.copy(), torso_twist=z.copy(), head_pitch=z.copy(),
        upper_arm=[np.tile(REST_UPPER_ARM[s], (T, 1)) for s in (LEFT, RIGHT)],
        forearm=[np.tile(REST_FOREARM[s], (T, 1)) for s in (LEFT, RIGHT)],
        ankle=[np.tile([SIDE_SIGN[s] * STANCE_HALF_WIDTH, ANKLE_FLAT_HEIGHT[s], -ANKLE_BACK], (T, 1))
               for s in (LEFT, RIGHT)],
        foot_yaw=[z.copy(), z.copy()], foot_pitch=[np.full(T, FOOT_PITCH), np.full(T, FOOT_PITCH)],
        knee_out=z.copy())


def hip_positions(root: np.ndarray, yaw: np.ndarray) -> list[np.ndarray]:
    r = rot_y(yaw)
    return [root + apply(r, HIP_OFFSET[s]) for s in (LEFT, RIGHT)]


def pose_to_joints(p: Pose) -> np.ndarray:
    """Assemble (T,22,3) joint positions from the body curves."""
    T = len(p.yaw)
    J = np.zeros((T, NUM_JOINTS, 3))
    r_body = rot_y(p.yaw)
    J[:, 0] = p.root
    hips = hip_positions(p.root, p.yaw)
    fwd = forward_dir(p.yaw)
    knee_out = p.knee_out if p.knee_out is not None else np.zeros(T)
    for s in (LEFT, RIGHT):
        J[:, HIP[s]] = hips[s]
        foot_fwd = forward_dir(p.foot_yaw[s])
        side = apply(r_body, np.array([SIDE_SIGN[s], 0.0, 0.0]))
        # Knees point where the foot points (and the body faces), splayed outwards in squats.
        pole = foot_fwd + fwd + knee_out[:, None] * side
        knee, ankle = two_bone_ik(hips[s], p.ankle[s], pole, THIGH[s], SHIN[s], LEG_REACH[s])
        J[:, KNEE[s]], J[:, ANKLE[s]] = knee, ankle
        toe_dir = np.cos(p.foot_pitch[s])[:, None] * foot_fwd
        toe_dir[:, 1] = -np.sin(p.foot_pitch[s])
        J[:, TOE[s]] = ankle + FOOT_LENGTH[s] * toe_dir

    # Spine: the bend is spread over the chain (lower segments bend less).
    pitch, roll, twist = p.torso_pitch, p.torso_roll, p.torso_twist
    prev = p.root
    chest_rot = None
    for j, frac in ((3, 0.35), (6, 0.7), (9, 1.0), (12, 1.0), (15, 1.0)):
        rot = r_body @ rot_y(frac * twist) @ rot_x(frac * pitch) @ rot_z(frac * roll)
        if j == 15:
            rot = rot @ rot_x(p.head_pitch)
        J[:, j] = prev + BONE_LENGTHS[j] * apply(rot, _SPINE_DIRS[j])
        prev = J[:, j]
        if j == 9:
            chest_rot = rot
    # Arms hang in a gravity-aligned frame that turns with the chest (yaw + twist) but does not
    # pitch with it, so they dangle when the person bows.
    arm_rot = r_body @ rot_y(twist)
    for s in (LEFT, RIGHT):
        J[:, COLLAR[s]] = J[:, 9] + BONE_LENGTHS[COLLAR[s]] * apply(chest_rot, _COLLAR_DIR[s])
        J[:, SHOULDER[s]] = J[:, COLLAR[s]] + BONE_LENGTHS[SHOULDER[s]] * apply(chest_rot, _SHOULDER_DIR[s])
        J[:, ELBOW[s]] = J[:, SHOULDER[s]] + BONE_LENGTHS[ELBOW[s]] * _unit(apply(arm_rot, p.upper_arm[s]))
        J[:, WRIST[s]] = J[:, ELBOW[s]] + BONE_LENGTHS[WRIST[s]] * _unit(apply(arm_rot, p.forearm[s]))
    return J


def bone_lengths(joints: np.ndarray) -> np.ndarray:
    """(T,22,3) -> (T,21) lengths of bones 1..21."""
    par = np.array(PARENTS[1:])
    return np.linalg.norm(joints[:, 1:] - joints[:, par], axis=-1)
