"""Where the finishing step's FID change comes from (docs/inference.md, "The finishing step").

    OMP_NUM_THREADS=2 python scripts/results/finish_fid_parts.py [--out docs/data/results/finish_fid]
        [--models teacher,student] [--frames 120,196] [--seeds 4] [--first-seed 0]

The finishing step (stablemo.inference.finish) does two things to the features the evaluator reads:
it moves the joints (the rigid body, planted feet, the floor) and it computes every column seen
from the root again from the joints, the 6D rotations included, where the network predicted its own.
On the kinematic report's draw (stablemo.bench.kinematic_report: 72 prompts x `seeds` seeds, FID
against synthetic ground truth of the same actions, R@3 over batches of 32 distinct prompts), each
model and length is scored four ways, from one generation:

- raw: the network's features;
- raw, recomputed: the raw joints unchanged, the columns computed again from them (Finish.rows);
- final, network's rotations: what the user receives, with the 6D rotation columns put back to the
  network's (not something StableMo writes: it shows how much of the change is those columns);
- final: what the user receives.

Each way's R@3 is also compared with the raw output's pair by pair (the same motions, texts and
batches: a motion found in its batch's top 3 one way and not the other is a discordant pair), with
the paired difference's standard error, which is several times smaller than either R@3's own.

Writes finish_fid.json and finish_fid.md (the table) under --out.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from stablemo.bench import kinematic_report as report
from stablemo.checks import check_positive_int, check_seed
from stablemo.errors import StableMoError, run_script
from stablemo.eval import metrics
from stablemo.eval.evaluate import embed_motions, embed_texts, generation_outputs
from stablemo.inference.bundle import EVALUATOR_SYNTH
from stablemo.io import check_output_dir, write_text
from stablemo.motion.features import feature_slices

MODELS = report.DEMO_MODELS
WAYS = ("raw", "raw, recomputed", "final, network's rotations", "final")


def parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="docs/data/results/finish_fid", help="folder for finish_fid.json and .md")
    p.add_argument("--models", default="teacher,student",
                   help="comma-separated: teacher, student (the shipped ones) or bundle folders")
    p.add_argument("--frames", default="120,196", help="comma-separated motion lengths in frames")
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--first-seed", type=int, default=0, help="seeds first-seed .. first-seed + seeds - 1")
    return p.parse_args(argv)


def ways(pipe, texts: list[str], seeds: list[int], frames: int, chunk: int) -> dict[str, torch.Tensor]:
    """{way: features (B, T, D)} of one generation, the four ways of the module docstring;
    generated `chunk` motions at a time (one seed's prompts)."""
    parts = [generation_outputs(pipe.generate(texts[i:i + chunk], [frames] * len(texts[i:i + chunk]),
                                              seed=seeds[i:i + chunk])) for i in range(0, len(texts), chunk)]
    features, _, raw_features, raw_joints = (torch.cat(list(x)) for x in zip(*parts))
    lengths = [frames] * len(texts)
    recomputed, _ = pipe.finish.rows(raw_features, raw_joints.permute(2, 3, 0, 1).contiguous(), lengths)
    rot = feature_slices(pipe.skeleton)["rot6d"]
    network_rotations = features.clone()
    network_rotations[..., rot] = raw_features[..., rot]
    return dict(zip(WAYS, (raw_features, recomputed, network_rotations, features)))


def main(argv=None) -> int:
    args = parse(argv)
    models = [m.strip() for m in args.models.split(",") if m.strip()]
    unknown = [m for m in models if m not in MODELS and not (Path(m) / "config.json").is_file()]
    if unknown or not models:
        raise StableMoError(f"--models: expected some of {', '.join(MODELS)} or bundle folders, got {args.models!r}")
    frames = report.parse_frames(args.frames)
    check_positive_int("--seeds", args.seeds)
    check_seed("--first-seed", args.first_seed, count=args.seeds)
    out = check_output_dir(args.out, "--out")
    from stablemo.eval.text_motion import load_text_motion_evaluator
    from stablemo.inference.pipeline import Pipeline

    pipes = [(MODELS[m][0], Pipeline.from_bundle(MODELS[m][1])) if m in MODELS else (m, Pipeline.from_bundle(m))
             for m in models]
    for _, pipe in pipes:
        for n in frames:
            pipe.inference.check_length(n, "--frames")
    evaluator = load_text_motion_evaluator(EVALUATOR_SYNTH, "humanml3d")
    items = report.prompts(8, 0)
    reference = report.reference_statistics(evaluator, items, args.seeds)
    texts = [p.text for _ in range(args.seeds) for p in items]  # seed-major: each batch of 32 holds distinct prompts
    seeds = [args.first_seed + s for s in range(args.seeds) for _ in items]
    text_emb = embed_texts(evaluator, texts, [[] for _ in texts], 64)
    rows = []
    for name, pipe in pipes:
        for n in frames:
            print(f"== {name}, {len(items)} prompts x {args.seeds} seeds, {n} frames", flush=True)
            hits = {}
            for way, feats in ways(pipe, texts, seeds, n, len(items)).items():
                emb = embed_motions(evaluator, [x.float().cpu() for x in feats], 64)
                fid = metrics.frechet_distance(*metrics.embedding_statistics(emb), *reference)
                hits[way] = (metrics.retrieval_ranks(text_emb, emb)[0] < 3).astype(np.float64)
                diff = hits[way] - hits["raw"]  # (N,) paired: -1, 0 or 1 per motion
                rows.append({"model": name, "frames": n, "way": way, "fid": fid, "r3": float(hits[way].mean()),
                             "r3_minus_raw": float(diff.mean()),
                             "r3_minus_raw_se": float(diff.std(ddof=1) / np.sqrt(len(diff))),
                             "discordant": int((diff != 0).sum())})
                print(f"   {way}: FID {fid:.4f}, R@3 {hits[way].mean():.3f} "
                      f"({diff.mean():+.3f} ± {rows[-1]['r3_minus_raw_se']:.3f} against raw)", flush=True)
    lines = ["| Model | Frames | " + " | ".join(f"FID, {w}" for w in WAYS) + " | R@3, raw | "
             + " | ".join(f"R@3 − raw, {w}" for w in WAYS[1:]) + " |",
             "|---|---|" + "---|" * (2 * len(WAYS))]
    for name, _ in pipes:
        for n in frames:
            got = {r["way"]: r for r in rows if r["model"] == name and r["frames"] == n}
            raw_fid = got["raw"]["fid"]
            cells = ([f"{got['raw']['fid']:.4f}"] + [f"{got[w]['fid']:.4f} ({got[w]['fid'] / raw_fid:.3f}×)" for w in WAYS[1:]]
                     + [f"{got['raw']['r3']:.3f}"]
                     + [f"{got[w]['r3_minus_raw']:+.3f} ± {got[w]['r3_minus_raw_se']:.3f}" for w in WAYS[1:]])
            lines.append(f"| {name} | {n} | " + " | ".join(cells) + " |")
    table = "\n".join(lines) + "\n"
    print(table)
    write_text(out / "finish_fid.json", json.dumps({"prompts": len(items), "seeds": args.seeds,
                                                   "first_seed": args.first_seed, "rows": rows},
                                                  indent=1) + "\n")
    write_text(out / "finish_fid.md", table)
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main, "finish_fid_parts.py", sys.argv[1:]))
