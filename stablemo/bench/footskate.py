"""Foot-skate benchmark by motion type: synthetic motions with known contacts, injected sliding.

    stablemo bench footskate [--seed 1000] [--per-type 6] [--contacts heuristic|vgrf|gt]
        [--threads 1] [--json out.json]

For each motion type (walk, run, jump, hop, turn in place, side step, kick, dance) `--per-type`
motions are built by the synthetic generator (stablemo.data.synth) from seeds seed, seed+1, ...
(the types' parameter draws are independent of each other). Sliding is injected the way
generators produce it: the root travels `overshoot` (25 %) further than the legs step (every joint
follows the over-travelling root, so stance feet slide at a quarter of the body's speed), and in
every contact range each leg additionally drifts through its true position at `drift` m/s
(0.7 m/s, offsets clamped to ±12 cm, interpolated across the swing; knee at half the offset).
The cleanup then sees only the sliding motion (contacts detected from it unless `--contacts gt`).

Reported per type: stance-foot speed (mean horizontal speed of ankle and toe joints over frame
pairs inside the ground-truth contacts) before / after and its reduction, non-leg joints moved
(every joint but hips, knees, ankles, toes; mean, p95 and max), knees moved (the leg IK's), bone-length change
(max), foot acceleration (mean |second difference| of ankles and toes) before / after, and
contact-detection F1 of the height rule and the vGRF network on the sliding input against the
synthetic labels. `--real` adds F1 on a real clip against its hand labels (REAL_CONTACTS), and the
stance-foot speed reduction on that clip with sliding injected (root overshoot alone, and with the
drift too) for the gated and the rule's contacts.

Also here, for scripts/footskate/train_vgrf.py (fine-tuning the vGRF network on every type): the
augmentations heel_raise and foot_shuffle, build_training_set and heldout_f1. The calibration of
the gated contact decision is stablemo.bench.footskate_calibrate.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from stablemo.errors import StableMoError
from stablemo.motion import skeleton

TYPES = ("walk", "run", "jump", "hop", "turn_in_place", "side_step", "kick", "dance")
_BODY, _KIT = skeleton.HUMANML3D, skeleton.KIT  # the per-skeleton facts live there
FPS = _BODY.fps
FEET = [*_BODY.feet_left, *_BODY.feet_right]  # HumanML3D [L_ankle, L_toe, R_ankle, R_toe]
LEGS = {0: (_BODY.legs["left"][1], *_BODY.feet_left), 1: (_BODY.legs["right"][1], *_BODY.feet_right)}  # knee, ankle, toe


def _plan(kind: str, rng: np.random.Generator) -> tuple:
    """(builder, params) of one motion of `kind`."""
    from stablemo.data.synth import actions
    from stablemo.data.synth.dance import build_dance, sample_dance_params

    name = {"walk": "walk", "run": str(rng.choice(["jog", "run"])), "jump": str(rng.choice(["jump", "jump_forward"])),
            "hop": "hop", "turn_in_place": "turn", "side_step": "walk_sideways", "kick": "kick"}.get(kind)
    if kind == "dance":
        return build_dance, sample_dance_params(rng)
    if name is None:
        raise KeyError(kind)
    params = actions.sample_params(name, rng)
    if name == "walk":
        params["waving"] = None
    return actions.BUILDERS[name], params


def build_motion(kind: str, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """One synthetic motion of `kind`: joints (T, 22, 3) metres, y up, floor 0; contacts (T, 4) bool."""
    from stablemo.data.synth import actions
    from stablemo.data.synth.timeline import Timeline

    rng = np.random.default_rng([seed, TYPES.index(kind)])
    builder, params = _plan(kind, rng)
    tl = Timeline()
    actions.build_stand(tl, {"duration": float(rng.uniform(0.2, 0.4)), "phase": 0.0})
    builder(tl, params)
    actions.build_stand(tl, {"duration": float(rng.uniform(0.3, 0.5)), "phase": 0.0})
    built = tl.build(min(tl.t, 196))
    return built.joints.astype(np.float32), built.contacts.astype(bool)


# HumanML3D joint -> KIT-ML joint (stablemo.motion.skeleton.KIT names). The KIT foot has an extra
# metatarsal joint between ankle and toe; it is placed 2/3 of the way from ankle to toe.
KIT_FROM_HUMANML3D = (0, 3, 6, 12, 15, 17, 19, 21, 16, 18, 20, 2, 5, 8, None, 11, 1, 4, 7, None, 10)
KIT_FEET = [*_KIT.feet_left, *_KIT.feet_right]  # [L_metatarsal, L_toe, R_metatarsal, R_toe], the KIT contact joints
KIT_FPS = _KIT.fps


def to_kit(joints: np.ndarray, contacts: np.ndarray, fps: float = FPS) -> tuple[np.ndarray, np.ndarray]:
    """A HumanML3D-skeleton motion (T, 22, 3) metres at `fps` + contacts (T, 4) -> the same motion on
    the KIT-ML topology (T', 21, 3) metres at 12.5 fps + KIT contacts (T', 4). A joint map, not a
    refit: the proportions stay the synthetic body's. Ankle contacts become metatarsal contacts."""
    src = joints.astype(np.float64)
    out = np.zeros((len(src), 21, 3))
    for k, j in enumerate(KIT_FROM_HUMANML3D):
        if j is not None:
            out[:, k] = src[:, j]
    out[:, 14] = src[:, 8] + (src[:, 11] - src[:, 8]) * 2 / 3
    out[:, 19] = src[:, 7] + (src[:, 10] - src[:, 7]) * 2 / 3
    t = len(out)
    n = max(2, int(np.floor((t - 1) * KIT_FPS / fps)) + 1)
    time = np.arange(n) * fps / KIT_FPS                                       # source frame of each output frame
    lo = np.minimum(np.floor(time).astype(int), t - 1)
    hi = np.minimum(lo + 1, t - 1)
    a = (time - lo)[:, None, None]
    return (out[lo] * (1 - a) + out[hi] * a).astype(np.float32), contacts[np.minimum(np.rint(time).astype(int), t - 1)]


def kit_from_v22(v22):
    """A KIT-ML (21-joint) network starting from `v22`: its first convolution reads each KIT joint
    with the weights of the HumanML3D joint it was mapped from (the metatarsal and the HumanML3D
    joints KIT lacks — spine3, collars — get none); every later layer is copied."""
    from footskate.vgrf import VGRFNet

    cfg = dict(v22.config, num_joints=21)
    kit = VGRFNet(**cfg)
    state = v22.net.state_dict()
    w = state["3.weight"]                                                     # (C, 3 * 22, K)
    new = torch.zeros(w.shape[0], 3 * 21, w.shape[2])
    for k, j in enumerate(KIT_FROM_HUMANML3D):
        if j is not None:
            new[:, 3 * k:3 * k + 3] = w[:, 3 * j:3 * j + 3]
    state["3.weight"] = new
    kit.net.load_state_dict(state)
    return kit


def inject_sliding(joints: np.ndarray, contacts: np.ndarray, rng: np.random.Generator, overshoot: float = 0.25,
                   drift: float = 0.7, clamp: float = 0.12, fps: float = FPS) -> np.ndarray:
    """joints (T, 22, 3), contacts (T, 4) -> sliding joints (T, 22, 3) (see the module doc)."""
    out = joints.astype(np.float64).copy()
    root = out[:, 0, [0, 2]]
    out[:, :, [0, 2]] += overshoot * (root - root[:1])[:, None, :]
    frames = np.arange(len(out))
    for side, (knee, ankle, toe) in LEGS.items():
        planted = contacts[:, 2 * side:2 * side + 2].any(-1)
        starts = np.flatnonzero(planted & ~np.r_[False, planted[:-1]])
        ends = np.flatnonzero(planted & ~np.r_[planted[1:], False])
        if len(starts) == 0:
            continue
        keys_t, keys_off = [], []
        for s, e in zip(starts, ends):
            angle = rng.uniform(0, 2 * np.pi)
            direction = np.array([np.cos(angle), np.sin(angle)])
            mid = 0.5 * (s + e)
            for t in range(s, e + 1):
                keys_t.append(t)
                keys_off.append(np.clip(drift / fps * (t - mid), -clamp, clamp) * direction)
        keys_off = np.array(keys_off)
        offset = np.stack([np.interp(frames, keys_t, keys_off[:, i]) for i in (0, 1)], -1)  # (T, 2)
        for joint, w in ((knee, 0.5), (ankle, 1.0), (toe, 1.0)):
            out[:, joint, [0, 2]] += w * offset
    return out.astype(np.float32)


def build_set(seed: int, per_type: int, types=TYPES, skeleton: str = "humanml3d") -> dict:
    """The benchmark batch: clean and sliding joints (B, T, J, 3), contacts (B, T, 4), lengths, kinds.
    skeleton "kit": the same motions (sliding injected at 20 fps) mapped to KIT-ML at 12.5 fps."""
    clean, contacts, kinds, seeds = [], [], [], []
    for kind in types:
        for i in range(per_type):
            j, c = build_motion(kind, seed + i)
            clean.append(j), contacts.append(c), kinds.append(kind), seeds.append(seed + i)
    sliding = [inject_sliding(j, c, np.random.default_rng([s, 7, k])) for k, (j, c, s) in enumerate(zip(clean, contacts, seeds))]
    if skeleton == "kit":
        sliding = [to_kit(j, c)[0] for j, c in zip(sliding, contacts)]
        clean, contacts = map(list, zip(*[to_kit(j, c) for j, c in zip(clean, contacts)]))
    lengths = np.array([len(j) for j in clean])
    t = int(lengths.max())
    pad = lambda a: np.concatenate([a, np.repeat(a[-1:], t - len(a), 0)])
    return {"skeleton": skeleton, "clean": torch.from_numpy(np.stack([pad(j) for j in clean])),
            "sliding": torch.from_numpy(np.stack([pad(j) for j in sliding])),
            "contacts": torch.from_numpy(np.stack([pad(c) & (np.arange(t) < len(c))[:, None] for c in contacts])),
            "lengths": torch.from_numpy(lengths), "kinds": kinds}


def _valid(lengths: torch.Tensor, t: int) -> torch.Tensor:
    return torch.arange(t)[None, :] < lengths[:, None]


def _skeleton(data_or_name) -> tuple[list[int], float, list[int]]:
    """(contact joints, fps, parents) of a benchmark batch's skeleton."""
    from footskate import HUMANML3D, KIT

    name = data_or_name.get("skeleton", "humanml3d") if isinstance(data_or_name, dict) else data_or_name
    return (KIT_FEET, KIT_FPS, list(KIT.parents)) if name == "kit" else (FEET, FPS, list(HUMANML3D.parents))


def stance_speed(joints: torch.Tensor, contacts: torch.Tensor, lengths: torch.Tensor, feet_idx=FEET,
                 fps: float = FPS) -> tuple[torch.Tensor, torch.Tensor]:
    """Per sample: summed horizontal speed (m/s) of foot joints over frame pairs inside contacts, and
    the pair count (the definition is stablemo.eval.kinematics.stance_speed_sums, shared with evaluate)."""
    from stablemo.eval.kinematics import stance_speed_sums

    return stance_speed_sums(joints, contacts, lengths, feet_idx, fps)


def foot_acceleration(joints: torch.Tensor, lengths: torch.Tensor, feet_idx=FEET,
                      fps: float = FPS) -> tuple[torch.Tensor, torch.Tensor]:
    """Per sample: summed |second difference| (m/s², per coordinate) of the contact joints, and the count."""
    from stablemo.skating.metrics import foot_second_difference

    acc = foot_second_difference(joints.double(), feet_idx, fps)  # (B, T-2, 4, 3)
    valid = _valid(lengths - 2, joints.shape[1] - 2)[..., None, None].expand_as(acc)
    return (acc * valid).sum((1, 2, 3)), valid.sum((1, 2, 3)).double()


def f1(pred: torch.Tensor, truth: torch.Tensor, valid: torch.Tensor) -> tuple[int, int, int]:
    """(true positives, false positives, false negatives) over valid frames; pred/truth (B, T, 4)."""
    v = valid[..., None]
    return (int((pred & truth & v).sum()), int((pred & ~truth & v).sum()), int((~pred & truth & v).sum()))


def _f1_score(tp: int, fp: int, fn: int) -> float:
    return 2 * tp / max(2 * tp + fp + fn, 1)


def table(data: dict, result_joints: torch.Tensor, detected: dict[str, torch.Tensor] | None = None) -> dict:
    """Per type and overall: the measurements named in the module doc."""
    from footskate.cleanup import leg_joints

    feet_idx, fps, parents = _skeleton(data)
    lengths, contacts = data["lengths"], data["contacts"]
    valid = _valid(lengths, result_joints.shape[1])
    legs = set(leg_joints(parents, feet_idx)) | {parents[j] for j in leg_joints(parents, feet_idx)}
    others = [j for j in range(len(parents)) if j not in legs]
    bones = lambda x: (x[..., 1:, :] - x[..., parents[1:], :]).norm(dim=-1)
    s_clean = stance_speed(data["clean"], contacts, lengths, feet_idx, fps)
    s_before = stance_speed(data["sliding"], contacts, lengths, feet_idx, fps)
    s_after = stance_speed(result_joints, contacts, lengths, feet_idx, fps)
    a_clean = foot_acceleration(data["clean"], lengths, feet_idx, fps)
    a_before = foot_acceleration(data["sliding"], lengths, feet_idx, fps)
    a_after = foot_acceleration(result_joints, lengths, feet_idx, fps)
    moved = (result_joints - data["sliding"])[:, :, others].norm(dim=-1)      # (B, T, J')
    knees = [j for j in leg_joints(parents, feet_idx) if parents[j] not in leg_joints(parents, feet_idx)]
    knee_moved = (result_joints - data["sliding"])[:, :, knees].norm(dim=-1)  # (B, T, 2): moved by the leg IK
    bone_err = (bones(result_joints) - bones(data["sliding"])).abs().amax(-1)  # (B, T)
    kinds = np.array(data["kinds"])
    out = {}
    for kind in list(dict.fromkeys(data["kinds"])) + ["all"]:
        sel = torch.from_numpy(kinds == kind) if kind != "all" else torch.ones(len(kinds), dtype=torch.bool)
        def ratio(s, sel=sel):
            return float(s[0][sel].sum() / s[1][sel].sum().clamp(min=1))
        before, after = ratio(s_before), ratio(s_after)
        vmask = valid[sel]
        row = {"motions": int(sel.sum()), "stance_speed_clean": ratio(s_clean), "stance_speed_before": before,
               "stance_speed_after": after, "reduction": 1 - after / before if before > 0 else 0.0,
               "non_leg_moved_mean_m": float(moved[sel][vmask].mean()),
               "non_leg_moved_p95_m": float(moved[sel][vmask].quantile(0.95)),
               "non_leg_moved_max_m": float(moved[sel][vmask].max()),
               "knee_moved_mean_m": float(knee_moved[sel][vmask].mean()),
               "knee_moved_max_m": float(knee_moved[sel][vmask].max()),
               "bone_change_max_m": float(bone_err[sel][vmask].max()),
               "foot_acc_clean": ratio(a_clean), "foot_acc_before": ratio(a_before), "foot_acc_after": ratio(a_after)}
        for name, pred in (detected or {}).items():
            row[f"f1_{name}"] = _f1_score(*f1(pred[sel], contacts[sel], vmask))
        out[kind] = row
    return out


# Hand labels of the real HumanML3D clip 012314 (170 frames at 20 fps: walks ~2.3 m forward with a
# hop-like step, stands, walks back, then stands shifting its weight), frame ranges inclusive, per
# contact joint. Labelled frame by frame from plots and a table of each joint's height above its
# own lowest point and its 3D speed, by judgement of support, not by a threshold:
# - a joint is down when it bears weight and stays put: the table's speed drops to the
#   0.0-0.2 m/s of a still foot at the height it settles at, and stays there;
# - the range starts at the first settled frame (a landing that is still descending, e.g.
#   2.4 cm at 0.26 m/s, is not yet down) and ends at the last one before it lifts;
# - a heel that rises slowly while the ball stays still (heel-off: L heel frames 3-10 at
#   2.3-7 cm, 0.1-0.35 m/s; R heel 150-155, up to 3.3 cm at 0.2 m/s) is *up*, a ball that stays
#   still 2-4 cm above its lowest point while the other foot swings (L toe 13-21: the body stands
#   on it) or while standing with the heel raised (L toe 46-61) is *down*, and a lifted toe that
#   creeps slowly 2-3 cm up (R toe 151-155) is *up*;
# - short touches count when the other foot is in the air (R toe 21-23, 65-68).
# The height rule (within 5 cm of the lowest point, < 0.93 m/s) disagrees with these labels on
# heel-offs and weight shifts (it calls them down) and on fast rolling touch-downs.
REAL_CONTACTS = {
    "012314": {
        "L_ankle": [(0, 2), (30, 31), (70, 78), (91, 99), (114, 124), (130, 158), (163, 169)],
        "L_toe": [(0, 21), (30, 35), (46, 61), (68, 77), (90, 98), (114, 125), (130, 158), (163, 169)],
        "R_ankle": [(0, 11), (39, 42), (48, 61), (67, 68), (79, 88), (102, 117), (124, 149), (156, 169)],
        "R_toe": [(0, 12), (21, 23), (39, 43), (46, 62), (65, 68), (79, 88), (101, 116), (123, 150), (156, 169)],
    },
}


def hand_labels(name: str, frames: int) -> np.ndarray | None:
    """REAL_CONTACTS[name] as (frames, 4) bool in FEET order, or None if that clip has no hand labels."""
    ranges = REAL_CONTACTS.get(name)
    if ranges is None:
        return None
    out = np.zeros((frames, 4), bool)
    for k, joint in enumerate(("L_ankle", "L_toe", "R_ankle", "R_toe")):
        for s, e in ranges[joint]:
            out[s:e + 1, k] = True
    return out


def label_real_contacts(joints: np.ndarray, height: float = 0.05, speed: float = 0.3) -> np.ndarray:
    """Contact labels (T, 4) for a clean mocap clip (T, 22, 3), by a strict rule checked by hand on
    the HumanML3D sample 012314 (plots of each joint's height and speed): a joint is down when it
    is within `height` of its own lowest point and moves less than `speed` horizontally over both
    frame pairs around the frame; 1-frame gaps are filled, then 1-frame ranges dropped. Much
    stricter on speed than the heuristic detector (0.93 m/s), which is fine on clean mocap, where a
    planted foot barely moves."""
    feet = joints[:, FEET].astype(np.float64)
    h = feet[..., 1] - feet[..., 1].min(0)
    v = np.linalg.norm(np.diff(feet[..., [0, 2]], axis=0), axis=-1) * FPS          # (T-1, 4)
    vmax = np.maximum(np.r_[v[:1], v], np.r_[v, v[-1:]])
    c = (h < height) & (vmax < speed)
    inner = slice(1, len(c) - 1)
    c[inner] |= c[:-2] & c[2:]                                                     # fill 1-frame gaps
    prev = np.r_[np.zeros((1, 4), bool), c[:-1]]
    nxt = np.r_[c[1:], np.zeros((1, 4), bool)]
    return c & (prev | nxt)                                                        # drop 1-frame ranges


def real_clip_f1(path: Path, vgrf, seeds=(0, 1, 2, 3)) -> dict:
    """F1 of the rule, the network and the gated network against `label_real_contacts` on a real
    clip, clean and with the benchmark's injected sliding (one draw per seed)."""
    from footskate.cleanup import detect_contacts

    joints = np.load(path, allow_pickle=False).astype(np.float32)
    labels = hand_labels(Path(path).stem, len(joints))
    labelled_by = "hand (REAL_CONTACTS)"
    if labels is None:
        labels, labelled_by = label_real_contacts(joints), "rule (label_real_contacts)"
    clips = {"clean": [joints]} | {"sliding": [inject_sliding(joints, labels, np.random.default_rng([s, 22])) for s in seeds]}
    out = {}
    for name, xs in clips.items():
        x = torch.from_numpy(np.stack(xs))
        truth = torch.from_numpy(labels)[None].expand(len(xs), -1, -1)
        valid = torch.ones(x.shape[:2], dtype=torch.bool)
        preds = {"rule": detect_contacts(x, None, FEET, FPS, 1)[0]}
        if vgrf is not None:
            preds["vgrf"] = detect_contacts(x, None, FEET, FPS, 1, vgrf)[0]
            preds["gated"] = detect_contacts(x, None, FEET, FPS, 1, vgrf, gate=True)[0]
        out[name] = {k: _f1_score(*f1(p, truth, valid)) for k, p in preds.items()}
    out["labels"] = labelled_by
    return out


def real_clip_removal(path: Path, vgrf, seeds=(0, 1, 2, 3)) -> dict:
    """Stance-foot speed reduction on a real clip with injected sliding (one draw per seed), over
    its labelled stances (hand labels where the clip has them): root overshoot alone ("overshoot",
    the way the issue's real-clip measurement injects it) and with the per-foot drift too
    ("overshoot+drift", the synthetic benchmark's injection), for each contact source."""
    from footskate.cleanup import CleanupConfig, cleanup

    joints = np.load(path, allow_pickle=False).astype(np.float32)
    labels = hand_labels(Path(path).stem, len(joints))
    if labels is None:
        labels = label_real_contacts(joints)
    truth = torch.from_numpy(labels)[None].expand(len(seeds), -1, -1)
    lengths = torch.full((len(seeds),), len(joints))
    out = {}
    for name, drift in (("overshoot", 0.0), ("overshoot+drift", 0.7)):
        x = torch.from_numpy(np.stack([inject_sliding(joints, labels, np.random.default_rng([s, 22]), drift=drift)
                                       for s in seeds]))
        before = stance_speed(x, truth, lengths)
        row = {"stance_speed_before": float(before[0].sum() / before[1].sum())}
        for source in ("gated", "heuristic") if vgrf is not None else ("heuristic",):
            cfg = CleanupConfig(fps=FPS)
            cfg.detect = source
            after = stance_speed(cleanup(x, _skeleton("humanml3d")[2], FEET, vgrf=vgrf, config=cfg).joints, truth, lengths)
            row[f"reduction_{source}"] = 1 - float(after[0].sum() / after[1].sum()) / row["stance_speed_before"]
        out[name] = row
    return out


def run(seed: int = 1000, per_type: int = 6, contacts: str = "heuristic", vgrf=None, config=None, types=TYPES,
        skeleton: str = "humanml3d") -> dict:
    from footskate.cleanup import CleanupConfig, cleanup, detect_contacts

    data = build_set(seed, per_type, types, skeleton)
    feet_idx, fps, parents = _skeleton(data)
    x, lengths = data["sliding"], data["lengths"]
    detected = {"rule": detect_contacts(x, lengths, feet_idx, fps, 1)[0]}
    if vgrf is not None:
        detected["vgrf"] = detect_contacts(x, lengths, feet_idx, fps, 1, vgrf)[0]
        detected["gated"] = detect_contacts(x, lengths, feet_idx, fps, 1, vgrf, gate=True)[0]
    cfg = config or CleanupConfig(fps=fps)
    if contacts != "gt":
        cfg.detect = contacts
    res = cleanup(x, parents, feet_idx, lengths=lengths, vgrf=vgrf,
                  contacts=data["contacts"] if contacts == "gt" else None, config=cfg)
    detected["used"] = res.contacts
    rows = table(data, res.joints, detected)
    return {"seed": seed, "per_type": per_type, "contacts": contacts, "skeleton": skeleton, "seconds": res.info["seconds"],
            "anchored_ranges": res.info["anchored_ranges"], "ranges": res.info["ranges"], "types": rows}


def format_table(report: dict) -> str:
    lines = [("| type | stance-foot speed clean / before → after (m/s) | reduction | non-leg moved mean / p95 / max (cm) "
             "| knees moved mean / max (cm) | bone change max (m) | foot acc. clean / before → after (m/s²) "
             "| F1 rule / vGRF / gated / used |"),
             "|---|---|---|---|---|---|---|---|"]
    for kind, r in report["types"].items():
        f1s = " / ".join(f"{r[k]:.3f}" for k in ("f1_rule", "f1_vgrf", "f1_gated", "f1_used") if k in r)
        lines.append(f"| {kind} | {r['stance_speed_clean']:.3f} / {r['stance_speed_before']:.3f} → "
                     f"{r['stance_speed_after']:.3f} | {100 * r['reduction']:.0f} % | "
                     f"{100 * r['non_leg_moved_mean_m']:.2f} / {100 * r['non_leg_moved_p95_m']:.2f} / "
                     f"{100 * r['non_leg_moved_max_m']:.2f} | "
                     f"{100 * r['knee_moved_mean_m']:.2f} / {100 * r['knee_moved_max_m']:.2f} | "
                     f"{r['bone_change_max_m']:.1e} | {r['foot_acc_clean']:.2f} / {r['foot_acc_before']:.2f} → {r['foot_acc_after']:.2f} | {f1s} |")
    return "\n".join(lines)


def run_footskate_bench(args) -> dict:
    """The benchmark of `stablemo bench footskate` (args: its parsed options): prints the table,
    writes args.json if given, returns the report."""
    from stablemo.io import write_text
    from stablemo.skating.cleanup import load_vgrf_model

    torch.set_num_threads(args.threads)
    vgrf = None if args.no_vgrf else load_vgrf_model(args.weights, args.skeleton)
    if args.contacts in ("gated", "vgrf") and vgrf is None:
        raise StableMoError(f"--contacts {args.contacts}: no vGRF network for skeleton {args.skeleton} (give --weights)")
    report = run(args.seed, args.per_type, args.contacts, vgrf, skeleton=args.skeleton)
    if args.real:
        if not Path(args.real).is_file():
            raise StableMoError(f"--real: {args.real} is not a file")
        report["real_clip_f1"] = real_clip_f1(Path(args.real), vgrf)
        print("real clip contact F1:", json.dumps(report["real_clip_f1"]))
        report["real_clip_removal"] = real_clip_removal(Path(args.real), vgrf)
        print("real clip, injected sliding, stance-foot speed reduction:", json.dumps(report["real_clip_removal"]))
    print(format_table(report))
    print(f"{report['anchored_ranges']} of {report['ranges']} ranges anchored; cleanup {report['seconds']:.1f} s")
    if args.json:
        write_text(Path(args.json), json.dumps(report, indent=2) + "\n")
    return report


# ------------------------------------------------------------------ training the vGRF network on every type
# (scripts/footskate/train_vgrf.py: augmentations, the training set and the held-out F1)


def resample(joints: np.ndarray, contacts: np.ndarray, factor: float) -> tuple[np.ndarray, np.ndarray]:
    """Play a motion `factor` times faster: joints linearly interpolated, contacts nearest frame."""
    t = len(joints)
    n = max(8, round((t - 1) / factor) + 1)
    src = np.linspace(0, t - 1, n)
    lo = np.floor(src).astype(int)
    hi = np.minimum(lo + 1, t - 1)
    a = (src - lo)[:, None, None]
    return (joints[lo] * (1 - a) + joints[hi] * a).astype(np.float32), contacts[np.rint(src).astype(int)]


def heel_raise(joints: np.ndarray, contacts: np.ndarray, rng: np.random.Generator, prob: float = 0.5,
               lift=(0.03, 0.10), min_frames: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Standing on the ball of the foot: in each flat-foot stance (heel and toe both down for at
    least `min_frames`) picked with `prob`, the foot pitches about its toe joint so the heel rises
    by U(`lift`) metres, ramped in and out over 2 frames; the knee moves with the ankle. Heel
    contact is off where the heel is up by more than 1.5 cm, the toe stays down, so the force
    labels put that foot's load on its front cells. The synthetic generator has almost no such
    stances; a real clip (HumanML3D 012314) stands on the ball of its left foot for 16 frames."""
    out, c = joints.astype(np.float64).copy(), contacts.copy()
    for side, (knee, ankle, toe) in {0: (4, 7, 10), 1: (5, 8, 11)}.items():
        flat = contacts[:, 2 * side] & contacts[:, 2 * side + 1]
        starts = np.flatnonzero(flat & ~np.r_[False, flat[:-1]])
        ends = np.flatnonzero(flat & ~np.r_[flat[1:], False])
        for s, e in zip(starts, ends):
            if e - s + 1 < min_frames or rng.random() >= prob:
                continue
            h = rng.uniform(*lift)
            t = np.arange(s, e + 1)
            ramp = np.clip(np.minimum(t - s + 1, e + 1 - t) / 3.0, 0, 1)       # 1/3, 2/3, 1, ..., 2/3, 1/3
            for k, tt in enumerate(t):
                v = out[tt, ankle] - out[tt, toe]                              # toe -> heel, length kept
                length = np.linalg.norm(v)
                flat_len = np.linalg.norm(v[[0, 2]])
                if length < 1e-6 or flat_len < 1e-6:
                    continue
                rise = min(h * ramp[k], 0.9 * length)
                new_y = v[1] + rise
                horiz = np.sqrt(max(length ** 2 - new_y ** 2, 0.0))
                nv = np.array([v[0] / flat_len * horiz, new_y, v[2] / flat_len * horiz])
                delta = nv - v
                out[tt, ankle] += delta
                out[tt, knee] += delta
                if rise > 0.015:
                    c[tt, 2 * side] = False
    return out.astype(np.float32), c


def foot_shuffle(joints: np.ndarray, contacts: np.ndarray, rng: np.random.Generator, prob: float = 0.5,
                 lift=(0.015, 0.04), min_frames: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Weight shifts while standing: in each flat-foot stance of at least `min_frames` while the
    other foot is down too (double support), picked with `prob`, the foot is lifted by U(`lift`)
    metres for 4-8 frames (a half-sine bump, the knee moving with it) and set down up to 4 cm
    away; its contacts are off where it is up by more than 1 cm, so the force labels put the
    weight on the other foot. Standing people shuffle their feet; the generator's stances never
    leave the floor."""
    out, c = joints.astype(np.float64).copy(), contacts.copy()
    t_all = len(out)
    for side, (knee, ankle, toe) in {0: (4, 7, 10), 1: (5, 8, 11)}.items():
        other = contacts[:, 2 - 2 * side:4 - 2 * side].any(-1)
        flat = contacts[:, 2 * side] & contacts[:, 2 * side + 1] & other
        starts = np.flatnonzero(flat & ~np.r_[False, flat[:-1]])
        ends = np.flatnonzero(flat & ~np.r_[flat[1:], False])
        for s, e in zip(starts, ends):
            if e - s + 1 < min_frames or rng.random() >= prob:
                continue
            n = int(rng.integers(4, 9))
            a = int(rng.integers(s + 2, max(s + 3, e - n - 1)))
            if a + n > min(e, t_all - 1):
                continue
            h = rng.uniform(*lift)
            angle = rng.uniform(0, 2 * np.pi)
            step = rng.uniform(0, 0.04) * np.array([np.cos(angle), np.sin(angle)])
            phase = np.arange(n + 1) / n                                        # 0 .. 1 over the bump
            bump = np.sin(np.pi * phase)
            for k, tt in enumerate(range(a, a + n + 1)):
                delta = np.array([step[0] * phase[k], h * bump[k], step[1] * phase[k]])
                out[tt, [knee, ankle, toe]] += delta
                if h * bump[k] > 0.01:
                    c[tt, 2 * side:2 * side + 2] = False
            out[a + n + 1:e + 1, [knee, ankle, toe]] += np.array([step[0], 0.0, step[1]])   # set down there
    return out.astype(np.float32), c


def build_training_set(motions: int, per_type: int, seed: int, log, skeleton: str = "humanml3d",
                       heel: float = 0.0, shuffle: float = 0.0) -> tuple[list, list]:
    """(joints, forces) training sequences of scripts/footskate/train_vgrf.py (its module doc): every
    clean motion, with injected sliding, time-resampled, and with heel raises / foot shuffles."""
    from footskate import HUMANML3D, KIT
    from footskate.forces import forces_from_contacts
    from stablemo.data.synth import generate_motion

    rng = np.random.default_rng(seed)
    clean = []
    for _ in range(motions):
        m = generate_motion(rng)
        clean.append((m.joints.astype(np.float32), m.contacts.astype(bool)))
    for kind in TYPES:
        for i in range(per_type):
            clean.append(build_motion(kind, 10000 + i))
    log(f"{len(clean)} clean motions ({motions} generator mix + {per_type} x {len(TYPES)} types)")
    joints, forces = [], []

    def add(j: np.ndarray, c: np.ndarray, labels_from: np.ndarray | None = None) -> None:
        topo, fps = HUMANML3D, FPS
        if skeleton == "kit":
            topo, fps = KIT, KIT_FPS
            labels_from = None if labels_from is None else to_kit(labels_from, c)[0]
            j, c = to_kit(j, c)
        src = torch.from_numpy(labels_from if labels_from is not None else j)[None]
        f = forces_from_contacts(src, torch.from_numpy(c)[None], topo.feet, fps, 1)[0]
        joints.append(torch.from_numpy(j)), forces.append(f)

    for j, c in clean:
        add(j, c)
        slid = inject_sliding(j, c, rng, overshoot=float(rng.uniform(0, 0.35)), drift=float(rng.uniform(0, 1.0)))
        slid = slid + rng.normal(0, 0.005, slid.shape).astype(np.float32)
        add(slid, c, labels_from=j)
        rj, rc = resample(j, c, float(np.exp(rng.uniform(np.log(0.75), np.log(1.33)))))
        add(rj, rc)
        if heel > 0:
            hj, hc = heel_raise(j, c, rng, prob=heel)
            if not np.array_equal(hc, c):
                add(hj + rng.normal(0, 0.005, hj.shape).astype(np.float32), hc)
        if shuffle > 0:
            sj, sc = foot_shuffle(j, c, rng, prob=shuffle)
            if not np.array_equal(sc, c):
                add(sj + rng.normal(0, 0.005, sj.shape).astype(np.float32), sc)
    return joints, forces


def heldout_f1(model, seed: int = 1000, per_type: int = 6, skeleton: str = "humanml3d") -> dict:
    """Contact F1 per motion type of the height rule, `model` and the gated `model` on the benchmark's
    held-out motions (`seed`), sliding and clean: {"sliding/walk": {"rule": ..., "vgrf": ..., "gated": ...}, ...}."""
    from footskate.cleanup import detect_contacts

    data = build_set(seed, per_type, skeleton=skeleton)
    feet, fps, _ = _skeleton(data)
    out = {}
    for source in ("sliding", "clean"):
        x, lengths, truth = data[source], data["lengths"], data["contacts"]
        valid = torch.arange(x.shape[1])[None] < lengths[:, None]
        preds = {"rule": detect_contacts(x, lengths, feet, fps, 1)[0],
                 "vgrf": detect_contacts(x, lengths, feet, fps, 1, model)[0],
                 "gated": detect_contacts(x, lengths, feet, fps, 1, model, gate=True)[0]}
        kinds = np.array(data["kinds"])
        for kind in [*dict.fromkeys(data["kinds"]), "all"]:
            sel = torch.from_numpy(kinds == kind) if kind != "all" else torch.ones(len(kinds), dtype=torch.bool)
            out[f"{source}/{kind}"] = {k: _f1_score(*f1(p[sel], truth[sel], valid[sel])) for k, p in preds.items()}
    return out
