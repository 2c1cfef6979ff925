"""`stablemo data import-bvh DIR --out DATASET`: BVH mocap of any rig -> a HumanML3D-layout dataset.

Per file: parse (errors name the file and line), resample to 20 fps (rotations by slerp, then
forward kinematics), take the 22 HumanML3D joints through a name map (ours/Mixamo, CMU, or a YAML
file), turn z-up files upright if asked, cut clips longer than 196 frames into consecutive windows,
and extract features with the project's own extraction (stablemo.motion.joints_to_features: it
rescales to the standard skeleton, so the file's units and proportions do not matter). Then the
dataset's Mean/Std, seeded 80/5/15 splits and captions (from a CSV or the file names). The folder
appears only when everything succeeded.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stablemo.bvh.names import load_name_map, resolve_name_map
from stablemo.bvh.resample import resample
from stablemo.bvh.rig import forward_kinematics
from stablemo.bvh.text import read_bvh
from stablemo.data.layout import DATASETS
from stablemo.errors import StableMoError

_SPEC = DATASETS["humanml3d"]  # imported mocap becomes HumanML3D clips
FPS = _SPEC.fps
WINDOW = _SPEC.max_length  # feature frames per clip at most (HumanML3D's maximum motion length)
MIN_FRAMES = _SPEC.min_length  # shorter clips are skipped by the HumanML3D loader
SPLIT_FRACTIONS = (0.80, 0.05, 0.15)
_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # (x, y, z) -> (x, z, -y)


@dataclass
class Clip:
    clip_id: str
    source: Path
    features: np.ndarray  # (T, 263) float32
    captions: list[str]


def bvh_joints(path: Path, name_map: dict[str, str] | None = None, up: str = "y", fps: float = FPS) -> np.ndarray:
    """The 22 HumanML3D joint positions (T, 22, 3) of a BVH file at `fps`, in the file's units."""
    anim = read_bvh(path)
    index = resolve_name_map(list(anim.rig.names), str(path), name_map)
    joints = forward_kinematics(resample(anim, fps))[:, index]  # (T, 22, 3)
    return joints @ _Z_UP.T if up == "z" else joints


def caption_from_name(path: Path) -> str:
    """'walk_forward_01.bvh' -> 'walk forward' (digits and separators dropped)."""
    words = re.findall(r"[A-Za-z]+", re.sub(r"([a-z])([A-Z])", r"\1 \2", path.stem))
    return " ".join(w.lower() for w in words) or "a motion"


def read_texts(path: Path, files: list[Path], root: Path) -> dict[Path, list[str]]:
    """CSV with a header `file,text`, one caption per row; `file` is a path under DIR or a stem."""
    if not path.is_file():
        raise StableMoError(f"--texts: {path}: file not found")
    try:
        rows = list(csv.DictReader(path.read_text(encoding="utf-8").splitlines()))
    except (UnicodeDecodeError, csv.Error) as err:
        raise StableMoError(f"--texts: {path}: not a readable UTF-8 CSV ({err})") from None
    if not rows or not {"file", "text"} <= set(rows[0]):
        raise StableMoError(f"--texts: {path}: expected a header row 'file,text' and one caption per row")
    by_key: dict[str, Path] = {}
    for f in files:
        by_key[f.relative_to(root).as_posix()] = f
        by_key.setdefault(f.stem, f)
    out: dict[Path, list[str]] = {f: [] for f in files}
    for n, row in enumerate(rows, start=2):
        key, text = (row.get("file") or "").strip(), (row.get("text") or "").strip()
        target = by_key.get(key) or by_key.get(Path(key).stem)
        if target is None:
            raise StableMoError(f"{path}:{n}: {key!r} names no BVH file under {root}")
        if not text or "#" in text:
            raise StableMoError(f"{path}:{n}: caption {'empty' if not text else 'contains #'}")
        out[target].append(text)
    missing = [f.relative_to(root).as_posix() for f, caps in out.items() if not caps]
    if missing:
        raise StableMoError(f"{path}: no caption for {len(missing)} file(s), e.g. {missing[0]}")
    return out


def _clip_ids(files: list[Path], root: Path) -> list[str]:
    ids = [re.sub(r"[^A-Za-z0-9_-]+", "_", f.relative_to(root).with_suffix("").as_posix()) for f in files]
    seen: dict[str, int] = {}
    out = []
    for i in ids:
        seen[i] = seen.get(i, 0) + 1
        out.append(i if seen[i] == 1 else f"{i}_{seen[i]}")
    return out


def windows(num_frames: int) -> list[tuple[int, int]]:
    """[start, stop) joint-frame ranges giving <= WINDOW feature frames each (stop - start - 1)."""
    out = [(a, min(a + WINDOW + 1, num_frames)) for a in range(0, max(num_frames - 1, 1), WINDOW)]
    if len(out) > 1 and out[-1][1] - out[-1][0] - 1 < MIN_FRAMES:
        out.pop()  # a short tail would be skipped by the loader anyway
    return out


def import_clips(src: Path, files: list[Path], captions: dict[Path, list[str]], name_map=None, up: str = "y") -> list[Clip]:
    from stablemo.motion import joints_to_features

    clips = []
    for f, base in zip(files, _clip_ids(files, src)):
        joints = bvh_joints(f, name_map, up)
        if len(joints) < 2:
            raise StableMoError(f"{f}: {len(joints)} frame(s) at {FPS:g} fps; need at least 2")
        spans = windows(len(joints))
        for k, (a, b) in enumerate(spans):
            try:
                feats = joints_to_features(joints[a:b], "humanml3d")
            except StableMoError as err:
                raise StableMoError(f"{f}: {err}") from None
            clip_id = base if len(spans) == 1 else f"{base}_{k:02d}"
            clips.append(Clip(clip_id, f, feats, captions[f]))
    return clips


def splits(ids: list[str], seed: int) -> dict[str, list[str]]:
    order = np.random.default_rng(np.random.SeedSequence([seed, 7919])).permutation(len(ids))
    n = len(ids)
    n_val = max(1, round(SPLIT_FRACTIONS[1] * n)) if n >= 3 else 0
    n_test = max(1, round(SPLIT_FRACTIONS[2] * n)) if n >= 3 else 0
    shuffled = [ids[i] for i in order]
    test, val, train = shuffled[:n_test], shuffled[n_test:n_test + n_val], shuffled[n_test + n_val:]
    out = {"train": sorted(train), "val": sorted(val), "test": sorted(test)}
    out["train_val"] = sorted(train + val)
    out["all"] = sorted(ids)
    return out


def import_bvh_dir(src: str | Path, out: str | Path, *, texts: str | Path | None = None,
                   name_map: str | Path | None = None, up: str = "y", seed: int = 0) -> list[Clip]:
    """Write the dataset; returns its clips. Everything is checked before the folder appears."""
    from stablemo.data.stats import compute_stats
    from stablemo.data.synth.captions import caption_line
    from stablemo.io import atomic_dir, check_output_dir, save_npy, write_text
    from stablemo.motion import features_to_joints

    src, out = Path(src), Path(out)
    if not src.is_dir():
        raise StableMoError(f"{src}: folder not found")
    if up not in ("y", "z"):
        raise StableMoError(f"--up {up!r}: choose y or z")
    files = sorted(p for p in src.rglob("*") if p.is_file() and p.suffix.lower() == ".bvh")
    if not files:
        raise StableMoError(f"{src}: no .bvh files")
    check_output_dir(out, "--out")
    if out.exists() and any(out.iterdir()):
        raise StableMoError(f"--out: {out}: folder is not empty; choose a new folder")
    mapping = load_name_map(name_map) if name_map is not None else None
    captions = read_texts(Path(texts), files, src) if texts is not None else {f: [caption_from_name(f)] for f in files}

    clips = import_clips(src, files, captions, mapping, up)
    mean, std = compute_stats((c.features for c in clips), 263)
    std = np.maximum(std, np.float32(1e-6))  # a constant group (e.g. one still clip) must not divide by zero
    with atomic_dir(out) as tmp:
        for c in clips:
            save_npy(tmp / "new_joint_vecs" / f"{c.clip_id}.npy", c.features)
            save_npy(tmp / "new_joints" / f"{c.clip_id}.npy", features_to_joints(c.features, "humanml3d").astype(np.float32))
            write_text(tmp / "texts" / f"{c.clip_id}.txt", "".join(caption_line(t) + "\n" for t in c.captions))
        save_npy(tmp / "Mean.npy", mean)
        save_npy(tmp / "Std.npy", std)
        for name, ids in splits([c.clip_id for c in clips], seed).items():
            write_text(tmp / f"{name}.txt", "".join(i + "\n" for i in ids))
    return clips
