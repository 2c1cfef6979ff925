"""Training items: whole clips and sub-captioned windows, normalised, cropped, with one caption.

Randomness (caption choice, crop window) comes from a generator seeded by (seed, epoch, index),
so an item is the same whatever worker process builds it and whenever the epoch is replayed.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from stablemo.data.cache import SplitData, load_split
from stablemo.data.layout import Caption, DatasetSpec, get_spec
from stablemo.data.stats import load_model_stats, normalize
from stablemo.errors import StableMoError

CROPS = ("train", "eval", "none")


@dataclass(frozen=True)
class ItemIndex:
    """Where each item's frames live in SplitData, and the captions it may be paired with."""

    ids: list[str]
    clip: np.ndarray  # (N,) row in SplitData
    start: np.ndarray  # (N,) first frame within the clip
    length: np.ndarray  # (N,) number of frames
    captions: list[list[Caption]]

    def __len__(self) -> int:
        return len(self.ids)


def build_items(data: SplitData, spec: DatasetSpec) -> ItemIndex:
    """Whole clips with min <= T < max_clip_length (if they have a whole-clip caption) plus one item
    per sub-caption whose window [int(from*20), int(to*20)) has min <= length < max_clip_length.
    Sub-caption items are named `<clip>#<start>-<end>` (`.1`, `.2`, ... for repeated windows)."""
    ids: list[str] = []
    rows: list[tuple[int, int, int]] = []  # (clip row, start, length)
    captions: list[list[Caption]] = []

    def add(item_id: str, row: int, start: int, length: int, caps: list[Caption]) -> None:
        ids.append(item_id)
        rows.append((row, start, length))
        captions.append(caps)

    for row, (clip_id, n, caps) in enumerate(zip(data.ids, data.lengths.tolist(), data.captions)):
        if not spec.min_length <= n < spec.max_clip_length:
            continue
        whole = [c for c in caps if c.whole_clip]
        if whole:
            add(clip_id, row, 0, n, whole)
        repeats: dict[str, int] = {}
        for cap in caps:
            if cap.whole_clip:
                continue
            a, b = cap.frames()
            a, b = min(a, n), min(b, n)  # python slicing semantics of the reference loader
            if not spec.min_length <= b - a < spec.max_clip_length:
                continue
            item_id = f"{clip_id}#{a}-{b}"
            repeats[item_id] = repeats.get(item_id, 0) + 1
            add(item_id if repeats[item_id] == 1 else f"{item_id}.{repeats[item_id] - 1}", row, a, b - a, [cap])
    table = np.asarray(rows, dtype=np.int64).reshape(-1, 3)
    return ItemIndex(ids, table[:, 0], table[:, 1], table[:, 2], captions)


def crop_window(length: int, mode: str, max_length: int, unit_length: int, rng: np.random.Generator) -> tuple[int, int]:
    """(offset, new_length) of the crop of an item of `length` frames.

    train: a random window of max_length frames, only if the item is longer.
    eval:  the evaluator's rule: with p = 2/3 floor(L/unit)*unit frames, else (floor(L/unit) - 1)*unit,
           capped at max_length, at a random offset.
    none:  the whole item.
    """
    if mode == "none":
        return 0, length
    if mode == "train":
        new = min(length, max_length)
    elif mode == "eval":
        units = length // unit_length
        if rng.random() < 1 / 3:
            units -= 1
        new = min(max(units, 1) * unit_length, max_length, length)
    else:
        raise StableMoError(f"crop={mode!r}: choose from {', '.join(CROPS)}")
    offset = int(rng.integers(0, length - new + 1)) if new < length else 0
    return offset, new


class MotionDataset(Dataset):
    """Items of one split. `dataset[i]` or `dataset[(i, epoch)]` -> dict with
    motion (T, D) float32 tensor normalised, length, text (one caption), tokens list[str], id."""

    def __init__(
        self,
        data: SplitData,
        spec: DatasetSpec,
        mean: np.ndarray,
        std: np.ndarray,
        *,
        max_length: int | None = None,
        crop: str = "train",
        seed: int = 0,
    ):
        if crop not in CROPS:
            raise StableMoError(f"crop={crop!r}: choose from {', '.join(CROPS)}")
        if seed < 0:
            raise StableMoError(f"seed={seed}: must be >= 0")
        self.data, self.spec = data, spec
        self.mean, self.std = np.asarray(mean, np.float32), np.asarray(std, np.float32)
        self.max_length = spec.max_length if max_length is None else int(max_length)
        if self.max_length < 1:
            raise StableMoError(f"max_length={max_length}: must be >= 1")
        self.crop, self.seed = crop, int(seed)
        self.items = build_items(data, spec)

    @classmethod
    def from_folder(
        cls,
        data_dir: str | Path,
        split: str,
        dataset: str = "humanml3d",
        *,
        feat_bias: float = 5.0,
        max_length: int | None = None,
        crop: str = "train",
        seed: int = 0,
        skip_bad: bool = False,
        cache: bool = True,
        cache_dir: str | Path | None = None,
        progress: bool = True,
    ) -> MotionDataset:
        spec = get_spec(dataset)
        mean, std = load_model_stats(data_dir, spec, feat_bias)
        data = load_split(data_dir, split, spec, skip_bad=skip_bad, cache=cache, cache_dir=cache_dir, progress=progress)
        return cls(data, spec, mean, std, max_length=max_length, crop=crop, seed=seed)

    def __len__(self) -> int:
        return len(self.items)

    def rng(self, index: int, epoch: int) -> np.random.Generator:
        # The constant 1 separates item streams from the sampler's stream (see sampler.py).
        return np.random.default_rng([self.seed, epoch, 1, index])

    def __getitem__(self, key: int | tuple[int, int]) -> dict:
        index, epoch = key if isinstance(key, tuple) else (key, 0)
        index = int(index)
        if not -len(self) <= index < len(self):
            raise IndexError(f"item {index} out of range for {len(self)} items")
        index %= len(self)
        rng = self.rng(index, int(epoch))
        captions = self.items.captions[index]
        caption = captions[int(rng.integers(len(captions)))] if len(captions) > 1 else captions[0]
        offset, length = crop_window(int(self.items.length[index]), self.crop, self.max_length,
                                     self.spec.unit_length, rng)
        start = int(self.items.start[index]) + offset
        raw = self.data.motion(int(self.items.clip[index]))[start : start + length]  # (T, D)
        return {
            "motion": torch.from_numpy(normalize(raw, self.mean, self.std)),
            "length": length,
            "text": caption.text,
            "tokens": caption.tokens.split(),
            "id": self.items.ids[index],
        }
