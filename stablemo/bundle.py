"""Inference bundles: a folder with a readable `config.json` and weights in `model.safetensors`.

A bundle is everything generation needs (network config, schedule, prediction type, text encoder
id, Mean/Std, skeleton) and nothing that could execute code when loaded.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import torch
from safetensors.torch import load_file, save_file

from stablemo.errors import StableMoError

BUNDLE_FORMAT = "stablemo-bundle"
BUNDLE_VERSION = 1
CONFIG_NAME = "config.json"
WEIGHTS_NAME = "model.safetensors"


@dataclass
class Bundle:
    path: Path
    config: dict
    state_dict: dict[str, torch.Tensor]


def save_bundle(out_dir: str | os.PathLike, config: dict, state_dict: dict[str, torch.Tensor]) -> Path:
    """Write a bundle atomically: built in a temporary sibling folder, then renamed into place."""
    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    config = {"format": BUNDLE_FORMAT, "version": BUNDLE_VERSION, **config}
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))
    try:
        tensors = {k: v.detach().to("cpu").contiguous() for k, v in state_dict.items()}
        save_file(tensors, str(tmp / WEIGHTS_NAME))
        (tmp / CONFIG_NAME).write_text(json.dumps(config, indent=2) + "\n")
        if out_dir.exists():
            old = out_dir.with_name(f".{out_dir.name}.old")
            shutil.rmtree(old, ignore_errors=True)
            os.replace(out_dir, old)
            os.replace(tmp, out_dir)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out_dir)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out_dir


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
    if config.get("format") != BUNDLE_FORMAT:
        raise StableMoError(f"{config_path}: not a StableMo bundle (format={config.get('format')!r})")
    if config.get("version", 0) > BUNDLE_VERSION:
        raise StableMoError(f"{config_path}: bundle version {config['version']} is newer than this StableMo")
    try:
        state_dict = load_file(str(weights_path))
    except Exception as err:  # safetensors raises its own error types for corrupt headers
        raise StableMoError(f"{weights_path}: unreadable safetensors file ({err})") from None
    return Bundle(path=path, config=config, state_dict=state_dict)
