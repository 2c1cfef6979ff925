"""`stablemo nets summary --config FILE [--length 196]`: parameters and FLOPs per module.

The config is a denoiser YAML (``name`` + keyword arguments, as in ``configs/nets/``) or a
training config holding one under a ``denoiser`` key (e.g. ``model.model.denoiser``). FLOPs are
counted by ``torch.utils.flop_counter.FlopCounterMode`` for one forward pass (one denoising step
without CFG) of a batch of one: matrix products, convolutions and attention kernels, 2 FLOPs per
multiply-add; element-wise operations (norms, activations) are not counted.
"""

from __future__ import annotations

import torch

from stablemo.checks import check_seed
from stablemo.errors import StableMoError


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


def human(n: float) -> str:
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


