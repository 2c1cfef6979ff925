"""`stablemo data check DIR`: validate a HumanML3D-layout folder and summarise it.

Every problem is collected (nothing stops at the first bad file); the summary gives counts per
split, a text histogram of clip lengths, caption statistics and the list of problems.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stablemo.data.cache import SplitData, load_split, read_clips
from stablemo.data.dataset import build_items
from stablemo.data.layout import (
    DATASETS,
    FEATURE_DIR,
    JOINT_DIR,
    SPLITS,
    Caption,
    DatasetSpec,
    check_root,
    feature_path,
    get_spec,
    read_split,
)
from stablemo.data.stats import load_stat
from stablemo.errors import StableMoError
from stablemo.io import load_npy
from stablemo.motion.plausible import MAX_ABS_FEATURE

REQUIRED_SPLITS = ("train", "val", "test")
# Sane ranges (stablemo.motion.plausible says why): finite values as large as 3e38 pass the
# NaN/Inf check and then overflow float32 once normalised, and training diverges.
MAX_ABS_VALUE = MAX_ABS_FEATURE
# Normalising divides by Std (after feat_bias): below this even float32 rounding of a feature
# (~1e-7 of its size) is amplified past 1, and a constant feature needs no tiny Std (see stats_problems).
MIN_STD = 1e-8
_ROWS_PER_CHUNK = 1 << 16
DISJOINT = (("train", "val"), ("train", "test"), ("val", "test"))
_WORD = re.compile(r"[a-z0-9']+")


@dataclass
class SplitSummary:
    listed: int
    readable: int
    items: int  # training items: whole clips + sub-caption windows
    sub_items: int
    too_short: int
    too_long: int


@dataclass
class CheckReport:
    root: Path
    spec: DatasetSpec
    splits: dict[str, SplitSummary] = field(default_factory=dict)
    lengths: list[int] = field(default_factory=list)  # frames of every readable clip (each once)
    captions_per_motion: list[int] = field(default_factory=list)
    words_per_caption: list[int] = field(default_factory=list)
    sub_captions: int = 0
    vocabulary: set[str] = field(default_factory=set)
    problems: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems


def check_dataset(root: str | Path, dataset: str = "humanml3d", *, cache: bool = True) -> CheckReport:
    """Validate everything that the loader reads; only a missing folder raises."""
    spec = get_spec(dataset)
    root = check_root(root)
    report = CheckReport(root, spec)
    for name in ("Mean.npy", "Std.npy"):
        try:
            load_stat(root, name, spec)
        except StableMoError as err:
            report.problems.append(str(err))
    if report.problems:
        _guess_dataset(report)
    report.problems += stats_problems(root, spec)

    # Each clip is read once: train/val/test through their caches (which training reuses), the
    # clips only listed in train_val/all (normally none) directly.
    results: dict[str, tuple[int, list[Caption]] | str] = {}  # id -> (frames, captions) or problem
    problems: dict[str, None] = {}  # ordered set
    split_ids: dict[str, list[str]] = {}
    for split in SPLITS:
        if not (root / f"{split}.txt").is_file():
            if split in REQUIRED_SPLITS:
                problems[f"{root / f'{split}.txt'}: split file not found"] = None
            continue
        try:
            ids = read_split(root, split)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                if split in REQUIRED_SPLITS:
                    data = load_split(root, split, spec, skip_bad=True, cache=cache)
                    _record(results, ids, data)
                else:
                    unseen = [i for i in ids if i not in results]
                    if unseen:
                        _record(results, unseen, read_clips(root, split, unseen, spec, skip_bad=True))
        except StableMoError as err:  # the split file itself is unreadable
            problems[str(err)] = None
            continue
        split_ids[split] = ids
        problems.update((r, None) for r in (results[i] for i in ids) if isinstance(r, str))
        report.splits[split] = _summarise(root, split, ids, results, spec)
    for a, b in DISJOINT:
        shared = set(split_ids.get(a, ())) & set(split_ids.get(b, ()))
        if shared:
            problems[f"{root / f'{a}.txt'}: {len(shared)} id(s) also in {b}.txt (e.g. {min(shared)})"] = None
    report.problems += list(problems)

    clips = {i: r for i, r in results.items() if not isinstance(r, str)}
    untagged = 0
    for n, caps in clips.values():
        report.lengths.append(n)
        report.captions_per_motion.append(len(caps))
        for cap in caps:
            words = _WORD.findall(cap.text.lower())
            report.words_per_caption.append(len(words))
            report.vocabulary.update(words)
            report.sub_captions += not cap.whole_clip
            untagged += not cap.tokens
    if untagged:
        report.notes.append(f"{untagged} caption(s) have no word/POS tokens (the Guo et al. evaluator needs them)")
    _add_notes(report, set(clips))
    return report


def stats_problems(root: Path, spec: DatasetSpec) -> list[str]:
    """Mean.npy / Std.npy entries outside the sane range (finite and shape problems are load_stat's).

    A Std entry is tiny only for a (nearly) constant feature; dividing by it turns rounding noise into
    large normalised values, and generation multiplies by it. Such a dimension should get Std 1 (its
    normalised value is then x - mean, i.e. 0 for a constant feature), which is what HumanML3D's
    group-averaged Std does in effect: no group of real motion data has a tiny spread.
    """
    problems = []
    for name in ("Mean.npy", "Std.npy"):
        try:
            values = load_stat(root, name, spec)
        except StableMoError:
            continue  # reported by the caller
        big = np.abs(values) > MAX_ABS_VALUE
        if big.any():
            dim = int(np.argmax(big))
            problems.append(f"{root / name}: {int(big.sum())} value(s) with |x| > {MAX_ABS_VALUE:g} (dim {dim} is "
                            f"{values[dim]:g}): outside the range of motion features")
        if name == "Std.npy":
            tiny = values < MIN_STD
            if tiny.any():
                dim = int(np.argmax(tiny))
                problems.append(f"{root / name}: {int(tiny.sum())} value(s) below {MIN_STD:g} (dim {dim} is "
                                f"{values[dim]:g}): normalising divides by Std and would blow up; use 1 for a "
                                "constant feature")
    return problems


def range_problems(data: SplitData) -> dict[int, str]:
    """Clips (row in `data`) holding finite feature values with |x| > MAX_ABS_VALUE -> problem line.

    One pass over the split's (memory-mapped) features in chunks, per-row max/min only, so a large
    split costs one sequential read and no big temporaries.
    """
    features, offsets = data.features, np.asarray(data.offsets)
    bad_rows = []
    for lo in range(0, len(features), _ROWS_PER_CHUNK):
        block = np.asarray(features[lo : lo + _ROWS_PER_CHUNK])
        rows = np.flatnonzero((block.max(axis=1) > MAX_ABS_VALUE) | (block.min(axis=1) < -MAX_ABS_VALUE))
        bad_rows.append(rows + lo)
    rows = np.concatenate(bad_rows) if bad_rows else np.zeros(0, np.int64)
    problems = {}
    for clip in np.unique(np.searchsorted(offsets, rows, side="right") - 1).tolist():
        big = np.abs(data.motion(clip)) > MAX_ABS_VALUE
        frame = int(np.argmax(big.any(axis=1)))
        largest = float(np.abs(data.motion(clip)).max())
        problems[clip] = (f"{feature_path(data.root, data.ids[clip])}: {int(big.sum())} value(s) with |x| > "
                          f"{MAX_ABS_VALUE:g} (largest {largest:.3g}), first in frame {frame}: outside the range of "
                          "motion features (they overflow once normalised)")
    return problems


def without_clips(data: SplitData, rows: Iterable[int], problems: list[str]) -> SplitData:
    """`data` without the clips at `rows` (same feature array), their problems appended."""
    drop = set(rows)
    keep = [i for i in range(len(data)) if i not in drop]
    return SplitData(data.root, data.split, [data.ids[i] for i in keep], data.lengths[keep], data.offsets[keep],
                     data.features, [data.captions[i] for i in keep], list(data.problems) + list(problems),
                     data.from_cache)


def _record(results: dict, ids: list[str], data: SplitData) -> None:
    """Store each id's (frames, captions), or its problem: the reader keeps problems in id order;
    readable clips with out-of-range values are problems too."""
    good = dict(zip(data.ids, zip(data.lengths.tolist(), data.captions)))
    out_of_range = {data.ids[row]: problem for row, problem in range_problems(data).items()}
    bad = iter(data.problems)
    for clip_id in ids:
        if clip_id not in results:
            if clip_id in out_of_range:
                results[clip_id] = out_of_range[clip_id]
            else:
                results[clip_id] = good[clip_id] if clip_id in good else next(bad)


def _summarise(root: Path, split: str, ids: list[str], results: dict, spec: DatasetSpec) -> SplitSummary:
    good = [i for i in ids if not isinstance(results[i], str)]
    lengths = np.asarray([results[i][0] for i in good], dtype=np.int64)
    data = SplitData(root, split, good, lengths, np.zeros_like(lengths), np.zeros((0, spec.feature_dim), np.float32),
                     [results[i][1] for i in good])
    items = build_items(data, spec)
    return SplitSummary(
        listed=len(ids),
        readable=len(good),
        items=len(items),
        sub_items=sum("#" in i for i in items.ids),
        too_short=int((lengths < spec.min_length).sum()),
        too_long=int((lengths >= spec.max_clip_length).sum()),
    )


def _guess_dataset(report: CheckReport) -> None:
    """A hint when Mean.npy has the width of another dataset (a KIT folder checked as HumanML3D, ...)."""
    try:
        width = load_npy(report.root / "Mean.npy").shape[-1]
    except (StableMoError, IndexError):
        return
    for other in DATASETS.values():
        if other.name != report.spec.name and other.feature_dim == width:
            report.notes.append(f"Mean.npy is {width}-d: this looks like a {other.name} folder (--dataset {other.name})")


def _add_notes(report: CheckReport, readable: set[str]) -> None:
    feature_dir = report.root / FEATURE_DIR
    if feature_dir.is_dir():
        on_disk = {p.stem for p in feature_dir.glob("*.npy")}
        unlisted = on_disk - readable
        if unlisted:
            report.notes.append(f"{len(unlisted)} feature file(s) in {FEATURE_DIR}/ are in no split "
                                f"(or unreadable), e.g. {min(unlisted)}")
    else:
        report.problems.append(f"{feature_dir}: feature folder not found")
    if not (report.root / JOINT_DIR).is_dir():
        report.notes.append(f"{JOINT_DIR}/ absent (not needed for training; used to view the reference joints)")


def _stats_line(name: str, values: list[int]) -> str:
    if not values:
        return f"{name}: none"
    a = np.asarray(values)
    return f"{name}: min {a.min()}, mean {a.mean():.1f}, median {np.median(a):g}, max {a.max()}"


def length_histogram(lengths: list[int], spec: DatasetSpec, bin_width: int = 20, width: int = 40) -> list[str]:
    """Text histogram of clip lengths in frames; the last bin holds clips the loader drops as too long."""
    edges = list(range(0, spec.max_clip_length + 1, bin_width))
    counts = np.histogram(np.clip(lengths, 0, spec.max_clip_length), bins=edges + [10**9])[0] if lengths else []
    peak = max(max(counts, default=0), 1)
    lines = []
    for lo, count in zip(edges, counts):
        label = f">={lo}" if lo >= spec.max_clip_length else f"{lo}-{lo + bin_width - 1}"
        flag = "  (dropped: too long)" if lo >= spec.max_clip_length else (
            "  (partly below min length)" if lo < spec.min_length < lo + bin_width else
            "  (dropped: too short)" if lo + bin_width <= spec.min_length else "")
        bar = "#" * int(round(width * count / peak))
        lines.append(f"  {label:>8} | {bar:<{width}} {count}{flag if count else ''}")
    return lines


def notes_and_problems(notes: list[str], problems: list[str], max_problems: int) -> list[str]:
    """The closing lines of a check's report (a folder's or shards'): notes, then up to
    `max_problems` problems and how many more there are."""
    out = ["", "notes:"] + [f"  - {n}" for n in notes] if notes else []
    out.append("")
    if not problems:
        return [*out, "problems: none"]
    out.append(f"problems ({len(problems)}):")
    out += [f"  - {p}" for p in problems[:max_problems]]
    if len(problems) > max_problems:
        out.append(f"  ... and {len(problems) - max_problems} more (--all-problems lists them)")
    return out


def format_report(report: CheckReport, max_problems: int = 30) -> str:
    spec = report.spec
    out = [f"dataset: {report.root} ({spec.name}: {spec.feature_dim}-d features, {spec.fps:g} fps, "
           f"clips used when {spec.min_length} <= frames < {spec.max_clip_length})", "", "splits:"]
    out.append(f"  {'split':<10} {'listed':>7} {'readable':>9} {'items':>7} {'sub-capt.':>9} {'too short':>9} {'too long':>8}")
    for name, s in report.splits.items():
        out.append(f"  {name:<10} {s.listed:>7} {s.readable:>9} {s.items:>7} {s.sub_items:>9} {s.too_short:>9} {s.too_long:>8}")
    out += ["", f"clip lengths (frames; {len(report.lengths)} readable clips):"]
    out += length_histogram(report.lengths, spec)
    n_caps = sum(report.captions_per_motion)
    out += ["", f"captions: {n_caps} ({report.sub_captions} with from/to time stamps), "
                f"vocabulary {len(report.vocabulary)} words",
            "  " + _stats_line("caption lines per motion", report.captions_per_motion),
            "  " + _stats_line("words per caption", report.words_per_caption)]
    return "\n".join(out + notes_and_problems(report.notes, report.problems, max_problems))
