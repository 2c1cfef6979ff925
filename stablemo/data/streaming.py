"""Training items streamed from shards (stablemo.data.shards): bounded memory, seeded order, rank shares.

Items are numbered as MotionDataset numbers them (build_items over the split's clips in order, shard
after shard), and an item's caption and crop come from the same generator, seeded by (seed, epoch,
item): a single-source shard folder yields exactly the items of its source folder.

The epoch order (ShardSampler) is ours, not a library's: WebDataset, LitData and MosaicML streaming
all shuffle inside their own iterators, none of which lets a resumed run skip to item k of an epoch
without reading the k items before it, nor keeps our per-item seeds (scripts/bench/shard_libraries.py
and docs/training.md say what was measured). Order of epoch e, for rank r of W:

    1. the shards in a permutation drawn from (seed, e);
    2. their items laid end to end, cut into W equal contiguous shares (the last N mod W items of the
       epoch are left out, a different few every epoch), rank r takes share r: each rank reads only
       about 1/W of the shards, and every rank has the same number of batches;
    3. inside the share, items shuffled within consecutive windows of `shuffle_shards` shards' worth
       of items (a permutation drawn from (seed, e, r, window)).

A rank therefore holds at most ~shuffle_shards + 1 decoded shards at a time (an LRU of decoded
shards per loader worker), whatever the corpus size. The order is a pure function of (seed, epoch,
rank, world size): resuming at item k of an epoch starts the sampler at k (`start_at`) without
reading anything before it.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Iterator

import numpy as np
from torch.utils.data import Dataset, DistributedSampler

from stablemo.data.dataset import MotionDataset
from stablemo.data.shard_format import (
    Manifest,
    ShardInfo,
    decode_shard,
    join,
    read_bytes,
)
from stablemo.errors import StableMoError

SHUFFLE_SHARDS = 4  # shuffle window, in shards; memory per loader worker ~ (SHUFFLE_SHARDS + 2) decoded shards


class _ShardItems(MotionDataset):
    """The items of one decoded shard, numbered from `first` (their index in the whole split)."""

    def __init__(self, *args, first: int, **kwargs):
        super().__init__(*args, **kwargs)
        self.first = first

    def rng(self, index: int, epoch: int) -> np.random.Generator:
        return super().rng(self.first + index, epoch)


class ShardDataset(Dataset):
    """Items of one split of a shard folder. `dataset[(index, epoch)]` -> the same dict as MotionDataset.

    Shards are fetched whole (local path or URL) and decoded on first use; the `cache_shards` most
    recently used stay decoded.
    """

    def __init__(self, manifest: Manifest, split: str, mean: np.ndarray, std: np.ndarray, *,
                 max_length: int | None = None, crop: str = "train", seed: int = 0,
                 cache_shards: int = SHUFFLE_SHARDS + 2):
        self.manifest, self.split = manifest, split
        self.shards: list[ShardInfo] = manifest.shards(split)
        self.mean, self.std = np.asarray(mean, np.float32), np.asarray(std, np.float32)
        self.max_length, self.crop, self.seed = max_length, crop, int(seed)
        counts = np.asarray([s.items for s in self.shards], np.int64)
        self.first = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)  # (S + 1,) item offsets
        self.cache_shards = max(1, int(cache_shards))
        self._decoded: OrderedDict[int, _ShardItems] = OrderedDict()

    def __len__(self) -> int:
        return int(self.first[-1])

    @property
    def items_per_shard(self) -> np.ndarray:
        return np.diff(self.first)

    def shard(self, s: int) -> _ShardItems:
        if s in self._decoded:
            self._decoded.move_to_end(s)
            return self._decoded[s]
        info = self.shards[s]
        where = join(self.manifest.location, info.file)
        data = decode_shard(read_bytes(where), where, self.manifest.spec)
        items = _ShardItems(data, self.manifest.spec, self.mean, self.std, max_length=self.max_length,
                            crop=self.crop, seed=self.seed, first=int(self.first[s]))
        if len(data) != info.clips or len(items) != info.items:
            raise StableMoError(f"{where}: holds {len(data)} clips / {len(items)} items, the manifest says "
                                f"{info.clips} / {info.items} (`stablemo data check` the folder)")
        self._decoded[s] = items
        while len(self._decoded) > self.cache_shards:
            self._decoded.popitem(last=False)
        return items

    def __getitem__(self, key: int | tuple[int, int]) -> dict:
        index, epoch = key if isinstance(key, tuple) else (key, 0)
        index = int(index)
        if not 0 <= index < len(self):
            raise IndexError(f"item {index} out of range for {len(self)} items")
        s = int(np.searchsorted(self.first, index, side="right") - 1)
        return self.shard(s)[(index - int(self.first[s]), int(epoch))]

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_decoded"] = OrderedDict()  # a worker process decodes its own shards
        return state


class ShardSampler(DistributedSampler):
    """Yields (item index, epoch) pairs of this rank's share in the order the module docstring gives.

    A DistributedSampler by type only, so that Lightning leaves it in place instead of wrapping it in
    its own distributed sampler (it splits the epoch by rank itself); nothing of the parent is used.
    """

    def __init__(self, items_per_shard: np.ndarray, *, seed: int = 0, shuffle: bool = True,
                 per_epoch: bool = True, rank: int = 0, world_size: int = 1, shuffle_shards: int = SHUFFLE_SHARDS):
        if not 0 <= rank < world_size:
            raise StableMoError(f"rank {rank} of world size {world_size}: out of range")
        self.counts = np.asarray(items_per_shard, np.int64)
        self.first = np.concatenate([[0], np.cumsum(self.counts)]).astype(np.int64)
        self.seed, self.shuffle, self.per_epoch = int(seed), shuffle, per_epoch
        self.rank, self.world_size = int(rank), int(world_size)
        self.window = max(1, round(shuffle_shards * self.counts.mean())) if len(self.counts) else 1
        self.epoch = 0
        self._start = 0  # one-shot: the next iteration begins at this position of the share

    def set_epoch(self, epoch: int) -> None:
        if self.per_epoch:
            self.epoch = int(epoch)

    def start_at(self, position: int) -> None:
        """Begin the next iteration at `position` of this epoch's share (a mid-epoch resume)."""
        self._start = int(position)

    def __len__(self) -> int:
        total = int(self.first[-1])
        return total // self.world_size if self.world_size > 1 else total

    def order(self) -> np.ndarray:
        """(len(self),) item indices of this rank's share of the current epoch."""
        shards = np.arange(len(self.counts))
        if self.shuffle:
            shards = np.random.default_rng([self.seed, self.epoch, 0, 2]).permutation(len(self.counts))
        stream = np.concatenate([np.arange(self.first[s], self.first[s + 1]) for s in shards]) if len(shards) else \
            np.zeros(0, np.int64)
        n = len(self)
        share = stream[self.rank * n : (self.rank + 1) * n]
        if self.shuffle:
            share = share.copy()
            for w, lo in enumerate(range(0, n, self.window)):
                rng = np.random.default_rng([self.seed, self.epoch, 3, self.rank, w])
                share[lo : lo + self.window] = share[lo : lo + self.window][rng.permutation(len(share[lo : lo + self.window]))]
        return share

    def __iter__(self) -> Iterator[tuple[int, int]]:
        start, self._start = self._start, 0
        epoch = self.epoch
        return iter([(int(i), epoch) for i in self.order()[start:]])
