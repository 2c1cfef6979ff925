"""The README's headline prompt as the shipped models make it, drawn: docs/data/results/readme_prompt.png.

    python scripts/results/readme_prompt_picture.py [--out docs/data/results/readme_prompt.png]

"a person walks forward, then waves their right hand" (no length given; prompts in parts, as
`stablemo generate` does), teacher and 1-step student, seeds 0 and 1: per motion the wrists' and the
right shoulder's heights and the pelvis speed over time with the parts' boundaries, and a side view
of ten frames (the right arm red, the left blue), so a reader sees the walk end before the right hand
rises above the shoulder and the left hand stay down.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from stablemo.inference.bundle import DEMO_BUNDLE, DEMO_STUDENT
from stablemo.inference.pipeline import Pipeline, Request
from stablemo.motion.skeleton import get_skeleton

TEXT = "a person walks forward, then waves their right hand"
DOCS = Path(__file__).resolve().parents[2] / "docs"


def main(argv: list[str]) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stablemo.outputs.render import save_png

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=str(DOCS / "data" / "results" / "readme_prompt.png"))
    args = p.parse_args(argv)
    skel = get_skeleton("humanml3d")
    names = skel.joint_names
    rw, lw, rs = names.index("R_wrist"), names.index("L_wrist"), names.index("R_shoulder")
    right, left = {names.index("R_elbow"), rw}, {names.index("L_elbow"), lw}
    fig, axes = plt.subplots(4, 2, figsize=(14, 12))
    for row, (name, bundle) in enumerate([("teacher", DEMO_BUNDLE), ("1-step student", DEMO_STUDENT)]):
        pipe = Pipeline.from_bundle(bundle)
        for col, seed in enumerate([0, 1]):
            out = pipe.generate(Request([TEXT], seed=seed, plan=True))
            j, plan = out.joint_list()[0], out.info["plans"][0]  # (T, J, 3), the parts
            t = np.arange(len(j)) / pipe.fps
            ax = axes[2 * row, col]
            ax.plot(t, j[:, rw, 1], label="right wrist height (m)")
            ax.plot(t, j[:, lw, 1], label="left wrist height (m)")
            ax.plot(t, j[:, rs, 1], "--", label="right shoulder height (m)")
            speed = np.linalg.norm(np.diff(j[:, 0, [0, 2]], axis=0), axis=1) * pipe.fps
            ax.plot(t[1:], speed, ":", label="pelvis speed (m/s)")
            for part in plan[1:]:
                ax.axvline(part["start"] / pipe.fps, color="k", lw=0.6)
            ax.set_title(f"{name}, seed {seed}: " + " | ".join(part["text"] for part in plan), fontsize=9)
            ax.set_xlabel("s")
            ax.legend(fontsize=7)
            ax = axes[2 * row + 1, col]
            for f in np.linspace(0, len(j) - 1, 10).astype(int):
                for c, parent in enumerate(skel.parents):
                    if parent >= 0:
                        color = "r" if c in right else "b" if c in left else "k"
                        ax.plot([j[f, c, 2], j[f, parent, 2]], [j[f, c, 1], j[f, parent, 1]], color, lw=1)
            ax.set_aspect("equal")
            ax.set_title("ten frames seen from the side (forward to the right); right arm red, left blue", fontsize=9)
    fig.suptitle(f'"{TEXT}" (stablemo generate\'s defaults)')
    fig.tight_layout()
    save_png(fig, args.out, dpi=70)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
