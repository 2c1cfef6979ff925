"""`stablemo bench {aits,stream,train,footskate}`: the benchmarks' options; the measuring is stablemo.bench's.

    stablemo bench aits --random-weights          # the paper's Table 5, measured here
    stablemo bench stream                         # per-chunk cost of Pipeline.stream
    stablemo bench train --config configs/demo.yaml
    stablemo bench footskate --contacts gated     # foot-skate cleanup per motion type
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict

import torch

from stablemo.bench.aits import CONFIG_MAX_FRAMES, format_report, run_aits
from stablemo.bench.timeline import format_report as format_stream_report
from stablemo.bench.timeline import run_stream_bench
from stablemo.checks import check_finite, check_positive_int, check_seed
from stablemo.errors import StableMoError
from stablemo.inference.config import PAPER_CFG, PAPER_STEPS
from stablemo.motion.skeleton import MAX_FRAMES
from stablemo.timeline.stream import DEFAULT_CONTEXT_S

BENCHMARKS = {
    "aits": ("main_aits", "inference time per sentence (paper Table 5) and FLOP efficiency"),
    "stream": ("main_stream", "per-chunk cost of Pipeline.stream, teacher and 1-step student"),
    "train": ("main_train", "training throughput"),
    "footskate": ("main_footskate", "foot-skate cleanup: injected sliding and contact F1 per motion type"),
    "official": ("main_official", "StableMo's network against the official StableMoFusion code: equality, AITS"),
}


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    usage = f"usage: stablemo bench {{{','.join(BENCHMARKS)}}} [options]"
    if not argv or argv[0] in ("-h", "--help"):
        print(usage + "\n\n" + "\n".join(f"  {name:<9} {help_}" for name, (_, help_) in BENCHMARKS.items()))
        return 0
    name, rest = argv[0], argv[1:]
    if name not in BENCHMARKS:
        raise StableMoError(f"bench: unknown benchmark {name!r}; {usage}")
    return int(globals()[BENCHMARKS[name][0]](rest) or 0)


def _aits_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="stablemo bench aits", description="AITS: inference time per sentence (the paper's Table 5), measured here.")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--config", help="YAML with the model description (default: the paper network, "
                                      "stablemo/assets/paper_network.yaml, with the packaged text encoder)")
    src.add_argument("--bundle", help="an inference bundle folder")
    p.add_argument("--random-weights", action="store_true", help="with --bundle: do not load its weights")
    p.add_argument("--text-encoder", help="override the config's frozen text encoder (e.g. minilm when CLIP is not available)")
    p.add_argument("--frames", type=int, default=MAX_FRAMES, help=f"motion length (default {MAX_FRAMES})")
    p.add_argument("--repeats", type=int, default=3, help="timed sentences per row (default 3)")
    p.add_argument("--steps", type=int, default=PAPER_STEPS, help=f"steps of the fast sampler (default {PAPER_STEPS})")
    p.add_argument("--cfg", type=float, default=PAPER_CFG, help=f"guidance scale (default {PAPER_CFG})")
    p.add_argument("--ddpm-steps", type=int, default=None,
                   help="run only this many of the 1000 DDPM steps and extrapolate (label shown in the table)")
    p.add_argument("--skip-ddpm", action="store_true", help="leave out the DDPM baseline row")
    p.add_argument("--skip-student", action="store_true", help="leave out the 1-step consistency student row")
    p.add_argument("--skip-controlnet", action="store_true",
                   help="leave out the 1-step student + ControlNet rows (with and without a guidance refinement)")
    p.add_argument("--stock", action="store_true", help="stock PyTorch convolutions (no stablemo.fast)")
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's choice)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", help="also write the results as JSON to this file")
    return p


def main_aits(argv: list[str]) -> int:
    args = _aits_parser().parse_args(argv)
    if not 1 <= args.frames <= CONFIG_MAX_FRAMES:  # the widest range any model here gets (check_frames)
        raise StableMoError(f"--frames: must be in [1, {CONFIG_MAX_FRAMES}], got {args.frames}")
    if args.repeats < 1:
        raise StableMoError(f"--repeats: must be >= 1, got {args.repeats}")
    if args.ddpm_steps is not None and not 1 <= args.ddpm_steps <= 1000:
        raise StableMoError(f"--ddpm-steps: must be in [1, 1000], got {args.ddpm_steps}")
    check_positive_int("--steps", args.steps)
    check_finite("--cfg", args.cfg, low=0.0, high=100.0)
    check_seed("--seed", args.seed)
    if args.threads is not None:
        check_positive_int("--threads", args.threads)
    if args.json:
        from stablemo.io import check_output_file

        check_output_file(args.json, "--json")
    result = run_aits(args)
    print(format_report(result))
    if args.json:
        from stablemo.io import write_text

        data = dict(result, rows=[dict(asdict(r), aits=r.aits, best=r.best, cpu=r.cpu) for r in result["rows"]])
        write_text(args.json, json.dumps(data, indent=2) + "\n")
    return 0


def _stream_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="stablemo bench stream", description="Per-chunk cost of Pipeline.stream, teacher and 1-step student.")
    p.add_argument("--bundle", default=None, help="teacher bundle (default: the packaged demo model)")
    p.add_argument("--student", default=None, help="student bundle (default: see the module docstring)")
    p.add_argument("--chunks", type=int, default=20, help="timed chunks per row (default 20)")
    p.add_argument("--chunk-seconds", type=float, default=2.0)
    p.add_argument("--context-seconds", type=float, default=DEFAULT_CONTEXT_S)
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument("--seed", type=int, default=0)
    return p


def main_stream(argv: list[str]) -> int:
    args = _stream_parser().parse_args(argv)
    check_positive_int("--chunks", args.chunks)
    check_positive_int("--threads", args.threads)
    check_finite("--chunk-seconds", args.chunk_seconds, low=0.0, strict=True)
    check_finite("--context-seconds", args.context_seconds, low=0.0)
    threads = torch.get_num_threads()
    torch.set_num_threads(args.threads)
    try:
        print(format_stream_report(run_stream_bench(args)))
    finally:
        torch.set_num_threads(threads)
    return 0


def main_train(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="stablemo bench train", description="Training throughput of a config (or --paired: the denoiser step of each implementation).")
    parser.add_argument("--config", default=None,
                        help="training YAML (as for `stablemo fit --config`); --paired: default the paper network")
    parser.add_argument("--steps", type=int, default=20, help="timed optimiser steps (default 20)")
    parser.add_argument("--warmup", type=int, default=3, help="untimed steps first, >= 1 (default 3)")
    parser.add_argument("--batch-size", type=int, default=None, help="override data.batch_size")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's)")
    parser.add_argument("--json", default=None, help="also write the result to this JSON file")
    parser.add_argument("--paired", action="store_true",
                        help="time the denoiser step of stock PyTorch, StableMo (fp32, bf16-mixed) and, with "
                             "STABLEMO_OFFICIAL_SRC, the official network, alternating (see --rounds)")
    parser.add_argument("--rounds", type=int, default=5, help="--paired: timed rounds, one step of each row per round")
    parser.add_argument("--frames", type=int, default=196, help="--paired: motion length (padded as the network needs)")
    parser.add_argument("--rows", default=None,
                        help="--paired: comma-separated rows to run (default all available: stock,stablemo,"
                             "stablemo-onednn,stablemo-bf16,official-variant,official-variant-onednn,official)")
    parser.add_argument("--profile", action="store_true",
                        help="--paired: then profile one step of each row (torch.profiler: phases, top ops, backward nodes)")
    parser.add_argument("--optimizer", choices=("adamw", "none"), default="adamw",
                        help="--paired: include the AdamW step (default) or time forward + backward only")
    parser.add_argument("overrides", nargs="*", help="extra LightningCLI overrides, e.g. --model.lr=1e-4 (after --)")
    args = parser.parse_args(argv)
    if args.config is None and not args.paired:
        raise StableMoError("--config: a training YAML is required (or --paired)")
    if args.steps < 1 or args.warmup < 1:
        raise StableMoError("--steps and --warmup must be >= 1")
    if args.threads:
        torch.set_num_threads(args.threads)
    from stablemo.bench.train import run_train_bench

    return run_train_bench(args)


def main_footskate(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="stablemo bench footskate", description="Foot-skate cleanup benchmark: injected sliding per motion type, contact F1 (docs/footskate.md).")
    p.add_argument("--seed", type=int, default=1000, help="first seed (held-out seeds: 1000 and up)")
    p.add_argument("--per-type", type=int, default=6)
    p.add_argument("--contacts", choices=("heuristic", "gated", "vgrf", "gt"), default="heuristic")
    p.add_argument("--no-vgrf", action="store_true", help="no network (no vGRF term, no vGRF F1)")
    p.add_argument("--weights", default=None, help="vGRF weights (default: the shipped V22, or V21 for kit)")
    p.add_argument("--skeleton", choices=("humanml3d", "kit"), default="humanml3d",
                   help="kit: the motions mapped to the KIT-ML skeleton at 12.5 fps (stablemo.bench.footskate.to_kit)")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--json", default=None)
    p.add_argument("--real", default=None, help="also: contact F1 on this real clip (new_joints .npy), labelled "
                                                "by label_real_contacts")
    args = p.parse_args(argv)
    from stablemo.bench.footskate import run_footskate_bench

    run_footskate_bench(args)
    return 0


def main_official(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="stablemo bench official", description="StableMo's UNet against a checkout of the official code: outputs, padding, AITS.")
    p.add_argument("--official-src", required=True, help="a checkout of github.com/Linketic/StableMoFusion")
    p.add_argument("--clip", help="a local CLIP folder (default: a random CLIP text model of width 512)")
    p.add_argument("--size", choices=["paper", "small"], default="paper")
    p.add_argument("--frames", type=int, default=196)
    p.add_argument("--aits", action="store_true", help="also time the official loop and StableMo's pipeline")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", help="also write the results as JSON to this file")
    args = p.parse_args(argv)
    from stablemo.official.compare import run_compare

    run_compare(args)
    return 0
