"""Write the synthetic dataset in the HumanML3D folder layout.

    new_joint_vecs/<id>.npy  (T, 263) float32 features (stablemo.motion.joints_to_features)
    new_joints/<id>.npy      (T, 22, 3) float32 joint positions of the same T frames
    contacts/<id>.npy        (T, 4) uint8 ground-truth foot contacts [L_ankle, L_toe, R_ankle, R_toe]
    texts/<id>.txt           3 whole-clip captions + timed sub-captions for composites
    Mean.npy, Std.npy        statistics over all clips (std averaged within feature groups)
    train/val/test/train_val/all.txt   80 / 5 / 15 % split
    synth.json               generator version, seed, count, per-action counts

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
from collections import Counter
from pathlib import Path

import numpy as np
from tqdm import tqdm

from stablemo.data.stats import feature_groups
from stablemo.data.synth.compose import generate_motion, text_file
from stablemo.errors import StableMoError
from stablemo.io import atomic_dir, output_dir_problem, save_npy, write_text

VERSION = 1
FEATURE_DIM = 263
CHUNK = 25  # motions per work unit (fixed: the statistics' summation order must not depend on workers)
SPLIT_FRACTIONS = (0.80, 0.05, 0.15)  # train, val, test
MARKER = "synth.json"


def motion_rng(seed: int, index: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, index, VERSION]))


def clip_id(index: int) -> str:
    return f"{index:06d}"


def _write_chunk(args) -> tuple[np.ndarray, np.ndarray, int, list[str]]:
    root, seed, indices = args
    from stablemo.motion import joints_to_features

    root = Path(root)
    total = np.zeros(FEATURE_DIM)
    total_sq = np.zeros(FEATURE_DIM)
    count = 0
    names: list[str] = []
    for i in indices:
        m = generate_motion(motion_rng(seed, i))
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


def _check_target(out_dir: Path) -> None:
    """Refuse, before generating anything, a target that is not ours to replace."""
    if out_dir.is_symlink() or (out_dir.exists() and not out_dir.is_dir()):
        raise StableMoError(f"{out_dir}: exists and is not a folder")
    if out_dir.is_dir() and any(out_dir.iterdir()) and not _is_synth(out_dir):
        raise StableMoError(f"{out_dir}: folder is not empty and is not a synthetic dataset; choose another --out")
    problem = output_dir_problem(out_dir.parent)
    if problem:
        raise StableMoError(f"{out_dir}: cannot write beside it ({problem})")


def _generate(tmp: Path, num: int, seed: int, workers: int) -> list[tuple]:
    """Write the clips into `tmp` in chunks; returns each chunk's statistics and action names."""
    jobs = [(str(tmp), seed, range(a, min(a + CHUNK, num))) for a in range(0, num, CHUNK)]
    bar = tqdm(total=num, desc="synth", unit="motion", disable=None)
    results = []
    if workers == 1 or len(jobs) == 1:
        for job in jobs:
            results.append(_write_chunk(job))
            bar.update(len(job[2]))
    else:
        ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
        with ctx.Pool(workers) as pool:
            for res in pool.imap(_write_chunk, jobs):  # ordered: fixed summation order
                results.append(res)
                bar.update(len(res[3]))
    bar.close()
    return results


def _write_summary(tmp: Path, results: list[tuple], num: int, seed: int) -> None:
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
    meta = dict(generator="stablemo.data.synth", version=VERSION, seed=seed, num=num, fps=20,
                skeleton="humanml3d", frames=int(count), action_counts=dict(sorted(kinds.items())),
                parts=dict(sorted(Counter(len(n.split("+")) for r in results for n in r[3]).items())))
    write_text(tmp / MARKER, json.dumps(meta, indent=2) + "\n")


def write_dataset(out_dir, num: int = 2000, seed: int = 0, workers: int | None = None) -> Path:
    """Generate `num` motions with `seed` into `out_dir` (HumanML3D layout); returns the folder."""
    if int(num) < 3:
        raise StableMoError(f"num={num}: must be >= 3 (train, val and test need a motion each)")
    if int(seed) < 0:
        raise StableMoError(f"seed={seed}: must be >= 0")
    num, seed = int(num), int(seed)
    out_dir = Path(out_dir)
    workers = min(os.cpu_count() or 1, 2) if workers is None else int(workers)
    if workers < 1:
        raise StableMoError(f"workers={workers}: must be >= 1")
    _check_target(out_dir)
    try:
        # built in a fresh hidden sibling folder, renamed into place: a replaced dataset is ours (MARKER)
        with atomic_dir(out_dir, replaceable=_is_synth) as tmp:
            for sub in ("new_joint_vecs", "new_joints", "contacts", "texts"):
                (tmp / sub).mkdir()
            _write_summary(tmp, _generate(tmp, num, seed, workers), num, seed)
    except FileExistsError:
        raise StableMoError(f"{out_dir}: changed while the dataset was written; nothing replaced") from None
    return out_dir
