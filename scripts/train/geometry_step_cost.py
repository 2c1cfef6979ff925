"""What the geometric losses (`model.geometry`) add to a training step, measured paired.

    python scripts/train/geometry_step_cost.py [--configs configs/demo.yaml configs/demo_geometry.yaml]
        [--data data/synth] [--accelerator cpu|gpu] [--rounds 20] [--warmup 3] [--threads N] [--json FILE]

Builds the model of the last config set (the demo recipe with its geometry overlay by default) and a
copy without geometry holding the same weights, takes one batch of the training data, and then
alternates one optimiser step of each (training_step, backward, gradient clipping, AdamW, EMA) for
--rounds rounds, the first of the pair switching every round so that neither always runs warm. Data
loading is not timed (the same for both). Prints the median step of each and the median of the
per-round differences.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
import warnings

import torch

from stablemo.errors import StableMoError, run_script


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _timed_step(module, optimizer, batch: dict, index: int, device: torch.device) -> tuple[float, float]:
    """(wall seconds, process CPU seconds) of one optimiser step."""
    _sync(device)
    start, cpu = time.perf_counter(), time.process_time()
    loss = module.training_step(batch, index)
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(module.model.parameters(), 1.0)  # the recipe's gradient_clip_val
    optimizer.step()
    module.ema.update(module.model)
    _sync(device)
    return time.perf_counter() - start, time.process_time() - cpu


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="geometry_step_cost", description=__doc__.split("\n\n")[0])
    p.add_argument("--configs", nargs="+", default=["configs/demo.yaml", "configs/demo_geometry.yaml"])
    p.add_argument("--data", default=None, help="data folder (default: the config's data.data_dir)")
    p.add_argument("--accelerator", choices=("cpu", "gpu"), default="cpu")
    p.add_argument("--rounds", type=int, default=20)
    p.add_argument("--warmup", type=int, default=3)
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--json", default=None, help="also write the result here")
    args = p.parse_args(argv)
    if args.rounds < 1 or args.warmup < 0:
        raise StableMoError("--rounds must be >= 1 and --warmup >= 0")
    if args.threads:
        torch.set_num_threads(args.threads)
    device = torch.device("cuda" if args.accelerator == "gpu" else "cpu")
    if device.type == "cuda" and not torch.cuda.is_available():
        raise StableMoError("--accelerator gpu: no CUDA device")

    from stablemo.training.lightning_cli import run_cli
    from stablemo.training.module import DiffusionModule, data_info_from

    cli_args = [a for path in args.configs for a in ("--config", path)] + ["--trainer.accelerator=cpu"]
    if args.data:
        cli_args.append(f"--data.data_dir={args.data}")
    cli = run_cli(DiffusionModule, cli_args, run=False, save_config_callback=None)
    geometric = cli.model
    if not geometric.geometry_weights:
        raise StableMoError(f"--configs {' '.join(args.configs)}: no geometric term is switched on (model.geometry)")
    cli.datamodule.setup("fit")
    geometric.data_info = data_info_from(cli.datamodule)
    settings = {k: v for k, v in geometric.hparams.items() if not k.startswith("_")}  # LightningCLI adds _instantiator
    plain = DiffusionModule(**{**settings, "geometry": None})
    plain.load_state_dict(geometric.state_dict())
    plain.data_info = geometric.data_info
    batch = next(iter(cli.datamodule.train_dataloader()))
    batch = {k: v.to(device) if torch.is_tensor(v) else v for k, v in batch.items()}
    rows = {}
    for name, module in (("plain", plain), ("geometry", geometric)):
        module.to(device).train()
        rows[name] = (module, module.configure_optimizers()["optimizer"])
    times: dict[str, list[tuple[float, float]]] = {"plain": [], "geometry": []}
    warnings.filterwarnings("ignore", message=".*self.log.*")  # no Trainer here: logging is a no-op
    for index in range(args.warmup + args.rounds):
        order = ("plain", "geometry") if index % 2 == 0 else ("geometry", "plain")
        for name in order:
            seconds = _timed_step(*rows[name], batch, index, device)
            if index >= args.warmup:
                times[name].append(seconds)
    result = {
        "configs": args.configs, "device": str(device), "threads": torch.get_num_threads(),
        "batch_size": int(batch["motion"].shape[0]), "frames": int(batch["motion"].shape[1]),
        "terms": geometric.geometry_weights, "rounds": args.rounds,
    }
    print(f"device {device} ({result['threads']} threads), batch {result['batch_size']} x {result['frames']} frames, "
          f"{args.rounds} paired rounds; terms {geometric.geometry_weights}")
    # process CPU time: what a step costs on a CPU shared with other work (wall time, with one thread
    # and nothing else running); on a GPU the wall time is the one that counts
    for column, clock in (("wall", 0), ("cpu", 1)):
        plain = statistics.median(t[clock] for t in times["plain"]) * 1e3
        geometry = statistics.median(t[clock] for t in times["geometry"]) * 1e3
        extra = statistics.median(g[clock] - b[clock] for g, b in zip(times["geometry"], times["plain"])) * 1e3
        result[column] = {"plain_ms": plain, "geometry_ms": geometry, "extra_ms": extra, "extra_percent": 100.0 * extra / plain}
        print(f"{column:4} step: {plain:9.1f} ms without, {geometry:9.1f} ms with geometry (medians); "
              f"paired difference {extra:+8.1f} ms ({100.0 * extra / plain:+.1f} %)")
    if args.json:
        from stablemo.io import write_text

        write_text(args.json, json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main, "geometry_step_cost"))
