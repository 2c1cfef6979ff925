"""Training logs: merge a run's CSV logs into one file, and plot runs side by side.

    python scripts/train/training_log.py merge runs/demo/logs docs/data/training/demo_training_log.csv
    python scripts/train/training_log.py plot --out runs.png "fp32=runs/fp32" "bf16-mixed=runs/bf16"
    python scripts/train/training_log.py plot --metric joint_err_m --out docs/data/control/controlnet_training.png \
        "λ 1, no output injection, 1800 steps=docs/data/control/controlnet_training_log_lambda1.csv" \
        "λ 10, lr/10 at 2000, 4500 steps=docs/data/control/controlnet_training_log_decay2000.csv" \
        "λ 10, lr/10 at 3500 and 7000, 7500 steps (shipped)=docs/data/control/controlnet_training_log.csv"

merge: Lightning's CSV logger writes one RUN/logs/version_N/metrics.csv per start of a run; a
resumed run logs again the steps after its checkpoint. The merged CSV has one row per logged step
(a later version wins a step) and is written atomically.

plot: each LABEL=RUN (the label without "=") reads RUN/logs/version_*/metrics.csv (merged as above) or a merged CSV:
train/<metric> every `log_every_n_steps`, val/<metric> at each validation. Left panel: the train
value (one batch per point, so noisy) and its moving average; right: the validation value (EMA
weights, fixed timesteps and seeded noise: comparable between runs). Also prints the numbers
plotted, so the figure can be checked against the CSVs.
"""

from __future__ import annotations

import argparse
import csv
import io
import sys
from pathlib import Path


def merge(log_dir: Path) -> tuple[list[str], list[dict]]:
    """(columns, one row per logged step) of every version_*/metrics.csv under log_dir."""
    rows: dict[int, dict] = {}
    columns: list[str] = []
    for metrics in sorted(log_dir.glob("version_*/metrics.csv"), key=lambda p: int(p.parent.name.split("_")[1])):
        with metrics.open() as f:
            for row in csv.DictReader(f):
                columns += [c for c in row if c not in columns]
                # a resumed run re-logs steps after its checkpoint: the later version wins
                step = rows.setdefault(int(row["step"]), {})
                step.update({k: v for k, v in row.items() if v != ""})
    return columns, [rows[s] for s in sorted(rows)]


def merge_command(log_dir: str, out: str) -> int:
    from stablemo.io import write_text

    columns, rows = merge(Path(log_dir))
    if not rows:
        print(f"{log_dir}: no metrics.csv found", file=sys.stderr)
        return 1
    buffer = io.StringIO(newline="")
    writer = csv.DictWriter(buffer, fieldnames=columns)
    writer.writeheader()
    writer.writerows(rows)
    write_text(out, buffer.getvalue())  # atomic: a failed merge never truncates the old CSV
    print(f"wrote {out} ({len(rows)} steps)")
    return 0


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
    sub = parser.add_subparsers(dest="command", required=True)
    m = sub.add_parser("merge", help="merge RUN/logs/version_*/metrics.csv into one CSV")
    m.add_argument("log_dir", help="the run's logs folder (RUN/logs)")
    m.add_argument("out", help="CSV to write")
    p = sub.add_parser("plot", help="train and validation curves of runs side by side")
    p.add_argument("runs", nargs="+", help="LABEL=RUN_DIR or LABEL=merged.csv")
    p.add_argument("--out", required=True, help="PNG to write")
    p.add_argument("--smooth", type=int, default=5, help="moving-average width (logged points) for the train value")
    p.add_argument("--metric", default="loss", help="what to plot: train/<metric> and val/<metric> (loss, joint_err_m)")
    args = parser.parse_args(argv)
    if args.command == "merge":
        return merge_command(args.log_dir, args.out)
    return plot(args)


def plot(args: argparse.Namespace) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stablemo.outputs.render import save_png

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
