"""`stablemo generate`: prompts -> features .npy, joints .npy and an animation per prompt.

    stablemo generate "a person walks forward, then waves their right hand" --seconds 6 --out outputs
    stablemo generate --prompts prompts.txt --frames 120 --steps 10 --cfg 2.5 --format mp4
    stablemo generate "a person walks forward" --control path.npz     # joint targets (docs/control.md)
    stablemo generate --timeline timeline.txt                            # prompts over time, one motion

Every file is written atomically: an interrupted run leaves no half-written output.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
from pathlib import Path

from stablemo.errors import StableMoError
from stablemo.inference.config import check_finite, check_positive_int, check_seed
from stablemo.io import check_output_dir, check_output_file

DEFAULT_BUNDLE = Path(__file__).resolve().parent / "assets" / "demo_bundle"
DEFAULT_SECONDS = 6.0


def slugify(text: str, max_len: int = 60) -> str:
    """A file name stem from user text: only [a-z0-9-], never empty, never '.', '..' or a path."""
    slug = re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")[:max_len].rstrip("-")
    return slug or "motion"


def unique_slugs(texts: list[str]) -> list[str]:
    """One distinct file stem per text, in order. The first text of each slug keeps it; a repeat
    gets the first `<slug>-N` (N = 2, 3, ...) that no text's own slug and no earlier pick took, so
    "x", "x", "x 2" -> x, x-3, x-2 (never two prompts writing the same files)."""
    slugs = [slugify(text) for text in texts]
    taken = set(slugs)
    seen: set[str] = set()
    out = []
    for slug in slugs:
        if slug in seen:
            n = 2
            while f"{slug}-{n}" in taken:
                n += 1
            taken.add(f"{slug}-{n}")
            out.append(f"{slug}-{n}")
        else:
            seen.add(slug)
            out.append(slug)
    return out


NAME_MAX = 200  # bytes; the longest suffix (".features.npy") and the temp name's must still fit 255


def check_output_name(name: str, flag: str = "--name") -> str:
    """A user-given file name stem: one plain name inside --out, so the outputs never land elsewhere.
    Refused: empty, a path (any separator, '..', absolute), a hidden name, control characters."""
    if not name or not name.strip():
        raise StableMoError(f"{flag}: empty name")
    seps = {"/", "\\", os.sep, os.altsep or "/"}
    if any(sep in name for sep in seps) or os.path.isabs(name) or name in (".", ".."):
        raise StableMoError(f"{flag}: {name!r} is a path; give a plain file name (the files go into --out)")
    if name.startswith("."):
        raise StableMoError(f"{flag}: {name!r} starts with '.'; give a plain, visible file name")
    if any(ord(c) < 32 or ord(c) == 127 for c in name):
        raise StableMoError(f"{flag}: {name!r} holds control characters; give a plain file name")
    if len(os.fsencode(name)) > NAME_MAX:
        raise StableMoError(f"{flag}: name is {len(os.fsencode(name))} bytes long; at most {NAME_MAX}")
    return name


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
    length.add_argument("--seconds", type=float, help=f"motion length in seconds (default {DEFAULT_SECONDS:g}, capped at the model's maximum)")
    length.add_argument("--frames", type=int, help="motion length in frames")
    p.add_argument("--steps", type=int, default=None,
                   help="sampler steps (default: the bundle's inference config: 10, or a student's 1-4)")
    p.add_argument("--cfg", type=float, default=None,
                   help="classifier-free guidance scale (default: the bundle's, 2.5 for the paper; 1 = off; a student's absorbed 1 + w)")
    p.add_argument("--sampler", default=None, help="ddpm, ddim, dpmpp_2m, dpmpp_2m_sde (default: the bundle kind's default)")
    p.add_argument("--seed", type=int, default=0, help="seed; prompt i uses seed + i (default 0)")
    p.add_argument("--bundle", default=None, help=f"bundle folder (default: the packaged demo model, {DEFAULT_BUNDLE})")
    p.add_argument("--out", default="outputs", help="output folder (default ./outputs)")
    p.add_argument("--format", action="append", choices=["gif", "mp4", "bvh"], default=None,
                   help="output format, may repeat: gif (default), mp4 (needs ffmpeg), bvh (for Blender and game engines, docs/bvh.md)")
    p.add_argument("--no-render", action="store_true", help="write the .npy files only")
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
    p.add_argument("--dtype", default=None, help="network precision: fp32, bf16 (CPU/GPU) or fp16 (GPU); default fp32 on CPU, fp16 on GPU")
    p.add_argument("--device", default=None, help="cpu or cuda (default: cuda if available)")
    return p


def _bundle_path(arg: str | None) -> Path:
    if arg is not None:
        path = Path(arg)
        if not path.is_dir():
            raise StableMoError(f"--bundle: {path}: bundle folder not found")
        return path
    if not (DEFAULT_BUNDLE / "config.json").is_file():
        raise StableMoError(
            f"no bundle given and the packaged demo model is missing ({DEFAULT_BUNDLE}). Train one "
            "(`stablemo fit --config <config.yaml>`), export it (`stablemo export CKPT --out DIR`) "
            "and pass `--bundle DIR`"
        )
    return DEFAULT_BUNDLE


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.timeline is not None:
        from stablemo.cli.timeline import run_timeline

        _check_numbers(args)
        return run_timeline(args, _bundle_path(args.bundle), check_output_dir(args.out, "--out"))
    prompts = [p.strip() for p in args.prompt]
    for i, p in enumerate(prompts):
        if not p:
            raise StableMoError(f"prompt {i + 1}: empty prompt")
    if args.prompts:
        prompts += read_prompts(args.prompts)
    if not prompts:
        raise StableMoError("prompt: give a text prompt or --prompts FILE")
    _check_numbers(args)
    bundle = _bundle_path(args.bundle)
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
    else:
        frames, flag = min(round(DEFAULT_SECONDS * pipe.fps), pipe.max_length), None
    if flag and not pipe.min_length <= frames <= pipe.max_length:
        raise StableMoError(
            f"{flag}: {frames} frames is outside this model's range [{pipe.min_length}, {pipe.max_length}] frames "
            f"({pipe.min_length / pipe.fps:g}-{pipe.max_length / pipe.fps:g} s at {pipe.fps:g} fps)"
        )
    targets = None
    if control is not None:  # checked against the length now, before any network call
        targets = control.resolve(frames, pipe.skeleton, what=f"--control {args.control}")
    hooks = make_hooks(pipe, footskate=args.footskate, footskate_weights=args.footskate_weights)
    request = Request(prompts, frames, seed=args.seed, sampler=args.sampler, steps=args.steps, cfg=args.cfg,
                      hooks=hooks, progress=True, control=[control] * len(prompts) if control else None,
                      control_guidance=args.control_guidance)
    # generate() checks every setting before its first network call, and raises, writing nothing,
    # if any motion is not finite
    result = pipe.generate(request)
    for text, slug, feats, joints in zip(prompts, slugs, result.feature_list(), result.joint_list()):
        written = write_motion(out, slug, feats, joints, pipe, formats, text, targets)
        print(f"{text!r}: {frames} frames -> {out}/{{{', '.join(written)}}}")
    return 0


def write_motion(out: Path, slug: str, feats, joints, pipe, formats: list[str], title: str,
                 targets=None) -> list[str]:
    """Features, joints and each of `formats` (gif, mp4: an animation; bvh) of one motion; the names written.
    targets: joint-control targets (positions, mask) drawn in the animation."""
    from stablemo.io import save_npy

    save_npy(out / f"{slug}.features.npy", feats)
    save_npy(out / f"{slug}.joints.npy", joints)
    written = [f"{slug}.features.npy", f"{slug}.joints.npy"]
    for fmt in formats:
        if fmt == "bvh":
            from stablemo.bvh import write_bvh

            write_bvh(out / f"{slug}.bvh", joints, skeleton=pipe.skeleton, source_fps=pipe.fps)
        else:
            from stablemo.outputs.render import render_animation

            render_animation(joints, out / f"{slug}.{fmt}", pipe.skeleton, fps=pipe.fps, title=title,
                             targets=targets)
        written.append(f"{slug}.{fmt}")
    return written


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
