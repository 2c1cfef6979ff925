"""The compiled CPU kernels (stablemo.fast.kernels): norm + affine + Mish in one pass, im2col of a
'same' convolution, the reading side of linear cross-attention; the same results as PyTorch."""

import copy

import pytest
import torch
from torch import nn

from stablemo.fast import accelerate
from stablemo.fast import kernels as fused
from stablemo.fast.blocks import FastResBlock1D, FusedLinearCrossAttention, norm_mish
from stablemo.fast.gemm import _unfold_frames, _unfold_same
from stablemo.nets.layers import LinearCrossAttention, MaskedGroupNorm, zero_pad_bct
from stablemo.nets.unet import ResBlock1D


@pytest.fixture(scope="module")
def kernels():
    built = fused.kernels()
    if built is None:
        pytest.skip("the fused CPU kernels cannot be built here (no compiler or ninja)")
    return built


def _norm(channels: int, groups: int = 8) -> MaskedGroupNorm:
    torch.manual_seed(0)
    norm = MaskedGroupNorm(groups, channels, "frame")
    nn.init.normal_(norm.weight, 1.0, 0.5)
    nn.init.normal_(norm.bias, 0.0, 0.5)
    return norm


@pytest.mark.parametrize("frames_major", [True, False])
@pytest.mark.parametrize("adagn", [True, False])
@pytest.mark.parametrize("residual", [True, False])
def test_fused_norm_act_matches_pytorch(kernels, frames_major, adagn, residual):
    norm = _norm(256)
    B, C, T = 3, 256, 17
    x = torch.randn(B, T, C).transpose(1, 2) if frames_major else torch.randn(B, C, T)
    x = x * 4 + 1
    x[0, :, 3] = 60.0  # a constant frame: zero variance, output = the affine's bias alone
    x[1, :, 12:] = float("nan")  # padding: its content must not matter
    scale = torch.randn(B, C, 1) if adagn else None
    shift = torch.randn(B, C, 1) if adagn else None
    res = torch.randn(B, T, C).transpose(1, 2) if residual else None
    # a strided mask, as a down-sampled resolution's mask[:, ::2] is: sample 1 has 12 valid frames
    mask = (torch.arange(2 * T)[None] < torch.tensor([[2 * T], [23], [2 * T]]))[:, ::2]
    with torch.inference_mode():
        ref = zero_pad_bct(nn.functional.mish(norm(x, mask, scale, shift)) + (0 if res is None else res), mask)
        out = norm_mish(norm, x, mask, True, scale, shift, res)
    assert out.shape == ref.shape and out.transpose(1, 2).is_contiguous()  # returned frames-major
    assert (out[1, :, 12:] == 0).all() and torch.isfinite(out).all()
    torch.testing.assert_close(out, ref, rtol=1e-5, atol=2e-5)
    # Mish's tails are in range: large positive inputs pass through, large negative ones vanish
    y = kernels.frame_norm_act(torch.tensor([[[-400.0, 0.0, 400.0, 0.0]]]), torch.tensor([[1.0, 1, 1, 1]]) * 100,
                               torch.zeros(1, 4), 1, 1e-5, True)
    assert y[0, 0, 2] == pytest.approx(100 * 400 / (400**2 / 2) ** 0.5, rel=1e-5) and abs(y[0, 0, 0]) < 1e-20


def test_fused_norm_falls_back_under_autograd(kernels):
    norm = _norm(256)
    x = torch.randn(2, 256, 9, requires_grad=True)
    mask = torch.ones(2, 9, dtype=torch.bool)
    ref = nn.functional.mish(norm(x, mask))
    out = norm_mish(norm, x, mask, True)
    assert out.requires_grad  # the PyTorch path: gradients flow to x and the norm's parameters
    out.square().sum().backward()
    assert x.grad is not None and norm.weight.grad is not None
    torch.testing.assert_close(out, ref)


def _block(channels: int) -> ResBlock1D:
    torch.manual_seed(0)
    return ResBlock1D(channels, channels, 16, 5, 8, "frame", 0.0).eval()


def test_accelerate_fuses_only_wide_blocks_and_keeps_the_state_dict(kernels):
    model = nn.ModuleList([_block(256), _block(64)])
    state = {k: v.clone() for k, v in model.state_dict().items()}
    model = accelerate(model)
    assert [type(m) for m in model] == [FastResBlock1D, FastResBlock1D]
    assert [m.fused_ok for m in model] == [True, False]
    assert list(model.state_dict()) == list(state)
    assert all(torch.equal(v, model.state_dict()[k]) for k, v in state.items())


def test_turned_off_by_the_environment(monkeypatch):
    monkeypatch.setenv("STABLEMO_FUSED_KERNELS", "0")
    fused.kernels.cache_clear()
    try:
        assert fused.kernels() is None
        block = _block(256)
        x, emb, mask = torch.randn(2, 256, 9), torch.randn(2, 16), torch.ones(2, 9, dtype=torch.bool)
        fast = accelerate(copy.deepcopy(block))
        with torch.inference_mode():
            ref = block(x, block.adagn(emb), mask)
            torch.testing.assert_close(fast(x, fast.adagn(emb), mask), ref, rtol=1e-5, atol=1e-5)
    finally:
        monkeypatch.undo()
        fused.kernels.cache_clear()


def test_wide_accelerated_unet_matches_stock(kernels):
    nets = pytest.importorskip("stablemo.nets")
    torch.manual_seed(0)
    net = nets.build_denoiser("unet", input_dim=11, text_dim=8, base_channels=256, channel_mults=(1, 2),
                              time_dim=16, num_groups=8, num_heads=2, dropout=0.0).eval()
    for p in net.parameters():
        nn.init.normal_(p, std=0.02)
    fast = accelerate(copy.deepcopy(net))
    blocks = [m for m in fast.modules() if isinstance(m, ResBlock1D)]
    assert len(blocks) == 10 and all(type(m) is FastResBlock1D and m.fused_ok for m in blocks)  # 5 stages x 2
    attns = [m for m in fast.modules() if isinstance(m, LinearCrossAttention)]
    assert len(attns) == 10 and all(type(m) is FusedLinearCrossAttention for m in attns)
    assert fast.fused_ok  # the output head's norm
    x, t = torch.randn(2, 12, 11), torch.tensor([3, 700])
    text, text_mask = torch.randn(2, 5, 8), torch.tensor([[1, 1, 1, 0, 0], [1, 1, 1, 1, 1]], dtype=torch.bool)
    mask = torch.arange(12)[None] < torch.tensor([[7], [12]])
    with torch.inference_mode():
        ref, out = net(x, t, net.prepare(text, text_mask, mask)), fast(x, t, fast.prepare(text, text_mask, mask))
    assert (out[~mask] == 0).all()
    torch.testing.assert_close(out, ref, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("T", [200, 25, 7])
@pytest.mark.parametrize("layout", ["frames", "batch_slice", "channels"])
@pytest.mark.parametrize("k, p", [(5, 2), (3, 1)])
def test_unfold_kernel_gives_the_same_matrix(kernels, T, layout, k, p):
    torch.manual_seed(0)
    C = 256
    base = {"frames": torch.randn(2, T, C), "batch_slice": torch.randn(3, T + 4, C)[1:, 2 : T + 2],
            "channels": torch.randn(2, C, T).transpose(1, 2)}[layout]
    padded = nn.functional.pad(base, (0, 0, p, p))
    expected = padded.as_strided((2, T, k * C), (padded.stride(0), C, 1))
    rows = base if layout != "channels" else base.contiguous()
    assert torch.equal(kernels.unfold_same(rows, k, p), expected)
    with torch.inference_mode():
        assert torch.equal(_unfold_frames(base, k, 1, p, T, fused_ok=True), expected)  # the kernel path
    assert torch.equal(_unfold_same(rows, k, p), expected)
    with pytest.raises(RuntimeError, match="k = 2p"):
        kernels.unfold_same(rows, k + 1, p)
    with pytest.raises(RuntimeError, match="contiguous rows"):
        kernels.unfold_same(torch.randn(2, C, T).transpose(1, 2), k, p)


def _attention(dim: int, heads: int) -> LinearCrossAttention:
    torch.manual_seed(0)
    attn = LinearCrossAttention(dim, 16, heads).eval()
    for param in attn.parameters():
        nn.init.normal_(param, std=0.3)
    return attn


@pytest.mark.parametrize("dim, heads", [(1024, 8), (256, 2), (256, 8), (384, 4)])  # d = 128, 128, 32, 96
@pytest.mark.parametrize("T", [200, 31, 5])
def test_fused_cross_attention_matches_pytorch(kernels, dim, heads, T):
    attn = _attention(dim, heads)
    fast = FusedLinearCrossAttention(copy.deepcopy(attn))
    x = torch.randn(3, T, dim) * 3
    text = torch.randn(3, 6, 16)
    text_mask = torch.tensor([[1, 1, 1, 1, 1, 1], [1, 1, 0, 0, 0, 0], [0, 0, 0, 0, 0, 0]], dtype=torch.bool)
    with torch.inference_mode():
        ref, out = attn(x, attn.context(text, text_mask)), fast(x, fast.context(text, text_mask))
        torch.testing.assert_close(out, ref, rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(out[2], x[2] + attn.out.bias)  # no valid token: no context read
        # the kernel's own softmax keeps large logits finite (max-shifted, as torch.softmax)
        q, context = torch.randn(2, T, dim) * 300, torch.randn(2, heads, dim // heads, dim // heads)
        read = kernels.read_context(q, context)
        assert torch.isfinite(read).all()
        torch.testing.assert_close(read, LinearCrossAttention.read(attn, q, context), rtol=1e-5, atol=1e-4)


def test_fused_cross_attention_falls_back_under_autograd_and_is_only_for_wide_layers(kernels):
    attn = _attention(256, 2)
    model = accelerate(nn.ModuleList([copy.deepcopy(attn), _attention(128, 2)]))
    assert [type(m) for m in model] == [FusedLinearCrossAttention, LinearCrossAttention]
    x = torch.randn(2, 9, 256, requires_grad=True)
    text, text_mask = torch.randn(2, 4, 16), torch.ones(2, 4, dtype=torch.bool)
    out = model[0](x, model[0].context(text, text_mask))
    out.square().sum().backward()  # the PyTorch path: gradients reach the input and the query weights
    assert x.grad is not None and model[0].query.weight.grad is not None
    torch.testing.assert_close(out, attn(x, attn.context(text, text_mask)))
    with pytest.raises(RuntimeError, match="H\\*d = C"):
        kernels.read_context(torch.randn(1, 4, 256), torch.randn(1, 2, 64, 64))


def test_a_stale_build_lock_is_removed_and_a_live_one_kept(tmp_path):
    """A build killed mid-way leaves torch's `lock` file; every later process would wait on it forever."""
    import os
    import time

    lock = tmp_path / "lock"
    lock.touch()
    assert not fused.clear_stale_lock(tmp_path) and lock.exists()  # a build may be running right now
    old = time.time() - fused.STALE_LOCK_SECONDS - 60
    os.utime(lock, (old, old))
    with pytest.warns(UserWarning, match="stale build lock"):
        assert fused.clear_stale_lock(tmp_path)
    assert not lock.exists() and not fused.clear_stale_lock(tmp_path)
