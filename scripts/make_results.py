"""Write docs/results.md: the demo model on the synthetic benchmark, samplers and students side by side.

    python scripts/make_results.py --bundle stablemo/assets/demo_bundle --data data/synth \
        --evaluator outputs/evaluator_synth/checkpoints/last.ckpt \
        [--student LCM=bundles/demo_lcm --student PCM=bundles/demo_pcm] [--replications 20] \
        [--ddpm-items 96 --ddpm-replications 1] [--out docs/results.md]

Every row is scored by the same evaluator on the same test split with the same replication seeds;
AITS (batch 1, model loaded, text cache warm) is measured for every row in this one run. The
1000-step DDPM row is expensive on a CPU: it runs on `--ddpm-items` items for `--ddpm-replications`
replication(s), and is compared with the 10-step SDE row scored on exactly the same items.
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
from stablemo.eval import metrics
from stablemo.eval.command import REAL_ROW, evaluate, load_text_motion_evaluator
from stablemo.io import write_text
from stablemo.pipeline import Pipeline

COLUMNS = [("r1", "R@1 ↑"), ("r3", "R@3 ↑"), ("fid", "FID ↓"), ("mm_dist", "MM-Dist ↓"), ("diversity", "Diversity →")]


def make_generate(pipe: Pipeline, steps: int, sampler: str | None, cfg: float):
    lo, hi = pipe.min_length, pipe.max_length

    def generate(texts, lengths, seeds):
        out = pipe.generate(texts, [min(max(n, lo), hi) for n in lengths], steps=steps, cfg=cfg, sampler=sampler,
                            seed=seeds)
        return out.features, out.joints

    return generate


def aits(pipe: Pipeline, items: list[dict], steps: int, sampler: str | None, cfg: float) -> float:
    lo, hi = pipe.min_length, pipe.max_length
    return metrics.average_inference_time(
        lambda text, n: pipe.generate([text], [min(max(n, lo), hi)], steps=steps, cfg=cfg, sampler=sampler, seed=0),
        [it["text"] for it in items], [it["length"] for it in items])


def cell(row: dict, key: str) -> str:
    return f"{row[key]['mean']:.3f} ± {row[key]['conf95']:.3f}" if key in row else "–"


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
    p.add_argument("--aits-sentences", type=int, default=10)
    p.add_argument("--cfg", type=float, default=2.5)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="docs/results.md")
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

    main_rows: list[tuple[str, dict, float | None]] = []
    raw: dict = {"rows": {}, "aits": {}}
    real = None
    for name, pipe, steps, sampler in runs:
        print(f"== {name}", flush=True)
        result = evaluate(data, evaluator, make_generate(pipe, steps, sampler, args.cfg), row_name=name, **common)
        real = result["rows"][REAL_ROW]
        t = aits(pipe, timing_items, steps, sampler, args.cfg)
        main_rows.append((name, result["rows"][name], t))
        raw["rows"][name], raw["aits"][name] = result["rows"][name], t
    raw["rows"][REAL_ROW] = real

    # Table 5's claim on a subset: 1000 DDPM steps vs 10 SDE steps on the same items and seeds
    subset = dict(replications=args.ddpm_replications, seed=args.seed, max_items=args.ddpm_items, progress=True)
    claim_rows = []
    for name, steps, sampler in (("Teacher, DDPM, 1000 steps", 1000, "ddpm"),
                                 ("Teacher, SDE-DPM-Solver++ 2M, 10 steps", 10, "dpmpp_2m_sde")):
        print(f"== {name} (subset)", flush=True)
        result = evaluate(data, evaluator, make_generate(teacher, steps, sampler, args.cfg), row_name=name, **subset)
        t = aits(teacher, timing_items[:2], steps, sampler, args.cfg)
        claim_rows.append((name, result["rows"][name], t))
        raw.setdefault("subset", {})[name] = {"row": result["rows"][name], "aits": t}
    claim_rows.insert(0, ("Real motion", result["rows"][REAL_ROW], None))

    minutes = (time.time() - started) / 60
    cmd = "python scripts/make_results.py " + " ".join(argv)
    text = f"""# Results on the synthetic benchmark

Generated by `scripts/make_results.py` (do not edit by hand). Command:

```bash
{cmd}
```

Machine: {platform.machine()}, {torch.get_num_threads()} torch threads, torch {torch.__version__}; the run took
{minutes:.0f} min. Model: `{args.bundle}` (the demo CondUNet1D, see `configs/demo.yaml`). Evaluator:
`{args.evaluator}` (StableMo's contrastive text–motion evaluator trained on the same synthetic
data, `configs/evaluator_synth.yaml`). Test split with the evaluation crops; mean ± 95% interval over
{args.replications} replications; CFG {args.cfg:g}. AITS: average inference time per sentence, batch 1,
model loaded, over {args.aits_sentences} test sentences, measured in this run. Items scored per
replication: {args.max_items or 'the whole test split'}.

## Samplers and consistency students

{table([("Real motion", real, None)] + main_rows)}

## Table 5's claim: 10 SDE-DPM-Solver++ steps vs 1000 DDPM steps

The same {args.ddpm_items} test items and seeds, {args.ddpm_replications} replication(s) (1000 steps are
expensive on a CPU); intervals are not meaningful with one replication.

{table(claim_rows)}
"""
    write_text(args.out, text)
    write_text(Path(args.out).with_suffix(".json"), json.dumps(raw, indent=2) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
