"""accelerate(): GEMM convolutions and cached low-precision weights give the stock results."""

import copy

import pytest
import torch
from torch import nn

from stablemo.errors import StableMoError
from stablemo.fast import accelerate
from stablemo.fast import gemm as accel
from stablemo.fast.blocks import FastMish, fast_mish
from stablemo.fast.gemm import CachedCastLinear, GemmConv1d, GemmConvTranspose1d


@pytest.mark.parametrize("k, s, p", [(5, 1, 2), (3, 2, 1), (1, 1, 0), (4, 1, 0), (3, 2, 0), (5, 1, 3), (5, 3, 2), (2, 1, 1), (1, 1, 1)])
@pytest.mark.parametrize("frames_major", [False, True])
def test_gemm_conv1d_matches_conv1d(k, s, p, frames_major):
    torch.manual_seed(0)
    conv = nn.Conv1d(12, 7, k, stride=s, padding=p)
    fast = accelerate(copy.deepcopy(conv))
    assert type(fast) is GemmConv1d
    x = torch.randn(3, 20, 12).transpose(1, 2) if frames_major else torch.randn(3, 12, 19)
    torch.testing.assert_close(fast(x), conv(x), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("k, p", [(5, 2), (3, 1), (7, 3)])
@pytest.mark.parametrize("T", [7, 8, 19])
@pytest.mark.parametrize("layout", ["frames", "channels", "batch_slice"])
def test_same_convolution_unfolds_without_a_padded_copy_to_the_same_matrix(k, p, T, layout):
    from stablemo.fast.gemm import _unfold_frames, _unfold_same

    torch.manual_seed(0)
    base = {"frames": torch.randn(2, T, 6), "channels": torch.randn(2, 6, T).transpose(1, 2),
            "batch_slice": torch.randn(3, T + 4, 6)[1:, 2 : T + 2]}[layout]
    if T < k:
        pytest.skip("short sequences take the padded path")
    padded = nn.functional.pad(base, (0, 0, p, p))
    expected = padded.as_strided((2, T, k * 6), (padded.stride(0), 6, 1))
    assert torch.equal(_unfold_frames(base, k, 1, p, T), expected)
    if layout != "channels":
        assert torch.equal(_unfold_same(base, k, p), expected)


@pytest.mark.parametrize("k, s, p", [(4, 2, 1), (3, 1, 1), (2, 2, 0), (5, 3, 2)])
def test_gemm_conv_transpose1d_matches(k, s, p):
    torch.manual_seed(0)
    conv = nn.ConvTranspose1d(10, 6, k, stride=s, padding=p)
    fast = accelerate(copy.deepcopy(conv))
    assert type(fast) is GemmConvTranspose1d
    x = torch.randn(2, 10, 9)
    torch.testing.assert_close(fast(x), conv(x), rtol=1e-5, atol=1e-5)


@pytest.mark.skipif(not accel._MKL_PACK, reason="MKL's packed GEMM is CPU/MKL only")
def test_mkl_packs_large_weights_when_a_row_count_repeats(monkeypatch):
    """MKL's packing pays for large weights only, and only when a row count repeats (a sampling
    loop): a small layer never packs, and a large one does not pack for a single call at a new
    length (one-step students serving varied lengths would pack at every sentence)."""
    monkeypatch.setenv("STABLEMO_GEMM", "mkl")
    torch.manual_seed(0)
    small, large = nn.Conv1d(64, 64, 5, padding=2), nn.Conv1d(512, 512, 5, padding=2)  # 20 k / 1.3 M weights
    for conv in (small, large):
        fast = accelerate(copy.deepcopy(conv))
        with torch.inference_mode():
            for frames in (40, 48):  # a new row count: plain product first, packed from the second call on
                x = torch.randn(2, conv.in_channels, frames)
                for call in range(3):
                    torch.testing.assert_close(fast(x), conv(x), rtol=1e-4, atol=1e-4)
                    packs = fast.__dict__.get("_mkl_packs", {})
                    if conv is large:
                        key, packed = packs["weight"]
                        assert key[1] == 2 * frames
                        assert (packed is None) == (call == 0)
                    else:
                        assert packs == {}


@pytest.mark.skipif(not accel._ONEDNN_PACK, reason="oneDNN's packed GEMM is CPU/oneDNN only")
def test_onednn_packs_large_weights_once_for_every_row_count(monkeypatch):
    monkeypatch.setenv("STABLEMO_GEMM", "onednn")
    torch.manual_seed(0)
    small, large = nn.Conv1d(64, 64, 5, padding=2), nn.Conv1d(512, 512, 5, padding=2)
    for conv in (small, large):
        fast = accelerate(copy.deepcopy(conv))
        with torch.inference_mode():
            seen = set()
            for frames in (40, 48, 9):  # one pack serves every row count, from the first call
                x = torch.randn(2, conv.in_channels, frames)
                torch.testing.assert_close(fast(x), conv(x), rtol=1e-4, atol=1e-4)
                packs = fast.__dict__.get("_onednn_packs", {})
                if conv is large:
                    seen.add(id(packs["weight"][1]))
                else:
                    assert packs == {}
            assert len(seen) == (1 if conv is large else 0)
            with torch.no_grad():
                fast.weight.mul_(-0.5)  # an in-place update (load_state_dict) re-packs
            x = torch.randn(1, conv.in_channels, 30)
            torch.testing.assert_close(fast(x), nn.functional.conv1d(x, fast.weight, fast.bias, padding=2),
                                       rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("backend", ["onednn", "mkl", "plain"])
def test_every_gemm_backend_gives_the_stock_layers_results(monkeypatch, backend):
    monkeypatch.setenv("STABLEMO_GEMM", backend)
    assert accel.gemm_backend() in (backend, "plain")  # "plain" where the library is missing
    torch.manual_seed(0)
    layers = [nn.Conv1d(300, 700, 5, padding=2), nn.ConvTranspose1d(1100, 1000, 4, stride=2, padding=1),
              nn.Linear(1024, 1100)]
    inputs = [torch.randn(2, 300, 25), torch.randn(2, 1100, 13), torch.randn(3, 17, 1024)]
    for layer, x in zip(layers, inputs):
        fast = accelerate(copy.deepcopy(layer))
        with torch.inference_mode():
            for _ in range(3):  # plain, packing and packed calls
                torch.testing.assert_close(fast(x), layer(x), rtol=1e-4, atol=1e-4)


def test_gemm_backend_rejects_an_unknown_name(monkeypatch):
    monkeypatch.setenv("STABLEMO_GEMM", "blas")
    with pytest.raises(StableMoError, match="STABLEMO_GEMM"):
        accel.gemm_backend()


@pytest.mark.skipif(not (accel._MKL_PACK and accel._ONEDNN_PACK), reason="needs both MKL and oneDNN")
def test_default_gemm_backend_follows_the_cpu_vendor(monkeypatch):
    monkeypatch.delenv("STABLEMO_GEMM", raising=False)
    try:
        for vendor, expected in (("GenuineIntel", "mkl"), ("AuthenticAMD", "onednn"), ("", "onednn")):
            monkeypatch.setattr(accel, "_cpu_vendor", lambda: vendor)
            accel._default_backend.cache_clear()
            assert accel.gemm_backend() == expected
    finally:
        accel._default_backend.cache_clear()


def test_unsupported_configurations_fall_back():
    torch.manual_seed(0)
    for conv in (nn.Conv1d(4, 4, 3, groups=2, padding=1), nn.Conv1d(4, 4, 3, dilation=2, padding="same"),
                 nn.Conv1d(4, 4, 3, padding=1, padding_mode="circular")):
        fast = accelerate(copy.deepcopy(conv))
        x = torch.randn(2, 4, 10)
        torch.testing.assert_close(fast(x), conv(x))


def test_weight_updates_invalidate_the_cache_and_state_dict_is_unchanged():
    conv = nn.Conv1d(4, 5, 3, padding=1)
    keys = list(conv.state_dict())
    fast = accelerate(conv)
    assert list(fast.state_dict()) == keys
    x = torch.randn(1, 4, 8)
    fast(x)
    with torch.no_grad():
        fast.weight.mul_(2)  # in-place update (as load_state_dict does)
    torch.testing.assert_close(fast(x), nn.functional.conv1d(x, fast.weight, fast.bias, padding=1), rtol=1e-5, atol=1e-5)


def test_autocast_uses_one_cached_low_precision_weight():
    torch.manual_seed(0)
    lin = accelerate(nn.Linear(8, 3))
    assert type(lin) is CachedCastLinear
    x = torch.randn(4, 8)
    with torch.inference_mode(), torch.autocast("cpu", dtype=torch.bfloat16):
        y1 = lin(x)
        y2 = lin(x)
    assert y1.dtype == torch.bfloat16 and torch.equal(y1, y2)
    cached = [v for (name, dtype), (_, v) in lin._gemm_cache.items() if name == "weight"]
    assert len(cached) == 1 and cached[0].dtype == torch.bfloat16
    torch.testing.assert_close(y1.float(), nn.functional.linear(x, lin.weight, lin.bias), rtol=2e-2, atol=2e-2)
    assert lin(x).dtype == torch.float32  # outside autocast: the float32 weights


def test_fast_mish_matches_mish_to_float_rounding():
    x = torch.cat([torch.linspace(-110.0, 110.0, 400_001), torch.randn(100_000) * 4,
                   torch.tensor([0.0, -0.0, 1e-30, -1e-30, 3e38, -3e38])])
    ref = nn.functional.mish(x.double())
    out = fast_mish(x)
    assert out.dtype == torch.float32
    normal = ref.abs() > 1e-30  # down to x ~ -62, where e^x is still a normal float32
    rel = (out.double() - ref).abs()[normal] / ref.abs()[normal]
    assert rel.max() < 2e-6  # a few float32 ulps, also deep in the negative tail
    assert (out.double() - ref).abs()[~normal].max() < 1e-30  # beyond: float32 underflow, as the stock kernel
    assert fast_mish(torch.tensor([float("inf")])).item() == float("inf")
    assert torch.isnan(fast_mish(torch.tensor([float("nan")]))).all()
    frames_major = torch.randn(2, 30, 16).transpose(1, 2)  # the layout the UNet hands it
    torch.testing.assert_close(fast_mish(frames_major), nn.functional.mish(frames_major), rtol=2e-6, atol=1e-7)


def test_fast_mish_module_falls_back_under_autograd_and_for_low_precision():
    act = accelerate(nn.Sequential(nn.Mish()))[0]
    assert type(act) is FastMish
    x = torch.randn(64, requires_grad=True)
    act(x).sum().backward()
    grad = x.grad.clone()
    x.grad = None
    nn.functional.mish(x).sum().backward()
    assert torch.equal(grad, x.grad)  # the stock kernel, so training is unchanged
    xb = torch.randn(64).bfloat16()
    with torch.inference_mode():
        assert torch.equal(act(xb), nn.functional.mish(xb))


@pytest.mark.parametrize("input_head, mid_attention, up_attention", [(0, 0, ()), (8, 0, ()), (8, 2, ()), (8, 2, (2, 2))])
@pytest.mark.parametrize("context", ["grad", "inference"])
def test_accelerated_unet_matches_stock_and_stays_padding_invariant(context, input_head, mid_attention, up_attention):
    nets = pytest.importorskip("stablemo.nets")
    torch.manual_seed(0)
    net = nets.build_denoiser("unet", input_dim=11, text_dim=8, base_channels=8, channel_mults=(1, 2, 2),
                              time_dim=16, num_groups=4, num_heads=2, dropout=0.0, input_head=input_head,
                              mid_attention=mid_attention, up_attention=up_attention).eval()
    for p in net.parameters():
        nn.init.normal_(p, std=0.1)
    fast = accelerate(copy.deepcopy(net))
    x, t = torch.randn(2, 24, 11), torch.tensor([3, 700])
    text, text_mask = torch.randn(2, 5, 8), torch.tensor([[1, 1, 1, 0, 0], [1, 1, 1, 1, 1]], dtype=torch.bool)
    mask = torch.arange(24)[None] < torch.tensor([[13], [24]])
    x[0, 13:] = float("nan")  # padding content must not matter (in-place zeroing outside autograd)
    x_before = x.clone()
    with torch.enable_grad() if context == "grad" else torch.inference_mode():
        ref = net(x, t, net.prepare(text, text_mask, mask))
        out = fast(x, t, fast.prepare(text, text_mask, mask))
        # sample 0 alone, padded only to its own length multiple, gives the same valid frames
        alone = fast(x[:1, :16], t[:1], fast.prepare(text[:1], text_mask[:1], mask[:1, :16]))
    assert torch.isfinite(out).all() and (out[~mask] == 0).all()
    torch.testing.assert_close(out, ref, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(alone[0, :13], out[0, :13], rtol=1e-5, atol=1e-5)
    assert torch.equal(x.isnan(), x_before.isnan()) and torch.equal(x.nan_to_num(), x_before.nan_to_num())  # input untouched


def test_training_through_accelerated_layers_gives_the_stock_gradients():
    torch.manual_seed(0)
    stock = nn.Sequential(nn.Conv1d(6, 32, 5, padding=2), nn.ConvTranspose1d(32, 8, 4, stride=2, padding=1))
    head = nn.Linear(8, 3)
    fast_stock, fast_head = accelerate(copy.deepcopy(stock)), accelerate(copy.deepcopy(head))
    x = torch.randn(2, 6, 20)
    with torch.no_grad():  # fills the inference caches first: training must not use them
        fast_head(fast_stock(x).transpose(1, 2))
    head(stock(x).transpose(1, 2)).square().sum().backward()
    fast_head(fast_stock(x).transpose(1, 2)).square().sum().backward()
    for a, b in zip(list(stock.parameters()) + list(head.parameters()),
                    list(fast_stock.parameters()) + list(fast_head.parameters())):
        torch.testing.assert_close(b.grad, a.grad, rtol=1e-4, atol=1e-5)
