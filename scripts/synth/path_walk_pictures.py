"""Top views of synthetic path walks (docs/synth.md, "Path walks").

    .venv/bin/python scripts/synth/path_walk_pictures.py [--out docs/data/synth/path_walks.png] [--seed 0] [--num 8]

Each panel: the pelvis path, the planted foot joints (ground-truth contacts: left blue, right red),
and the body's facing (stablemo.motion.heading.facing_yaw) every half second as an arrow; the first
frame faces +z (up in the panel). Titles: the first caption and the median angle between facing and
travel over moving frames (stablemo.eval.heading.heading_measures).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

from stablemo.data.synth import compose
from stablemo.data.synth.timeline import FPS
from stablemo.data.synth.writer import motion_rng
from stablemo.errors import run_script
from stablemo.eval.heading import heading_measures
from stablemo.io import check_output_file
from stablemo.motion.heading import facing_yaw
from stablemo.motion.skeleton import get_skeleton
from stablemo.outputs.render import save_png

FEET = ((7, 0, "tab:blue"), (10, 1, "tab:blue"), (8, 2, "tab:red"), (11, 3, "tab:red"))  # joint, contact channel


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
    skel = get_skeleton("humanml3d")
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
        yaw = facing_yaw(torch.from_numpy(j), skel).numpy()
        median = float(heading_measures(j[None], [len(j)], "humanml3d")["facing_deg"][0])
        for f in range(0, len(j), FPS // 2):
            ax.annotate("", xy=(j[f, 0, 0] + 0.35 * np.sin(yaw[f]), j[f, 0, 2] + 0.35 * np.cos(yaw[f])),
                        xytext=(j[f, 0, 0], j[f, 0, 2]), arrowprops=dict(arrowstyle="->", color="tab:green"))
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(f"{m.captions[0]}\nfacing vs travel {median:.1f}°, {len(j) / FPS:.1f} s",
                     fontsize=7, wrap=True)
        ax.tick_params(labelsize=6)
    fig.tight_layout()
    save_png(fig, args.out, dpi=80)
    plt.close(fig)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main, "/".join(Path(__file__).parts[-2:]), sys.argv[1:]))
