"""Issue #39's targets on the demo teacher and 1-step student: raw network output against what the user receives.

    OMP_NUM_THREADS=2 .venv/bin/python scripts/results/kinematic_report.py [--models teacher,student]
        [--frames 120,196] [--prompts-per-category 8] [--seeds 4] [--no-evaluator] [--json out.json] [--summary docs/data/results/kinematics.json]

72 prompts (8 per category: walks, runs, jumps, turns, waves, kicks, squats, side steps, standing; the
synthetic data's vocabulary) x 4 seeds at 120 frames (the default 6 s) and 196 frames, each model's
own sampler, steps and CFG. Per row (model, length, raw or final): bone-length change (max and
median over motions), the lowest foot's 1st percentile (mean and worst motion), the share of frames
below -1 cm, the stance foot's height on standing/walking prompts and its speed, foot acceleration,
the airborne share on jump and on standing/walking prompts, the end effectors' displacement raw ->
final, FID against synthetic ground truth of the same actions and R@3 (the packaged evaluator).
What each measure means: docs/evaluation.md; the library is stablemo.bench.kinematic_report.
Prints a markdown table; --json keeps every per-motion number.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

from stablemo.bench import kinematic_report as report
from stablemo.checks import check_positive_int
from stablemo.errors import StableMoError, run_script
from stablemo.inference.bundle import EVALUATOR_SYNTH, is_bundle

MODELS = report.DEMO_MODELS


def parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--models", default="teacher,student", help="comma-separated: teacher, student ('' for none)")
    p.add_argument("--bundle", action="append", default=[], metavar="LABEL=PATH",
                   help="also score the bundle at PATH under LABEL (repeatable), e.g. a candidate before shipping it")
    p.add_argument("--frames", default="120,196", help="comma-separated motion lengths in frames")
    p.add_argument("--prompts-per-category", type=int, default=8)
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--summary", help="also write the table's numbers (no per-motion values), e.g. "
                   "docs/data/results/kinematics.json, which docs/results.md shows")
    p.add_argument("--no-evaluator", dest="evaluator", action="store_false", help="skip FID and R@3")
    p.add_argument("--seed", type=int, default=0, help="draws the prompts' parameters and captions")
    p.add_argument("--device", default=None)
    p.add_argument("--json", help="write every row (per-motion numbers included) here")
    return p.parse_args(argv)


def main(argv: list[str]) -> int:
    args = parse(argv)
    models = [m.strip() for m in args.models.split(",") if m.strip()]
    unknown = [m for m in models if m not in MODELS]
    if unknown:
        raise StableMoError(f"--models: {unknown}; choose from {', '.join(MODELS)}")
    extra = []
    for spec in args.bundle:
        label, sep, path = spec.partition("=")
        if not sep or not label.strip() or not path.strip():
            raise StableMoError(f"--bundle: expected LABEL=PATH, got {spec!r}")
        if not is_bundle(Path(path)):
            raise StableMoError(f"--bundle {spec}: {path} is not a bundle folder (no StableMo config.json)")
        extra.append((label.strip(), path))
    if not models and not extra:
        raise StableMoError("--models and --bundle: nothing to score")
    frames = report.parse_frames(args.frames)
    report.check_prompts(check_positive_int("--prompts-per-category", args.prompts_per_category))
    check_positive_int("--seeds", args.seeds)
    for flag, path in (("--json", args.json), ("--summary", args.summary)):
        if path:
            from stablemo.io import check_output_file

            check_output_file(path, flag)
    from stablemo.inference.pipeline import Pipeline

    pipes = [(MODELS[m][0], Pipeline.from_bundle(MODELS[m][1], device=args.device)) for m in models]
    pipes += [(label, Pipeline.from_bundle(path, device=args.device)) for label, path in extra]
    for _, pipe in pipes:
        for n in frames:
            pipe.inference.check_length(n, "--frames")
    evaluator = None
    if args.evaluator:
        from stablemo.eval.text_motion import load_text_motion_evaluator

        evaluator = load_text_motion_evaluator(EVALUATOR_SYNTH, "humanml3d")
    start = time.perf_counter()
    result = report.run(pipes, frames, args.prompts_per_category, args.seeds, evaluator, args.seed)
    named = models + [f"{label}={path}" for label, path in extra]
    result["settings"].update(models=named, seconds=time.perf_counter() - start, threads=torch.get_num_threads())
    s = result["settings"]
    print(f"\n{s['prompts']} prompts x {s['seeds']} seeds per row; {s['seconds']:.0f} s in all "
          f"({s['threads']} threads)\n")
    print(report.render(result["rows"]))
    if args.json:
        from stablemo.io import write_text

        write_text(args.json, json.dumps(result, indent=1) + "\n")
        print(f"\nwrote {args.json}")
    if args.summary:
        from stablemo.io import write_text

        result["settings"]["measured"] = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
        write_text(args.summary, json.dumps(report.compact(result), indent=1) + "\n")
        print(f"wrote {args.summary}")
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main, "kinematic_report.py", sys.argv[1:]))
