"""`stablemo bench train --config FILE`: training iterations/s and peak memory for a training config.

Builds the model and data exactly as `stablemo fit --config FILE` would, then runs a short fit
(no validation, no checkpoints, no logger) and times the optimiser steps after a warm-up. Timed
steps include data loading, text encoding, forward, backward, clipping, the optimiser and the EMA
update: what a real run pays per step.

`stablemo bench train --paired [--config FILE]` instead times the denoiser's training step alone
(forward, masked x0 MSE, backward, AdamW) on random inputs for several implementations of the same
network side by side in one process (stablemo.bench.paired): what the step costs, not the data.
"""

from __future__ import annotations

import json
import resource
import sys
import time

import torch
from lightning.pytorch import Callback, Trainer

from stablemo.errors import StableMoError


class StepTimer(Callback):
    def __init__(self) -> None:
        self.stamps: list[float] = []
        self.cpu: list[float] = []  # process CPU time: what the steps cost on a machine shared with others

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        if pl_module.device.type == "cuda":
            torch.cuda.synchronize(pl_module.device)
        self.stamps.append(time.perf_counter())
        self.cpu.append(time.process_time())


def peak_memory_mb(device: torch.device) -> tuple[str, float]:
    if device.type == "cuda":
        return "cuda max allocated", torch.cuda.max_memory_allocated(device) / 2**20
    # ru_maxrss is KiB on Linux, bytes on macOS
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return "process peak RSS", rss / (2**20 if sys.platform == "darwin" else 2**10)


def run_train_bench(args) -> int:
    """Time `args.steps` optimiser steps of a training config (or, with args.paired, the denoiser
    step of each implementation side by side); prints the table, writes args.json if given."""
    if args.paired:
        from stablemo.bench.paired import run_paired

        return run_paired(args)

    from stablemo.training.lightning_cli import run_cli
    from stablemo.training.module import DiffusionModule

    cli_args = ["--config", args.config, f"--seed_everything={args.seed}", *args.overrides]
    if args.batch_size:
        cli_args.append(f"--data.batch_size={args.batch_size}")
    cli = run_cli(DiffusionModule, cli_args, run=False, save_config_callback=None, auto_configure_optimizers=False)
    configured = cli.trainer
    timer = StepTimer()
    trainer = Trainer(
        accelerator=configured.accelerator,
        devices=1,
        precision=cli.config.trainer.get("precision"),
        gradient_clip_val=configured.gradient_clip_val,
        max_steps=args.warmup + args.steps,
        limit_val_batches=0,
        num_sanity_val_steps=0,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        callbacks=[timer],
    )
    trainer.fit(cli.model, datamodule=cli.datamodule)
    device = cli.model.device
    # timed: from the end of the last warm-up step to the end of the last step
    stamps = timer.stamps[args.warmup - 1:]
    if len(stamps) < 2:
        raise StableMoError(f"{args.config}: too few steps ran to time ({len(timer.stamps)})")
    its = (len(stamps) - 1) / (stamps[-1] - stamps[0])
    cpu = timer.cpu[args.warmup - 1:]
    cpu_per_it = (cpu[-1] - cpu[0]) / (len(cpu) - 1)
    kind, peak = peak_memory_mb(device)
    n_params = sum(p.numel() for p in cli.model.model.parameters() if p.requires_grad)
    result = {
        "config": args.config,
        "device": str(device),
        "threads": torch.get_num_threads(),
        "batch_size": cli.datamodule.batch_size,
        "trainable_params": n_params,
        "timed_steps": len(stamps) - 1,
        "it_per_s": its,
        "s_per_it": 1.0 / its,
        "samples_per_s": its * cli.datamodule.batch_size,
        "cpu_s_per_it": cpu_per_it,
        "peak_memory_mb": peak,
        "peak_memory_kind": kind,
    }
    print(f"config            {args.config}")
    print(f"device            {device} ({result['threads']} threads)")
    print(f"trainable params  {n_params / 1e6:.2f} M")
    print(f"batch size        {result['batch_size']}")
    print(f"training speed    {its:.3f} it/s  ({1 / its:.3f} s/it, {result['samples_per_s']:.1f} samples/s)")
    print(f"CPU time          {cpu_per_it:.3f} CPU-s/it (all threads; wall time when nothing else runs, 1 thread)")
    print(f"peak memory       {peak:.0f} MiB ({kind})")
    max_steps = configured.max_steps
    if max_steps and max_steps > 0:
        print(f"full run          {max_steps} steps ~ {max_steps / its / 60:.1f} min at this speed")
    if args.json:
        from stablemo.io import write_text

        write_text(args.json, json.dumps(result, indent=2) + "\n")
    return 0
