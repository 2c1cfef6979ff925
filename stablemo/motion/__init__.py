"""Motion representation: skeletons, rotations, HumanML3D features <-> joint positions."""

from stablemo.motion.extract_torch import (
    canonicalize_joints_batched,
    joints_to_features_batched,
)
from stablemo.motion.features import (
    canonicalize_joints,
    feature_slices,
    features_to_joints,
    joints_to_features,
    recover_root,
    uniform_skeleton,
)
from stablemo.motion.skeleton import (
    HUMANML3D,
    KIT,
    Skeleton,
    get_skeleton,
    skeleton_for_shape,
)

__all__ = [
    "HUMANML3D",
    "KIT",
    "Skeleton",
    "canonicalize_joints",
    "canonicalize_joints_batched",
    "feature_slices",
    "features_to_joints",
    "get_skeleton",
    "joints_to_features",
    "joints_to_features_batched",
    "recover_root",
    "skeleton_for_shape",
    "uniform_skeleton",
]
