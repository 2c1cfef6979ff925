"""Write the synthetic dataset in the HumanML3D folder layout.

    new_joint_vecs/<id>.npy  (T, 263) float32 features (stablemo.motion.joints_to_features)
    new_joints/<id>.npy      (T, 22, 3) float32 joint positions of the same T frames
    contacts/<id>.npy        (T, 4) uint8 ground-truth foot contacts [L_ankle, L_toe, R_ankle, R_toe]
    texts/<id>.txt           3 whole-clip captions + timed sub-captions for composites
    Mean.npy, Std.npy        statistics over all clips (std averaged within feature groups)
    train/val/test/train_val/all.txt   80 / 5 / 15 % split
    synth.json               generator version, seed, rest mode, caption vocabulary (when not plain),
                             count, per-action counts
    .stablemo-files.json     every file written, with its size (written last)

Replacing an earlier dataset: only one whose content is exactly what that file lists (a `data
check`/training read cache, .stablemo_cache, may go with it); one extra or changed file and the
folder is refused. The new dataset is built in a hidden sibling `.<name>.<random>.partial` and
swapped in atomically (footskate.atomicio.replace_dir), so the path holds the old dataset or the
new one at every instant. Ctrl-C or SIGTERM removes the partial folder; a harder kill's leftover
is removed by the next `data synth` into the same --out.

Size: at most MAX_NUM motions per dataset (about BYTES_PER_MOTION each on disk), and the
estimate must fit the free space beside --out; progress goes to stderr.

As in HumanML3D, `new_joints` and `new_joint_vecs` have the same number of frames: a motion is
generated with T+1 positions; its T feature rows describe frames 0..T-1 (the last position only
enters velocities and contact bits).

Motion i depends only on (seed, i), and statistics are summed in fixed chunks in index order, so
the output is identical for any number of worker processes.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import shutil
import sys
from collections import Counter
from pathlib import Path

import numpy as np
from tqdm import tqdm

from stablemo.data.cache import CACHE_DIRNAME
from stablemo.data.stats import feature_groups
from stablemo.data.synth.captions import CAPTION_MODES, DEFAULT_CAPTIONS
from stablemo.data.synth.compose import generate_motion, generate_path_walk, text_file
from stablemo.data.synth.idle import DEFAULT_REST, REST_MODES
from stablemo.errors import StableMoError
from stablemo.io import (
    atomic_dir,
    default_signals,
    output_dir_problem,
    ownership_problem,
    save_npy,
    terminate_as_interrupt,
    write_text,
)

VERSION = 1
FEATURE_DIM = 263
CHUNK = 25  # motions per work unit (fixed: the statistics' summation order must not depend on workers)
SPLIT_FRACTIONS = (0.80, 0.05, 0.15)  # train, val, test
MARKER = "synth.json"
MANIFEST = ".stablemo-files.json"  # every file this writer wrote: what may be replaced, exactly
MIN_NUM = 3  # train, val and test need a motion each
# HumanML3D has ~29k clips; 100k synthetic ones are ~21 GB and about an hour on two cores. Beyond
# that a typo (1e9) would fill the disk for days: refused, one line, before anything is written.
MAX_NUM = 100_000
# measured mean on disk, seed 0, 2000 motions: 205 kB per motion with the varied rest (154 frames
# on average), 149 kB with the tight one (112 frames)
BYTES_PER_MOTION = 210_000
PROGRESS_STEPS = 10  # without a terminal: one stderr line per 10 % of the motions
PROGRESS_MIN = 200  # motions: smaller runs take seconds and print no progress


def motion_rng(seed: int, index: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, index, VERSION]))


def is_path_walk(seed: int, index: int, share: float) -> bool:
    """Whether motion `index` is a path walk (compose.generate_path_walk), from its own stream, so
    that the other motions are those of the dataset without path walks, file for file."""
    return share > 0 and np.random.default_rng(np.random.SeedSequence([seed, index, VERSION, 1])).uniform() < share


def clip_id(index: int) -> str:
    return f"{index:06d}"


def _write_chunk(args) -> tuple[np.ndarray, np.ndarray, int, list[str]]:
    root, seed, indices, rest, path_walks, caption_mode = args
    from stablemo.motion import joints_to_features

    root = Path(root)
    total = np.zeros(FEATURE_DIM)
    total_sq = np.zeros(FEATURE_DIM)
    count = 0
    names: list[str] = []
    for i in indices:
        make = generate_path_walk if is_path_walk(seed, i, path_walks) else generate_motion
        m = make(motion_rng(seed, i), rest, caption_mode=caption_mode)
        feats = joints_to_features(m.joints, "humanml3d")  # (T, 263)
        T = len(feats)
        cid = clip_id(i)
        save_npy(root / "new_joint_vecs" / f"{cid}.npy", feats)
        save_npy(root / "new_joints" / f"{cid}.npy", m.joints[:T].astype(np.float32))
        save_npy(root / "contacts" / f"{cid}.npy", m.contacts[:T].astype(np.uint8))
        write_text(root / "texts" / f"{cid}.txt", text_file(m))
        f64 = feats.astype(np.float64)
        total += f64.sum(0)
        total_sq += (f64 * f64).sum(0)
        count += T
        names.append("+".join(m.actions))
    return total, total_sq, count, names


def _splits(num: int, seed: int) -> dict[str, list[str]]:
    order = np.random.default_rng(np.random.SeedSequence([seed, 7919])).permutation(num)
    n_val = max(1, round(SPLIT_FRACTIONS[1] * num))
    n_test = max(1, round(SPLIT_FRACTIONS[2] * num))
    ids = [clip_id(i) for i in order]
    test, val, train = ids[:n_test], ids[n_test:n_test + n_val], ids[n_test + n_val:]
    out = {"train": sorted(train), "val": sorted(val), "test": sorted(test)}
    out["train_val"] = sorted(set(out["train"]) | set(out["val"]))
    out["all"] = [clip_id(i) for i in range(num)]
    return out


def _is_synth(path: Path) -> bool:
    return (path / MARKER).is_file()


def check_num(num, flag: str = "num") -> int:
    """The number of motions: an int in [MIN_NUM, MAX_NUM] (the cap keeps a typo off the disk)."""
    if isinstance(num, bool) or not isinstance(num, (int, np.integer)):
        raise StableMoError(f"{flag}={num!r}: must be a whole number of motions")
    if not MIN_NUM <= num <= MAX_NUM:
        raise StableMoError(f"{flag}={num}: must be in [{MIN_NUM}, {MAX_NUM}] (train, val and test need a motion "
                            f"each; {MAX_NUM} motions are about {MAX_NUM * BYTES_PER_MOTION / 1e9:.0f} GB)")
    return int(num)


def check_share(share, flag: str = "path_walks") -> float:
    """The share of path walks: a number in [0, 1]."""
    if isinstance(share, bool) or not isinstance(share, (int, float, np.floating)) or not 0.0 <= float(share) <= 1.0:
        raise StableMoError(f"{flag}={share}: must be a share in [0, 1]")
    return float(share)


def _replace_problem(out_dir: Path) -> str | None:
    """Why the existing non-empty folder `out_dir` is not ours to replace, or None."""
    if not _is_synth(out_dir):
        return "folder is not empty and is not a synthetic dataset; choose another --out"
    problem = ownership_problem(out_dir, manifest=MANIFEST, derived=(CACHE_DIRNAME,))
    if problem:
        return f"{problem}; nothing was replaced (move them away, delete the folder yourself or choose another --out)"
    return None


def _check_target(out_dir: Path, num: int, prefix: str = "") -> None:
    """Refuse, before generating anything, a target that is not ours to replace or won't fit."""
    def refuse(reason: str):
        raise StableMoError(f"{prefix}{out_dir}: {reason}")

    if out_dir.is_symlink() or (out_dir.exists() and not out_dir.is_dir()):
        refuse("exists and is not a folder")
    if out_dir.is_dir() and any(out_dir.iterdir()):
        problem = _replace_problem(out_dir)
        if problem:
            refuse(problem)
    problem = output_dir_problem(out_dir.parent)
    if problem:
        refuse(f"cannot write beside it ({problem})")
    parent = next(p for p in (out_dir.parent, *out_dir.parent.parents) if p.exists())
    need, free = num * BYTES_PER_MOTION, shutil.disk_usage(parent).free
    if need > free:
        refuse(f"{num} motions need about {need / 1e9:.1f} GB and {parent} has {free / 1e9:.1f} GB free; "
               "pass a smaller --num")


class _Progress:
    """Motions written so far, on stderr: a bar on a terminal, else a line per PROGRESS_STEPS-th
    (nothing for runs under PROGRESS_MIN motions)."""

    def __init__(self, total: int):
        self.total, self.done, self.shown = total, 0, 0
        self.quiet = total < PROGRESS_MIN
        self.bar = tqdm(total=total, desc="synth", unit="motion") if sys.stderr.isatty() and not self.quiet else None

    def update(self, n: int) -> None:
        self.done += n
        if self.bar is not None:
            self.bar.update(n)
            return
        step = self.done * PROGRESS_STEPS // self.total
        if step > self.shown and not self.quiet:
            self.shown = step
            print(f"synth: {self.done}/{self.total} motions ({100 * self.done // self.total}%)",
                  file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _generate(tmp: Path, num: int, seed: int, workers: int, rest: str, path_walks: float,
              caption_mode: str) -> list[tuple]:
    """Write the clips into `tmp` in chunks; returns each chunk's statistics and action names."""
    jobs = [(str(tmp), seed, range(a, min(a + CHUNK, num)), rest, path_walks, caption_mode)
            for a in range(0, num, CHUNK)]
    bar = _Progress(num)
    results = []
    if workers == 1 or len(jobs) == 1:
        for job in jobs:
            results.append(_write_chunk(job))
            bar.update(len(job[2]))
    else:
        ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
        with ctx.Pool(workers, initializer=default_signals) as pool:
            for res in pool.imap(_write_chunk, jobs):  # ordered: fixed summation order
                results.append(res)
                bar.update(len(res[3]))
    bar.close()
    return results


def _write_summary(tmp: Path, results: list[tuple], num: int, seed: int, rest: str, path_walks: float,
                   caption_mode: str) -> None:
    """Mean/Std, the split lists and the marker file, from the chunks' statistics."""
    total = sum(r[0] for r in results)
    total_sq = sum(r[1] for r in results)
    count = sum(r[2] for r in results)
    mean = total / count
    std = np.sqrt(np.maximum(total_sq / count - mean * mean, 0.0))
    for group in feature_groups(FEATURE_DIM):
        std[group] = std[group].mean()
    std = np.maximum(std, 1e-6)  # a constant group (never expected) must not divide by zero
    save_npy(tmp / "Mean.npy", mean.astype(np.float32))
    save_npy(tmp / "Std.npy", std.astype(np.float32))
    for name, ids in _splits(num, seed).items():
        write_text(tmp / f"{name}.txt", "\n".join(ids) + "\n")
    kinds = Counter(a for r in results for names in r[3] for a in names.split("+"))
    meta = dict(generator="stablemo.data.synth", version=VERSION, seed=seed, rest=rest, num=num, fps=20,
                **({"path_walks": path_walks} if path_walks else {}),
                **({"captions": caption_mode} if caption_mode != DEFAULT_CAPTIONS else {}),
                skeleton="humanml3d", frames=int(count), action_counts=dict(sorted(kinds.items())),
                parts=dict(sorted(Counter(len(n.split("+")) for r in results for n in r[3]).items())))
    write_text(tmp / MARKER, json.dumps(meta, indent=2) + "\n")


def write_dataset(out_dir, num: int = 2000, seed: int = 0, workers: int | None = None,
                  flag: str | None = None, rest: str = DEFAULT_REST, path_walks: float = 0.0,
                  captions: str = DEFAULT_CAPTIONS) -> Path:
    """Generate `num` motions with `seed` into `out_dir` (HumanML3D layout); returns the folder.
    flag: the option that named `out_dir` (e.g. "--out"), to start its error lines.
    rest: the idle rest around each action (idle.REST_MODES).
    path_walks: the share of motions that are path walks (synth/path_walks.py: walks along curved
    paths in any direction, for training path control); the others are the dataset's without them.
    captions: the captions' vocabulary (captions.CAPTION_MODES); the motions are the same in each."""
    num = check_num(num)
    if int(seed) < 0:
        raise StableMoError(f"seed={seed}: must be >= 0")
    if rest not in REST_MODES:
        raise StableMoError(f"rest={rest!r}: must be one of {', '.join(REST_MODES)}")
    if captions not in CAPTION_MODES:
        raise StableMoError(f"captions={captions!r}: must be one of {', '.join(CAPTION_MODES)}")
    seed, path_walks = int(seed), check_share(path_walks)
    out_dir = Path(out_dir)
    workers = min(os.cpu_count() or 1, 2) if workers is None else int(workers)
    if workers < 1:
        raise StableMoError(f"workers={workers}: must be >= 1")
    prefix = f"{flag}: " if flag else ""
    _check_target(out_dir, num, prefix)
    try:
        # built in a fresh hidden sibling folder, swapped into place; an existing dataset is only
        # replaced when it is exactly what its file list says we wrote (checked again at the swap)
        with terminate_as_interrupt(), atomic_dir(out_dir, replaceable=lambda p: _replace_problem(p) is None,
                                                  manifest=MANIFEST, derived=(CACHE_DIRNAME,)) as tmp:
            for sub in ("new_joint_vecs", "new_joints", "contacts", "texts"):
                (tmp / sub).mkdir()
            _write_summary(tmp, _generate(tmp, num, seed, workers, rest, path_walks, captions), num, seed, rest,
                           path_walks, captions)
    except FileExistsError as err:
        raise StableMoError(f"{prefix}{out_dir}: changed while the dataset was written ({err.strerror}); "
                            "nothing replaced") from None
    except SystemExit:
        print(f"synth: interrupted; the partial dataset was removed, {out_dir} is as it was", file=sys.stderr)
        raise
    return out_dir
