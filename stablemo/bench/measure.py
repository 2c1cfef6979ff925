"""Measurements behind `stablemo bench aits`: the matmul reference, the denoiser's FLOPs per step,
and timed generations, including the paper's baselines (no text cache, serial CFG) as denoiser
factories the bench passes to `Pipeline.generate`.
"""

from __future__ import annotations

import time

import torch

from stablemo.diffusion.hooks import AtSteps, StepState
from stablemo.fast import flops as fast_flops
from stablemo.fast import gemm
from stablemo.inference.pipeline import Request


def matmul_gflops(dtype: torch.dtype = torch.float32, n: int = 2048, repeats: int = 5) -> dict[str, tuple[float, float]]:
    """Best-of-`repeats` throughput of an n x n x n matmul, GFLOP/s per wall second and per CPU second,
    for each GEMM that StableMo's kernels can call: torch.matmul and, for float32 on a CPU with
    oneDNN, oneDNN's packed-weight product (stablemo.fast's default on non-Intel
    CPUs, where it beats MKL's). An efficiency is taken against the fastest of them."""
    n = _affordable_size(dtype, n)
    a = torch.randn(n, n).to(dtype)
    b = torch.randn(n, n).to(dtype)
    products = {"torch.matmul": lambda: a @ b}
    if dtype == torch.float32 and gemm._ONEDNN_PACK:
        packed = torch.ops.mkldnn._reorder_linear_weight(b.t().contiguous(), n)  # (out, in) = b^T
        products["oneDNN packed"] = lambda: torch.ops.mkldnn._linear_pointwise(a, packed, None, "none", [], "")
    flops = 2 * n**3
    result = {}
    with torch.inference_mode():
        for name, product in products.items():
            product()
            wall = cpu = float("inf")
            for _ in range(repeats):
                start, start_cpu = time.perf_counter(), time.process_time()
                product()
                wall = min(wall, time.perf_counter() - start)
                cpu = min(cpu, time.process_time() - start_cpu)
            result[name] = (flops / wall / 1e9, flops / max(cpu, 1e-9) / 1e9)
    return result


def _affordable_size(dtype: torch.dtype, n: int, budget_s: float = 0.5, probe: int = 512) -> int:
    """`n`, halved until one n x n x n product should take at most `budget_s`, for a low precision.
    A precision this CPU has no fast kernel for (bf16 without AVX512-BF16 or AMX runs near 1 GFLOP/s,
    100x below fp32) would otherwise spend minutes on its reference; a CPU with the kernel keeps the
    full size, and float32 always does."""
    if dtype == torch.float32 or n <= probe:
        return n
    x = torch.randn(probe, probe).to(dtype)
    with torch.inference_mode():
        x @ x
        start = time.perf_counter()
        x @ x
        seconds = time.perf_counter() - start
    while n > probe and seconds * (n / probe) ** 3 > budget_s:
        n //= 2
    return n


def _fastest(sample: dict[str, tuple[float, float]]) -> tuple[float, float]:
    """A matmul_gflops sample's reference: the fastest product, per wall second and per CPU second."""
    return max(w for w, _ in sample.values()), max(c for _, c in sample.values())


def denoiser_flops(pipe, frames: int, batch: int) -> float:
    """FLOPs of one network call on `batch` sequences of `frames` frames (padded as generation pads).

    Counted as a sampling step runs them: the per-request work (attention contexts, pooled text)
    is prepared before counting, not counted per step.
    """
    from torch.utils.flop_counter import FlopCounterMode

    mult = pipe.length_multiple
    T = -(-frames // mult) * mult
    text, text_mask = pipe.encode(["a person walks"] * batch)
    x = torch.zeros(batch, T, pipe.mean.shape[0], device=pipe.device)
    t = torch.full((batch,), 500, dtype=torch.long, device=pipe.device)
    mask = (torch.arange(T, device=pipe.device)[None] < frames).expand(batch, T)
    counter = FlopCounterMode(display=False, custom_mapping=fast_flops.counter_formulas())
    with torch.inference_mode():
        kind = pipe.config.get("kind")
        from stablemo.control.controlnet import ControlledModel

        if isinstance(pipe.model, ControlledModel):  # counted following a dense pelvis path (without
            # targets the base runs alone)
            from stablemo.control.hints import hint_input

            model = pipe.model
            targets = torch.zeros(batch, T, model.joints, 3, device=pipe.device)
            hinted = torch.zeros(batch, T, model.joints, dtype=torch.bool, device=pipe.device)
            hinted[:, :frames, 0] = True
            hint = hint_input(targets, hinted, 1.0, path=model.control.path)
            cond = torch.zeros(batch, device=pipe.device) if model.base_kind == "consistency" else None
            ctx = model.prepare(text, text_mask, mask, cond, (), hint=hint)
        elif kind == "consistency":  # a student's condition: its embedded guidance w (B,)
            ctx = pipe.model.prepare(text, text_mask, mask, torch.zeros(batch, device=pipe.device))
        else:
            ctx = pipe.model.prepare(text, text_mask, mask)
        pipe.model.denoise(x, t, ctx)  # warm: packed weights exist before counting
        with fast_flops.fused_read_flops(pipe.model) as unseen, counter:
            pipe.model.denoise(x, t, ctx)
    return float(counter.get_total_flops() + unseen[0])


class _Stop(Exception):
    pass


class _StepCounter(AtSteps):
    """A hook that counts the sampler's steps and stops the loop after `max_steps` (time per step
    is then extrapolated)."""

    def __init__(self, max_steps: int):
        super().__init__(None)
        self.max_steps, self.done = max_steps, 0

    def __call__(self, state: StepState) -> None:
        self.done = state.step + 1
        if self.done >= self.max_steps:
            raise _Stop


def baseline_denoiser(text_cache: bool, parallel_cfg: bool):
    """The paper's baselines as a DenoiserFactory (None: the pipeline's own, both tricks on):
    text_cache=False encodes the prompts and prepares the network's conditioning again at every
    network call, bypassing every cache; parallel_cfg=False runs CFG's halves as two forwards."""
    if text_cache and parallel_cfg:
        return None
    from stablemo.diffusion.guidance import CFGDenoiser

    def factory(pipe, texts, motion_mask, cfg, dtype, timesteps):
        def build():
            text, text_mask = pipe.encode(texts)
            null_text, null_mask = pipe.null_condition(len(texts))
            return CFGDenoiser(pipe.model, text, text_mask, null_text, null_mask, motion_mask, scale=cfg,
                               batched=parallel_cfg, dtype=dtype, timesteps=timesteps)

        if text_cache:
            return build()

        def uncached(x, t):
            pipe.clear_text_caches()
            return build()(x, t)

        return uncached

    return factory


def time_generation(pipe, prompt: str, frames: int, sampler: str, steps: int, cfg: float, text_cache: bool,
                    parallel_cfg: bool, dtype, seed: int, max_steps: int | None = None, control=None,
                    control_guidance: bool = True) -> tuple[float, float, int]:
    """Wall and CPU time of one generate() call, and how many sampler steps it ran (max_steps stops early);
    control: a JointControl for the prompt (control_guidance: with the guidance refinement)."""
    counter = _StepCounter(max_steps) if max_steps is not None and max_steps < steps else None
    request = Request([prompt], [frames], seed=seed, sampler=sampler, steps=steps, cfg=cfg, dtype=dtype,
                      hooks=[counter] if counter else [], control=control, control_guidance=control_guidance)
    pipe.clear_text_caches(keep_null=True)  # every timed sentence encodes its text; the null prompt is the model's
    start, start_cpu = time.perf_counter(), time.process_time()
    try:
        pipe.generate(request, denoiser=baseline_denoiser(text_cache, parallel_cfg))
        done = steps
    except _Stop:
        done = counter.done
    return time.perf_counter() - start, time.process_time() - start_cpu, done
