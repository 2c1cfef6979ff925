"""`stablemo nets summary --config FILE [--length 196]`: parameters and FLOPs per module.

The config is a denoiser YAML (``name`` + keyword arguments, as in ``configs/nets/``) or a
training config holding one under a ``denoiser`` key (e.g. ``model.model.denoiser``). FLOPs are
counted by ``torch.utils.flop_counter.FlopCounterMode`` for one forward pass (one denoising step
without CFG) of a batch of one: matrix products, convolutions and attention kernels, 2 FLOPs per
multiply-add; element-wise operations (norms, activations) are not counted.
"""

from __future__ import annotations

import argparse

import torch

from stablemo.errors import StableMoError, one_line
from stablemo.inference.config import MAX_FRAMES, check_seed
from stablemo.nets import build_denoiser
from stablemo.nets.config import load_denoiser_config


def count_parameters(module: torch.nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


def summarize(model: torch.nn.Module, length: int, text_length: int = 20, batch: int = 1, depth: int = 1,
              seed: int = 0) -> tuple[list[tuple[str, int, int]], int, int]:
    """Rows (module, params, flops), total FLOPs, padded length for one forward at `length` frames."""
    from torch.utils.flop_counter import FlopCounterMode

    if length < 1:
        raise StableMoError(f"--length: must be >= 1, got {length}")
    k = int(model.length_multiple)
    total_len = -(-length // k) * k
    gen = torch.Generator().manual_seed(seed)
    x = torch.randn(batch, total_len, model.input_dim, generator=gen)
    text = torch.randn(batch, text_length, model.text_dim, generator=gen)
    mm = torch.zeros(batch, total_len, dtype=torch.bool)
    mm[:, :length] = True
    tm = torch.ones(batch, text_length, dtype=torch.bool)
    t = torch.full((batch,), 500)
    model.eval()
    with torch.no_grad(), FlopCounterMode(display=False, depth=None) as counter:
        model(x, t, model.prepare(text, tm, mm))  # per-request work counted with the step, as in training
    flops = {name: sum(ops.values()) for name, ops in counter.get_flop_counts().items()}
    root = type(model).__name__

    def module_flops(name: str, module: torch.nn.Module) -> int:
        # containers that are never called (ModuleList) have no entry: add up their children
        key = f"{root}.{name}"
        if key in flops:
            return int(flops[key])
        return sum(module_flops(f"{name}.{child}", sub) for child, sub in module.named_children())

    rows = []
    for name, module in model.named_modules():
        if not name or name.count(".") >= depth:
            continue
        rows.append((name, count_parameters(module), module_flops(name, module)))
    return rows, int(counter.get_total_flops()), total_len


def _human(n: float) -> str:
    for unit in ("", "K", "M", "G", "T"):
        if abs(n) < 1000:
            return f"{n:.2f}{unit}" if unit else f"{int(n)}"
        n /= 1000
    return f"{n:.2f}P"


# Bounds of the command line's sizes: the FLOP count runs a real forward pass, so a size is memory
# (1e8 frames asked for 105 GB); a network's widths stay far below these.
MAX_LENGTH = 10_000  # frames, as `stablemo bench aits` allows a network without a bundle
MAX_TEXT_LENGTH = 1024  # tokens (CLIP takes 77)
MAX_WIDTH = 65_536  # feature / text latent width


def check_options(args) -> None:
    """Every numeric option in range, before anything is read or built."""
    _check_int_range("--length", args.length, 1, MAX_LENGTH)
    _check_int_range("--text-length", args.text_length, 1, MAX_TEXT_LENGTH)
    for flag, value in (("--input-dim", args.input_dim), ("--text-dim", args.text_dim)):
        if value is not None:
            _check_int_range(flag, value, 1, MAX_WIDTH)
    _check_int_range("--depth", args.depth, 1, 64)
    check_seed("--seed", args.seed)


def _check_int_range(flag: str, value: int, low: int, high: int) -> None:
    if not low <= value <= high:
        raise StableMoError(f"{flag}: must be in [{low}, {high}], got {value}")


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="stablemo nets", description="denoiser tools")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("summary", help="parameters and FLOPs per module")
    p.add_argument("--config", required=True, help="denoiser YAML (name + kwargs) or training YAML")
    p.add_argument("--length", type=int, default=MAX_FRAMES, help=f"motion frames (padded up to the length multiple; default {MAX_FRAMES})")
    p.add_argument("--text-length", type=int, default=20, help="text tokens")
    p.add_argument("--input-dim", type=int, default=None, help="feature width if the config has none (263)")
    p.add_argument("--text-dim", type=int, default=None, help="text latent width if the config has none (256)")
    p.add_argument("--depth", type=int, default=1, help="module nesting depth to list")
    p.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    check_options(args)

    config = load_denoiser_config(args.config)
    name = config.pop("name")
    if args.input_dim is not None:
        config["input_dim"] = args.input_dim
    if args.text_dim is not None:
        config["text_dim"] = args.text_dim
    config.setdefault("input_dim", 263)
    config.setdefault("text_dim", 256)
    torch.manual_seed(args.seed)
    try:
        model = build_denoiser(name, **config)
        rows, total_flops, total_len = summarize(model, args.length, args.text_length, depth=args.depth, seed=args.seed)
    except StableMoError as err:
        raise StableMoError(f"{args.config}: {err}") from None
    except (RuntimeError, ValueError, TypeError) as err:
        # the options built a network that cannot run a forward pass (e.g. input_dim: 0 in the file)
        raise StableMoError(f"{args.config}: denoiser {name!r} with {config} fails on a {args.length}-frame input "
                            f"({type(err).__name__}: {one_line(str(err))})") from None

    width = max([len("module")] + [len(r[0]) for r in rows])
    print(f"denoiser {name}: {', '.join(f'{k}={v}' for k, v in config.items())}")
    print(f"{'module':<{width}}  {'params':>14}  {'GFLOPs':>10}")
    for mod, n, f in rows:
        print(f"{mod:<{width}}  {n:>14,}  {f / 1e9:>10.3f}")
    n_total = count_parameters(model)
    print(f"{'total':<{width}}  {n_total:>14,}  {total_flops / 1e9:>10.3f}")
    print(f"parameters: {_human(n_total)}; FLOPs per forward (batch 1, {args.length} frames padded to {total_len}, "
          f"{args.text_length} text tokens): {_human(total_flops)}")
    return 0
