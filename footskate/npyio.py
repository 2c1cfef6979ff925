"""Atomic .npy writes and pickle-free reads for footskate's commands (torch/numpy only, no stablemo)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from footskate.atomicio import atomic_open
from footskate.errors import FootskateError

NPY_MAGIC = b"\x93NUMPY"
ZIP_MAGIC = b"PK\x03\x04"  # .npz archives are zip files


def save_npy(path: str | Path, array: np.ndarray) -> None:
    """Write exactly `path` through an exclusive temp file and a rename: never a half-written file."""
    with atomic_open(path) as f:
        np.save(f, np.asarray(array), allow_pickle=False)


def _magic(path: Path) -> bytes:
    try:
        with open(path, "rb") as f:
            return f.read(len(NPY_MAGIC))
    except OSError as err:
        raise FootskateError(f"{path}: cannot read ({err.strerror})") from None


def _refuse_non_npy(magic: bytes, path: Path) -> None:
    """Checked before np.load: on other content numpy tries pickle and suggests allow_pickle=True."""
    if magic.startswith(ZIP_MAGIC):
        raise FootskateError(f"{path}: an .npz archive, not a .npy file; save one array with np.save")
    if not magic.startswith(NPY_MAGIC):
        raise FootskateError(f"{path}: not a .npy file ({'empty' if not magic else 'no NUMPY header'})")


def _numeric(load, path: Path) -> np.ndarray:
    try:
        array = load()
    except ValueError as err:
        if "allow_pickle" in str(err):  # an object array: numpy's message would hint at enabling pickle
            raise FootskateError(f"{path}: holds Python objects (an object array), not numbers; refused") from None
        raise FootskateError(f"{path}: not a readable .npy file ({err})") from None
    except (EOFError, OSError, SyntaxError) as err:  # truncated or unreadable
        raise FootskateError(f"{path}: not a readable .npy file ({err})") from None
    if not np.issubdtype(array.dtype, np.number):
        raise FootskateError(f"{path}: expected a numeric array, found dtype {array.dtype}")
    return array


def load_npy(path: str | Path, *, mmap: bool = False) -> np.ndarray:
    """Read a numeric .npy without pickle (memory-mapped with `mmap`); errors name the file and say
    what it is instead. The one .npy reader of both packages (stablemo.io.load_npy wraps it)."""
    path = Path(path)
    if not path.is_file():
        raise FootskateError(f"{path}: {'is a folder, not a .npy file' if path.is_dir() else 'file not found'}")
    _refuse_non_npy(_magic(path), path)
    return _numeric(lambda: np.load(path, allow_pickle=False, mmap_mode="r" if mmap else None), path)


# the header np.save writes for a C-ordered array of plain numbers, e.g.
# "{'descr': '<f4', 'fortran_order': False, 'shape': (179, 263), }" padded with spaces to "\n"
_PLAIN_HEADER = re.compile(r"\{'descr': '([<>|][fiu][1248])', 'fortran_order': False, 'shape': \(((?:\d+, ?)*\d*)\), \} *\n")


def _plain_npy(data: bytes | bytearray) -> np.ndarray | None:
    """The array of a .npy file np.save wrote for plain numbers, else None (for np.load to judge).

    np.load spends ~0.1 ms per file parsing the header with ast.literal_eval, as long as reading
    a whole 190 kB HumanML3D clip; `stablemo data shard` reads every clip of a dataset."""
    major = data[6:7]
    if major == b"\x01":
        start = 10 + int.from_bytes(data[8:10], "little")
    elif major in (b"\x02", b"\x03"):
        start = 12 + int.from_bytes(data[8:12], "little")
    else:
        return None
    found = _PLAIN_HEADER.fullmatch(data[10 if major == b"\x01" else 12 : start].decode("latin-1"))
    if found is None:
        return None
    shape = tuple(int(n) for n in found[2].split(",") if n.strip())
    dtype = np.dtype(found[1])
    count = math.prod(shape)
    if len(data) < start + count * dtype.itemsize:
        return None  # truncated: np.load's error names it
    array = np.frombuffer(data, dtype, count, start).reshape(shape)
    # writable, as np.load's: a bytearray's own memory (copying a clip costs as much as parsing it)
    return array if isinstance(data, bytearray) else array.copy()


def npy_from_bytes(data: bytes | bytearray, path: str | Path) -> np.ndarray:
    """load_npy for a file's bytes already read (`path` names it in errors). The array of a
    bytearray may share its memory: the caller hands the buffer over."""
    import io

    _refuse_non_npy(data[: len(NPY_MAGIC)], Path(path))
    plain = _plain_npy(data)
    if plain is not None:
        return plain
    return _numeric(lambda: np.load(io.BytesIO(data), allow_pickle=False), Path(path))
