"""Checkpoint files that are never half-written and never unpickle arbitrary objects.

Lightning's own save goes through an fsspec transaction whose temporary file lives in the system
temp dir; when that is another filesystem the final move is a copy, and a kill during the copy
leaves a truncated `last.ckpt`. Here the temporary file sits beside the target (the project's
`atomic_open`: exclusive, random name), is fsync'ed, and is renamed over it (atomic on POSIX), so
a checkpoint path always holds a complete file.

A hard kill during a save leaves its temporary `.<name>.ckpt.<random>.partial` behind (tens of MB).
Such leftovers are removed when a run next touches the folder: on its first save there, and when
it resumes from a checkpoint there (`--ckpt_path last`), i.e. at the start of the next run.
"""

from __future__ import annotations

import contextlib
import os
import re
import time
from pathlib import Path
from typing import Any, Callable, Optional

import torch
from lightning.pytorch.plugins.io import TorchCheckpointIO

from stablemo.errors import StableMoError
from stablemo.io import atomic_open

PARTIAL_SUFFIX = ".partial"
# exactly what atomic_open(…/<name>.ckpt, suffix=".partial") creates: "." + name + "." + mkstemp's
# 8 random characters + suffix. Hidden and not *.ckpt, so never taken for a checkpoint.
PARTIAL_PATTERN = re.compile(r"^\.(?P<name>.+\.ckpt)\.[a-z0-9_]{8}\.partial$")
# A live save keeps its temp file locked (flock) and recently modified; a temp file younger than
# this is left alone even when unlocked (the instant between its creation and the lock).
PARTIAL_GRACE_S = 5.0
# Where locks are not supported, a partial is taken as abandoned only after this long.
PARTIAL_UNLOCKABLE_AGE_S = 24 * 3600.0

try:
    import fcntl
except ImportError:  # not POSIX: fall back to the age rule alone
    fcntl = None


def _lock(f) -> None:
    """Hold an exclusive advisory lock while writing; the kernel drops it when the process dies."""
    if fcntl is not None:
        with contextlib.suppress(OSError):  # a filesystem without locks: the age rule covers it
            fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)


def _held_by_a_live_writer(path: Path) -> Optional[bool]:
    """True if some process holds the lock, False if nobody does, None if locks are unsupported."""
    if fcntl is None:
        return None
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    except OSError:
        return True  # vanished or unreadable: not ours to judge
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return False
    except BlockingIOError:
        return True
    except OSError:
        return None
    finally:
        os.close(fd)  # also releases the lock we may have taken


def _is_stale(path: Path, now: float) -> bool:
    """Stale = of our naming, a regular file of ours, and no live process writing it."""
    try:
        st = path.lstat()
    except OSError:
        return False
    if not path.is_file() or path.is_symlink() or (hasattr(os, "getuid") and st.st_uid != os.getuid()):
        return False
    age = now - st.st_mtime
    if age < PARTIAL_GRACE_S:
        return False
    held = _held_by_a_live_writer(path)
    return held is False or (held is None and age > PARTIAL_UNLOCKABLE_AGE_S)


def remove_stale_partials(folder: str | os.PathLike) -> list[Path]:
    """Delete the checkpoint temp files a hard-killed save left in `folder`; returns what was removed.

    Only names of our own pattern (`.<name>.ckpt.<8 random chars>.partial`), only regular files owned
    by this user, only when no process holds the file's write lock (a live save holds it; the kernel
    releases it at a kill) and the file is older than PARTIAL_GRACE_S. Anything else is left alone.
    """
    folder = Path(folder)
    if not folder.is_dir():
        return []
    now = time.time()
    removed = []
    for entry in folder.iterdir():
        if PARTIAL_PATTERN.match(entry.name) and _is_stale(entry, now):
            with contextlib.suppress(FileNotFoundError):
                entry.unlink()
                removed.append(entry)
    return removed


class AtomicCheckpointIO(TorchCheckpointIO):
    def __init__(self) -> None:
        super().__init__()
        self._cleaned: set[Path] = set()

    def _clean_once(self, folder: Path) -> None:
        # once per folder and process: the first save (or the resume) of a run is its start
        folder = folder.resolve()
        if folder not in self._cleaned:
            self._cleaned.add(folder)
            remove_stale_partials(folder)

    def save_checkpoint(self, checkpoint: dict[str, Any], path, storage_options: Optional[Any] = None) -> None:
        if storage_options is not None:
            raise TypeError(f"{type(self).__name__} takes no storage_options, got {storage_options!r}")
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        self._clean_once(path.parent)
        with atomic_open(path, suffix=PARTIAL_SUFFIX, durable=True) as f:
            _lock(f)
            torch.save(checkpoint, f)

    def load_checkpoint(
        self, path, map_location: Optional[Callable] = lambda storage, loc: storage, weights_only: Optional[bool] = None
    ) -> dict[str, Any]:
        # weights_only is forced: a checkpoint is data, never code
        checkpoint = load_checkpoint_file(path, map_location=map_location)
        self._clean_once(Path(path).parent)  # a resume is the start of a run in that folder
        return checkpoint


def load_checkpoint_file(path, map_location: Any = "cpu") -> dict[str, Any]:
    path = Path(path)
    if not path.is_file():
        raise StableMoError(f"{path}: checkpoint not found")
    try:
        checkpoint = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as err:  # truncated zip, foreign pickle, ... all mean "not a loadable checkpoint"
        raise StableMoError(f"{path}: not a loadable StableMo checkpoint ({type(err).__name__}: {err})") from None
    if not isinstance(checkpoint, dict):
        raise StableMoError(f"{path}: not a Lightning checkpoint (top level is {type(checkpoint).__name__})")
    return checkpoint
