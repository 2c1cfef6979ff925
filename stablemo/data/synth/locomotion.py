"""Locomotion actions: foot placement that follows the pelvis, the gait table, and the
builders for stand, walk (forward, backward, sideways), jog, run, circle and turn on the spot."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from stablemo.data.synth import body
from stablemo.data.synth.action_helpers import G, body_to_world, dir2, envelope
from stablemo.data.synth.body import LEFT, RIGHT, SIDE_SIGN
from stablemo.data.synth.gait import Plant, Swing, minjerk, smoothstep
from stablemo.data.synth.gestures import arm_sides, wave_arms
from stablemo.data.synth.timeline import FPS, Timeline

# ---------------------------------------------------------------------------------------------
# Stepping: foot placements follow the pelvis (each foot lands where the hip will be at the
# middle of its stance), so one rule serves walking, running, side-stepping, backing up,
# circling and turning on the spot.
# ---------------------------------------------------------------------------------------------


def place_steps(tl: Timeline, lifts: list[list[float]], swing_frames: float, rest_time: float,
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
            foot_xz = xz[0] + body_to_world(yaw[0], SIDE_SIGN[s] * width, -body.ANKLE_BACK)
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


def locomote(tl: Timeline, params: dict, gait_name: str, direction: float, curvature: float = 0.0,
              distance: float | None = None, turning: Callable[[np.ndarray], np.ndarray] | None = None) -> None:
    """Move the pelvis at speed v in `direction` (radians from the heading; + = left) for
    params['duration'] seconds of travel (or `distance` metres), stepping all the way.
    curvature: a constant turning rate (rad/m); turning: instead, the heading change (rad) after s
    metres of travel, s (n,) -> (n,) (a path of any shape)."""
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
    heading = tl.heading + (curvature * s if turning is None else turning(s))
    ds = 0.5 * (vel[1:] + vel[:-1]) / sub  # metres per sub-step
    step_xz = dir2(0.5 * (heading[1:] + heading[:-1]) + direction) * ds[:, None]
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
    elif turning is not None:
        # Lean into each bend, as far as its own curvature asks.
        bend = np.interp(f, tt, (turning(s + 0.01) - turning(s - 0.01)) / 0.02)  # rad/m
        tl.torso_roll[sl] += -np.sign(bend) * np.minimum(0.12, v * v * np.abs(bend) / G) * ramp

    half_width = body.STANCE_HALF_WIDTH + abs(np.sin(direction)) * v * (cycle / FPS) / 4
    gp = {k: g[k] for k in ("off_pitch", "land_pitch", "clearance")}
    # The ankle passes under the pelvis before mid-stance: the foot rolls heel to toe, and the
    # trailing ankle rises on the toe, reaching further back than a flat foot could.
    gp["under"] = g.get("under", 0.5)
    gp["heel_off"] = g["heel_off"] * cycle
    gp["slap"] = g["slap"] * cycle
    last_land = place_steps(tl, lifts, sw, rest_time, half_width, gp)
    # The body is still once travel has ended and the last foot is down (the frames reserved
    # above keep holding the final root).
    tl.t += min(n, int(np.ceil(max(last_land, rest_time) - tl.t)) + int(0.25 * FPS))


def build_walk(tl: Timeline, p: dict) -> None:
    start = tl.t
    locomote(tl, p, "walk", 0.0)
    if p.get("waving"):  # "walks forward while waving": the gesture replaces that arm's swing
        sl = slice(start, tl.t)
        env = envelope(tl.t - start, 0.5 * FPS, 0.5 * FPS)
        wave_arms(tl, sl, p["waving"], env)
        for s in arm_sides(p["waving"]):
            tl.arm_swing[sl, s] *= 1 - env
    tl.add_part("walk", p, start)


def build_walk_backward(tl: Timeline, p: dict) -> None:
    start = tl.t
    locomote(tl, p, "walk_backward", np.pi)
    tl.add_part("walk_backward", p, start)


def build_walk_sideways(tl: Timeline, p: dict) -> None:
    start = tl.t
    side = LEFT if p["direction"] == "left" else RIGHT
    locomote(tl, dict(p, first_foot=side), "walk_sideways", SIDE_SIGN[side] * np.pi / 2)
    tl.add_part("walk_sideways", p, start)


def build_jog(tl: Timeline, p: dict) -> None:
    start = tl.t
    locomote(tl, p, "jog", 0.0)
    tl.add_part("jog", p, start)


def build_run(tl: Timeline, p: dict) -> None:
    start = tl.t
    locomote(tl, p, "run", 0.0)
    tl.add_part("run", p, start)


def build_circle(tl: Timeline, p: dict) -> None:
    start = tl.t
    sign = 1.0 if p["direction"] == "counterclockwise" else -1.0
    first = LEFT if sign > 0 else RIGHT
    locomote(tl, dict(p, first_foot=first), "circle", 0.0, curvature=sign / p["radius"],
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
    place_steps(tl, lifts, sw, tl.t + duration, body.STANCE_HALF_WIDTH, GAITS["turn"])
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
    xz = tl.pos + body_to_world(tl.heading, sway, 0.0 * sway)
    tl.set_root(sl, xz, np.full(n, tl.heading))
    tl.torso_roll[sl] += -0.4 * sway
    tl.head_pitch[sl] += 0.05 * np.sin(2 * np.pi * f / (3.1 * FPS) + phase) * envelope(n, 10, 10)
    tl.t += n
    tl.add_part("stand", p, start)
