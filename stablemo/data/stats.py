"""Feature statistics: the dataset's Mean/Std, the feat_bias convention, z-normalisation."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from stablemo.data.layout import DatasetSpec, check_root
from stablemo.errors import StableMoError
from stablemo.io import load_npy


def feature_groups(feature_dim: int) -> list[slice]:
    """The seven feature groups (root rot vel, root lin vel, root y, ric, rot6d, local vel, contacts)."""
    if (feature_dim + 1) % 12:
        raise StableMoError(f"feature_dim={feature_dim}: not of the form 12*J - 1")
    j = (feature_dim + 1) // 12
    edges = [0, 1, 3, 4, 4 + (j - 1) * 3, 4 + (j - 1) * 9, 4 + (j - 1) * 9 + j * 3, feature_dim]
    return [slice(a, b) for a, b in zip(edges[:-1], edges[1:])]


def apply_feat_bias(std: np.ndarray, feat_bias: float) -> np.ndarray:
    """Model std: root dims 0:4 and the 4 contact dims divided by feat_bias (MotionDiffuse/StableMoFusion)."""
    if not feat_bias > 0:
        raise StableMoError(f"feat_bias={feat_bias}: must be > 0")
    std = np.array(std, dtype=np.float32, copy=True)
    std[0:4] /= feat_bias
    std[-4:] /= feat_bias
    return std


def _check_stat(array: np.ndarray, path: Path, dim: int, positive: bool) -> np.ndarray:
    if array.shape != (dim,):
        raise StableMoError(f"{path}: expected shape ({dim},), found {tuple(array.shape)}")
    array = array.astype(np.float32)
    if not np.isfinite(array).all():
        raise StableMoError(f"{path}: contains NaN/Inf values")
    if positive and not (array > 0).all():
        raise StableMoError(f"{path}: std must be > 0 everywhere (dim {int(np.argmin(array > 0))} is {array.min()})")
    return array


def load_stat(root: str | Path, name: str, spec: DatasetSpec) -> np.ndarray:
    """One validated statistics file ("Mean.npy" or "Std.npy", the latter must be > 0) as float32 (D,)."""
    path = check_root(root) / name
    return _check_stat(load_npy(path), path, spec.feature_dim, positive=name == "Std.npy")


def load_dataset_stats(root: str | Path, spec: DatasetSpec) -> tuple[np.ndarray, np.ndarray]:
    """The dataset's own Mean.npy / Std.npy, validated, as float32 (D,)."""
    return load_stat(root, "Mean.npy", spec), load_stat(root, "Std.npy", spec)


def same_statistics(ours, theirs) -> bool:
    """Whether two copies of a model's feature statistics (mean or std, (D,)) are the same: equal shape,
    and equal within float32 round trips through JSON and checkpoints (relative 1e-4, absolute 1e-6).
    Training against a bundle (distillation, a ControlNet, `model.init_from`) needs the dataset to
    normalise with the statistics its network was trained with."""
    if ours is None or theirs is None:
        return False
    ours = np.asarray(ours, dtype=np.float64)
    theirs = np.asarray(theirs, dtype=np.float64)
    return ours.shape == theirs.shape and bool(np.allclose(ours, theirs, rtol=1e-4, atol=1e-6))


def load_model_stats(root: str | Path, spec: DatasetSpec, feat_bias: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    """(mean, std) used to normalise model inputs: dataset stats with feat_bias applied to std."""
    mean, std = load_dataset_stats(root, spec)
    return mean, apply_feat_bias(std, feat_bias)


def compute_stats(motions: Iterable[np.ndarray], feature_dim: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean/Std over all frames of all clips; std replaced by its group average (HumanML3D's recipe)."""
    count = 0
    total = np.zeros(feature_dim, np.float64)
    total_sq = np.zeros(feature_dim, np.float64)
    for m in motions:
        m = np.asarray(m, np.float64).reshape(-1, feature_dim)
        count += len(m)
        total += m.sum(0)
        total_sq += (m * m).sum(0)
    return stats_from_sums(count, total, total_sq)


def stats_from_sums(count: int, total: np.ndarray, total_sq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """compute_stats from the frame count and float64 (D,) sums of values and squares (so that parts
    of a corpus, e.g. shards written in several runs, can be summed separately)."""
    if count == 0:
        raise StableMoError("compute_stats: no frames")
    mean = total / count
    std = np.sqrt(np.maximum(total_sq / count - mean * mean, 0.0))
    for group in feature_groups(len(mean)):
        std[group] = std[group].mean()
    return mean.astype(np.float32), std.astype(np.float32)


def normalize(features: np.ndarray, mean: np.ndarray, std: np.ndarray) -> np.ndarray:
    return ((features - mean) / std).astype(np.float32, copy=False)


def denormalize(features, mean, std):
    """Inverse of normalize; works on numpy arrays and torch tensors (..., D) on any device."""
    if not isinstance(features, np.ndarray):
        import torch

        std = torch.as_tensor(std, dtype=features.dtype, device=features.device)
        mean = torch.as_tensor(mean, dtype=features.dtype, device=features.device)
    return features * std + mean


BODY_CLIPS = 256  # clips measured for the body's bone lengths (the median is stable long before)


def body_picks(num_clips: int) -> np.ndarray:
    """Rows of the (up to BODY_CLIPS) train clips, spread over the split, whose bones make the body."""
    if num_clips < 1:
        raise StableMoError("body: the train split has no clips")
    return np.unique(np.linspace(0, num_clips - 1, min(BODY_CLIPS, num_clips)).astype(int))


def body_lengths(motions: Iterable[np.ndarray], skeleton) -> np.ndarray:
    """(J,) bone lengths (parent -> joint, root 0): the median over every frame of the given raw
    (T, D) feature clips. A bundle stores them and generation puts every motion on this body."""
    import torch

    from stablemo.motion.features import features_to_joints
    from stablemo.motion.rigid import bone_lengths_of

    # one thread: on tensors of one clip, OpenMP's threads mostly wait for each other (256 clips:
    # 0.2 s with 1 thread, 0.3-2.1 s with 2 on this 2-core machine while other jobs ran)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        joints = torch.cat([features_to_joints(torch.from_numpy(np.array(m, np.float64)), skeleton) for m in motions])
        return bone_lengths_of(joints, skeleton).median(0).values.numpy()  # (J,) over every frame at once
    finally:
        torch.set_num_threads(threads)
