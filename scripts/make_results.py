"""Write docs/results.md: the demo model on the synthetic benchmark, samplers and students side by side.

    python scripts/make_results.py --bundle stablemo/assets/demo_bundle --data data/synth \
        --evaluator outputs/evaluator_synth/checkpoints/last.ckpt \
        [--student LCM=bundles/demo_lcm --student PCM=bundles/demo_pcm] [--replications 20] \
        [--ddpm-items 96 --ddpm-replications 1] [--out docs/results.md]

Every row is scored by the same evaluator on the same test split with the same replication seeds.
AITS (batch 1, model loaded, each sentence encoding its own text) is measured for every row in this
one run, after the quality rows, round-robin sentence by sentence so the rows' ratios are measured
side by side (never taken from an earlier run, even with `--resume`). The
1000-step DDPM row is expensive on a CPU: it runs on `--ddpm-items` items for `--ddpm-replications`
replication(s), and is compared with the 10-step SDE row scored on exactly the same items.
The report (markdown and JSON) is rewritten after every row, marked partial until the last one;
`--resume` continues a stopped run with the same settings.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch

from stablemo.data import MotionDataset
from stablemo.errors import run_script
from stablemo.eval import metrics
from stablemo.eval.command import REAL_ROW, evaluate, load_text_motion_evaluator
from stablemo.io import write_text
from stablemo.pipeline import Pipeline
from stablemo.inference_config import PAPER_CFG

COLUMNS = [("r1", "R@1 ↑"), ("r3", "R@3 ↑"), ("fid", "FID ↓"), ("mm_dist", "MM-Dist ↓"), ("diversity", "Diversity →")]


def make_generate(pipe: Pipeline, steps: int, sampler: str | None, cfg: float):
    lo, hi = pipe.min_length, pipe.max_length

    def generate(texts, lengths, seeds):
        out = pipe.generate(texts, [min(max(n, lo), hi) for n in lengths], steps=steps, cfg=cfg, sampler=sampler,
                            seed=seeds)
        return out.features, out.joints

    return generate


def aits(runs: list[tuple[str, Pipeline, int, str | None]], items: list[dict], cfg: float) -> dict[str, float]:
    """AITS of every run {name: seconds}, measured side by side with cold text caches."""
    methods = {name: metrics.pipeline_method(pipe, steps, cfg, sampler) for name, pipe, steps, sampler in runs}
    return metrics.average_inference_times(methods, [it["text"] for it in items], [it["length"] for it in items])


def cell(row: dict, key: str) -> str:
    if key not in row:
        return "–"
    if len(row[key]["values"]) < 2:  # one replication has no interval
        return f"{row[key]['mean']:.3f}"
    return f"{row[key]['mean']:.3f} ± {row[key]['conf95']:.3f}"


def table(rows: list[tuple[str, dict, float | None]]) -> str:
    header = "| Method | " + " | ".join(h for _, h in COLUMNS) + " | AITS (s) |"
    lines = [header, "|" + "---|" * (len(COLUMNS) + 2)]
    for name, row, t in rows:
        lines.append(f"| {name} | " + " | ".join(cell(row, k) for k, _ in COLUMNS) + f" | {'–' if t is None else f'{t:.4f}'} |")
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bundle", required=True)
    p.add_argument("--data", required=True)
    p.add_argument("--evaluator", required=True)
    p.add_argument("--student", action="append", default=[], metavar="NAME=DIR", help="consistency student bundle")
    p.add_argument("--replications", type=int, default=20)
    p.add_argument("--max-items", type=int, default=None, help="items scored per replication (default: the split)")
    p.add_argument("--ddpm-items", type=int, default=96)
    p.add_argument("--ddpm-replications", type=int, default=1)
    p.add_argument("--aits-sentences", type=int, default=20)
    p.add_argument("--cfg", type=float, default=PAPER_CFG)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="docs/results.md")
    p.add_argument("--resume", action="store_true",
                   help="keep the rows already in OUT's .json when it was written with the same settings")
    args = p.parse_args(argv)

    torch.manual_seed(args.seed)
    teacher = Pipeline.from_bundle(args.bundle)
    data = MotionDataset.from_folder(args.data, "test", teacher.config.get("dataset", "humanml3d"), crop="eval",
                                     seed=args.seed, progress=False)
    evaluator = load_text_motion_evaluator(args.evaluator, teacher.config.get("dataset", "humanml3d"))
    rng = np.random.default_rng(args.seed)
    timing_items = [data[int(i)] for i in rng.choice(len(data), args.aits_sentences, replace=False)]
    common = dict(replications=args.replications, seed=args.seed, max_items=args.max_items, progress=True)
    started = time.time()

    runs: list[tuple[str, Pipeline, int, str | None]] = [
        ("Teacher, SDE-DPM-Solver++ 2M, 10 steps", teacher, 10, "dpmpp_2m_sde"),
        ("Teacher, DPM-Solver++ 2M (ODE), 10 steps", teacher, 10, "dpmpp_2m"),
        ("Teacher, DDIM, 10 steps", teacher, 10, "ddim"),
        ("Teacher, DDIM, 4 steps", teacher, 4, "ddim"),
        ("Teacher, DDIM, 1 step", teacher, 1, "ddim"),
    ]
    for spec in args.student:
        name, _, path = spec.partition("=")
        student = Pipeline.from_bundle(path)
        for steps in (1, 2, 4):
            runs.append((f"{name} student, {steps} step{'s' if steps > 1 else ''}", student, steps, None))

    settings = {"bundle": args.bundle, "data": args.data, "evaluator": args.evaluator, "students": args.student,
                "replications": args.replications, "max_items": args.max_items, "ddpm_items": args.ddpm_items,
                "ddpm_replications": args.ddpm_replications, "cfg": args.cfg, "seed": args.seed}
    raw: dict = {"settings": settings, "rows": {}, "aits": {}, "subset": {}, "complete": False}
    json_path = Path(args.out).with_suffix(".json")
    if args.resume and json_path.is_file():
        previous = json.loads(json_path.read_text())
        if previous.get("settings") == settings:
            raw.update({k: previous.get(k, raw[k]) for k in ("rows", "subset")})
            print(f"resuming: {len(raw['rows'])} row(s) and {len(raw['subset'])} subset row(s) from {json_path}")
        else:
            print(f"not resuming: {json_path} was written with other settings")
    claim_runs = [("Teacher, DDPM, 1000 steps", 1000, "ddpm"), ("Teacher, SDE-DPM-Solver++ 2M, 10 steps", 10, "dpmpp_2m_sde")]
    total = len(runs) + (len(claim_runs) if args.ddpm_replications else 0)

    def rows_done() -> int:
        return len([n for n, *_ in runs if n in raw["rows"]]) + len(raw["subset"])

    kept = rows_done()

    def save() -> None:
        done = rows_done()
        raw["complete"] = done == total
        write_text(args.out, render(args, argv, raw, runs, (time.time() - started) / 60, done, total, kept))
        write_text(json_path, json.dumps(raw, indent=2) + "\n")

    for name, pipe, steps, sampler in runs:
        if name in raw["rows"]:
            continue
        print(f"== {name}", flush=True)
        result = evaluate(data, evaluator, make_generate(pipe, steps, sampler, args.cfg), row_name=name, **common)
        raw["rows"][REAL_ROW] = result["rows"][REAL_ROW]
        raw["rows"][name] = result["rows"][name]
        save()
    print(f"== AITS of {len(runs)} rows, side by side over {len(timing_items)} sentences", flush=True)
    raw["aits"] = aits(runs, timing_items, args.cfg)
    save()

    # Table 5's claim on a subset: 1000 DDPM steps vs 10 SDE steps on the same items and seeds
    if args.ddpm_replications:
        subset = dict(replications=args.ddpm_replications, seed=args.seed, max_items=args.ddpm_items, progress=True)
        for name, steps, sampler in claim_runs:
            if name in raw["subset"]:
                continue
            print(f"== {name} (subset)", flush=True)
            result = evaluate(data, evaluator, make_generate(teacher, steps, sampler, args.cfg), row_name=name, **subset)
            timed = aits([(name, teacher, steps, sampler)], timing_items[:2], args.cfg)[name]
            raw["subset"][name] = {"row": result["rows"][name], "aits": timed, "real": result["rows"][REAL_ROW]}
            save()
    save()
    print(f"wrote {args.out}")
    return 0


def render(args, argv, raw: dict, runs, minutes: float, done: int, total: int, kept: int = 0) -> str:
    cmd = "python scripts/make_results.py " + " ".join(argv)
    real = raw["rows"].get(REAL_ROW)
    main_rows = [(name, raw["rows"][name], raw["aits"].get(name)) for name, *_ in runs if name in raw["rows"]]
    claim_rows = [(name, v["row"], v["aits"]) for name, v in raw["subset"].items()]
    if claim_rows:
        claim_rows.insert(0, ("Real motion", next(iter(raw["subset"].values()))["real"], None))
    status = "" if done == total else f"\n**Partial: {done} of {total} rows so far (the run is still going or was stopped).**\n"
    claim = f"""## Table 5's claim: 10 SDE-DPM-Solver++ steps vs 1000 DDPM steps

The same {args.ddpm_items} test items and seeds, {args.ddpm_replications} replication(s) (1000 steps are
expensive on a CPU).

{table(claim_rows)}
""" if claim_rows else ""
    ratios = student_ratios(raw, runs)
    return f"""# Results on the synthetic benchmark

Generated by `scripts/make_results.py` (do not edit by hand). Command:

```bash
{cmd}
```
{status}
Machine: {platform.machine()}, {torch.get_num_threads()} torch threads, torch {torch.__version__}; this invocation took
{minutes:.0f} min{f" ({kept} of the {total} rows were kept from an earlier invocation with the same settings, `--resume`)" if kept else ""}. Model: `{args.bundle}` (the demo CondUNet1D, see `configs/demo.yaml`). Evaluator:
`{args.evaluator}` (StableMo's contrastive text–motion evaluator trained on the same synthetic
data, `configs/evaluator_synth.yaml`). Test split with the evaluation crops; mean ± 95% interval over
{args.replications} replications; CFG {args.cfg:g}. AITS: average inference time per sentence, batch 1,
model loaded, every sentence encoding its own text (cold caches), over {args.aits_sentences} test sentences
timed round-robin across the rows. Items scored per replication:
{args.max_items or 'the whole test split'}.

## Samplers and consistency students

{table(([("Real motion", real, None)] if real else []) + main_rows)}
{ratios}
{claim}"""


TEACHER_ROW = "Teacher, SDE-DPM-Solver++ 2M, 10 steps"


def student_ratios(raw: dict, runs) -> str:
    """Each student row against the teacher's 10-step SDE row: FID ratio and AITS ratio (the
    distillation targets: 1 step FID <= 1.5x, 4 steps <= 1.1x, 1-step AITS <= 1/8)."""
    if TEACHER_ROW not in raw["rows"] or TEACHER_ROW not in raw["aits"]:
        return ""
    teacher_fid, teacher_aits = raw["rows"][TEACHER_ROW]["fid"]["mean"], raw["aits"][TEACHER_ROW]
    lines = []
    for name, _, steps, sampler in runs:
        if sampler is None and name in raw["rows"]:
            fid = raw["rows"][name]["fid"]["mean"]
            lines.append(f"| {name} | {fid / teacher_fid:.2f} | {raw['aits'][name] / teacher_aits:.3f} |")
    one_step = "Teacher, DDIM, 1 step"
    if one_step in raw["rows"]:
        lines.append(f"| {one_step} | {raw['rows'][one_step]['fid']['mean'] / teacher_fid:.2f} | "
                     f"{raw['aits'][one_step] / teacher_aits:.3f} |")
    if not lines:
        return ""
    return ("\n### Against the teacher's 10-step SDE-DPM-Solver++ row\n\n"
            "| Method | FID / teacher FID | AITS / teacher AITS |\n|---|---|---|\n" + "\n".join(lines) + "\n")


if __name__ == "__main__":
    sys.exit(run_script(main, Path(__file__).name, sys.argv[1:]))
