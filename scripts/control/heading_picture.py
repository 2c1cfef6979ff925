"""docs/data/control/heading.png: a drawn path walked without and with the body steered along it.

    python scripts/control/heading_picture.py [--model student] [--out docs/data/control/heading.png]

Top view (x right, z up) of "a person walks forward" following an arc and an out-and-back path
(stablemo.eval.paths, seed 7) with the student; arrows: where the hips and shoulders face, every
half second; the title of each panel gives the median facing-vs-travel angle.
"""

from __future__ import annotations

import argparse

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import torch

from stablemo.eval.heading import heading_measures
from stablemo.eval.paths import family_path, path_control
from stablemo.inference.bundle import DEMO_BUNDLE, DEMO_STUDENT
from stablemo.inference.pipeline import Pipeline, Request
from stablemo.motion.heading import facing_yaw
from stablemo.motion.skeleton import get_skeleton
from stablemo.outputs.render import save_png


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", choices=["student", "teacher"], default="student")
    ap.add_argument("--out", default="docs/data/control/heading.png")
    args = ap.parse_args(argv)
    pipe = Pipeline.from_bundle(DEMO_STUDENT if args.model == "student" else DEMO_BUNDLE)
    skel = get_skeleton(pipe.skeleton)
    T, text = 120, "a person walks forward"
    fig, axes = plt.subplots(2, 2, figsize=(9, 9))
    for row, family in enumerate(("arc", "out_and_back")):
        xz = family_path(family, np.random.default_rng(7), T, pipe.fps, 0.9)
        control = path_control(xz, np.full(T, 0.93), skel.num_joints)
        for col, steer in enumerate((False, True)):
            out = pipe.generate(Request([text], T, seed=0, control=[control], face_travel=steer))
            j = out.joints[0]
            face = facing_yaw(j, skel, 5.0).numpy()
            angle = heading_measures(out.joints, torch.tensor([T]), skel)["facing_deg"][0]
            ax = axes[row, col]
            ax.plot(xz[:, 0], xz[:, 1], color="#e08a00", lw=4, alpha=0.4, label="drawn path")
            ax.plot(j[:, 0, 0], j[:, 0, 2], color="k", lw=1, label="pelvis")
            for t in range(0, T, 10):
                ax.arrow(float(j[t, 0, 0]), float(j[t, 0, 2]), 0.3 * np.sin(face[t]), 0.3 * np.cos(face[t]),
                         color="#c0392b", head_width=0.08, length_includes_head=True)
            ax.set_title(f"{family}, {'steered' if steer else 'not steered'}: facing vs travel {angle:.0f}°")
            ax.set_aspect("equal")
            ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="best", fontsize=8)
    fig.suptitle(f'"{text}", {args.model}, pelvis at every frame; arrows: facing every 0.5 s (start at the origin)')
    fig.tight_layout()
    save_png(fig, args.out, dpi=90)
    print(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
