"""Training from shards against the memory-mapped folder reader: a paired, interleaved A/B, and RSS.

    .venv/bin/python scripts/bench/shard_throughput.py ab --data DIR --shards SHARDS \
        [--config configs/synth_small.yaml] [--rounds 6] [--steps 30] [--warmup 5]
    .venv/bin/python scripts/bench/shard_throughput.py rss --shards SHARDS [--batch-size 32] [--every 200]

`ab`: one model (the config's), two MotionDataModules that differ only in data_dir / shards. Each
round trains `warmup + steps` optimiser steps from the folder, then as many from the shards (the
order alternates every round: this VM's speed drifts, and a pair measured back to back sees the same
machine). Only the steps after the warm-up are timed (stablemo.bench.train.StepTimer), so a round
includes data loading, text encoding, forward, backward and the optimiser, not the Trainer's set-up.
Prints every pair, and the median over pairs of the speed ratio (shards / folder) from wall time
and from this process's CPU time per step (less sensitive to other jobs on a shared machine).

`rss`: the resident memory of this process while the shard loader serves one whole training epoch
(every item decoded, cropped, collated), sampled every `--every` batches; then the same for `--steps`
training steps of the config's model. Prints the samples and the spread (max - min after warm-up).
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch


def rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def build(config: str, data: list[str]):
    from stablemo.training.lightning_cli import run_cli
    from stablemo.training.module import DiffusionModule

    cli = run_cli(DiffusionModule, ["--config", config, *data], run=False, save_config_callback=None,
                  auto_configure_optimizers=False)
    return cli.model, cli.datamodule


def timed_fit(module, datamodule, steps: int, warmup: int) -> tuple[float, float]:
    """(optimiser steps per second, process CPU seconds per step) after the warm-up."""
    from lightning.pytorch import Trainer

    from stablemo.bench.train import StepTimer

    timer = StepTimer()
    trainer = Trainer(accelerator="cpu", devices=1, max_steps=warmup + steps, limit_val_batches=0,
                      num_sanity_val_steps=0, logger=False, enable_checkpointing=False, enable_progress_bar=False,
                      enable_model_summary=False, callbacks=[timer], gradient_clip_val=1.0)
    trainer.fit(module, datamodule=datamodule)
    stamps, cpu = timer.stamps[warmup - 1:], timer.cpu[warmup - 1:]
    return (len(stamps) - 1) / (stamps[-1] - stamps[0]), (cpu[-1] - cpu[0]) / (len(cpu) - 1)


def run_ab(args) -> None:
    from stablemo.data import MotionDataModule

    module, folder = build(args.config, [f"--data.data_dir={args.data}"])
    keep = {k: v for k, v in folder.hparams.items() if k not in ("data_dir", "shards") and not k.startswith("_")}
    shards = MotionDataModule(shards=args.shards, **keep)
    print(f"model {sum(p.numel() for p in module.parameters() if p.requires_grad) / 1e6:.2f} M trainable, "
          f"batch {folder.batch_size}, {torch.get_num_threads()} torch threads")
    arms = {"folder": folder, "shards": shards}
    speeds: dict[str, list[float]] = {"folder": [], "shards": []}
    cpus: dict[str, list[float]] = {"folder": [], "shards": []}
    for r in range(args.rounds):
        order = ["folder", "shards"] if r % 2 == 0 else ["shards", "folder"]
        for name in order:
            speed, cpu = timed_fit(module, arms[name], args.steps, args.warmup)
            speeds[name].append(speed)
            cpus[name].append(cpu)
        print(f"round {r}: folder {speeds['folder'][-1]:.3f} it/s ({cpus['folder'][-1]:.3f} CPU-s/it), shards "
              f"{speeds['shards'][-1]:.3f} it/s ({cpus['shards'][-1]:.3f} CPU-s/it), ratio "
              f"{speeds['shards'][-1] / speeds['folder'][-1]:.3f} (CPU {cpus['folder'][-1] / cpus['shards'][-1]:.3f})",
              flush=True)
    ratios = [s / f for s, f in zip(speeds["shards"], speeds["folder"])]
    cpu_ratios = [f / s for s, f in zip(cpus["shards"], cpus["folder"])]
    print(f"median it/s: folder {statistics.median(speeds['folder']):.3f}, shards {statistics.median(speeds['shards']):.3f}")
    print(f"shards / folder speed (wall): median of pairs {statistics.median(ratios):.3f} "
          f"(min {min(ratios):.3f}, max {max(ratios):.3f})")
    print(f"shards / folder speed (CPU time per step): median of pairs {statistics.median(cpu_ratios):.3f} "
          f"(min {min(cpu_ratios):.3f}, max {max(cpu_ratios):.3f})")


def run_rss(args) -> None:
    from stablemo.data import MotionDataModule

    start = rss_mb()
    dm = MotionDataModule(shards=args.shards, batch_size=args.batch_size, max_length=196, pad_multiple=4)
    dm.setup("fit")
    loader = dm.train_dataloader()
    loader.sampler.set_epoch(0)
    samples, t0 = [], time.perf_counter()
    for i, _ in enumerate(loader):
        if i % args.every == 0:
            samples.append((i, rss_mb()))
            print(f"batch {i:>6}: RSS {samples[-1][1]:.0f} MiB", flush=True)
    took = time.perf_counter() - t0
    samples.append((i + 1, rss_mb()))
    after_warmup = [m for b, m in samples if b >= args.every]
    print(f"one epoch: {i + 1} batches, {len(loader.dataset)} items, {len(loader.dataset.shards)} shards in {took:.0f} s "
          f"({len(loader.dataset) / took:.0f} items/s); RSS at start {start:.0f} MiB, after warm-up "
          f"{min(after_warmup):.0f}..{max(after_warmup):.0f} MiB (spread {max(after_warmup) - min(after_warmup):.0f} MiB)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    ab = sub.add_parser("ab")
    ab.add_argument("--data", required=True)
    ab.add_argument("--shards", required=True)
    ab.add_argument("--config", default="configs/synth_small.yaml")
    ab.add_argument("--rounds", type=int, default=6)
    ab.add_argument("--steps", type=int, default=30)
    ab.add_argument("--warmup", type=int, default=5)
    rss = sub.add_parser("rss")
    rss.add_argument("--shards", required=True)
    rss.add_argument("--batch-size", type=int, default=32)
    rss.add_argument("--every", type=int, default=200)
    args = parser.parse_args()
    torch.set_num_threads(1)  # the tests' and the paired benches' setting: a shared 2-core VM
    run_ab(args) if args.command == "ab" else run_rss(args)


if __name__ == "__main__":
    main()
