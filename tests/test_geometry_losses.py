"""MDM's geometric training losses (stablemo.training.geometry) and their wiring into DiffusionModule."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from test_training import TINY_MODEL, make_module, tiny_config, write_random_dataset

from stablemo.data.synth import generate_motion
from stablemo.data.synth.body import neutral_pose, pose_to_joints
from stablemo.data.synth.writer import motion_rng
from stablemo.errors import StableMoError
from stablemo.motion import joints_to_features
from stablemo.motion.features import feature_slices
from stablemo.motion.skeleton import KIT
from stablemo.training.checkpoint_io import load_checkpoint_file
from stablemo.training.geometry import GEOMETRY_TERMS, GeometricLoss, geometry_weights
from stablemo.training.module import masked_mse

REPO = Path(__file__).resolve().parents[1]
ALL_ON = {name: 1.0 for name in GEOMETRY_TERMS}
FRAMES = 60


@pytest.fixture(scope="module")
def walks():
    """Three synthetic motions (features, HumanML3D layout) and Mean/Std measured on them."""
    feats = [joints_to_features(generate_motion(motion_rng(0, i)).joints) for i in range(3)]
    stacked = np.concatenate(feats)
    return feats, stacked.mean(0), stacked.std(0) + 1e-3


def normalised(feats: np.ndarray, mean, std) -> torch.Tensor:
    return torch.tensor((feats - mean) / std, dtype=torch.float32)


def batch_of(walks, frames: int = FRAMES) -> tuple[torch.Tensor, torch.Tensor]:
    feats, mean, std = walks
    x0 = torch.stack([normalised(f[:frames], mean, std) for f in feats])  # (B, T, D)
    return x0, torch.ones(x0.shape[:2], dtype=torch.bool)


def height_columns(skeleton: str) -> list[int]:
    """Feature columns holding joint heights: the root's and every ric y (heights are not root-relative)."""
    ric = feature_slices(skeleton)["ric"]
    return [3, *range(ric.start + 1, ric.stop, 3)]


def loss_for(walks, weights=ALL_ON) -> GeometricLoss:
    _, mean, std = walks
    return GeometricLoss(weights, "humanml3d", mean, std)


# ---------------------------------------------------------------------------------------------- the terms


def test_terms_vanish_for_the_exact_prediction(walks):
    x0, mask = batch_of(walks)
    terms = loss_for(walks).terms(x0, x0, mask)
    assert set(terms) == set(GEOMETRY_TERMS)
    for name in ("positions", "velocities", "bone_lengths"):
        assert torch.equal(terms[name], torch.zeros(3)), name
    # extracted features' rotation columns are those their joints imply, up to float rounding
    assert (terms["rotations"] < 1e-10).all()
    # the foot term compares the prediction with stillness, not with the data: its floor is the data's
    # own foot motion on frames labelled planted (HumanML3D's label allows up to 4.5 cm per frame)
    assert (terms["foot_contact"] >= 0).all()


def test_foot_term_is_zero_for_a_still_foot_and_follows_the_contact_labels(walks):
    _, mean, std = walks
    geo = loss_for(walks, {"foot_contact": 1.0, "positions": 1.0})
    still = joints_to_features(pose_to_joints(neutral_pose(FRAMES + 1)))  # (T, D), a body standing still
    contacts = feature_slices("humanml3d")["contacts"]
    assert (still[:, contacts] > 0.5).all()  # every foot planted on every frame
    lifted = still.copy()
    lifted[:, height_columns("humanml3d")] += 0.05  # the whole body 5 cm higher, still not moving
    mask = torch.ones(1, FRAMES, dtype=torch.bool)
    target = normalised(still, mean, std)[None]
    terms = geo.terms(normalised(lifted, mean, std)[None], target, mask)
    assert terms["foot_contact"].item() < 1e-15  # zero up to the rounding of (de)normalising
    # a mean over joint coordinates, as MDM's masked L2: one of three coordinates is 5 cm off
    torch.testing.assert_close(terms["positions"], torch.tensor([0.05 ** 2 / 3]), rtol=1e-3, atol=0)

    walking = normalised(walks[0][0][:FRAMES], mean, std)[None]  # feet that move
    assert geo.terms(walking, target, mask)["foot_contact"].item() > 1e-5
    airborne = still.copy()
    airborne[:, contacts] = 0.0  # the data says no foot is planted: moving feet cost nothing
    assert geo.terms(walking, normalised(airborne, mean, std)[None], mask)["foot_contact"].item() == 0.0


def test_perturbed_prediction_is_penalised_with_a_gradient(walks):
    x0, mask = batch_of(walks)
    geo = loss_for(walks)
    noise = torch.randn(x0.shape, generator=torch.Generator().manual_seed(0))
    exact = geo.terms(x0, x0, mask)["foot_contact"]
    for name in GEOMETRY_TERMS:
        pred = (x0 + 0.1 * noise).requires_grad_()
        value = geo.terms(pred, x0, mask)[name]
        assert (value > (exact if name == "foot_contact" else 0.0)).all(), name
        value.sum().backward()
        assert torch.isfinite(pred.grad).all() and pred.grad.abs().sum() > 0, name


def test_padding_contributes_nothing(walks):
    """Each clip scores the same alone as in a batch with other lengths and garbage in the padding,
    and no gradient reaches a padding frame."""
    feats, mean, std = walks
    geo = loss_for(walks)
    lengths, frames = [50, 37, 44], 56
    gen = torch.Generator().manual_seed(1)
    x0 = torch.zeros(3, frames, feats[0].shape[1])
    pred = 50.0 * torch.randn(x0.shape, generator=gen)  # padding frames hold garbage
    mask = torch.zeros(3, frames, dtype=torch.bool)
    for i, n in enumerate(lengths):
        x0[i, :n] = normalised(feats[i][:n], mean, std)
        pred[i, :n] = x0[i, :n] + 0.1 * torch.randn(n, x0.shape[2], generator=gen)
        mask[i, :n] = True
    pred.requires_grad_()
    batched = geo.terms(pred, x0, mask)
    sum(v.sum() for v in batched.values()).backward()
    assert torch.equal(pred.grad[~mask], torch.zeros_like(pred.grad[~mask]))
    for i, n in enumerate(lengths):
        alone = geo.terms(pred.detach()[i:i + 1, :n], x0[i:i + 1, :n], mask[i:i + 1, :n])
        for name in GEOMETRY_TERMS:
            torch.testing.assert_close(alone[name][0], batched[name][i], rtol=1e-5, atol=0, msg=name)


def test_weights_mean_the_same_in_metres_and_millimetres(walks):
    """KIT's millimetres are scaled to metres: the same 1 cm error costs the same on both skeletons."""
    _, mean, std = walks
    human = loss_for(walks, {"positions": 1.0})
    x0, mask = batch_of(walks)
    up = x0.clone()
    columns = height_columns("humanml3d")
    up[..., columns] += 0.01 / torch.tensor(std[columns])  # every joint 1 cm higher, in model space
    torch.testing.assert_close(human.terms(up, x0, mask)["positions"], torch.full((3,), 1e-4 / 3), rtol=1e-3, atol=0)

    rng = np.random.default_rng(0)
    kit_mean, kit_std = rng.normal(size=KIT.feature_dim), np.full(KIT.feature_dim, 0.5)
    kit = GeometricLoss({"positions": 1.0}, "kit", kit_mean, kit_std)
    x0 = torch.tensor(rng.normal(size=(2, 30, KIT.feature_dim)), dtype=torch.float32)
    up = x0.clone()
    up[..., height_columns("kit")] += 10.0 / 0.5  # every joint 10 mm higher
    mask = torch.ones(2, 30, dtype=torch.bool)
    torch.testing.assert_close(kit.terms(up, x0, mask)["positions"], torch.full((2,), 1e-4 / 3), rtol=1e-3, atol=0)


# ---------------------------------------------------------------------------------------------- configuration


@pytest.mark.parametrize("config, message", [
    ({"position": 1.0}, r"model\.geometry\.position: unknown term"),
    ({"positions": -1.0}, r"model\.geometry\.positions: the weight must be a finite number >= 0"),
    ({"velocities": float("nan")}, r"model\.geometry\.velocities: the weight"),
    ({"foot_contact": "1"}, r"model\.geometry\.foot_contact: the weight"),
    ({"bone_lengths": True}, r"model\.geometry\.bone_lengths: the weight"),
    ([1.0], r"model\.geometry: expected a mapping"),
])
def test_bad_geometry_config_is_one_clear_error(config, message):
    with pytest.raises(StableMoError, match=message):
        geometry_weights(config)
    with pytest.raises(StableMoError, match=message):
        make_module(geometry=config)


def test_geometry_config_keeps_only_the_terms_that_count():
    assert geometry_weights(None) == {} and geometry_weights({}) == {}
    assert geometry_weights(dict.fromkeys(GEOMETRY_TERMS, 0.0)) == {}
    assert geometry_weights({"bone_lengths": 0.5, "positions": 2}) == {"positions": 2.0, "bone_lengths": 0.5}


def test_cli_names_a_bad_geometry_key_in_one_line(tmp_path, capsys):
    from stablemo.cli import main as cli

    data = write_random_dataset(tmp_path / "data", num=6, splits=(4, 1))
    config = tiny_config(tmp_path / "run", data)
    code = cli(["fit", "--config", str(config), "--model.geometry={positions: 1, feet: 1}"])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(err) == 1 and "model.geometry.feet: unknown term" in err[0], err


def test_demo_geometry_overlay_changes_only_the_geometry_and_run_folder(capsys):
    from stablemo.cli.train import main_fit

    def printed(*files):
        args = [a for f in files for a in ("--config", str(REPO / "configs" / f))]
        with pytest.raises(SystemExit):
            main_fit([*args, "--print_config"])
        return yaml.safe_load(capsys.readouterr().out)

    base, overlay = printed("demo.yaml"), printed("demo.yaml", "demo_geometry.yaml")
    assert geometry_weights(overlay["model"]["init_args"]["geometry"])  # something is switched on
    assert base["model"]["init_args"].pop("geometry") is None
    overlay["model"]["init_args"].pop("geometry")
    assert overlay["trainer"].pop("default_root_dir") != base["trainer"].pop("default_root_dir")
    assert overlay == base


# ---------------------------------------------------------------------------------------------- the module


def step_inputs(module, walks):
    x0, mask = batch_of(walks)
    mask[1, 45:] = False
    texts, _, t, noise = module.training_inputs({"motion": x0, "text": ["a", "b", "c"]}, 0)
    return x0, mask, texts, t, noise


def with_data_info(module, walks):
    _, mean, std = walks
    module.data_info = {"skeleton": "humanml3d", "mean": mean.tolist(), "std": std.tolist()}
    return module


@pytest.mark.parametrize("geometry", [None, {}, dict.fromkeys(GEOMETRY_TERMS, 0.0)])
def test_without_geometry_the_loss_is_bit_identical_to_the_plain_objective(walks, geometry, monkeypatch):
    """The objective before this option existed: masked MSE of the output against its target, under
    the same dropout seed; nothing geometric is built or computed."""
    def not_built(*args, **kwargs):
        raise AssertionError("a geometric loss was built")

    monkeypatch.setattr(GeometricLoss, "__init__", not_built)
    module = with_data_info(make_module(geometry=geometry).train(), walks)
    x0, mask, texts, t, noise = step_inputs(module, walks)
    torch.manual_seed(5)
    terms = module.loss_terms(x0, mask, texts, t, noise)
    torch.manual_seed(5)
    x_t = module.schedule.q_sample(x0, t, noise)
    text, text_mask = module.model.encode_text(texts)
    before = masked_mse(module.model(x_t, t, text, text_mask, mask), x0, mask)
    assert set(terms) == {"simple"}
    assert torch.equal(module.objective(terms), before)


@pytest.mark.parametrize("prediction_type", ["sample", "epsilon", "v_prediction"])
def test_geometry_reads_the_clean_motion_estimate_of_either_parameterisation(walks, prediction_type, monkeypatch):
    module = with_data_info(make_module(geometry=ALL_ON, prediction_type=prediction_type), walks)
    x0, mask, texts, t, noise = step_inputs(module, walks)
    t = torch.tensor([10, 200, 600])  # where 1/sqrt(abar) stays moderate for the epsilon estimate
    exact = module.schedule.target(x0, noise, t, prediction_type)

    monkeypatch.setattr(module.model, "forward", lambda *args, **kwargs: exact)
    terms = module.loss_terms(x0, mask, texts, t, noise)
    reference = module.geometric_loss().terms(x0, x0, mask)
    for name in ("positions", "velocities", "bone_lengths"):
        assert terms[name].abs().max() < 1e-8, (name, terms[name])
    torch.testing.assert_close(terms["foot_contact"], reference["foot_contact"], rtol=1e-3, atol=1e-9)

    wrong = (exact + 0.05 * torch.randn(exact.shape, generator=torch.Generator().manual_seed(2))).requires_grad_()
    monkeypatch.setattr(module.model, "forward", lambda *args, **kwargs: wrong)
    terms = module.loss_terms(x0, mask, texts, t, noise)
    assert all((terms[name] > 0).all() for name in ("positions", "velocities", "bone_lengths"))
    # epsilon: the terms of x̂0 = (x_t - sqrt(1 - abar) eps) / sqrt(abar), not of the output itself;
    # v: those of x̂0 = sqrt(abar) x_t - sqrt(1 - abar) v
    x0_hat = module.schedule.predict_x0(wrong.detach(), module.schedule.q_sample(x0, t, noise), t, prediction_type)
    direct = module.geometric_loss().terms(x0_hat, x0, mask)
    for name in GEOMETRY_TERMS:
        torch.testing.assert_close(terms[name].detach(), direct[name], msg=name)
    total = module.objective(terms)
    torch.testing.assert_close(total, terms["simple"] + sum(terms[name] for name in GEOMETRY_TERMS))
    total.sum().backward()
    assert torch.isfinite(wrong.grad).all() and wrong.grad.abs().sum() > 0



@pytest.mark.parametrize("prediction_type", ["sample", "v_prediction"])
def test_loss_on_x0_scores_the_clean_motion_estimate(walks, prediction_type, monkeypatch):
    """loss_on: x0 trains any output parameterisation on the paper's x0 objective: for v,
    x0 - x̂0 = sqrt(1 - abar) (v̂ - v), so the loss is the v loss times 1 - abar per sample."""
    on_target = make_module(prediction_type=prediction_type)
    on_x0 = make_module(prediction_type=prediction_type, loss_on="x0")
    x0, mask, texts, t, noise = step_inputs(on_x0, walks)
    t = torch.tensor([10, 400, 990])
    out = torch.randn(x0.shape, generator=torch.Generator().manual_seed(5))
    for module in (on_target, on_x0):
        monkeypatch.setattr(module.model, "forward", lambda *args, **kwargs: out)
    target_loss = on_target.loss_terms(x0, mask, texts, t, noise)["simple"]
    x0_loss = on_x0.loss_terms(x0, mask, texts, t, noise)["simple"]
    if prediction_type == "sample":
        assert torch.equal(target_loss, x0_loss)
    else:
        abar = on_x0.schedule.alphas_cumprod[t].float()
        torch.testing.assert_close(x0_loss, target_loss * (1 - abar), rtol=1e-4, atol=1e-7)
    with pytest.raises(StableMoError, match="loss_on: expected one of"):
        make_module(loss_on="eps")

def test_geometry_without_dataset_facts_is_a_clear_error(walks):
    module = make_module(geometry={"positions": 1.0})
    x0, mask, texts, t, noise = step_inputs(module, walks)
    with pytest.raises(StableMoError, match="model.geometry: the geometric losses need the dataset's Mean/Std"):
        module.loss_terms(x0, mask, texts, t, noise)


def test_fit_logs_each_term_and_resumes_exactly(tmp_path):
    """Through `stablemo fit`: the terms are logged one by one; 4 steps straight == 2 + resume 2."""
    from test_training import _fit

    data = write_random_dataset(tmp_path / "data", num=12, splits=(8, 2))
    geometry = {"positions": 1.0, "velocities": 1.0, "foot_contact": 1.0, "bone_lengths": 0.5, "rotations": 0.5}
    model = {"model": TINY_MODEL, "ema_decay": 0.9, "lr": 1e-3, "geometry": geometry}
    straight, split = tmp_path / "straight", tmp_path / "split"
    _fit(tiny_config(straight, data, **{"model.geometry": geometry, "trainer.max_steps": 4}))
    config = tiny_config(split, data, **{"model.geometry": geometry, "trainer.max_steps": 4})
    _fit(config, "--trainer.max_steps=2")
    _fit(config, "--ckpt_path=last")
    a = load_checkpoint_file(straight / "checkpoints" / "last.ckpt")
    b = load_checkpoint_file(split / "checkpoints" / "last.ckpt")
    assert a["global_step"] == b["global_step"] == 4 and a["hyper_parameters"]["geometry"] == model["geometry"]
    for key in a["state_dict"]:
        assert torch.equal(a["state_dict"][key], b["state_dict"][key]), key
    for key in a["stablemo"]["ema"]["shadow"]:
        assert torch.equal(a["stablemo"]["ema"]["shadow"][key], b["stablemo"]["ema"]["shadow"][key]), key

    rows = list(csv.DictReader(open(straight / "logs" / "version_0" / "metrics.csv")))
    logged = [r for r in rows if r.get("train/loss")]
    assert len(logged) == 4
    for row in logged:
        simple = float(row["train/loss_simple"])
        parts = {name: float(row[f"train/{log}"]) for name, log in GEOMETRY_TERMS.items()}
        assert all(v > 0 for v in parts.values())
        expected = simple + sum(geometry[name] * value for name, value in parts.items())
        assert float(row["train/loss"]) == pytest.approx(expected, rel=1e-5)


# ---------------------------------------------------------------------------------------------- the ablation tools


@pytest.mark.parametrize("args, env, message", [
    (["tpu", "10", "out"], {}, "ACCELERATOR: cpu or gpu, got 'tpu'"),
    (["cpu", "ten", "out"], {}, "STEPS: a positive integer, got 'ten'"),
    (["cpu", "10", "out"], {"VARIANTS": "baseline legs"}, "VARIANTS: unknown 'legs'"),
    (["cpu", "10"], {}, "usage: scripts/train/geometry_ablation.sh ACCELERATOR STEPS OUT"),
])
def test_ablation_script_refuses_bad_arguments_before_any_work(tmp_path, args, env, message):
    import os
    import subprocess

    done = subprocess.run(["bash", str(REPO / "scripts/train/geometry_ablation.sh"), *args],
                          cwd=tmp_path, env={**os.environ, **env, "DATA": str(tmp_path / "missing")},
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and done.stderr.strip().splitlines() == [done.stderr.strip()], done.stderr
    assert message in done.stderr
    assert not (tmp_path / "missing").exists() and not (REPO / "out").exists()


def test_step_cost_script_times_both_objectives(tmp_path):
    import json
    import subprocess
    import sys

    data = write_random_dataset(tmp_path / "data", num=8, splits=(6, 1))
    base = tiny_config(tmp_path / "run", data)
    overlay = tmp_path / "geometry.yaml"
    overlay.write_text(yaml.safe_dump({"model": {"geometry": {"positions": 1.0, "foot_contact": 0.5}}}))
    out = tmp_path / "cost.json"
    done = subprocess.run([sys.executable, str(REPO / "scripts/train/geometry_step_cost.py"), "--configs", str(base),
                           str(overlay), "--rounds", "2", "--warmup", "1", "--threads", "1", "--json", str(out)],
                          cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(out.read_text())
    assert result["terms"] == {"positions": 1.0, "foot_contact": 0.5} and result["rounds"] == 2
    for clock in ("wall", "cpu"):
        assert result[clock]["plain_ms"] > 0 and result[clock]["geometry_ms"] > 0


def test_geometry_max_t_keeps_the_terms_below_it_only(walks, monkeypatch):
    """geometry_max_t: the geometric terms of samples at t >= max_t are zero, the others as without it;
    the simple loss is untouched; a bad value is one line."""
    plain = with_data_info(make_module(geometry={"positions": 1.0, "rotations": 1.0}), walks)
    capped = with_data_info(make_module(geometry={"positions": 1.0, "rotations": 1.0}, geometry_max_t=300), walks)
    capped.model.load_state_dict(plain.model.state_dict())
    x0, mask, texts, _, noise = step_inputs(plain, walks)
    t = torch.tensor([10, 299, 300])
    wrong = x0 + 0.05 * torch.randn(x0.shape, generator=torch.Generator().manual_seed(3))
    for module in (plain, capped):
        monkeypatch.setattr(module.model, "forward", lambda *args, **kwargs: wrong)
    a = plain.loss_terms(x0, mask, texts, t, noise)
    b = capped.loss_terms(x0, mask, texts, t, noise)
    assert torch.equal(a["simple"], b["simple"])
    for name in ("positions", "rotations"):
        assert (a[name] > 0).all(), name
        assert torch.equal(b[name][:2], a[name][:2]) and b[name][2] == 0, name
    for bad in (0, 1001, 2.5, True):
        with pytest.raises(StableMoError, match="geometry_max_t: a timestep in \\[1, 1000\\]"):
            make_module(geometry={"positions": 1.0}, geometry_max_t=bad)
