"""Atomic file writes, output checks and safe loads: nothing half-written, nothing unpickled.

The write helpers are `footskate.atomicio`'s (the project's single implementation; see its
docstring for why it lives there), re-exported here so StableMo code imports them from one place:

    atomic_open(path, *, suffix=".tmp", mode=None, durable=False)  # context manager -> binary file
    atomic_path(path, *, suffix=None)    # context manager -> temp file name, for external programs
    atomic_dir(path, *, replaceable=None, manifest=None)  # context manager -> temp folder swapped in
    replace_dir(new, target)             # folder swap: the old or the new one at every instant
    write_text(path, text), write_bytes(path, data), save_npy(path, array)

and the checks every command runs on its output arguments before any compute:

    check_output_file(path, flag) -> Path   # raises StableMoError("--out: ...") when unwritable
    check_output_dir(path, flag) -> Path
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from footskate.atomicio import (  # noqa: F401  (re-exported)
    atomic_dir,
    atomic_open,
    atomic_path,
    default_signals,
    output_dir_problem,
    output_file_problem,
    ownership_problem,
    recover_dir,
    replace_dir,
    same_output,
    terminate_as_interrupt,
    write_bytes,
    write_text,
)
from footskate.errors import FootskateError
from footskate.npyio import load_npy as _load_npy
from footskate.npyio import save_npy  # noqa: F401  (re-exported: the one .npy writer)
from stablemo.errors import StableMoError


def check_output_file(path: str | os.PathLike, flag: str) -> Path:
    """Return `path` if a file can be written there, else raise StableMoError naming `flag`.

    One line, e.g. "--out: out/x.gif: out is not a folder". Refuses an existing folder, a path
    under a regular file, and a read-only or unwritable folder; creates nothing. Call it before
    the compute starts, so a bad argument costs nothing.
    """
    problem = output_file_problem(path)
    if problem:
        raise StableMoError(f"{flag}: {problem}")
    return Path(path)


def check_output_dir(path: str | os.PathLike, flag: str) -> Path:
    """Return `path` if files can be written into that folder (existing or not), else raise
    StableMoError naming `flag`. Refuses an existing non-folder, a path under a regular file, and
    a read-only or unwritable folder; creates nothing. Call it before the compute starts."""
    problem = output_dir_problem(path)
    if problem:
        raise StableMoError(f"{flag}: {problem}")
    return Path(path)


def read_text(path: str | os.PathLike, what: str) -> str:
    """A UTF-8 text file (`what`: "prompts file", "timeline file", …); errors name the file."""
    file = Path(path)
    if not file.is_file():
        raise StableMoError(f"{file}: {what} not found")
    try:
        return file.read_text(encoding="utf-8")
    except UnicodeDecodeError as err:
        raise StableMoError(f"{file}: not UTF-8 text (byte {err.start}); save the {what} as UTF-8") from None
    except OSError as err:
        raise StableMoError(f"{file}: cannot read ({err.strerror})") from None


def load_npy(path: str | os.PathLike, *, mmap: bool = False) -> np.ndarray:
    """Load a numeric .npy without pickle; errors name the file (footskate.npyio.load_npy, its
    error as StableMo's one line)."""
    try:
        return _load_npy(path, mmap=mmap)
    except FootskateError as err:
        raise StableMoError(str(err)) from None
