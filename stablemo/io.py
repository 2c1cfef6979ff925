"""Atomic file writes and safe loads: nothing half-written, nothing unpickled."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Iterator

import numpy as np

from stablemo.errors import StableMoError


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside `path`; on success rename it over `path`, else delete it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix or ".tmp", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        # mkstemp creates the file private (0600); give it the permissions a plain open() would
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def save_npy(path: str | os.PathLike, array: np.ndarray) -> None:
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.save(f, np.asarray(array))


def write_text(path: str | os.PathLike, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def load_npy(path: str | os.PathLike, *, mmap: bool = False) -> np.ndarray:
    """Load a numeric .npy without pickle; errors name the file."""
    path = Path(path)
    if not path.is_file():
        raise StableMoError(f"{path}: file not found")
    try:
        with open(path, "rb") as f:
            magic = f.read(6)
    except OSError as err:
        raise StableMoError(f"{path}: cannot read ({err})") from None
    if magic != b"\x93NUMPY" and not magic.startswith(b"PK\x03\x04"):
        # numpy would fall back to pickle here and suggest allow_pickle=True: never for us.
        raise StableMoError(f"{path}: not a .npy file ({'empty file' if not magic else 'no NUMPY header'})")
    try:
        array = np.load(path, allow_pickle=False, mmap_mode="r" if mmap else None)
    except Exception as err:  # numpy raises ValueError/EOFError/OSError for broken files
        raise StableMoError(f"{path}: not a readable .npy file ({err})") from None
    if not isinstance(array, np.ndarray):  # np.load returns an NpzFile for zip content
        raise StableMoError(f"{path}: not a .npy file (found an .npz archive)")
    if not np.issubdtype(array.dtype, np.number):
        raise StableMoError(f"{path}: expected a numeric array, found dtype {array.dtype}")
    return array
