"""`stablemo export CKPT --out DIR`: a Lightning training checkpoint -> an inference bundle (stablemo.training.export)."""

from __future__ import annotations

import argparse

from stablemo.checks import check_finite, check_positive_int
from stablemo.inference.bundle import check_bundle_target
from stablemo.training.export import WEIGHTS, export


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="stablemo export", description=__doc__.splitlines()[0])
    parser.add_argument("ckpt", help="Lightning checkpoint (.ckpt) written by `stablemo fit`")
    parser.add_argument("--out", required=True,
                        help="bundle folder to write: a new or empty folder (written atomically)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace an existing bundle at --out (never anything that is not a bundle)")
    parser.add_argument("--weights", choices=WEIGHTS, default="ema", help="EMA weights (default) or the raw weights")
    parser.add_argument("--cfg", type=float, default=None,
                        help="the bundle's default classifier-free guidance scale (its inference config; default: the "
                             "paper's 2.5 for a diffusion model, a student's absorbed one); choose it on the val split, "
                             "e.g. scripts/results/cfg_sweep.py")
    parser.add_argument("--steps", type=int, default=None,
                        help="the bundle's default number of sampler steps (its inference config; default: the "
                             "paper's 10 for a diffusion model, a student's trained ones), 1-1000")
    args = parser.parse_args(argv)
    if args.cfg is not None:
        check_finite("--cfg", args.cfg, low=0.0, high=100.0)
    if args.steps is not None:
        check_finite("--steps", check_positive_int("--steps", args.steps), high=1000)
    check_bundle_target(args.out, args.overwrite, flag="--out")  # before the checkpoint is even read
    path = export(args.ckpt, args.out, weights=args.weights, overwrite=args.overwrite, cfg=args.cfg,
                  steps=args.steps)
    print(f"wrote {path}")
    return 0
