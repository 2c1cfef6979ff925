"""One parallel-CFG forward of the paper UNet (random weights) four ways, side by side in one process:
stock PyTorch eager, StableMo's fast path (stablemo.fast), torch.compile (inductor, freezing=True)
of the stock network, and torch.jit.freeze of a trace of the stock network.

    python scripts/compare_compilers.py [--frames 196] [--rounds 8] [--threads 2]

Each variant is built and warmed up first (compilation is reported, not timed with the forward),
then the variants run in alternating rounds so that drift of the machine's speed hits all of them
alike; the table gives the median milliseconds per forward and the ratio to the fast path, and
each variant's largest difference from the stock output.
"""

from __future__ import annotations

import argparse
import copy
import statistics
import time

import torch

from stablemo.bench import _model_kwargs
from stablemo.fast import accelerate
from stablemo.model import MotionDiffusionModel


def build_inputs(model: MotionDiffusionModel, frames: int, seed: int):
    """(x, t, ctx) of a parallel-CFG step: batch 2 (conditional + unconditional), padded frames."""
    mult = model.length_multiple
    T = -(-frames // mult) * mult
    gen = torch.Generator().manual_seed(seed)
    with torch.inference_mode():
        text, text_mask = model.encode_text(["a person walks forward and waves", ""])
        mask = (torch.arange(T)[None] < frames).expand(2, T)
        ctx = model.prepare(text, text_mask, mask)
    x = torch.randn(2, T, model.denoiser.input_dim, generator=gen)
    t = torch.full((2,), 500, dtype=torch.long)
    return x, t, ctx


class Traceable(torch.nn.Module):
    """forward(x, t) with the request's conditioning held as constants (what tracing needs)."""

    def __init__(self, model: MotionDiffusionModel, ctx):
        super().__init__()
        self.model, self.ctx = model, ctx

    def forward(self, x, t):
        return self.model.denoise(x, t, self.ctx)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--config", default=None, help="model YAML (default: the paper network, as stablemo bench aits)")
    p.add_argument("--frames", type=int, default=196)
    p.add_argument("--rounds", type=int, default=8)
    p.add_argument("--per-round", type=int, default=3)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--skip", nargs="*", default=[], help="variants to leave out: compile, jit")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    kwargs, source = _model_kwargs(args.config)
    torch.manual_seed(args.seed)
    stock = MotionDiffusionModel(**kwargs).eval().requires_grad_(False)
    for param in stock.denoiser.out.parameters():  # the zero-initialised output would hide differences
        torch.nn.init.normal_(param, std=0.02)
    x, t, ctx = build_inputs(stock, args.frames, args.seed)
    print(f"{source}; batch 2 x {x.shape[1]} frames, {args.threads} threads")

    variants = {"stock eager": lambda: stock.denoise(x, t, ctx)}
    fast = accelerate(copy.deepcopy(stock))
    variants["stablemo.fast"] = lambda: fast.denoise(x, t, ctx)
    if "compile" not in args.skip:
        import torch._inductor.config as inductor_config

        inductor_config.freezing = True  # weights folded as constants (inference only)
        compiled = torch.compile(Traceable(stock, ctx), backend="inductor")
        variants["torch.compile (inductor, freezing)"] = lambda: compiled(x, t)
    if "jit" not in args.skip:
        with torch.inference_mode(False), torch.no_grad():
            traced = torch.jit.freeze(torch.jit.trace(Traceable(stock, ctx).eval(), (x, t), check_trace=False))
        variants["torch.jit.freeze (trace)"] = lambda: traced(x, t)

    with torch.no_grad():
        reference = variants["stock eager"]()
        for name, run in variants.items():
            start = time.perf_counter()
            out = run()
            run()  # a second call: packed weights, guard checks, profiling passes settled
            print(f"  warm-up {name}: {time.perf_counter() - start:.1f} s, "
                  f"max |difference| from stock {float((out - reference).abs().max()):.2e}", flush=True)
        times: dict[str, list[float]] = {name: [] for name in variants}
        for r in range(args.rounds):
            order = list(variants) if r % 2 == 0 else list(reversed(variants))
            for name in order:
                for _ in range(args.per_round):
                    start = time.perf_counter()
                    variants[name]()
                    times[name].append(time.perf_counter() - start)
    ours = statistics.median(times["stablemo.fast"])
    print(f"\n{'variant':<36} {'median ms':>10} {'min ms':>8} {'/ fast path':>11}")
    for name, samples in times.items():
        med = statistics.median(samples)
        print(f"{name:<36} {1000 * med:>10.1f} {1000 * min(samples):>8.1f} {med / ours:>11.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
