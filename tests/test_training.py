"""Training: EMA arithmetic, CFG dropout, overfitting, exact resume, NaN guard, export, DDP."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from lightning.pytorch import Trainer
from lightning.pytorch.callbacks import ModelCheckpoint
from torch import nn

from stablemo.errors import StableMoError
from stablemo.inference.bundle import load_bundle
from stablemo.training.callbacks import NonFiniteGuard, NonFiniteLossError
from stablemo.training.checkpoint_io import AtomicCheckpointIO, load_checkpoint_file
from stablemo.training.ema import EMA

REPO = Path(__file__).resolve().parents[1]

TINY_MODEL = {
    "denoiser": {"name": "unet", "input_dim": 263, "base_channels": 16, "channel_mults": [1, 2], "time_dim": 32,
                 "num_groups": 4, "num_heads": 2, "dropout": 0.1},
    "text": {"encoder": "minilm", "latent_dim": 32, "num_layers": 1, "num_heads": 2, "ff_dim": 64},
}
VERBS = ["walks", "runs", "jumps", "waves", "turns", "kicks"]


def write_random_dataset(root: Path, num: int = 24, dim: int = 263, seed: int = 0,
                         splits: tuple[int, int] = (16, 4)) -> Path:
    """Smooth random features with two captions per clip, in the HumanML3D folder layout."""
    rng = np.random.default_rng(seed)
    (root / "new_joint_vecs").mkdir(parents=True)
    (root / "texts").mkdir()
    ids = []
    for i in range(num):
        clip = f"{i:06d}"
        frames = int(rng.integers(40, 64))
        x = np.cumsum(rng.normal(size=(frames, dim)), axis=0) * 0.1 + rng.normal(size=dim)
        np.save(root / "new_joint_vecs" / f"{clip}.npy", x.astype(np.float32))
        verb = VERBS[i % len(VERBS)]
        (root / "texts" / f"{clip}.txt").write_text(
            f"a person {verb}#a/DET person/NOUN {verb}/VERB#0.0#0.0\n"
            f"someone {verb} slowly#someone/PRON {verb}/VERB slowly/ADV#0.0#0.0\n")
        ids.append(clip)
    feats = np.concatenate([np.load(root / "new_joint_vecs" / f"{c}.npy") for c in ids])
    np.save(root / "Mean.npy", feats.mean(0).astype(np.float32))
    np.save(root / "Std.npy", (feats.std(0) + 1e-3).astype(np.float32))
    n_train, n_val = splits
    parts = {"train": ids[:n_train], "val": ids[n_train:n_train + n_val], "test": ids[n_train + n_val:], "all": ids}
    for name, part in parts.items():
        (root / f"{name}.txt").write_text("\n".join(part) + "\n")
    return root


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory) -> Path:
    return write_random_dataset(tmp_path_factory.mktemp("data") / "tiny")


def tiny_config(tmp: Path, data_dir: Path, **overrides) -> Path:
    config = {
        "seed_everything": 0,
        "trainer": {
            "accelerator": "cpu", "devices": 1, "max_steps": 6, "gradient_clip_val": 1.0, "limit_val_batches": 0,
            "log_every_n_steps": 1, "default_root_dir": str(tmp), "enable_progress_bar": False,
            "enable_model_summary": False,
            "logger": {"class_path": "lightning.pytorch.loggers.CSVLogger",
                       "init_args": {"save_dir": str(tmp), "name": "logs"}},
        },
        "checkpoint": {"dirpath": str(tmp / "checkpoints"), "every_n_train_steps": 3},
        "model": {"model": TINY_MODEL, "ema_decay": 0.9, "lr": 1e-3},
        "data": {"data_dir": str(data_dir), "batch_size": 4, "pad_multiple": 2, "max_length": 64},
    }
    for key, value in overrides.items():
        section, name = key.split(".", 1)
        config[section][name] = value
    tmp.mkdir(parents=True, exist_ok=True)
    path = tmp / "config.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


def make_module(**kwargs):
    from stablemo.training.module import DiffusionModule

    return DiffusionModule(model=TINY_MODEL, **kwargs)


def make_datamodule(data_dir: Path, **kwargs):
    from stablemo.data import MotionDataModule

    return MotionDataModule(data_dir=str(data_dir), **{"batch_size": 4, "pad_multiple": 2, "max_length": 64, **kwargs})


# ---------------------------------------------------------------------------------------------- EMA


def test_ema_arithmetic_with_and_without_warmup():
    model = nn.Linear(3, 2)
    with torch.no_grad():
        model.weight.fill_(1.0)
        model.bias.fill_(0.0)
    ema = EMA(model, decay=0.9, warmup=0.0)  # warm-up off: beta = decay from the first step
    with torch.no_grad():
        model.weight.fill_(3.0)
        model.bias.fill_(-1.0)
    ema.update(model)
    assert torch.allclose(ema.shadow["weight"], torch.full((2, 3), 0.9 * 1.0 + 0.1 * 3.0))
    assert torch.allclose(ema.shadow["bias"], torch.full((2,), 0.1 * -1.0))
    ema.update(model)
    assert torch.allclose(ema.shadow["weight"], torch.full((2, 3), 0.9 * 1.2 + 0.1 * 3.0))

    warm = EMA(model, decay=0.9, warmup=10.0)
    # beta_n = min(decay, (1 + n) / (10 + n))
    expected = [0.1, 2 / 11, 3 / 12]
    for n, beta in enumerate(expected):
        assert warm.current_decay() == pytest.approx(beta)
        warm.update(model)
    assert warm.num_updates == 3
    for _ in range(200):
        warm.update(model)
    assert warm.current_decay() == pytest.approx(0.9)


def test_ema_swap_restores_live_weights_and_state_round_trips():
    model = nn.Sequential(nn.Linear(4, 4), nn.BatchNorm1d(4))
    ema = EMA(model, decay=0.5, warmup=0.0)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(1.0)
    live = {k: v.clone() for k, v in model.state_dict().items()}
    ema.update(model)
    with ema.swapped_into(model):
        assert torch.equal(model[0].weight, ema.shadow["0.weight"])
        assert not torch.equal(model[0].weight, live["0.weight"])
    for k, v in model.state_dict().items():
        assert torch.equal(v, live[k]), k
    # integer buffers are copied, not averaged
    assert int(ema.shadow["1.num_batches_tracked"]) == int(model[1].num_batches_tracked)

    other = EMA(model, decay=0.5, warmup=0.0)
    other.load_state_dict(ema.state_dict())
    assert other.num_updates == 1
    assert all(torch.equal(other.shadow[k], ema.shadow[k]) for k in ema.shadow)
    with pytest.raises(StableMoError):
        EMA(nn.Linear(2, 2)).load_state_dict(ema.state_dict())
    with pytest.raises(StableMoError):
        EMA(model, decay=1.0)


# ---------------------------------------------------------------------------------------------- objective


def test_cfg_dropout_rate_is_seeded_and_per_sample():
    module = make_module(cond_drop_prob=0.1, seed=3)
    bsz = 50
    batch = {"motion": torch.zeros(bsz, 8, 263), "mask": torch.ones(bsz, 8, dtype=torch.bool),
             "text": [f"caption {i}" for i in range(bsz)], "id": [str(i) for i in range(bsz)]}
    drops = []
    for batch_idx in range(60):
        texts, drop, t, noise = module.training_inputs(batch, batch_idx)
        assert [tx == "" for tx in texts] == drop.tolist()
        assert all(tx == f"caption {i}" for i, tx in enumerate(texts) if not drop[i])
        assert t.min() >= 0 and t.max() < 1000 and noise.shape == (bsz, 8, 263)
        drops.append(drop)
    rate = torch.cat(drops).float().mean().item()
    # 3000 Bernoulli(0.1) draws: sd 0.0055
    assert abs(rate - 0.1) < 0.02, rate
    # same step -> same draws; other step -> other draws; every sample decides on its own
    again = module.training_inputs(batch, 0)
    assert torch.equal(again[1], drops[0]) and torch.equal(again[2], module.training_inputs(batch, 0)[2])
    assert not all(torch.equal(drops[0], d) for d in drops[1:])
    per_batch = torch.stack(drops).sum(1)
    assert ((per_batch > 0) & (per_batch < bsz)).any()  # not one coin per batch
    none = make_module(cond_drop_prob=0.0).training_inputs(batch, 0)[1]
    assert not none.any()


def test_bad_hyperparameters_are_named():
    with pytest.raises(StableMoError, match="prediction_type"):
        make_module(prediction_type="v")
    with pytest.raises(StableMoError, match="val_timesteps"):
        make_module(val_timesteps=[1000])


def test_validation_loss_is_fixed_and_independent_of_batching(tiny_data):
    module = make_module().eval()
    dm = make_datamodule(tiny_data, batch_size=4)
    dm.setup("validate")
    batch = next(iter(dm.val_dataloader()))
    both = module.fixed_noise_losses(batch)  # (B, K)
    assert both.shape == (batch["motion"].shape[0], 5)
    assert torch.equal(both, module.fixed_noise_losses(batch))
    # the first clip alone, with 8 more frames of padding, scores the same
    n = int(batch["length"][0])
    frames = batch["motion"].shape[1] + 8
    alone = {"motion": torch.zeros(1, frames, 263), "mask": torch.zeros(1, frames, dtype=torch.bool),
             "text": batch["text"][:1], "id": batch["id"][:1]}
    alone["motion"][0, :n] = batch["motion"][0, :n]
    alone["mask"][0, :n] = True
    torch.testing.assert_close(module.fixed_noise_losses(alone)[0], both[0], rtol=1e-4, atol=1e-6)



@pytest.mark.parametrize("prediction_type", ["sample", "v_prediction"])
def test_validation_reports_the_clean_motion_error_of_any_parameterisation(tiny_data, prediction_type):
    """val/loss_x0 makes runs of different prediction types comparable: for x0 prediction it is the
    loss itself; for v, x0 - x̂0 = sqrt(1 - abar) (v̂ - v) on every element, so it is (1 - abar) times it."""
    module = make_module(prediction_type=prediction_type).eval()
    dm = make_datamodule(tiny_data, batch_size=4)
    dm.setup("validate")
    batch = next(iter(dm.val_dataloader()))
    losses, x0_errors = module.fixed_noise_errors(batch)
    assert torch.equal(losses, module.fixed_noise_losses(batch))
    if prediction_type == "sample":
        assert torch.equal(losses, x0_errors)
    else:
        abar = module.schedule.alphas_cumprod[torch.tensor(module.hparams.val_timesteps)].float()
        torch.testing.assert_close(x0_errors, losses * (1 - abar), rtol=1e-4, atol=1e-7)
        assert (x0_errors < losses).all()

def test_tiny_model_overfits_a_tiny_batch(tiny_data, tmp_path):
    from lightning.pytorch.loggers import CSVLogger

    model = dict(TINY_MODEL, denoiser=dict(TINY_MODEL["denoiser"], dropout=0.0),
                 text=dict(TINY_MODEL["text"], dropout=0.0))
    from stablemo.training.module import DiffusionModule

    module = DiffusionModule(model=model, lr=5e-3, lr_step=1000, cond_drop_prob=0.0, seed=0)
    data = tmp_path / "four"
    write_random_dataset(data, num=6, splits=(4, 1))
    dm = make_datamodule(data, batch_size=4)
    trainer = Trainer(accelerator="cpu", devices=1, max_steps=120, limit_val_batches=0, logger=CSVLogger(tmp_path),
                      log_every_n_steps=1, enable_checkpointing=False, enable_progress_bar=False,
                      enable_model_summary=False, gradient_clip_val=1.0)
    trainer.fit(module, datamodule=dm)
    import csv

    rows = list(csv.DictReader(open(Path(trainer.logger.log_dir) / "metrics.csv")))
    losses = [float(r["train/loss"]) for r in rows if r.get("train/loss")]
    assert len(losses) == 120
    # random timesteps keep a floor under the loss; measured: 1.56 -> 0.24 (x6.5)
    first, last = np.mean(losses[:10]), np.mean(losses[-10:])
    assert last < first / 4, (first, last)


# ---------------------------------------------------------------------------------------------- checkpoints


def test_atomic_checkpoint_io_keeps_old_file_on_failure(tmp_path):
    io = AtomicCheckpointIO()
    path = tmp_path / "last.ckpt"
    io.save_checkpoint({"x": torch.ones(3)}, path)
    before = path.read_bytes()

    class Unsaveable:
        def __reduce__(self):
            raise RuntimeError("disk full, say")

    with pytest.raises(RuntimeError):
        io.save_checkpoint({"x": torch.zeros(3), "bad": Unsaveable()}, path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["last.ckpt"]
    assert torch.equal(io.load_checkpoint(path)["x"], torch.ones(3))


def test_checkpoint_loading_never_unpickles_objects(tmp_path):
    path = tmp_path / "evil.ckpt"
    torch.save({"state_dict": {}, "payload": Path("/etc/passwd")}, path)  # an arbitrary class
    with pytest.raises(StableMoError, match="evil.ckpt"):
        load_checkpoint_file(path)
    with pytest.raises(StableMoError, match="not found"):
        load_checkpoint_file(tmp_path / "missing.ckpt")


def _fit(config: Path, *extra: str) -> None:
    from stablemo.cli.train import main_fit

    assert main_fit(["--config", str(config), *extra]) == 0


def test_resume_is_exact(tiny_data, tmp_path):
    """6 steps straight == 3 steps, then resume for 3 (mid-epoch: 4 batches per epoch)."""
    straight, split = tmp_path / "straight", tmp_path / "split"
    _fit(tiny_config(straight, tiny_data))
    cfg = tiny_config(split, tiny_data)
    _fit(cfg, "--trainer.max_steps=3")
    _fit(cfg, "--ckpt_path=last")
    a = load_checkpoint_file(straight / "checkpoints" / "last.ckpt")
    b = load_checkpoint_file(split / "checkpoints" / "last.ckpt")
    assert a["global_step"] == b["global_step"] == 6
    assert a["state_dict"].keys() == b["state_dict"].keys()
    for key in a["state_dict"]:
        assert torch.equal(a["state_dict"][key], b["state_dict"][key]), key
    ema_a, ema_b = a["stablemo"]["ema"], b["stablemo"]["ema"]
    assert ema_a["num_updates"] == ema_b["num_updates"] == 6
    for key in ema_a["shadow"]:
        assert torch.equal(ema_a["shadow"][key], ema_b["shadow"][key]), key
    opt_a, opt_b = a["optimizer_states"][0]["state"], b["optimizer_states"][0]["state"]
    for idx in opt_a:
        for name in ("exp_avg", "exp_avg_sq"):
            assert torch.equal(opt_a[idx][name], opt_b[idx][name])
    assert a["lr_schedulers"] == b["lr_schedulers"]



def test_nan_loss_stops_and_keeps_last_good_checkpoint(tiny_data, tmp_path):
    from stablemo.training.module import DiffusionModule

    class PoisonedAt(DiffusionModule):
        def training_step(self, batch, batch_idx):
            if self.global_step == 4:
                batch = dict(batch, motion=batch["motion"] * float("nan"))
            return super().training_step(batch, batch_idx)

    module = PoisonedAt(model=TINY_MODEL, lr=1e-3)
    ckpt_dir = tmp_path / "checkpoints"
    checkpoint = ModelCheckpoint(dirpath=ckpt_dir, every_n_train_steps=2, save_last=True)
    trainer = Trainer(accelerator="cpu", devices=1, max_steps=10, limit_val_batches=0, logger=False,
                      callbacks=[checkpoint, NonFiniteGuard()], plugins=[AtomicCheckpointIO()],
                      enable_progress_bar=False, enable_model_summary=False, gradient_clip_val=1.0)
    with pytest.raises(NonFiniteLossError, match=r"diverged at step 4 .*loss = nan.*last\.ckpt"):
        trainer.fit(module, datamodule=make_datamodule(tiny_data))
    last = ckpt_dir / "last.ckpt"
    saved = load_checkpoint_file(last)
    assert saved["global_step"] == 4
    assert all(torch.isfinite(v).all() for v in saved["state_dict"].values() if v.is_floating_point())
    # the live weights were never touched by the NaN step either
    assert all(torch.isfinite(p).all() for p in module.parameters())
    for key, value in module.model.state_dict().items():
        assert torch.equal(value, saved["state_dict"]["model." + key]), key
    assert not any(p.name.startswith(".") for p in ckpt_dir.iterdir())  # no temp files left


# ---------------------------------------------------------------------------------------------- export


def test_export_round_trip_reproduces_the_ema_model(tiny_data, tmp_path):
    from stablemo.nets.model import MotionDiffusionModel
    from stablemo.cli.export import main as export_main
    from stablemo.training.module import DiffusionModule

    run = tmp_path / "run"
    _fit(tiny_config(run, tiny_data, **{"trainer.max_steps": 3}))
    ckpt = run / "checkpoints" / "last.ckpt"
    out = tmp_path / "bundle"
    assert export_main([str(ckpt), "--out", str(out)]) == 0
    bundle = load_bundle(out)
    dm = make_datamodule(tiny_data)
    assert bundle.config["prediction_type"] == "sample"
    assert bundle.config["schedule"]["num_train_timesteps"] == 1000
    assert bundle.config["model"]["text"]["encoder"] == "minilm"
    assert bundle.config["dataset"] == "humanml3d" and bundle.config["skeleton"] == "humanml3d"
    np.testing.assert_allclose(bundle.config["mean"], dm.mean, rtol=1e-6)
    np.testing.assert_allclose(bundle.config["std"], dm.std, rtol=1e-6)
    assert bundle.config["training"]["global_step"] == 3

    loaded = MotionDiffusionModel(**bundle.config["model"]).eval()
    loaded.load_state_dict(bundle.state_dict, strict=True)
    module = DiffusionModule.load_from_checkpoint(ckpt, weights_only=True).eval()
    gen = torch.Generator().manual_seed(0)
    x, t = torch.randn(2, 16, 263, generator=gen), torch.tensor([10, 900])
    mask = torch.ones(2, 16, dtype=torch.bool)
    texts = ["a person walks", ""]
    with torch.no_grad():
        with module.ema.swapped_into(module.model):
            want = module.model(x, t, *module.model.encode_text(texts), mask)
        got = loaded(x, t, *loaded.encode_text(texts), mask)
        raw = module.model(x, t, *module.model.encode_text(texts), mask)
    assert torch.equal(got, want)
    assert not torch.allclose(got, raw)  # EMA weights, not the raw ones

    with pytest.raises(StableMoError, match="checkpoint not found"):
        export_main([str(tmp_path / "nope.ckpt"), "--out", str(tmp_path / "b2")])


def test_init_from_a_bundle_starts_from_its_weights_and_checks_config_and_statistics(tiny_data, tmp_path):
    import shutil

    from stablemo.cli.export import main as export_main

    run = tmp_path / "run"
    _fit(tiny_config(run, tiny_data, **{"trainer.max_steps": 3}))
    out = tmp_path / "bundle"
    assert export_main([str(run / "checkpoints" / "last.ckpt"), "--out", str(out)]) == 0
    bundle = load_bundle(out)

    # one step at learning rate 0 (AdamW's decay is scaled by it too): the weights the run starts from
    still = tmp_path / "still"
    _fit(tiny_config(still, tiny_data, **{"trainer.max_steps": 1, "model.init_from": str(out)}), "--model.lr=0.0")
    ckpt = load_checkpoint_file(still / "checkpoints" / "last.ckpt")
    raw = {k[len("model."):]: v for k, v in ckpt["state_dict"].items() if k.startswith("model.")}
    shadow = ckpt["stablemo"]["ema"]["shadow"]
    assert set(raw) == set(bundle.state_dict)
    assert all(torch.equal(raw[k], bundle.state_dict[k]) for k in raw)
    assert all(torch.equal(shadow[k], bundle.state_dict[k]) for k in shadow)

    # resuming takes the checkpoint's weights, not the bundle's again: 4 steps straight == 2, then 2
    straight, split = tmp_path / "straight", tmp_path / "split"
    _fit(tiny_config(straight, tiny_data, **{"trainer.max_steps": 4, "model.init_from": str(out)}))
    cfg = tiny_config(split, tiny_data, **{"trainer.max_steps": 4, "model.init_from": str(out)})
    _fit(cfg, "--trainer.max_steps=2")
    _fit(cfg, "--ckpt_path=last")
    a = load_checkpoint_file(straight / "checkpoints" / "last.ckpt")["state_dict"]
    b = load_checkpoint_file(split / "checkpoints" / "last.ckpt")["state_dict"]
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert any(not torch.equal(a["model." + k], raw[k]) for k in raw)  # and they trained on from there

    # a checkpoint of such a run exports without the bundle it started from
    shutil.rmtree(out)
    assert export_main([str(straight / "checkpoints" / "last.ckpt"), "--out", str(tmp_path / "again")]) == 0
    assert export_main([str(run / "checkpoints" / "last.ckpt"), "--out", str(out)]) == 0

    other = dict(TINY_MODEL, denoiser=dict(TINY_MODEL["denoiser"], base_channels=8))
    bad = tiny_config(tmp_path / "other", tiny_data, **{"trainer.max_steps": 1, "model.init_from": str(out)})
    with pytest.raises(StableMoError, match="model.init_from: .*network config differs"):
        _fit(bad, f"--model.model={json.dumps(other)}")
    with pytest.raises(StableMoError, match="model.init_from: .*bundle folder not found"):
        _fit(tiny_config(tmp_path / "nope", tiny_data, **{"trainer.max_steps": 1,
                                                           "model.init_from": str(tmp_path / "nope_bundle")}))
    shifted = write_random_dataset(tmp_path / "shifted", seed=5)
    with pytest.raises(StableMoError, match="feature mean differs from the bundle's"):
        _fit(tiny_config(tmp_path / "bad", shifted, **{"trainer.max_steps": 1, "model.init_from": str(out)}))


def test_init_from_grows_temporal_attention_starting_as_the_bundles_network(tiny_data, tmp_path):
    """A bundle's UNet grown by temporal self-attention (up_attention, mid_attention) starts from the
    bundle's weights, its new blocks at their identity start: the same function at step 0; any other
    difference of the network config stays an error."""
    from stablemo.cli.export import main as export_main
    from stablemo.training.module import grown_attention

    run, out = tmp_path / "run", tmp_path / "bundle"
    _fit(tiny_config(run, tiny_data, **{"trainer.max_steps": 2}))
    assert export_main([str(run / "checkpoints" / "last.ckpt"), "--out", str(out)]) == 0
    bundle = load_bundle(out)
    grown = dict(TINY_MODEL, denoiser=dict(TINY_MODEL["denoiser"], up_attention=[2, 2], mid_attention=2))
    still = tmp_path / "still"
    _fit(tiny_config(still, tiny_data, **{"trainer.max_steps": 1, "model.init_from": str(out),
                                          "model.model": grown}), "--model.lr=0.0")
    state = {k[len("model."):]: v for k, v in
             load_checkpoint_file(still / "checkpoints" / "last.ckpt")["state_dict"].items() if k.startswith("model.")}
    new = [k for k in state if k not in bundle.state_dict]
    assert new and all(".self_attn." in k for k in new)
    assert all(torch.equal(state[k], bundle.state_dict[k]) for k in bundle.state_dict)

    from stablemo.nets.model import MotionDiffusionModel
    before, after = MotionDiffusionModel(**TINY_MODEL).eval(), MotionDiffusionModel(**grown).eval()
    before.load_state_dict(bundle.state_dict)
    after.load_state_dict(state)
    torch.manual_seed(0)
    x, t = torch.randn(2, 24, 263), torch.tensor([5, 800])
    text, text_mask = torch.randn(2, 4, 32), torch.ones(2, 4, dtype=torch.bool)
    mask = torch.arange(24)[None] < torch.tensor([[20], [24]])
    with torch.no_grad():
        a = before.denoiser(x, t, before.denoiser.prepare(text, text_mask, mask))
        b = after.denoiser(x, t, after.denoiser.prepare(text, text_mask, mask))
    assert torch.equal(a, b)

    assert grown_attention(TINY_MODEL, TINY_MODEL) == ()
    assert set(grown_attention(TINY_MODEL, grown)) == {"denoiser.mid.self_attn.", "denoiser.up.0.self_attn.",
                                                       "denoiser.up.1.self_attn."}
    assert grown_attention(grown, TINY_MODEL) is None  # attention is grown, never removed
    wider = dict(grown, denoiser=dict(grown["denoiser"], base_channels=8))
    assert grown_attention(TINY_MODEL, wider) is None
    with pytest.raises(StableMoError, match="model.init_from: .*network config differs"):
        _fit(tiny_config(tmp_path / "wider", tiny_data, **{"trainer.max_steps": 1, "model.init_from": str(out),
                                                           "model.model": wider}))


def test_input_dim_mismatch_is_a_clear_error(tiny_data, tmp_path):
    model = dict(TINY_MODEL, denoiser=dict(TINY_MODEL["denoiser"], input_dim=251))
    cfg = tiny_config(tmp_path, tiny_data, **{"model.model": model})
    with pytest.raises(StableMoError, match="input_dim: 251 does not match .* 263"):
        _fit(cfg)


# ---------------------------------------------------------------------------------------------- DDP


@pytest.mark.slow  # two fresh processes: 20-100 s on a shared 2-core machine
def test_ddp_smoke_two_cpu_processes(tiny_data, tmp_path):
    cfg = tiny_config(tmp_path, tiny_data, **{"trainer.max_steps": 2})
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONWARNINGS="ignore")
    proc = subprocess.run(
        [sys.executable, "-m", "stablemo.cli", "fit", "--config", str(cfg), "--trainer.strategy=ddp",
         "--trainer.devices=2", "--trainer.accelerator=cpu", "--checkpoint.every_n_train_steps=2"],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "world_size=2" in proc.stderr + proc.stdout or "Initializing distributed" in proc.stderr + proc.stdout
    saved = load_checkpoint_file(tmp_path / "checkpoints" / "last.ckpt")
    assert saved["global_step"] == 2 and saved["stablemo"]["ema"]["num_updates"] == 2


# ---------------------------------------------------------------------------------------------- configs, tools

ABLATION = ["unet_base", "unet_xattn", "unet_xattn_gn", "dit_base", "dit_xattn", "retnet_base", "retnet_xattn"]
CONFIG_SETS = [["synth_small.yaml"], ["humanml3d.yaml"], ["kit.yaml"]] + [
    ["ablation/common.yaml", f"ablation/{v}.yaml"] for v in ABLATION] + [
    ["demo.yaml"], ["demo.yaml", "demo_variants/input_head_k1.yaml"], ["demo.yaml", "demo_variants/no_input_head.yaml"],
    ["demo.yaml", "demo_variants/no_mid_attention.yaml"], ["demo.yaml", "demo_variants/base16.yaml"],
    ["demo.yaml", "demo_variants/base64.yaml"], ["demo.yaml", "demo_variants/text_noise.yaml"],
    ["demo.yaml", "demo_variants/further_same_data.yaml"], ["demo.yaml", "demo_variants/further_more_data.yaml"],
    ["demo.yaml", "demo_variants/further_16k.yaml"], ["demo.yaml", "demo_variants/further_16k_varied.yaml"]]


@pytest.mark.parametrize("files", CONFIG_SETS, ids=lambda f: f[-1])
def test_shipped_configs_parse(files, capsys):
    from stablemo.cli.train import main_fit

    args = [a for f in files for a in ("--config", str(REPO / "configs" / f))]
    with pytest.raises(SystemExit) as exit_:
        main_fit([*args, "--print_config"])
    assert exit_.value.code in (0, None)
    printed = yaml.safe_load(capsys.readouterr().out)
    assert printed["trainer"]["gradient_clip_val"] == 1.0
    assert printed["checkpoint"]["save_last"] is True
    assert printed["model"]["class_path"] == "stablemo.training.module.DiffusionModule"  # the default LightningModule
    model = printed["model"]["init_args"]
    assert model["prediction_type"] == "sample" and model["cond_drop_prob"] == 0.1
    assert model["schedule"] == {"num_train_timesteps": 1000, "beta_start": 1e-4, "beta_end": 0.02,
                                 "beta_schedule": "linear"}
    assert set(model["model"]) == {"denoiser", "text"}
    if files[0] in ("humanml3d.yaml", "kit.yaml"):
        assert printed["data"]["batch_size"] == 64 and printed["trainer"]["max_steps"] == 50000
        assert model["lr"] == 2e-4 and model["weight_decay"] == 0.01 and model["lr_step"] == 5000
        assert model["lr_gamma"] == 0.9 and model["ema_decay"] == 0.9999
        assert model["model"]["text"]["encoder"] == "openai/clip-vit-base-patch32"
        # the paper configs train the published network (293.7 M), padded as its layout needs
        assert model["model"]["denoiser"]["variant"] == "official" and printed["data"]["pad_multiple"] == 16


@pytest.mark.parametrize("variant, data_dir", [("further_same_data", "data/synth"),
                                               ("further_more_data", "data/synth_8k")])
def test_the_further_demo_variants_start_from_the_6000_step_teacher(variant, data_dir, capsys):
    """They train the recipe's network on from its 6000-step weights (bundles/demo_6000, which
    scripts/train/train_demo.sh's first stage exports and a clean clone lacks; model.init_from checks
    that its config equals the run's), at the learning rate its schedule had reached at step 6000."""
    from stablemo.cli.train import main_fit

    printed = {}
    for files in (["demo.yaml"], ["demo.yaml", f"demo_variants/{variant}.yaml"]):
        with pytest.raises(SystemExit):
            main_fit([a for f in files for a in ("--config", str(REPO / "configs" / f))] + ["--print_config"])
        printed[len(files)] = yaml.safe_load(capsys.readouterr().out)
    recipe, overlay = printed[1], printed[2]
    model = overlay["model"]["init_args"]
    assert model["init_from"] == "bundles/demo_6000" and model["model"] == recipe["model"]["init_args"]["model"]
    assert "stage 1 runs/demo 6000 bundles/demo_6000 " in (REPO / "scripts/train/train_demo.sh").read_text()
    assert model["lr"] == pytest.approx(recipe["model"]["init_args"]["lr"] * 0.9 ** 6, rel=1e-3)
    assert overlay["data"]["data_dir"] == data_dir and overlay["trainer"]["max_steps"] == 2000
    # the shipped teacher's statistics: its own data's, or data/synth's named for new clips
    assert overlay["data"].get("stats_dir") == (None if data_dir == "data/synth" else "data/synth")
    changed = {k for k in model if model[k] != recipe["model"]["init_args"][k]}
    assert changed == {"init_from", "lr"}


def test_the_16k_variant_continues_the_more_clips_teacher_where_its_schedule_stopped(capsys):
    """configs/demo_variants/further_16k.yaml: the more-clips teacher (the further_more_data run
    resumed to 4000 steps: 10000 in all, exported to bundles/, which a clean clone lacks) trained on
    from its weights on new clips, at the recipe's learning rate decayed ten times, its network and
    everything else as the recipe."""
    from stablemo.cli.train import main_fit

    printed = {}
    for files in (["demo.yaml"], ["demo.yaml", "demo_variants/further_16k.yaml"]):
        with pytest.raises(SystemExit):
            main_fit([a for f in files for a in ("--config", str(REPO / "configs" / f))] + ["--print_config"])
        printed[len(files)] = yaml.safe_load(capsys.readouterr().out)
    recipe, overlay = printed[1]["model"]["init_args"], printed[2]["model"]["init_args"]
    assert overlay["init_from"] == "bundles/demo_more_data_10000"
    assert overlay["lr"] == pytest.approx(recipe["lr"] * recipe["lr_gamma"] ** 10, rel=1e-4)
    assert {k for k in overlay if overlay[k] != recipe[k]} == {"init_from", "lr"}
    assert printed[2]["data"]["data_dir"] == "data/synth_16k" and printed[2]["data"]["stats_dir"] == "data/synth"


def _recipe_stages(script: str) -> list[dict]:
    """The `stage N RUN STEPS BUNDLE LOG CONFIG...` lines of a recipe script (scripts/train/...)."""
    text = (REPO / script).read_text().replace("\\\n", " ")
    stages = []
    for line in text.splitlines():
        if line.startswith("stage "):
            _, n, run, steps, bundle, log, *configs = line.split()
            stages.append({"n": int(n), "run": run, "steps": int(steps), "bundle": bundle, "log": log,
                           "configs": configs})
    return stages


def _merged_config(configs: list[str]) -> dict:
    """The configs merged as the Lightning CLI merges repeated --config files (later ones win, key by key)."""
    def merge(a: dict, b: dict) -> dict:
        return {**a, **{k: merge(a[k], v) if isinstance(v, dict) and isinstance(a.get(k), dict) else v
                        for k, v in b.items()}}
    merged: dict = {}
    for config in configs:
        merged = merge(merged, yaml.safe_load((REPO / config).read_text()))
    return merged


def test_the_teacher_recipe_chains_its_stages_into_the_shipped_bundle():
    """scripts/train/train_demo.sh: each stage trains the recipe's config (plus its overlay) in its own
    run folder, from the bundle the stage before exported, and the last one exports the packaged
    teacher, which says so (its training step count is the last stage's)."""
    stages = _recipe_stages("scripts/train/train_demo.sh")
    assert [s["n"] for s in stages] == [1, 2, 3]
    assert stages[-1]["bundle"] == "stablemo/assets/demo_bundle"
    assert load_bundle(REPO / stages[-1]["bundle"]).config["training"]["global_step"] == stages[-1]["steps"]
    for before, stage in zip([None, *stages], stages):
        assert stage["configs"][0] == "configs/demo.yaml"
        merged = _merged_config(stage["configs"])
        assert merged["trainer"]["default_root_dir"] == stage["run"]
        assert merged["model"].get("init_from") == (before["bundle"] if before else None)
        assert stage["steps"] >= merged["checkpoint"]["every_n_train_steps"]
    assert len({s["run"] for s in stages}) == len({s["bundle"] for s in stages}) == len({s["log"] for s in stages}) == 3


def test_the_controlnet_recipe_chains_its_stages_on_the_shipped_student_into_what_ship_demo_exports():
    """scripts/train/train_controlnet.sh: stage 1 trains the toward-targets ControlNet on the packaged
    student, stage 2 fine-tunes the bundle stage 1 exported (its `init`), each in the run folder and
    for the steps its configs say; scripts/train/ship_demo.sh exports stage 2's run into the package,
    and the packaged ControlNet is of that recipe's form."""
    stages = _recipe_stages("scripts/train/train_controlnet.sh")
    assert [s["n"] for s in stages] == [1, 2]
    for before, stage in zip([None, *stages], stages):
        merged = _merged_config(stage["configs"])
        assert merged["trainer"]["default_root_dir"] == stage["run"]
        assert merged["trainer"]["max_steps"] == stage["steps"]
        init = merged["model"]["init_args"]
        assert init["base"] == "stablemo/assets/demo_student" and init.get("init") == (before["bundle"] if before else None)
        assert init["control"]["root_only"] and init["control"]["toward_targets"]
    ship = (REPO / "scripts/train/ship_demo.sh").read_text()
    assert f"controlnet={stages[-1]['run']}/checkpoints/last.ckpt" in ship
    shipped = load_bundle(REPO / "stablemo/assets/demo_controlnet").config
    assert shipped["controlnet"]["control"]["toward_targets"] and shipped["controlnet"]["control"]["root_only"]


def test_the_controlnet_recipe_skips_a_stage_only_when_its_bundle_was_trained_on_todays_student(tmp_path):
    """A stage bundle counts as done when it holds the stage's steps and records the packaged student's
    weights (training.base_weights_sha256); one trained on another student is trained again (here the
    script then reaches `stablemo fit`, which this test replaces by a missing program)."""
    import hashlib

    (tmp_path / "scripts/train").mkdir(parents=True)
    for name in ("train_controlnet.sh", "stages.sh"):
        (tmp_path / "scripts/train" / name).write_text((REPO / "scripts/train" / name).read_text())
    for folder in ("data/synth_paths", "data/synth"):
        (tmp_path / folder).mkdir(parents=True)
        (tmp_path / folder / "Mean.npy").write_bytes(b"")
    student = tmp_path / "stablemo/assets/demo_student"
    student.mkdir(parents=True)
    (student / "model.safetensors").write_bytes(b"today's student")
    today = hashlib.sha256(b"today's student").hexdigest()

    def stage_bundle(name: str, sha: str) -> None:
        (tmp_path / "bundles" / name).mkdir(parents=True, exist_ok=True)
        (tmp_path / "bundles" / name / "config.json").write_text(
            json.dumps({"training": {"global_step": 1500, "base_weights_sha256": sha}}))

    env = {**os.environ, "STABLEMO": str(tmp_path / "no-such-stablemo"), "PYTHON": sys.executable}
    script = tmp_path / "scripts/train/train_controlnet.sh"
    stage_bundle("demo_controlnet_toward", today)
    stage_bundle("demo_controlnet_toward_clip", today)
    done = subprocess.run(["bash", str(script)], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["train_controlnet.sh: stage 1 done (bundles/demo_controlnet_toward)",
                                        "train_controlnet.sh: stage 2 done (bundles/demo_controlnet_toward_clip)"]
    stage_bundle("demo_controlnet_toward", hashlib.sha256(b"an earlier student").hexdigest())
    done = subprocess.run(["bash", str(script)], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode != 0
    assert done.stdout.splitlines() == ["train_controlnet.sh: stage 1: 1500 steps -> bundles/demo_controlnet_toward"]


@pytest.mark.parametrize("script, args", [("train_demo.sh", ["--stage", "4"]), ("train_demo.sh", ["--stage"]),
                                          ("train_demo.sh", ["--fast"]), ("train_controlnet.sh", ["--stage", "3"]),
                                          ("train_controlnet.sh", ["--fast"])])
def test_the_recipes_refuse_a_bad_argument_in_one_line(script, args, tmp_path):
    """Checked before anything is written or trained (the script stops at its argument check)."""
    env = {**os.environ, "STABLEMO": str(tmp_path / "no-such-stablemo")}
    done = subprocess.run(["bash", str(REPO / "scripts/train" / script), *args], capture_output=True,
                          text=True, env=env, timeout=60)
    assert done.returncode == 2 and done.stdout == ""
    assert len(done.stderr.strip().splitlines()) == 1 and done.stderr.startswith(f"{script}: ")


def test_the_teacher_recipe_refuses_a_run_trained_past_its_stage(tmp_path):
    """A run folder whose checkpoints went past the stage's steps would be exported as it is: the
    script says so in one line instead (here the first stage's run at step 7000 of 6000), before any
    data is written or anything trained."""
    (tmp_path / "scripts/train").mkdir(parents=True)
    script = tmp_path / "scripts/train/train_demo.sh"
    script.write_text((REPO / "scripts/train/train_demo.sh").read_text())
    (tmp_path / "scripts/train/stages.sh").write_text((REPO / "scripts/train/stages.sh").read_text())
    (tmp_path / "data/synth").mkdir(parents=True)
    (tmp_path / "data/synth/Mean.npy").write_bytes(b"")
    (tmp_path / "data/synth/synth.json").write_text('{"rest": "varied"}')
    (tmp_path / "runs/demo/checkpoints").mkdir(parents=True)
    (tmp_path / "runs/demo/checkpoints/epoch=69-step=7000.ckpt").write_bytes(b"")
    env = {**os.environ, "STABLEMO": str(tmp_path / "no-such-stablemo"), "PYTHON": sys.executable}
    done = subprocess.run(["bash", str(script)], capture_output=True, text=True, env=env, timeout=60)
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.strip() == ("train_demo.sh: runs/demo has trained past stage 1's 6000 steps (step 7000); "
                                   "move it away to train the stage again")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data", "runs", "scripts"]


def test_the_varied_captions_variant_is_the_16k_run_with_other_captions():
    """configs/demo_variants/further_16k_varied.yaml trains on the 16k run's clips captioned in the
    varied vocabulary (`stablemo data synth ... --captions varied`: the same motions): only its data
    folder and run folder differ from further_16k.yaml."""
    plain = yaml.safe_load((REPO / "configs/demo_variants/further_16k.yaml").read_text())
    varied = yaml.safe_load((REPO / "configs/demo_variants/further_16k_varied.yaml").read_text())
    assert varied["data"].pop("data_dir") == "data/synth_16k_varied" and plain["data"].pop("data_dir") == "data/synth_16k"
    assert varied["trainer"].pop("default_root_dir") != plain["trainer"].pop("default_root_dir")
    assert varied == plain
    config = (REPO / "configs/demo_variants/further_16k_varied.yaml").read_text()
    assert "--num 16000 --seed 2 --rest varied --captions varied" in config


@pytest.mark.parametrize("variant, base, head", [("base16", 16, 64), ("base64", 64, 256)])
def test_the_width_demo_variants_change_only_the_width(variant, base, head):
    """configs/demo_variants/base16.yaml and base64.yaml (docs/training.md, "Behaviour against size
    and training time"): the recipe's network at half and twice the denoiser's width, everything else
    as shipped."""
    recipe = yaml.safe_load((REPO / "configs/demo.yaml").read_text())["model"]["model"]
    overlay = yaml.safe_load((REPO / f"configs/demo_variants/{variant}.yaml").read_text())["model"]["model"]
    assert overlay["text"] == recipe["text"]
    changed = {k: (recipe["denoiser"][k], v) for k, v in overlay["denoiser"].items() if recipe["denoiser"][k] != v}
    assert changed == {"base_channels": (32, base), "input_head": (128, head)}
    assert set(overlay["denoiser"]) == set(recipe["denoiser"])


def test_the_text_noise_variant_changes_only_the_text_noise():
    """configs/demo_variants/text_noise.yaml (docs/training.md, "Noise on the text features"): the
    recipe with feature_noise on the frozen text features, nothing else."""
    recipe = yaml.safe_load((REPO / "configs/demo.yaml").read_text())["model"]["model"]
    overlay = yaml.safe_load((REPO / "configs/demo_variants/text_noise.yaml").read_text())["model"]["model"]
    assert overlay["denoiser"] == recipe["denoiser"]
    assert overlay["text"] == {**recipe["text"], "feature_noise": 0.5}


@pytest.mark.parametrize("variant, head, kernel, heads", [(None, 128, 3, 4), ("no_mid_attention", 128, 3, 0),
                                                          ("input_head_k1", 128, 1, 0), ("no_input_head", 0, 1, 0)])
def test_demo_recipe_is_the_packaged_teachers_network_and_its_variants_change_only_their_part(variant, head, kernel, heads):
    from stablemo.inference.bundle import DEMO_BUNDLE
    from stablemo.training.module import DiffusionModule

    recipe = yaml.safe_load((REPO / "configs/demo.yaml").read_text())["model"]
    if variant is None:  # what the recipe trains is what the package ships
        assert json.loads((DEMO_BUNDLE / "config.json").read_text())["model"] == recipe["model"]
    else:
        overlay = yaml.safe_load((REPO / f"configs/demo_variants/{variant}.yaml").read_text())["model"]["model"]
        assert overlay["text"] == recipe["model"]["text"]
        own = ("input_head", "input_head_kernel", "mid_attention")  # what a variant may change
        assert {k: v for k, v in overlay["denoiser"].items() if k not in own} == \
            {k: v for k, v in recipe["model"]["denoiser"].items() if k not in own}
        recipe = {**recipe, "model": overlay}
    module = DiffusionModule(**recipe)
    stage = module.model.denoiser.input_stage
    assert (stage is None) == (head == 0)
    if head:
        convs = [conv for block in stage.blocks for conv in (block.conv1, block.conv2)]
        assert [(c.out_channels, c.kernel_size) for c in convs] == [(head, (kernel,))] * 4
    attention = module.model.denoiser.mid.self_attn
    assert (attention is None) == (heads == 0)
    if heads:
        assert attention.attn.num_heads == heads


@pytest.mark.parametrize("variant", ABLATION)
def test_ablation_variants_build_and_pad_consistently(variant):
    from stablemo.training.module import DiffusionModule

    common = yaml.safe_load((REPO / "configs/ablation/common.yaml").read_text())["model"]
    own = yaml.safe_load((REPO / f"configs/ablation/{variant}.yaml").read_text())["model"]
    module = DiffusionModule(**{**common, **own})
    pad = yaml.safe_load((REPO / "configs/ablation/common.yaml").read_text())["data"]["pad_multiple"]
    assert pad % module.model.length_multiple == 0


def test_bench_train_reports_speed_and_memory(tiny_data, tmp_path, capsys):
    import json

    from stablemo.cli.bench import main_train as bench_main

    cfg = tiny_config(tmp_path, tiny_data)
    out = tmp_path / "bench.json"
    assert bench_main(["--config", str(cfg), "--steps", "3", "--warmup", "1", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["timed_steps"] == 3 and result["it_per_s"] > 0 and result["peak_memory_mb"] > 50
    assert result["trainable_params"] == sum(
        p.numel() for p in make_module().model.parameters() if p.requires_grad)
    assert "it/s" in capsys.readouterr().out
    assert not (tmp_path / "checkpoints").exists()  # a benchmark writes no checkpoints


def test_ablate_script_writes_csv_table_and_chart(tiny_data, tmp_path):
    """scripts/train/ablate.py run as users run it (a process), two variants of two steps."""
    import csv

    script = [sys.executable, str(REPO / "scripts" / "train" / "ablate.py")]
    out = tmp_path / "ablation"
    done = subprocess.run([*script, "--data", str(tiny_data), "--out", str(out), "--steps", "2", "--batch-size", "4",
                           "--variants", "dit_xattn", "unet_base", "--", "--data.max_length=64"],
                          capture_output=True, text=True, cwd=REPO, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    rows = list(csv.DictReader(open(out / "ablation.csv")))
    assert [r["variant"] for r in rows] == ["unet_base", "dit_xattn"]  # paper order, not argument order
    assert all(float(r["val_loss"]) > 0 and int(r["steps"]) == 2 for r in rows)
    table = (out / "ablation.md").read_text()
    assert "| Dataset | Network | Val loss" in table and "Conv1D UNet baseline" in table and "+ cross-attention" in table
    assert (out / "ablation.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    missing = subprocess.run([*script, "--data", str(tmp_path / "missing")], capture_output=True, text=True,
                             cwd=REPO, check=False)
    assert missing.returncode == 2 and "folder not found" in missing.stderr and "Traceback" not in missing.stderr


@pytest.mark.slow  # a real process killed mid-run
def test_killed_run_resumes_from_its_last_checkpoint(tiny_data, tmp_path):
    import signal
    import time

    cfg = tiny_config(tmp_path, tiny_data, **{"trainer.max_steps": 100000, "checkpoint.every_n_train_steps": 1})
    last = tmp_path / "checkpoints" / "last.ckpt"
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONWARNINGS="ignore")
    proc = subprocess.Popen([sys.executable, "-m", "stablemo.cli", "fit", "--config", str(cfg)], cwd=REPO, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.time() + 600
        while time.time() < deadline and not (last.exists() and load_checkpoint_file(last)["global_step"] >= 5):
            time.sleep(0.2)
        proc.send_signal(signal.SIGKILL)  # no clean-up: possibly in the middle of a checkpoint write
    finally:
        proc.kill()
        proc.wait()
    step = load_checkpoint_file(last)["global_step"]  # complete and loadable, never truncated
    assert step >= 5
    _fit(cfg, "--ckpt_path=last", f"--trainer.max_steps={step + 2}", "--checkpoint.every_n_train_steps=5")
    resumed = load_checkpoint_file(last)  # written at the final step although 5 does not divide it
    assert resumed["global_step"] == step + 2
    assert resumed["stablemo"]["ema"]["num_updates"] == step + 2
    assert not list(last.parent.glob("last-v*.ckpt"))


def test_guard_catches_non_finite_gradients_with_a_finite_loss():
    class FakeStrategy:
        @staticmethod
        def reduce_boolean_decision(decision, all=True):
            return decision

    class FakeTrainer:
        strategy, precision_plugin, global_step, checkpoint_callback = FakeStrategy(), object(), 7, None

    module = nn.Linear(2, 2)
    module.last_train_loss = torch.tensor(0.5)
    module.weight.grad = torch.zeros(2, 2)
    module.bias.grad = torch.zeros(2)
    guard = NonFiniteGuard()
    guard.on_before_optimizer_step(FakeTrainer(), module, None)  # all finite: no error
    module.bias.grad[1] = float("inf")
    with pytest.raises(NonFiniteLossError, match=r"step 7 \(non-finite gradients in 1 tensors \(first: bias\)\)"):
        guard.on_before_optimizer_step(FakeTrainer(), module, None)
