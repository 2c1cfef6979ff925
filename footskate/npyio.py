"""Atomic .npy writes and pickle-free reads for footskate's commands (torch/numpy only, no stablemo)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from footskate.errors import FootskateError


def save_npy(path: Path, array: np.ndarray) -> None:
    """Write through a temporary sibling and rename: never a half-written file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp.npy")
    try:
        np.save(tmp, array)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def load_npy(path: Path) -> np.ndarray:
    """Read a .npy without pickle; errors name the file."""
    if not path.is_file():
        raise FootskateError(f"{path}: file not found")
    try:
        return np.load(path, allow_pickle=False)
    except Exception as err:
        raise FootskateError(f"{path}: not a readable .npy file ({err})") from None
