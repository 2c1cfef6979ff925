"""Seams and segments of long motions: choose the window joining on some prompts, report it on others.

    OMP_NUM_THREADS=1 python scripts/long_motion/report.py --out /tmp/long/report [--seeds 2]

1. Grid over overlap x blend x settle (stablemo.timeline.generate_timeline) on the TUNING timelines
   (prompts that appear in no held-out timeline): at every join, the root and foot acceleration
   peak (stablemo.timeline.seams) over the motion's own inside 99th percentile and over the data's
   99th percentile (data/synth). The chosen setting: the most joins within 2x the inside p99 (root
   and foot), then the smallest mean ratio.
2. The chosen setting and the plain one (in-painted prefix only) on the HELD-OUT timelines, same
   numbers.
3. Per segment of the 30-s held-out timeline: root measures (turn, path, forward, rise, as
   scripts/results/check_demo.py) and the evaluator's R@3 (each segment's text among 31 captions of the
   test split) vs single-prompt generations of the same text and length with the same seeds.
Writes report.json and report.md under --out.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from pathlib import Path

import numpy as np
import torch

from stablemo.errors import run_script
from stablemo.io import write_text
from stablemo.motion import features_to_joints
from stablemo.inference.pipeline import Pipeline
from stablemo.timeline.seams import data_percentiles, seam_report

TUNING = [
    [(0, 4, "a person walks backwards"), (4, 8, "a person kicks forward with their left foot"),
     (8, 12, "a person does a squat"), (12, 16, "a person jogs forward"), (16, 20, "a person bows")],
    [(0, 5, "a person waves hello with their right hand"), (5, 9, "a person walks sideways to the right"),
     (9, 14, "a person jogs forward"), (14, 18, "a person does a squat"), (18, 22, "a person walks backwards")],
]
TARGET = [(0, 5, "a person walks forward"), (5, 10, "a person jumps in place"), (10, 15, "a person turns left"),
          (15, 20, "a person walks forward"), (20, 25, "a person turns right"), (25, 30, "a person runs forward")]
HELD_OUT = [TARGET,
            [(0, 6, "a person walks in a circle clockwise"), (6, 9, "a person jumps in place"),
             (9, 17, "a person runs forward"), (17, 21, "a person turns right"), (21, 30, "a person walks forward")]]
OVERLAPS, BLENDS, SETTLES = (0.5, 1.0, 2.0), (0.0, 0.5), (0.0, 0.5, 1.0)
PLAIN = {"overlap": 1.0, "blend": 0.0, "settle_s": 0.0}


def join_ratios(pipe, segments, seed: int, setting: dict, data_p99: dict) -> list[dict]:
    motion = pipe.generate_timeline(segments, seed=seed, **setting)
    assert len(motion.features) == round(segments[-1][1] * pipe.fps)
    rep = seam_report(motion.joints, motion.join_spans, pipe.fps)
    inside = rep["inside_p99"]
    return [{"frame": j["frame"], "boundary": j["frame"] in motion.boundaries,
             **{f"{k}_inside": j[k] / inside[k] for k in ("root", "foot")},
             **{f"{k}_data": j[k] / data_p99[k] for k in ("root", "foot")}} for j in rep["joins"]]


def summarise(rows: list[dict]) -> dict:
    worst = [max(r["root_inside"], r["foot_inside"]) for r in rows]
    return {"joins": len(rows), "within_2x_inside": float(np.mean([w <= 2.0 for w in worst])),
            "within_data_p99": float(np.mean([max(r["root_data"], r["foot_data"]) <= 1.0 for r in rows])),
            "mean_worst_ratio": float(np.mean(worst)), "max_worst_ratio": float(np.max(worst)),
            "root_inside_max": float(max(r["root_inside"] for r in rows)),
            "foot_inside_max": float(max(r["foot_inside"] for r in rows)),
            "root_data_max": float(max(r["root_data"] for r in rows)),
            "foot_data_max": float(max(r["foot_data"] for r in rows))}


def run_setting(pipe, timelines, seeds, setting, data_p99) -> dict:
    rows = []
    for segments, seed in itertools.product(timelines, seeds):
        rows += join_ratios(pipe, segments, seed, setting, data_p99)
    return summarise(rows)


def segment_stats(features: np.ndarray) -> dict:
    """The root measures of scripts/results/check_demo.py (turning angle: the sum of the root's angular
    velocity channel; path length and forward displacement of the root, metres) in the segment's own
    frame, with the rise taken from the segment's median root height (a segment starts mid-motion,
    perhaps already in the air)."""
    joints = features_to_joints(features[None].astype(np.float32))[0]       # (T, 22, 3)
    root = joints[:, 0]
    step = np.linalg.norm(np.diff(root[:, [0, 2]], axis=0), axis=-1)
    return {"turn": float(features[:, 0].sum()), "path": float(step.sum()), "forward": float(root[-1, 2] - root[0, 2]),
            "rise": float(features[:, 3].max() - np.median(features[:, 3]))}


def distractor_captions(data: Path, avoid: set[str], count: int, seed: int) -> list[str]:
    names = (data / "test.txt").read_text().split()
    caps = sorted({(data / "texts" / f"{n}.txt").read_text().splitlines()[0].split("#")[0].strip() for n in names})
    caps = [c for c in caps if c.rstrip(".") not in avoid]
    rng = np.random.default_rng(seed)
    return [caps[i] for i in rng.choice(len(caps), count, replace=False)]


def segment_measures(pipe, setting: dict, seeds, data: Path, evaluator_dir: str) -> dict:
    from stablemo.eval.text_motion import OurEvaluator

    evaluator = OurEvaluator(evaluator_dir)
    texts = [s[2] for s in TARGET]
    pools = {t: [t] + distractor_captions(data, set(texts), 31, i) for i, t in enumerate(texts)}
    out = [{"timeline": [], "single": []} for _ in texts]
    for seed in seeds:
        motion = pipe.generate_timeline(TARGET, seed=seed, **setting)
        for i, ((a, b), text) in enumerate(zip(motion.frames, texts)):
            single = pipe.generate([text], b - a, seed=seed * 100 + i).feature_list()[0]
            for kind, feats in (("timeline", motion.features[a:b]), ("single", single)):
                emb_m = evaluator.embed_motion(torch.from_numpy(feats[None]), torch.tensor([len(feats)]))
                emb_t = evaluator.embed_text(pools[text], [[] for _ in pools[text]])
                rank = int((np.linalg.norm(emb_t - emb_m, axis=-1) < np.linalg.norm(emb_t[0] - emb_m[0])).sum())
                out[i][kind].append({**segment_stats(feats), "top3": rank < 3})
    table = []
    for i, text in enumerate(texts):
        row = {"segment": i + 1, "text": text}
        for kind in ("timeline", "single"):
            vals = out[i][kind]
            row[kind] = {k: float(np.mean([v[k] for v in vals])) for k in ("turn", "path", "forward", "rise", "top3")}
        table.append(row)
    return {"segments": table}


def to_markdown(result: dict) -> str:
    lines = [f"data p99 (data/synth, m/s^2): root {result['data_p99']['root']:.1f}, foot {result['data_p99']['foot']:.1f}", ""]
    head = ("| overlap s | blend s | settle s | joins | within 2x inside p99 | within data p99 | mean worst ratio | "
            "max worst ratio | root/inside max | foot/inside max |")
    for name in ("tuning", "held_out"):
        lines += [f"### {name.replace('_', '-')}", "", head, "|" + "---|" * 10]
        for r in result[name]:
            s, m = r["setting"], r["summary"]
            lines.append(f"| {s['overlap']:g} | {s['blend']:g} | {s['settle_s']:g} | {m['joins']} | "
                         f"{m['within_2x_inside']:.0%} | {m['within_data_p99']:.0%} | {m['mean_worst_ratio']:.2f} | "
                         f"{m['max_worst_ratio']:.2f} | {m['root_inside_max']:.2f} | {m['foot_inside_max']:.2f} |")
        lines.append("")
    if "segments" in result:
        lines += ["### segments of the 30-s timeline (timeline / single prompt)", "",
                  "| # | text | turn rad | path m | forward m | rise m | R@3 |", "|---|---|---|---|---|---|---|"]
        for row in result["segments"]["segments"]:
            cells = [f"{row['timeline'][k]:+.2f} / {row['single'][k]:+.2f}" for k in ("turn", "path", "forward", "rise")]
            cells.append(f"{row['timeline']['top3']:.2f} / {row['single']['top3']:.2f}")
            lines.append(f"| {row['segment']} | {row['text']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bundle", default="stablemo/assets/demo_bundle")
    p.add_argument("--data", default="data/synth")
    p.add_argument("--evaluator", default="stablemo/assets/evaluator_synth")
    p.add_argument("--seeds", type=int, default=2)
    p.add_argument("--segment-seeds", type=int, default=4)
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    out = Path(args.out)
    pipe = Pipeline.from_bundle(args.bundle)
    result = {"data_p99": data_percentiles(args.data, pipe.skeleton, pipe.fps), "tuning": [], "held_out": []}
    seeds = list(range(args.seeds))
    for overlap, blend, settle in itertools.product(OVERLAPS, BLENDS, SETTLES):
        if blend > overlap:
            continue
        setting = {"overlap": overlap, "blend": blend, "settle_s": settle}
        result["tuning"].append({"setting": setting, "summary": run_setting(pipe, TUNING, seeds, setting, result["data_p99"])})
        print(json.dumps(result["tuning"][-1]), flush=True)
    best = max(result["tuning"], key=lambda r: (r["summary"]["within_2x_inside"], -r["summary"]["mean_worst_ratio"]))
    result["chosen"] = best["setting"]
    for setting in ([PLAIN, best["setting"]] if best["setting"] != PLAIN else [PLAIN]):
        result["held_out"].append({"setting": setting, "summary": run_setting(pipe, HELD_OUT, seeds, setting, result["data_p99"])})
        print(json.dumps(result["held_out"][-1]), flush=True)
    result["segments"] = segment_measures(pipe, best["setting"], range(args.segment_seeds), Path(args.data), args.evaluator)
    write_text(out / "report.json", json.dumps(result, indent=1) + "\n")
    write_text(out / "report.md", to_markdown(result))
    print(to_markdown(result))


if __name__ == "__main__":
    sys.exit(run_script(main, "/".join(Path(__file__).parts[-2:]), sys.argv[1:]))
