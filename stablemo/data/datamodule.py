"""LightningDataModule over a HumanML3D-layout folder (HumanML3D or KIT-ML), or over its shards
(`stablemo data shard`, read by stablemo.data.streaming)."""

from __future__ import annotations

import random
import warnings
from typing import Literal

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader

from stablemo.data.cache import SplitData, load_split
from stablemo.data.check import (
    MAX_ABS_VALUE,
    MIN_STD,
    range_problems,
    stats_problems,
    without_clips,
)
from stablemo.data.collate import Collate
from stablemo.data.dataset import CROPS, MotionDataset
from stablemo.data.layout import check_root, get_spec, split_path
from stablemo.data.resumable import ResumableLoader
from stablemo.data.sampler import EpochSampler
from stablemo.data.stats import (
    apply_feat_bias,
    body_lengths,
    body_picks,
    load_model_stats,
)
from stablemo.data.streaming import ShardDataset, ShardSampler
from stablemo.errors import StableMoError
from stablemo.motion.skeleton import MAX_FRAMES


def seed_worker(worker_id: int) -> None:
    """Seed numpy/random in a worker from torch's per-worker seed (itself derived from the loader's generator)."""
    seed = torch.initial_seed() % 2**32
    np.random.seed(seed)
    random.seed(seed)


class MotionDataModule(L.LightningDataModule):
    """Batches: motion (B, T, D) normalised and zero-padded to a multiple of pad_multiple, mask (B, T) bool,
    length (B,) int64, text list[str] (one caption per item), tokens list[list[str]], id list[str].

    Args:
        data_dir: dataset folder in the HumanML3D layout (or give `shards`).
        shards: a shard folder written by `stablemo data shard` (local path or URL, see
            stablemo.data.shard_format) to stream from instead: bounded memory, each rank its own share
            of every epoch (stablemo.data.streaming). Splits are the manifest's train/val/test.
        dataset: "humanml3d" or "kit" (feature width, minimum length, fps, skeleton).
        batch_size, num_workers: DataLoader settings.
        pad_multiple: padded length is a multiple of this (the denoiser's length_multiple).
        max_length: training crop length (items longer than this are randomly cropped).
        feat_bias: std of the root (0:4) and contact dims is divided by this.
        seed: drives shuffling, caption choice, crops and worker seeds; the order of an epoch depends
            only on (seed, epoch).
        skip_bad: skip unreadable clips with a counted warning instead of raising.
        train_split, val_split, test_split: split file names (without .txt).
        eval_crop: crop rule of val/test items: "eval" (the evaluator's unit-length rule), "train" or "none".
        cache, cache_dir: memory-mapped split cache (default: <data_dir>/.stablemo_cache or ~/.cache/stablemo).
        drop_last: drop the last incomplete training batch.
        stats_dir: normalise with this dataset folder's Mean.npy/Std.npy instead of the data's own: a
            frozen network trained on that folder (a ControlNet's base, a fine-tune's start) must see
            new clips in the units it learned.
    """

    def __init__(
        self,
        data_dir: str | None = None,
        dataset: str = "humanml3d",
        batch_size: int = 64,
        num_workers: int = 0,
        pad_multiple: int = 16,
        max_length: int = MAX_FRAMES,
        feat_bias: float = 5.0,
        seed: int = 0,
        skip_bad: bool = False,
        train_split: str = "train",
        val_split: str = "val",
        test_split: str = "test",
        eval_crop: Literal["eval", "train", "none"] = "eval",
        cache: bool = True,
        cache_dir: str | None = None,
        drop_last: bool = False,
        shards: str | None = None,
        stats_dir: str | None = None,
    ):
        super().__init__()
        self.spec = get_spec(dataset)
        if data_dir is not None and shards is not None:
            raise StableMoError(f"data: both data_dir ({data_dir}) and shards ({shards}) given; to train from the "
                                "shards with a config that names a folder, add --data.data_dir=null")
        if data_dir is None and shards is None:
            raise StableMoError("data: give data_dir (a dataset folder) or shards (a shard folder or URL)")
        for name, value in (("batch_size", batch_size), ("pad_multiple", pad_multiple), ("max_length", max_length)):
            if value < 1:
                raise StableMoError(f"{name}={value}: must be >= 1")
        if num_workers < 0:
            raise StableMoError(f"num_workers={num_workers}: must be >= 0")
        if seed < 0:
            raise StableMoError(f"seed={seed}: must be >= 0")
        if eval_crop not in CROPS:
            raise StableMoError(f"eval_crop={eval_crop!r}: choose from {', '.join(CROPS)}")
        self.save_hyperparameters()
        self.data_dir, self.dataset = data_dir, self.spec.name
        self.batch_size, self.num_workers = batch_size, num_workers
        self.pad_multiple, self.max_length, self.feat_bias = pad_multiple, max_length, feat_bias
        self.seed, self.skip_bad = seed, skip_bad
        self.splits = {"train": train_split, "val": val_split, "test": test_split}
        self.eval_crop, self.cache, self.cache_dir, self.drop_last = eval_crop, cache, cache_dir, drop_last
        self.shards, self.stats_dir = shards, stats_dir
        self._manifest = None
        self.datasets: dict[str, MotionDataset | ShardDataset] = {}
        self._splits: dict[str, SplitData] = {}  # by split name: read (and warned about) once
        self._range_checked: set[str] = set()
        self._stats: tuple[np.ndarray, np.ndarray] | None = None
        self._skeleton = None

    # -- statistics and dataset facts (available before setup) --------------------------------
    @property
    def feature_dim(self) -> int:
        return self.spec.feature_dim

    @property
    def min_length(self) -> int:
        return self.spec.min_length

    @property
    def fps(self) -> float:
        return self.spec.fps

    @property
    def manifest(self):
        """The shard folder's manifest (shards mode), read once."""
        if self._manifest is None:
            from stablemo.data.shard_format import MANIFEST, join, read_manifest

            manifest = read_manifest(self.shards)
            if manifest.spec.name != self.spec.name:
                raise StableMoError(f"{join(self.shards, MANIFEST)}: holds {manifest.spec.name} clips, "
                                    f"but dataset={self.spec.name!r} (set --data.dataset={manifest.spec.name})")
            big = np.abs(manifest.mean) > MAX_ABS_VALUE
            if big.any() or (manifest.std < MIN_STD).any():
                raise StableMoError(f"{join(self.shards, MANIFEST)}: stats outside the range of motion features "
                                    f"(|mean| > {MAX_ABS_VALUE:g} or std < {MIN_STD:g})")
            self._manifest = manifest
        return self._manifest

    def _load_stats(self) -> tuple[np.ndarray, np.ndarray]:
        if self._stats is None and self.shards is not None and self.stats_dir is None:
            self._stats = self.manifest.mean, apply_feat_bias(self.manifest.std, self.feat_bias)
        if self._stats is None:
            root = check_root(self.stats_dir or self.data_dir)
            stats = load_model_stats(root, self.spec, self.feat_bias)
            problems = stats_problems(root, self.spec)  # finite but absurd: training would diverge
            if problems:
                raise StableMoError(problems[0])
            self._stats = stats
        return self._stats

    @property
    def mean(self) -> np.ndarray:
        """(D,) float32 model mean."""
        return self._load_stats()[0]

    @property
    def std(self) -> np.ndarray:
        """(D,) float32 model std (feat_bias applied)."""
        return self._load_stats()[1]

    @property
    def skeleton(self):
        if self._skeleton is None:
            from stablemo.motion import get_skeleton

            self._skeleton = get_skeleton(self.spec.skeleton)
        return self._skeleton

    @property
    def body(self) -> np.ndarray:
        """(J,) bone lengths of the training motions (parent -> joint, root 0): the median over the
        frames of up to BODY_CLIPS clips spread over the train split. A bundle stores them, and
        generation puts every motion on this body (stablemo.inference.finish). Clips made by our
        extraction all keep the skeleton's standard body; this also holds for data that does not."""
        if self.shards is not None:
            if self.manifest.body is not None:
                return self.manifest.body  # measured on the same clips by `stablemo data shard`
            data = self._dataset("train").shard(0).data
            return body_lengths((data.motion(int(i)) for i in body_picks(len(data.ids))), self.skeleton)
        data = self._checked_split(self.splits["train"])
        return body_lengths((data.motion(int(i)) for i in body_picks(len(data.ids))), self.skeleton)

    # -- Lightning hooks -------------------------------------------------------------------------
    def prepare_data(self) -> None:
        """Build the split caches once (rank 0) so the other ranks only map them."""
        if self.shards is not None:
            self.manifest  # noqa: B018  (a missing or broken manifest is named before training starts)
            return
        check_root(self.data_dir)
        if self.cache:
            for split in dict.fromkeys(self.splits.values()):
                if (check_root(self.data_dir) / f"{split}.txt").is_file():
                    self._read_split(split)

    def _read_split(self, split: str) -> SplitData:
        """A split's clips, read once per data module: prepare_data and setup used to read it twice,
        and with skip_bad every skipped clip was announced twice."""
        if split not in self._splits:
            self._splits[split] = load_split(self.data_dir, split, self.spec, skip_bad=self.skip_bad,
                                             cache=self.cache, cache_dir=self.cache_dir)
        return self._splits[split]

    def _checked_split(self, split: str) -> SplitData:
        """The split without clips whose values are out of range (|x| > 1e4): refused like the other
        corruptions, or with skip_bad skipped with one counted warning."""
        data = self._read_split(split)
        if split in self._range_checked:
            return data
        problems = range_problems(data)
        if problems:
            if not self.skip_bad:
                raise StableMoError(next(iter(problems.values())))
            lines = list(problems.values())
            shown = "\n  ".join(lines[:5]) + ("\n  ..." if len(lines) > 5 else "")
            warnings.warn(f"{split_path(check_root(self.data_dir), split)}: skipped {len(lines)} clip(s) with "
                          f"out-of-range values:\n  {shown}", stacklevel=2)
            data = without_clips(data, problems, lines)
        self._range_checked.add(split)
        self._splits[split] = data
        return data

    def _shard_dataset(self, role: str) -> ShardDataset:
        from stablemo.data.shard_format import MANIFEST, join

        mean, std = self._load_stats()
        split = self.splits[role]
        ds = ShardDataset(self.manifest, split, mean, std, max_length=self.max_length,
                          crop="train" if role == "train" else self.eval_crop, seed=self.seed)
        if len(ds) == 0:
            raise StableMoError(f"{join(self.shards, MANIFEST)}: no usable items in the {split} split")
        return ds

    def _dataset(self, role: str) -> MotionDataset | ShardDataset:
        if role not in self.datasets and self.shards is not None:
            self.datasets[role] = self._shard_dataset(role)
        if role not in self.datasets:
            mean, std = self._load_stats()
            data = self._checked_split(self.splits[role])
            ds = MotionDataset(data, self.spec, mean, std, max_length=self.max_length,
                               crop="train" if role == "train" else self.eval_crop, seed=self.seed)
            if len(ds) == 0:
                raise StableMoError(
                    f"{check_root(self.data_dir) / (self.splits[role] + '.txt')}: no usable items "
                    f"({len(data)} clip(s) read; clips need {self.spec.min_length} <= frames < "
                    f"{self.spec.max_clip_length} and a caption)"
                )
            self.datasets[role] = ds
        return self.datasets[role]

    def setup(self, stage: str | None = None) -> None:
        roles = {"fit": ("train", "val"), "validate": ("val",), "test": ("test",), "predict": ("test",)}
        for role in roles.get(stage or "", ("train", "val", "test")):
            # Training without a val split is allowed; val_dataloader() then names the missing file.
            if stage == "fit" and role == "val" and not self._has_split(self.splits[role]):
                continue
            self._dataset(role)

    def _has_split(self, split: str) -> bool:
        if self.shards is not None:
            return split in self.manifest.splits
        return (check_root(self.data_dir) / f"{split}.txt").is_file()

    def _loader(self, role: str, shuffle: bool) -> DataLoader:
        ds = self._dataset(role)
        if isinstance(ds, ShardDataset):
            # each rank its own share of the epoch (Lightning leaves a DistributedSampler in place)
            trainer = self.trainer
            rank, world = (trainer.global_rank, trainer.world_size) if trainer is not None else (0, 1)
            sampler = ShardSampler(ds.items_per_shard, seed=self.seed, shuffle=shuffle, per_epoch=shuffle,
                                   rank=rank, world_size=world)
        else:
            sampler = EpochSampler(len(ds), seed=self.seed, shuffle=shuffle, per_epoch=shuffle)
        # ResumableLoader: a DataLoader whose in-epoch position is saved in Lightning checkpoints
        return ResumableLoader(
            ds,
            batch_size=self.batch_size,
            sampler=sampler,
            collate_fn=Collate(self.pad_multiple),
            num_workers=self.num_workers,
            worker_init_fn=seed_worker,
            generator=torch.Generator().manual_seed(self.seed),
            persistent_workers=self.num_workers > 0,
            drop_last=self.drop_last and shuffle,
        )

    def train_dataloader(self) -> DataLoader:
        return self._loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader("val", shuffle=False)

    def test_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)

    def predict_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)
