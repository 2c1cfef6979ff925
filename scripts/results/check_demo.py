"""Does the demo model do what the prompt says? Root-motion statistics of generations vs the data.

    python scripts/results/check_demo.py [--bundle stablemo/assets/demo_bundle] [--data data/synth] [--samples 8]

For each probe prompt, `--samples` motions are generated (10 SDE steps, CFG 2.5, seeds 0..n-1) at
the median length of the matching data clips, and compared with the data clips whose caption
matches the probe's pattern (single-action captions only): turning angle (sum of the root's
angular velocity channel, radians; counterclockwise is negative in it), path length and net forward
displacement of the root (metres), and the root's highest rise above its starting height (metres).
Prints a markdown table; the numbers are means over the clips.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import numpy as np
import torch

from stablemo.errors import run_script
from stablemo.motion import features_to_joints
from stablemo.inference.pipeline import Pipeline

PROBES = [  # (prompt, caption pattern in the data)
    ("a person walks forward", r"\bwalks forward\b"),
    ("a person turns left", r"\bturns?\b.*\bleft\b"),
    ("a person turns right", r"\bturns?\b.*\bright\b"),
    ("a person walks in a circle counterclockwise", r"\bcounterclockwise\b"),
    ("a person walks in a circle clockwise", r"(?<!counter)\bclockwise\b"),
    ("a person walks backwards", r"\bbackwards?\b"),
    ("a person jumps in place", r"\bjumps\b"),
    ("a person runs forward", r"\bruns\b"),
]


def root_stats(features: np.ndarray) -> dict:
    """features (T, 263) de-normalised -> turning angle, path length, forward displacement, rise."""
    joints = features_to_joints(features[None].astype(np.float32))[0]       # (T, 22, 3)
    root = joints[:, 0]
    step = np.linalg.norm(np.diff(root[:, [0, 2]], axis=0), axis=-1)
    return {"turn": float(features[:, 0].sum()), "path": float(step.sum()),
            "forward": float(root[-1, 2] - root[0, 2]), "rise": float(root[:, 1].max() - root[0, 1])}


def data_clips(data_dir: Path, pattern: str) -> list[np.ndarray]:
    rx = re.compile(pattern)
    clips = []
    for path in sorted((data_dir / "texts").glob("*.txt")):
        captions = [line.split("#")[0] for line in path.read_text().splitlines() if line.strip()]
        single = [c for c in captions if " then " not in c and " while " not in c and " and " not in c]
        if single and all(rx.search(c) for c in single) and len(single) == len(captions):
            clips.append(np.load(data_dir / "new_joint_vecs" / f"{path.stem}.npy"))
    return clips


def mean_stats(clips: list[np.ndarray]) -> dict:
    stats = [root_stats(c) for c in clips]
    return {k: float(np.mean([s[k] for s in stats])) for k in stats[0]}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bundle", default="stablemo/assets/demo_bundle")
    p.add_argument("--data", default="data/synth")
    p.add_argument("--samples", type=int, default=8)
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    pipe = Pipeline.from_bundle(args.bundle)
    print("| prompt | data clips | turn (rad) data / model | path (m) data / model | forward (m) data / model | rise (m) data / model |")
    print("|---|---|---|---|---|---|")
    for prompt, pattern in PROBES:
        clips = data_clips(Path(args.data), pattern)
        if not clips:
            print(f"| {prompt} | 0 | | | | |")
            continue
        frames = int(np.clip(np.median([len(c) for c in clips]), pipe.min_length, pipe.max_length))
        gen = pipe.generate([prompt] * args.samples, [frames] * args.samples,  # the bundle's sampler settings
                            seed=list(range(args.samples)))
        model = mean_stats([gen.features[i, :frames].numpy() for i in range(args.samples)])
        real = mean_stats(clips)
        cells = [f"{real[k]:+.2f} / {model[k]:+.2f}" for k in ("turn", "path", "forward", "rise")]
        print(f"| {prompt} | {len(clips)} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    sys.exit(run_script(main, "/".join(Path(__file__).parts[-2:]), sys.argv[1:]))
