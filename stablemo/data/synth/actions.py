"""Procedural actions. Each `build_<name>(tl, params)` appends one action at the timeline cursor.

Every action starts and ends standing with both feet planted, and writes a `Part` recording its
caption parameters (speed, direction, count, side, ...). `sample_params(name, rng)` draws them.
"""

from __future__ import annotations

import numpy as np

from stablemo.data.synth import body
from stablemo.data.synth.body import LEFT, RIGHT, SIDE_SIGN
from stablemo.data.synth.gait import Plant, Swing, minjerk, smoothstep
from stablemo.data.synth.timeline import FPS, Timeline

G = 9.81


def _dir2(theta):
    """World xz direction of a body heading (yaw)."""
    theta = np.asarray(theta, float)
    return np.stack([np.sin(theta), np.cos(theta)], -1)


def _body_to_world(yaw, x, z):
    """Body-frame (left x, forward z) offsets -> world xz."""
    yaw = np.asarray(yaw, float)
    left = np.stack([np.cos(yaw), -np.sin(yaw)], -1)
    return np.asarray(x)[..., None] * left + np.asarray(z)[..., None] * _dir2(yaw)


def envelope(n: int, rise: float, fall: float) -> np.ndarray:
    """(n,) weight rising over `rise` frames, holding 1, falling over the last `fall` frames."""
    f = np.arange(n, dtype=float)
    return smoothstep(f / max(rise, 1e-6)) * smoothstep((n - 1 - f) / max(fall, 1e-6))


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _tile(v, n):
    return np.tile(_unit(v), (n, 1))


# ---------------------------------------------------------------------------------------------
# Stepping: foot placements follow the pelvis (each foot lands where the hip will be at the
# middle of its stance), so one rule serves walking, running, side-stepping, backing up,
# circling and turning on the spot.
# ---------------------------------------------------------------------------------------------


def _place_steps(tl: Timeline, lifts: list[list[float]], swing_frames: float, rest_time: float,
                 half_width: float, gait: dict) -> float:
    """Schedule steps for both feet from lift-off times; returns the last touchdown frame."""
    for s in (LEFT, RIGHT):
        if not lifts[s]:
            continue
        lands = [t + swing_frames for t in lifts[s]]
        cur = tl.current_plant(s)
        first_new = len(tl.plants[s])
        cur.end, cur.heel_off, cur.off_pitch = lifts[s][0], gait["heel_off"], gait["off_pitch"]
        for k, land in enumerate(lands):
            nxt_lift = lifts[s][k + 1] if k + 1 < len(lifts[s]) else None
            mid = rest_time if nxt_lift is None else min(land + gait.get("under", 0.5) * (nxt_lift - land), rest_time)
            xz, yaw = tl.root_at(np.array([mid]))
            # The closing steps bring the feet back to a normal standing width.
            width = body.STANCE_HALF_WIDTH if nxt_lift is None else half_width
            foot_xz = xz[0] + _body_to_world(yaw[0], SIDE_SIGN[s] * width, -body.ANKLE_BACK)
            tl.plants[s].append(Plant(
                start=land, end=np.inf if nxt_lift is None else nxt_lift, xz=foot_xz,
                yaw=float(yaw[0] + SIDE_SIGN[s] * gait.get("toe_out", 0.06)),
                heel_off=gait["heel_off"] if nxt_lift is not None else 0.0,
                off_pitch=gait["off_pitch"] if nxt_lift is not None else 0.0,
                slap=gait["slap"], swing=Swing(clearance=gait["clearance"], land_pitch=gait["land_pitch"])))
        # A closing step that would barely move the foot is not taken.
        plants = tl.plants[s]
        if len(plants) - first_new >= 1:
            prev, last = plants[-2], plants[-1]
            if np.linalg.norm(last.xz - prev.xz) < 0.06 and abs(last.yaw - prev.yaw) < 0.15:
                plants.pop()
                prev.end, prev.heel_off, prev.off_pitch = np.inf, 0.0, 0.0
    return max([tl.t] + [tl.plants[s][-1].start for s in (LEFT, RIGHT)])


GAITS = {
    # speed m/s, cadence steps/s, stance fraction of the cycle, ...
    "walk": dict(stance=0.56, under=0.45, heel_off=0.08, off_pitch=1.0, slap=0.05, land_pitch=-0.22,
                 clearance=0.10, lean=0.05, drop=0.0, arm=0.28, flex=0.15),
    "walk_backward": dict(cadence=1.7, stance=0.64, heel_off=0.10, off_pitch=0.5, slap=0.06,
                          land_pitch=0.0, clearance=0.12, lean=-0.04, drop=0.0, arm=0.2, flex=0.2),
    "walk_sideways": dict(cadence=1.6, stance=0.68, heel_off=0.08, off_pitch=0.3, slap=0.05,
                          land_pitch=-0.1, clearance=0.08, lean=0.0, drop=0.01, arm=0.0, flex=0.15),
    "jog": dict(cadence=2.7, stance=0.38, under=0.42, heel_off=0.08, off_pitch=0.6, slap=0.06, land_pitch=-0.15,
                clearance=0.14, lean=0.12, drop=0.04, arm=0.55, flex=1.1),
    "run": dict(cadence=3.1, stance=0.30, under=0.42, heel_off=0.10, off_pitch=0.7, slap=0.05, land_pitch=-0.1,
                clearance=0.18, lean=0.2, drop=0.06, arm=0.7, flex=1.35),
    "circle": dict(stance=0.56, under=0.45, heel_off=0.08, off_pitch=1.0, slap=0.05, land_pitch=-0.22,
                   clearance=0.10, lean=0.05, drop=0.0, arm=0.3, flex=0.2),
    "turn": dict(heel_off=1.5, off_pitch=0.45, slap=1.0, land_pitch=-0.1, clearance=0.11, toe_out=0.06),
}


def _locomote(tl: Timeline, params: dict, gait_name: str, direction: float, curvature: float = 0.0,
              distance: float | None = None) -> None:
    """Move the pelvis at speed v in `direction` (radians from the heading; + = left) for
    params['duration'] seconds of travel (or `distance` metres), stepping all the way."""
    g = GAITS[gait_name]
    v = params["speed"]
    t_acc = t_dec = (0.8 if v < 2 else 1.0) * FPS
    # Cadence grows with speed; steps longer than 0.72 m would overstretch this skeleton's legs.
    cadence = g["cadence"] if "cadence" in g else float(np.clip(max(1.15 + 0.55 * v, v / 0.72), 1.4, 2.6))
    cycle = 2.0 / cadence * FPS  # frames per stride (two steps)
    if distance is not None:
        moving = distance / (v / FPS) + 0.5 * (t_acc + t_dec)
    else:
        moving = params["duration"] * FPS
    sub = 8
    tt = np.arange(int(np.ceil(moving * sub)) + 1) / sub
    vel = v / FPS * smoothstep(tt / t_acc) * smoothstep((moving - tt) / t_dec)  # m/frame
    s = np.concatenate([[0.0], np.cumsum(0.5 * (vel[1:] + vel[:-1]) / sub)])
    heading = tl.heading + curvature * s
    ds = 0.5 * (vel[1:] + vel[:-1]) / sub  # metres per sub-step
    step_xz = _dir2(0.5 * (heading[1:] + heading[:-1]) + direction) * ds[:, None]
    xz = tl.pos + np.concatenate([[[0.0, 0.0]], np.cumsum(step_xz, 0)])

    sw = (1.0 - g["stance"]) * cycle
    first = params.get("first_foot", LEFT)
    rest_time = tl.t + moving
    lifts = [[], []]
    for s_idx, phase in ((first, 0.0), (1 - first, 0.5)):
        t_lift = tl.t + 1.0 + phase * cycle
        lifts[s_idx].append(t_lift)
        # Keep stepping until this foot's touchdown is close to the end of travel; its last
        # plant then goes beside the resting pelvis.
        while t_lift + sw < rest_time - 0.25 * cycle:
            t_lift += cycle
            lifts[s_idx].append(t_lift)
    last_land = max(l[-1] for l in lifts) + sw
    n = int(np.ceil(max(last_land, tl.t + moving) - tl.t)) + int(0.3 * FPS)
    sl = tl.frames(n)
    f = np.arange(n, dtype=float)
    root_xz = np.stack([np.interp(f, tt, xz[:, i]) for i in (0, 1)], -1)
    yaw = np.interp(f, tt, heading)
    tl.set_root(sl, root_xz, yaw)

    # Gait intensity follows the speed profile: lean, lowered pelvis and arm swing ramp in/out.
    ramp = np.interp(f, tt, vel) / (v / FPS)
    tl.torso_pitch[sl] += g["lean"] * ramp
    tl.root_y[sl] -= g["drop"] * ramp
    tl.arm_swing[sl] += g["arm"] * ramp[:, None]
    tl.elbow_flex[sl] += g["flex"] * ramp
    if curvature:
        # Lean into the curve.
        tl.torso_roll[sl] += -np.sign(curvature) * min(0.12, v * v * abs(curvature) / G) * ramp

    half_width = body.STANCE_HALF_WIDTH + abs(np.sin(direction)) * v * (cycle / FPS) / 4
    gp = {k: g[k] for k in ("off_pitch", "land_pitch", "clearance")}
    # The ankle passes under the pelvis before mid-stance: the foot rolls heel to toe, and the
    # trailing ankle rises on the toe, reaching further back than a flat foot could.
    gp["under"] = g.get("under", 0.5)
    gp["heel_off"] = g["heel_off"] * cycle
    gp["slap"] = g["slap"] * cycle
    last_land = _place_steps(tl, lifts, sw, rest_time, half_width, gp)
    # The body is still once travel has ended and the last foot is down (the frames reserved
    # above keep holding the final root).
    tl.t += min(n, int(np.ceil(max(last_land, rest_time) - tl.t)) + int(0.25 * FPS))


def build_walk(tl: Timeline, p: dict) -> None:
    start = tl.t
    _locomote(tl, p, "walk", 0.0)
    if p.get("waving"):  # "walks forward while waving": the gesture replaces that arm's swing
        sl = slice(start, tl.t)
        env = envelope(tl.t - start, 0.5 * FPS, 0.5 * FPS)
        _wave_arms(tl, sl, p["waving"], env)
        for s in _arm_sides(p["waving"]):
            tl.arm_swing[sl, s] *= 1 - env
    tl.add_part("walk", p, start)


def build_walk_backward(tl: Timeline, p: dict) -> None:
    start = tl.t
    _locomote(tl, p, "walk_backward", np.pi)
    tl.add_part("walk_backward", p, start)


def build_walk_sideways(tl: Timeline, p: dict) -> None:
    start = tl.t
    side = LEFT if p["direction"] == "left" else RIGHT
    _locomote(tl, dict(p, first_foot=side), "walk_sideways", SIDE_SIGN[side] * np.pi / 2)
    tl.add_part("walk_sideways", p, start)


def build_jog(tl: Timeline, p: dict) -> None:
    start = tl.t
    _locomote(tl, p, "jog", 0.0)
    tl.add_part("jog", p, start)


def build_run(tl: Timeline, p: dict) -> None:
    start = tl.t
    _locomote(tl, p, "run", 0.0)
    tl.add_part("run", p, start)


def build_circle(tl: Timeline, p: dict) -> None:
    start = tl.t
    sign = 1.0 if p["direction"] == "counterclockwise" else -1.0
    first = LEFT if sign > 0 else RIGHT
    _locomote(tl, dict(p, first_foot=first), "circle", 0.0, curvature=sign / p["radius"],
              distance=2 * np.pi * p["radius"])
    tl.add_part("circle", p, start)


def build_turn(tl: Timeline, p: dict) -> None:
    """Turn on the spot by stepping the feet around."""
    start = tl.t
    sign = 1.0 if p["direction"] == "left" else -1.0
    angle = np.deg2rad(p["angle"])
    duration = (0.55 + angle / np.deg2rad(p.get("rate", 150.0))) * FPS
    n_steps = int(np.ceil(angle / np.deg2rad(50.0))) + 1
    sw = 0.22 * FPS
    n = int(np.ceil(duration + 0.5 * sw)) + int(0.3 * FPS)
    sl = tl.frames(n)
    f = np.arange(n, dtype=float)
    yaw = tl.heading + sign * angle * minjerk((f - 2) / (duration - 2))
    tl.set_root(sl, np.tile(tl.pos, (n, 1)), yaw)
    lead = LEFT if sign > 0 else RIGHT
    lifts = [[], []]
    gap = (duration - sw) / max(n_steps - 1, 1)
    for i in range(n_steps):
        lifts[lead if i % 2 == 0 else 1 - lead].append(tl.t + 1.0 + i * gap)
    _place_steps(tl, lifts, sw, tl.t + duration, body.STANCE_HALF_WIDTH, GAITS["turn"])
    tl.arm_swing[sl] += 0.08 * envelope(n, 4, 4)[:, None]
    tl.t += n
    tl.add_part("turn", p, start)


def build_stand(tl: Timeline, p: dict) -> None:
    """Stand still, breathing, with a slight weight shift."""
    start = tl.t
    n = int(p["duration"] * FPS)
    sl = tl.frames(n)
    f = np.arange(n, dtype=float)
    phase = p.get("phase", 0.0)
    sway = 0.015 * np.sin(2 * np.pi * f / (2.5 * FPS) + phase) * envelope(n, 10, 10)
    xz = tl.pos + _body_to_world(tl.heading, sway, 0.0 * sway)
    tl.set_root(sl, xz, np.full(n, tl.heading))
    tl.torso_roll[sl] += -0.4 * sway
    tl.head_pitch[sl] += 0.05 * np.sin(2 * np.pi * f / (3.1 * FPS) + phase) * envelope(n, 10, 10)
    tl.t += n
    tl.add_part("stand", p, start)


def _hold_root(tl: Timeline, n: int) -> slice:
    sl = tl.frames(n)
    tl.set_root(sl, np.tile(tl.pos, (n, 1)), np.full(n, tl.heading))
    return sl


# --- jumps and hops ----------------------------------------------------------------------------


def _jump_feet(tl: Timeline, sides, takeoff: float, land: float, forward: float, apex: float) -> None:
    for s in sides:
        cur = tl.current_plant(s)
        cur.end, cur.heel_off, cur.off_pitch = takeoff, 3.0, 0.75
        xz = cur.xz + _dir2(tl.heading) * forward
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
    sl = _hold_root(tl, n)
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
            xz += _dir2(tl.heading) * forward * minjerk((fl - takeoff + 2) / (flight + 4))[:, None]
        arms_back += crouch * (1 - push)
        arms_up += np.clip(push + air + (1 - smoothstep(u)) * (u >= 0) * (u < 1), 0, 1)
        pitch += 0.35 * crouch * (1 - push) + 0.25 * np.where(landing, np.sin(np.pi * np.clip(u, 0, 1)), 0.0)
        _jump_feet(tl, (LEFT, RIGHT), takeoff, land, forward, apex)
    tl.root_y[sl] = y
    tl.set_root(sl, xz, np.full(n, tl.heading))
    tl.torso_pitch[sl] += pitch
    for s in (LEFT, RIGHT):
        sg = SIDE_SIGN[s]
        tl.blend_arm(s, sl, _tile([sg * 0.15, -0.8, -0.55], n), _tile([sg * 0.1, -0.9, -0.2], n),
                     np.clip(arms_back, 0, 1) * 0.9)
        tl.blend_arm(s, sl, _tile([sg * 0.2, 0.45, 0.85], n), _tile([sg * 0.1, 0.6, 0.8], n),
                     gaussian_smooth(np.clip(arms_up, 0, 1), 1.5) * 0.85)
    tl.t += n
    tl.add_part("jump_forward" if forward else "jump", p, start)


def gaussian_smooth(x, sigma):
    from scipy.ndimage import gaussian_filter1d
    return gaussian_filter1d(x, sigma, mode="nearest")


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
    sl = _hold_root(tl, n)
    f = np.arange(n, dtype=float) + tl.t
    t_lift = tl.t + shift
    t_hops = t_lift + lift
    t_down = t_hops + count * per
    t_end = t_down + lift
    # Pelvis over the stance foot while the other leg is up.
    over = smoothstep((f - tl.t) / shift) * (1 - smoothstep((f - t_end) / shift))
    foot_xz = tl.current_plant(stance).xz
    target = foot_xz + _body_to_world(tl.heading, -SIDE_SIGN[stance] * 0.02, body.ANKLE_BACK)
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
        hip = root_xz[idx] + _body_to_world(heading, SIDE_SIGN[free] * 0.08, 0.0)
        # The free leg pumps with the hops (foot swings forward and back under the knee).
        phase = 2 * np.pi * (frames - t_hops) / per
        pump = np.sin(phase) * smoothstep((frames - t_hops) / 4) * (1 - smoothstep((frames - t_down + 4) / 4))
        raised_xz = hip + _body_to_world(heading, 0.0, -0.26 + 0.12 * pump)
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
        tl.blend_arm(s, sl, _tile([sg * 0.75, -0.55, 0.15], n), _tile([sg * 0.5, -0.3, 0.8], n), over * 0.8)
    tl.t += n
    tl.add_part("hop", p, start)


def build_kick(tl: Timeline, p: dict) -> None:
    """Front kick: weight onto the support leg, wind up, kick forward and high, step back down."""
    start = tl.t
    kick = LEFT if p["leg"] == "left" else RIGHT
    support = 1 - kick
    shift, wind, strike, ret = 0.4 * FPS, 0.45 * FPS, 0.25 * FPS, 0.65 * FPS
    n = int(np.ceil(shift + wind + strike + ret + shift + 0.2 * FPS))
    sl = _hold_root(tl, n)
    f = np.arange(n, dtype=float) + tl.t
    t_up = tl.t + shift
    t_strike = t_up + wind
    t_back = t_strike + strike
    t_down = t_back + ret
    over = smoothstep((f - tl.t) / shift) * (1 - smoothstep((f - t_down) / shift))
    foot_xz = tl.current_plant(support).xz
    target = foot_xz + _body_to_world(tl.heading, 0.0, body.ANKLE_BACK)
    xz = tl.pos + (target - tl.pos) * 0.7 * over[:, None]
    tl.set_root(sl, xz, np.full(n, tl.heading))
    tl.root_y[sl] -= 0.03 * over
    tl.torso_pitch[sl] += -0.12 * smoothstep((f - t_up) / wind) * (1 - smoothstep((f - t_back) / ret))
    plant = tl.current_plant(kick)
    base, heading = plant.xz.copy(), tl.heading
    flat_y = body.ANKLE_FLAT_HEIGHT[kick]
    height = p.get("height", 0.5)
    # The strike puts the ankle at (almost) full leg reach from the hip, forward and up.
    hip_fwd = float(np.dot(xz[int(t_strike - tl.t)] - base, _dir2(heading)))
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
        xz_ = base + _body_to_world(heading, 0.0, fwd)
        return np.stack([xz_[:, 0], y, xz_[:, 1]], -1), np.full(len(frames), plant.yaw), pt

    plant.end = t_up
    tl.plants[kick].append(Plant(t_down, np.inf, base, plant.yaw, swing=Swing(path=path)))
    for s in (LEFT, RIGHT):
        sg = SIDE_SIGN[s]
        tl.blend_arm(s, sl, _tile([sg * 0.6, -0.7, 0.2 if s == kick else -0.1], n),
                     _tile([sg * 0.3, -0.5, 0.7], n), over * 0.8)
    tl.t += n
    tl.add_part("kick", p, start)


# --- lowering the body ---------------------------------------------------------------------------


def build_squat(tl: Timeline, p: dict) -> None:
    start = tl.t
    count, depth = p["count"], p.get("depth", 0.36)
    per = p.get("period", 1.7) * FPS
    n = int(np.ceil(count * per + 0.5 * FPS))
    sl = _hold_root(tl, n)
    f = np.arange(n, dtype=float)
    down = np.zeros(n)
    for i in range(count):
        u = (f - 4 - i * per) / per
        down += np.where((u >= 0) & (u <= 1), np.sin(np.pi * np.clip(u, 0, 1)) ** 2, 0.0)
    _lower(tl, sl, down, depth, back=0.14, lean=0.55)
    arms = smoothstep(gaussian_smooth(down, 2.0) * 1.6)
    for s in (LEFT, RIGHT):
        sg = SIDE_SIGN[s]
        tl.blend_arm(s, sl, _tile([sg * 0.12, 0.0, 1.0], n), _tile([sg * 0.08, 0.05, 1.0], n), arms)
    tl.t += n
    tl.add_part("squat", p, start)


def build_crouch(tl: Timeline, p: dict) -> None:
    start = tl.t
    hold = p.get("hold", 1.2) * FPS
    go = 0.8 * FPS
    n = int(np.ceil(2 * go + hold + 0.4 * FPS))
    sl = _hold_root(tl, n)
    f = np.arange(n, dtype=float)
    down = smoothstep((f - 2) / go) * (1 - smoothstep((f - 2 - go - hold) / go))
    _lower(tl, sl, down, p.get("depth", 0.42), back=0.12, lean=0.7)
    tl.head_pitch[sl] += -0.3 * down
    for s in (LEFT, RIGHT):
        sg = SIDE_SIGN[s]
        tl.blend_arm(s, sl, _tile([sg * 0.1, -0.55, 0.85], n), _tile([sg * 0.02, -0.75, 0.6], n), down)
    tl.t += n
    tl.add_part("crouch", p, start)


def _lower(tl: Timeline, sl: slice, down: np.ndarray, depth: float, back: float, lean: float) -> None:
    """Bend the knees: pelvis down and back, chest forward, knees out over the toes."""
    n = len(down)
    tl.root_y[sl] -= depth * down
    xz = tl.root_xz[sl] + _body_to_world(np.full(n, tl.heading), 0.0, -back * down)
    tl.set_root(sl, xz, tl.yaw[sl].copy())
    tl.torso_pitch[sl] += lean * down
    tl.knee_out[sl] += 0.35 * down


def build_bow(tl: Timeline, p: dict) -> None:
    start = tl.t
    angle = np.deg2rad(p.get("angle", 50.0))
    go, hold = 0.7 * FPS, p.get("hold", 0.6) * FPS
    n = int(np.ceil(2 * go + hold + 0.4 * FPS))
    sl = _hold_root(tl, n)
    f = np.arange(n, dtype=float)
    w = smoothstep((f - 2) / go) * (1 - smoothstep((f - 2 - go - hold) / go))
    tl.torso_pitch[sl] += angle * w
    tl.head_pitch[sl] += 0.25 * w
    xz = tl.root_xz[sl] + _body_to_world(np.full(n, tl.heading), 0.0, -0.09 * w * angle)
    tl.set_root(sl, xz, tl.yaw[sl].copy())
    tl.root_y[sl] -= 0.02 * w
    tl.t += n
    tl.add_part("bow", p, start)


# --- arm gestures -----------------------------------------------------------------------------


def _arm_sides(which: str):
    return {"left": (LEFT,), "right": (RIGHT,), "both": (LEFT, RIGHT)}[which]


def build_wave(tl: Timeline, p: dict) -> None:
    start = tl.t
    n = int(p.get("duration", 2.4) * FPS)
    sl = _hold_root(tl, n)
    env = envelope(n, 0.45 * FPS, 0.45 * FPS)
    _wave_arms(tl, sl, p["hand"], env)
    if p["hand"] != "both":
        tl.torso_roll[sl] += SIDE_SIGN[_arm_sides(p["hand"])[0]] * 0.04 * env
    tl.t += n
    tl.add_part("wave", p, start)


def _wave_arms(tl: Timeline, sl: slice, hand: str, env: np.ndarray) -> None:
    """Raise the hand(s) and swing the forearm side to side at 2 Hz, with weight env (n,)."""
    n = len(env)
    f = np.arange(n, dtype=float)
    both = hand == "both"
    for s in _arm_sides(hand):
        sg = SIDE_SIGN[s]
        phi = 0.15 + 0.45 * np.sin(2 * np.pi * 2.0 * f / FPS) * smoothstep(2 * env - 1)
        upper = _tile([sg * 0.7, 0.75 if both else 0.35, 0.25], n)
        fore = np.stack([sg * np.sin(phi), np.cos(phi), np.full(n, 0.2)], -1)
        tl.blend_arm(s, sl, upper, fore, env)


RAISE_POSES = {  # (upper, forearm) for the left arm; x is mirrored for the right
    "up": ([0.2, 1.0, 0.08], [0.12, 1.0, 0.05]),
    "sideways": ([1.0, 0.05, 0.0], [1.0, 0.08, 0.05]),
    "forward": ([0.12, 0.05, 1.0], [0.06, 0.07, 1.0]),
}


def build_raise_arms(tl: Timeline, p: dict) -> None:
    start = tl.t
    go, hold = 0.6 * FPS, p.get("hold", 1.0) * FPS
    n = int(np.ceil(2 * go + hold + 0.3 * FPS))
    sl = _hold_root(tl, n)
    env = envelope(n, go, go)
    up, fore = RAISE_POSES[p["mode"]]
    for s in _arm_sides(p["hand"]):
        sg = SIDE_SIGN[s]
        tl.blend_arm(s, sl, _tile([sg * up[0], up[1], up[2]], n), _tile([sg * fore[0], fore[1], fore[2]], n), env)
    tl.t += n
    tl.add_part("raise_arms", p, start)


def build_punch(tl: Timeline, p: dict) -> None:
    """Guard up, then `count` straight punches (alternating if hand == 'both'), guard down."""
    start = tl.t
    count = p["count"]
    guard_t, per = 0.45 * FPS, 0.45 * FPS
    n = int(np.ceil(2 * guard_t + count * per + 0.3 * FPS))
    sl = _hold_root(tl, n)
    f = np.arange(n, dtype=float)
    guard = envelope(n, guard_t, guard_t)
    for s in (LEFT, RIGHT):
        sg = SIDE_SIGN[s]
        tl.blend_arm(s, sl, _tile([sg * 0.3, -0.8, 0.5], n), _tile([-sg * 0.25, 0.8, 0.55], n), guard)
    hands = [RIGHT if p["hand"] == "right" else LEFT if p["hand"] == "left" else (RIGHT, LEFT)[i % 2]
             for i in range(count)]
    tl.root_y[sl] -= 0.03 * guard
    for i, s in enumerate(hands):
        sg = SIDE_SIGN[s]
        u = (f - guard_t - i * per) / per
        ext = np.where((u >= 0) & (u <= 1), np.sin(np.pi * np.clip(u, 0, 1)) ** 1.5, 0.0)
        tl.blend_arm(s, sl, _tile([-sg * 0.1, 0.12, 1.0], n), _tile([-sg * 0.1, 0.12, 1.0], n), ext)
        tl.torso_twist[sl] += -sg * 0.35 * ext
    tl.t += n
    tl.add_part("punch", p, start)


def build_clap(tl: Timeline, p: dict) -> None:
    start = tl.t
    count = p["count"]
    go, per = 0.4 * FPS, 0.4 * FPS
    n = int(np.ceil(2 * go + count * per + 0.3 * FPS))
    sl = _hold_root(tl, n)
    f = np.arange(n, dtype=float)
    env = envelope(n, go, go)
    closed = np.zeros(n)
    for i in range(count):
        u = (f - go - i * per) / per
        closed += np.where((u >= 0) & (u <= 1), np.sin(np.pi * np.clip(u, 0, 1)) ** 2, 0.0)
    for s in (LEFT, RIGHT):
        sg = SIDE_SIGN[s]
        tl.blend_arm(s, sl, _tile([sg * 0.25, -0.5, 0.8], n), _tile([sg * 0.2, 0.15, 0.9], n), env)
        tl.blend_arm(s, sl, _tile([sg * 0.15, -0.5, 0.8], n), _tile([-sg * 0.85, 0.2, 0.5], n), closed * env)
    tl.t += n
    tl.add_part("clap", p, start)


BUILDERS = {
    "stand": build_stand, "walk": build_walk, "walk_backward": build_walk_backward,
    "walk_sideways": build_walk_sideways, "jog": build_jog, "run": build_run, "turn": build_turn,
    "circle": build_circle, "jump": build_jump, "jump_forward": build_jump, "hop": build_hop,
    "kick": build_kick, "squat": build_squat, "crouch": build_crouch, "bow": build_bow,
    "wave": build_wave, "raise_arms": build_raise_arms, "punch": build_punch, "clap": build_clap,
}
ACTIONS = tuple(BUILDERS)
LOCOMOTION = ("walk", "walk_backward", "walk_sideways", "jog", "run", "circle")

WALK_SPEEDS = {"slow": (0.7, 0.9), "normal": (1.1, 1.35), "fast": (1.6, 1.85)}


def sample_params(name: str, rng: np.random.Generator) -> dict:
    """Draw caption-relevant parameters (and a few hidden style ones) for one action."""
    u = rng.uniform
    if name == "stand":
        return dict(duration=float(u(1.5, 3.0)), phase=float(u(0, 2 * np.pi)))
    if name == "walk":
        speed = str(rng.choice(list(WALK_SPEEDS)))
        waving = str(rng.choice(["left", "right", "both"])) if speed != "fast" and u() < 0.2 else None
        return dict(speed_label=speed, speed=float(u(*WALK_SPEEDS[speed])), duration=float(u(2.5, 4.5)),
                    first_foot=int(rng.integers(2)), waving=waving)
    if name == "walk_backward":
        speed = str(rng.choice(["slow", "normal"]))
        return dict(speed_label=speed, speed=float(u(0.45, 0.6) if speed == "slow" else u(0.75, 0.95)),
                    duration=float(u(2.5, 4.0)), first_foot=int(rng.integers(2)))
    if name == "walk_sideways":
        return dict(direction=str(rng.choice(["left", "right"])), speed=float(u(0.35, 0.55)),
                    duration=float(u(2.0, 3.5)))
    if name == "jog":
        return dict(speed=float(u(2.0, 2.5)), duration=float(u(2.2, 3.5)), first_foot=int(rng.integers(2)))
    if name == "run":
        return dict(speed=float(u(3.0, 3.7)), duration=float(u(2.2, 3.2)), first_foot=int(rng.integers(2)))
    if name == "turn":
        return dict(direction=str(rng.choice(["left", "right"])), angle=int(rng.choice([90, 180])),
                    rate=float(u(120, 170)))
    if name == "circle":
        return dict(direction=str(rng.choice(["clockwise", "counterclockwise"])), radius=float(u(0.6, 0.85)),
                    speed=float(u(0.9, 1.15)))
    if name == "jump":
        return dict(count=int(rng.integers(1, 4)), flight=float(u(0.36, 0.46)))
    if name == "jump_forward":
        return dict(count=int(rng.integers(1, 3)), distance=float(u(0.5, 0.9)), flight=float(u(0.4, 0.48)))
    if name == "hop":
        return dict(leg=str(rng.choice(["left", "right"])), count=int(rng.integers(2, 5)))
    if name == "kick":
        return dict(leg=str(rng.choice(["left", "right"])), height=float(u(0.4, 0.6)))
    if name == "squat":
        return dict(count=int(rng.integers(1, 4)), depth=float(u(0.3, 0.4)), period=float(u(1.5, 1.9)))
    if name == "crouch":
        return dict(hold=float(u(0.8, 1.8)), depth=float(u(0.38, 0.45)))
    if name == "bow":
        return dict(angle=float(u(40, 60)), hold=float(u(0.4, 1.0)))
    if name == "wave":
        return dict(hand=str(rng.choice(["left", "right", "both"])), duration=float(u(2.0, 3.2)))
    if name == "raise_arms":
        return dict(hand=str(rng.choice(["both", "both", "left", "right"])),
                    mode=str(rng.choice(list(RAISE_POSES))), hold=float(u(0.6, 1.4)))
    if name == "punch":
        return dict(hand=str(rng.choice(["left", "right", "both"])), count=int(rng.integers(1, 4)))
    if name == "clap":
        return dict(count=int(rng.integers(2, 5)))
    raise KeyError(name)
