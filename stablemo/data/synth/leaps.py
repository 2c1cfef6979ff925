"""Leaps: two-footed jumps (in place or forward), one-legged hops and a front kick."""

from __future__ import annotations

import numpy as np

from stablemo.data.synth import body
from stablemo.data.synth.action_helpers import (
    G,
    body_to_world,
    dir2,
    gaussian_smooth,
    hold_root,
    tile,
)
from stablemo.data.synth.body import LEFT, RIGHT, SIDE_SIGN
from stablemo.data.synth.gait import Plant, Swing, minjerk, smoothstep
from stablemo.data.synth.timeline import FPS, Timeline

# --- jumps and hops ----------------------------------------------------------------------------


def _jump_feet(tl: Timeline, sides, takeoff: float, land: float, forward: float, apex: float) -> None:
    for s in sides:
        cur = tl.current_plant(s)
        cur.end, cur.heel_off, cur.off_pitch = takeoff, 3.0, 0.75
        xz = cur.xz + dir2(tl.heading) * forward
        tl.plants[s].append(Plant(land, np.inf, xz, cur.yaw, slap=1.5,
                                  swing=Swing(clearance=apex + 0.06, land_pitch=-0.1)))


def build_jump(tl: Timeline, p: dict) -> None:
    """Two-footed jumps in place or forward: dip, push off, fly, land, absorb."""
    start = tl.t
    count, forward = p["count"], p.get("distance", 0.0)
    flight = p.get("flight", 0.42) * FPS
    apex = G * (flight / FPS) ** 2 / 8
    prep, absorb = 0.45 * FPS, 0.4 * FPS
    per = prep + flight + absorb
    n = int(np.ceil(count * per + 0.35 * FPS))
    sl = hold_root(tl, n)
    f = np.arange(n, dtype=float)
    y = np.full(n, body.STAND_HEIGHT)
    xz = np.tile(tl.pos, (n, 1))
    arms_up = np.zeros(n)
    arms_back = np.zeros(n)
    pitch = np.zeros(n)
    for i in range(count):
        t0 = tl.t + i * per
        takeoff, land = t0 + prep, t0 + prep + flight
        fl = f + tl.t
        crouch = smoothstep((fl - t0) / (0.6 * prep)) * (fl < takeoff - 0.25 * prep)
        push = smoothstep((fl - (takeoff - 0.25 * prep)) / (0.25 * prep)) * (fl < takeoff)
        y -= 0.16 * crouch * (1 - push)
        y += 0.05 * push
        tau = (fl - takeoff) / flight
        air = (tau > 0) & (tau < 1)
        y += np.where(air, 0.05 - 0.08 * tau + apex * 4 * tau * (1 - tau), 0.0)
        u = (fl - land) / absorb
        landing = (u >= 0) & (u <= 1)
        y -= np.where(landing, 0.14 * np.sin(np.pi * np.clip(u, 0, 1)) ** 1.0 + 0.03 * (1 - np.clip(u, 0, 1)), 0.0)
        if forward:
            xz += dir2(tl.heading) * forward * minjerk((fl - takeoff + 2) / (flight + 4))[:, None]
        arms_back += crouch * (1 - push)
        arms_up += np.clip(push + air + (1 - smoothstep(u)) * (u >= 0) * (u < 1), 0, 1)
        pitch += 0.35 * crouch * (1 - push) + 0.25 * np.where(landing, np.sin(np.pi * np.clip(u, 0, 1)), 0.0)
        _jump_feet(tl, (LEFT, RIGHT), takeoff, land, forward, apex)
    tl.root_y[sl] = y
    tl.set_root(sl, xz, np.full(n, tl.heading))
    tl.torso_pitch[sl] += pitch
    for s in (LEFT, RIGHT):
        sg = SIDE_SIGN[s]
        tl.blend_arm(s, sl, tile([sg * 0.15, -0.8, -0.55], n), tile([sg * 0.1, -0.9, -0.2], n),
                     np.clip(arms_back, 0, 1) * 0.9)
        tl.blend_arm(s, sl, tile([sg * 0.2, 0.45, 0.85], n), tile([sg * 0.1, 0.6, 0.8], n),
                     gaussian_smooth(np.clip(arms_up, 0, 1), 1.5) * 0.85)
    tl.t += n
    tl.add_part("jump_forward" if forward else "jump", p, start)


def build_hop(tl: Timeline, p: dict) -> None:
    """Hop on one leg: shift weight, raise the other foot behind, hop `count` times, put it down."""
    start = tl.t
    stance = LEFT if p["leg"] == "left" else RIGHT
    free = 1 - stance
    count = p["count"]
    flight = 0.3 * FPS
    per = 0.3 * FPS + flight
    shift, lift = 0.35 * FPS, 0.3 * FPS
    n = int(np.ceil(shift + lift + count * per + lift + shift + 0.2 * FPS))
    sl = hold_root(tl, n)
    f = np.arange(n, dtype=float) + tl.t
    t_lift = tl.t + shift
    t_hops = t_lift + lift
    t_down = t_hops + count * per
    t_end = t_down + lift
    # Pelvis over the stance foot while the other leg is up.
    over = smoothstep((f - tl.t) / shift) * (1 - smoothstep((f - t_end) / shift))
    foot_xz = tl.current_plant(stance).xz
    target = foot_xz + body_to_world(tl.heading, -SIDE_SIGN[stance] * 0.02, body.ANKLE_BACK)
    xz = tl.pos + (target - tl.pos) * 0.85 * over[:, None]
    tl.set_root(sl, xz, np.full(n, tl.heading))
    tl.torso_roll[sl] += SIDE_SIGN[stance] * -0.06 * over
    y = np.full(n, body.STAND_HEIGHT)
    apex = G * (flight / FPS) ** 2 / 8
    for i in range(count):
        t0 = t_hops + i * per
        takeoff, land = t0 + 0.15 * FPS, t0 + 0.15 * FPS + flight
        u = (f - t0) / (0.15 * FPS)
        y -= 0.08 * np.sin(np.pi / 2 * np.clip(u, 0, 1)) * (f < takeoff)
        tau = (f - takeoff) / flight
        air = (tau > 0) & (tau < 1)
        y += np.where(air, -0.03 + apex * 4 * tau * (1 - tau), 0.0)
        v = (f - land) / (0.15 * FPS)
        y -= np.where((v >= 0) & (v <= 1), 0.08 * np.sin(np.pi / 2 * (1 - np.clip(v, 0, 1)) + 0.0) * (1 - v), 0.0)
        cur = tl.current_plant(stance)
        cur.end, cur.heel_off, cur.off_pitch = takeoff, 2.0, 0.6
        tl.plants[stance].append(Plant(land, np.inf, cur.xz.copy(), cur.yaw, slap=1.0,
                                       swing=Swing(clearance=apex + 0.03, land_pitch=-0.05)))
    tl.root_y[sl] = y
    # The free foot: an explicit path to a raised pose behind the body and back to its spot.
    plant = tl.current_plant(free)
    base = plant.xz.copy()
    heading = tl.heading
    root_xz, root_y = tl.root_xz, tl.root_y
    flat_y = body.ANKLE_FLAT_HEIGHT[free]

    def path(frames):
        idx = np.clip(frames.astype(int), 0, len(root_y) - 1)
        hip = root_xz[idx] + body_to_world(heading, SIDE_SIGN[free] * 0.08, 0.0)
        # The free leg pumps with the hops (foot swings forward and back under the knee).
        phase = 2 * np.pi * (frames - t_hops) / per
        pump = np.sin(phase) * smoothstep((frames - t_hops) / 4) * (1 - smoothstep((frames - t_down + 4) / 4))
        raised_xz = hip + body_to_world(heading, 0.0, -0.26 + 0.12 * pump)
        raised_y = root_y[idx] - 0.55 + 0.05 * pump
        w = smoothstep((frames - t_lift) / lift) * (1 - smoothstep((frames - t_down) / lift))
        xz_ = base + (raised_xz - base) * w[:, None]
        y_ = flat_y + (raised_y - flat_y) * w
        ankle = np.stack([xz_[:, 0], y_, xz_[:, 1]], -1)
        return ankle, np.full(len(frames), plant.yaw), body.FOOT_PITCH + 0.7 * w

    plant.end = t_lift
    tl.plants[free].append(Plant(t_end, np.inf, base, plant.yaw, swing=Swing(path=path)))
    for s in (LEFT, RIGHT):
        sg = SIDE_SIGN[s]
        tl.blend_arm(s, sl, tile([sg * 0.75, -0.55, 0.15], n), tile([sg * 0.5, -0.3, 0.8], n), over * 0.8)
    tl.t += n
    tl.add_part("hop", p, start)


def build_kick(tl: Timeline, p: dict) -> None:
    """Front kick: weight onto the support leg, wind up, kick forward and high, step back down."""
    start = tl.t
    kick = LEFT if p["leg"] == "left" else RIGHT
    support = 1 - kick
    shift, wind, strike, ret = 0.4 * FPS, 0.45 * FPS, 0.25 * FPS, 0.65 * FPS
    n = int(np.ceil(shift + wind + strike + ret + shift + 0.2 * FPS))
    sl = hold_root(tl, n)
    f = np.arange(n, dtype=float) + tl.t
    t_up = tl.t + shift
    t_strike = t_up + wind
    t_back = t_strike + strike
    t_down = t_back + ret
    over = smoothstep((f - tl.t) / shift) * (1 - smoothstep((f - t_down) / shift))
    foot_xz = tl.current_plant(support).xz
    target = foot_xz + body_to_world(tl.heading, 0.0, body.ANKLE_BACK)
    xz = tl.pos + (target - tl.pos) * 0.7 * over[:, None]
    tl.set_root(sl, xz, np.full(n, tl.heading))
    tl.root_y[sl] -= 0.03 * over
    tl.torso_pitch[sl] += -0.12 * smoothstep((f - t_up) / wind) * (1 - smoothstep((f - t_back) / ret))
    plant = tl.current_plant(kick)
    base, heading = plant.xz.copy(), tl.heading
    flat_y = body.ANKLE_FLAT_HEIGHT[kick]
    height = p.get("height", 0.5)
    # The strike puts the ankle at (almost) full leg reach from the hip, forward and up.
    hip_fwd = float(np.dot(xz[int(t_strike - tl.t)] - base, dir2(heading)))
    hip_y = body.STAND_HEIGHT - 0.03 - 0.086
    reach = 0.96 * body.LEG_REACH[kick]
    strike_fwd = hip_fwd + np.sqrt(max(reach**2 - (hip_y - height) ** 2, 0.04))
    # Keyframes in body frame: (time, forward offset from start spot, height, toe pitch)
    # Lift in place, wind back, strike, return above the spot, set down vertically (so the toe
    # never slides while it is near the floor).
    p0 = body.FOOT_PITCH
    hold = 3.0  # frames at full extension
    keys_t = np.array([t_up, t_up + 4, t_strike, t_back, t_back + hold, t_down - 4, t_down])
    keys_fwd = np.array([0.0, 0.0, -0.2, strike_fwd, strike_fwd - 0.02, 0.0, 0.0])
    keys_y = np.array([flat_y, flat_y + 0.08, flat_y + 0.22, height, height - 0.01, flat_y + 0.07, flat_y])
    keys_pitch = np.array([p0, p0 + 0.3, p0 + 0.8, p0 + 0.3, p0 + 0.3, p0, p0])

    def path(frames):
        seg = np.clip(np.searchsorted(keys_t, frames) - 1, 0, len(keys_t) - 2)
        u = minjerk((frames - keys_t[seg]) / (keys_t[seg + 1] - keys_t[seg]))
        fwd = keys_fwd[seg] + (keys_fwd[seg + 1] - keys_fwd[seg]) * u
        y = keys_y[seg] + (keys_y[seg + 1] - keys_y[seg]) * u
        pt = keys_pitch[seg] + (keys_pitch[seg + 1] - keys_pitch[seg]) * u
        xz_ = base + body_to_world(heading, 0.0, fwd)
        return np.stack([xz_[:, 0], y, xz_[:, 1]], -1), np.full(len(frames), plant.yaw), pt

    plant.end = t_up
    tl.plants[kick].append(Plant(t_down, np.inf, base, plant.yaw, swing=Swing(path=path)))
    for s in (LEFT, RIGHT):
        sg = SIDE_SIGN[s]
        tl.blend_arm(s, sl, tile([sg * 0.6, -0.7, 0.2 if s == kick else -0.1], n),
                     tile([sg * 0.3, -0.5, 0.7], n), over * 0.8)
    tl.t += n
    tl.add_part("kick", p, start)
