"""Pictures of the synthetic generator's idle rest (docs/synth.md, "Rest around the action").

    .venv/bin/python scripts/synth/rest_pictures.py [--out docs/data/synth] [--seed 0]

rest_sheet.png: one "jumps twice" plan built at three total lengths (the same two jumps, more
or less idle rest before and after), frames evenly spaced. rest_curves.png: for the same three
clips, the pelvis' sideways offset and height and the fastest foot joint's speed over time, with
the action's frames shaded: the rest sways by millimetres to centimetres with the feet still.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from stablemo.data.synth import captions, compose, idle
from stablemo.data.synth.timeline import FPS
from stablemo.errors import run_script
from stablemo.outputs.render import render_contact_sheet, save_png

PLAN = [("jump", dict(count=2, flight=0.42))]
TOTALS = (60, 120, 196)  # feature frames: near the plan's shortest, middle, HumanML3D's longest
FOOT_JOINTS = [7, 8, 10, 11]


def clips(seed: int) -> list[tuple[str, np.ndarray, int, int]]:
    """(title, joints (T+1, 22, 3), first action frame, first lead-out frame) per total length."""
    rng = np.random.default_rng(seed)
    core = len(compose.build_rested(PLAN, 0, 0, (idle.sample_style(rng), idle.sample_style(rng))).joints) - 1
    text = captions.captions_for(PLAN, rng, num=1)[0]
    out = []
    for total in TOTALS:
        before = int(rng.integers(0, total - core + 1))
        built = compose.build_rested(PLAN, before, total - core - before, (idle.sample_style(rng), idle.sample_style(rng)))
        part = built.parts[0]
        out.append((f"{text} ({total / FPS:.1f} s)", built.joints, part.start, part.end))
    return out


def plot_curves(items, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(9, 6.5), sharex=True)
    for k, (title, j, a, b) in enumerate(items):
        j = j.astype(np.float64)
        t = np.arange(len(j)) / FPS
        colour = f"C{k}"
        axes[0].plot(t, 100 * (j[:, 0, 0] - j[0, 0, 0]), colour, label=title)
        axes[1].plot(t, j[:, 0, 1], colour)
        speed = np.linalg.norm(np.diff(j[:, FOOT_JOINTS], axis=0), axis=-1).max(1) * FPS  # (T,) m/s
        axes[2].plot(t[1:], speed, colour)
        for ax in axes:
            ax.axvspan(a / FPS, b / FPS, color=colour, alpha=0.08)
    axes[0].set_ylabel("pelvis sideways (cm)")
    axes[1].set_ylabel("pelvis height (m)")
    axes[2].set_ylabel("fastest foot joint (m/s)")
    axes[2].set_yscale("symlog", linthresh=0.01)
    axes[2].set_xlabel("time (s); shaded: the two jumps")
    axes[0].legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    save_png(fig, path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="docs/data/synth", help="folder for rest_sheet.png and rest_curves.png")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    out = Path(args.out)
    items = clips(args.seed)
    render_contact_sheet([j for _, j, _, _ in items], [t for t, _, _, _ in items], out / "rest_sheet.png",
                         frames_per_row=10)
    plot_curves(items, out / "rest_curves.png")
    print(f"wrote {out / 'rest_sheet.png'} and {out / 'rest_curves.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main, "/".join(Path(__file__).parts[-2:]), sys.argv[1:]))
