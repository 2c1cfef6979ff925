"""`stablemo fit|validate|test --config configs/x.yaml [--trainer.max_steps=...]` via LightningCLI.

Everything is configured in YAML and overridable on the command line. Two callbacks are always
present and configurable under their own keys: `checkpoint` (ModelCheckpoint that also saves the
final step; save_last on) and
`guard` (NonFiniteGuard). Checkpoints are written atomically and loaded with weights_only=True
(AtomicCheckpointIO) unless the config names another CheckpointIO plugin.
A config whose `model:` has a `class_path` trains that LightningModule instead of DiffusionModule
(e.g. `stablemo.eval.evaluator.EvaluatorModule` in configs/evaluator_*.yaml).
"""

from __future__ import annotations

import warnings


from lightning.pytorch.cli import LightningCLI
from lightning.pytorch.plugins.io import CheckpointIO

from stablemo.lit.callbacks import FinalStepCheckpoint, NonFiniteGuard
from stablemo.lit.checkpoint_io import AtomicCheckpointIO
from stablemo.lit.module import DiffusionModule


class StableMoCLI(LightningCLI):
    def __init__(self, *args, **kwargs) -> None:
        # `stablemo fit ...` hands LightningCLI its own argv; sys.argv must stay intact for DDP's
        # re-launch of the same command, so the "args and sys.argv both given" warning is noise here.
        warnings.filterwarnings("ignore", message="LightningCLI's args parameter is intended")
        super().__init__(*args, **kwargs)

    def add_arguments_to_parser(self, parser) -> None:
        parser.add_lightning_class_args(FinalStepCheckpoint, "checkpoint")
        parser.set_defaults({
            "checkpoint.save_last": True,
            "checkpoint.every_n_train_steps": 500,
            "checkpoint.save_top_k": 1,  # keep the newest step-named file beside last.ckpt
            # a resumed run (even with other checkpoint settings) keeps writing last.ckpt, not last-v1.ckpt
            "checkpoint.enable_version_counter": False,
        })
        parser.add_lightning_class_args(NonFiniteGuard, "guard")

    def instantiate_trainer(self, **kwargs):
        plugins = self._get(self.config_init, "trainer", default={}).get("plugins") or []
        plugins = list(plugins) if isinstance(plugins, (list, tuple)) else [plugins]
        if not any(isinstance(p, CheckpointIO) for p in plugins):
            plugins.append(AtomicCheckpointIO())
        kwargs.setdefault("plugins", plugins)
        return super().instantiate_trainer(**kwargs)


def _names_model_class(argv: list[str]) -> bool:
    """True if a --config file or a --model.class_path override selects another LightningModule."""
    from pathlib import Path

    import yaml

    for i, arg in enumerate(argv):
        if arg.startswith("--model.class_path"):
            return True
        path = argv[i + 1] if arg == "--config" and i + 1 < len(argv) else arg.partition("=")[2] if arg.startswith("--config=") else None
        if path:
            try:
                cfg = yaml.safe_load(Path(path).read_text())
            except (OSError, yaml.YAMLError):
                continue  # LightningCLI reports unreadable configs itself
            if isinstance(cfg, dict) and isinstance(cfg.get("model"), dict) and "class_path" in cfg["model"]:
                return True
    return False


def _run(subcommand: str, argv: list[str]) -> int:
    from lightning.pytorch import LightningModule

    from stablemo.data import MotionDataModule

    subclass = _names_model_class(argv)
    StableMoCLI(
        LightningModule if subclass else DiffusionModule,
        MotionDataModule,
        subclass_mode_model=subclass,
        args=[subcommand, *argv],
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
