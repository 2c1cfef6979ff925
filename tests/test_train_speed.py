"""Training speed-ups (stablemo.fast.train, issue #28): exact against stock PyTorch.

Speed itself is measured by `stablemo bench train --paired` (never timed in tests); here: the
fast layers' gradients equal stock's (<= 1e-5 relative, float32), their analytic backward passes
gradcheck in float64, the model's parameters and state_dict are untouched, padding invariance
holds, and the fast path is really taken (a check that the swap happened).
"""

from __future__ import annotations

import copy
import math
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F
from test_training import TINY_MODEL, _fit, tiny_config, write_random_dataset

from stablemo.errors import StableMoError
from stablemo.fast.train import (
    DropoutFunction,
    GemmConv1dFunction,
    MishFunction,
    NormMishFunction,
    TrainConv1d,
    TrainDropout,
    TrainResBlock1D,
    accelerate_training,
)
from stablemo.nets import build_denoiser
from stablemo.training.checkpoint_io import load_checkpoint_file

D, C = 12, 16
SMALL = {"base_channels": 16, "channel_mults": [1, 2, 2], "time_dim": 32, "num_groups": 2, "num_heads": 2,
         "cross_attention": True, "norm": "frame", "dropout": 0.0}


@pytest.mark.parametrize("k,stride,padding,T", [(5, 1, 2, 13), (3, 2, 1, 16), (1, 1, 0, 9), (4, 2, 1, 10)])
def test_gemm_conv_backward_gradchecks(k, stride, padding, T):
    g = torch.Generator().manual_seed(k * 10 + stride)
    x = torch.randn(2, 5, T, dtype=torch.float64, generator=g, requires_grad=True)
    w = torch.randn(4, 5, k, dtype=torch.float64, generator=g, requires_grad=True)
    b = torch.randn(4, dtype=torch.float64, generator=g, requires_grad=True)
    out = GemmConv1dFunction.apply(x, w, b, stride, padding)
    torch.testing.assert_close(out, F.conv1d(x, w, b, stride=stride, padding=padding))
    assert torch.autograd.gradcheck(lambda x, w, b: GemmConv1dFunction.apply(x, w, b, stride, padding), (x, w, b))


def test_mish_backward_gradchecks_and_matches_stock_in_float32():
    x = (torch.linspace(-30, 30, 301, dtype=torch.float64)).requires_grad_()
    assert torch.autograd.gradcheck(MishFunction.apply, (x,))
    g = torch.Generator().manual_seed(0)
    x32 = (8 * torch.randn(10000, generator=g)).requires_grad_()
    grad = torch.randn(10000, generator=g)
    ours = torch.autograd.grad(MishFunction.apply(x32), x32, grad)[0]
    stock = torch.autograd.grad(F.mish(x32), x32, grad)[0]
    torch.testing.assert_close(MishFunction.apply(x32), F.mish(x32), rtol=1e-6, atol=1e-6)
    assert float((ours - stock).norm() / stock.norm()) < 1e-6


def test_norm_mish_backward_gradchecks_and_matches_stock():
    """NormMishFunction (keeps only its input) against MaskedGroupNorm + AdaGN + mish: the same
    forward as the unfused training layers' (norm, then MishFunction) bit for bit in float32, a
    gradcheck in float64, gradients within 1e-6 of autograd's through the stock ops."""
    from stablemo.fast.train import train_mish, train_norm_mish
    from stablemo.nets.layers import MaskedGroupNorm

    g = torch.Generator().manual_seed(0)
    norm = MaskedGroupNorm(2, 6, "frame")
    with torch.no_grad():
        norm.weight.normal_(1, 0.3, generator=g)
        norm.bias.normal_(0, 0.3, generator=g)
    x = torch.randn(3, 6, 7, generator=g, requires_grad=True)
    scale = torch.randn(3, 6, 1, generator=g, requires_grad=True)
    shift = torch.randn(3, 6, 1, generator=g, requires_grad=True)
    mask = torch.ones(3, 7, dtype=torch.bool)
    grad = torch.randn(3, 6, 7, generator=g)
    ours = train_norm_mish(norm, x, mask, scale, shift)
    stock = F.mish(norm(x, mask, scale, shift))
    assert torch.equal(ours, train_mish(norm(x, mask, scale, shift)))
    torch.testing.assert_close(ours, stock, rtol=1e-6, atol=1e-6)
    inputs = (x, norm.weight, norm.bias, scale, shift)
    a = torch.autograd.grad(ours, inputs, grad)
    b = torch.autograd.grad(stock, inputs, grad)
    for u, v in zip(a, b):
        assert float((u - v).norm() / v.norm()) < 1e-6
    w64, b64 = (torch.randn(3, 1, 6, dtype=torch.float64, generator=g, requires_grad=True) for _ in range(2))
    x64 = torch.randn(3, 6, 7, dtype=torch.float64, generator=g, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x, w, b: NormMishFunction.apply(x, w, b, 2, 1e-5), (x64, w64, b64))


def test_dropout_draws_as_stock_and_keeps_a_bool_mask():
    x = torch.randn(4, 8, 50, requires_grad=True)
    grad = torch.randn(4, 8, 50)
    torch.manual_seed(3)
    stock = F.dropout(x, 0.1, training=True)
    (g_stock,) = torch.autograd.grad(stock, x, grad)
    torch.manual_seed(3)
    saved = []
    with torch.autograd.graph.saved_tensors_hooks(lambda t: saved.append(t) or t, lambda t: t):
        ours = TrainDropout(0.1).train()(x)
    assert torch.equal(ours, stock)  # the same draw from the same generator
    assert [t.dtype for t in saved] == [torch.bool]
    (g_ours,) = torch.autograd.grad(ours, x, grad)
    assert torch.equal(g_ours, g_stock)
    torch.manual_seed(0)
    x64 = torch.randn(30, dtype=torch.float64, requires_grad=True)
    out = DropoutFunction.apply(x64, 0.5)
    (g,) = torch.autograd.grad(out, x64, torch.ones_like(out))
    assert torch.equal(g, out / x64)  # d out / d x = the kept entries' 1 / (1 - p), 0 elsewhere


def _unet(variant: str = "stablemo", seed: int = 0, **overrides) -> torch.nn.Module:
    torch.manual_seed(seed)
    net = build_denoiser("unet", input_dim=D, text_dim=C, variant=variant, **{**SMALL, **overrides})
    with torch.no_grad():  # zero-initialised layers randomised, else the output (and most gradients) are 0
        for p in net.parameters():
            if not p.any():
                p.normal_(0, 0.2)
    return net


def _batch(lengths, total, seed=0):
    g = torch.Generator().manual_seed(seed)
    B = len(lengths)
    x = torch.randn(B, total, D, generator=g)
    mask = torch.arange(total)[None] < torch.tensor(lengths)[:, None]
    text = torch.randn(B, 5, C, generator=g)
    text_mask = torch.arange(5)[None] < torch.tensor([5, 3, 4, 2][:B])[:, None]
    t = torch.randint(0, 1000, (B,), generator=g)
    target = torch.randn(B, total, D, generator=g)
    return x, t, text, text_mask, mask, target


def _grads(net, batch):
    x, t, text, text_mask, mask, target = batch
    net.zero_grad(set_to_none=True)
    pred = net(x, t, net.prepare(text, text_mask, mask))
    loss = ((pred - target).square().mean(-1) * mask).sum() / mask.sum()
    loss.backward()
    return loss.detach(), {n: p.grad.clone() for n, p in net.named_parameters()}


@pytest.mark.parametrize("variant", ["stablemo", "official"])
@pytest.mark.parametrize("lengths", [[16, 16, 16], [16, 9, 4]], ids=["no_padding", "padding"])
@pytest.mark.parametrize("dropout", [0.0, 0.1], ids=["no_dropout", "dropout"])
def test_training_gradients_equal_stock(variant, lengths, dropout):
    stock = _unet(variant, dropout=dropout)
    fast = accelerate_training(copy.deepcopy(stock))
    # the swap happened (else this test would compare stock with stock)
    assert any(isinstance(m, TrainConv1d) for m in fast.modules())
    assert any(isinstance(m, TrainResBlock1D) for m in fast.modules())
    assert any(isinstance(m, TrainDropout) for m in fast.modules())
    assert fast.state_dict().keys() == stock.state_dict().keys()
    batch = _batch(lengths, 16)
    torch.manual_seed(7)  # the dropout layers draw the same masks from the same generator state
    loss_s, grads_s = _grads(stock, batch)
    torch.manual_seed(7)
    loss_f, grads_f = _grads(fast, batch)
    torch.testing.assert_close(loss_f, loss_s, rtol=1e-6, atol=0)
    # every parameter's gradient within 1e-5 relative of stock's; the attention key biases are
    # excluded from the per-parameter check: their exact gradient is 0 (the keys' softmax over
    # tokens ignores a per-feature shift), so both sides hold only rounding noise (~1e-10 here)
    total = torch.cat([g.flatten() for g in grads_s.values()]).norm()
    diff = torch.cat([(grads_f[n] - g).flatten() for n, g in grads_s.items()]).norm()
    assert float(diff / total) <= 1e-5
    checked = {n: g for n, g in grads_s.items() if not n.endswith("key.bias")}
    assert len(checked) > 0.9 * len(grads_s)
    worst = max(float((grads_f[n] - g).norm() / g.norm().clamp(min=1e-30)) for n, g in checked.items() if g.any())
    assert worst <= 1e-5, worst
    for n, g in checked.items():
        if not g.any():  # exactly-zero gradients stay exactly zero
            assert not grads_f[n].any(), n


def test_training_layers_with_stock_convolutions_equal_stock():
    """accelerate_training(gemm_conv=False): the oneDNN convolutions, the other training layers."""
    stock = _unet(dropout=0.1)
    fast = accelerate_training(copy.deepcopy(stock), gemm_conv=False)
    convs = [m for m in fast.modules() if isinstance(m, TrainConv1d)]
    assert convs and not any(m.gemm for m in convs)  # swapped for their autocast path only
    assert any(isinstance(m, TrainResBlock1D) for m in fast.modules())
    batch = _batch([16, 9, 4], 16)
    torch.manual_seed(7)
    loss_s, grads_s = _grads(stock, batch)
    torch.manual_seed(7)
    loss_f, grads_f = _grads(fast, batch)
    torch.testing.assert_close(loss_f, loss_s, rtol=1e-6, atol=0)
    total = torch.cat([g.flatten() for g in grads_s.values()]).norm()
    assert float(torch.cat([(grads_f[n] - g).flatten() for n, g in grads_s.items()]).norm() / total) <= 1e-5


@pytest.mark.parametrize("variant", ["stablemo", "official"])
def test_bf16_autocast_equals_stock_autocast_without_keeping_weight_copies(variant):
    """Under CPU autocast (bf16-mixed) the training layers give stock autocast's loss and gradients
    bit for bit, and the backward keeps no bf16 copy of a convolution or linear weight (the float32
    weight is cast again there): the copies stock autocast keeps are what the step's peak lacks."""
    stock = _unet(variant, dropout=0.0)
    fast = accelerate_training(copy.deepcopy(stock))
    batch = _batch([16, 9, 4], 16)
    weight_shapes = {tuple(p.shape) for n, p in stock.named_parameters() if n.endswith("weight") and p.dim() >= 2}

    def run(net):
        kept = []

        def pack(t):
            if t.dtype == torch.bfloat16 and tuple(t.shape) in weight_shapes:
                kept.append(tuple(t.shape))
            return t

        with torch.autograd.graph.saved_tensors_hooks(pack, lambda t: t):
            with torch.autocast("cpu", dtype=torch.bfloat16):
                x, t, text, text_mask, mask, target = batch
                pred = net(x, t, net.prepare(text, text_mask, mask))
            loss = ((pred.float() - target).square().mean(-1) * mask).sum() / mask.sum()
        net.zero_grad(set_to_none=True)
        loss.backward()
        return loss.detach(), {n: p.grad for n, p in net.named_parameters()}, kept

    loss_s, grads_s, kept_s = run(stock)
    loss_f, grads_f, kept_f = run(fast)
    assert torch.equal(loss_f, loss_s)
    for n, g in grads_s.items():
        assert torch.equal(grads_f[n], g), n
        assert grads_f[n].dtype == torch.float32
    assert len(kept_s) > 10 and kept_f == []


def test_padding_still_gets_no_gradient_and_changes_nothing():
    """Exact padding invariance with the training layers: the valid frames' loss and the weights'
    gradients do not depend on how much padding the batch carries or what it holds."""
    fast = accelerate_training(_unet())
    x, t, text, text_mask, mask, target = _batch([16, 9, 4], 16)
    loss_a, grads_a = _grads(fast, (x, t, text, text_mask, mask, target))
    pad = 8  # a longer batch, padding filled with large values

    def big(a):
        return torch.cat([a, 1e4 * torch.ones(a.shape[0], pad, a.shape[2])], dim=1)

    mask_b = torch.cat([mask, torch.zeros(3, pad, dtype=torch.bool)], dim=1)
    xb = big(x).requires_grad_()
    fast.zero_grad(set_to_none=True)
    pred = fast(xb, t, fast.prepare(text, text_mask, mask_b))
    loss_b = ((pred - big(target)).square().mean(-1) * mask_b).sum() / mask_b.sum()
    loss_b.backward()
    torch.testing.assert_close(loss_b.detach(), loss_a, rtol=1e-6, atol=0)
    assert not xb.grad[:, 16:].any()
    for n, p in fast.named_parameters():
        torch.testing.assert_close(p.grad, grads_a[n], rtol=1e-5, atol=1e-7)


def test_inference_is_the_stock_computation():
    stock = _unet().eval()
    fast = accelerate_training(copy.deepcopy(stock)).eval()
    x, t, text, text_mask, mask, _ = _batch([16, 9, 4], 16)
    with torch.no_grad():
        a = stock(x, t, stock.prepare(text, text_mask, mask))
        b = fast(x, t, fast.prepare(text, text_mask, mask))
    assert torch.equal(a, b)


# ----------------------------------------------------------------------------- the Lightning module

@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory) -> Path:
    return write_random_dataset(tmp_path_factory.mktemp("data") / "tiny")


def _read_losses(run: Path) -> list[float]:
    import csv

    (metrics,) = run.glob("logs/version_*/metrics.csv")
    with metrics.open() as f:
        return [float(r["train/loss"]) for r in csv.DictReader(f) if r.get("train/loss")]


def test_module_trains_through_the_fast_layers_with_the_stock_losses(tiny_data, tmp_path):
    """fit with fast_training (the default) and without: the same losses step by step (the fp32
    fast path changes rounding only), the fast layers and the fused AdamW really in use."""
    from stablemo.training.module import DiffusionModule

    module = DiffusionModule(model=TINY_MODEL)
    assert any(isinstance(m, TrainConv1d) for m in module.model.modules())
    assert not any(isinstance(m, TrainConv1d) for m in DiffusionModule(model=TINY_MODEL, fast_training=False).model.modules())
    onednn = DiffusionModule(model=TINY_MODEL, gemm_conv=False).model
    assert not any(m.gemm for m in onednn.modules() if isinstance(m, TrainConv1d))
    assert any(isinstance(m, TrainResBlock1D) for m in onednn.modules())
    fast_run, stock_run = tmp_path / "fast", tmp_path / "stock"
    _fit(tiny_config(fast_run, tiny_data))
    _fit(tiny_config(stock_run, tiny_data), "--model.fast_training=false")
    fast, stock = _read_losses(fast_run), _read_losses(stock_run)
    assert len(fast) == len(stock) == 6
    torch.testing.assert_close(torch.tensor(fast), torch.tensor(stock), rtol=1e-4, atol=0)
    ckpt = load_checkpoint_file(fast_run / "checkpoints" / "last.ckpt")
    assert ckpt["optimizer_states"][0]["param_groups"][0]["fused"] is True
    assert ckpt["state_dict"].keys() == load_checkpoint_file(stock_run / "checkpoints" / "last.ckpt")["state_dict"].keys()


def test_bf16_mixed_trains_with_float32_weights_and_ema(tiny_data, tmp_path):
    """Lightning's precision=bf16-mixed with our module: finite losses near the fp32 run's, weights,
    gradients' optimiser state and EMA kept in float32 (autocast casts per op)."""
    _fit(tiny_config(tmp_path / "bf16", tiny_data), "--trainer.precision=bf16-mixed")
    _fit(tiny_config(tmp_path / "fp32", tiny_data))
    bf16, fp32 = _read_losses(tmp_path / "bf16"), _read_losses(tmp_path / "fp32")
    assert len(bf16) == 6 and all(math.isfinite(v) for v in bf16)
    torch.testing.assert_close(torch.tensor(bf16), torch.tensor(fp32), rtol=0.05, atol=0)
    ckpt = load_checkpoint_file(tmp_path / "bf16" / "checkpoints" / "last.ckpt")
    assert all(v.dtype == torch.float32 for v in ckpt["state_dict"].values() if v.is_floating_point())
    assert all(v.dtype == torch.float32 for v in ckpt["stablemo"]["ema"]["shadow"].values())
    assert all(s["exp_avg"].dtype == torch.float32 for s in ckpt["optimizer_states"][0]["state"].values())
    assert ckpt["optimizer_states"][0]["param_groups"][0]["fused"] is True  # clipped by Lightning all the same


# ----------------------------------------------------------------------------- the paired benchmark

def test_paired_bench_rows_ratios_and_memory(tmp_path, capsys):
    import json

    from stablemo.cli.bench import main_train as bench_main

    config = tmp_path / "net.yaml"
    config.write_text("model:\n  model:\n    denoiser: {name: unet, input_dim: 12, base_channels: 16, channel_mults: [1, 2],"
                      " time_dim: 32, num_groups: 4, num_heads: 2}\n    text: {latent_dim: 16}\n")
    out = tmp_path / "paired.json"
    assert bench_main(["--paired", "--config", str(config), "--rows", "stock,stablemo,stablemo-bf16,official-variant",
                       "--batch-size", "2", "--frames", "20", "--rounds", "2", "--warmup", "1", "--profile",
                       "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    rows = result["rows"]
    assert set(rows) == {"stock", "stablemo", "stablemo-bf16", "official-variant"}
    assert rows["stock"]["cpu_ratio_stock"] == 1.0 and rows["stablemo"]["cpu_ratio_stock"] > 0
    assert rows["stablemo"]["params"] == rows["stock"]["params"] != rows["official-variant"]["params"]
    # the peak holds at least the weights, gradients and AdamW moments (16 bytes a parameter)
    assert all(r["peak_mb"] * 2**20 > 16 * r["params"] and r["saved_mb"] > 0 for r in rows.values())
    # the training layers keep fewer activations than stock (bool dropout masks, norm + Mish
    # recomputed), and so peak lower with the same weights
    assert rows["stablemo"]["saved_mb"] < rows["stock"]["saved_mb"]
    assert rows["stablemo"]["peak_mb"] < rows["stock"]["peak_mb"]
    printed = capsys.readouterr().out
    assert "/stock CPU" in printed
    assert "profile of one step: stablemo" in printed and "backward GemmConv1dFunctionBackward" in printed
    with pytest.raises(StableMoError, match="--rows: unknown row"):
        bench_main(["--paired", "--config", str(config), "--rows", "stock,fastest"])
