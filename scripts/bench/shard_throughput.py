"""Shards: writing speed (paired against another commit), training from shards against the
memory-mapped folder reader (a paired, interleaved A/B), and RSS.

    .venv/bin/python scripts/bench/shard_throughput.py link SRC --copies 10 --out BIG
    .venv/bin/python scripts/bench/shard_throughput.py write SRC [SRC ...] [--against REV] [--rounds 3] [--workers 2]
    .venv/bin/python scripts/bench/shard_throughput.py ab --data DIR --shards SHARDS \
        [--config configs/synth_small.yaml] [--rounds 6] [--steps 30] [--warmup 5]
    .venv/bin/python scripts/bench/shard_throughput.py rss --shards SHARDS [--batch-size 32] [--every 200]

`link`: a dataset folder `--copies` times as large as SRC, of hard links (clip `<id>` becomes
`<id>_0`, `<id>_1`, ...; statistics copied): a large single-source corpus in no time and no disk
space (`stablemo data synth` makes ~100 clips/s here). Its clips are read from the page cache once
the first copy has been read, so `write` measures the CPU side of sharding, not a cold disk.

`write`: `stablemo.data.shards.write_shards` of SRC into a fresh folder, in a child process per
run (imports done before the clock starts), timed by wall clock and by CPU time (the child and its
worker processes). With `--against REV`, the same run from REV's `stablemo` and `footskate`
(`git archive`d into a temporary folder; with `--only FILE ...`, this checkout with just those files
as REV has them), alternating which goes first each round (this VM's speed
drifts; a pair run back to back sees the same machine); each pair's outputs are compared byte for byte.

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
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

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


def run_link(args) -> None:
    from stablemo.io import atomic_dir, write_bytes, write_text

    src, out = Path(args.src), Path(args.out)
    if out.exists():
        raise SystemExit(f"--out: {out}: exists; give a new folder")
    with atomic_dir(out) as tmp:  # the corpus appears whole or not at all
        for sub in ("new_joint_vecs", "texts"):
            (tmp / sub).mkdir(parents=True)
        for name in ("Mean.npy", "Std.npy"):
            write_bytes(tmp / name, (src / name).read_bytes())
        for split in ("train", "val", "test"):
            if not (src / f"{split}.txt").is_file():
                continue
            ids = (src / f"{split}.txt").read_text().split()
            copies = [f"{i}_{k}" for k in range(args.copies) for i in ids]  # copy after copy: split order kept
            for clip_id, new in zip(ids * args.copies, copies):
                # hard links: a 200 000-clip corpus costs no disk beyond its source
                os.link(src / "new_joint_vecs" / f"{clip_id}.npy", tmp / "new_joint_vecs" / f"{new}.npy")
                os.link(src / "texts" / f"{clip_id}.txt", tmp / "texts" / f"{new}.txt")
            write_text(tmp / f"{split}.txt", "\n".join(copies) + "\n")
    print(f"{out}: {args.copies} copies of {src}")


# run in a child process: imports first, then the clock; CPU time counts the worker processes
_WRITE_ONE = """
import json, resource, sys, time
import numpy, torch, tqdm, webdataset, zstandard
from stablemo.data.shards import write_shards
def cpu():
    return sum(r.ru_utime + r.ru_stime for r in (resource.getrusage(resource.RUSAGE_SELF),
                                                 resource.getrusage(resource.RUSAGE_CHILDREN)))
sources, out, workers = json.loads(sys.argv[1])
c0, t0 = cpu(), time.perf_counter()
manifest, _ = write_shards(sources, out, workers=workers, progress=False)
took, used = time.perf_counter() - t0, cpu() - c0
clips = sum(split["clips"] for split in manifest["splits"].values())
print(json.dumps({"clips": clips, "seconds": took, "cpu": used}))
"""


def write_once(tree: str, sources: list[str], out: str, workers: int) -> dict:
    env = {**os.environ, "PYTHONPATH": tree}  # before the editable install's finder: this tree's code
    done = subprocess.run([sys.executable, "-c", _WRITE_ONE, json.dumps([sources, out, workers])], cwd=tree,
                          env=env, capture_output=True, text=True, check=False)
    if done.returncode:
        raise SystemExit(f"write_shards from {tree} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def same_files(a: Path, b: Path) -> bool:
    names = sorted(p.name for p in a.iterdir())
    return names == sorted(p.name for p in b.iterdir()) and all(
        (a / n).read_bytes() == (b / n).read_bytes() for n in names)


def run_write(args) -> None:
    repo = Path(__file__).resolve().parents[2]
    with tempfile.TemporaryDirectory(prefix="shard_write_") as scratch:
        _run_write(args, repo, Path(scratch))


def _run_write(args, repo: Path, work: Path) -> None:
    from stablemo.io import write_bytes

    trees = {"this tree": str(repo)}
    if args.against:
        base = work / "against"
        if args.only:  # this checkout with only these files as REV has them
            for package in ("stablemo", "footskate"):
                shutil.copytree(repo / package, base / package, ignore=shutil.ignore_patterns("__pycache__"))
            for path in args.only:
                old = subprocess.run(["git", "-C", str(repo), "show", f"{args.against}:{path}"],
                                     capture_output=True, check=True).stdout
                write_bytes(base / path, old)
        else:
            base.mkdir()
            archive = subprocess.run(["git", "-C", str(repo), "archive", args.against, "stablemo", "footskate"],
                                     capture_output=True, check=True).stdout
            subprocess.run(["tar", "-x", "-C", str(base)], input=archive, check=True)
        trees = {args.against: str(base), **trees}
    names = list(trees)
    rates: dict[str, list[float]] = {n: [] for n in names}
    cpus: dict[str, list[float]] = {n: [] for n in names}
    for r in range(args.rounds):
        outs = {}
        for name in (names if r % 2 == 0 else names[::-1]):
            outs[name] = work / f"out_{len(outs)}"
            got = write_once(trees[name], args.src, str(outs[name]), args.workers)
            rates[name].append(got["clips"] / got["seconds"])
            cpus[name].append(got["cpu"] / got["clips"] * 1e3)
            print(f"round {r} {name}: {got['clips']} clips in {got['seconds']:.2f} s = {rates[name][-1]:.0f} "
                  f"clips/s, {cpus[name][-1]:.3f} CPU-ms per clip", flush=True)
        if len(outs) == 2:
            print(f"round {r}: outputs byte-identical: {same_files(*outs.values())}", flush=True)
        for out in outs.values():
            shutil.rmtree(out)
    for name in names:
        print(f"{name}: median {statistics.median(rates[name]):.0f} clips/s "
              f"({min(rates[name]):.0f}-{max(rates[name]):.0f}), median {statistics.median(cpus[name]):.3f} "
              f"CPU-ms per clip, --workers {args.workers}, load average {os.getloadavg()[0]:.1f} at the end")
    if len(names) == 2:
        ratios = [b / a for a, b in zip(rates[names[0]], rates[names[1]])]
        print(f"speed-up (this tree / {names[0]}): median of pairs {statistics.median(ratios):.2f} "
              f"(min {min(ratios):.2f}, max {max(ratios):.2f})")


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
    link = sub.add_parser("link")
    link.add_argument("src")
    link.add_argument("--copies", type=int, required=True)
    link.add_argument("--out", required=True)
    write = sub.add_parser("write")
    write.add_argument("src", nargs="+")
    write.add_argument("--against", help="a git revision to compare with, e.g. HEAD~3")
    write.add_argument("--only", nargs="+", help="with --against: only these files from that revision, the "
                       "rest from this checkout (other changes since then, e.g. to the body's kinematics, left out)")
    write.add_argument("--rounds", type=int, default=3)
    write.add_argument("--workers", type=int, default=2)
    rss = sub.add_parser("rss")
    rss.add_argument("--shards", required=True)
    rss.add_argument("--batch-size", type=int, default=32)
    rss.add_argument("--every", type=int, default=200)
    args = parser.parse_args()
    torch.set_num_threads(1)  # the tests' and the paired benches' setting: a shared 2-core VM
    {"link": run_link, "write": run_write, "ab": run_ab, "rss": run_rss}[args.command](args)


if __name__ == "__main__":
    main()
