"""`stablemo edit`: regenerate part of a motion with a (new) text, keeping the rest exactly.

    stablemo edit walk.features.npy --keep lower_body --text "a person waves both hands" --out edits
    stablemo edit walk.features.npy --keep frames=0:40,160:196 --text "a person jumps"   # in-betweening
    stablemo edit walk.features.npy --keep frames=0:60 --text "a person turns left"     # continuation
    stablemo edit walk.features.npy --keep frames=120:196 --text "a person walks"       # lead-in

The kept entries are in-painted inside the sampler (stablemo.diffusion.inpainting) and come back
exactly; `--keep` phrases are in stablemo.control.parts. Outputs as `stablemo generate`'s.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from stablemo.checks import check_finite, check_positive_int, check_seed
from stablemo.errors import StableMoError
from stablemo.inference.bundle import bundle_or_demo
from stablemo.io import check_output_dir, check_output_file, load_npy
from stablemo.outputs.files import check_output_name, slugify, write_motion


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="stablemo edit", description="Regenerate part of a motion, keeping the rest.")
    p.add_argument("features", help="the motion to edit: a .features.npy (T, 263) or (T, 251) file")
    p.add_argument("--keep", action="append", required=True,
                   help="what to keep (repeatable): lower_body, upper_body, root, contacts, joints=L_wrist,R_wrist, "
                        "frames=0:40,160:196")
    p.add_argument("--text", required=True, help="the text for the regenerated part")
    p.add_argument("--frames", type=int, default=None,
                   help="length of the result (default: the input's; longer continues it, e.g. with frames=0:N kept)")
    p.add_argument("--steps", type=int, default=None, help="sampler steps (default: the bundle's)")
    p.add_argument("--cfg", type=float, default=None, help="guidance scale (default: the bundle's)")
    p.add_argument("--sampler", default=None, help="sampler (default: the bundle's)")
    p.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    p.add_argument("--bundle", default=None, help="bundle folder (default: the packaged demo model)")
    p.add_argument("--out", default="outputs", help="output folder (default ./outputs)")
    p.add_argument("--name", default=None,
                   help="file name stem inside --out, a plain name without folders (default: from the text)")
    p.add_argument("--format", action="append", choices=["gif", "mp4", "bvh", "glb", "fbx"], default=None,
                   help="output format beside the .npy files (repeatable; default gif; glb/fbx: the skinned "
                        "mannequin, fbx needs Blender, docs/gltf.md)")
    p.add_argument("--no-render", action="store_true", help="write the .npy files only")
    p.add_argument("--device", default=None, help="cpu or cuda")
    return p


def _read_features(path: str) -> np.ndarray:
    arr = load_npy(path)
    if arr.ndim != 2:
        raise StableMoError(f"{path}: expected a (T, D) array of features, got shape {arr.shape}")
    if len(arr) == 0:
        raise StableMoError(f"{path}: the motion has no frames (shape {arr.shape}); nothing to edit")
    return arr.astype(np.float32)


def _length_problem(length: int, frames: int | None, path: str, low: int, high: int) -> str:
    """The one line for a result length outside the model's range [low, high], with its true cause."""
    if frames:
        return f"--frames: {length} frames is outside this model's range [{low}, {high}]"
    side = "short" if length < low else "long"
    hint = f"pass --frames {low} or more to continue it" if side == "short" else f"pass --frames {high} or fewer"
    return (f"{path}: the input has {length} frame{'s' * (length != 1)}, outside this model's range "
            f"[{low}, {high}] (the input is too {side}: {hint})")


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if "fbx" in (args.format or []) and not args.no_render:  # before anything is read, loaded or written
        from stablemo.gltf.fbx import check_blender

        check_blender()
    if not args.text.strip():
        raise StableMoError("--text: empty prompt")
    if args.steps is not None:
        check_positive_int("--steps", args.steps)
    if args.cfg is not None:
        check_finite("--cfg", args.cfg, low=0.0, high=100.0)
    if args.frames is not None:
        check_positive_int("--frames", args.frames)
    check_seed("--seed", args.seed)
    if args.name is not None:
        check_output_name(args.name, "--name")  # a plain name: the files never land outside --out
    feats = _read_features(args.features)
    bundle = bundle_or_demo(args.bundle)
    out = check_output_dir(args.out, "--out")
    slug = args.name if args.name is not None else slugify(args.text)
    formats = [] if args.no_render else list(dict.fromkeys(args.format or ["gif"]))
    for suffix in ["features.npy", "joints.npy"] + formats:
        check_output_file(out / f"{slug}.{suffix}", "--out")

    from stablemo.control import Inpaint
    from stablemo.control.parts import keep_mask
    from stablemo.inference.pipeline import Pipeline

    pipe = Pipeline.from_bundle(bundle, device=args.device)
    D = pipe.mean.shape[0]
    if feats.shape[1] != D:
        raise StableMoError(f"{args.features}: features have {feats.shape[1]} columns, this bundle's have {D}")
    length = args.frames or len(feats)
    if not pipe.min_length <= length <= pipe.max_length:
        raise StableMoError(_length_problem(length, args.frames, args.features, pipe.min_length, pipe.max_length))
    mask = keep_mask(args.keep, len(feats), pipe.skeleton)
    spec = Inpaint(feats, mask)
    spec.resolve(length, D, what=f"--keep on {args.features}")  # before any network call
    result = pipe.generate([args.text], length, seed=args.seed, sampler=args.sampler, steps=args.steps,
                           cfg=args.cfg, inpaint=[spec], progress=True)
    written = write_motion(out, slug, result.feature_list()[0], result.joint_list()[0], pipe, formats,
                           f"{args.text} (kept: {', '.join(args.keep)})", warn=lambda line: print(line, file=sys.stderr))
    kept = int(mask[:length].any(1).sum())
    print(f"{args.text!r}: {length} frames ({kept} with kept entries) -> {out}/{{{', '.join(written)}}}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
