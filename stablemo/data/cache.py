"""Read a split once, keep it as one memory-mapped float32 file.

Opening 30k small .npy files takes seconds to minutes on a cold disk, so the first read of a split
validates every clip and writes two files into a cache folder:

    <split>.<dataset>.<token>.f32    all clips' features concatenated, raw float32 (frames, D)
    <split>.<dataset>.json           ids, lengths, captions, skipped files, and a fingerprint

The fingerprint hashes the split file and (size, mtime) of every feature and caption file, so any
change invalidates the cache. The JSON index is written last and atomically: it is the commit
point, and it names the data file it belongs to (a random token), so a reader never pairs an index
with a half-written or foreign data file.
"""

from __future__ import annotations

import hashlib
import json
import os
import secrets
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from footskate.errors import FootskateError
from footskate.npyio import npy_from_bytes
from stablemo.data.layout import (
    FEATURE_DIR,
    TEXT_DIR,
    Caption,
    DatasetSpec,
    check_root,
    feature_path,
    parse_captions,
    read_split,
    split_path,
    text_path,
)
from stablemo.errors import StableMoError
from stablemo.io import atomic_open, write_text

CACHE_VERSION = 1
CACHE_DIRNAME = ".stablemo_cache"
CACHE_DTYPE = np.dtype("<f4")  # explicit little-endian float32: the file means the same on any machine


@dataclass
class SplitData:
    """Every readable clip of one split: raw (unnormalised) features and captions."""

    root: Path
    split: str
    ids: list[str]
    lengths: np.ndarray  # (N,) int64 frames per clip
    offsets: np.ndarray  # (N,) int64 first row of each clip in `features`
    features: np.ndarray  # (total_frames, D) float32, usually a read-only memmap
    captions: list[list[Caption]]
    problems: list[str] = field(default_factory=list)  # one message per skipped clip
    from_cache: bool = False

    def motion(self, index: int) -> np.ndarray:
        """Features of clip `index`: (T, D) view into the concatenated array."""
        start = int(self.offsets[index])
        return self.features[start : start + int(self.lengths[index])]

    def __len__(self) -> int:
        return len(self.ids)

    def __getstate__(self) -> dict:
        # DataLoader workers started with "spawn" pickle the dataset: send the cache file's name,
        # not gigabytes of mapped features.
        state = dict(self.__dict__)
        if isinstance(self.features, np.memmap) and self.features.filename:
            state["features"] = ("memmap", self.features.filename, self.features.shape)
        return state

    def __setstate__(self, state: dict) -> None:
        features = state["features"]
        if isinstance(features, tuple) and features[0] == "memmap":
            state["features"] = np.memmap(features[1], dtype=CACHE_DTYPE, mode="r", shape=features[2])
        self.__dict__.update(state)


def validate_features(array: np.ndarray, path: Path, spec: DatasetSpec) -> np.ndarray:
    """(T, D) finite float features or a StableMoError naming `path`."""
    if array.ndim != 2 or array.shape[1] != spec.feature_dim:
        raise StableMoError(
            f"{path}: expected features of shape (T, {spec.feature_dim}) for {spec.name}, found {tuple(array.shape)}"
        )
    if array.shape[0] == 0:
        raise StableMoError(f"{path}: clip has no frames")
    array = np.asarray(array, dtype=np.float32)
    # max and min carry any NaN or Inf, without isfinite's (T, D) mask for every clip
    if not (np.isfinite(array.max()) and np.isfinite(array.min())):
        finite = np.isfinite(array)
        frame = int(np.argmin(finite.all(axis=1)))
        raise StableMoError(f"{path}: {int((~finite).sum())} NaN/Inf value(s), first in frame {frame}")
    return array


def parse_npy(data: bytes, path: Path) -> np.ndarray:
    """A real-valued numeric array from the bytes of the .npy file `path` (named in errors); never
    unpickles (footskate.npyio.npy_from_bytes, the one .npy reader)."""
    try:
        array = npy_from_bytes(data, path)
    except FootskateError as err:
        raise StableMoError(str(err)) from None
    if not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        raise StableMoError(f"{path}: expected a real-valued numeric array, found dtype {array.dtype}")
    return array


def read_buffer(path: Path) -> bytearray:
    """A whole file in a bytearray: parse_npy's array then uses it in place (no copy of the clip)."""
    with open(path, "rb", buffering=0) as f:
        buffer = bytearray(os.fstat(f.fileno()).st_size)
        view, got = memoryview(buffer), 0
        while got < len(buffer):
            n = f.readinto(view[got:])
            if not n:  # the file shrank since fstat
                del view
                del buffer[got:]
                return buffer
            got += n
        del view
        buffer += f.read()  # the file grew since fstat
        return buffer


def fetch_clip(root: Path, clip_id: str, split: str) -> tuple[bytearray, bytes]:
    """Raw bytes of a clip's feature and caption files (the I/O part; safe to run in threads)."""
    out = []
    for path, kind in ((feature_path(root, clip_id), "feature"), (text_path(root, clip_id), "caption")):
        try:
            out.append(read_buffer(path) if kind == "feature" else path.read_bytes())
        except FileNotFoundError:
            raise StableMoError(f"{path}: listed in {split}.txt but the {kind} file does not exist") from None
        except OSError as err:
            raise StableMoError(f"{path}: cannot read {kind} file ({err})") from None
    return out[0], out[1]


def decode_clip(root: Path, clip_id: str, spec: DatasetSpec, raw: tuple[bytes, bytes]) -> tuple[np.ndarray, list[Caption]]:
    """Validated features (T, D) float32 and captions from fetch_clip's bytes.

    Kept out of the reader threads: np.load parses the header with ast.literal_eval, and
    CPython 3.11's compiler is not thread-safe.
    """
    fpath = feature_path(root, clip_id)
    features = validate_features(parse_npy(raw[0], fpath), fpath, spec)
    return features, parse_captions(raw[1], text_path(root, clip_id))


def read_clip(root: Path, clip_id: str, spec: DatasetSpec, split: str) -> tuple[np.ndarray, list[Caption]]:
    """Validated features (T, D) float32 and captions of one clip."""
    return decode_clip(root, clip_id, spec, fetch_clip(root, clip_id, split))


def default_cache_dir(root: Path) -> Path:
    """`<root>/.stablemo_cache` when the dataset folder is writable, else a per-user cache folder."""
    if os.access(root, os.W_OK):
        return root / CACHE_DIRNAME
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    key = hashlib.sha1(str(root.resolve()).encode()).hexdigest()[:16]
    return base / "stablemo" / "datasets" / key


def fingerprint(root: Path, split: str, ids: list[str], spec: DatasetSpec) -> str:
    """Hash of the split file and the (size, mtime) of every clip's files; missing files count too."""
    h = hashlib.sha1(f"v{CACHE_VERSION} {spec.name} {spec.feature_dim}\n".encode())
    # Plain strings, not pathlib: this runs over ~60k paths on every start.
    base = os.fspath(root)
    paths = [os.fspath(split_path(root, split))]
    paths += [f"{base}/{FEATURE_DIR}/{clip_id}.npy" for clip_id in ids]
    paths += [f"{base}/{TEXT_DIR}/{clip_id}.txt" for clip_id in ids]
    parts = []
    for path in paths:
        try:
            st = os.stat(path)
            parts.append(f"{st.st_size} {st.st_mtime_ns}")
        except OSError:
            parts.append("missing")
    h.update("\n".join(parts).encode())
    return h.hexdigest()


def _caption_objs(rows: list[list]) -> list[Caption]:
    return [Caption._make(row) for row in rows]


def _index_path(cache_dir: Path, split: str, spec: DatasetSpec) -> Path:
    return cache_dir / f"{split}.{spec.name}.json"


def _try_load_cache(cache_dir: Path, root: Path, split: str, spec: DatasetSpec, fp: str) -> SplitData | None:
    index_path = _index_path(cache_dir, split, spec)
    try:
        index = json.loads(index_path.read_text())
        if index.get("version") != CACHE_VERSION or index.get("fingerprint") != fp:
            return None
        data_path = cache_dir / index["data_file"]
        total = int(index["total_frames"])
        if data_path.stat().st_size != total * spec.feature_dim * 4:
            return None
        lengths = np.asarray(index["lengths"], dtype=np.int64)
        features = _open_features(data_path, total, spec.feature_dim)
    except (OSError, ValueError, KeyError, TypeError):
        return None  # absent, stale or damaged cache: rebuild
    return SplitData(
        root=root,
        split=split,
        ids=list(index["ids"]),
        lengths=lengths,
        offsets=_offsets(lengths),
        features=features,
        captions=[_caption_objs(rows) for rows in index["captions"]],
        problems=list(index["problems"]),
        from_cache=True,
    )


def _open_features(path: Path, total: int, dim: int) -> np.ndarray:
    if total == 0:
        return np.zeros((0, dim), np.float32)
    return np.memmap(path, dtype=CACHE_DTYPE, mode="r", shape=(total, dim))


def _offsets(lengths: np.ndarray) -> np.ndarray:
    return np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64) if len(lengths) else lengths.copy()


class _ClipReader:
    """Reads and validates the clips of a split, collecting problems when skipping is allowed.

    Files are read by a small thread pool (file reads and numpy checks release the GIL; on a cold
    disk the latency of many small reads dominates), in bounded chunks so memory stays small, and
    handed to `write` in split order.
    """

    CHUNK = 256

    def __init__(self, root: Path, split: str, spec: DatasetSpec, skip_bad: bool, progress: bool, threads: int = 8):
        self.root, self.split, self.spec = root, split, spec
        self.skip_bad, self.progress, self.threads = skip_bad, progress, threads
        self.ids: list[str] = []
        self.lengths: list[int] = []
        self.captions: list[list[Caption]] = []
        self.problems: list[str] = []

    def _fetch(self, clip_id: str):
        try:
            return fetch_clip(self.root, clip_id, self.split)
        except StableMoError as err:
            return err

    def __call__(self, ids: list[str], write) -> None:
        from tqdm import tqdm

        with ThreadPoolExecutor(self.threads) as pool, tqdm(
            total=len(ids), desc=f"reading {self.split}", unit="clip", disable=None if self.progress else True,
            leave=False,
        ) as bar:
            for lo in range(0, len(ids), self.CHUNK):
                chunk = ids[lo : lo + self.CHUNK]
                for clip_id, raw in zip(chunk, pool.map(self._fetch, chunk)):
                    try:
                        if isinstance(raw, StableMoError):
                            raise raw
                        features, captions = decode_clip(self.root, clip_id, self.spec, raw)
                    except StableMoError as err:
                        if not self.skip_bad:
                            raise
                        self.problems.append(str(err))
                        continue
                    write(features)
                    self.ids.append(clip_id)
                    self.lengths.append(len(features))
                    self.captions.append(captions)
                bar.update(len(chunk))


def _build(root: Path, split: str, ids: list[str], spec: DatasetSpec, skip_bad: bool,
           cache_dir: Path | None, fp: str, progress: bool) -> SplitData:
    reader = _ClipReader(root, split, spec, skip_bad, progress)
    features: np.ndarray
    if cache_dir is not None:
        try:
            cache_dir.mkdir(parents=True, exist_ok=True)
            data_name = f"{split}.{spec.name}.{secrets.token_hex(6)}.f32"
            # mode 0o644: a shared dataset folder, other users may read the cache
            with atomic_open(cache_dir / data_name, mode=0o644) as f:
                reader(ids, lambda a: f.write(a.astype(CACHE_DTYPE, copy=False).tobytes()))
            total = int(sum(reader.lengths))
            features = _open_features(cache_dir / data_name, total, spec.feature_dim)
            index = {
                "version": CACHE_VERSION,
                "fingerprint": fp,
                "dataset": spec.name,
                "feature_dim": spec.feature_dim,
                "data_file": data_name,
                "total_frames": total,
                "ids": reader.ids,
                "lengths": reader.lengths,
                "captions": reader.captions,  # NamedTuples serialise as [text, tokens, start, end]
                "problems": reader.problems,
            }
            index_path = _index_path(cache_dir, split, spec)
            write_text(index_path, json.dumps(index), mode=0o644)
            _remove_stale(cache_dir, split, spec, keep=data_name)
        except OSError as err:
            warnings.warn(f"{cache_dir}: cannot write the dataset cache ({err}); reading without it", stacklevel=3)
            return _build(root, split, ids, spec, skip_bad, None, fp, progress)
    else:
        chunks: list[np.ndarray] = []
        reader(ids, chunks.append)
        features = np.concatenate(chunks) if chunks else np.zeros((0, spec.feature_dim), np.float32)
    lengths = np.asarray(reader.lengths, dtype=np.int64)
    return SplitData(root, split, reader.ids, lengths, _offsets(lengths), features, reader.captions, reader.problems)


def read_clips(root: Path, split: str, ids: list[str], spec: DatasetSpec, *, skip_bad: bool = False,
               progress: bool = True) -> SplitData:
    """Read the given clips into memory without touching any cache."""
    return _build(check_root(root), split, ids, spec, skip_bad, None, "", progress)


def _remove_stale(cache_dir: Path, split: str, spec: DatasetSpec, keep: str) -> None:
    # Readers that still map an old file keep it alive (POSIX unlink semantics).
    for path in cache_dir.glob(f"{split}.{spec.name}.*.f32"):
        if path.name != keep:
            path.unlink(missing_ok=True)


def load_split(
    root: str | Path,
    split: str,
    spec: DatasetSpec,
    *,
    skip_bad: bool = False,
    cache: bool = True,
    cache_dir: str | Path | None = None,
    progress: bool = True,
) -> SplitData:
    """All clips of `split`; bad clips raise StableMoError, or with skip_bad are skipped with one warning."""
    root = check_root(root)
    ids = read_split(root, split)
    data = None
    fp = ""
    cdir = None
    if cache:
        cdir = Path(cache_dir) if cache_dir is not None else default_cache_dir(root)
        fp = fingerprint(root, split, ids, spec)
        data = _try_load_cache(cdir, root, split, spec, fp)
    if data is None:
        data = _build(root, split, ids, spec, skip_bad, cdir, fp, progress)
    if data.problems:
        if not skip_bad:
            raise StableMoError(data.problems[0])
        shown = "\n  ".join(data.problems[:5]) + ("\n  ..." if len(data.problems) > 5 else "")
        warnings.warn(f"{split_path(root, split)}: skipped {len(data.problems)} bad clip(s) of {len(ids)}:\n  {shown}",
                      stacklevel=2)
    return data
