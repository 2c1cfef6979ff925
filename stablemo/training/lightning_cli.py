"""The LightningCLI behind `stablemo fit|validate|test --config configs/x.yaml` (stablemo.cli.train).

Everything is configured in YAML and overridable on the command line. Two callbacks are always
present and configurable under their own keys: `checkpoint` (ModelCheckpoint that also saves the
final step; save_last on) and
`guard` (NonFiniteGuard). The run folder `trainer.default_root_dir` holds a run's checkpoints
(`<root>/checkpoints`) and CSV log (`<root>/logs`) unless `checkpoint.dirpath` or `trainer.logger`
say otherwise. Checkpoints are written atomically and loaded with weights_only=True
(AtomicCheckpointIO) unless the config names another CheckpointIO plugin.
A config whose `model:` has a `class_path` trains that LightningModule instead of DiffusionModule
(e.g. `stablemo.eval.evaluator.EvaluatorModule` in configs/evaluator_*.yaml), with that class's own
defaults for every argument the config does not set; DiffusionModule is the default class only for
a command line whose configs and flags name none (stablemo.cli.train decides).
"""

from __future__ import annotations

import inspect
import re
import signal
import warnings
from pathlib import Path

from jsonargparse import Namespace
from lightning.fabric.utilities.exceptions import MisconfigurationException
from lightning.pytorch.cli import LightningCLI
from lightning.pytorch.plugins.io import CheckpointIO

from stablemo.errors import StableMoError, one_line, yaml_error_line
from stablemo.training.callbacks import FinalStepCheckpoint, NonFiniteGuard
from stablemo.training.checkpoint_io import AtomicCheckpointIO, load_checkpoint_file
from stablemo.training.module import DiffusionModule


class StableMoCLI(LightningCLI):
    """LightningCLI with StableMo's defaults, through its public hooks only."""

    def __init__(self, *args, default_model_class: type | None = None, **kwargs) -> None:
        """default_model_class: with subclass_mode_model, the LightningModule trained when the
        command line names none (the caller decides; stablemo.cli.train reads its command line)."""
        # `stablemo fit ...` hands LightningCLI its own argv; sys.argv must stay intact for DDP's
        # re-launch of the same command, so the "args and sys.argv both given" warning is noise here.
        warnings.filterwarnings("ignore", message="LightningCLI's args parameter is intended")
        self._default_model_class = default_model_class
        self._model_parsers: list = []  # filled by add_arguments_to_parser, read by parse_arguments
        super().__init__(*args, **kwargs)

    def parse_arguments(self, parser, args) -> None:
        """Parse as LightningCLI does, with two StableMo rules around it:

        - `default_model_class` (DiffusionModule for `stablemo fit`) is set only when the caller
          gives it, i.e. for a command line whose configs and flags name no class: jsonargparse keeps
          a default class's init_args (filled with its defaults) that the class a config switches to
          also accepts, so ControlNetTraining trained with DiffusionModule's cond_drop_prob=0.1 and
          weight_decay=0.01 instead of its own 0.0 while this default was always set.
        - A `--ckpt_path` file is read once with load_checkpoint_file before LightningCLI merges its
          hyperparameters: LightningCLI reads it with a bare torch.load before the Trainer and its
          CheckpointIO exist, where a truncated file or a pickle that weights_only refuses ends in a
          raw traceback; here it is one line naming the file.
        """
        if self.subclass_mode_model and self._default_model_class is not None:
            cls = self._default_model_class
            default = {"model": {"class_path": f"{cls.__module__}.{cls.__qualname__}"}}
            for sub in self._model_parsers:
                sub.set_defaults(default)
        super().parse_arguments(parser, args)
        subcommand = self.config.get("subcommand")
        ckpt_path = self.config[subcommand].get("ckpt_path") if subcommand else None
        if ckpt_path and Path(ckpt_path).is_file():  # "last", "best", URLs, missing files: the Trainer's
            load_checkpoint_file(ckpt_path)

    def add_arguments_to_parser(self, parser) -> None:
        parser.add_lightning_class_args(FinalStepCheckpoint, "checkpoint")
        parser.set_defaults({
            "checkpoint.save_last": True,
            "checkpoint.every_n_train_steps": 500,
            "checkpoint.save_top_k": 1,  # keep the newest step-named file beside last.ckpt
            # a resumed run (even with other checkpoint settings) keeps writing last.ckpt, not last-v1.ckpt
            "checkpoint.enable_version_counter": False,
        })
        # any LightningModule by `model.class_path` (e.g. ConsistencyDistillation); a command line
        # that names none trains the diffusion model (its default is set in parse_arguments)
        self._model_parsers.append(parser)
        parser.add_lightning_class_args(NonFiniteGuard, "guard")

    def before_instantiate_classes(self) -> None:
        """The run folder (`trainer.default_root_dir`) holds the run: checkpoints go to
        `<root>/checkpoints` and, when the config names no logger, the CSV log to `<root>/logs`, unless
        `checkpoint.dirpath` / `trainer.logger` are set explicitly. So `--trainer.default_root_dir DIR`
        moves the whole run, and `--ckpt_path last` finds the checkpoints of an earlier run in the
        same folder (Lightning's own default, `<root>/lightning_logs/version_N/checkpoints`, is a new
        folder per run, where "last" finds nothing to resume)."""
        config = self.config[self.subcommand] if self.subcommand else self.config
        root = config.get("trainer", {}).get("default_root_dir")
        if not root:
            return  # no run folder: Lightning's defaults
        if config.get("checkpoint") is not None and config["checkpoint"].get("dirpath") is None:
            config["checkpoint"]["dirpath"] = str(Path(root) / "checkpoints")
        if config["trainer"].get("logger") is None:
            config["trainer"]["logger"] = Namespace(class_path="lightning.pytorch.loggers.CSVLogger",
                                                    init_args=Namespace(save_dir=str(root), name="logs"))

    def _run_subcommand(self, subcommand: str) -> None:
        """Lightning answers a Ctrl-C during fit/validate/test with its own shutdown and `sys.exit(1)`,
        leaving SIGINT ignored: it is a KeyboardInterrupt again here, so that `stablemo` reports it
        as every command does (one line, exit 130), and a second Ctrl-C works again."""
        try:
            super()._run_subcommand(subcommand)
        except SystemExit:
            if not self.trainer.interrupted:
                raise
            signal.signal(signal.SIGINT, signal.default_int_handler)
            raise KeyboardInterrupt from None

    def instantiate_trainer(self, **kwargs):
        plugins = self._get(self.config_init, "trainer", default={}).get("plugins") or []
        plugins = list(plugins) if isinstance(plugins, (list, tuple)) else [plugins]
        if not any(isinstance(p, CheckpointIO) for p in plugins):
            plugins.append(AtomicCheckpointIO())
        kwargs.setdefault("plugins", plugins)
        if self._get(self.config_init, "trainer", default={}).get("strategy") == "fsdp":
            # Lightning's own "fsdp" (FSDP1) refuses CPUs; ours is FSDP2 with the networks' block policy
            from stablemo.training.sharding import FullShardStrategy

            if not isinstance(self.model, DiffusionModule):
                raise StableMoError(f"--trainer.strategy=fsdp: {type(self.model).__name__} has no sharding policy "
                                    "(only DiffusionModule is sharded); train it with ddp")
            kwargs.setdefault("strategy", FullShardStrategy())
        return super().instantiate_trainer(**kwargs)


def run_cli(model_class, argv: list[str], **kwargs) -> StableMoCLI:
    """StableMoCLI(model_class, MotionDataModule, args=argv, **kwargs) with every configuration
    error as one StableMoError line: a bad config or flag (instead of ~80 lines of usage), and a
    StableMoError raised while jsonargparse instantiates a class_path'd module (it wraps it)."""
    from jsonargparse import ArgumentError

    from stablemo.data import MotionDataModule

    try:
        return StableMoCLI(model_class, MotionDataModule, args=argv, parser_kwargs={"exit_on_error": False},
                           **kwargs)
    except StableMoError as err:
        err.args = (one_line(str(err)),)  # same exception type (NonFiniteLossError, ...), one line
        raise
    except ArgumentError as err:
        raise StableMoError(argument_error_line(str(err), argv)) from None
    except MisconfigurationException as err:
        # the Trainer's own checks of its settings (max_steps >= -1, ...) and of the run's set-up
        raise StableMoError(misconfiguration_line(str(err))) from None
    except (ValueError, TypeError) as err:
        # jsonargparse instantiates the class_path'd module inside its own checks and wraps what the
        # module's __init__ raised ("Does not validate against any of the Union subtypes"): a
        # StableMoError underneath is the message the user needs
        cause = _stablemo_cause(err)
        if cause is None:
            raise
        raise type(cause)(one_line(str(cause))) from None


def _stablemo_cause(err: BaseException) -> StableMoError | None:
    seen = set()
    while err is not None and id(err) not in seen:
        if isinstance(err, StableMoError):
            return err
        seen.add(id(err))
        err = err.__cause__ or err.__context__
    return None


def misconfiguration_line(message: str) -> str:
    """Lightning's MisconfigurationException as one line naming the flag: "`max_steps` must be a
    non-negative integer ..." -> "--trainer.max_steps: must be a non-negative integer ...". """
    from lightning.pytorch import Trainer

    message = one_line(message)
    match = re.match(r"`(\w+)`\s*(.*)", message)
    if match and match.group(1) in inspect.signature(Trainer.__init__).parameters:
        return f"--trainer.{match.group(1)}: {match.group(2)}"
    return message


def argument_error_line(message: str, argv: list[str]) -> str:
    """jsonargparse's error as one line: the dotted key at fault and the innermost reason, e.g.
    "model.lr: Expected a <class 'float'>. Got value: abc"; a file that is not a config at all is
    named (jsonargparse would quote its whole content)."""
    lines = [line.strip() for line in message.splitlines() if line.strip()]
    if not lines:
        return "invalid arguments"
    if lines[0].startswith("Problems parsing config"):
        broken = broken_yaml_file(argv)
        if broken is not None:
            return broken
    if lines[0].startswith("Unexpected config"):
        configs = [argv[i + 1] for i, a in enumerate(argv[:-1]) if a in ("--config", "-c")]
        return f"--config: {', '.join(configs) or 'a config'}: not a StableMo/LightningCLI config (a YAML mapping of settings)"
    keys, reasons = [], []
    for line in lines:
        if line.startswith('Parser key "') and line.count('"') >= 2:
            key, _, rest = line[len('Parser key "'):].partition('"')
            keys.append(key)
            rest = rest.lstrip(": ").strip()
            if rest:
                reasons.append(rest)
        elif not line.startswith(("- ", "Errors:", "Subtypes:", "Given value", "Does not validate")):
            reasons.append(line)
    # the most specific reason: an "Expected ..." line if there is one, else the innermost line
    reason = next((r for r in reversed(reasons) if r.startswith("Expected")), reasons[-1] if reasons else lines[-1])
    if keys[:1] == ["config"]:
        keys[0] = "--config"
    return f"{'.'.join(keys)}: {reason}" if keys else reason


def broken_yaml_file(argv: list[str]) -> str | None:
    """`--config: FILE: line N, column M: not valid YAML (...)` for the first file given on the
    command line that YAML cannot parse (jsonargparse parses it from a string, so its error says
    `in "<unicode string>"` and names no file); None when every file parses."""
    import yaml

    for flag, value in _flag_values(argv):
        path = Path(value)
        if not path.is_file():
            continue  # an inline YAML value, or not a file: jsonargparse's own message stands
        try:
            yaml.safe_load(path.read_text())
        except yaml.YAMLError as err:
            return f"{flag}: {yaml_error_line(path, err)}"
        except (OSError, UnicodeDecodeError) as err:
            return f"{flag}: {path}: cannot be read as YAML ({err})"
    return None


def _flag_values(argv: list[str]) -> list[tuple[str, str]]:
    """(flag, value) for every `--flag value` and `--flag=value` on a command line."""
    pairs = []
    for i, arg in enumerate(argv):
        if not arg.startswith("-"):
            continue
        key, eq, value = arg.partition("=")
        if eq:
            pairs.append((key, value))
        elif i + 1 < len(argv) and not argv[i + 1].startswith("--"):
            pairs.append((key, argv[i + 1]))
    return pairs
