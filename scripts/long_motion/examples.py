"""The renders of docs/long_motion.md: the example timeline as one motion.

    OMP_NUM_THREADS=1 python scripts/long_motion/examples.py --out docs/data/long_motion [--gif]

Writes example_segments.png (one row per segment, its frames in the motion's global frame),
example_path.png (top view of the root path coloured by segment with the joins marked, and the root
and foot heights over time) and, with --gif, example.gif (the whole motion).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

from stablemo.errors import run_script
from stablemo.inference.pipeline import Pipeline
from stablemo.timeline import read_timeline

FEET = [7, 8, 10, 11]


def plot_path(motion, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stablemo.outputs.render import save_png

    fig, (top, side) = plt.subplots(1, 2, figsize=(11, 4.2), gridspec_kw={"width_ratios": [1, 1.6]})
    root = motion.joints[:, 0]
    t = np.arange(len(root)) / motion.fps
    colours = plt.cm.tab10(np.arange(len(motion.segments)))
    for (a, b), seg, c in zip(motion.frames, motion.segments, colours):
        top.plot(root[a:b + 1, 0], root[a:b + 1, 2], color=c, lw=2, label=f"{seg.start_s:g}-{seg.end_s:g} s {seg.text}")
        side.plot(t[a:b + 1], root[a:b + 1, 1], color=c, lw=1.5)
        side.plot(t[a:b + 1], motion.joints[a:b + 1, FEET, 1].min(-1), color=c, lw=1, ls="--")
    joins = motion.joins
    top.scatter(root[joins, 0], root[joins, 2], s=25, c="k", zorder=3, label="joins")
    top.plot(root[0, 0], root[0, 2], "k^", ms=8)
    top.set_aspect("equal")
    top.set_xlabel("x (m)")
    top.set_ylabel("z (m)")
    top.set_title("root path from above (start: triangle)", fontsize=9)
    top.legend(fontsize=6, loc="best")
    for j in joins:
        side.axvline(j / motion.fps, color="k", lw=0.5, alpha=0.4)
    side.set_xlabel("time (s)")
    side.set_ylabel("height (m)")
    side.set_title("root height (solid) and lowest foot (dashed); joins: grey lines", fontsize=9)
    fig.tight_layout()
    save_png(fig, path, dpi=110)
    plt.close(fig)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bundle", default="stablemo/assets/demo_bundle")
    p.add_argument("--timeline", default="docs/data/long_motion/example.txt")
    p.add_argument("--out", default="docs/data/long_motion")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--gif", action="store_true")
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    from stablemo.outputs.render import render_animation, render_contact_sheet

    pipe = Pipeline.from_bundle(args.bundle)
    motion = pipe.generate_timeline(read_timeline(args.timeline), seed=args.seed, source=args.timeline)
    out = Path(args.out)
    rows = [motion.joints[a:b] for a, b in motion.frames]
    titles = [f"{s.start_s:g}-{s.end_s:g} s: {s.text}" for s in motion.segments]
    render_contact_sheet(rows, titles, out / "example_segments.png", pipe.skeleton, frames_per_row=6)
    plot_path(motion, out / "example_path.png")
    if args.gif:
        render_animation(motion.joints, out / "example.gif", pipe.skeleton, fps=pipe.fps,
                         title=f"{args.timeline}: {len(motion.segments)} prompts, {len(motion.features) / pipe.fps:g} s")
    print(f"{len(motion.features)} frames, joins at {motion.joins} -> {out}")


if __name__ == "__main__":
    sys.exit(run_script(main, "/".join(Path(__file__).parts[-2:]), sys.argv[1:]))
