"""`stablemo fit|validate|test --config configs/x.yaml [--trainer.max_steps=...]` through the LightningCLI
(stablemo.training.lightning_cli); any failure of the input is one line naming the flag or file."""

from __future__ import annotations

from stablemo.training.lightning_cli import run_cli


def _run(subcommand: str, argv: list[str]) -> int:
    from lightning.pytorch import LightningModule

    run_cli(
        LightningModule,
        [subcommand, *argv],
        subclass_mode_model=True,
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
