"""`stablemo generate`: prompts -> features .npy, joints .npy and an animation per prompt.

    stablemo generate "a person walks forward, then waves their right hand" --seconds 6 --out outputs
    stablemo generate --prompts prompts.txt --frames 120 --steps 10 --cfg 2.5 --format mp4
    stablemo generate "a person walks forward" --control path.npz     # joint targets (docs/control.md)
    stablemo generate "a person waves" --format glb --format fbx         # a skinned mannequin (docs/gltf.md)
    stablemo generate --timeline timeline.txt                            # prompts over time, one motion

Every file is written atomically: an interrupted run leaves no half-written output.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from stablemo.checks import check_finite, check_positive_int, check_seed
from stablemo.errors import StableMoError
from stablemo.inference.bundle import DEMO_BUNDLE, bundle_or_demo
from stablemo.inference.config import DEFAULT_SECONDS
from stablemo.io import check_output_dir, check_output_file
from stablemo.outputs.files import unique_slugs, write_motion


def read_prompts(path: str) -> list[str]:
    """One prompt per line; blank lines and lines starting with '#' are skipped."""
    from stablemo.io import read_text

    file = Path(path)
    content = read_text(file, "prompts file")
    prompts = [line.strip() for line in content.splitlines()]
    prompts = [p for p in prompts if p and not p.startswith("#")]
    if not prompts:
        raise StableMoError(f"{file}: no prompts in the file")
    return prompts


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="stablemo generate", description="Generate motions from text with a trained bundle.")
    p.add_argument("prompt", nargs="*", help="text prompt(s), e.g. \"a person walks forward and waves\"")
    p.add_argument("--prompts", metavar="FILE", help="file with one prompt per line (added to the positional ones)")
    length = p.add_mutually_exclusive_group()
    length.add_argument("--seconds", type=float,
                        help="motion length in seconds (default: each prompt's own, from the bundle's length predictor; "
                             f"{DEFAULT_SECONDS:g} s for a bundle without one)")
    length.add_argument("--frames", type=int, help="motion length in frames")
    p.add_argument("--steps", type=int, default=None,
                   help="sampler steps (default: the bundle's inference config: 10, or a student's 1-4)")
    p.add_argument("--cfg", type=float, default=None,
                   help="classifier-free guidance scale (default: the bundle's, 2.5 for the paper; 1 = off; a student's absorbed 1 + w)")
    p.add_argument("--sampler", default=None, help="ddpm, ddim, dpmpp_2m, dpmpp_2m_sde (default: the bundle kind's default)")
    p.add_argument("--seed", type=int, default=0, help="seed; prompt i uses seed + i (default 0)")
    p.add_argument("--bundle", default=None, help=f"bundle folder (default: the packaged demo model, {DEMO_BUNDLE})")
    p.add_argument("--out", default="outputs", help="output folder (default ./outputs)")
    p.add_argument("--format", action="append", choices=["gif", "mp4", "bvh", "glb", "fbx"], default=None,
                   help="output format, may repeat: gif (default), mp4 (needs ffmpeg), bvh (for Blender and game engines, "
                        "docs/bvh.md), glb (the motion on a skinned mannequin, docs/gltf.md), fbx (the same, needs Blender)")
    p.add_argument("--no-render", action="store_true", help="write the .npy files only")
    p.add_argument("--whole", action="store_true",
                   help="give the network each prompt (or --timeline segment) whole at the length asked for; by "
                        "default a prompt that says an order (\"X, then Y\") is generated part by part, a length "
                        "longer than the text asks for ends standing, and a turn the text sizes (\"a quarter turn\", \"90 degrees\") "
                        "turns that far (docs/inference.md, \"Prompts in parts\", \"Turns as said\")")
    p.add_argument("--footskate", action="store_true",
                   help="remove foot skating at the last denoising step (StableMoFusion*, vGRF-guided)")
    p.add_argument("--footskate-weights", default=None,
                   help="vGRF weights for --footskate (default: StableMo's own V22, V21 for KIT-ML; or one distilled by you)")
    p.add_argument("--control", metavar="FILE.npz", default=None,
                   help="joint targets for every prompt: positions (T, J, 3) and mask (T, J) (docs/control.md); "
                        "the length defaults to the file's T")
    p.add_argument("--no-control-guidance", dest="control_guidance", action="store_false",
                   help="with --control: no guidance refinement of x0 towards the targets (a ControlNet bundle "
                        "then follows them by its hint alone; other bundles ignore the targets)")
    p.add_argument("--timeline", metavar="FILE", default=None,
                   help="lines 'start_s end_s text' (contiguous from 0): one motion of the whole length, its "
                        "windows joined by in-painting (docs/long_motion.md)")
    p.add_argument("--raw", action="store_true",
                   help="write the network's own output, without the finishing step that puts every motion on "
                        "the bundle's rigid body and on the floor (docs/inference.md): for studying the model; "
                        "its bones change length and its feet may sink")
    p.add_argument("--dtype", default=None, help="network precision: fp32, bf16 (CPU/GPU) or fp16 (GPU); default fp32 on CPU, fp16 on GPU")
    p.add_argument("--device", default=None, help="cpu or cuda (default: cuda if available)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if "fbx" in (args.format or []) and not args.no_render:  # before anything is loaded or computed
        from stablemo.gltf.fbx import check_blender

        check_blender()
    if args.timeline is not None:
        if args.raw:
            raise StableMoError("--raw: not with --timeline (a timeline's windows are joined and finished as one motion)")
        from stablemo.cli.timeline import run_timeline

        _check_numbers(args)
        return run_timeline(args, bundle_or_demo(args.bundle), check_output_dir(args.out, "--out"))
    prompts = [p.strip() for p in args.prompt]
    for i, p in enumerate(prompts):
        if not p:
            raise StableMoError(f"prompt {i + 1}: empty prompt")
    if args.prompts:
        prompts += read_prompts(args.prompts)
    if not prompts:
        raise StableMoError("prompt: give a text prompt or --prompts FILE")
    _check_numbers(args)
    bundle = bundle_or_demo(args.bundle)
    out = check_output_dir(args.out, "--out")
    slugs = unique_slugs(prompts)
    formats = [] if args.no_render else list(dict.fromkeys(args.format or ["gif"]))
    suffixes = ["features.npy", "joints.npy"] + formats
    for slug in slugs:  # every file is checked before the compute, so a bad --out costs nothing
        for suffix in suffixes:
            check_output_file(out / f"{slug}.{suffix}", "--out")

    from stablemo.inference.hooks import make_hooks
    from stablemo.inference.pipeline import Pipeline, Request

    pipe = Pipeline.from_bundle(bundle, device=args.device, dtype=args.dtype)
    control = None
    if args.control is not None:
        from stablemo.control.files import load_control

        control = load_control(args.control, pipe.skeleton)
    if args.frames is not None:
        frames, flag = args.frames, f"--frames {args.frames}"
    elif args.seconds is not None:
        frames, flag = round(args.seconds * pipe.fps), f"--seconds {args.seconds:g}"
    elif control is not None:
        frames, flag = len(control.positions), f"--control {args.control} ({len(control.positions)} frames)"
    else:  # each prompt's own length (Pipeline.text_lengths)
        frames, flag = None, None
    if flag:
        pipe.inference.check_length(frames, flag)
    targets = None
    if control is not None:  # checked against the length now, before any network call
        targets = control.resolve(frames, pipe.skeleton, what=f"--control {args.control}")
    hooks = make_hooks(pipe, footskate=args.footskate, footskate_weights=args.footskate_weights)
    request = Request(prompts, frames, seed=args.seed, sampler=args.sampler, steps=args.steps, cfg=args.cfg,
                      hooks=hooks, progress=True, control=[control] * len(prompts) if control else None,
                      control_guidance=args.control_guidance, finish=not args.raw, plan=not args.whole)
    # generate() checks every setting before its first network call, and raises, writing nothing,
    # if any motion is not finite
    result = pipe.generate(request)
    from stablemo.text.familiar import Unfamiliar

    for unfamiliar in result.info.get("unfamiliar", []):
        print(f"warning: {Unfamiliar(**unfamiliar).message()}", file=sys.stderr)
    sources = result.info["lengths_from"]
    for text, slug, feats, joints, source, plan, turns in zip(prompts, slugs, result.feature_list(), result.joint_list(),
                                                              sources, result.info["plans"], result.info["turns"]):
        written = write_motion(out, slug, feats, joints, pipe, formats, text, targets,
                               warn=lambda line: print(line, file=sys.stderr))
        said = {"text": ", length from the text", "default": ", default length"}.get(source, "")
        if plan:
            said += "; in parts: " + ", ".join(f"{p['text']!r} {(p['end'] - p['start']) / pipe.fps:g} s" for p in plan)
        for turn in turns or []:  # the angle the words say, which the body was turned by
            said += f"; turning {turn['degrees']:g} degrees" + (f" to the {turn['side']}" if turn["side"] else "")
        print(f"{text!r}: {len(feats)} frames ({len(feats) / pipe.fps:g} s{said}) -> {out}/{{{', '.join(written)}}}")
    return 0


def _check_numbers(args) -> None:
    """Numeric flags: finite and in range (and options that need another), before anything is loaded."""
    from stablemo.skating.cleanup import check_footskate_options

    check_footskate_options(args.footskate, args.footskate_weights, flags=True)
    if args.steps is not None:
        check_positive_int("--steps", args.steps)
    if args.cfg is not None:
        check_finite("--cfg", args.cfg, low=0.0, high=100.0)
    if args.seconds is not None:
        check_finite("--seconds", args.seconds, low=0.0, strict=True)
    if args.frames is not None:
        check_positive_int("--frames", args.frames)
    check_seed("--seed", args.seed)


if __name__ == "__main__":
    sys.exit(main())
