"""Architecture ablation (paper Table 4): train every denoiser variant on the same data with the same
budget, evaluate them the same way, and write a CSV, a markdown table and a bar chart.

    python scripts/train/ablate.py --data data/synth                      # all seven variants, configs' budget
    python scripts/train/ablate.py --data data/synth --steps 100 --variants unet_base unet_xattn
    python scripts/train/ablate.py --data data/synth --evaluator runs/evaluator/evaluator.ckpt   # + FID, R-precision

Each variant is `configs/ablation/common.yaml` + `configs/ablation/<variant>.yaml`, trained through the
same LightningCLI as `stablemo fit`. Every variant is scored by the validation loss of its EMA weights
(fixed timesteps, noise fixed per clip: comparable across architectures); with --evaluator, each is also
exported to a bundle and scored by `stablemo evaluate` (FID, R-precision top-3) on the test split.
Outputs in --out: ablation.csv, ablation.md, ablation.png, and one run folder per variant.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
CONFIGS = REPO / "configs" / "ablation"

# (variant, family, row label) in the paper's Table 4 order
VARIANTS = [
    ("unet_base", "Conv1D UNet", "baseline"),
    ("unet_xattn", "Conv1D UNet", "+ cross-attention"),
    ("unet_xattn_gn", "Conv1D UNet", "+ GroupNorm tweak"),
    ("dit_base", "DiT", "baseline"),
    ("dit_xattn", "DiT", "+ cross-attention"),
    ("retnet_base", "RetNet", "baseline"),
    ("retnet_xattn", "RetNet", "+ cross-attention"),
]
FIELDS = ["variant", "network", "row", "dataset", "params", "steps", "batch_size", "train_seconds", "it_per_s",
          "val_loss", "val_loss_t50", "val_loss_t250", "val_loss_t500", "val_loss_t750", "val_loss_t950",
          "fid", "fid_conf95", "r_precision_top3", "r_precision_top3_conf95"]


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", default="data/synth", help="dataset folder in the HumanML3D layout (default data/synth)")
    p.add_argument("--dataset", default=None, choices=["humanml3d", "kit"], help="default: the configs' (humanml3d)")
    p.add_argument("--out", default="runs/ablation", help="output folder (default runs/ablation)")
    p.add_argument("--variants", nargs="+", default=[v for v, _, _ in VARIANTS], choices=[v for v, _, _ in VARIANTS])
    p.add_argument("--steps", type=int, default=None, help="optimiser steps per variant (default: common.yaml's)")
    p.add_argument("--batch-size", type=int, default=None, help="default: common.yaml's")
    p.add_argument("--seed", type=int, default=0, help="seeds data order, initialisation and noise (same for all)")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    p.add_argument("--evaluator", default=None, help="evaluator for FID / R-precision (see `stablemo evaluate`)")
    p.add_argument("--replications", type=int, default=3, help="evaluation replications with --evaluator")
    p.add_argument("--progress", action="store_true", help="show Lightning's progress bar")
    p.add_argument("overrides", nargs="*", help="extra LightningCLI overrides for every variant (after --)")
    return p.parse_args(argv)


def train_variant(variant: str, args: argparse.Namespace, run_dir: Path) -> dict:
    import torch
    from stablemo.training.lightning_cli import run_cli
    from stablemo.training.module import DiffusionModule

    cli_args = [
        "--config", str(CONFIGS / "common.yaml"), "--config", str(CONFIGS / f"{variant}.yaml"),
        f"--seed_everything={args.seed}", f"--model.seed={args.seed}", f"--data.seed={args.seed}",
        f"--data.data_dir={args.data}",
        f"--trainer.default_root_dir={run_dir}",  # its checkpoints/ and logs/ follow (stablemo.training.lightning_cli)
        f"--trainer.enable_progress_bar={str(args.progress).lower()}",
    ]
    if args.dataset:
        cli_args.append(f"--data.dataset={args.dataset}")
    if args.steps:
        cli_args.append(f"--trainer.max_steps={args.steps}")
    if args.batch_size:
        cli_args.append(f"--data.batch_size={args.batch_size}")
    cli_args += args.overrides
    cli = run_cli(DiffusionModule, cli_args, run=False, save_config_kwargs={"overwrite": True},
                  auto_configure_optimizers=False)
    start = time.perf_counter()
    cli.trainer.fit(cli.model, datamodule=cli.datamodule)
    seconds = time.perf_counter() - start
    steps = cli.trainer.global_step
    # The final score: validation loss of the EMA weights on the whole val split.
    metrics = cli.trainer.validate(cli.model, datamodule=cli.datamodule, verbose=False)[0]
    info = cli.model.data_info or {}
    row = {
        "variant": variant,
        "dataset": info.get("dataset", ""),
        "params": sum(p.numel() for p in cli.model.model.parameters() if p.requires_grad),
        "steps": steps,
        "batch_size": cli.datamodule.batch_size,
        "train_seconds": round(seconds, 1),
        "it_per_s": round(steps / seconds, 3) if seconds > 0 else "",
        "val_loss": float(metrics["val/loss"]),
    }
    for t in cli.model.hparams.val_timesteps:
        row[f"val_loss_t{int(t)}"] = float(metrics[f"val/loss_t{int(t)}"])
    row["checkpoint"] = cli.trainer.checkpoint_callback.last_model_path
    del cli
    torch.cuda.empty_cache() if torch.cuda.is_available() else None
    return row


def evaluate_variant(row: dict, args: argparse.Namespace, run_dir: Path) -> None:
    from stablemo.eval.evaluate import REAL_ROW
    from stablemo.cli.evaluate import main as evaluate_main
    from stablemo.training.export import export

    bundle = export(row["checkpoint"], run_dir / "bundle")
    out = run_dir / "evaluation.json"
    evaluate_main(["--bundle", str(bundle), "--data", args.data, "--evaluator", args.evaluator,
                   "--replications", str(args.replications), "--seed", str(args.seed), "--aits", "0",
                   "--out", str(out), "--no-progress"])
    rows = json.loads(out.read_text())["rows"]
    model_row = next(v for k, v in rows.items() if k != REAL_ROW)
    row["fid"], row["fid_conf95"] = model_row["fid"]["mean"], model_row["fid"]["conf95"]
    row["r_precision_top3"], row["r_precision_top3_conf95"] = model_row["r3"]["mean"], model_row["r3"]["conf95"]


def markdown_table(rows: list[dict], steps_note: str) -> str:
    """Paper Table 4 layout: Dataset | Network | FID | R Precision (top3), plus our validation loss."""
    def fmt(value, conf=None, digits=3):
        if value in ("", None):
            return "–"
        return f"{value:.{digits}f}" + (f" ± {conf:.{digits}f}" if conf not in ("", None) else "")

    lines = [
        "| Dataset | Network | Val loss ↓ | FID ↓ | R Precision (top3) ↑ | Params | Train time |",
        "|---|---|---|---|---|---|---|",
    ]
    last_family = None
    for r in rows:
        dataset = r["dataset"] if r is rows[0] or r["dataset"] != rows[0]["dataset"] else ""
        network = f"{r['network']} {r['row']}" if r["network"] != last_family else r["row"]
        last_family = r["network"]
        lines.append(
            f"| {dataset} | {network} | {fmt(r['val_loss'], digits=4)} | {fmt(r.get('fid'), r.get('fid_conf95'))} | "
            f"{fmt(r.get('r_precision_top3'), r.get('r_precision_top3_conf95'))} | {r['params'] / 1e6:.2f} M | "
            f"{r['train_seconds']:.0f} s |"
        )
    lines += ["", steps_note]
    return "\n".join(lines) + "\n"


def bar_chart(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stablemo.outputs.render import save_png

    colours = {"Conv1D UNet": "#4C72B0", "DiT": "#DD8452", "RetNet": "#55A868"}
    metrics = [("val_loss", "validation loss (EMA) ↓")]
    if any(r.get("fid") not in ("", None) for r in rows):
        metrics += [("fid", "FID ↓"), ("r_precision_top3", "R-precision top-3 ↑")]
    fig, axes = plt.subplots(1, len(metrics), figsize=(4.5 * len(metrics) + 1, 4), squeeze=False)
    labels = [f"{r['network']}\n{r['row']}" for r in rows]
    for ax, (key, title) in zip(axes[0], metrics):
        values = [float(r[key]) if r.get(key) not in ("", None) else 0.0 for r in rows]
        bars = ax.bar(range(len(rows)), values, color=[colours[r["network"]] for r in rows])
        ax.bar_label(bars, fmt="%.3f", fontsize=7)
        ax.set_xticks(range(len(rows)), labels, rotation=45, ha="right", fontsize=7)
        ax.set_title(title, fontsize=9)
    fig.suptitle(f"Architecture ablation ({rows[0]['dataset']}, {rows[0]['steps']} steps each)", fontsize=10)
    fig.tight_layout()
    save_png(fig, path, dpi=120)
    plt.close(fig)


def write_outputs(rows: list[dict], out: Path) -> None:
    from stablemo.io import write_text

    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=FIELDS, extrasaction="ignore")
    writer.writeheader()
    writer.writerows(rows)
    write_text(out / "ablation.csv", buffer.getvalue())
    steps = {r["steps"] for r in rows}
    note = (f"Same data, seed and budget for every variant ({', '.join(map(str, sorted(steps)))} steps, batch "
            f"{rows[0]['batch_size']}). Val loss: masked MSE of the EMA model at t ∈ {{50, 250, 500, 750, 950}} "
            "with noise fixed per clip.")
    write_text(out / "ablation.md", markdown_table(rows, note))
    bar_chart(rows, out / "ablation.png")


def main(argv: list[str] | None = None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    from stablemo.errors import StableMoError

    if not Path(args.data).is_dir():
        raise StableMoError(f"--data {args.data}: folder not found (write one with `stablemo data synth --out {args.data}`)")
    if args.threads:
        import torch

        torch.set_num_threads(args.threads)
    out = Path(args.out)
    order = {v: i for i, (v, _, _) in enumerate(VARIANTS)}
    labels = {v: (family, label) for v, family, label in VARIANTS}
    rows = []
    for variant in sorted(dict.fromkeys(args.variants), key=order.get):
        run_dir = out / variant
        print(f"[ablate] {variant}: training", flush=True)
        row = train_variant(variant, args, run_dir)
        row["network"], row["row"] = labels[variant]
        if args.evaluator:
            print(f"[ablate] {variant}: evaluating", flush=True)
            evaluate_variant(row, args, run_dir)
        print(f"[ablate] {variant}: val loss {row['val_loss']:.4f} after {row['steps']} steps "
              f"({row['train_seconds']:.0f} s)", flush=True)
        rows.append(row)
        write_outputs(rows, out)  # partial results survive an interrupted sweep
    print((out / "ablation.md").read_text())
    print(f"wrote {out / 'ablation.csv'}, {out / 'ablation.md'}, {out / 'ablation.png'}")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except Exception as err:  # StableMoError: one clear line
        from stablemo.errors import StableMoError

        if isinstance(err, StableMoError):
            print(f"ablate: error: {err}", file=sys.stderr)
            sys.exit(2)
        raise
