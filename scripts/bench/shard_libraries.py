"""Compare streaming-dataset libraries on our clips: write speed, size, read speed, determinism.

    PYTHONPATH=/tmp/shardlibs .venv/bin/python scripts/bench/shard_libraries.py DATASET_DIR [--copies 4]

The libraries are not dependencies of StableMo; install them into a separate folder to measure
(installing LitData or MosaicML streaming into .venv with their dependencies would replace torch
and, for streaming, downgrade numpy):

    .venv/bin/pip install --target /tmp/shardlibs --no-deps litdata mosaicml-streaming webdataset \
        braceexpand zstd zstandard xxhash boto3 botocore jmespath s3transfer python-dateutil six \
        brotli python-snappy cramjam obstore tifffile catalogue

(MosaicML streaming imports torchvision at start only for its image datasets: a stub package on
PYTHONPATH with `datasets.VisionDataset`, `datasets.CIFAR10`, `transforms.functional.to_tensor`
is enough.) Every library gets the same clips (the split's features and caption files, copied
`--copies` times under new keys), zstd level 1 on the raw float32 bytes and ~64 MB shards; each is timed writing
from memory and reading every sample back to numpy. Writing twice into two folders tells whether
the library's output is byte-identical for the same input.
"""

from __future__ import annotations

import argparse
import hashlib
import tempfile
import time
from pathlib import Path

import numpy as np

SHARD_BYTES = 64 << 20
LEVEL = 1  # zstd level for all three (level 1 is what stablemo.data.shard_format uses)


def load_clips(root: Path, copies: int) -> list[tuple[str, np.ndarray, str]]:
    ids = [line.strip() for line in (root / "all.txt").read_text().splitlines() if line.strip()]
    base = [(i, np.load(root / "new_joint_vecs" / f"{i}.npy"), (root / "texts" / f"{i}.txt").read_text()) for i in ids]
    return [(f"{c}_{i}", m, t) for c in range(copies) for i, m, t in base]


def tree_digest(folder: Path) -> str:
    h = hashlib.sha256()
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        h.update(path.relative_to(folder).as_posix().encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def size_of(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


# -- WebDataset: tar shards, each member zstd-compressed by us (the library itself offers gzip) ---
def wds_write(clips, out: Path) -> None:
    import webdataset as wds
    import zstandard

    cctx = zstandard.ZstdCompressor(level=LEVEL)
    out.mkdir()
    shard, size, writer = 0, 0, None
    for key, motion, text in clips:
        if writer is None or size > SHARD_BYTES:
            if writer is not None:
                writer.close()
            writer = wds.TarWriter(str(out / f"shard-{shard:05d}.tar"), mtime=0, encoder=False)
            shard, size = shard + 1, 0
        blob = cctx.compress(motion.astype("<f4").tobytes())
        writer.write({"__key__": key, "f32.zst": blob, "txt": text.encode(), "json": str(motion.shape[0]).encode()})
        size += len(blob)
    writer.close()


def wds_read(out: Path) -> int:
    import webdataset as wds
    import zstandard

    dctx = zstandard.ZstdDecompressor()
    urls = [str(p) for p in sorted(out.glob("*.tar"))]
    n = 0
    for sample in wds.WebDataset(urls, shardshuffle=False, empty_check=False):
        np.frombuffer(dctx.decompress(sample["f32.zst"]), "<f4").reshape(int(sample["json"]), -1)
        sample["txt"].decode()
        n += 1
    return n


# -- LitData: its BinaryWriter (what litdata.optimize runs in each worker), zstd chunks -----------
def litdata_write(clips, out: Path) -> None:
    from litdata.streaming.writer import BinaryWriter

    writer = BinaryWriter(str(out), chunk_bytes=SHARD_BYTES, compression=f"zstd:{LEVEL}")
    for index, (key, motion, text) in enumerate(clips):
        writer.add_item(index, {"id": key, "motion": motion, "text": text})
    writer.done()
    writer.merge()


def litdata_read(out: Path) -> int:
    from litdata import StreamingDataset

    ds = StreamingDataset(str(out))
    n = 0
    for item in ds:
        np.asarray(item["motion"])
        n += 1
    return n


# -- MosaicML streaming: MDSWriter, zstd shards, read by index ------------------------------------
def mds_write(clips, out: Path) -> None:
    from streaming import MDSWriter

    columns = {"id": "str", "motion": "ndarray:float32", "text": "str"}
    with MDSWriter(out=str(out), columns=columns, compression=f"zstd:{LEVEL}", size_limit=SHARD_BYTES) as writer:
        for key, motion, text in clips:
            writer.write({"id": key, "motion": motion, "text": text})


def mds_read(out: Path) -> int:
    from streaming import StreamingDataset

    ds = StreamingDataset(local=str(out), shuffle=False, batch_size=1)  # decompresses shards as it goes
    n = 0
    for item in ds:
        np.asarray(item["motion"])
        n += 1
    return n


LIBRARIES = {"webdataset": (wds_write, wds_read), "litdata": (litdata_write, litdata_read),
             "mosaicml-streaming": (mds_write, mds_read)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--copies", type=int, default=4)
    parser.add_argument("--only", nargs="*", default=list(LIBRARIES))
    args = parser.parse_args()
    clips = load_clips(args.dataset, args.copies)
    raw = sum(m.nbytes for _, m, _ in clips)
    print(f"{len(clips)} clips, {raw / 2**20:.0f} MiB of float32 features")
    print(f"{'library':<20} {'write clips/s':>13} {'size/raw':>9} {'read clips/s':>12} {'deterministic':>13}")
    for name in args.only:
        write, read = LIBRARIES[name]
        with tempfile.TemporaryDirectory() as tmp:
            a, b = Path(tmp) / "a", Path(tmp) / "b"
            t0 = time.perf_counter()
            write(clips, a)
            t_write = time.perf_counter() - t0
            write(clips, b)
            same = tree_digest(a) == tree_digest(b)
            size = size_of(a)  # before reading: MosaicML's reader leaves decompressed copies beside the shards
            t0 = time.perf_counter()
            n = read(a)
            t_read = time.perf_counter() - t0
            assert n == len(clips), (name, n)
            print(f"{name:<20} {len(clips) / t_write:>13.0f} {size / raw:>9.3f} {n / t_read:>12.0f} "
                  f"{'yes' if same else 'no':>13}", flush=True)


if __name__ == "__main__":
    main()
