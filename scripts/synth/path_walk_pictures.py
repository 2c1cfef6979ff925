"""Top views of synthetic path walks (docs/synth.md, "Path walks").

    .venv/bin/python scripts/synth/path_walk_pictures.py [--out docs/data/synth/path_walks.png] [--seed 0] [--num 8]

Each panel: the pelvis path, the planted foot joints (ground-truth contacts: left blue, right red),
and the body's facing (from hips and shoulders) every half second as an arrow; the first frame
faces +z (up in the panel). Titles: the first caption and the median angle between facing and
travel while walking (> 0.5 m/s).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from stablemo.data.synth import compose
from stablemo.data.synth.timeline import FPS
from stablemo.data.synth.writer import motion_rng
from stablemo.errors import run_script
from stablemo.io import check_output_file
from stablemo.outputs.render import save_png

FEET = ((7, 0, "tab:blue"), (10, 1, "tab:blue"), (8, 2, "tab:red"), (11, 3, "tab:red"))  # joint, contact channel


def facing(j: np.ndarray) -> np.ndarray:
    """(T,) body yaw (0 = +z) from the hips and shoulders."""
    across = (j[:, 2] - j[:, 1]) + (j[:, 17] - j[:, 16])
    fwd = np.cross([0.0, 1.0, 0.0], across)
    return np.arctan2(fwd[:, 0], fwd[:, 2])


def facing_vs_travel(j: np.ndarray) -> float:
    """Median angle (degrees) between facing and the pelvis' direction of travel while walking."""
    step = np.diff(j[:, 0, [0, 2]], axis=0)
    speed = np.linalg.norm(step, axis=-1) * FPS
    travel = np.arctan2(step[:, 0], step[:, 1])
    diff = np.abs((facing(j)[:-1] - travel + np.pi) % (2 * np.pi) - np.pi)
    walking = speed > 0.5
    return float(np.degrees(np.median(diff[walking]))) if walking.any() else float("nan")


def main(argv=None) -> int:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/data/synth/path_walks.png")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--num", type=int, default=8)
    args = ap.parse_args(argv)
    check_output_file(args.out, "out")
    cols = 4
    rows = -(-args.num // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 4 * rows), squeeze=False)
    for k, ax in enumerate(axes.flat):
        if k >= args.num:
            ax.axis("off")
            continue
        m = compose.generate_path_walk(motion_rng(args.seed, k))
        j = m.joints.astype(np.float64)
        ax.plot(j[:, 0, 0], j[:, 0, 2], color="0.3", lw=1)
        for joint, channel, colour in FEET:
            down = m.contacts[:, channel].astype(bool)
            ax.scatter(j[down, joint, 0], j[down, joint, 2], s=2, color=colour)
        yaw = facing(j)
        for f in range(0, len(j), FPS // 2):
            ax.annotate("", xy=(j[f, 0, 0] + 0.35 * np.sin(yaw[f]), j[f, 0, 2] + 0.35 * np.cos(yaw[f])),
                        xytext=(j[f, 0, 0], j[f, 0, 2]), arrowprops=dict(arrowstyle="->", color="tab:green"))
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(f"{m.captions[0]}\nfacing vs travel {facing_vs_travel(j):.1f}°, {len(j) / FPS:.1f} s",
                     fontsize=7, wrap=True)
        ax.tick_params(labelsize=6)
    fig.tight_layout()
    save_png(fig, args.out, dpi=80)
    plt.close(fig)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main, "/".join(Path(__file__).parts[-2:]), sys.argv[1:]))
