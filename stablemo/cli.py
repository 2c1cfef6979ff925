"""`stablemo` console script: one table of subcommands, each a `main(argv)` in its own module.

Training commands (fit/validate/test) go to the LightningCLI; the others are small argparse
front-ends living next to the code they drive. Imports are lazy so `stablemo --help` is instant.
"""

from __future__ import annotations

import importlib
import sys

from stablemo.errors import StableMoError, one_line

# name -> (module, function, one-line help)
COMMANDS: dict[str, tuple[str, str, str]] = {
    "fit": ("stablemo.lit.cli", "main_fit", "train a model (LightningCLI)"),
    "validate": ("stablemo.lit.cli", "main_validate", "validate a model (LightningCLI)"),
    "test": ("stablemo.lit.cli", "main_test", "test a model (LightningCLI)"),
    "export": ("stablemo.lit.export", "main", "export a training checkpoint to an inference bundle"),
    "import-official": ("stablemo.official.command", "main", "convert a published StableMoFusion checkpoint to a bundle"),
    "generate": ("stablemo.generate", "main", "generate motions from text"),
    "edit": ("stablemo.edit", "main", "regenerate part of a motion (body parts, frames) with a new text"),
    "control-file": ("stablemo.control.command", "main", "write a joint-control file (.npz) from joints"),
    "render": ("stablemo.render", "main", "render features or joints (.npy) as an animation"),
    "data": ("stablemo.data.commands", "main", "dataset tools: synth, check, import-bvh"),
    "nets": ("stablemo.nets.summary", "main", "denoiser tools: summary"),
    "bench": ("stablemo.bench", "main", "benchmarks: aits, train"),
    "evaluate": ("stablemo.eval.command", "main", "evaluate a bundle against a dataset"),
    "footskate": ("stablemo.footskate_guidance", "main", "remove foot skating from a motion file"),
    "bvh": ("stablemo.bvh.command", "main", "write features or joints (.npy) as BVH or an SMPL-order pose (.npz)"),
    "serve": ("stablemo.serve.command", "main", "a local web page and JSON API for generating motions"),
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
    func = getattr(importlib.import_module(module_name), func_name)
    try:
        return int(func(rest) or 0)
    except StableMoError as err:
        print(f"stablemo {name}: error: {one_line(str(err))}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
