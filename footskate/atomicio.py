"""The project's one way to write a file or a folder: atomically, through an unpredictable temp name.

Every write in StableMo and footskate goes through this module (tests/test_bad_input_writes.py
greps the source tree for writes that bypass it). The rules it enforces:

* the temporary file (or folder) is created *exclusively* (`tempfile.mkstemp` / `mkdtemp`: O_EXCL,
  random name) in the target's own folder, so a planted file or symlink is never followed or
  overwritten, and the final `os.replace` is a same-filesystem rename (atomic on POSIX);
* on any failure the temporary is removed and the target is untouched;
* a folder target that is not empty is only replaced when the caller says it is its own kind
  (`replaceable`), so nothing we did not write is ever deleted.

Why it lives in footskate: footskate is the lower layer (torch/numpy only, it never imports
stablemo) while stablemo imports footskate, so this is the one place both can use. It needs the
standard library only; `stablemo.io` re-exports it with StableMo's error type for the checks.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import tempfile
from pathlib import Path
from typing import BinaryIO, Callable, Iterator, Optional

__all__ = [
    "atomic_dir", "atomic_open", "atomic_path", "output_dir_problem", "output_file_problem",
    "write_bytes", "write_text",
]


def _umask() -> int:
    # os.umask can only be read by setting it; restore it at once
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _new_file_mode(mode: Optional[int]) -> int:
    """mkstemp makes the file private (0600); give it what a plain open() would, unless told."""
    return (0o666 & ~_umask()) if mode is None else mode


def _unlink_quietly(path: str | os.PathLike) -> None:
    with contextlib.suppress(FileNotFoundError):
        os.unlink(path)


def _temp_file(path: Path, suffix: str) -> tuple[int, str]:
    path.parent.mkdir(parents=True, exist_ok=True)
    return tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, *, suffix: str = ".tmp", mode: Optional[int] = None,
                durable: bool = False) -> Iterator[BinaryIO]:
    """Open a binary file that becomes `path` when the block ends without an exception.

    Writes go to `.<name>.<random><suffix>` in `path`'s folder (created if missing); on success
    the file gets permission bits `mode` (default: 0o666 minus the umask), is fsync'ed when
    `durable`, and is renamed over `path` (a symlink at `path` is replaced, never followed).
    """
    path = Path(path)
    fd, tmp = _temp_file(path, suffix)
    try:
        with os.fdopen(fd, "wb") as f:
            yield f
            f.flush()
            os.fchmod(f.fileno(), _new_file_mode(mode))
            if durable:
                os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        _unlink_quietly(tmp)
        raise


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, suffix: Optional[str] = None) -> Iterator[Path]:
    """For writers that need a file *name* (an external program such as ffmpeg): yield the name
    of an empty temp file created exclusively beside `path`; rename it over `path` on success.
    In-process writers use `atomic_open` (a file object) instead."""
    path = Path(path)
    fd, tmp = _temp_file(path, (path.suffix or ".tmp") if suffix is None else suffix)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, _new_file_mode(None))
        os.replace(tmp, path)
    except BaseException:
        _unlink_quietly(tmp)
        raise


def write_bytes(path: str | os.PathLike, data: bytes, **kwargs) -> Path:
    """Atomically write `data` to `path` (keyword arguments as for `atomic_open`)."""
    with atomic_open(path, **kwargs) as f:
        f.write(data)
    return Path(path)


def write_text(path: str | os.PathLike, text: str, *, encoding: str = "utf-8", **kwargs) -> Path:
    """Atomically write `text` to `path` (keyword arguments as for `atomic_open`)."""
    return write_bytes(path, text.encode(encoding), **kwargs)


def _is_empty_dir(path: Path) -> bool:
    with os.scandir(path) as entries:
        return next(entries, None) is None


def _move_dir_into_place(tmp: Path, path: Path, replaceable: Optional[Callable[[Path], bool]]) -> None:
    if path.is_symlink() or (path.exists() and not path.is_dir()):
        raise FileExistsError(errno.EEXIST, "exists and is not a folder", str(path))
    if not path.exists() or _is_empty_dir(path):
        os.replace(tmp, path)  # rename(2) may replace an empty folder
        return
    if replaceable is None or not replaceable(path):
        raise FileExistsError(errno.ENOTEMPTY, "folder is not empty and is not ours to replace", str(path))
    # Two renames (POSIX has no portable atomic swap of folders): the old folder is moved aside
    # under an unpredictable name, put back if the second rename fails, deleted after success.
    old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=path.parent))
    os.replace(path, old)
    try:
        os.replace(tmp, path)
    except BaseException:
        os.replace(old, path)
        raise
    shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike, *, replaceable: Optional[Callable[[Path], bool]] = None) -> Iterator[Path]:
    """Build a folder that becomes `path` when the block ends without an exception.

    Yields a fresh folder `.<name>.<random>.partial` made exclusively beside `path`; write into it
    (with `atomic_open` etc.). On success it is renamed to `path` when `path` is absent or an empty
    folder, or when `replaceable(path)` says the existing folder is the caller's own kind (then the
    old one is removed). Anything else at `path` raises FileExistsError and is left untouched.
    On failure the temp folder is removed.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent))
    try:
        yield tmp
        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes it private (0700)
        _move_dir_into_place(tmp, path, replaceable)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


# ------------------------------------------------------------------------------ output checks
# Used by the commands *before* any compute: a bad --out must not cost a sampling run.


def _nearest_existing(folder: Path) -> Path:
    for candidate in (folder, *folder.parents):
        if os.path.lexists(candidate):
            return candidate
    return Path(".")


def _cannot_write_in(folder: Path) -> Optional[str]:
    """Why files cannot be created in `folder` (an existing path), or None."""
    if folder.is_symlink() and not folder.exists():
        return f"{folder} is a broken symbolic link"
    if not folder.is_dir():
        return f"{folder} is not a folder"
    if os.access(folder, os.W_OK | os.X_OK):
        return None
    try:
        read_only = bool(os.statvfs(folder).f_flag & os.ST_RDONLY)
    except OSError:
        read_only = False
    return f"{folder} is on a read-only file system" if read_only else f"no permission to write in {folder}"


def output_file_problem(path: str | os.PathLike) -> Optional[str]:
    """Why `path` cannot be written as a file (a one-line reason naming the path), or None.

    Creates nothing. Refused: an existing folder, a path under a regular file, a folder that is
    read-only or not writable (a missing folder is fine when its nearest existing ancestor is writable).
    """
    path = Path(path)
    if path.name in ("", ".", ".."):
        return f"{path}: not a file name"
    if path.is_dir():
        return f"{path}: is an existing folder; give a file name"
    problem = _cannot_write_in(_nearest_existing(path.parent))
    return f"{path}: {problem}" if problem else None


def output_dir_problem(path: str | os.PathLike) -> Optional[str]:
    """Why files cannot be written into folder `path` (one line naming the path), or None.

    Creates nothing. Refused: an existing non-folder, a path under a regular file, a read-only or
    unwritable folder (the nearest existing ancestor when `path` does not exist yet).
    """
    path = Path(path)
    if os.path.lexists(path) and not path.is_dir():
        return f"{path}: exists and is not a folder"
    problem = _cannot_write_in(_nearest_existing(path))
    return f"{path}: {problem}" if problem else None
