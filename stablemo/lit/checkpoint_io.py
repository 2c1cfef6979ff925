"""Checkpoint files that are never half-written and never unpickle arbitrary objects.

Lightning's own save goes through an fsspec transaction whose temporary file lives in the system
temp dir; when that is another filesystem the final move is a copy, and a kill during the copy
leaves a truncated `last.ckpt`. Here the temporary file sits beside the target, is fsync'ed, and
is renamed over it (atomic on POSIX), so a checkpoint path always holds a complete file.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any, Callable, Optional

import torch
from lightning.pytorch.plugins.io import TorchCheckpointIO

from stablemo.errors import StableMoError


class AtomicCheckpointIO(TorchCheckpointIO):
    def save_checkpoint(self, checkpoint: dict[str, Any], path, storage_options: Optional[Any] = None) -> None:
        if storage_options is not None:
            raise TypeError(f"{type(self).__name__} takes no storage_options, got {storage_options!r}")
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        # hidden and not *.ckpt: a temp file left by a hard kill is never taken for a checkpoint
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as f:
                torch.save(checkpoint, f)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)

    def load_checkpoint(
        self, path, map_location: Optional[Callable] = lambda storage, loc: storage, weights_only: Optional[bool] = None
    ) -> dict[str, Any]:
        # weights_only is forced: a checkpoint is data, never code
        return load_checkpoint_file(path, map_location=map_location)


def load_checkpoint_file(path, map_location: Any = "cpu") -> dict[str, Any]:
    path = Path(path)
    if not path.is_file():
        raise StableMoError(f"{path}: checkpoint not found")
    try:
        checkpoint = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as err:  # truncated zip, foreign pickle, ... all mean "not a usable checkpoint"
        raise StableMoError(f"{path}: not a loadable StableMo checkpoint ({type(err).__name__}: {err})") from None
    if not isinstance(checkpoint, dict):
        raise StableMoError(f"{path}: not a Lightning checkpoint (top level is {type(checkpoint).__name__})")
    return checkpoint
