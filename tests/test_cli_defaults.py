"""`stablemo fit`: the model class a command line names gets its own defaults.

DiffusionModule used to be the parser's default `model.class_path` always; jsonargparse keeps a
default class's init_args (filled with its defaults) that a class named by the config also accepts,
so ControlNetTraining configs trained with DiffusionModule's cond_drop_prob=0.1 / weight_decay=0.01
instead of their own 0.0 / 0.0. Each case prints the config (`--print_config`, nothing is built)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from stablemo.cli.train import main_fit

REPO = Path(__file__).resolve().parents[1]
CONTROLNET = "stablemo.training.controlnet_module.ControlNetTraining"
DISTILL = "stablemo.training.distill_module.ConsistencyDistillation"
DIFFUSION = "stablemo.training.module.DiffusionModule"


def printed_model(argv: list[str], capsys) -> dict:
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_:
        main_fit([*argv, "--print_config"])
    assert exit_.value.code in (0, None)
    return yaml.safe_load(capsys.readouterr().out)["model"]


def write_config(tmp_path: Path, model: dict) -> Path:
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump({"model": model}))
    return path


def test_a_named_class_gets_its_own_defaults(tmp_path, capsys):
    cfg = write_config(tmp_path, {"class_path": CONTROLNET, "init_args": {"base": "x", "lr": 1e-3}})
    for argv in (["--config", str(cfg)], ["-c", str(cfg)], [f"--config={cfg}"],
                 [f"--model={CONTROLNET}", "--model.base=x", "--model.lr=1e-3"],
                 ["--model.class_path", CONTROLNET, "--model.init_args.base=x", "--model.lr=1e-3"]):
        model = printed_model(argv, capsys)
        assert model["class_path"] == CONTROLNET, argv
        args = model["init_args"]
        # ControlNetTraining's own defaults (DiffusionModule's are 0.1, 0.01, 0.9999)
        assert (args["cond_drop_prob"], args["weight_decay"], args["ema_decay"]) == (0.0, 0.0, 0.999), argv
        assert args["lr"] == 1e-3, argv
    # a flag after the config still overrides it
    model = printed_model(["--config", str(cfg), "--model.weight_decay=0.05"], capsys)
    assert model["init_args"]["weight_decay"] == 0.05 and model["init_args"]["cond_drop_prob"] == 0.0


def test_distillation_gets_its_own_defaults(tmp_path, capsys):
    cfg = write_config(tmp_path, {"class_path": DISTILL, "init_args": {"teacher": "x"}})
    args = printed_model(["--config", str(cfg)], capsys)["init_args"]
    # ConsistencyDistillation's own (DiffusionModule's: 0.9999, 2e-4, 0.01)
    assert (args["ema_decay"], args["lr"], args["weight_decay"]) == (0.95, 1e-4, 0.0)


def test_a_config_without_class_path_still_trains_the_diffusion_model(tmp_path, capsys):
    for argv in ([], ["--config", str(REPO / "configs" / "synth_small.yaml")],
                 ["--config", str(write_config(tmp_path, {"lr": 1e-3})), "--model.ema_decay=0.99"]):
        model = printed_model(argv, capsys)
        assert model["class_path"] == DIFFUSION, argv
        assert (model["init_args"]["cond_drop_prob"], model["init_args"]["weight_decay"]) == (0.1, 0.01), argv


@pytest.mark.parametrize("name", ["controlnet_lcm_synth.yaml", "controlnet_teacher_synth.yaml"])
def test_shipped_control_configs_print_their_own_defaults(name, capsys):
    """Neither config sets weight_decay: ControlNetTraining's 0.0, not DiffusionModule's 0.01."""
    model = printed_model(["--config", str(REPO / "configs" / "control" / name)], capsys)
    assert model["class_path"] == CONTROLNET
    assert model["init_args"]["weight_decay"] == 0.0
    assert model["init_args"]["cond_drop_prob"] == (0.1 if "teacher" in name else 0.0)  # the teacher's sets it


def test_names_model_class(tmp_path):
    from stablemo.cli.train import names_model_class

    named = write_config(tmp_path, {"class_path": CONTROLNET})
    plain = tmp_path / "plain.yaml"
    plain.write_text(yaml.safe_dump({"model": {"lr": 1.0}, "trainer": {"max_steps": 3}}))
    top = tmp_path / "top.yaml"
    top.write_text(yaml.safe_dump({"fit": {"model": {"class_path": CONTROLNET}}}))
    assert names_model_class(["fit", "--config", str(named)])
    assert names_model_class(["fit", "--config", str(plain), "-c", str(named)])
    assert names_model_class(["--config", str(top), "fit"])
    assert names_model_class(["fit", "--config", yaml.safe_dump({"model": {"class_path": CONTROLNET}})])
    assert names_model_class(["fit", "--model", "ControlNetTraining"])
    assert names_model_class(["fit", f"--model.class_path={CONTROLNET}"])
    assert not names_model_class(["fit", "--config", str(plain), "--model.lr=1"])
    assert not names_model_class(["fit", "--config", str(tmp_path / "missing.yaml")])
    assert not names_model_class(["fit", "--model", '{"lr": 1}'])
    assert not names_model_class(["fit", "--config"])
    assert not names_model_class([])


def test_the_bone_length_distillation_overlay_changes_only_the_geometry_and_the_run_folder(capsys):
    """configs/distill/lcm_synth_bones.yaml: the LCM recipe with the bone-length term, nothing else."""
    recipe = ["--config", str(REPO / "configs/distill/lcm_synth.yaml")]
    plain = printed_model(recipe, capsys)["init_args"]
    argv = [*recipe, "--config", str(REPO / "configs/distill/lcm_synth_bones.yaml")]
    bones = printed_model(argv, capsys)["init_args"]
    assert bones["geometry"] == {"bone_lengths": 20.0} and plain.get("geometry") is None
    assert {k for k in bones if bones[k] != plain.get(k)} == {"geometry"}
