"""`stablemo bench aits`: the Table 5 rows, FLOPs and efficiency figures, on a tiny network."""

import json

from pathlib import Path

import pytest
import torch

from stablemo.bench import aits as bench
from stablemo.cli import bench as bench_cli
from stablemo.errors import StableMoError

TINY = """
denoiser: {name: unet, input_dim: 263, base_channels: 8, channel_mults: [1, 2], time_dim: 16, num_groups: 4, num_heads: 2}
text: {encoder: minilm, latent_dim: 16, num_layers: 1, num_heads: 2, ff_dim: 32}
"""


@pytest.fixture
def tiny_config(tmp_path):
    pytest.importorskip("stablemo.nets.model")
    path = tmp_path / "tiny.yaml"
    path.write_text(TINY)
    return path


def test_aits_table_and_json(tiny_config, tmp_path, capsys):
    out = tmp_path / "aits.json"
    threads = torch.get_num_threads()
    rc = bench_cli.main(["aits", "--config", str(tiny_config), "--frames", "12", "--repeats", "1", "--steps", "3",
                     "--ddpm-steps", "2", "--threads", "1", "--json", str(out)])
    assert rc == 0 and torch.get_num_threads() == threads  # thread setting restored
    text = capsys.readouterr().out
    for name in ("DDPM 1000 (baseline) *", "+ SDE-DPM-Solver++ 2M, 3 steps", "+ text cache", "+ parallel CFG",
                 "+ low precision (bf16)", "1-step LCM student (fp32)", "extrapolated: 2 of 1000 steps",
                 "measured fp32 matmul", "1-step student AITS / teacher's 3-step AITS"):
        assert name in text
    data = json.loads(out.read_text())
    rows = data["rows"]
    assert [r["steps"] for r in rows] == [1000, 3, 3, 3, 3, 1, 1, 1]
    assert rows[0]["measured_steps"] == 2 and rows[0]["aits"] == pytest.approx(rows[0]["seconds"][0] * 500)
    assert [(r["text_cache"], r["parallel_cfg"], r["dtype"]) for r in rows[1:6]] == [
        (False, False, "fp32"), (True, False, "fp32"), (True, True, "fp32"), (True, True, "bf16"), (True, False, "fp32")]
    # the student runs its network once on batch 1: half the FLOPs of a CFG step
    assert rows[5]["sampler"] == "lcm" and rows[5]["flops_per_step"] == pytest.approx(rows[1]["flops_per_step"] / 2)
    # + ControlNet (the shipped form: the first stage again and the hint encoder, whose 64 channels
    # outweigh this tiny network's 16): more than the student's, less than three times
    assert [r["name"] for r in rows[6:]] == [bench.CONTROLNET_ROW, bench.CONTROLNET_GUIDED_ROW]
    assert rows[5]["flops_per_step"] < rows[6]["flops_per_step"] < 3 * rows[5]["flops_per_step"]
    assert f"'{bench.CONTROLNET_ROW}' AITS / '{bench.STUDENT_ROW}' AITS" in text
    assert data["matmul_fp32_gflops"] > 0 and data["frames"] == 12
    # the distillation speed-up again over a test set's varied lengths, side by side
    varied = data["varied_lengths"]
    assert varied["lengths"] == list(bench.VARIED_LENGTHS) and varied["teacher"] > 0 and varied["student"] > 0
    assert f"ratio {varied['student'] / varied['teacher']:.3f}" in text


def test_flops_per_step_counts_both_cfg_halves(tiny_config):
    from stablemo.diffusion.schedule import NoiseSchedule
    from stablemo.inference.pipeline import Pipeline
    from stablemo.nets.model import MotionDiffusionModel

    kwargs, _ = bench.model_kwargs(str(tiny_config))
    pipe = Pipeline(MotionDiffusionModel(**kwargs), NoiseSchedule(), [0.0] * 263, [1.0] * 263, device="cpu")
    one, two = bench.denoiser_flops(pipe, 12, 1), bench.denoiser_flops(pipe, 12, 2)
    assert one > 0 and two == pytest.approx(2 * one)
    # frames are padded to the network's length multiple (2 here): 11 frames cost as much as 12
    assert bench.denoiser_flops(pipe, 11, 1) == one


@pytest.mark.parametrize("backend", ["onednn", "mkl", "plain"])
def test_packed_products_are_counted(monkeypatch, backend):
    """The FLOP counter does not know the packed linears: without the bench's formulas it would
    count nothing for them, and every efficiency figure would be wrong."""
    from torch.utils.flop_counter import FlopCounterMode

    from stablemo.fast import accelerate
    from stablemo.fast.flops import counter_formulas

    monkeypatch.setenv("STABLEMO_GEMM", backend)
    layer = accelerate(torch.nn.Linear(1024, 1100))
    x = torch.randn(40, 1024)
    with torch.inference_mode():
        layer(x)  # MKL packs at the second call with a row count
        layer(x)
        counter = FlopCounterMode(display=False, custom_mapping=counter_formulas())
        with counter:
            layer(x)
    assert counter.get_total_flops() == 2 * 40 * 1024 * 1100


def test_matmul_reference_takes_the_fastest_product():
    sample = bench.matmul_gflops(n=256, repeats=2)
    assert "torch.matmul" in sample and all(w > 0 and c > 0 for w, c in sample.values())
    wall, cpu = bench._fastest(sample)
    assert wall == max(w for w, _ in sample.values()) and cpu == max(c for _, c in sample.values())


def test_model_description_formats(tmp_path):
    denoiser_only = tmp_path / "d.yaml"
    denoiser_only.write_text("name: unet\nbase_channels: 8\ntext_dim: 32\n")
    kwargs, _ = bench.model_kwargs(str(denoiser_only))
    assert kwargs["denoiser"]["name"] == "unet" and kwargs["denoiser"]["input_dim"] == 263
    assert kwargs["text"]["latent_dim"] == 32 and kwargs["text"]["encoder"] == "minilm"
    lightning = tmp_path / "l.yaml"
    lightning.write_text("model:\n  model:\n    denoiser: {name: dit, input_dim: 251}\n    text: {latent_dim: 64}\n")
    kwargs, _ = bench.model_kwargs(str(lightning))
    assert kwargs["denoiser"] == {"name": "dit", "input_dim": 251, "text_dim": 64} and kwargs["text"]["latent_dim"] == 64
    kwargs, source = bench.model_kwargs(None)  # the paper network by default
    assert kwargs["denoiser"]["base_channels"] == 512 and list(kwargs["denoiser"]["channel_mults"]) == [2, 2, 2, 2]


def test_the_packaged_paper_network_is_the_one_the_paper_config_trains():
    """The benchmark's network ships in the package (an installed wheel has no configs/); the
    training config describes the same network, so the two may not drift apart."""
    from stablemo.nets.config import load_model_config

    packaged = load_model_config(bench.PAPER_NETWORK)
    assert packaged == load_model_config(Path(__file__).resolve().parents[1] / "configs" / "humanml3d.yaml")
    assert packaged["denoiser"]["variant"] == "official" and packaged["text"]["num_layers"] == 4


def test_bad_arguments(tmp_path):
    with pytest.raises(StableMoError, match="--config: .*missing.yaml: file not found"):
        bench_cli.main(["aits", "--config", str(tmp_path / "missing.yaml")])
    with pytest.raises(StableMoError, match="--ddpm-steps"):
        bench_cli.main(["aits", "--ddpm-steps", "0"])
    empty = tmp_path / "empty.yaml"
    empty.write_text("trainer: {max_steps: 3}\n")
    with pytest.raises(StableMoError, match="no model description"):
        bench_cli.main(["aits", "--config", str(empty)])
    with pytest.raises(StableMoError, match="unknown benchmark 'speed'"):
        bench_cli.main(["speed"])


def test_flops_are_the_same_with_and_without_the_fused_attention_kernel(tiny_config):
    """The fused cross-attention read is invisible to the FLOP counter; its products are counted
    from the call shapes, so the count equals the PyTorch path's."""
    from stablemo.diffusion.schedule import NoiseSchedule
    from stablemo.fast import kernels as fused
    from stablemo.fast.blocks import FusedLinearCrossAttention
    from stablemo.inference.pipeline import Pipeline
    from stablemo.nets.model import MotionDiffusionModel

    if fused.kernels() is None:
        pytest.skip("the fused CPU kernels cannot be built here")
    kwargs, _ = bench.model_kwargs(str(tiny_config))
    pipe = Pipeline(MotionDiffusionModel(**kwargs), NoiseSchedule(), [0.0] * 263, [1.0] * 263, device="cpu")
    stock = bench.denoiser_flops(pipe, 12, 2)
    for stage in pipe.model.denoiser.stages():  # the tiny model is below the kernels' width: switch by hand
        for attn in stage.attns:
            attn.attn = FusedLinearCrossAttention(attn.attn)
    assert any(isinstance(m, FusedLinearCrossAttention) for m in pipe.model.modules())
    assert bench.denoiser_flops(pipe, 12, 2) == stock
