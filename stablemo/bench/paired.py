"""Paired training-step benchmark (`stablemo bench train --paired`).

One process builds the config's denoiser several ways with the same weights and runs their
training steps in rounds, one step of each row per round (the order rotating), so that a machine
shared with other jobs slows every row alike: the numbers to trust are the medians over rounds of
each row's time divided by the reference's *in the same round*, on process CPU time (what the step
costs, whatever else runs) and on wall time (what it takes on this machine now).

A step: forward on (B, T, D) noisy motion with random text features (B, 77, text_dim), the masked
x0 MSE, backward, AdamW. Rows:
- stock:            the config's network in plain PyTorch layers, torch's default AdamW;
- stablemo:         the same weights through stablemo.fast.train, fused AdamW (what `fit` runs);
- stablemo-onednn:  that with the stock (oneDNN) convolutions instead of the GEMM ones;
- stablemo-bf16:    that under torch.autocast(bfloat16) (Lightning's `precision: bf16-mixed`; on
                    CUDA the row is fp16, `16-mixed`, with torch's default AdamW as `fit` then uses);
- official-variant: our network in the published T2MUnet layout (`variant: official`), fast path;
- official-variant-onednn: that with the stock (oneDNN) convolutions;
- official:         the published CondUnet1D itself, loaded from $STABLEMO_OFFICIAL_SRC (its own
                    `models/unet.py`), stock AdamW, its input padded to a multiple of 16 as its
                    T2MUnet does.
Memory: the step's peak, CUDA's max allocated per row, or on the CPU the most tensor memory alive
during one step as the CPU allocator reports it to torch.profiler (weights, gradients, AdamW
moments, activations, temporaries); and, on the CPU, the activations autograd saves for the
backward (unique storages).
"""

from __future__ import annotations

import copy
import json
import os
import statistics
import time
from collections.abc import Callable

import torch
import torch.nn.functional as F

from stablemo.errors import StableMoError

ROWS = ("stock", "stablemo", "stablemo-onednn", "stablemo-bf16", "official-variant", "official-variant-onednn",
        "official")
TEXT_TOKENS = 77


def _denoiser_kwargs(config: str | None) -> dict:
    from stablemo.bench.aits import model_kwargs

    kwargs, _ = model_kwargs(config)
    denoiser = dict(kwargs["denoiser"])
    if denoiser.pop("name") != "unet":
        raise StableMoError(f"--config: --paired compares UNets (CondUNet1D); {config} describes another denoiser")
    denoiser.setdefault("text_dim", kwargs["text"]["latent_dim"])
    return denoiser


def _randomize_zero_layers(net: torch.nn.Module) -> None:
    """Give exactly-zero initialised weights small random values: with a zero output layer most of
    the backward would multiply zeros (the same FLOPs, but no meaningful gradient check)."""
    with torch.no_grad():
        for p in net.parameters():
            if p.dim() > 1 and not p.any():
                p.normal_(0, 0.02)


class Row:
    """A network + optimiser + the step callable; time and memory per step."""

    def __init__(self, name: str, net: torch.nn.Module, step: Callable[[], torch.Tensor], optimizer):
        self.name, self.net, self.step_fn, self.optimizer = name, net, step, optimizer
        self.wall: list[float] = []
        self.cpu: list[float] = []
        self.saved_mb = float("nan")
        self.peak_mb = float("nan")  # CUDA: max allocated; CPU: measure_peak
        self.params = sum(p.numel() for p in net.parameters())

    def step(self, device: torch.device, record: bool = True) -> float:
        if device.type == "cuda":
            torch.cuda.synchronize(device)
            torch.cuda.reset_peak_memory_stats(device)
        w0, c0 = time.perf_counter(), time.process_time()
        loss = self.step_fn()
        loss.backward()
        self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)
        if device.type == "cuda":
            torch.cuda.synchronize(device)
            self.peak_mb = torch.cuda.max_memory_allocated(device) / 2**20
        if record:
            self.wall.append(time.perf_counter() - w0)
            self.cpu.append(time.process_time() - c0)
        return float(loss.detach())

    def measure_saved(self) -> None:
        """MiB of distinct storages autograd keeps for the backward of one step's forward."""
        seen: dict[int, int] = {}

        def pack(t: torch.Tensor):
            if t.device.type != "meta":
                storage = t.untyped_storage()
                seen[storage.data_ptr()] = storage.nbytes()
            return t

        params = {p.untyped_storage().data_ptr() for p in self.net.parameters()}
        with torch.autograd.graph.saved_tensors_hooks(pack, lambda t: t):
            loss = self.step_fn()
        del loss
        self.saved_mb = sum(n for ptr, n in seen.items() if ptr not in params) / 2**20

    def measure_peak(self) -> None:
        """CPU: the most tensor memory alive at any moment of one whole step (forward, backward,
        AdamW, zero_grad), in MiB: what is alive when it starts (weights, AdamW moments) plus the peak of the allocations and frees the CPU allocator
        reports to torch.profiler during the step (every tensor, temporaries included; the inputs,
        made before, ~2 MiB at the paper config, are not counted)."""
        from torch.profiler import ProfilerActivity, profile

        tensors = [*self.net.parameters(), *(p.grad for p in self.net.parameters() if p.grad is not None),
                   *(v for state in self.optimizer.state.values() for v in state.values() if torch.is_tensor(v))]
        alive = {t.untyped_storage().data_ptr(): t.untyped_storage().nbytes() for t in tensors}
        with profile(activities=[ProfilerActivity.CPU], profile_memory=True) as prof:
            self.step(torch.device("cpu"), record=False)
        events, stack = [], list(prof.profiler.kineto_results.experimental_event_tree())
        while stack:
            node = stack.pop()
            stack.extend(node.children)
            fields = node.extra_fields
            if type(fields).__name__ == "_ExtraFields_Allocation" and fields.device.type == "cpu":
                events.append((node.start_time_ns, fields.alloc_size))
        live = peak = 0
        for _, size in sorted(events, key=lambda e: e[0]):
            live += size
            peak = max(peak, live)
        self.peak_mb = (sum(alive.values()) + peak) / 2**20


def _official_row(kwargs: dict, inputs: dict, device: torch.device, optimizer: str) -> Row | None:
    src = os.environ.get("STABLEMO_OFFICIAL_SRC")
    if not src:
        return None
    import types

    from stablemo.official.reference import official_unet_module

    module = official_unet_module(src, types.ModuleType("clip"))  # CondUnet1D needs no CLIP
    net = module.CondUnet1D(input_dim=kwargs["input_dim"], cond_dim=kwargs["text_dim"], dim=kwargs["base_channels"],
                            dim_mults=tuple(kwargs["channel_mults"]), time_dim=kwargs["time_dim"],
                            dropout=kwargs.get("dropout", 0.1)).to(device).train()
    _randomize_zero_layers(net)
    x_t, x0, t, text, mask = inputs["x_t"], inputs["x0"], inputs["t"], inputs["text"], inputs["mask"]
    B, T, _ = x_t.shape
    pad = (16 - T % 16) % 16  # T2MUnet.forward pads to a multiple of 16 and crops the output
    everyone = torch.arange(B, device=device)

    def step() -> torch.Tensor:
        out = net(F.pad(x_t.transpose(1, 2), (0, pad)), t, text, everyone)[:, :, :T].transpose(1, 2)
        return ((out - x0).square().mean(-1) * mask).sum() / mask.sum()

    return Row("official", net, step, _optimizer(net, optimizer, fused=False))  # its trainer's AdamW


def _ours_row(name: str, net: torch.nn.Module, inputs: dict, device: torch.device, fused: bool,
              autocast: torch.dtype | None, optimizer: str = "adamw") -> Row:
    x_t, x0, t, text, text_mask, mask = (inputs[k] for k in ("x_t", "x0", "t", "text", "text_mask", "mask"))
    T = x_t.shape[1]
    multiple = net.length_multiple
    T_pad = -(-T // multiple) * multiple
    x_t_pad = F.pad(x_t, (0, 0, 0, T_pad - T))
    mask_pad = F.pad(mask, (0, T_pad - T))

    def step() -> torch.Tensor:
        # cache_enabled=False as Lightning's MixedPrecision: weights cast where used, every step
        with torch.autocast(device.type, dtype=autocast, enabled=autocast is not None, cache_enabled=False):
            pred = net(x_t_pad, t, net.prepare(text, text_mask, mask_pad))[:, :T]
        # the loss in float32, as DiffusionModule's masked_mse does
        return ((pred.float() - x0).square().mean(-1) * mask).sum() / mask.sum()

    return Row(name, net, step, _optimizer(net, optimizer, fused))


class _NoOptimizer:
    """--optimizer none: forward and backward only (the gradients are dropped)."""

    def __init__(self, params):
        self.params, self.state = list(params), {}

    def step(self) -> None:
        pass

    def zero_grad(self, set_to_none: bool = True) -> None:
        for p in self.params:
            p.grad = None


def _optimizer(net: torch.nn.Module, kind: str, fused: bool):
    if kind == "none":
        return _NoOptimizer(net.parameters())
    return torch.optim.AdamW(net.parameters(), lr=2e-4, weight_decay=0.01, **({"fused": True} if fused else {}))


def build_rows(kwargs: dict, names: list[str], batch: int, frames: int, seed: int, device: torch.device,
               optimizer: str = "adamw") -> list[Row]:
    from stablemo.fast.train import accelerate_training
    from stablemo.nets.unet import CondUNet1D

    g = torch.Generator().manual_seed(seed)
    D = int(kwargs["input_dim"])
    inputs = {
        "x_t": torch.randn(batch, frames, D, generator=g),
        "x0": torch.randn(batch, frames, D, generator=g),
        "t": torch.randint(0, 1000, (batch,), generator=g),
        "text": torch.randn(batch, TEXT_TOKENS, int(kwargs["text_dim"]), generator=g),
        "text_mask": torch.ones(batch, TEXT_TOKENS, dtype=torch.bool),
        "mask": torch.ones(batch, frames, dtype=torch.bool),
    }
    inputs = {k: v.to(device) for k, v in inputs.items()}
    rows: list[Row] = []
    torch.manual_seed(seed)
    base = CondUNet1D(**kwargs).to(device).train()
    _randomize_zero_layers(base)

    def twin() -> torch.nn.Module:
        """Another module tree over the very same Parameter objects (a paper UNet's weights,
        gradients and AdamW moments are ~5 GB: one set serves every row of this network)."""
        return copy.deepcopy(base, memo={id(p): p for p in base.parameters()})

    ours: list[Row] = []
    if "stock" in names:
        ours.append(_ours_row("stock", twin(), inputs, device, fused=False, autocast=None, optimizer=optimizer))
    if "stablemo" in names:
        ours.append(_ours_row("stablemo", accelerate_training(twin()), inputs, device, True, None, optimizer))
    if "stablemo-onednn" in names:  # the training layers but the stock (oneDNN) convolutions
        ours.append(_ours_row("stablemo-onednn", accelerate_training(twin(), gemm_conv=False), inputs, device, True,
                              None, optimizer))
    if "stablemo-bf16" in names:
        low = torch.bfloat16 if device.type == "cpu" else torch.float16
        ours.append(_ours_row(f"stablemo-{'bf16' if low == torch.bfloat16 else 'fp16'}",
                              accelerate_training(twin()), inputs, device, device.type == "cpu", low, optimizer))
    if device.type == "cpu":  # one set of AdamW moments for the shared weights (CUDA: fused wants its own)
        for row in ours[1:]:
            row.optimizer.state = ours[0].optimizer.state
    rows += ours
    variant_names = [n for n in ("official-variant", "official-variant-onednn") if n in names]
    if variant_names and kwargs.get("variant", "stablemo") != "official":
        torch.manual_seed(seed)
        published = CondUNet1D(**{**kwargs, "variant": "official"}).to(device).train()
        _randomize_zero_layers(published)
        variants = [_ours_row(name, accelerate_training(copy.deepcopy(published, memo={id(p): p for p in published.parameters()}),
                                                        gemm_conv=not name.endswith("onednn")),
                              inputs, device, True, None, optimizer) for name in variant_names]
        if device.type == "cpu":  # one set of weights and AdamW moments, as for ours
            for row in variants[1:]:
                row.optimizer.state = variants[0].optimizer.state
        rows += variants
    if "official" in names:
        row = _official_row(kwargs, inputs, device, optimizer)
        if row is not None:
            rows.append(row)
    return rows


def profile_row(row: Row, top: int = 12) -> str:
    """One step of `row` under torch.profiler: forward / backward / optimiser CPU time, the ops
    with the most self CPU time, and the backward by autograd node. -> printable text."""
    from torch.profiler import ProfilerActivity, profile, record_function

    with profile(activities=[ProfilerActivity.CPU]) as prof:
        with record_function("phase: forward"):
            loss = row.step_fn()
        with record_function("phase: backward"):
            loss.backward()
        with record_function("phase: optimizer"):
            row.optimizer.step()
            row.optimizer.zero_grad(set_to_none=True)
    events = prof.key_averages()
    total = sum(e.self_cpu_time_total for e in events) / 1e6
    lines = [f"profile of one step: {row.name} ({total:.2f} CPU-s under the profiler)"]
    for e in events:
        if e.key.startswith("phase: "):
            lines.append(f"  {e.key:44s} {e.cpu_time_total / 1e6:8.2f} s")
    ops = sorted((e for e in events if not e.key.startswith(("phase: ", "autograd::"))),
                 key=lambda e: -e.self_cpu_time_total)[:top]
    lines += [f"  op {e.key:41s} {e.self_cpu_time_total / 1e6:8.2f} s  {100 * e.self_cpu_time_total / 1e6 / total:5.1f} %  x{e.count}"
              for e in ops]
    backward = sorted((e for e in events if e.key.startswith("autograd::engine::evaluate_function: ")),
                      key=lambda e: -e.cpu_time_total)[:top]
    lines += [f"  backward {e.key.split(': ', 1)[1]:35s} {e.cpu_time_total / 1e6:8.2f} s" for e in backward]
    return "\n".join(lines)


def _ratio(rows_by: dict[str, Row], name: str, ref: str, field: str) -> float:
    a, b = getattr(rows_by[name], field), getattr(rows_by[ref], field)
    return statistics.median(x / y for x, y in zip(a, b))


def run_paired(args) -> int:
    names = ROWS if args.rows is None else tuple(r.strip() for r in args.rows.split(",") if r.strip())
    unknown = [r for r in names if r not in ROWS]
    if unknown:
        raise StableMoError(f"--rows: unknown row(s) {', '.join(unknown)}; expected some of {', '.join(ROWS)}")
    if args.rounds < 1 or args.frames < 1:
        raise StableMoError("--rounds and --frames must be >= 1")
    if "official" in names and args.rows is not None and not os.environ.get("STABLEMO_OFFICIAL_SRC"):
        raise StableMoError("--rows official: set STABLEMO_OFFICIAL_SRC to a checkout of the official code")
    batch = args.batch_size or 8
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    kwargs = _denoiser_kwargs(args.config)
    rows = build_rows(kwargs, list(names), batch, args.frames, args.seed, device, args.optimizer)
    if not rows:
        raise StableMoError("--rows: nothing to run")
    for row in rows:  # warm-up (allocator, oneDNN primitives, AdamW state), then the saved bytes
        for _ in range(max(1, args.warmup)):
            row.step(device, record=False)
        if device.type == "cpu":
            row.measure_saved()
            row.measure_peak()
    for r in range(args.rounds):
        for row in rows[r % len(rows):] + rows[: r % len(rows)]:  # rotate: no row always first
            row.step(device)
    by = {row.name: row for row in rows}
    refs = [name for name in ("official", "stock") if name in by]
    result = {"config": args.config or "the paper network (stablemo/assets/paper_network.yaml)", "device": str(device), "threads": torch.get_num_threads(),
              "batch": batch, "frames": args.frames, "rounds": args.rounds, "optimizer": args.optimizer, "rows": {}}
    what = "forward + backward + AdamW" if args.optimizer == "adamw" else "forward + backward (no optimiser)"
    print(f"paired training step: {what} ({result['config']}, batch {batch} x {args.frames} frames, {device}, "
          f"{result['threads']} threads, {args.rounds} rounds)")
    head = f"{'row':24s} {'params':>8s} {'wall s':>8s} {'CPU s':>8s}"
    for ref in refs:
        head += f" {'/' + ref + ' CPU':>14s} {'/' + ref + ' wall':>15s}"
    head += f" {'peak MiB':>9s} {'saved MiB':>10s}"
    print(head)
    for row in rows:
        entry = {"params": row.params, "wall_s": statistics.median(row.wall), "cpu_s": statistics.median(row.cpu)}
        line = f"{row.name:24s} {row.params / 1e6:7.1f}M {entry['wall_s']:8.3f} {entry['cpu_s']:8.3f}"
        for ref in refs:
            entry[f"cpu_ratio_{ref}"] = _ratio(by, row.name, ref, "cpu")
            entry[f"wall_ratio_{ref}"] = _ratio(by, row.name, ref, "wall")
            line += f" {entry[f'cpu_ratio_{ref}']:14.3f} {entry[f'wall_ratio_{ref}']:15.3f}"
        entry["peak_mb"], entry["saved_mb"] = row.peak_mb, row.saved_mb
        entry["peak_kind"] = "cuda max allocated" if device.type == "cuda" else "cpu allocator (torch.profiler)"
        line += f" {row.peak_mb:9.0f} {row.saved_mb:10.0f}"
        print(line)
        result["rows"][row.name] = entry
    print("ratios: median over rounds of the row's step time / the reference's in the same round; peak: "
          + ("CUDA max allocated in a step" if device.type == "cuda" else
             "the most tensor memory alive during a step (weights, gradients, AdamW moments, activations, "
             "temporaries; CPU allocator, torch.profiler)")
          + "; saved: activations autograd keeps for the backward" + (" (CPU only)" if device.type == "cuda" else ""))
    if args.profile:
        for row in rows:
            print(profile_row(row))
    if args.json:
        from stablemo.io import write_text

        write_text(args.json, json.dumps(result, indent=2) + "\n")
    return 0
