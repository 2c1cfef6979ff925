"""`stablemo` console script: one table of subcommands, each a `main(argv)` in a module of this package.

Training commands (fit/validate/test) go to the LightningCLI (stablemo.cli.train); the others are
small argparse front-ends over the library. Imports are lazy so `stablemo --help` is instant. Bad
input is one line and exit 2, a refusal of the machine (full disk, read-only) one line and exit 1,
Ctrl-C one line and exit 130.
"""

from __future__ import annotations

import errno
import importlib
import os
import sys
import warnings

from stablemo.errors import StableMoError, one_line

# name -> (module of stablemo.cli, function, one-line help): every subcommand's options live in this
# package; the modules below it never parse argv nor import a command module
COMMANDS: dict[str, tuple[str, str, str]] = {
    "fit": ("train", "main_fit", "train a model (LightningCLI)"),
    "validate": ("train", "main_validate", "validate a model (LightningCLI)"),
    "test": ("train", "main_test", "test a model (LightningCLI)"),
    "export": ("export", "main", "export a training checkpoint to an inference bundle"),
    "import-official": ("official", "main", "convert a published StableMoFusion checkpoint to a bundle"),
    "generate": ("generate", "main", "generate motions from text"),
    "edit": ("edit", "main", "regenerate part of a motion (body parts, frames) with a new text"),
    "control-file": ("control_file", "main", "write a joint-control file (.npz) from joints"),
    "render": ("render", "main", "render features or joints (.npy) as an animation"),
    "data": ("data", "main", "dataset tools: synth, check, import-bvh"),
    "nets": ("nets", "main", "denoiser tools: summary"),
    "bench": ("bench", "main", "benchmarks: aits, stream, train, footskate"),
    "evaluate": ("evaluate", "main", "evaluate a bundle against a dataset"),
    "behaviour": ("behaviour", "main", "does each motion do what its prompt says (counts, sides, turns, order)"),
    "footskate": ("footskate", "main", "remove foot skating from a motion file"),
    "bvh": ("bvh", "main", "write features or joints (.npy) as BVH or an AMASS-style SMPL-X pose (.npz)"),
    "serve": ("serve", "main", "a local web page and JSON API for generating motions"),
    "retarget": ("retarget", "main", "put a motion (.npy or .bvh) on any humanoid rig (BVH, glTF/GLB, FBX)"),
    "vendor": ("vendor", "main", "install pinned npm packages: three (the page), gltf-validator (tests)"),
}


def _usage() -> str:
    width = max(map(len, COMMANDS))
    lines = ["usage: stablemo <command> [options]", "", "commands:"]
    lines += [f"  {name:<{width}}  {help_}" for name, (_, _, help_) in COMMANDS.items()]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(_usage())
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"stablemo: unknown command {name!r}\n\n{_usage()}", file=sys.stderr)
        return 2
    module_name, func_name, _ = COMMANDS[name]
    # torch warns about the protocol of a raw pickle before refusing it: the refusal is the one line
    warnings.filterwarnings("ignore", message="Detected pickle protocol", category=UserWarning)
    try:
        func = getattr(importlib.import_module(f"stablemo.cli.{module_name}"), func_name)
        return int(func(rest) or 0)
    except StableMoError as err:
        print(f"stablemo {name}: error: {one_line(str(err))}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        # Ctrl-C: every write is atomic (stablemo.io), so nothing half-written is left to report
        print(f"stablemo {name}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as err:
        os_error = _os_error_in(err)
        if os_error is None:
            raise  # a bug, not the input or the machine: its traceback is what a report needs
        print(f"stablemo {name}: error: {os_error_line(os_error, err)}", file=sys.stderr)
        return EXIT_ENVIRONMENT


# Exit codes: 2 is bad input (StableMoError, argparse); these are the machine's side.
EXIT_ENVIRONMENT = 1  # the disk is full, read-only, over quota, ...: the same command may work elsewhere
EXIT_INTERRUPTED = 130  # 128 + SIGINT, as shells report a Ctrl-C'd command

_REASONS = {
    errno.ENOSPC: "no space left on device",
    errno.EDQUOT: "disk quota exceeded (no space left on device for this user)",
    errno.EROFS: "read-only file system",
}


def _os_error_in(err: BaseException) -> OSError | None:
    """The OSError behind `err`: itself, or the one a RuntimeError was raised while handling
    (torch.save reports a full disk so: "PytorchStreamWriter failed ..." during the OSError)."""
    if isinstance(err, OSError):
        return err
    inner = err.__cause__ or err.__context__
    return inner if isinstance(err, RuntimeError) and isinstance(inner, OSError) else None


def os_error_line(os_error: OSError, raised: BaseException) -> str:
    """`<path>: <what the machine refused>` for an OSError met while reading or writing."""
    reason = _REASONS.get(os_error.errno) or (os_error.strerror or str(os_error) or type(os_error).__name__)
    if os_error.errno is None and "written" in str(os_error):  # numpy's short write: the disk filled up
        reason = f"write failed ({os_error}): no space left on device?"
    path = os_error.filename or _target_of_atomic_write(raised)
    return f"{path}: {reason[0].lower() + reason[1:]}" if path else reason


def _target_of_atomic_write(err: BaseException) -> str | None:
    """The file being written when `err` was raised, for an OSError that names none (write() on
    an open file, numpy's short write): the `path` of the innermost StableMo or footskate frame
    that holds one, i.e. the writer's target (save_npy, write_text, save_checkpoint, ...).
    atomic_open's own frame is not in the traceback: contextlib puts the original one back."""
    tb, target = err.__traceback__, None
    while tb is not None:
        frame = tb.tb_frame
        value = frame.f_locals.get("path")
        if frame.f_globals.get("__name__", "").startswith(_OWN_PACKAGES) and isinstance(value, (str, os.PathLike)):
            target = os.fspath(value)
        tb = tb.tb_next
    return target


_OWN_PACKAGES = ("stablemo.", "footskate.")


if __name__ == "__main__":
    sys.exit(main())
