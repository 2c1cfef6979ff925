"""Plot the training and validation loss of several runs side by side (docs/training.md, #28).

    python scripts/plot_precision_runs.py --out docs/precision_runs.png \
        "fp32 seed 0=runs/q28_fp32" "bf16-mixed seed 0=runs/q28_bf16" "fp32 seed 1=runs/q28_fp32_s1"

Each LABEL=RUN reads RUN/logs/version_*/metrics.csv (the newest version) as Lightning's CSV logger
writes it: train/loss every `log_every_n_steps`, val/loss at each validation. Left panel: the
train loss (one batch per point, so noisy) and its moving average; right: val/loss, the EMA
model's masked MSE at fixed timesteps and seeded noise (comparable between runs). Also prints
the numbers plotted, so the figure can be checked against the CSVs.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path


def read_run(run: Path) -> tuple[list[tuple[int, float]], list[tuple[int, float]]]:
    versions = sorted(run.glob("logs/version_*/metrics.csv"), key=lambda p: int(p.parent.name.split("_")[1]))
    if not versions:
        raise SystemExit(f"{run}: no logs/version_*/metrics.csv")
    train, val = [], []
    with versions[-1].open() as f:
        for row in csv.DictReader(f):
            step = int(row["step"]) + 1  # Lightning logs the 0-based index of the step just done
            if row.get("train/loss"):
                train.append((step, float(row["train/loss"])))
            if row.get("val/loss"):
                val.append((step, float(row["val/loss"])))
    return train, val


def moving_average(values: list[float], width: int) -> list[float]:
    out = []
    for i in range(len(values)):
        window = values[max(0, i - width + 1): i + 1]
        out.append(sum(window) / len(window))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", help="LABEL=RUN_DIR")
    parser.add_argument("--out", required=True, help="PNG to write")
    parser.add_argument("--smooth", type=int, default=5, help="moving-average width (logged points) for train/loss")
    args = parser.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stablemo.io import atomic_open

    fig, (ax_t, ax_v) = plt.subplots(1, 2, figsize=(11, 4))
    for spec in args.runs:
        label, _, run = spec.partition("=")
        if not run:
            raise SystemExit(f"{spec!r}: expected LABEL=RUN_DIR")
        train, val = read_run(Path(run))
        steps, losses = zip(*train)
        line, = ax_t.plot(steps, losses, alpha=0.25, linewidth=0.8)
        ax_t.plot(steps, moving_average(list(losses), args.smooth), color=line.get_color(), label=label)
        if val:
            vs, vl = zip(*val)
            ax_v.plot(vs, vl, marker="o", color=line.get_color(), label=label)
        print(f"{label}: train/loss {' '.join(f'{s}:{v:.3f}' for s, v in train)}")
        print(f"{label}: val/loss {' '.join(f'{s}:{v:.4f}' for s, v in val)}")
    ax_t.set(title=f"train/loss (faint: each logged batch; bold: moving average of {args.smooth})",
             xlabel="optimiser step", ylabel="masked MSE (x0)")
    ax_v.set(title="val/loss (EMA weights, fixed timesteps and noise)", xlabel="optimiser step", ylabel="masked MSE (x0)")
    for ax in (ax_t, ax_v):
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    with atomic_open(args.out) as f:
        fig.savefig(f, format="png", dpi=110)
    return 0


if __name__ == "__main__":
    sys.exit(main())
