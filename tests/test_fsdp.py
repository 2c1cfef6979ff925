"""Sharded training (FSDP2, stablemo.training.sharding): the per-network unit policy, a sharded step
against the unsharded one in one process (a 1-process gloo group), the 1 B DiT config's parameter
count and memory per GPU (meta device), and, slow, 2 CPU processes with gloo through `stablemo fit
--trainer.strategy=fsdp`: their checkpoint reloads in one process, exports, generates as the
weights the shards held, resumes exactly under FSDP and continues unsharded."""

from __future__ import annotations

import copy
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import yaml
from test_training import TINY_MODEL, tiny_config, write_random_dataset

from stablemo.errors import StableMoError
from stablemo.training.checkpoint_io import load_checkpoint_file

REPO = Path(__file__).resolve().parents[1]
TESTS = Path(__file__).resolve().parent
CONFIG_1B = REPO / "configs" / "scale" / "dit_1b_fsdp.yaml"
SMALL_TEXT = {"encoder": "minilm", "latent_dim": 32, "num_layers": 2, "num_heads": 2, "ff_dim": 64, "dropout": 0.0}
SMALL_NETS = {
    "unet": {"name": "unet", "input_dim": 263, "base_channels": 16, "channel_mults": [1, 2], "time_dim": 32,
             "num_groups": 4, "num_heads": 2, "dropout": 0.0},
    "dit": {"name": "dit", "input_dim": 263, "latent_dim": 32, "num_layers": 2, "num_heads": 2, "ff_dim": 64,
            "dropout": 0.0},
    "retnet": {"name": "retnet", "input_dim": 263, "latent_dim": 32, "num_layers": 2, "num_heads": 2, "ff_dim": 64,
               "dropout": 0.0},
}


def small_model(net: str, fast: bool):
    from stablemo.fast.train import accelerate_training
    from stablemo.nets.model import MotionDiffusionModel

    torch.manual_seed(0)
    model = MotionDiffusionModel(denoiser=SMALL_NETS[net], text=SMALL_TEXT)
    for p in model.parameters():  # zero-initialised heads would leave most gradients zero
        torch.nn.init.normal_(p, std=0.05)
    return accelerate_training(model) if fast else model


# ---------------------------------------------------------------------------------------------- the policy


@pytest.mark.parametrize("net", sorted(SMALL_NETS))
@pytest.mark.parametrize("fast", [False, True], ids=["stock", "fast_training"])
def test_every_block_and_cross_attention_is_a_unit(net, fast):
    from torch import nn

    from stablemo.nets.dit import DiTBlock
    from stablemo.nets.layers import LinearCrossAttention
    from stablemo.nets.retnet import RetNetBlock
    from stablemo.nets.unet import ResBlock1D
    from stablemo.training.sharding import shard_units

    model = small_model(net, fast)
    found = shard_units(model)
    kinds = [unit.block for _, unit in found]
    block = {"unet": ResBlock1D, "dit": DiTBlock, "retnet": RetNetBlock}[net]
    expected_blocks = sum(isinstance(m, block) for m in model.modules())
    assert expected_blocks >= 2 and kinds.count(block) == expected_blocks
    assert kinds.count(LinearCrossAttention) == sum(isinstance(m, LinearCrossAttention) for m in model.modules()) > 0
    assert kinds.count(nn.TransformerEncoderLayer) == SMALL_TEXT["num_layers"]
    # bottom-up: a cross-attention inside a block comes before that block
    order = {id(m): i for i, (m, _) in enumerate(found)}
    for module, unit in found:
        for child in module.modules():
            if child is not module and id(child) in order:
                assert order[id(child)] < order[id(module)]


def test_a_network_without_a_policy_is_refused_in_one_line():
    from torch import nn

    from stablemo.training.sharding import units_of

    with pytest.raises(StableMoError, match=r"--trainer.strategy=fsdp: Linear has no sharding policy"):
        units_of(nn.Linear(2, 2))


# ---------------------------------------------------------------------------------------------- one process


@pytest.fixture(scope="module")
def one_process_group():
    """A gloo group of one process in this one: FSDP2's DTensor weights (whole shards), in-process."""
    import torch.distributed as dist
    from torch.distributed.device_mesh import init_device_mesh

    if dist.is_initialized():
        pytest.skip("a process group is already initialised in this process")
    dist.init_process_group("gloo", store=dist.HashStore(), rank=0, world_size=1)
    try:
        yield init_device_mesh("cpu", (1,))
    finally:
        dist.destroy_process_group()


def _loss_and_grads(model, x, t, texts, mask):
    text, text_mask = model.encode_text(texts)
    out = model(x, t, text, text_mask, mask)
    loss = (out.float() - x).square().mean()
    loss.backward()
    grads = {}
    for name, p in model.named_parameters():
        g = p.grad
        grads[name] = (g.full_tensor() if hasattr(g, "full_tensor") else g).clone()
    return loss.detach(), grads


def _step_inputs():
    gen = torch.Generator().manual_seed(1)
    x = torch.randn(3, 8, 263, generator=gen)
    t, mask = torch.tensor([5, 500, 990]), torch.ones(3, 8, dtype=torch.bool)
    mask[1, 6:] = False
    return x, t, ["a person walks forward", "someone jumps", ""], mask


@pytest.mark.parametrize("net", sorted(SMALL_NETS))
@pytest.mark.parametrize("fast", [False, True], ids=["stock", "fast_training"])
def test_sharded_step_equals_unsharded_step_to_the_bit(one_process_group, net, fast):
    """The sharded network's loss and every gradient are the unsharded copy's, bit for bit, once that
    copy's gradient sums are grouped as FSDP2 groups them (group_unit_gradients, what unsharded
    training does): every weight read, inside a unit's forward or through a registered method
    (context, adagn, encode_text), is gathered, and every sum is associated alike."""
    from stablemo.training.sharding import group_unit_gradients, is_sharded, shard_model

    whole = small_model(net, fast)
    sharded = copy.deepcopy(whole)
    units = shard_model(sharded, one_process_group)
    assert is_sharded(sharded) and units >= 6
    assert group_unit_gradients(whole)
    x, t, texts, mask = _step_inputs()
    loss_a, grads_a = _loss_and_grads(whole, x, t, texts, mask)
    loss_b, grads_b = _loss_and_grads(sharded, x, t, texts, mask)
    assert torch.equal(loss_a, loss_b)
    assert grads_a.keys() == grads_b.keys()
    for name in grads_a:
        assert grads_a[name].abs().max() > 0, name  # a real gradient reached every weight
        assert torch.equal(grads_a[name], grads_b[name]), name


def test_ungrouped_unet_sums_its_skip_gradients_in_another_order(one_process_group):
    """Why the grouping exists: without it the UNet's gradients differ from the sharded network's in
    the last bits (the skip connections' sums), in the down stages and what feeds them."""
    from stablemo.training.sharding import shard_model

    whole = small_model("unet", fast=False)
    sharded = copy.deepcopy(whole)
    shard_model(sharded, one_process_group)
    x, t, texts, mask = _step_inputs()
    _, grads_a = _loss_and_grads(whole, x, t, texts, mask)
    _, grads_b = _loss_and_grads(sharded, x, t, texts, mask)
    differ = [name for name in grads_a if not torch.equal(grads_a[name], grads_b[name])]
    assert differ and all(name.startswith(("text.", "denoiser.time_embed", "denoiser.text_embed", "denoiser.down"))
                          for name in differ), differ
    assert all(torch.allclose(grads_a[n], grads_b[n], rtol=1e-5, atol=1e-10) for n in differ)


def test_grouping_is_idempotent_and_a_deep_copy_trains_its_own_weights():
    from stablemo.nets.unet import ResBlock1D
    from stablemo.training.sharding import group_unit_gradients

    grouped = small_model("unet", fast=True)
    assert group_unit_gradients(grouped) and group_unit_gradients(grouped)
    block = next(m for m in grouped.modules() if isinstance(m, ResBlock1D))
    assert "adagn" in vars(block) and "forward" in vars(block) and "encode_text" in vars(grouped)
    twin = copy.deepcopy(grouped)
    x, t, texts, mask = _step_inputs()
    _loss_and_grads(twin, x, t, texts, mask)
    assert all(p.grad is None for p in grouped.parameters())  # the copy's methods call the copy
    assert all(p.grad is not None for p in twin.parameters())
    with torch.no_grad():  # not training: nothing added to the graph, same output
        text, text_mask = twin.encode_text(texts)
        assert torch.equal(twin(x, t, text, text_mask, mask), grouped(x, t, *grouped.encode_text(texts), mask))
    assert not group_unit_gradients(torch.nn.Linear(2, 2))  # no policy: nothing to match


def test_bf16_units_keep_float32_master_weights_and_gradients(one_process_group):
    """param_dtype=bfloat16 (the 1 B config's): units compute in bf16, the sharded weights and their
    gradients stay float32, and the loss is the float32 network's to bf16 precision."""
    from stablemo.training.sharding import shard_model

    whole = small_model("dit", fast=True)
    sharded = copy.deepcopy(whole)
    shard_model(sharded, one_process_group, param_dtype=torch.bfloat16)
    x = torch.randn(2, 8, 263, generator=torch.Generator().manual_seed(2))
    t, mask = torch.tensor([10, 700]), torch.ones(2, 8, dtype=torch.bool)
    loss_a, _ = _loss_and_grads(whole, x, t, ["a person waves", "jump"], mask)
    loss_b, grads = _loss_and_grads(sharded, x, t, ["a person waves", "jump"], mask)
    assert all(p.dtype == torch.float32 and p.grad.dtype == torch.float32 for p in sharded.parameters())
    assert all(torch.isfinite(g).all() for g in grads.values())
    assert loss_a != loss_b and torch.allclose(loss_a, loss_b, rtol=2e-2)  # computed in bf16, not float32


def test_ema_of_sharded_weights_saves_full_tensors_and_loads_back(one_process_group):
    from stablemo.training.ema import EMA
    from stablemo.training.sharding import shard_model

    whole = small_model("dit", fast=False)
    sharded = copy.deepcopy(whole)
    shard_model(sharded, one_process_group)
    ema_whole, ema_sharded = EMA(whole, decay=0.5, warmup=0.0), EMA(sharded, decay=0.5, warmup=0.0)
    with torch.no_grad():
        for a, b in zip(whole.parameters(), sharded.parameters()):
            a.add_(1.0)
            b.add_(1.0)
    ema_whole.update(whole)
    ema_sharded.update(sharded)
    saved = ema_sharded.state_dict()
    assert all(type(v) is torch.Tensor for v in saved["shadow"].values())  # gathered, plain tensors
    for key, value in ema_whole.state_dict()["shadow"].items():
        assert torch.equal(saved["shadow"][key], value), key
    fresh = EMA(sharded, decay=0.5, warmup=0.0)
    fresh.load_state_dict(saved)
    assert all(hasattr(v, "placements") for v in fresh.shadow.values())  # sharded again
    assert all(torch.equal(fresh.shadow[k].full_tensor(), saved["shadow"][k]) for k in saved["shadow"])


# ---------------------------------------------------------------------------------------------- the 1 B config


def test_one_billion_dit_config_states_its_parameters_and_memory_per_gpu():
    """The config's comment states what its network has and needs: counted on the meta device (no
    weight allocated), the memory per GPU computed for full sharding on 8 GPUs."""
    from stablemo.nets.model import MotionDiffusionModel
    from stablemo.text.encoders import get_encoder
    from stablemo.training.shard_memory import sharded_memory

    text = CONFIG_1B.read_text()
    config = yaml.safe_load(text)
    model_cfg = config["model"]["model"]
    get_encoder(model_cfg["text"]["encoder"], 4096, None)  # the frozen encoder holds real weights: not on meta
    with torch.device("meta"):
        model = MotionDiffusionModel(**model_cfg)
    assert next(model.parameters()).is_meta
    memory = sharded_memory(model, world_size=8)
    stated = int(re.search(r"Parameters \(counted .*?\): ([\d,]+)\.", text).group(1).replace(",", ""))
    assert memory.parameters == stated and 0.95e9 < stated < 1.15e9
    for line in memory.lines():
        assert f"#   {line}\n" in text, line
    # full sharding: the float32 state is 1/8 of an unsharded run's, weights + grads + Adam + EMA = 20 B
    assert abs(sum(memory.sharded.values()) * 8 / (20 * memory.parameters) - 1) < 0.01
    assert config["trainer"]["strategy"]["class_path"] == "stablemo.training.sharding.FullShardStrategy"


def test_one_billion_config_parses_through_the_cli(capsys):
    from stablemo.cli.train import main_fit

    with pytest.raises(SystemExit) as exit_:
        main_fit(["--config", str(CONFIG_1B), "--print_config"])
    assert exit_.value.code in (0, None)
    printed = yaml.safe_load(capsys.readouterr().out)
    assert printed["trainer"]["strategy"]["init_args"]["param_dtype"] == "bfloat16"
    assert printed["model"]["init_args"]["model"]["denoiser"]["latent_dim"] == 2048


def test_bad_param_dtype_is_one_line():
    from stablemo.training.sharding import FullShardStrategy

    with pytest.raises(StableMoError, match="--trainer.strategy.param_dtype: expected one of"):
        FullShardStrategy(param_dtype="int8")


# ---------------------------------------------------------------------------------------------- 2 processes


STEPS = 4


def environment() -> dict[str, str]:
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONWARNINGS="ignore",
               PYTHONPATH=os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")]))
    for key in [k for k in env if k.startswith(("SLURM_", "TORCHELASTIC_"))]:
        del env[key]
    return env


def fit(folder: Path, data: Path, *extra: str, steps: int = STEPS) -> Path:
    probes = [{"class_path": "cluster_probes.SaveRankWeights", "init_args": {"dirpath": str(folder / "ranks")}}]
    # validation at step STEPS: the EMA swapped into the (sharded) network, its loss averaged over ranks
    cfg = tiny_config(folder, data, **{"trainer.max_steps": steps, "trainer.accelerator": "cpu",
                                       "trainer.callbacks": probes, "trainer.limit_val_batches": 2,
                                       "trainer.val_check_interval": STEPS, "trainer.check_val_every_n_epoch": None})
    done = subprocess.run([sys.executable, "-m", "stablemo.cli", "fit", "--config", str(cfg), *extra], cwd=REPO,
                          env=environment(), capture_output=True, text=True, timeout=900, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    return folder


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory) -> Path:
    return write_random_dataset(tmp_path_factory.mktemp("data") / "tiny")


@pytest.fixture(scope="module")
def fsdp_run(tiny_data, tmp_path_factory) -> Path:
    return fit(tmp_path_factory.mktemp("fsdp") / "run", tiny_data, "--trainer.strategy=fsdp", "--trainer.devices=2")


def _generate(bundle: Path) -> torch.Tensor:
    from stablemo.inference.pipeline import Pipeline, Request

    pipe = Pipeline.from_bundle(bundle)
    out = pipe.generate(Request(["a person walks forward", "someone jumps"], [48, 40], seed=3, steps=4, cfg=2.5))
    return out.features


def _max_diff(a: dict, b: dict) -> float:
    assert a.keys() == b.keys()
    return max((a[k].double() - b[k].double()).abs().max().item() for k in a)


@pytest.mark.slow  # 2 fresh processes (+ 1 to export): ~1 min on 2 busy cores
def test_two_process_fsdp_checkpoint_reloads_in_one_process_and_exports(fsdp_run, tmp_path):
    from stablemo.cli.export import main as export_main
    from stablemo.inference.bundle import load_bundle, save_bundle
    from stablemo.training.module import DiffusionModule

    ckpt = fsdp_run / "checkpoints" / "last.ckpt"
    saved = load_checkpoint_file(ckpt)
    ranks = [torch.load(fsdp_run / "ranks" / f"rank{r}.pt", weights_only=True) for r in (0, 1)]
    assert saved["global_step"] == ranks[0]["step"] == ranks[1]["step"] == STEPS
    # the checkpoint is full and unsharded: plain tensors, the shapes of an unsharded module's
    whole = DiffusionModule(model=TINY_MODEL)
    shapes = {k: tuple(v.shape) for k, v in whole.state_dict().items()}
    assert {k: tuple(v.shape) for k, v in saved["state_dict"].items()} == shapes
    assert all(type(v) is torch.Tensor for v in saved["state_dict"].values())
    for r in (0, 1):  # what both shards held, gathered, is what rank 0 wrote
        assert _max_diff({"model." + k: v for k, v in ranks[r]["weights"].items()}, saved["state_dict"]) == 0.0
        assert _max_diff(ranks[r]["ema"], saved["stablemo"]["ema"]["shadow"]) == 0.0
    assert saved["stablemo"]["ema"]["num_updates"] == STEPS

    module = DiffusionModule.load_from_checkpoint(ckpt, weights_only=True)  # one process, no strategy
    assert _max_diff({"model." + k: v for k, v in module.model.state_dict().items()}, saved["state_dict"]) == 0.0

    bundle = tmp_path / "bundle"
    assert export_main([str(ckpt), "--out", str(bundle)]) == 0
    # the same weights never sharded: rank 0's gathered EMA in a bundle of the same config
    loaded = load_bundle(bundle)
    reference = save_bundle(tmp_path / "reference", loaded.config, ranks[0]["ema"])
    got, want = _generate(bundle), _generate(reference)
    diff = (got - want).abs().max().item()
    print(f"FSDP checkpoint (2 processes) exported, generation vs the shards' own EMA weights: max |diff| = {diff:.3g}")
    assert diff <= 1e-6 and got.abs().max() > 0


@pytest.mark.slow  # 2 x 2 fresh processes + 1
def test_fsdp_resume_is_exact_and_an_unsharded_run_continues_its_checkpoint(fsdp_run, tiny_data, tmp_path):
    split = tmp_path / "split"
    fit(split, tiny_data, "--trainer.strategy=fsdp", "--trainer.devices=2", steps=2)
    fit(split, tiny_data, "--trainer.strategy=fsdp", "--trainer.devices=2", "--ckpt_path=last")
    a, b = (load_checkpoint_file(f / "checkpoints" / "last.ckpt") for f in (fsdp_run, split))
    assert a["global_step"] == b["global_step"] == STEPS
    assert _max_diff(a["state_dict"], b["state_dict"]) == 0.0
    assert _max_diff(a["stablemo"]["ema"]["shadow"], b["stablemo"]["ema"]["shadow"]) == 0.0
    for idx, state in a["optimizer_states"][0]["state"].items():
        for name in ("exp_avg", "exp_avg_sq"):
            assert torch.equal(state[name], b["optimizer_states"][0]["state"][idx][name]), (idx, name)

    # across world sizes: one unsharded process resumes the 2-process FSDP checkpoint (weights,
    # EMA, Adam moments, step) and trains on
    single = tmp_path / "single"
    fit(single, tiny_data, f"--ckpt_path={fsdp_run / 'checkpoints' / 'last.ckpt'}", steps=STEPS + 1)
    c = load_checkpoint_file(single / "checkpoints" / "last.ckpt")
    assert c["global_step"] == STEPS + 1 and c["stablemo"]["ema"]["num_updates"] == STEPS + 1
    assert all(int(s["step"]) == STEPS + 1 for s in c["optimizer_states"][0]["state"].values())
    assert 0 < _max_diff(a["state_dict"], c["state_dict"]) < 1e-2  # one more small step from the same weights


@pytest.mark.slow  # 2 fresh processes (+ 2 exports)
def test_fsdp_trains_and_generates_as_ddp_to_the_bit(fsdp_run, tiny_data, tmp_path):
    """The same 4 steps unsharded (DDP, 2 processes, its gradient sums grouped as FSDP2 groups them:
    sharding.group_unit_gradients): the same gradients, so the same weights, EMA and Adam moments up
    to the fused CPU AdamW's last bits (its vector and scalar paths round differently, and a shard
    boundary moves elements from one to the other: 2.9e-11 in one element of the 263-wide output
    bias, measured; 8.3e-6 before the grouping); the 2-process FSDP checkpoint, exported in one
    process, generates what the DDP one generates (<= 1e-6; measured 0)."""
    from stablemo.cli.export import main as export_main

    ddp = fit(tmp_path / "ddp", tiny_data, "--trainer.strategy=ddp", "--trainer.devices=2")
    a, b = (load_checkpoint_file(f / "checkpoints" / "last.ckpt") for f in (fsdp_run, ddp))
    weights = _max_diff(a["state_dict"], b["state_dict"])
    ema = _max_diff(a["stablemo"]["ema"]["shadow"], b["stablemo"]["ema"]["shadow"])
    val = [_val_loss(f) for f in (fsdp_run, ddp)]
    generated = []
    for name, run in (("fsdp", fsdp_run), ("ddp", ddp)):
        assert export_main([str(run / "checkpoints" / "last.ckpt"), "--out", str(tmp_path / f"{name}_bundle")]) == 0
        generated.append(_generate(tmp_path / f"{name}_bundle"))
    gen = (generated[0] - generated[1]).abs().max().item()
    print(f"FSDP vs DDP after {STEPS} steps: weights max |diff| = {weights:.3g}, EMA {ema:.3g}, "
          f"val/loss {val[0]:.9g} vs {val[1]:.9g}; generation from the exported bundles: max |diff| = {gen:.3g}")
    assert max(v.abs().max().item() for v in a["state_dict"].values()) > 0
    assert weights < 1e-9 and ema < 1e-9
    for idx, state in a["optimizer_states"][0]["state"].items():
        for name in ("exp_avg", "exp_avg_sq"):
            other = b["optimizer_states"][0]["state"][idx][name]
            assert torch.allclose(state[name], other, rtol=1e-6, atol=0), (idx, name)
    assert val[0] > 0 and abs(val[0] - val[1]) < 1e-7
    assert gen <= 1e-6 and generated[0].abs().max() > 0


def _val_loss(run: Path) -> float:
    """The last val/loss a run's CSV log holds."""
    import csv

    rows = [row for log in sorted((run / "logs").glob("version_*/metrics.csv"))
            for row in csv.DictReader(log.read_text().splitlines())]
    return float([row["val/loss"] for row in rows if row.get("val/loss")][-1])


def test_fsdp_for_a_module_without_a_policy_is_one_line(tmp_path):
    """`--trainer.strategy=fsdp` on another LightningModule (the evaluator) stops before any process
    starts, naming the flag."""
    from stablemo.cli.train import main_fit

    with pytest.raises(StableMoError, match=r"^--trainer.strategy=fsdp: EvaluatorModule has no sharding policy"):
        main_fit(["--config", str(REPO / "configs" / "evaluator_synth.yaml"), "--trainer.strategy=fsdp",
                  f"--trainer.default_root_dir={tmp_path}", f"--data.data_dir={tmp_path}"])


@pytest.mark.slow  # 2 x 2 fresh processes per network
@pytest.mark.parametrize("net", ["dit", "retnet"])
def test_transformer_denoisers_train_sharded_over_two_processes(net, tiny_data, tmp_path):
    """DiT and RetNet (with their text transformer) sharded over 2 processes: 2 steps give DDP's
    weights (to the fused AdamW's last bits at most), and the checkpoint exports from one process."""
    from stablemo.cli.export import main as export_main
    from stablemo.inference.bundle import load_bundle

    model = {"denoiser": dict(SMALL_NETS[net], dropout=0.1), "text": dict(SMALL_TEXT, dropout=0.1)}
    runs = {}
    for strategy in ("fsdp", "ddp"):
        folder = tmp_path / strategy
        probes = [{"class_path": "cluster_probes.SaveRankWeights", "init_args": {"dirpath": str(folder / "ranks")}}]
        cfg = tiny_config(folder, tiny_data, **{"trainer.max_steps": 2, "trainer.accelerator": "cpu",
                                                "trainer.callbacks": probes, "model.model": model})
        done = subprocess.run([sys.executable, "-m", "stablemo.cli", "fit", "--config", str(cfg),
                               f"--trainer.strategy={strategy}", "--trainer.devices=2"], cwd=REPO, env=environment(),
                              capture_output=True, text=True, timeout=900, check=False)
        assert done.returncode == 0, done.stderr[-3000:]
        runs[strategy] = load_checkpoint_file(folder / "checkpoints" / "last.ckpt")
    a, b = runs["fsdp"], runs["ddp"]
    assert a["global_step"] == b["global_step"] == 2
    diff = _max_diff(a["state_dict"], b["state_dict"])
    print(f"{net}: FSDP vs DDP after 2 steps: weights max |diff| = {diff:.3g}")
    assert 0 < max(v.abs().max().item() for v in a["state_dict"].values()) and diff < 1e-9  # measured 0
    assert export_main([str(tmp_path / "fsdp" / "checkpoints" / "last.ckpt"), "--out", str(tmp_path / "bundle")]) == 0
    assert load_bundle(tmp_path / "bundle").config["model"]["denoiser"]["name"] == net
