"""Ten minutes of Pipeline.stream: does the floor drift, does anything go non-finite?

    OMP_NUM_THREADS=1 python scripts/long_motion/stream_drift.py --minutes 10 [--bundle DIR] [--steps N] [--settle 0.5]

The text changes every 5 chunks (2-s chunks, 1 s of context) through walking, turning, jumping,
running prompts. Per block of one text cycle (7 prompts x 5 chunks = 70 s, so every block holds the
same actions and only drift can tell them apart): the floor = the 5th percentile over frames of the lowest foot
joint's height; drift = the largest minus the smallest block floor. Also the root height range and
the path travelled. Prints one JSON line per block and a summary.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from stablemo.errors import run_script
from stablemo.inference.pipeline import Pipeline

TEXTS = ["a person walks forward", "a person turns left", "a person jumps in place", "a person runs forward",
         "a person walks backwards", "a person turns right", "a person walks in a circle clockwise"]
FEET = [7, 8, 10, 11]  # ankles and toes of the HumanML3D skeleton


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bundle", default="stablemo/assets/demo_bundle")
    p.add_argument("--minutes", type=float, default=10.0)
    p.add_argument("--steps", type=int, default=None)
    p.add_argument("--settle", type=float, default=None)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    pipe = Pipeline.from_bundle(args.bundle)
    chunks = round(args.minutes * 60 / 2.0)
    options = {} if args.settle is None else {"settle_s": args.settle}
    stream = pipe.stream(lambda i, prev: TEXTS[(i // 5) % len(TEXTS)], 2.0, seed=args.seed, max_chunks=chunks,
                         steps=args.steps, **options)
    floors, roots, block, path, last = [], [], [], 0.0, None
    for chunk in stream:
        if not (np.isfinite(chunk.joints).all() and np.isfinite(chunk.features).all()):
            raise SystemExit(f"chunk {chunk.index}: not finite")
        block.append(chunk.joints)
        xz = chunk.joints[:, 0, [0, 2]]
        if last is not None:
            xz = np.concatenate([last[None], xz])
        path += float(np.linalg.norm(np.diff(xz, axis=0), axis=-1).sum())
        last = xz[-1]
        if len(block) == 5 * len(TEXTS):  # one text cycle
            j = np.concatenate(block)
            floors.append(float(np.percentile(j[:, FEET, 1].min(-1), 5)))
            roots.append((float(j[:, 0, 1].min()), float(j[:, 0, 1].max())))
            print(json.dumps({"block": len(floors), "end_s": (chunk.index + 1) * 2, "floor_m": floors[-1],
                              "root_y": roots[-1], "position": last.tolist()}), flush=True)
            block = []
    slope = float(np.polyfit(np.arange(len(floors)), floors, 1)[0]) if len(floors) > 1 else 0.0
    print(json.dumps({"minutes": args.minutes, "chunks": chunks, "floor_drift_m": max(floors) - min(floors),
                      "floor_trend_m_per_10min": slope * len(floors) * 600 / (args.minutes * 60),
                      "floor_first_last_m": [floors[0], floors[-1]], "path_m": path, "finite": True}))


if __name__ == "__main__":
    sys.exit(run_script(main, "/".join(Path(__file__).parts[-2:]), sys.argv[1:]))
