"""Fine-tune the V22 vGRF network on every motion type, sliding feet included; with
`--skeleton kit`, train the KIT-ML V21 the same way from the same motions mapped to KIT.

    python scripts/footskate/train_vgrf.py --out footskate/weights/v22_synth.safetensors \
        [--init footskate/weights/v22_synth.safetensors] [--motions 1200] [--per-type 60] \
        [--steps 3000] [--batch 32] [--window 64] [--lr 1e-4] [--seed 0] [--heel-raise 0.5] [--threads 1] [--log train.log]

Training motions: `--motions` from the synthetic dataset's generator (its usual mix of actions,
seed `--seed`) plus `--per-type` motions of each benchmark type (stablemo.bench.footskate.TYPES,
dance included) from seeds 10000 and up — the benchmark's tuning seed is 0 and its held-out seeds
are 1000-1999, so neither is trained on. Every motion is also added

- with injected sliding (root overshoot U(0, 35 %), per-foot drift U(0, 1) m/s, 5 mm joint
  noise): the force labels stay those of the clean motion, so the network learns that a foot
  carrying weight is a contact even when the generator lets it slide;
- time-resampled by U(0.75, 1.33) (speed augmentation; labels recomputed);
- with `--heel-raise P`: with a share P of its flat-foot stances on the ball of the foot
  (heel_raise; heel contact off, labels recomputed), plus 5 mm joint noise;
- with `--shuffle P`: with a share P of its double-support stances shuffling a foot (foot_shuffle:
  lifted 1.5-4 cm for 4-8 frames, contacts off), plus 5 mm joint noise. Tried and not
  shipped: validation margin +0.0041 against +0.0051 without it.

`--skeleton kit`: every sequence is mapped to the KIT-ML skeleton at 12.5 fps
(stablemo.bench.footskate.to_kit: a joint map, the metatarsal 2/3 of the way from ankle to toe)
and the network starts from the V22 with its first convolution's inputs mapped joint by joint
(stablemo.bench.footskate.kit_from_v22).

Labels: footskate.forces from the ground-truth contacts. Heading, position and ±10 % scale
augmentation as footskate.train. At the end, contact F1 per motion type of the network, the gated
network and the height rule on the benchmark's held-out sliding motions (seed 1000) is printed.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch


def _resample(joints: np.ndarray, contacts: np.ndarray, factor: float) -> tuple[np.ndarray, np.ndarray]:
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
    from footskate import HUMANML3D, KIT
    from footskate.forces import forces_from_contacts
    from stablemo.data.synth import generate_motion
    from stablemo.bench.footskate import (
        KIT_FPS,
        TYPES,
        build_motion,
        inject_sliding,
        to_kit,
    )

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
        topo, fps = HUMANML3D, 20.0
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
        rj, rc = _resample(j, c, float(np.exp(rng.uniform(np.log(0.75), np.log(1.33)))))
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
    from footskate.cleanup import detect_contacts
    from stablemo.bench.footskate import _f1_score, _skeleton, build_set, f1

    data = build_set(seed, per_type, skeleton=skeleton)
    FEET, fps, _ = _skeleton(data)
    out = {}
    for source in ("sliding", "clean"):
        x, lengths, truth = data[source], data["lengths"], data["contacts"]
        valid = torch.arange(x.shape[1])[None] < lengths[:, None]
        preds = {"rule": detect_contacts(x, lengths, FEET, fps, 1)[0],
                 "vgrf": detect_contacts(x, lengths, FEET, fps, 1, model)[0],
                 "gated": detect_contacts(x, lengths, FEET, fps, 1, model, gate=True)[0]}
        kinds = np.array(data["kinds"])
        for kind in [*dict.fromkeys(data["kinds"]), "all"]:
            sel = torch.from_numpy(kinds == kind) if kind != "all" else torch.ones(len(kinds), dtype=torch.bool)
            out[f"{source}/{kind}"] = {k: _f1_score(*f1(p[sel], truth[sel], valid[sel])) for k, p in preds.items()}
    return out


def main(argv=None) -> int:
    from footskate.train import fit
    from footskate.vgrf import load_vgrf, save_vgrf

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True)
    p.add_argument("--init", default=None, help="start from these weights (default: the shipped V22)")
    p.add_argument("--motions", type=int, default=1200)
    p.add_argument("--per-type", type=int, default=60)
    p.add_argument("--steps", type=int, default=3000)
    p.add_argument("--batch", type=int, default=32)
    p.add_argument("--window", type=int, default=64)
    p.add_argument("--lr", type=float, default=1e-4)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--skeleton", choices=("humanml3d", "kit"), default="humanml3d")
    p.add_argument("--log", default=None)
    p.add_argument("--shuffle", type=float, default=0.0,
                   help="also add each motion with this share of its double-support stances shuffling a foot "
                        "(foot_shuffle; 0: off)")
    p.add_argument("--heel-raise", type=float, default=0.0,
                   help="also add each motion with this share of its flat-foot stances on the ball of the foot "
                        "(heel_raise; 0: off)")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    lines: list[str] = []

    def log(msg: str) -> None:
        print(msg, flush=True)
        lines.append(msg)

    log("$ python scripts/footskate/train_vgrf.py " + " ".join(argv if argv is not None else sys.argv[1:]))
    model = load_vgrf(args.init, quiet=True)  # a bad --init is named before the data is built
    started = time.time()
    joints, forces = build_training_set(args.motions, args.per_type, args.seed, log, args.skeleton, args.heel_raise,
                                        args.shuffle)
    log(f"{len(joints)} training sequences ({sum(len(j) for j in joints)} frames) in {time.time() - started:.0f}s")
    if args.skeleton == "kit" and model.num_joints == 22:
        from stablemo.bench.footskate import kit_from_v22

        model = kit_from_v22(model)
    before = heldout_f1(model.eval(), skeleton=args.skeleton)
    fit(model, joints, forces, args.steps, args.batch, args.window, args.lr,
        torch.Generator().manual_seed(args.seed), log)
    after = heldout_f1(model, skeleton=args.skeleton)
    for key in after:
        log(f"{key:24s} rule {after[key]['rule']:.3f}  vgrf {before[key]['vgrf']:.3f} -> {after[key]['vgrf']:.3f}  "
            f"gated {before[key]['gated']:.3f} -> {after[key]['gated']:.3f}")
    save_vgrf(model, args.out, {"trained_on": "synthetic generator mix + footskate_bench types"
                                              + (", mapped to KIT-ML at 12.5 fps" if args.skeleton == "kit" else ""),
                                "init": args.init or "shipped v22_synth", "steps": args.steps, "batch": args.batch,
                                "window": args.window, "lr": args.lr, "seed": args.seed,
                                "fps": 12.5 if args.skeleton == "kit" else 20.0, "up_axis": "y",
                                "augment": "sliding (overshoot<=35%, drift<=1 m/s, 5 mm noise), speed x0.75-1.33"
                                           + (f", heel raise {args.heel_raise}" if args.heel_raise else "")
                                           + (f", foot shuffle {args.shuffle}" if args.shuffle else ""),
                                "labels": "footskate.forces (kinematics + contact labels)",
                                "heldout_f1": after})
    log(f"saved {args.out}")
    if args.log:
        from stablemo.io import write_text

        write_text(Path(args.log), "\n".join(lines) + "\n")
        write_text(Path(args.log).with_suffix(".json"), json.dumps({"before": before, "after": after}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    from footskate.errors import FootskateError
    from stablemo.errors import StableMoError, run_script

    def _main(argv):
        try:
            return main(argv)
        except FootskateError as err:  # bad --init weights: one line, exit 2
            raise StableMoError(str(err)) from None

    sys.exit(run_script(_main, "/".join(Path(__file__).parts[-2:]), sys.argv[1:]))
