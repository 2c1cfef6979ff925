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

import sys
import warnings
from pathlib import Path

from lightning.pytorch.cli import LightningCLI
from lightning.pytorch.plugins.io import CheckpointIO

from stablemo.errors import StableMoError, one_line
from stablemo.lit.callbacks import FinalStepCheckpoint, NonFiniteGuard
from stablemo.lit.checkpoint_io import AtomicCheckpointIO, load_checkpoint_file
from stablemo.lit.module import DiffusionModule


class StableMoCLI(LightningCLI):
    def __init__(self, *args, **kwargs) -> None:
        # `stablemo fit ...` hands LightningCLI its own argv; sys.argv must stay intact for DDP's
        # re-launch of the same command, so the "args and sys.argv both given" warning is noise here.
        warnings.filterwarnings("ignore", message="LightningCLI's args parameter is intended")
        super().__init__(*args, **kwargs)

    def _parse_ckpt_path(self) -> None:
        """Merge the hyperparameters stored in `--ckpt_path` into the config, as LightningCLI does.

        LightningCLI reads the file here with a bare torch.load, before the Trainer and its
        CheckpointIO exist: a truncated file or a pickle that weights_only refuses ended in a raw
        traceback. The file is read with load_checkpoint_file instead (one error line naming it);
        the merge below is LightningCLI's own.
        """
        subcommand = self.config.get("subcommand")
        if not subcommand:
            return
        ckpt_path = self.config[subcommand].get("ckpt_path")
        if not (ckpt_path and Path(ckpt_path).is_file()):
            return  # "last", "best", URLs and missing files are resolved (and reported) by the Trainer
        hparams = load_checkpoint_file(ckpt_path).get("hyper_parameters") or {}
        if not isinstance(hparams, dict):
            return
        hparams = dict(hparams)
        hparams.pop("_instantiator", None)
        if not hparams:
            return
        if "_class_path" in hparams:
            hparams = {"class_path": hparams.pop("_class_path"), "dict_kwargs": hparams}
        try:
            self.config = self.parser.parse_object({subcommand: {"model": hparams}}, self.config)
        except SystemExit:
            sys.stderr.write("Parsing of ckpt_path hyperparameters failed!\n")
            raise

    def add_arguments_to_parser(self, parser) -> None:
        parser.add_lightning_class_args(FinalStepCheckpoint, "checkpoint")
        parser.set_defaults({
            "checkpoint.save_last": True,
            "checkpoint.every_n_train_steps": 500,
            "checkpoint.save_top_k": 1,  # keep the newest step-named file beside last.ckpt
            # a resumed run (even with other checkpoint settings) keeps writing last.ckpt, not last-v1.ckpt
            "checkpoint.enable_version_counter": False,
        })
        if self.subclass_mode_model:
            # any LightningModule by `model.class_path` (e.g. ConsistencyDistillation); a config that
            # gives only init arguments trains the diffusion model
            parser.set_defaults({"model": {"class_path": f"{DiffusionModule.__module__}.{DiffusionModule.__qualname__}"}})
        parser.add_lightning_class_args(NonFiniteGuard, "guard")

    def instantiate_trainer(self, **kwargs):
        plugins = self._get(self.config_init, "trainer", default={}).get("plugins") or []
        plugins = list(plugins) if isinstance(plugins, (list, tuple)) else [plugins]
        if not any(isinstance(p, CheckpointIO) for p in plugins):
            plugins.append(AtomicCheckpointIO())
        kwargs.setdefault("plugins", plugins)
        return super().instantiate_trainer(**kwargs)


def _run(subcommand: str, argv: list[str]) -> int:
    from lightning.pytorch import LightningModule

    from stablemo.data import MotionDataModule

    try:
        StableMoCLI(
            LightningModule,
            MotionDataModule,
            subclass_mode_model=True,
            args=[subcommand, *argv],
            # the same config file may be reused for a resumed run in the same folder
            save_config_kwargs={"overwrite": True},
            auto_configure_optimizers=False,
        )
    except StableMoError as err:
        err.args = (one_line(str(err)),)  # same exception type (NonFiniteLossError, ...), one line
        raise
    return 0


def main_fit(argv: list[str]) -> int:
    return _run("fit", argv)


def main_validate(argv: list[str]) -> int:
    return _run("validate", argv)


def main_test(argv: list[str]) -> int:
    return _run("test", argv)
