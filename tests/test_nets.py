"""Denoisers: one interface, exact padding invariance, precision, paper-sized build, a training step."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

from stablemo.errors import StableMoError
from stablemo.nets import build_denoiser
from stablemo.nets.config import load_denoiser_config
from stablemo.cli.nets import main as summary_main

D, C = 12, 16  # feature width, text width of the tiny test configs

TINY = {
    "unet_baseline": ("unet", dict(base_channels=16, channel_mults=[1, 2, 2, 2], time_dim=32, num_groups=2,
                                   num_heads=2, cross_attention=False, norm="group")),
    "unet_xattn": ("unet", dict(base_channels=16, channel_mults=[1, 2, 2, 2], time_dim=32, num_groups=2,
                                num_heads=2, cross_attention=True, norm="group")),
    "unet_tweak": ("unet", dict(base_channels=16, channel_mults=[1, 2, 2, 2], time_dim=32, num_groups=2,
                                num_heads=2, cross_attention=True, norm="frame")),
    # the input head: per-frame blocks over [last features | x_t] before the output convolution
    "unet_input_head": ("unet", dict(base_channels=16, channel_mults=[1, 2, 2, 2], time_dim=32, num_groups=2,
                                     num_heads=2, cross_attention=True, norm="frame", input_head=8)),
    "unet_input_head_k3": ("unet", dict(base_channels=16, channel_mults=[1, 2, 2, 2], time_dim=32, num_groups=2,
                                        num_heads=2, cross_attention=True, norm="frame", input_head=8,
                                        input_head_kernel=3)),
    # temporal self-attention at the coarsest resolution
    "unet_mid_attention": ("unet", dict(base_channels=16, channel_mults=[1, 2, 2, 2], time_dim=32, num_groups=2,
                                        num_heads=2, cross_attention=True, norm="frame", input_head=8,
                                        input_head_kernel=3, mid_attention=4)),
    # and more of it on the way up: a second layer at the coarsest resolution, one at the next
    "unet_up_attention": ("unet", dict(base_channels=16, channel_mults=[1, 2, 2, 2], time_dim=32, num_groups=2,
                                       num_heads=2, cross_attention=True, norm="frame", input_head=8,
                                       input_head_kernel=3, mid_attention=4, up_attention=[4, 2])),
    # the published T2MUnet's layout (stablemo.official imports its checkpoints into it)
    "unet_official": ("unet", dict(base_channels=16, channel_mults=[1, 2, 2, 2], time_dim=32, num_groups=2,
                                   num_heads=2, cross_attention=True, norm="frame", variant="official")),
}
if importlib.util.find_spec("stablemo.nets.dit"):
    TINY.update({
        "dit_baseline": ("dit", dict(latent_dim=32, num_layers=2, num_heads=4, ff_dim=64, cross_attention=False)),
        "dit_xattn": ("dit", dict(latent_dim=32, num_layers=2, num_heads=4, ff_dim=64, cross_attention=True)),
    })
if importlib.util.find_spec("stablemo.nets.retnet"):
    TINY.update({
        "retnet_baseline": ("retnet", dict(latent_dim=32, num_layers=2, num_heads=4, ff_dim=64, cross_attention=False)),
        "retnet_xattn": ("retnet", dict(latent_dim=32, num_layers=2, num_heads=4, ff_dim=64, cross_attention=True)),
    })



class OneCall(torch.nn.Module):
    """A denoiser called as training calls it: its conditioning prepared afresh at every call."""

    def __init__(self, net: torch.nn.Module):
        super().__init__()
        self.net = net
        self.length_multiple = net.length_multiple

    def forward(self, x, t, text, text_mask, motion_mask, time_cond=None):
        return self.net(x, t, self.net.prepare(text, text_mask, motion_mask, time_cond))


def make(variant: str, seed: int = 0) -> OneCall:
    """A tiny denoiser in eval mode whose zero-initialised layers are randomised (else output == 0)."""
    torch.manual_seed(seed)
    name, kwargs = TINY[variant]
    model = build_denoiser(name, input_dim=D, text_dim=C, **kwargs).eval()
    with torch.no_grad():
        for p in model.parameters():
            if torch.count_nonzero(p) == 0:
                p.normal_(0, 0.2)
    return OneCall(model)


def round_up(n: int, k: int) -> int:
    return int(math.ceil(n / k) * k)


def sample_items(gen: torch.Generator, lengths, text_lengths):
    """Per-item valid motion (n, D), timestep, text tokens (l, C)."""
    items = []
    for n, l in zip(lengths, text_lengths):
        items.append(dict(
            x=torch.randn(n, D, generator=gen),
            t=int(torch.randint(0, 1000, (1,), generator=gen)),
            text=torch.randn(l, C, generator=gen),
        ))
    return items


def collate(items, total: int, text_total: int, gen: torch.Generator | None, pad_scale: float = 1e4):
    """Pad items to (B, total, D) / (B, text_total, C); padding is random large values when gen is given."""
    B = len(items)
    if gen is None:
        x, text = torch.zeros(B, total, D), torch.zeros(B, text_total, C)
    else:
        x = pad_scale * torch.randn(B, total, D, generator=gen)
        text = pad_scale * torch.randn(B, text_total, C, generator=gen)
    mm = torch.zeros(B, total, dtype=torch.bool)
    tm = torch.zeros(B, text_total, dtype=torch.bool)
    for i, it in enumerate(items):
        n, l = it["x"].shape[0], it["text"].shape[0]
        x[i, :n], mm[i, :n] = it["x"], True
        text[i, :l], tm[i, :l] = it["text"], True
    t = torch.tensor([it["t"] for it in items])
    return x, t, text, tm, mm


def assert_close_rel(actual, expected, rtol=1e-5):
    scale = expected.abs().max().item()
    torch.testing.assert_close(actual, expected, rtol=rtol, atol=rtol * max(scale, 1e-6))


def cast(batch, dtype):
    return [a.to(dtype) if a.is_floating_point() else a for a in batch]


@pytest.mark.parametrize("dtype,rtol", [(torch.float32, 1e-5), (torch.float64, 1e-10)], ids=["fp32", "fp64"])
@pytest.mark.parametrize("variant", sorted(TINY))
def test_padding_invariance(variant, dtype, rtol):
    """Valid-frame outputs ignore padded values, total padded length and the other batch items.

    float32 at 1e-5 relative is the user-facing promise; float64 at 1e-10 shows the invariance is
    exact (what remains in float32 is rounding of differently-sized kernels, not a leak).
    """
    model = make(variant).to(dtype)
    k = model.length_multiple
    gen = torch.Generator().manual_seed(1)
    lengths = [int(v) for v in torch.randint(1, 41, (3,), generator=gen)] + [1, 40]
    text_lengths = [int(v) for v in torch.randint(1, 9, (len(lengths),), generator=gen)]
    items = sample_items(gen, lengths, text_lengths)
    with torch.no_grad():
        # reference: every item alone, shortest admissible padding, zeros in padding
        refs = []
        for it in items:
            n, l = it["x"].shape[0], it["text"].shape[0]
            refs.append(model(*cast(collate([it], round_up(n, k), l, None), dtype))[0, :n])
        for total in (round_up(40, k), round_up(40, k) + k, round_up(40, k) + 3 * k + round_up(8, k)):
            x, t, text, tm, mm = cast(collate(items, total, 12, gen), dtype)
            out = model(x, t, text, tm, mm)
            assert torch.isfinite(out).all()
            assert (out[~mm] == 0).all(), "padded frames must come out as exact zeros"
            for i, (it, ref) in enumerate(zip(items, refs)):
                assert_close_rel(out[i, : it["x"].shape[0]], ref, rtol)
        # the property is not vacuous: a valid frame's output depends on its valid neighbours
        x, t, text, tm, mm = cast(collate(items[-1:], round_up(40, k), text_lengths[-1], None), dtype)
        base = model(x, t, text, tm, mm)
        x2 = x.clone()
        x2[0, 20] += torch.randn(D, generator=gen, dtype=dtype)
        changed = (model(x2, t, text, tm, mm) - base).abs().amax(dim=-1)[0]
        assert changed[19] > 1e-6 and changed[21] > 1e-6
        # ... and on the text
        text2 = text.clone()
        text2[0, 0] += torch.randn(C, generator=gen, dtype=dtype)  # not a constant: LayerNorm ignores those
        assert (model(x, t, text2, tm, mm) - base).abs().max() > 1e-6


@pytest.mark.parametrize("variant", sorted(TINY))
def test_mixed_batch_shuffle_and_masked_text_tokens(variant):
    """Batch order and garbage (NaN/inf) in padded motion/text do not change valid outputs."""
    model = make(variant, seed=3)
    k = model.length_multiple
    gen = torch.Generator().manual_seed(7)
    items = sample_items(gen, [3, 17, 33], [2, 5, 1])
    total = round_up(33, k)
    with torch.no_grad():
        x, t, text, tm, mm = collate(items, total, 6, gen)
        out = model(x, t, text, tm, mm)
        perm = torch.tensor([2, 0, 1])
        x[~mm] = float("nan")
        text[~tm] = float("inf")
        out_perm = model(x[perm], t[perm], text[perm], tm[perm], mm[perm])
    assert torch.isfinite(out_perm).all()
    for j, i in enumerate(perm.tolist()):
        n = items[i]["x"].shape[0]
        assert_close_rel(out_perm[j, :n], out[i, :n])


@pytest.mark.parametrize("variant", sorted(TINY))
def test_bfloat16_cpu_close_to_float32(variant):
    """bf16 weights and bf16 autocast (Lightning "bf16-mixed") both run, stay close to float32, and
    keep padding invariance within bf16 precision."""
    model = make(variant)
    k = model.length_multiple
    gen = torch.Generator().manual_seed(2)
    items = sample_items(gen, [16, 9], [4, 2])
    batch = collate(items, round_up(16, k), 4, None)
    with torch.no_grad():
        ref = model(*batch)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            mixed = model(*batch)
        model = model.to(torch.bfloat16)
        out = model(*cast(batch, torch.bfloat16))
        longer = model(*cast(collate(items, round_up(16, k) + 3 * k, 9, gen, pad_scale=100.0), torch.bfloat16))
    for y in (mixed, out):
        assert y.dtype == torch.bfloat16 and torch.isfinite(y).all()
        err = (y.float() - ref).norm() / ref.norm()
        assert err < 0.1, f"bf16 relative error {err:.3f}"
    for i, it in enumerate(items):
        n = it["x"].shape[0]
        assert_close_rel(longer[i, :n].float(), out[i, :n].float(), rtol=2e-2)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="float16 needs CUDA")
@pytest.mark.parametrize("variant", sorted(TINY))
def test_float16_cuda(variant):
    model = make(variant)
    gen = torch.Generator().manual_seed(2)
    items = sample_items(gen, [16, 9], [4, 2])
    x, t, text, tm, mm = collate(items, round_up(16, model.length_multiple), 4, None)
    with torch.no_grad():
        ref = model(x, t, text, tm, mm)
        model = model.cuda().half()
        out = model(x.cuda().half(), t.cuda(), text.cuda().half(), tm.cuda(), mm.cuda())
    assert torch.isfinite(out).all()
    assert (out.float().cpu() - ref).norm() / ref.norm() < 0.05


@pytest.mark.parametrize("variant", sorted(TINY))
def test_training_steps_reduce_loss(variant):
    """A few AdamW steps on a fixed masked batch lower the masked x0 loss (gradients flow)."""
    torch.manual_seed(0)
    name, kwargs = TINY[variant]
    model = OneCall(build_denoiser(name, input_dim=D, text_dim=C, **kwargs).train())
    gen = torch.Generator().manual_seed(4)
    items = sample_items(gen, [16, 11, 5], [3, 4, 2])
    x, t, text, tm, mm = collate(items, round_up(16, model.length_multiple), 4, None)
    target = torch.sin(torch.arange(x.shape[1])[None, :, None] * 0.3 + torch.arange(D)) * mm[..., None]
    opt = torch.optim.AdamW(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(8):
        out = model(x, t, text, tm, mm)
        loss = ((out - target) ** 2)[mm].mean()
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        losses.append(loss.item())
    assert all(math.isfinite(v) for v in losses)
    assert losses[-1] < 0.85 * losses[0], losses


def test_zero_initialised_output():
    """Fresh denoisers predict exactly zero (zero-initialised output layer)."""
    for variant, (name, kwargs) in TINY.items():
        model = OneCall(build_denoiser(name, input_dim=D, text_dim=C, **kwargs).eval())
        k = model.length_multiple
        x, t, text, tm, mm = collate(sample_items(torch.Generator().manual_seed(0), [k], [3]), k, 3, None)
        assert (model(x, t, text, tm, mm) == 0).all(), variant


def test_bad_inputs_raise_clear_errors():
    model = make("unet_tweak")
    x, t, text, tm, mm = collate(sample_items(torch.Generator().manual_seed(0), [8], [2]), 8, 2, None)
    with pytest.raises(StableMoError, match="multiple of 8"):
        model(x[:, :7], t, text, tm, mm[:, :7])
    with pytest.raises(StableMoError, match="x: expected"):
        model(x[..., :5], t, text, tm, mm)
    with pytest.raises(StableMoError, match="motion_mask"):
        model(x, t, text, tm, mm.float())
    with pytest.raises(StableMoError, match="unknown option"):
        build_denoiser("unet", input_dim=D, bogus=1)
    with pytest.raises(StableMoError, match="unknown"):
        build_denoiser("transformer", input_dim=D)
    with pytest.raises(StableMoError, match="input_dim"):
        build_denoiser("unet")
    with pytest.raises(StableMoError, match="norm"):
        build_denoiser("unet", input_dim=D, norm="batch")


PAPER_UNET = dict(input_dim=263, text_dim=256, base_channels=512, channel_mults=[2, 2, 2, 2], time_dim=512,
                  cross_attention=True, norm="frame")


def test_paper_unet_builds():
    """Paper CondUNet1D (base 512, mults [2,2,2,2], time 512, text 256) builds (meta device: no memory)."""
    with torch.device("meta"):
        model = build_denoiser("unet", **PAPER_UNET)
    n_params = sum(p.numel() for p in model.parameters())
    assert 250e6 < n_params < 350e6, n_params  # 309,008,135 with this implementation
    assert model.length_multiple == 8


@pytest.mark.slow
def test_paper_unet_runs_short():
    """One real forward of the paper-sized CondUNet1D at T=16 (1.2 GB of float32 weights)."""
    model = OneCall(build_denoiser("unet", **PAPER_UNET).eval())
    with torch.no_grad():
        out = model(torch.randn(1, 16, 263), torch.tensor([10]), torch.randn(1, 5, 256),
                    torch.ones(1, 5, dtype=torch.bool), torch.ones(1, 16, dtype=torch.bool))
    assert out.shape == (1, 16, 263) and (out == 0).all()  # zero-initialised output layer


CONFIGS = sorted((Path(__file__).parents[1] / "configs" / "nets").rglob("*.yaml"))


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_yaml_configs_build(path):
    """Every configs/nets YAML names a valid denoiser and options (built on the meta device: no memory)."""
    config = load_denoiser_config(path)
    name = config.pop("name")
    with torch.device("meta"):
        model = build_denoiser(name, input_dim=263, text_dim=256, **config)
    assert sum(p.numel() for p in model.parameters()) > 0


def test_all_six_variants_have_yaml():
    kinds = set()
    for path in CONFIGS:
        cfg = load_denoiser_config(path)
        kinds.add((cfg["name"], cfg.get("cross_attention", True), cfg.get("norm", "frame") if cfg["name"] == "unet" else None))
    assert {("unet", False, "group"), ("unet", True, "group"), ("unet", True, "frame"),
            ("dit", False, None), ("dit", True, None), ("retnet", False, None), ("retnet", True, None)} <= kinds


def test_summary_cli_prints_params_and_flops(tmp_path, capsys):
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text("name: unet\nbase_channels: 16\nchannel_mults: [1, 2]\ntime_dim: 16\nnum_groups: 2\nnum_heads: 2\n")
    assert summary_main(["summary", "--config", str(cfg), "--length", "21", "--input-dim", "12", "--text-dim", "8"]) == 0
    out = capsys.readouterr().out
    torch.manual_seed(0)
    model = build_denoiser("unet", input_dim=12, text_dim=8, base_channels=16, channel_mults=[1, 2], time_dim=16,
                           num_groups=2, num_heads=2)
    n = sum(p.numel() for p in model.parameters())
    total = [line for line in out.splitlines() if line.startswith("total")][0]
    assert f"{n:,}" in total
    assert "padded to 22" in out
    # FLOPs: at least the output 1x1 convolution, 2 * 22 frames * 16 * 12 multiply-adds
    assert float(total.split()[-1]) * 1e9 > 2 * 22 * 16 * 12
    # a training YAML with the denoiser nested under model.init_args works too
    nested = tmp_path / "train.yaml"
    nested.write_text("model:\n  init_args:\n    denoiser:\n      name: dit\n      latent_dim: 16\n      num_layers: 1\n"
                      "      num_heads: 2\n      ff_dim: 32\n")
    assert summary_main(["summary", "--config", str(nested), "--length", "10"]) == 0
    with pytest.raises(StableMoError, match="not found"):
        summary_main(["summary", "--config", str(tmp_path / "missing.yaml")])
    bad = tmp_path / "bad.yaml"
    bad.write_text("foo: 1\n")
    with pytest.raises(StableMoError, match="no model description found"):
        summary_main(["summary", "--config", str(bad)])


@pytest.fixture(scope="module")
def synth_batch(tmp_path_factory):
    """One real batch from a tiny synthetic dataset (HumanML3D layout, 263 features)."""
    synth = pytest.importorskip("stablemo.data.synth")
    datamodule = pytest.importorskip("stablemo.data.datamodule")
    root = synth.write_dataset(tmp_path_factory.mktemp("synth") / "data", 8, 0, workers=1)
    dm = datamodule.MotionDataModule(str(root), batch_size=4, pad_multiple=8, max_length=48, seed=0)
    dm.setup("fit")
    return next(iter(dm.train_dataloader()))


@pytest.mark.parametrize("variant", sorted(TINY))
def test_train_steps_on_synthetic_data(variant, synth_batch):
    """MotionDiffusionModel (MiniLM text) trains on real synthetic batches: finite masked x0 loss, and
    within three AdamW steps every trainable weight (denoiser and text transformer) gets a gradient."""
    from stablemo.diffusion.schedule import NoiseSchedule
    from stablemo.nets.model import MotionDiffusionModel

    torch.manual_seed(0)
    name, kwargs = TINY[variant]
    model = MotionDiffusionModel({"name": name, "input_dim": 263, **kwargs},
                                 {"latent_dim": C, "num_layers": 1, "num_heads": 2, "ff_dim": 32}).train()
    schedule = NoiseSchedule()
    x0, mask = synth_batch["motion"], synth_batch["mask"]
    assert x0.shape[1] % model.length_multiple == 0
    texts = list(synth_batch["text"])
    texts[0] = ""  # the null condition trains alongside
    opt = torch.optim.AdamW(model.parameters(), lr=1e-3)
    touched = {n: False for n, _ in model.named_parameters()}
    for step in range(3):
        t = torch.randint(0, 1000, (x0.shape[0],))
        x_t = schedule.q_sample(x0, t, torch.randn_like(x0))
        text, text_mask = model.encode_text(texts)
        out = model(x_t, t, text, text_mask, mask)
        loss = ((out - x0) ** 2)[mask].mean()
        assert torch.isfinite(loss)
        opt.zero_grad()
        loss.backward()
        for n, p in model.named_parameters():
            assert p.grad is None or torch.isfinite(p.grad).all(), n
            touched[n] |= p.grad is not None and bool(p.grad.abs().sum() > 0)
        opt.step()
    untouched = [n for n, ok in touched.items() if not ok]
    assert not untouched, untouched


@pytest.mark.parametrize("variant", sorted(TINY))
def test_no_gradient_reaches_padding_or_other_items(variant):
    """Gradients of one item's valid outputs are exactly zero on padded frames, padded text tokens
    and on every other batch item (the training loss cannot learn from padding)."""
    model = make(variant, seed=5)
    k = model.length_multiple
    gen = torch.Generator().manual_seed(9)
    items = sample_items(gen, [5, 14], [3, 2])
    x, t, text, tm, mm = collate(items, round_up(14, k) + k, 4, gen, pad_scale=10.0)
    x.requires_grad_(True)
    text.requires_grad_(True)
    out = model(x, t, text, tm, mm)
    out[0][mm[0]].pow(2).sum().backward()
    assert (x.grad[0][~mm[0]] == 0).all() and (x.grad[1] == 0).all()
    assert (text.grad[0][~tm[0]] == 0).all() and (text.grad[1] == 0).all()
    assert x.grad[0][mm[0]].abs().sum() > 0 and text.grad[0][tm[0]].abs().sum() > 0


@pytest.mark.parametrize("mode", ["frame", "group"])
def test_group_norm_folds_adagn_modulation(mode):
    from stablemo.nets.layers import MaskedGroupNorm

    torch.manual_seed(0)
    norm = MaskedGroupNorm(4, 16, mode)
    with torch.no_grad():
        norm.weight.normal_()
        norm.bias.normal_()
    x, mask = torch.randn(2, 16, 10), torch.arange(10)[None] < torch.tensor([[10], [6]])
    scale, shift = torch.randn(2, 16, 1), torch.randn(2, 16, 1)
    separate = norm(x, mask) * scale + shift
    folded = norm(x, mask, scale, shift)
    torch.testing.assert_close(folded[:, :, :6], separate[:, :, :6], rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(folded[1:, :, :6], norm(x[1:, :, :6], mask[1:, :6], scale[1:], shift[1:]), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("variant", sorted(TINY))
def test_prepared_conditioning_is_reused_across_steps_and_changes_no_result(variant):
    """One `prepare` per request, read at every step: bit-identical to preparing at every call;
    under autograd the prepared tensors carry gradients to the text (training prepares per batch)."""
    model = make(variant).net
    gen = torch.Generator().manual_seed(3)
    items = sample_items(gen, [24, 17], [5, 3])
    x, t, text, tm, mm = collate(items, round_up(24, model.length_multiple), 6, gen)
    with torch.inference_mode():
        ctx = model.prepare(text, tm, mm)
        for step, t_step in enumerate([t, t // 2, torch.zeros_like(t)]):
            x_step = x + step
            expected = model(x_step, t_step, model.prepare(text, tm, mm))
            torch.testing.assert_close(model(x_step, t_step, ctx), expected, rtol=0, atol=0)
    text = text.clone().requires_grad_(True)
    model(x, t, model.prepare(text, tm, mm)).sum().backward()
    assert text.grad is not None and text.grad[tm].abs().sum() > 0


def test_planned_request_projects_adagn_once_and_changes_no_result():
    """With the sampler's timesteps known before the loop (Sampler.timesteps), each residual block
    projects the AdaGN embedding of every step in one product when the conditioning is prepared;
    the results are those of embedding each step as it comes."""
    from stablemo.diffusion.guidance import CFGDenoiser
    from stablemo.diffusion.samplers import SAMPLER_TABLE
    from stablemo.diffusion.schedule import NoiseSchedule

    model = make("unet_tweak").net
    gen = torch.Generator().manual_seed(5)
    items = sample_items(gen, [24, 17], [5, 3])
    x, _, text, tm, mm = collate(items, 24, 6, None)
    null, null_mask = torch.zeros(2, 1, C), torch.zeros(2, 1, dtype=torch.bool)
    rows: list[int] = []
    blocks = [m for m in model.modules() if type(m).__name__ == "ResBlock1D"]
    for block in blocks:
        block.emb.register_forward_hook(lambda mod, args, out: rows.append(args[0][..., 0].numel()))
    sampler, schedule = SAMPLER_TABLE["dpmpp_2m_sde"], NoiseSchedule()

    def run(steps: int, planned: bool):
        rows.clear()
        with torch.inference_mode():
            timesteps = sampler.timesteps(schedule, steps) if planned else ()
            network = SimpleNamespace(prepare=model.prepare, denoise=model)  # the guidance.Network contract
            denoiser = CFGDenoiser(network, text, tm, null, null_mask, mm, scale=2.5, timesteps=timesteps)
            out = sampler.run(denoiser, x, schedule, steps, generator=torch.Generator().manual_seed(0))
        return out, list(rows)

    plain, plain_rows = run(5, planned=False)
    planned, planned_rows = run(5, planned=True)
    assert plain_rows == [4] * 5 * len(blocks)  # every step: a 2-row product per block (CFG batch 2 x 2)
    assert planned_rows == [5 * 4] * len(blocks)  # once, for all 5 steps
    torch.testing.assert_close(planned, plain, rtol=1e-5, atol=1e-5)
    again, again_rows = run(3, planned=True)
    assert again_rows == [3 * 4] * len(blocks)
    torch.testing.assert_close(again, run(3, planned=False)[0], rtol=1e-5, atol=1e-5)


def test_samplers_visit_exactly_their_announced_timesteps():
    """Sampler.timesteps is what the loop asks the denoiser for, step by step (else the planned
    AdaGN tables would silently miss)."""
    from stablemo.diffusion.samplers import SAMPLER_TABLE
    from stablemo.diffusion.schedule import NoiseSchedule

    schedule = NoiseSchedule()
    for name, sampler in SAMPLER_TABLE.items():
        for steps in (1, 4, 10):
            seen: list[int] = []

            def denoise(x, t):
                seen.append(int(t[0]))
                return torch.zeros_like(x)

            sampler.run(denoise, torch.randn(1, 4, 3), schedule, steps, generator=torch.Generator().manual_seed(0))
            assert seen == list(sampler.timesteps(schedule, steps)), (name, steps)


@pytest.mark.parametrize("up_attention, match", [
    ([4, 4, 4, 4, 4], "at most 4"), ([-1], "heads >= 0"), ([True], "heads >= 0"), ([3], "not divisible by 3 heads"),
])
def test_up_attention_bad_values_are_one_clear_error(up_attention, match):
    from stablemo.errors import StableMoError
    from stablemo.nets import build_denoiser

    with pytest.raises(StableMoError, match=f"up_attention: .*{match}"):
        build_denoiser("unet", input_dim=11, text_dim=8, base_channels=8, channel_mults=(1, 2, 2, 2), time_dim=16,
                       num_groups=4, num_heads=2, up_attention=up_attention)
    with pytest.raises(StableMoError, match="up_attention: .*official"):
        build_denoiser("unet", input_dim=11, text_dim=8, base_channels=8, channel_mults=(1, 2, 2, 2), time_dim=16,
                       num_groups=4, num_heads=2, variant="official", up_attention=[2])
