"""HumanML3D / KIT-ML datasets: folder layout, cached reader, items, batches, LightningDataModule.

`MotionDataModule` is imported lazily (it pulls in Lightning) so `stablemo data check` starts fast.
"""

from stablemo.data.collate import Collate, pad_motions
from stablemo.data.dataset import MotionDataset, build_items, crop_window
from stablemo.data.layout import (
    DATASETS,
    Caption,
    DatasetSpec,
    get_spec,
    read_captions,
    read_split,
)
from stablemo.data.stats import (
    apply_feat_bias,
    compute_stats,
    denormalize,
    load_model_stats,
    normalize,
)

__all__ = [
    "DATASETS", "Caption", "Collate", "DatasetSpec", "MotionDataModule", "MotionDataset", "apply_feat_bias",
    "build_items", "compute_stats", "crop_window", "denormalize", "get_spec", "load_model_stats", "normalize",
    "pad_motions", "read_captions", "read_split",
]


def __getattr__(name: str):
    if name == "MotionDataModule":
        from stablemo.data.datamodule import MotionDataModule

        return MotionDataModule
    raise AttributeError(f"module 'stablemo.data' has no attribute {name!r}")
