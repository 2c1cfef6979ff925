"""Inference bundles: a folder with a readable `config.json` and weights in `model.safetensors`.

A bundle is everything generation needs (network config, schedule, prediction type, text encoder
id, Mean/Std, skeleton) and nothing that could execute code when loaded.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import torch
from safetensors.torch import load_file
from safetensors.torch import save as safetensors_bytes

from stablemo.errors import StableMoError
from stablemo.io import atomic_dir, output_dir_problem, write_bytes, write_text
from stablemo.text.familiar import FILE as FAMILIAR_FILE
from stablemo.text.length import ENTRY as LENGTH_ENTRY
from stablemo.text.length import FILE as LENGTH_FILE

# the bundles that ship inside the package (stablemo/assets): the demo teacher, its 1-step student,
# the ControlNet on that student, and the synthetic benchmark's evaluator
ASSETS = Path(__file__).resolve().parents[1] / "assets"
DEMO_BUNDLE = ASSETS / "demo_bundle"
DEMO_STUDENT = ASSETS / "demo_student"
DEMO_CONTROLNET = ASSETS / "demo_controlnet"
EVALUATOR_SYNTH = ASSETS / "evaluator_synth"

BUNDLE_FORMAT = "stablemo-bundle"
BUNDLE_VERSION = 1
CONFIG_NAME = "config.json"
WEIGHTS_NAME = "model.safetensors"


@dataclass
class Bundle:
    path: Path
    config: dict
    state_dict: dict[str, torch.Tensor]


# a bundle's own files; familiar.safetensors (stablemo.text.familiar) is added by scripts/text/familiarity.py,
# length.safetensors (stablemo.text.length) by scripts/text/length_predictor.py
BUNDLE_FILES = frozenset({CONFIG_NAME, WEIGHTS_NAME, FAMILIAR_FILE, LENGTH_FILE})
# the config entries naming those added files: save_bundle writes neither file, so not their entries
ADDED_FILE_ENTRIES = ("familiarity", LENGTH_ENTRY)


def is_bundle(path: Path) -> bool:
    """A real folder whose config.json says it is a StableMo bundle (other files are not checked here)."""
    if path.is_symlink() or not path.is_dir():
        return False
    try:
        config = json.loads((path / CONFIG_NAME).read_text())
    except (OSError, ValueError):
        return False
    return isinstance(config, dict) and config.get("format") == BUNDLE_FORMAT


def _foreign_entries(path: Path) -> list[str]:
    return sorted(p.name for p in path.iterdir() if p.name not in BUNDLE_FILES)


def _is_cwd_or_above(path: Path) -> bool:
    if path.name in ("", ".", ".."):
        return True
    cwd, target = Path.cwd().resolve(), path.resolve()
    return target == cwd or target in cwd.parents


def check_bundle_target(path: str | os.PathLike, overwrite: bool = False, flag: str | None = None) -> Path:
    """Refuse, before anything is computed, a bundle target that writing would destroy or cannot reach.

    Allowed: a new path, an empty folder, or (with `overwrite`) an existing bundle holding nothing but
    bundle files. Everything else (a regular file, a folder with other content, the current folder or
    one above it, a symlink, an unwritable place) raises one StableMoError line naming `flag`/the path.
    """
    path = Path(path)
    prefix = f"{flag}: " if flag else ""
    hint = "pass --overwrite" if flag else "pass overwrite=True"

    def refuse(reason: str):
        raise StableMoError(f"{prefix}{path}: {reason}")

    if _is_cwd_or_above(path):
        refuse("is the current folder (or contains it); give a new folder name for the bundle")
    if path.is_symlink():
        refuse("is a symbolic link; give the bundle folder itself")
    if path.exists() and not path.is_dir():
        refuse("exists and is not a folder; nothing was written")
    if path.is_dir() and any(path.iterdir()):
        if not is_bundle(path):
            refuse("folder is not empty and is not a StableMo bundle; nothing was written (choose a new folder)")
        if not overwrite:
            refuse(f"holds a bundle already; {hint} to replace it")
        foreign = _foreign_entries(path)
        if foreign:
            refuse(f"holds files that are not part of a bundle ({', '.join(foreign[:3])}); not replaced")
    problem = output_dir_problem(path.parent)
    if problem:
        raise StableMoError(f"{prefix}{path}: cannot write the bundle beside it ({problem})")
    return path


def save_bundle(out_dir: str | os.PathLike, config: dict, state_dict: dict[str, torch.Tensor],
                overwrite: bool = False) -> Path:
    """Write a bundle atomically: built in a temporary sibling folder, then renamed into place.

    Refuses (StableMoError) any target `check_bundle_target` refuses; with `overwrite` an existing
    bundle (and nothing else) is replaced. Nothing is ever removed that a bundle write did not make.
    """
    out_dir = check_bundle_target(out_dir, overwrite)
    # the added files of another bundle (a student's teacher: its training captions, its length
    # predictor) are not written with it, so their entries are dropped: a bundle without them warns
    # about no prompt and takes the default length; give it its own with scripts/text/familiarity.py
    # and scripts/text/length_predictor.py (a student or ControlNet may share its teacher's)
    config = {"format": BUNDLE_FORMAT, "version": BUNDLE_VERSION,
              **{k: v for k, v in config.items() if k not in ADDED_FILE_ENTRIES}}
    tensors = {k: v.detach().to("cpu").contiguous() for k, v in state_dict.items()}

    def replaceable(path: Path) -> bool:  # re-checked at the rename: the folder may have changed
        return overwrite and is_bundle(path) and not _foreign_entries(path)

    return write_weights_folder(out_dir, config, tensors, replaceable, "bundle", added=(FAMILIAR_FILE, LENGTH_FILE))


def write_weights_folder(out_dir: Path, config: dict, tensors: dict[str, torch.Tensor],
                         replaceable, what: str, added: tuple[str, ...] = ()) -> Path:
    """`config.json` + `model.safetensors` as one folder, built beside `out_dir` and renamed into
    place (an existing folder only where `replaceable(path)` says so, checked at the rename).
    added: files a later step adds to such a folder, which go with the folder it replaces."""
    try:
        with atomic_dir(out_dir, replaceable=replaceable, derived=added) as tmp:
            write_bytes(tmp / WEIGHTS_NAME, safetensors_bytes(tensors))
            write_text(tmp / CONFIG_NAME, json.dumps(config, indent=2) + "\n")
    except FileExistsError:
        raise StableMoError(f"{out_dir}: changed while the {what} was written; nothing replaced") from None
    return out_dir


def bundle_or_demo(arg: str | os.PathLike | None, flag: str = "--bundle") -> Path:
    """The bundle folder a user named (`flag`), or the packaged demo teacher when none is given."""
    if arg is not None:
        path = Path(arg)
        if not path.is_dir():
            raise StableMoError(f"{flag}: {path}: bundle folder not found")
        return path
    if not (DEMO_BUNDLE / "config.json").is_file():
        raise StableMoError(
            f"no bundle given and the packaged demo model is missing ({DEMO_BUNDLE}). Train one "
            "(`stablemo fit --config <config.yaml>`), export it (`stablemo export CKPT --out DIR`) "
            "and pass `--bundle DIR`"
        )
    return DEMO_BUNDLE


def weights_sha256(path: str | os.PathLike) -> str:
    """SHA-256 of a bundle's weights file: what a derived bundle (a student, a ControlNet) records of
    the bundle it was trained on, so a later check can tell whether that bundle has since changed."""
    return hashlib.sha256((Path(path) / WEIGHTS_NAME).read_bytes()).hexdigest()


def skeleton_name(config: dict) -> str:
    """The skeleton a bundle's features use: its `skeleton`, else its dataset's (bundles exported
    before the key was written), else HumanML3D's."""
    return config.get("skeleton") or config.get("dataset", "humanml3d")


def load_bundle(path: str | os.PathLike) -> Bundle:
    """Read a bundle; every failure names the folder or file at fault."""
    path = Path(path)
    if not path.is_dir():
        raise StableMoError(f"{path}: bundle folder not found")
    config_path, weights_path = path / CONFIG_NAME, path / WEIGHTS_NAME
    for file in (config_path, weights_path):
        if not file.is_file():
            raise StableMoError(f"{file}: missing from the bundle")
    try:
        config = json.loads(config_path.read_text())
    except json.JSONDecodeError as err:
        raise StableMoError(f"{config_path}: not valid JSON ({err})") from None
    if not isinstance(config, dict):
        raise StableMoError(f"{config_path}: not a StableMo bundle (a JSON {type(config).__name__}, not an object)")
    if config.get("format") != BUNDLE_FORMAT:
        raise StableMoError(f"{config_path}: not a StableMo bundle (format={config.get('format')!r})")
    if config.get("version", 0) > BUNDLE_VERSION:
        raise StableMoError(f"{config_path}: bundle version {config['version']} is newer than this StableMo")
    try:
        state_dict = load_file(str(weights_path))
    except Exception as err:  # safetensors raises its own error types for corrupt headers
        raise StableMoError(f"{weights_path}: unreadable safetensors file ({err})") from None
    return Bundle(path=path, config=config, state_dict=state_dict)
