"""`stablemo data shard SRC [SRC ...] --out DIR`: HumanML3D-layout folders -> shards + manifest.

The clips of each split (train, val, test), source after source in split-file order, are cut into
shards of `clips_per_shard` clips (format: stablemo.data.shard_format). The plan depends only on
the inputs and the options, so the same input gives byte-identical shards and manifest (nothing
records a time, a host or a random name).

Resumable and atomic: every shard is written whole through stablemo.io (a reader never sees half a
file) and, once written, described by a small record in `DIR/.partial/` (its sha256, counts, the
train statistics' sums). A killed run, started again with the same sources and options, keeps
every shard whose file still has its recorded sha256 and writes the rest. The manifest is written
last: a folder without one is unfinished, and readers refuse it. Changed sources or options
discard the unfinished records and shards (of this command's own names) and start over.

Statistics: one source keeps its own Mean.npy / Std.npy (training from its shards normalises
exactly as training from the folder); several sources get Mean/Std computed over their merged
train split with HumanML3D's recipe (stablemo.data.stats.compute_stats). The body (bone lengths,
stored in bundles) is measured on the same clips as MotionDataModule.body picks.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import sys
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stablemo.data.cache import (
    SplitData,
    decode_clip,
    feature_path,
    fetch_clip,
    fingerprint,
)
from stablemo.data.check import MAX_ABS_VALUE, MIN_STD
from stablemo.data.dataset import build_items
from stablemo.data.layout import DatasetSpec, check_root, get_spec, read_split
from stablemo.data.shard_format import (
    FORMAT,
    FORMAT_VERSION,
    MANIFEST,
    SHARD_NAME,
    ZSTD_LEVEL,
    clip_sample,
    sha256,
)
from stablemo.data.shard_tar import tar_bytes
from stablemo.data.stats import (
    body_lengths,
    body_picks,
    load_dataset_stats,
    stats_from_sums,
)
from stablemo.errors import StableMoError
from stablemo.io import check_output_dir, write_bytes, write_text

SHARD_SPLITS = ("train", "val", "test")
CLIPS_PER_SHARD = 512  # ~60 MB of HumanML3D features before compression, ~35 MB after
READ_GROUP = 16  # clips a reader thread fetches per task
PARTIAL = ".partial"  # records of finished shards while a run is unfinished
LICENCE_FILES = ("LICENCE", "LICENSE", "LICENCE.txt", "LICENSE.txt", "LICENCE.md", "LICENSE.md")


@dataclass(frozen=True)
class Source:
    root: Path
    name: str
    licence: str
    licence_from: str  # "--licence", a file name, or "none"
    splits: dict[str, list[str]]  # split -> ids (only the splits the folder has)


def find_licence(root: Path, given: str | None) -> tuple[str, str]:
    """(licence, where it came from): the option, else the first line of a LICENCE/LICENSE file."""
    if given:
        return given, "--licence"
    for name in LICENCE_FILES:
        path = root / name
        if path.is_file():
            try:
                lines = [line.strip() for line in path.read_text(encoding="utf-8", errors="replace").splitlines()]
            except OSError as err:
                raise StableMoError(f"{path}: cannot read ({err.strerror})") from None
            first = next((line for line in lines if line), "")
            return (first or "unknown"), name
    return "unknown", "none"


def read_sources(paths: list[str], licences: list[str] | None) -> list[Source]:
    if not paths:
        raise StableMoError("data shard: give at least one source folder")
    if licences and len(licences) not in (1, len(paths)):
        raise StableMoError(f"--licence: give one licence for all sources or one per source "
                            f"({len(paths)} source(s), {len(licences)} licence(s))")
    sources, names = [], set()
    for index, path in enumerate(paths):
        root = check_root(path).resolve()
        splits = {s: read_split(root, s) for s in SHARD_SPLITS if (root / f"{s}.txt").is_file()}
        if "train" not in splits:
            raise StableMoError(f"{root / 'train.txt'}: split file not found (every source needs a train split)")
        name = root.name
        while name in names:  # two folders of the same name: keep their ids apart
            name = f"{name}_{index}"
        names.add(name)
        given = licences[0 if len(licences) == 1 else index] if licences else None
        sources.append(Source(root, name, *find_licence(root, given), splits))
    return sources


def plan_shards(sources: list[Source], clips_per_shard: int) -> dict[str, list[list[tuple[int, str]]]]:
    """split -> shards -> [(source index, clip id)], sources in the order given, split-file order."""
    plan = {}
    for split in SHARD_SPLITS:
        clips = [(i, clip_id) for i, src in enumerate(sources) for clip_id in src.splits.get(split, [])]
        if clips:
            plan[split] = [clips[k : k + clips_per_shard] for k in range(0, len(clips), clips_per_shard)]
    return plan


def plan_key(sources: list[Source], spec: DatasetSpec, clips_per_shard: int, skip_bad: bool) -> str:
    """What a finished shard depends on: options, and every source file's size and mtime."""
    h = hashlib.sha256(json.dumps([FORMAT_VERSION, spec.name, clips_per_shard, ZSTD_LEVEL, skip_bad]).encode())
    for src in sources:
        h.update(f"\n{src.root}\n{src.name}\n{src.licence}\n".encode())
        for name in ("Mean.npy", "Std.npy"):
            path = src.root / name
            h.update(f"{path.stat().st_size} {path.stat().st_mtime_ns}\n".encode() if path.is_file() else b"-\n")
        for split, ids in src.splits.items():
            h.update(fingerprint(src.root, split, ids, spec).encode())
    return h.hexdigest()


class ShardWriter:
    def __init__(self, sources: list[Source], out: Path, spec: DatasetSpec, clips_per_shard: int,
                 skip_bad: bool, progress: bool):
        self.sources, self.out, self.spec = sources, out, spec
        self.clips_per_shard, self.skip_bad, self.progress = clips_per_shard, skip_bad, progress
        self.prefix = len(sources) > 1  # merged sources: ids become `<source name>:<id>`

    def _clip_id(self, source: int, clip_id: str) -> str:
        return f"{self.sources[source].name}:{clip_id}" if self.prefix else clip_id

    def _read(self, pool: ThreadPoolExecutor, clips: list[tuple[int, str]], split: str):
        """(source, id, features, captions) of the readable clips, and the problem lines of the rest."""

        def fetch(group):
            out = []
            for source, clip_id in group:
                try:
                    out.append(fetch_clip(self.sources[source].root, clip_id, split))
                except StableMoError as err:
                    out.append(err)
            return out

        # one task per run of READ_GROUP clips: a task per clip cost more in thread hand-offs than
        # its read from a warm page cache; 8 runs at a time still keep 8 reads waiting on a cold disk
        groups = [clips[k : k + READ_GROUP] for k in range(0, len(clips), READ_GROUP)]
        raws = (raw for group in pool.map(fetch, groups) for raw in group)  # decoded as they arrive
        good, problems = [], []
        for (source, clip_id), raw in zip(clips, raws):
            root = self.sources[source].root
            try:
                if isinstance(raw, StableMoError):
                    raise raw
                features, captions = decode_clip(root, clip_id, self.spec, raw)
                peak = max(float(features.max()), -float(features.min()))  # |x|'s largest, no (T, D) copy
                if peak > MAX_ABS_VALUE:
                    raise StableMoError(f"{feature_path(root, clip_id)}: value(s) with |x| > {MAX_ABS_VALUE:g} "
                                        f"(largest {peak:.3g}): outside the range of motion features")
            except StableMoError as err:
                if not self.skip_bad:
                    raise
                problems.append(str(err))
                continue
            good.append((source, clip_id, features, captions))
        return good, problems

    def write_shard(self, split: str, index: int, clips: list[tuple[int, str]]) -> dict:
        """Write one shard file (atomically) and return its record."""
        with ThreadPoolExecutor(8) as pool:  # many small reads: latency, not CPU, on a cold disk
            good, problems = self._read(pool, clips, split)
        samples = [clip_sample(row, self._clip_id(source, clip_id), features, captions)
                   for row, (source, clip_id, features, captions) in enumerate(good)]
        # members in WebDataset's order (a sample's extensions sorted); fixed owner, mode and time
        # stamps (shard_tar): the same clips give the same bytes
        data = tar_bytes((f"{sample['__key__']}.{ext}", sample[ext])
                         for sample in samples for ext in sorted(sample) if ext != "__key__")
        name = f"{split}-{index:05d}.tar"
        write_bytes(self.out / name, data)
        lengths = np.asarray([len(g[2]) for g in good], np.int64)
        items = build_items(SplitData(self.out, split, [g[1] for g in good], lengths, np.zeros_like(lengths),
                                      np.zeros((0, self.spec.feature_dim), np.float32), [g[3] for g in good]),
                            self.spec)
        digest = sha256(data)
        # per source, what its clips in this shard hold (provenance): the shard's own sha256 when the
        # shard holds one source's clips (all but the shards at a boundary between sources), else the
        # sha256 of the source's samples (ids, captions and compressed features fix the features)
        in_shard = sorted({g[0] for g in good})
        digests = {source: digest for source in in_shard} if len(in_shard) == 1 else {
            source: hashlib.sha256(b"".join(s["json"] + s["f32.zst"] for g, s in zip(good, samples)
                                            if g[0] == source)).hexdigest() for source in in_shard}
        record = {"file": name, "clips": len(good), "items": len(items), "frames": int(lengths.sum()),
                  "bytes": len(data), "sha256": digest, "problems": problems,
                  "sources": {str(s): {"clips": sum(g[0] == s for g in good), "sha256": d}
                              for s, d in digests.items()}}
        if split == "train" and good and self.prefix:  # merged sources: their Mean/Std is computed
            block = np.concatenate([g[2] for g in good])  # (frames, D) float32; float64 sums (10x faster than a copy)
            record["sum"] = block.sum(0, dtype=np.float64).tolist()
            record["sum_sq"] = np.square(block).sum(0, dtype=np.float64).tolist()
        return record


def _kept(out: Path, record_path: Path) -> dict | None:
    """A finished shard's record if the shard file still has the recorded checksum."""
    try:
        record = json.loads(record_path.read_text())
        data = (out / record["file"]).read_bytes()
    except (OSError, ValueError, KeyError):
        return None
    return record if len(data) == record["bytes"] and sha256(data) == record["sha256"] else None


def _start_over(out: Path, partial: Path) -> None:
    """Remove an unfinished run's records and its shard files (only names this command writes)."""
    shutil.rmtree(partial, ignore_errors=True)
    for path in out.iterdir():
        if SHARD_NAME.match(path.name):
            path.unlink()


def write_shards(paths: list[str], out: str, *, dataset: str = "humanml3d", clips_per_shard: int = CLIPS_PER_SHARD,
                 licences: list[str] | None = None, skip_bad: bool = False, workers: int = 1,
                 progress: bool = True) -> tuple[dict, int]:
    """Shard the sources into `out` (see the module docstring) -> (manifest, shards kept from an
    earlier run)."""
    spec = get_spec(dataset)
    if clips_per_shard < 1:
        raise StableMoError(f"--clips-per-shard={clips_per_shard}: must be >= 1")
    if workers < 1:
        raise StableMoError(f"--workers={workers}: must be >= 1")
    sources = read_sources(paths, licences)
    out_dir = check_output_dir(out, "--out")
    if any(out_dir.resolve() == s.root or s.root in out_dir.resolve().parents for s in sources):
        raise StableMoError(f"--out: {out}: inside a source folder; write the shards elsewhere")
    if not len(sources) > 1:
        load_dataset_stats(sources[0].root, spec)  # a broken Mean/Std is named before the work starts
    plan = plan_shards(sources, clips_per_shard)
    key = plan_key(sources, spec, clips_per_shard, skip_bad)
    partial = out_dir / PARTIAL
    if out_dir.is_dir() and any(out_dir.iterdir()):
        foreign = [p.name for p in out_dir.iterdir() if not (SHARD_NAME.match(p.name) or p.name in (PARTIAL, MANIFEST))]
        if foreign:
            raise StableMoError(f"--out: {out}: holds files this command did not write (e.g. {min(foreign)}); "
                                "give a new or empty folder")
        if (out_dir / MANIFEST).is_file() and not partial.is_dir():
            raise StableMoError(f"--out: {out}: already holds finished shards; give a new or empty folder")
        try:
            same_plan = json.loads((partial / "plan.json").read_text()).get("key") == key
        except (OSError, ValueError, AttributeError):
            same_plan = False
        if not same_plan:
            _start_over(out_dir, partial)
    partial.mkdir(parents=True, exist_ok=True)
    write_text(partial / "plan.json", json.dumps({"key": key}))

    from tqdm import tqdm

    writer = ShardWriter(sources, out_dir, spec, clips_per_shard, skip_bad, progress)
    records: dict[str, list[dict | None]] = {split: [None] * len(shards) for split, shards in plan.items()}
    todo = []
    for split, shards in plan.items():
        for index, clips in enumerate(shards):
            records[split][index] = _kept(out_dir, partial / f"{split}-{index:05d}.json")
            if records[split][index] is None:
                todo.append((split, index, clips))
    kept = sum(len(shards) for shards in plan.values()) - len(todo)

    def finished(split: str, index: int, record: dict) -> None:
        write_text(partial / f"{split}-{index:05d}.json", json.dumps(record))  # after its shard: the resume point
        records[split][index] = record
        bar.update(1)

    with tqdm(total=len(todo), desc="shards", unit="shard", file=sys.stderr, disable=None if progress else True,
              leave=False) as bar:
        if workers == 1 or len(todo) < 2:
            for split, index, clips in todo:
                finished(split, index, writer.write_shard(split, index, clips))
        else:
            # shards are independent: one process writes each (the work is CPU: decoding, zstd, tar, sha256)
            with ProcessPoolExecutor(min(workers, len(todo))) as pool:
                futures = {pool.submit(writer.write_shard, split, index, clips): (split, index)
                           for split, index, clips in todo}
                for future in as_completed(futures):
                    finished(*futures[future], future.result())
    manifest = _manifest(sources, spec, plan, records, clips_per_shard, skip_bad)
    write_text(out_dir / MANIFEST, json.dumps(manifest, indent=1, sort_keys=True) + "\n")
    shutil.rmtree(partial)
    return manifest, kept


def _train_clip(plan: dict, row: int) -> tuple[int, str]:
    shard = plan["train"][row // len(plan["train"][0])]
    return shard[row % len(plan["train"][0])]


def _manifest(sources: list[Source], spec: DatasetSpec, plan: dict, records: dict[str, list[dict]],
              clips_per_shard: int, skip_bad: bool) -> dict:
    train = records["train"]
    problems = [p for split in records.values() for r in split for p in r["problems"]]
    if len(sources) == 1:
        mean, std = load_dataset_stats(sources[0].root, spec)
        stats_from = f"{sources[0].name}/Mean.npy, Std.npy"
    else:
        count = sum(r["frames"] for r in train)
        total = np.sum([r["sum"] for r in train if r["clips"]], axis=0)
        total_sq = np.sum([r["sum_sq"] for r in train if r["clips"]], axis=0)
        mean, std = stats_from_sums(count, total, total_sq)
        stats_from = f"computed over the merged train split ({count} frames)"
        if (std < MIN_STD).any():
            raise StableMoError(f"{spec.name}: the merged train split's Std is below {MIN_STD:g} in dim "
                                f"{int(np.argmax(std < MIN_STD))}: a constant feature; cannot normalise")
    # the body: the clips MotionDataModule.body would measure (unreadable clips, skipped, are left out)
    picked = []
    for row in body_picks(sum(len(s) for s in plan["train"])):
        source, clip_id = _train_clip(plan, int(row))
        root = sources[source].root
        try:
            picked.append(decode_clip(root, clip_id, spec, fetch_clip(root, clip_id, "train"))[0])
        except StableMoError:
            continue
    from stablemo.motion import get_skeleton

    body = body_lengths(picked, get_skeleton(spec.skeleton)) if picked else None
    provenance = []
    for i, src in enumerate(sources):
        entry = {"name": src.name, "path": str(src.root), "licence": src.licence, "licence_from": src.licence_from,
                 "clips": {}, "sha256": ""}
        h = hashlib.sha256()
        for split, recs in records.items():
            entry["clips"][split] = sum(r["sources"].get(str(i), {}).get("clips", 0) for r in recs)
            for r in recs:
                h.update(r["sources"].get(str(i), {}).get("sha256", "").encode())
        entry["sha256"] = h.hexdigest()  # over its clips' features, captions and ids as stored
        synth = src.root / "synth.json"
        if synth.is_file():
            try:
                info = json.loads(synth.read_text())
                entry["generator"] = {k: info[k] for k in ("generator", "version", "seed", "num") if k in info}
            except (OSError, ValueError, TypeError):
                pass
        provenance.append(entry)
    return {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "dataset": spec.name,
        "feature_dim": spec.feature_dim,
        "codec": {"container": "webdataset tar", "features": f"float32 LE, 4 byte planes, zstd level {ZSTD_LEVEL}"},
        "clips_per_shard": clips_per_shard,
        "ids": "<source name>:<id>" if len(sources) > 1 else "as in the source",
        "stats": {"mean": [float(v) for v in mean], "std": [float(v) for v in std], "from": stats_from},
        "body": None if body is None else [float(v) for v in body],
        "sources": provenance,
        "skipped": problems if skip_bad else [],
        "splits": {split: {"clips": sum(r["clips"] for r in recs), "items": sum(r["items"] for r in recs),
                           "shards": [{k: r[k] for k in ("file", "clips", "items", "frames", "bytes", "sha256")}
                                      for r in recs]}
                   for split, recs in records.items()},
    }
