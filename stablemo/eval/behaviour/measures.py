"""What a body does, read from its joints: one motion `j` (T, 22, 3) in metres (HumanML3D joints,
y up), frame rate `fps`. Each measure is a number or a per-frame mask; stablemo.eval.behaviour.checks
turns them into verdicts.

Heights are taken above the motion's own ground (GROUND_QUANTILE of the lowest foot joint) so a body
the network left floating a few centimetres counts its flights from where it stands. Directions are
read in the body's own frame: facing from the hips and shoulders (stablemo.motion.heading), forward
(sin yaw, cos yaw) and left (cos yaw, -sin yaw) in xz, yaw increasing to the left. Thresholds lie
between what the synthetic generator's body does when it does the action and when it does not
(tests/test_behaviour.py and `stablemo behaviour --ground-truth` hold them there); docs/evaluation.md
says where each is fragile.
"""

from __future__ import annotations

import numpy as np
import torch

from stablemo.eval.heading import facing_vs_travel
from stablemo.motion.heading import facing_yaw, travel, unwrap
from stablemo.motion.skeleton import HUMANML3D

J = {name: i for i, name in enumerate(HUMANML3D.joint_names)}
SIDES = ("left", "right")
FEET = {"left": (J["L_ankle"], J["L_foot"]), "right": (J["R_ankle"], J["R_foot"])}
PREFIX = {"left": "L_", "right": "R_"}

GROUND_QUANTILE = 5.0  # percent: under every flight (a 3-jump clip is airborne < 30 % of its frames)
AIRBORNE_ON_M, AIRBORNE_OFF_M = 0.05, 0.03  # both feet this high: flying (a synthetic jump lifts them ~20 cm)
HOP_ON_M, HOP_OFF_M = 0.04, 0.02  # the stance foot of a hop leaves the floor less (~8 cm)
HOP_FREE_ABOVE_M = 0.10  # the free foot held this far above the stance foot
MIN_SPAN_S = 0.1  # a flight, clap or punch shorter than this is a flicker, not an event
FACING_SMOOTH_S = 0.25  # against the sway of a gait
TURNING_DEG_S = 30.0  # faster yaw than this: turning (a circle turns ~80 deg/s, a straight walk ~0)
MOVING_MIN_S = 0.5  # a gait needs at least this many moving frames to be judged
END_WINDOW_S = 0.25  # the facing at either end: averaged over this much
DIP_ON_M, DIP_OFF_M = 0.15, 0.08  # the pelvis this far under its standing height: a squat
STAND_QUANTILE = 90.0  # percent: the pelvis's standing height (a squat clip is down < half its frames)
RAISED_MIN_S = 0.5  # a raised hand: held at least this long (a jump's arm swing is shorter)
WAVE_SWING_M = 0.03  # a waving forearm crosses this far either side of its running mean
WAVE_SWINGS = 2  # at least this many side-to-side swings while raised
CLAP_ON_M, CLAP_OFF_M = 0.12, 0.18  # wrists this close: hands together (synthetic claps 5 cm, hanging arms 51)
PUNCH_ON_M, PUNCH_OFF_M = 0.43, 0.35  # wrist in front of the pelvis: half-way from the guard (0.32 m) to a punch (0.53)
ARM_OUT_M = 0.35  # a wrist this far out from its shoulder (forward or to the side): a stretched arm
ARM_LEVEL_M = 0.25  # ... and within this of the shoulder's height
KICK_HEIGHT_M = 0.30  # a kicking ankle rises this high (synthetic kicks 0.4-0.6 m; a walking step ~0.15)
KICK_FORWARD_M = 0.25  # ... in front of the pelvis
BOW_FORWARD_M = 0.25  # the head this far in front of the pelvis, the pelvis up: a bow


def _min_frames(fps: float, seconds: float) -> int:
    return max(1, round(seconds * fps))


def spans(on: np.ndarray, off: np.ndarray | None = None, min_frames: int = 1) -> list[tuple[int, int]]:
    """Runs [start, end) of a condition with hysteresis: a run starts where `on` holds and lasts
    while `off` does not (off defaults to not on); runs shorter than min_frames are dropped."""
    off = ~on if off is None else off
    out, start = [], None
    for t in range(len(on)):
        if start is None and on[t]:
            start = t
        elif start is not None and off[t]:
            if t - start >= min_frames:
                out.append((start, t))
            start = None
    if start is not None and len(on) - start >= min_frames:
        out.append((start, len(on)))
    return out


def span_mask(runs: list[tuple[int, int]], frames: int) -> np.ndarray:
    mask = np.zeros(frames, bool)
    for a, b in runs:
        mask[a:b] = True
    return mask


def ground(j: np.ndarray) -> float:
    """The motion's floor: a low percentile of its lowest foot joint."""
    feet = [i for side in SIDES for i in FEET[side]]
    return float(np.percentile(j[:, feet, 1].min(1), GROUND_QUANTILE))


def foot_height(j: np.ndarray, side: str) -> np.ndarray:
    """(T,) the lower of a foot's ankle and toe above the motion's ground."""
    return j[:, list(FEET[side]), 1].min(1) - ground(j)


def airborne_spans(j: np.ndarray, fps: float) -> list[tuple[int, int]]:
    """Flights: both feet off the ground (jumps; a jog's or run's flight phases too)."""
    low = np.minimum(foot_height(j, "left"), foot_height(j, "right"))
    return spans(low > AIRBORNE_ON_M, low < AIRBORNE_OFF_M, _min_frames(fps, MIN_SPAN_S))


def hop_spans(j: np.ndarray, stance: str, fps: float) -> list[tuple[int, int]]:
    """Hops on the `stance` foot: it leaves the ground while the other foot is held above it."""
    free = "right" if stance == "left" else "left"
    h_stance, h_free = foot_height(j, stance), foot_height(j, free)
    up = h_free - h_stance > HOP_FREE_ABOVE_M
    return spans((h_stance > HOP_ON_M) & up, (h_stance < HOP_OFF_M) | ~up, _min_frames(fps, MIN_SPAN_S))


def facing(j: np.ndarray, fps: float) -> np.ndarray:
    """(T,) radians, unwrapped: the yaw of the hips and shoulders, smoothed over FACING_SMOOTH_S."""
    yaw = facing_yaw(torch.from_numpy(j)[None], HUMANML3D, FACING_SMOOTH_S * fps)
    return unwrap(yaw)[0].numpy()


def heading_change(j: np.ndarray, fps: float) -> float:
    """Degrees the body turned from its first to its last END_WINDOW_S (+ = to the left)."""
    yaw = facing(j, fps)
    k = _min_frames(fps, END_WINDOW_S)
    return float(np.rad2deg(yaw[-k:].mean() - yaw[:k].mean()))


def turning(j: np.ndarray, fps: float) -> np.ndarray:
    """(T,) bool: frames turning faster than TURNING_DEG_S."""
    rate = np.rad2deg(np.gradient(facing(j, fps))) * fps
    return np.abs(rate) > TURNING_DEG_S


def gait(j: np.ndarray, fps: float) -> dict[str, np.ndarray]:
    """Per frame (stablemo.eval.heading): `angle` degrees between facing and travel, `signed` (travel
    minus facing: + = travelling to the body's left), `moving`, and `speed` m/s of the pelvis."""
    x = torch.from_numpy(j)[None]
    n = torch.tensor([len(j)])
    ft = facing_vs_travel(x, n, HUMANML3D)
    _, speed = travel(x[:, :, 0][..., [0, 2]], n, fps)
    return {"angle": ft["angle"][0].numpy(), "signed": ft["signed"][0].numpy(),
            "moving": ft["moving"][0].numpy(), "speed": speed[0].numpy()}


def moving_enough(g: dict, fps: float) -> bool:
    return int(g["moving"].sum()) >= _min_frames(fps, MOVING_MIN_S)


def start_frame_displacement(j: np.ndarray, fps: float) -> tuple[float, float]:
    """(forward, left) metres the pelvis moved over the motion, in the body frame of its start."""
    yaw = facing(j, fps)[: _min_frames(fps, END_WINDOW_S)].mean()
    d = j[-1, 0, [0, 2]] - j[0, 0, [0, 2]]
    return float(d @ [np.sin(yaw), np.cos(yaw)]), float(d @ [np.cos(yaw), -np.sin(yaw)])


def body_offsets(j: np.ndarray, joint: int, origin: int, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """(forward, left) (T,) offsets of `joint` from `origin` in each frame's body frame."""
    yaw = facing(j, fps)
    d = j[:, joint, [0, 2]] - j[:, origin, [0, 2]]
    return (d[:, 0] * np.sin(yaw) + d[:, 1] * np.cos(yaw), d[:, 0] * np.cos(yaw) - d[:, 1] * np.sin(yaw))


def pelvis_drop(j: np.ndarray) -> np.ndarray:
    """(T,) metres the pelvis is under its standing height."""
    return np.percentile(j[:, 0, 1], STAND_QUANTILE) - j[:, 0, 1]


def dip_spans(j: np.ndarray, fps: float, depth: float = DIP_ON_M) -> list[tuple[int, int]]:
    """Squats (or a crouch): the pelvis goes `depth` under its standing height and comes back up."""
    drop = pelvis_drop(j)
    return spans(drop > depth, drop < min(DIP_OFF_M, depth / 2), _min_frames(fps, MIN_SPAN_S))


def raised_spans(j: np.ndarray, side: str, fps: float) -> list[tuple[int, int]]:
    """The wrist above its shoulder for at least RAISED_MIN_S."""
    p = PREFIX[side]
    up = j[:, J[p + "wrist"], 1] > j[:, J[p + "shoulder"], 1]
    return spans(up, None, _min_frames(fps, RAISED_MIN_S))


def swings(x: np.ndarray, fps: float) -> int:
    """Side-to-side swings of a signal about its running mean over half a second (a 2 Hz wave
    swings four times a second): crossings from beyond +WAVE_SWING_M to beyond -WAVE_SWING_M."""
    k = _min_frames(fps, 0.5)
    mean = np.convolve(np.pad(x, (k // 2, k - 1 - k // 2), mode="edge"), np.ones(k) / k, mode="valid")
    d = x - mean
    state, count = 0, 0
    for v in d:
        s = 1 if v > WAVE_SWING_M else -1 if v < -WAVE_SWING_M else 0
        if s and s != state:
            count += state != 0
            state = s
    return count


def wave_spans(j: np.ndarray, side: str, fps: float) -> list[tuple[int, int]]:
    """Raised-hand spans in which the wrist swings side to side (relative to its shoulder, body frame)."""
    p = PREFIX[side]
    _, left = body_offsets(j, J[p + "wrist"], J[p + "shoulder"], fps)
    return [(a, b) for a, b in raised_spans(j, side, fps) if swings(left[a:b], fps) >= WAVE_SWINGS]


def arm_pose(j: np.ndarray, side: str, fps: float) -> dict[str, np.ndarray]:
    """(T,) bool per pose of one arm: `up` (wrist above the head), `sideways` / `forward` (wrist
    ARM_OUT_M out from the shoulder that way, near the shoulder's height), `lifted` (wrist no lower
    than 10 cm under the shoulder)."""
    p = PREFIX[side]
    wrist, shoulder = J[p + "wrist"], J[p + "shoulder"]
    fwd, left = body_offsets(j, wrist, shoulder, fps)
    outward = left if side == "left" else -left
    level = np.abs(j[:, wrist, 1] - j[:, shoulder, 1]) < ARM_LEVEL_M
    return {"up": j[:, wrist, 1] > j[:, J["head"], 1], "sideways": (outward > ARM_OUT_M) & level,
            "forward": (fwd > ARM_OUT_M) & level, "lifted": j[:, wrist, 1] > j[:, shoulder, 1] - 0.1}


def clap_spans(j: np.ndarray, fps: float) -> list[tuple[int, int]]:
    """The hands meet (wrists within CLAP_ON_M), above the pelvis."""
    gap = np.linalg.norm(j[:, J["L_wrist"]] - j[:, J["R_wrist"]], axis=-1)
    front = np.minimum(j[:, J["L_wrist"], 1], j[:, J["R_wrist"], 1]) > j[:, 0, 1]
    return spans((gap < CLAP_ON_M) & front, gap > CLAP_OFF_M, _min_frames(fps, MIN_SPAN_S))


def punch_spans(j: np.ndarray, side: str, fps: float) -> list[tuple[int, int]]:
    """A wrist thrown PUNCH_ON_M in front of the pelvis."""
    reach, _ = body_offsets(j, J[PREFIX[side] + "wrist"], 0, fps)
    return spans(reach > PUNCH_ON_M, reach < PUNCH_OFF_M, _min_frames(fps, MIN_SPAN_S))


def kick_frames(j: np.ndarray, side: str, fps: float) -> np.ndarray:
    """(T,) bool: the ankle KICK_HEIGHT_M above the ground and KICK_FORWARD_M in front of the pelvis."""
    ankle = FEET[side][0]
    fwd, _ = body_offsets(j, ankle, 0, fps)
    return (j[:, ankle, 1] - ground(j) > KICK_HEIGHT_M) & (fwd > KICK_FORWARD_M)


def bow_frames(j: np.ndarray, fps: float) -> np.ndarray:
    """(T,) bool: the head BOW_FORWARD_M in front of the pelvis while the pelvis stays up."""
    fwd, _ = body_offsets(j, J["head"], 0, fps)
    return (fwd > BOW_FORWARD_M) & (pelvis_drop(j) < DIP_OFF_M)


__all__ = [
    "SIDES",
    "J",
    "airborne_spans",
    "arm_pose",
    "body_offsets",
    "bow_frames",
    "clap_spans",
    "dip_spans",
    "facing",
    "foot_height",
    "gait",
    "ground",
    "heading_change",
    "hop_spans",
    "kick_frames",
    "moving_enough",
    "pelvis_drop",
    "punch_spans",
    "raised_spans",
    "span_mask",
    "spans",
    "start_frame_displacement",
    "swings",
    "turning",
    "wave_spans",
]
