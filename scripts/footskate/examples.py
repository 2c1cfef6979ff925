"""Feet of two prompts (a run, a double jump), plain and with `generate --footskate`, as one figure per prompt.

    python scripts/footskate/examples.py [--bundle stablemo/assets/demo_bundle] [--seconds 5] [--seed 3]
        [--out docs/data/footskate]

For "a person runs forward" and "a person jumps forward twice" the demo model generates once
without and once with the correction inside denoising (the same seed; `FootskateHook` at the last
step, the default of `generate --footskate`). Each figure shows, per foot joint, its height and
its horizontal speed over time (contact frames shaded, as detected on the corrected motion), and
the legs from the side at every frame of 1.2 s in the middle with the toes marked, plain and
corrected, so that planted feet read as stacked toe marks. Printed: the skating ratio (GMD definition), the feet's mean
acceleration and the height of the lowest foot joint on contact frames (mean) and in flight (highest) of both, read from
the joints recovered from the features. Both are the network's own output (`finish=False`): the finishing step that
puts every generation on the bundle's body and the floor (stablemo.inference.finish) is not part of the comparison.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

PROMPTS = {"run": "a person runs forward", "jump": "a person jumps forward twice"}
FEET = {"L ankle": 7, "L toe": 10, "R ankle": 8, "R toe": 11}
LEG_CHAINS = ((0, 1, 4, 7, 10), (0, 2, 5, 8, 11))


def _figure(plain: np.ndarray, clean: np.ndarray, contacts: np.ndarray, fps: float, title: str, path: Path) -> None:
    """plain / clean joints (T, 22, 3) y up, contacts (T, 4) of the corrected motion."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stablemo.outputs.render import save_png

    t = np.arange(len(plain)) / fps
    fig = plt.figure(figsize=(11, 10))
    grid = fig.add_gridspec(3, 2, height_ratios=[1, 1, 1.2])
    axes = [fig.add_subplot(grid[0, :]), fig.add_subplot(grid[1, :])]
    for k, (name, j) in enumerate(FEET.items()):
        colour = f"C{k}"
        for x, style, label in ((plain, ":", "plain"), (clean, "-", "--footskate")):
            speed = np.r_[np.linalg.norm(np.diff(x[:, j, [0, 2]], axis=0), axis=-1) * fps, np.nan]
            axes[0].plot(t, x[:, j, 1], style, color=colour, label=f"{name} {label}")
            axes[1].plot(t, speed, style, color=colour)
        axes[1].fill_between(t, 0, 0.15 * (k + 1), where=contacts[:, k], color=colour, alpha=0.15, step="mid")
    axes[0].set_ylabel("height (m)")
    axes[0].legend(ncol=4, fontsize=7)
    axes[1].set_ylabel("horizontal speed (m/s)")
    axes[1].set_ylim(0, 4)
    axes[1].set_xlabel("s (shaded: contacts of the corrected motion, one band per joint)")
    # side view of 1.2 s in the middle: forward (z) against height, every frame, toes marked
    lo = max(0, len(plain) // 2 - int(0.6 * fps))
    window = slice(lo, lo + int(1.2 * fps) + 1)
    for col, (x, colour, label) in enumerate(((plain, "0.4", "plain"), (clean, "C3", "--footskate"))):
        ax = fig.add_subplot(grid[2, col])
        for f in range(window.start, min(window.stop, len(x))):
            for chain in LEG_CHAINS:
                ax.plot(x[f, chain, 2], x[f, chain, 1], color=colour, lw=0.6, alpha=0.5)
        toes = x[window][:, [10, 11]]
        ax.plot(toes[..., 2].ravel(), toes[..., 1].ravel(), "o", ms=3, color="k")
        ax.set_aspect("equal")
        ax.set_title(f"{label}: legs from the side, {window.start / fps:.1f}-{(window.stop - 1) / fps:.1f} s, toes marked",
                     fontsize=9)
        ax.set_xlabel("forward (m)")
    fig.suptitle(title)
    fig.tight_layout()
    save_png(fig, path, dpi=80)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bundle", default="stablemo/assets/demo_bundle")
    p.add_argument("--seconds", type=float, default=5.0)
    p.add_argument("--seed", type=int, default=3)
    p.add_argument("--out", default="docs/data/footskate")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)

    from footskate.cleanup import detect_contacts
    from stablemo.skating.metrics import foot_skating_ratio
    from stablemo.skating.cleanup import topology, load_vgrf_model
    from stablemo.inference.hooks import make_hooks
    from stablemo.motion import features_to_joints
    from stablemo.inference.pipeline import Pipeline

    pipe = Pipeline.from_bundle(args.bundle)
    topo = topology(pipe.skeleton)
    frames = min(max(int(round(args.seconds * topo.fps)), pipe.min_length), pipe.max_length)
    vgrf = load_vgrf_model(None, pipe.skeleton)
    for key, text in PROMPTS.items():
        plain = pipe.generate([text], [frames], seed=[args.seed], finish=False).features
        clean = pipe.generate([text], [frames], seed=[args.seed], hooks=make_hooks(pipe, footskate=True),
                              finish=False).features
        jp, jc = features_to_joints(plain)[0], features_to_joints(clean)[0]           # (T, 22, 3)
        contacts = detect_contacts(jc[None], None, list(topo.feet), topo.fps, 1, vgrf, gate=True)[0][0]
        down = contacts[:, 0::2] | contacts[:, 1::2]                                  # (T, 2) a foot on the ground
        for name, j in (("plain", jp), ("--footskate", jc)):
            feet = j[:, list(topo.feet)]
            acc = float((feet[2:] - 2 * feet[1:-1] + feet[:-2]).abs().mean() * topo.fps ** 2)
            ratio = float(foot_skating_ratio(j[None], lengths=torch.tensor([frames])).mean())
            lowest = torch.minimum(feet[:, 0::2, 1], feet[:, 1::2, 1])               # (T, 2) per foot
            flight = lowest.amin(-1)[~down.any(-1)]
            print(f"{text!r} {name:12s} skating ratio {ratio:.3f}  foot acceleration {acc:.2f} m/s^2  lowest foot "
                  f"on contact frames {100 * float(lowest[down].mean()):.1f} cm, in flight up to "
                  f"{100 * float(flight.max()) if flight.numel() else float('nan'):.1f} cm")
        path = Path(args.out) / f"{key}_feet.png"
        _figure(jp.numpy(), jc.numpy(), contacts.numpy(), topo.fps, f"{text!r}, seed {args.seed}: plain (grey/dotted) "
                f"and generate --footskate", path)
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    from stablemo.errors import run_script

    sys.exit(run_script(main, "/".join(Path(__file__).parts[-2:]), sys.argv[1:]))
