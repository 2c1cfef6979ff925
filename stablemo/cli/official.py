"""`stablemo import-official CKPT --out BUNDLE`: a published StableMoFusion checkpoint -> a bundle."""

from __future__ import annotations

import argparse

from stablemo.inference.bundle import check_bundle_target
from stablemo.official.convert import DATASETS, DEFAULT_CLIP, import_official


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(
        prog="stablemo import-official",
        description="Convert a published StableMoFusion checkpoint (T2MUnet, e.g. "
                    "checkpoints/t2m/t2m_condunet1d_batch64/model/latest.tar) into a StableMo bundle "
                    "that generates, cleans feet, distils and benchmarks like StableMo's own (docs/official.md).")
    parser.add_argument("ckpt", help="the official checkpoint (latest.tar), read with torch.load(weights_only=True)")
    parser.add_argument("--out", required=True, help="bundle folder to write: a new or empty folder (written atomically)")
    parser.add_argument("--clip", default=DEFAULT_CLIP,
                        help=f"the CLIP ViT-B/32 text encoder: a local transformers folder (CLIPModel or "
                             f"CLIPTextModel with its tokenizer) or a hub id in the local cache (default {DEFAULT_CLIP})")
    parser.add_argument("--dataset", choices=sorted(DATASETS),
                        help="skeleton, fps and feature width (default: opt.txt's dataset_name, else the width)")
    parser.add_argument("--no-ema", action="store_true", help="import the raw weights ('encoder') instead of the EMA ones")
    parser.add_argument("--meta", help="folder with the model's mean.npy and std.npy (default: NAME/meta beside "
                                       "NAME/model/latest.tar)")
    parser.add_argument("--mean", help="the model's Mean .npy (with --std; instead of --meta)")
    parser.add_argument("--std", help="the model's Std .npy (with --mean)")
    parser.add_argument("--feat-bias", type=float, default=None,
                        help="with --mean/--std of a dataset (Mean.npy/Std.npy): divide the Std of the root features "
                             "and foot contacts by this, as the official training does (its --feat_bias, default 5)")
    parser.add_argument("--opt", help="the run's opt.txt (default: NAME/opt.txt if present; prediction type, "
                                      "schedule, dataset)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing bundle at --out")
    args = parser.parse_args(argv)
    check_bundle_target(args.out, args.overwrite, flag="--out")  # before anything is read
    path = import_official(args.ckpt, args.out, clip=args.clip, dataset=args.dataset, ema=not args.no_ema,
                           meta=args.meta, mean=args.mean, std=args.std, opt=args.opt, feat_bias=args.feat_bias,
                           overwrite=args.overwrite)
    print(f"wrote {path}")
    return 0
