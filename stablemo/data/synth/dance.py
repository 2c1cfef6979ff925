"""A dance step for the foot-skate benchmark: step-touch on the beat with a hip twist and a bounce.

Not part of the captioned dataset's action mix (ACTIONS/BUILDERS), so `stablemo data synth`
output is unchanged; stablemo.bench.footskate builds it directly. Its contacts are short and
pivoting (each foot lands with a new heading), which is what makes dances hard to clean.
"""

from __future__ import annotations

import numpy as np

from stablemo.data.synth import body
from stablemo.data.synth.action_helpers import body_to_world, envelope, tile
from stablemo.data.synth.body import LEFT, RIGHT, SIDE_SIGN
from stablemo.data.synth.gait import smoothstep
from stablemo.data.synth.locomotion import place_steps
from stablemo.data.synth.timeline import FPS, Timeline

DANCE_GAIT = {"heel_off": 1.5, "off_pitch": 0.4, "slap": 1.0, "land_pitch": -0.1, "clearance": 0.07, "under": 0.5, "toe_out": 0.1}


def sample_dance_params(rng: np.random.Generator) -> dict:
    return {"bpm": float(rng.uniform(100, 135)), "count": int(rng.integers(4, 9)), "width": float(rng.uniform(0.2, 0.35)),
                "twist": float(rng.uniform(0.2, 0.45)), "first": str(rng.choice(["left", "right"]))}


def build_dance(tl: Timeline, p: dict) -> None:
    """`count` beats of step-touch: on each beat the pelvis sways `width` metres sideways and
    twists by ±`twist` rad; the foot on the leading side steps out, the other closes to it."""
    start = tl.t
    beat = 60.0 / p["bpm"] * FPS                                   # frames per beat
    count = int(p["count"])
    n = int(np.ceil((count + 1.5) * beat))
    sl = tl.frames(n)
    f = np.arange(n, dtype=float)
    first = LEFT if p["first"] == "left" else RIGHT
    # Pelvis side offset (body frame, + = left): from 0 to ±width/2 over the first beat, then
    # across to the other side on every beat, back to 0 on the last one.
    sides = [0.0] + [SIDE_SIGN[first if k % 2 == 0 else 1 - first] * p["width"] / 2 for k in range(count - 1)] + [0.0]
    k = np.clip(f / beat, 0, count)
    idx = np.minimum(k.astype(int), count - 1)
    u = smoothstep(k - idx)
    lateral = np.array(sides)[idx] + (np.array(sides)[idx + 1] - np.array(sides)[idx]) * u
    heading = tl.heading
    twist = p["twist"] * np.sin(np.pi * k) * envelope(n, beat, beat)
    xz = tl.pos + body_to_world(heading, lateral, np.zeros(n))
    tl.set_root(sl, xz, heading + twist)
    lifts = [[], []]
    for b in range(count):
        lead = first if b % 2 == 0 else 1 - first
        lifts[lead].append(tl.t + b * beat + 0.05 * beat)
        lifts[1 - lead].append(tl.t + b * beat + 0.5 * beat)
    place_steps(tl, lifts, 0.4 * beat, tl.t + count * beat, body.STANCE_HALF_WIDTH, DANCE_GAIT)
    bounce = 0.5 - 0.5 * np.cos(2 * np.pi * k)
    tl.root_y[sl] -= 0.04 * bounce * envelope(n, beat, beat)
    tl.torso_twist[sl] -= 0.5 * twist
    for s in (LEFT, RIGHT):
        sg = SIDE_SIGN[s]
        swing = 0.5 + 0.5 * np.sin(np.pi * k + (0 if s == LEFT else np.pi))
        tl.blend_arm(s, sl, tile([sg * 0.8, 0.3, 0.4], n), tile([sg * 0.2, 0.8, 0.5], n),
                     0.8 * swing * envelope(n, beat, beat))
    tl.t += n
    tl.add_part("dance", p, start)
