"""The HumanML3D folder layout (also used by KIT-ML): per-dataset constants, splits, captions.

    <root>/new_joint_vecs/<id>.npy   features (T, D), float32
    <root>/texts/<id>.txt            one caption per line: `caption#tokens#from#to`
    <root>/Mean.npy, <root>/Std.npy  (D,) dataset statistics
    <root>/{train,val,test,train_val,all}.txt   one id per line
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

from stablemo.errors import StableMoError
from stablemo.motion.skeleton import MAX_FRAMES, get_skeleton

FEATURE_DIR = "new_joint_vecs"
JOINT_DIR = "new_joints"
TEXT_DIR = "texts"
SPLITS = ("train", "val", "test", "train_val", "all")
# Caption time stamps are seconds converted with 20 frames/s for both datasets (as the
# reference loaders do, even for KIT's 12.5 fps).
CAPTION_FPS = 20


@dataclass(frozen=True)
class DatasetSpec:
    """A dataset's loading rules; its body's facts (fps, joints, feature width) are its skeleton's
    (stablemo.motion.skeleton), their one home."""

    name: str
    skeleton: str
    min_length: int  # clips (and sub-captioned windows) shorter than this are dropped
    max_clip_length: int = 200  # clips this long or longer are dropped
    max_length: int = MAX_FRAMES  # training crop / padding length
    unit_length: int = 4  # evaluation crops are multiples of this

    @property
    def fps(self) -> float:
        return get_skeleton(self.skeleton).fps

    @property
    def num_joints(self) -> int:
        return get_skeleton(self.skeleton).num_joints

    @property
    def feature_dim(self) -> int:
        return get_skeleton(self.skeleton).feature_dim

    @property
    def contact_dims(self) -> slice:
        return slice(self.feature_dim - 4, self.feature_dim)


DATASETS: dict[str, DatasetSpec] = {
    "humanml3d": DatasetSpec("humanml3d", "humanml3d", min_length=40),
    "kit": DatasetSpec("kit", "kit", min_length=24),
}


def get_spec(name: str) -> DatasetSpec:
    try:
        return DATASETS[name.lower()]
    except KeyError:
        raise StableMoError(f"dataset={name!r}: unknown dataset (choose from {', '.join(DATASETS)})") from None


def check_root(root: str | Path) -> Path:
    root = Path(root)
    if not root.is_dir():
        raise StableMoError(f"{root}: dataset folder not found")
    return root


def feature_path(root: Path, clip_id: str) -> Path:
    return root / FEATURE_DIR / f"{clip_id}.npy"


def text_path(root: Path, clip_id: str) -> Path:
    return root / TEXT_DIR / f"{clip_id}.txt"


def split_path(root: Path, split: str) -> Path:
    return root / f"{split}.txt"


def read_split(root: str | Path, split: str) -> list[str]:
    """Ids of one split, in file order; blank lines ignored, duplicates are an error."""
    path = split_path(check_root(root), split)
    if not path.is_file():
        raise StableMoError(f"{path}: split file not found")
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except (OSError, UnicodeDecodeError) as err:
        raise StableMoError(f"{path}: cannot read split file ({err})") from None
    ids: list[str] = []
    seen: set[str] = set()
    for lineno, line in enumerate(lines, 1):
        clip_id = line.strip()
        if not clip_id:
            continue
        if "/" in clip_id or "\\" in clip_id or clip_id.startswith("."):
            raise StableMoError(f"{path}:{lineno}: invalid id {clip_id!r}")
        if clip_id in seen:
            raise StableMoError(f"{path}:{lineno}: id {clip_id!r} listed twice")
        seen.add(clip_id)
        ids.append(clip_id)
    if not ids:
        raise StableMoError(f"{path}: split file lists no ids")
    return ids


class Caption(NamedTuple):
    """One caption line. A NamedTuple because a full split holds ~70k of them (cheap to build)."""

    text: str
    tokens: str  # space-separated `word/POS` (spaCy coarse tags)
    start: float  # seconds; 0 and 0 = the whole clip
    end: float

    @property
    def whole_clip(self) -> bool:
        return self.start == 0.0 and self.end == 0.0

    def frames(self) -> tuple[int, int]:
        """Frame window [start, end) of a sub-caption."""
        return int(self.start * CAPTION_FPS), int(self.end * CAPTION_FPS)


def _parse_time(value: str, where: str) -> float:
    try:
        t = float(value)
    except ValueError:
        raise StableMoError(f"{where}: time stamp {value!r} is not a number") from None
    if math.isnan(t):
        return 0.0
    if math.isinf(t) or t < 0:
        raise StableMoError(f"{where}: time stamp {value!r} must be finite and >= 0")
    return t


def parse_caption_line(line: str, where: str) -> Caption:
    """`caption#tokens#from#to` -> Caption. `where` names the file and line for errors."""
    fields = line.strip().split("#")
    if len(fields) < 4:
        raise StableMoError(f"{where}: malformed caption line (expected caption#tokens#from#to, found {len(fields)} field(s))")
    # A stray '#' inside the caption text is kept in the text; the last three fields are fixed.
    text = "#".join(fields[:-3]).strip()
    if not text:
        raise StableMoError(f"{where}: empty caption")
    tokens = " ".join(fields[-3].split())
    return Caption(text, tokens, _parse_time(fields[-2], where), _parse_time(fields[-1], where))


def read_captions(path: Path) -> list[Caption]:
    """All captions of a text file; an empty file, blank line or malformed line is an error."""
    if not path.is_file():
        raise StableMoError(f"{path}: caption file not found")
    try:
        data = path.read_bytes()
    except OSError as err:
        raise StableMoError(f"{path}: cannot read caption file ({err})") from None
    return parse_captions(data, path)


def parse_captions(data: bytes, path: Path) -> list[Caption]:
    """Captions from the bytes of the text file `path` (named in errors)."""
    try:
        content = data.decode("utf-8-sig")  # tolerate a byte-order mark
    except UnicodeDecodeError as err:
        raise StableMoError(f"{path}: caption file is not UTF-8 text ({err})") from None
    lines = content.rstrip().splitlines()
    if not lines:
        raise StableMoError(f"{path}: caption file is empty")
    captions = []
    for lineno, line in enumerate(lines, 1):
        if not line.strip():
            raise StableMoError(f"{path}:{lineno}: empty caption line")
        captions.append(parse_caption_line(line, f"{path}:{lineno}"))
    return captions
