"""`stablemo fit|validate|test --config configs/x.yaml [--trainer.max_steps=...]` through the LightningCLI
(stablemo.training.lightning_cli); any failure of the input is one line naming the flag or file.

A command line whose configs and flags name no model class trains DiffusionModule; one that names a
class (ControlNetTraining, ConsistencyDistillation, the evaluator) gets that class with its own
defaults (`names_model_class`)."""

from __future__ import annotations

from pathlib import Path

from stablemo.training.lightning_cli import run_cli


def _run(subcommand: str, argv: list[str]) -> int:
    from lightning.pytorch import LightningModule

    from stablemo.training.module import DiffusionModule

    run_cli(
        LightningModule,
        [subcommand, *argv],
        subclass_mode_model=True,
        default_model_class=None if names_model_class(argv) else DiffusionModule,
        # the same config file may be reused for a resumed run in the same folder
        save_config_kwargs={"overwrite": True},
        auto_configure_optimizers=False,
    )
    return 0


def main_fit(argv: list[str]) -> int:
    return _run("fit", argv)


def main_validate(argv: list[str]) -> int:
    return _run("validate", argv)


def main_test(argv: list[str]) -> int:
    return _run("test", argv)


def names_model_class(argv) -> bool:
    """Whether a command line names the model's class itself: a `--config`/`-c` file (or YAML
    string) whose `model:` has a `class_path` (or is a class name), or a `--model.class_path` /
    `--model` flag that gives one. Anything unreadable counts as naming none (jsonargparse then
    reports it as before)."""
    argv = [str(a) for a in argv or []]
    i = 0
    while i < len(argv):
        arg = argv[i]
        key, eq, value = arg.partition("=")
        if key in ("--config", "-c", "--model", "--model.class_path"):
            if not eq:
                if i + 1 >= len(argv):
                    break
                value = argv[i + 1]
                i += 1
            if key == "--model.class_path":
                return True
            if key == "--model" and _model_value_names_class(value):
                return True
            if key in ("--config", "-c") and _config_names_model_class(_load_yaml(value)):
                return True
        i += 1
    return False


def _load_yaml(value: str):
    """A config file's content, or `value` itself as YAML (jsonargparse takes both); None if neither."""
    import yaml

    try:
        path = Path(value)
        text = path.read_text() if path.is_file() else value
        return yaml.safe_load(text)
    except (OSError, ValueError, yaml.YAMLError):
        return None


def _model_value_names_class(value) -> bool:
    if isinstance(value, dict):
        return bool(value.get("class_path"))
    if isinstance(value, str) and value.strip():
        loaded = _load_yaml(value)
        if isinstance(loaded, dict):
            return bool(loaded.get("class_path"))
        return isinstance(loaded, str)  # a class name (full or short)
    return False


def _config_names_model_class(config) -> bool:
    if not isinstance(config, dict):
        return False
    if "model" in config and _model_value_names_class(config["model"]):
        return True
    # a top-level config (before the subcommand) holds each subcommand's settings under its name
    return any(isinstance(config.get(sub), dict) and _model_value_names_class(config[sub].get("model"))
               for sub in ("fit", "validate", "test", "predict"))
