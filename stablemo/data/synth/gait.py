"""Footsteps: planted feet that stay exactly put, and swings between them.

A foot's life is a list of `Plant`s. During a plant the toe joint is fixed on the floor: the foot
lands heel first (toe raised, rotating about the ankle), lies flat, then peels off rotating about
the toe (heel-off). Between two plants the foot swings on a minimum-jerk path with a lifted
arc, or along an explicit path (kicks, a raised leg while hopping). Times are in frames (floats).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from stablemo.data.synth.body import ANKLE_FLAT_HEIGHT, FOOT_LENGTH, FOOT_PITCH

CONTACT_TOL = 0.01  # metres
SWING_DELAY = (0.14, 0.09)  # fractions of a swing spent lifting / setting down the foot in place
BUMP_SKEW = 1.0  # < 1: the foot rises quickly after lift-off and comes down gently


def smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def minjerk(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x**3 * (10 - 15 * x + 6 * x * x)


def wrap_angle(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


@dataclass
class Swing:
    """How a foot travels into the plant that owns this swing."""

    clearance: float = 0.10  # peak extra ankle height (m)
    land_pitch: float = -0.26  # pitch offset at touchdown (negative: toe up, heel strike)
    # Explicit path for frames strictly inside the swing: f(frames) -> (ankle (n,3), yaw (n,), pitch (n,))
    path: Callable | None = None


@dataclass
class Plant:
    start: float  # touchdown frame
    end: float  # lift-off frame (np.inf: stays down)
    xz: np.ndarray  # ankle position on the floor (2,)
    yaw: float  # foot heading
    heel_off: float = 0.0  # frames spent rotating about the toe before lift-off
    off_pitch: float = 0.0  # extra pitch reached at lift-off (toes pointing down)
    slap: float = 0.0  # frames from heel strike to a flat foot
    swing: Swing | None = None  # how the foot got here (None for the initial plant)


def flat_ankle(plant: Plant, side: int) -> np.ndarray:
    return np.array([plant.xz[0], ANKLE_FLAT_HEIGHT[side], plant.xz[1]])


def foot_dir(yaw, pitch) -> np.ndarray:
    yaw, pitch = np.asarray(yaw, float), np.asarray(pitch, float)
    return np.stack([np.sin(yaw) * np.cos(pitch), -np.sin(pitch), np.cos(yaw) * np.cos(pitch)], -1)


def toe_of(ankle, yaw, pitch, side: int) -> np.ndarray:
    return ankle + FOOT_LENGTH[side] * foot_dir(yaw, pitch)


def _liftoff_state(plant: Plant, side: int):
    """Ankle, yaw, pitch at the lift-off moment (after the heel-off pivot)."""
    pitch = FOOT_PITCH + plant.off_pitch
    toe = toe_of(flat_ankle(plant, side), plant.yaw, FOOT_PITCH, side)
    ankle = toe - FOOT_LENGTH[side] * foot_dir(plant.yaw, pitch)
    return ankle, plant.yaw, pitch


def render_foot(plants: list[Plant], side: int, T: int):
    """-> ankle (T,3), yaw (T,), pitch (T,), contact (T,2) bool [heel/ankle, toe]."""
    frames = np.arange(T, dtype=float)
    ankle = np.zeros((T, 3))
    yaw = np.zeros(T)
    pitch = np.zeros(T)
    contact = np.zeros((T, 2), dtype=bool)
    assigned = np.zeros(T, dtype=bool)
    for k, pl in enumerate(plants):
        flat = flat_ankle(pl, side)
        toe = toe_of(flat, pl.yaw, FOOT_PITCH, side)
        m = (frames >= pl.start) & (frames <= pl.end)
        if m.any():
            f = frames[m]
            p = np.full(len(f), FOOT_PITCH)
            heel = np.ones(len(f), dtype=bool)
            toe_down = np.ones(len(f), dtype=bool)
            if pl.slap > 0 and pl.swing is not None:
                u = (f - pl.start) / pl.slap
                landing = u < 1
                p = np.where(landing, FOOT_PITCH + pl.swing.land_pitch * (1 - smoothstep(u)), p)
                toe_down &= ~landing | (p >= FOOT_PITCH - 1e-9)
            a = np.tile(flat, (len(f), 1))
            if pl.heel_off > 0 and np.isfinite(pl.end):
                u = (f - (pl.end - pl.heel_off)) / pl.heel_off
                peel = u > 0
                pp = FOOT_PITCH + pl.off_pitch * smoothstep(u)
                a_peel = toe - FOOT_LENGTH[side] * foot_dir(np.full(len(f), pl.yaw), pp)
                a = np.where(peel[:, None], a_peel, a)
                p = np.where(peel, pp, p)
                heel &= ~peel
            ankle[m], yaw[m], pitch[m] = a, pl.yaw, p
            # A planted foot part within CONTACT_TOL of the floor counts as down: the first moments
            # of a heel-off (heel) and the last moment of a heel-first landing (toe).
            heel |= a[:, 1] - flat[1] < CONTACT_TOL
            toe_down |= a[:, 1] - FOOT_LENGTH[side] * np.sin(p) < CONTACT_TOL
            contact[m, 0], contact[m, 1] = heel, toe_down
            assigned |= m
        if k + 1 < len(plants):
            nxt = plants[k + 1]
            m = (frames > pl.end) & (frames < nxt.start)
            if not m.any():
                continue
            f = frames[m]
            sw = nxt.swing or Swing()
            if sw.path is not None:
                a, y, p = sw.path(f)
            else:
                a0, y0, p0 = _liftoff_state(pl, side)
                a1 = flat_ankle(nxt, side)
                p1 = FOOT_PITCH + sw.land_pitch
                dur = nxt.start - pl.end
                tau = (f - pl.end) / dur
                # Lift/set-down phases last at least about a frame, also in quick swings.
                d0, d1 = max(SWING_DELAY[0], min(1.3 / dur, 0.25)), max(SWING_DELAY[1], min(0.8 / dur, 0.2))
                # The foot rises before it travels and stops travelling before it comes down.
                s = smoothstep((tau - d0) / (1 - d0 - d1))[:, None]
                a = a0 + (a1 - a0) * s
                a[:, 1] = a0[1] + (a1[1] - a0[1]) * smoothstep(tau) + sw.clearance * np.sin(np.pi * tau**BUMP_SKEW)
                # The foot flattens as it rises, lifting the toe clear of the floor.
                p = p0 + (p1 - p0) * smoothstep(tau / 0.8)
                y = y0 + wrap_angle(nxt.yaw - y0) * smoothstep((tau - d0) / (1 - d0 - d1))
            ankle[m], yaw[m], pitch[m] = a, y, p
            assigned |= m
    if not assigned.all():
        raise ValueError("foot plants do not cover the whole motion")
    # Nothing goes through the floor: lift a swinging foot whose toe would dip below it.
    toe_y = ankle[:, 1] - FOOT_LENGTH[side] * np.sin(pitch)
    ankle[:, 1] += np.maximum(0.0, -toe_y) * ~contact[:, 1]
    return ankle, yaw, pitch, contact
