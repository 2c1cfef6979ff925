"""`stablemo data check DIR` on a shard folder: manifest, files, checksums, shapes, values.

Every shard is read whole and decoded, so the check costs one pass over the corpus. Every problem
is one line naming the file (and clip) at fault; nothing stops at the first one except a manifest
that cannot be read.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stablemo.data.check import MAX_ABS_VALUE, MIN_STD, notes_and_problems
from stablemo.data.dataset import build_items
from stablemo.data.shard_format import (
    MANIFEST,
    SHARD_NAME,
    Manifest,
    decode_shard,
    is_url,
    join,
    read_bytes,
    read_manifest,
    sha256,
)
from stablemo.errors import StableMoError


def is_shard_folder(location: str) -> bool:
    folder = Path(location)
    if is_url(location) or (folder / MANIFEST).is_file() or (folder / ".partial").is_dir():
        return True
    return folder.is_dir() and any(SHARD_NAME.match(p.name) for p in folder.iterdir())


@dataclass
class ShardReport:
    location: str
    manifest: Manifest | None = None
    problems: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    checked: dict[str, tuple[int, int, int, int]] = field(default_factory=dict)  # split -> shards, clips, items, bytes

    @property
    def ok(self) -> bool:
        return not self.problems


def _check_shard(report: ShardReport, manifest: Manifest, info) -> tuple[int, int]:
    """Problems of one shard into the report; returns the (clips, items) it holds."""
    where = join(manifest.location, info.file)
    try:
        data = read_bytes(where)
    except StableMoError as err:
        report.problems.append(str(err))
        return 0, 0
    if len(data) != info.bytes:
        report.problems.append(f"{where}: {len(data)} bytes, the manifest says {info.bytes} (truncated or replaced)")
        return 0, 0
    if sha256(data) != info.sha256:
        report.problems.append(f"{where}: sha256 differs from the manifest's (the file is damaged or replaced)")
        return 0, 0
    try:
        clips = decode_shard(data, where, manifest.spec)
    except StableMoError as err:
        report.problems.append(str(err))
        return 0, 0
    for row, clip_id in enumerate(clips.ids):
        motion = clips.motion(row)
        finite = np.isfinite(motion)
        if not finite.all():
            report.problems.append(f"{where}#{row:06d} ({clip_id}): {int((~finite).sum())} NaN/Inf value(s)")
        elif np.abs(motion).max() > MAX_ABS_VALUE:
            report.problems.append(f"{where}#{row:06d} ({clip_id}): value(s) with |x| > {MAX_ABS_VALUE:g}")
        if not clips.captions[row]:
            report.problems.append(f"{where}#{row:06d} ({clip_id}): no caption")
    items = len(build_items(clips, manifest.spec))
    if (len(clips), items, int(clips.lengths.sum())) != (info.clips, info.items, info.frames):
        report.problems.append(f"{where}: holds {len(clips)} clips / {items} items / {int(clips.lengths.sum())} frames, "
                               f"the manifest says {info.clips} / {info.items} / {info.frames}")
    return len(clips), items


def check_shards(location: str) -> ShardReport:
    report = ShardReport(location)
    try:
        manifest = read_manifest(location)
    except StableMoError as err:
        report.problems.append(str(err))
        return report
    report.manifest = manifest
    if np.abs(manifest.mean).max() > MAX_ABS_VALUE:
        report.problems.append(f"{join(location, MANIFEST)}: stats.mean has values with |x| > {MAX_ABS_VALUE:g}")
    if (manifest.std < MIN_STD).any():
        report.problems.append(f"{join(location, MANIFEST)}: stats.std has values below {MIN_STD:g}")
    if "train" not in manifest.splits:
        report.problems.append(f"{join(location, MANIFEST)}: no train split")
    listed = set()
    for split, shards in manifest.splits.items():
        clips = items = 0
        for info in shards:
            listed.add(info.file)
            c, i = _check_shard(report, manifest, info)
            clips, items = clips + c, items + i
        report.checked[split] = (len(shards), clips, items, sum(s.bytes for s in shards))
    if not is_url(location):
        extra = sorted(p.name for p in Path(location).iterdir() if p.name not in listed and p.name != MANIFEST)
        if extra:
            report.notes.append(f"{len(extra)} file(s) not in the manifest, e.g. {extra[0]}")
    return report


def format_shard_report(report: ShardReport, max_problems: int = 30) -> str:
    out = [f"shards: {report.location}"]
    m = report.manifest
    if m is not None:
        out[0] += f" ({m.spec.name}: {m.spec.feature_dim}-d features)"
        out += ["", "splits:", f"  {'split':<6} {'shards':>7} {'clips':>8} {'items':>8} {'MiB':>9}"]
        for split, (shards, clips, items, size) in report.checked.items():
            out.append(f"  {split:<6} {shards:>7} {clips:>8} {items:>8} {size / 2**20:>9.1f}")
        out += ["", "sources:"]
        for src in m.raw.get("sources", []):
            counts = ", ".join(f"{k} {v}" for k, v in src.get("clips", {}).items())
            out.append(f"  - {src.get('name')}: {counts}; licence: {src.get('licence')} ({src.get('licence_from')}); "
                       f"{src.get('path')}")
        out.append(f"statistics: {m.raw['stats'].get('from', '?')}")
    return "\n".join(out + notes_and_problems(report.notes, report.problems, max_problems))
