"""Plot the training and validation loss of several runs side by side (docs/training.md, #28).

    python scripts/plot_precision_runs.py --out docs/precision_runs.png \
        "fp32 seed 0=runs/q28_fp32" "bf16-mixed seed 0=runs/q28_bf16" "fp32 seed 1=runs/q28_fp32_s1"
    python scripts/plot_precision_runs.py --metric joint_err_m --out docs/control/controlnet_training.png \
        "session 10=docs/controlnet_training_log_session10.csv" "session 12=docs/controlnet_training_log.csv"

Each LABEL=RUN reads RUN/logs/version_*/metrics.csv as Lightning's CSV logger writes it (all
versions of a resumed run, merged by scripts/merge_logs.py: a later version wins a step), or a CSV
that script wrote: train/<metric> every `log_every_n_steps`, val/<metric> at each validation.
Left panel: the train value (one batch per point, so noisy) and its moving average; right: the
validation value (EMA weights, fixed timesteps and seeded noise: comparable between runs). Also
prints the numbers plotted, so the figure can be checked against the CSVs.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from merge_logs import merge  # noqa: E402


def read_run(run: Path, metric: str = "loss") -> tuple[list[tuple[int, float]], list[tuple[int, float]]]:
    if run.is_file():
        with run.open() as f:
            rows = list(csv.DictReader(f))
    else:
        rows = merge(run / "logs")[1]
        if not rows:
            raise SystemExit(f"{run}: no logs/version_*/metrics.csv")
    train, val = [], []
    for row in rows:
        step = int(row["step"]) + 1  # Lightning logs the 0-based index of the step just done
        if row.get(f"train/{metric}"):
            train.append((step, float(row[f"train/{metric}"])))
        if row.get(f"val/{metric}"):
            val.append((step, float(row[f"val/{metric}"])))
    return train, val


UNITS = {"loss": "masked MSE (x0)", "joint_err_m": "hinted-joint error (m)"}


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
    parser.add_argument("--smooth", type=int, default=5, help="moving-average width (logged points) for the train value")
    parser.add_argument("--metric", default="loss", help="what to plot: train/<metric> and val/<metric> (loss, joint_err_m)")
    args = parser.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stablemo.render import save_png

    fig, (ax_t, ax_v) = plt.subplots(1, 2, figsize=(11, 4))
    for spec in args.runs:
        label, _, run = spec.partition("=")
        if not run:
            raise SystemExit(f"{spec!r}: expected LABEL=RUN_DIR")
        train, val = read_run(Path(run), args.metric)
        steps, losses = zip(*train)
        line, = ax_t.plot(steps, losses, alpha=0.25, linewidth=0.8)
        ax_t.plot(steps, moving_average(list(losses), args.smooth), color=line.get_color(), label=label)
        if val:
            vs, vl = zip(*val)
            ax_v.plot(vs, vl, marker="o", color=line.get_color(), label=label)
        print(f"{label}: train/{args.metric} {' '.join(f'{s}:{v:.3f}' for s, v in train)}")
        print(f"{label}: val/{args.metric} {' '.join(f'{s}:{v:.4f}' for s, v in val)}")
    unit = UNITS.get(args.metric, args.metric)
    ax_t.set(title=f"train/{args.metric} (faint: each logged batch; bold: moving average of {args.smooth})",
             xlabel="optimiser step", ylabel=unit)
    ax_v.set(title=f"val/{args.metric} (EMA weights, fixed timesteps and noise)", xlabel="optimiser step", ylabel=unit)
    for ax in (ax_t, ax_v):
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    save_png(fig, args.out, dpi=110)
    return 0


if __name__ == "__main__":
    sys.exit(main())
