"""A motion under construction: per-frame body curves, foot plants, and the finishing passes.

Actions append themselves at the cursor `t` and leave the body standing still at their end, so
any sequence of actions joins with zero velocity and a neutral pose (no jumps between parts).
Overlays (arm gestures, torso bends, pelvis dips) are written as offsets with envelopes that
start and end at zero.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import gaussian_filter1d, maximum_filter1d

from stablemo.data.synth import body
from stablemo.data.synth.body import LEFT, RIGHT, SIDE_SIGN
from stablemo.data.synth.gait import Plant, render_foot

FPS = 20


@dataclass
class Part:
    """One action of a composite, with its frame range [start, end) and caption parameters."""

    action: str
    params: dict
    start: int
    end: int


@dataclass
class Built:
    joints: np.ndarray  # (T,22,3)
    contacts: np.ndarray  # (T,4) bool [L_ankle, L_toe, R_ankle, R_toe]
    parts: list[Part]


def _unit(v):
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-9)


@dataclass
class Timeline:
    cap: int = 480
    t: int = 0
    parts: list = field(default_factory=list)

    def __post_init__(self):
        n = self.cap
        self.root_xz = np.zeros((n, 2))
        self.root_y = np.full(n, body.STAND_HEIGHT)
        self.yaw = np.zeros(n)
        self.torso_pitch = np.zeros(n)
        self.torso_roll = np.zeros(n)
        self.torso_twist = np.zeros(n)
        self.head_pitch = np.zeros(n)
        self.knee_out = np.zeros(n)
        self.arm_swing = np.zeros((n, 2))  # gain of gait-driven arm swing per arm [L, R] (rad)
        self.elbow_flex = np.zeros(n)  # extra elbow bend while moving (rad)
        self.upper_arm = [np.tile(body.REST_UPPER_ARM[s], (n, 1)) for s in (LEFT, RIGHT)]
        self.forearm = [np.tile(body.REST_FOREARM[s], (n, 1)) for s in (LEFT, RIGHT)]
        stance = [np.array([SIDE_SIGN[s] * body.STANCE_HALF_WIDTH, -body.ANKLE_BACK]) for s in (LEFT, RIGHT)]
        self.plants = [[Plant(0.0, np.inf, stance[s], 0.0)] for s in (LEFT, RIGHT)]

    # --- state at the cursor -------------------------------------------------------------
    @property
    def pos(self) -> np.ndarray:
        return self.root_xz[max(self.t - 1, 0)].copy()

    @property
    def heading(self) -> float:
        return float(self.yaw[max(self.t - 1, 0)])

    def current_plant(self, side: int) -> Plant:
        return self.plants[side][-1]

    # --- writing ---------------------------------------------------------------------------
    def frames(self, n: int) -> slice:
        if self.t + n > self.cap:
            raise OverflowError("motion longer than the timeline capacity")
        return slice(self.t, self.t + n)

    def set_root(self, sl: slice, xz: np.ndarray, yaw: np.ndarray) -> None:
        """Write root xz and heading for frames in `sl` and hold the last values afterwards."""
        self.root_xz[sl], self.yaw[sl] = xz, yaw
        self.root_xz[sl.stop:] = xz[-1]
        self.yaw[sl.stop:] = yaw[-1]

    def blend_arm(self, side: int, sl: slice, upper: np.ndarray, fore: np.ndarray, env: np.ndarray) -> None:
        """Move an arm towards directions upper/fore (n,3) (body frame) with weight env (n,)."""
        e = env[:, None]
        self.upper_arm[side][sl] = _unit((1 - e) * self.upper_arm[side][sl] + e * upper)
        self.forearm[side][sl] = _unit((1 - e) * self.forearm[side][sl] + e * fore)

    def add_part(self, action: str, params: dict, start: int) -> None:
        self.parts.append(Part(action, dict(params), start, self.t))

    def root_at(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Root xz and yaw interpolated at fractional frames."""
        idx = np.arange(self.cap)
        xz = np.stack([np.interp(times, idx, self.root_xz[:, i]) for i in (0, 1)], -1)
        return xz, np.interp(times, idx, np.unwrap(self.yaw))

    # --- finishing -------------------------------------------------------------------------
    def build(self, T: int) -> Built:
        """Finish a motion of T frames: feet, pelvis height, arm swing, joints, floor and facing."""
        feet = [render_foot(self.plants[s], s, T) for s in (LEFT, RIGHT)]
        root = np.concatenate([self.root_xz[:T, :1], self.root_y[:T, None], self.root_xz[:T, 1:]], -1)
        yaw = self.yaw[:T].copy()
        root[:, 1] = _limit_height(root, yaw, [f[0] for f in feet])
        upper = [a[:T].copy() for a in self.upper_arm]
        fore = [a[:T].copy() for a in self.forearm]
        _gait_arm_swing(root, yaw, [f[0] for f in feet], self.arm_swing[:T], self.elbow_flex[:T], upper, fore)
        pose = body.Pose(
            root=root, yaw=yaw, torso_pitch=self.torso_pitch[:T], torso_roll=self.torso_roll[:T],
            torso_twist=self.torso_twist[:T], head_pitch=self.head_pitch[:T], upper_arm=upper,
            forearm=fore, ankle=[f[0] for f in feet], foot_yaw=[f[1] for f in feet],
            foot_pitch=[f[2] for f in feet], knee_out=self.knee_out[:T])
        joints = body.pose_to_joints(pose)
        contacts = np.concatenate([feet[LEFT][3], feet[RIGHT][3]], -1)
        parts = [Part(p.action, p.params, p.start, min(p.end, T)) for p in self.parts]
        return Built(normalise(joints), contacts, parts)


def _limit_height(root: np.ndarray, yaw: np.ndarray, ankles: list[np.ndarray]) -> np.ndarray:
    """Lower the pelvis smoothly where a leg could not reach its planted foot."""
    y = root[:, 1].copy()
    limit = np.full(len(y), np.inf)
    hips = body.hip_positions(root, yaw)
    for s in (LEFT, RIGHT):
        reach = body.LEG_REACH[s] * 0.995
        d_xz = np.linalg.norm((ankles[s] - hips[s])[:, [0, 2]], axis=-1)
        dy = np.sqrt(np.maximum(reach**2 - d_xz**2, 0.0))
        limit = np.minimum(limit, ankles[s][:, 1] + dy + (root[:, 1] - hips[s][:, 1]))
    deficit = np.maximum(y - limit, 0.0)
    if deficit.any():
        smooth = gaussian_filter1d(maximum_filter1d(deficit, 7, mode="nearest"), 1.5, mode="nearest")
        y = np.minimum(y - smooth, limit)
    return y


def _gait_arm_swing(root, yaw, ankles, gain, flex, upper, fore) -> None:
    """Arms swing opposite to the legs: an arm goes forward while the same-side foot is behind."""
    if not np.any(gain > 0):
        return  # gain: (T, 2)
    fwd = body.forward_dir(yaw)
    for s in (LEFT, RIGHT):
        offset = np.sum((ankles[s] - root) * fwd, -1)
        offset = gaussian_filter1d(offset, 1.0, mode="nearest")
        alpha = -gain[:, s] * np.tanh(offset / 0.3)  # + = arm forward
        bend = flex + 0.3 * np.maximum(alpha, 0.0)
        upper[s] = _unit(body.apply(body.rot_x(-alpha), upper[s]))
        fore[s] = _unit(body.apply(body.rot_x(-(alpha + bend)), fore[s]))


def normalise(joints: np.ndarray) -> np.ndarray:
    """Floor at y = 0, frame-0 root at the xz origin, frame-0 facing +z (as HumanML3D's extraction)."""
    j = joints - np.array([joints[0, 0, 0], joints[..., 1].min(), joints[0, 0, 2]])
    across = (j[0, 2] - j[0, 1]) + (j[0, 17] - j[0, 16])
    fwd = np.cross([0.0, 1.0, 0.0], across)
    angle = np.arctan2(fwd[0], fwd[2])
    rot = body.rot_y(np.array([-angle]))[0]
    return (j @ rot.T).astype(np.float32)
