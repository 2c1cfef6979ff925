"""How good a retargeting is, against the issue's targets (docs/retarget.md, tests/test_retarget*.py):
stance-foot speed, hands and feet against the scaled source, knees and elbows bending the source's
way, heading. Every function takes a stablemo.retarget.solve.Solved.
"""

from __future__ import annotations

import numpy as np

from stablemo.retarget.frames import unit
from stablemo.retarget.names import LIMBS, SIDES
from stablemo.retarget.solve import Solved
from stablemo.retarget.source import guess_per_metre, leg_length

BENT_DEG = 15.0  # a knee or elbow counts as bent past this angle (straight limbs have no bend side)


def upright(solved: Solved, x: np.ndarray) -> np.ndarray:
    """Target-world positions (..., 3) in our y-up world (the rig may be z up)."""
    return x @ solved.axes


def _pair(solved: Solved, side: str, role: str) -> tuple[np.ndarray, np.ndarray]:
    """(T, 3) the target's joint and the scaled source's, target units."""
    return (solved.positions[:, solved.roles.sides[side][role]],
            solved.scaled[:, solved.source.roles.sides[side][role]])


def stance_speed(solved: Solved) -> dict[str, float]:
    """Mean horizontal speed (m/s) of the feet (ankles and toes) over the source's contact frames
    (both frames of a step in contact): the target's and the source's, over the same steps."""
    per_metre_t = guess_per_metre(leg_length(solved.target.rest, solved.roles))
    src, fps = solved.source, solved.source.fps
    tgt_speeds, src_speeds = [], []
    for s_i, side in enumerate(SIDES):
        for k, role in enumerate(("Foot", "Toes")):
            jt, js = solved.roles.sides[side].get(role), src.roles.sides[side].get(role)
            if jt is None or js is None:
                continue
            c = solved.contacts[:, 2 * s_i + k]
            both = c[1:] & c[:-1]
            for pos, scale, out in ((upright(solved, solved.positions[:, jt]), per_metre_t, tgt_speeds),
                                    (src.positions[:, js], src.per_metre, src_speeds)):
                v = np.linalg.norm(np.diff(pos[:, [0, 2]], axis=0), axis=-1) * fps / scale
                out.append(v[both])
    t, s = np.concatenate(tgt_speeds), np.concatenate(src_speeds)
    return {"target_m_s": float(t.mean()) if len(t) else 0.0, "source_m_s": float(s.mean()) if len(s) else 0.0,
            "steps": len(t)}


def reach_error(solved: Solved) -> dict[str, float]:
    """Hands and ankles against the scaled source's, as a fraction of the target's leg length: each
    hand on the frames its scaled source position is within the target arm's reach of the target's
    shoulder (a rig whose arms are short for its legs cannot put its hands where the scaled source
    has them; `unreachable` is the share of hand frames left out so), each ankle on the frames no
    contact holds it (neither planted nor within a hold's fade); mean and max."""
    leg = leg_length(solved.target.rest, solved.roles)
    errors, hand_frames, unreachable = [], 0, 0
    for s_i, side in enumerate(SIDES):
        for role in ("Hand", "Foot"):
            a, b = _pair(solved, side, role)
            err = np.linalg.norm(a - b, axis=-1) / leg
            if role == "Foot":
                err = err[solved.held[:, s_i] == 0]
            else:
                shoulder, elbow, hand = (solved.roles.sides[side][r] for r in LIMBS["arm"])
                x = solved.positions
                arm = np.median(np.linalg.norm(x[:, elbow] - x[:, shoulder], axis=-1)
                                + np.linalg.norm(x[:, hand] - x[:, elbow], axis=-1))
                reachable = np.linalg.norm(b - x[:, shoulder], axis=-1) <= arm * (1 + 1e-3)
                hand_frames += len(err)
                unreachable += int((~reachable).sum())
                err = err[reachable]
            errors.append(err)
    every = np.concatenate(errors)
    return {"mean": float(every.mean()) if len(every) else 0.0, "max": float(every.max()) if len(every) else 0.0,
            "unreachable": unreachable / max(hand_frames, 1)}


def _bend_axis(x: np.ndarray, upper: int, mid: int, end: int) -> tuple[np.ndarray, np.ndarray]:
    """(T, 3) unit hinge axis and (T,) bend angle (degrees) of a limb in x (T, J, 3)."""
    a, b = x[:, mid] - x[:, upper], x[:, end] - x[:, mid]
    angle = np.degrees(np.arccos(np.clip((unit(a) * unit(b)).sum(-1), -1.0, 1.0)))
    return unit(np.cross(a, b)), angle


def flipped_joints(solved: Solved) -> dict[str, int]:
    """Frames where a target knee or elbow bends the other way round from the source's (both bent
    more than BENT_DEG), per limb ('LeftLeg', ...), and 'bent' the frames compared."""
    out, compared = {}, 0
    for side in SIDES:
        for limb, chain in LIMBS.items():
            nt, at = _bend_axis(solved.positions, *(solved.roles.sides[side][r] for r in chain))
            ns, as_ = _bend_axis(solved.scaled, *(solved.source.roles.sides[side][r] for r in chain))
            both = (at > BENT_DEG) & (as_ > BENT_DEG)
            compared += int(both.sum())
            out[side + limb.capitalize()] = int(((nt * ns).sum(-1)[both] < 0).sum())
    out["bent"] = compared
    return out


def _heading(x: np.ndarray, roles) -> np.ndarray:
    """(T,) degrees: where the pelvis faces (across the hips x up), about y."""
    lat = x[:, roles.sides["Left"]["UpperLeg"]] - x[:, roles.sides["Right"]["UpperLeg"]]
    up = x[:, roles.spine[0]] - x[:, roles.hips]
    fwd = np.cross(lat, up)
    return np.degrees(np.arctan2(fwd[:, 0], fwd[:, 2]))


def heading_error(solved: Solved) -> float:
    """Largest difference (degrees) between the target's and the source's pelvis heading."""
    d = (_heading(upright(solved, solved.positions), solved.roles)
         - _heading(upright(solved, solved.scaled), solved.source.roles))
    return float(np.abs((d + 180.0) % 360.0 - 180.0).max())


def report(solved: Solved) -> dict:
    """Every measure above, for docs and tests."""
    return {"scale": solved.scale, "stance": stance_speed(solved), "reach": reach_error(solved),
            "flipped": flipped_joints(solved), "heading_deg": heading_error(solved)}
