"""How much does a turn prompt turn when it continues another motion? The same window of new frames
generated freely and after an in-painted context of standing, walking or jumping (as a timeline's
window continues the motion before it), for the streamed-turn shortfall of docs/long_motion.md.

    OMP_NUM_THREADS=2 python scripts/long_motion/turn_context.py --bundle stablemo/assets/demo_bundle --out /tmp/turn_context

Per text and context, over seeds 0..n-1 (the context motion: seed 1000 + s, --new frames of its own
text; the window: --prefix frames of its end, in-painted, then --new frames of the turn, settled as a
timeline settles its joins): the facing turn of the new frames (degrees, from the hips and
shoulders, as scripts/long_motion/stream_prompts.py measures it; right positive), the root's own turn over them
(its yaw velocity channel, summed), and for the free window the facing turn of its first --prefix
frames, the part of the turn a continuation cannot make there. Writes report.json and report.md.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import torch

from stablemo.checks import check_positive_int
from stablemo.errors import run_script
from stablemo.inference.bundle import DEMO_BUNDLE
from stablemo.inference.pipeline import Pipeline
from stablemo.motion.features import features_to_joints
from stablemo.timeline.windows import DEFAULT_SETTLE_S, Sampling, generate_window, settle

sys.path.insert(0, str(Path(__file__).resolve().parent))
from stream_prompts import facing_turn, write_report  # noqa: E402  (the streamed-prompt report's turn measure)

CONTEXTS = ("a person stands still", "a person walks forward", "a person jumps in place")


def root_turn(features: np.ndarray) -> float:
    """Degrees the root's yaw turns over feature rows (T, D), right positive as facing_turn: the yaw
    velocity channel is a half-angle per frame (recover_root), so twice its sum."""
    return math.degrees(2.0 * float(features[:-1, 0].astype(np.float64).sum()))


def measure(pipe, text: str, seeds, new: int, prefix: int) -> dict:
    def joints(features: np.ndarray) -> np.ndarray:
        return features_to_joints(torch.from_numpy(features.astype(np.float64)), pipe.skeleton).numpy()

    settle_frames = round(DEFAULT_SETTLE_S * pipe.fps)
    rows = {"free": {"facing": [], "root": [], "first_prefix_frames": []}}
    for seed in seeds:
        free = generate_window(pipe, text, new, seed, None, 0, Sampling())
        j = joints(free)
        rows["free"]["facing"].append(facing_turn(j, pipe.skeleton))
        rows["free"]["root"].append(root_turn(free))
        rows["free"]["first_prefix_frames"].append(facing_turn(j[:prefix + 1], pipe.skeleton))
    for context in CONTEXTS:
        row = rows.setdefault(f"after: {context}", {"facing": [], "root": []})
        for seed in seeds:
            before = generate_window(pipe, context, new, 1000 + seed, None, 0, Sampling())
            window = generate_window(pipe, text, prefix + new, seed, before[-prefix:], prefix, Sampling())
            made = settle(before, window[prefix:], settle_frames, pipe.skeleton)
            j = joints(np.concatenate([before, made]))[len(before):]
            row["facing"].append(facing_turn(j, pipe.skeleton))
            row["root"].append(root_turn(window[prefix:]))
    return {name: {k: float(np.mean(v)) for k, v in row.items()} | {"per_seed_facing": row["facing"]}
            for name, row in rows.items()}


def to_markdown(result: dict) -> str:
    lines = [f"Model: {result['bundle']}; {result['new']} new frames after {result['prefix']} in-painted ones; "
             f"seeds 0-{result['seeds'] - 1}; mean degrees (right positive)", "",
             "| text | window | facing turn | root turn | facing turn in the first prefix frames |", "|---|---|---|---|---|"]
    for text, rows in result["texts"].items():
        for name, r in rows.items():
            first = f"{r['first_prefix_frames']:+.1f}" if "first_prefix_frames" in r else "–"
            lines.append(f"| {text} | {name} | {r['facing']:+.1f} | {r['root']:+.1f} | {first} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bundle", default=str(DEMO_BUNDLE))
    p.add_argument("--texts", nargs="+", default=["a person turns right", "a person turns left"])
    p.add_argument("--seeds", type=int, default=8)
    p.add_argument("--new", type=int, default=80, help="new frames of the turn (the streamed segments' 4 s)")
    p.add_argument("--prefix", type=int, default=10, help="in-painted frames (the timeline's 0.5-s overlap)")
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)
    for name in ("--seeds", "--new", "--prefix"):
        check_positive_int(name, getattr(args, name[2:]))
    pipe = Pipeline.from_bundle(args.bundle)
    result = {"bundle": Path(args.bundle).name, "seeds": args.seeds, "new": args.new, "prefix": args.prefix,
              "texts": {t: measure(pipe, t, range(args.seeds), args.new, args.prefix) for t in args.texts}}
    write_report(Path(args.out), result, to_markdown(result))


if __name__ == "__main__":
    sys.exit(run_script(main, "/".join(Path(__file__).parts[-2:]), sys.argv[1:]))
