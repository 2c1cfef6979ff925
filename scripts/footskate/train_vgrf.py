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

The augmentations, the training set and the held-out F1 are stablemo.bench.footskate's
(heel_raise, foot_shuffle, build_training_set, heldout_f1); this script parses the options,
trains and saves.

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

import torch

from stablemo.bench.footskate import build_training_set, heldout_f1


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
