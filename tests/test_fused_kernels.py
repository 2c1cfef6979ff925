"""The fused CPU kernel (stablemo.diffusion.fused): norm + affine + Mish in one pass, same results."""

import copy

import pytest
import torch
from torch import nn

from stablemo.diffusion import fused
from stablemo.diffusion.accelerate import FastMish, FusedFrameNorm, accelerate
from stablemo.nets.layers import MaskedGroupNorm


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
    fast = copy.deepcopy(norm)
    fast.__class__ = FusedFrameNorm
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
        ref = norm.forward_act(x, mask, nn.Mish(), scale, shift, res)
        out = fast.forward_act(x, mask, FastMish(), scale, shift, res)
    assert out.shape == ref.shape and out.transpose(1, 2).is_contiguous()  # returned frames-major
    assert (out[1, :, 12:] == 0).all() and torch.isfinite(out).all()
    torch.testing.assert_close(out, ref, rtol=1e-5, atol=2e-5)
    # Mish's tails are in range: large positive inputs pass through, large negative ones vanish
    y = kernels.frame_norm_act(torch.tensor([[[-400.0, 0.0, 400.0, 0.0]]]), torch.tensor([[1.0, 1, 1, 1]]) * 100,
                               torch.zeros(1, 4), 1, 1e-5, True)
    assert y[0, 0, 2] == pytest.approx(100 * 400 / (400**2 / 2) ** 0.5, rel=1e-5) and abs(y[0, 0, 0]) < 1e-20


def test_fused_norm_falls_back_under_autograd_and_for_other_activations(kernels):
    norm = _norm(256)
    fast = copy.deepcopy(norm)
    fast.__class__ = FusedFrameNorm
    x = torch.randn(2, 256, 9, requires_grad=True)
    mask = torch.ones(2, 9, dtype=torch.bool)
    ref = norm.forward_act(x, mask, nn.Mish())
    out = fast.forward_act(x, mask, nn.Mish())
    assert out.requires_grad  # the PyTorch path: gradients flow to x and the norm's parameters
    out.square().sum().backward()
    assert x.grad is not None and fast.weight.grad is not None
    torch.testing.assert_close(out, ref)
    with torch.inference_mode():  # an activation the kernel does not implement
        torch.testing.assert_close(fast.forward_act(x.detach(), mask, nn.GELU()), nn.GELU()(norm(x.detach(), mask)))


def test_accelerate_fuses_only_wide_frame_norms(kernels):
    wide, narrow, grouped = _norm(256), _norm(64), MaskedGroupNorm(8, 256, "group")
    model = nn.ModuleList([wide, narrow, grouped])
    state = {k: v.clone() for k, v in model.state_dict().items()}
    accelerate(model)
    assert [type(m) for m in model] == [FusedFrameNorm, MaskedGroupNorm, MaskedGroupNorm]
    assert all(torch.equal(v, model.state_dict()[k]) for k, v in state.items())


def test_turned_off_by_the_environment(monkeypatch):
    monkeypatch.setenv("STABLEMO_FUSED_KERNELS", "0")
    fused.kernels.cache_clear()
    try:
        assert fused.kernels() is None
        assert type(accelerate(nn.ModuleList([_norm(256)]))[0]) is MaskedGroupNorm
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
    norms = [m for m in fast.modules() if isinstance(m, MaskedGroupNorm)]
    assert len(norms) == 21 and all(type(m) is FusedFrameNorm for m in norms)  # 5 stages x 2 blocks x 2, final
    x, t = torch.randn(2, 12, 11), torch.tensor([3, 700])
    text, text_mask = torch.randn(2, 5, 8), torch.tensor([[1, 1, 1, 0, 0], [1, 1, 1, 1, 1]], dtype=torch.bool)
    mask = torch.arange(12)[None] < torch.tensor([[7], [12]])
    with torch.inference_mode():
        ref, out = net(x, t, text, text_mask, mask), fast(x, t, text, text_mask, mask)
    assert (out[~mask] == 0).all()
    torch.testing.assert_close(out, ref, rtol=1e-4, atol=1e-5)
