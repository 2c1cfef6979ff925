"""A rig at rest, whatever file it came from (stablemo.retarget.target reads the files).

Every reader gives the same thing: joints (parents before children), their rest offsets in world
axes (the BVH convention: a joint at rest has no rotation of its own) and, for formats whose joints
do have rest orientations (glTF nodes), those orientations, so that an animation solved in world
axes can be written back in the file's own node frames.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stablemo.bvh.rig import END_SITE_FRACTION, Rig
from stablemo.errors import StableMoError


@dataclass(frozen=True)
class RestRig:
    """names (J,), parents (J,) (-1 root, parents first), offsets (J, 3) parent -> joint in world
    axes at rest (root: its rest position), in the file's units; end_sites {leaf: (3,)};
    orient (J, 4) world rest orientation of each joint (w, x, y, z; identity for BVH);
    fmt: "bvh" | "gltf" | "fbx"; path: where it was read; extra: format-specific (glTF node ids)."""

    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: np.ndarray
    end_sites: dict[int, np.ndarray]
    orient: np.ndarray
    fmt: str
    path: str
    extra: dict = field(default_factory=dict)

    @property
    def num_joints(self) -> int:
        return len(self.names)

    @property
    def rest(self) -> np.ndarray:
        """(J, 3) world rest positions."""
        out = np.zeros((self.num_joints, 3))
        for j, p in enumerate(self.parents):
            out[j] = self.offsets[j] + (out[p] if p >= 0 else 0.0)
        return out

    def bvh_rig(self) -> Rig:
        return Rig(self.names, self.parents, self.offsets, self.end_sites)


def identity_orient(num: int) -> np.ndarray:
    out = np.zeros((num, 4))
    out[:, 0] = 1.0
    return out


def leaf_end_sites(parents, offsets: np.ndarray) -> dict[int, np.ndarray]:
    """End Sites for a rig that has none: each leaf continues its bone by half its length."""
    kids = {p for p in parents if p >= 0}
    return {j: END_SITE_FRACTION * offsets[j] for j in range(len(parents)) if j not in kids and parents[j] >= 0}


def bvh_rest(path: Path, fmt: str = "bvh") -> RestRig:
    from stablemo.bvh.text import read_bvh

    rig = read_bvh(path).rig
    if rig.num_joints < 2:
        raise StableMoError(f"{path}: one joint; not a body")
    return RestRig(rig.names, rig.parents, np.array(rig.offsets, dtype=np.float64), dict(rig.end_sites),
                   identity_orient(rig.num_joints), fmt, str(path))
