"""Test motions for the measurement scripts and the tests: synthetic actions on one rigid body,
turned to any heading, crawling (pitched to lying) and flipping (a somersault), rebuilt on the
standard body, and the joints a BVH file's forward kinematics gives back."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from stablemo.bvh import forward_kinematics, motion_to_animation, read_bvh
from stablemo.bvh.names import bvh_names
from stablemo.io import write_text
from stablemo.motion import HUMANML3D, features_to_joints, joints_to_features

__all__ = [
    "BODY",
    "bvh_fk",
    "crawl",
    "flip",
    "heading",
    "rotate",
    "standard_body",
    "synth_joints",
    "walk_on_the_standard_body",
]

BODY = HUMANML3D.bone_lengths  # (22,) the standard body every training clip is retargeted to


def synth_joints(action: str, seed: int = 0, rigid: bool = True, **params) -> np.ndarray:
    """(T, 22, 3) joints of one synthetic action (stablemo.data.synth). The generator's trunk is not
    quite rigid (its hip and chest triangles deform by ~1 mm); rigid=True gives the same motion
    on fixed bones, as mocap and HumanML3D have, by one pass through a rig."""
    from stablemo.data.synth import actions
    from stablemo.data.synth.compose import build

    p = actions.sample_params(action, np.random.default_rng(seed))
    p.update(params)
    joints = build([(action, p)], 0.2, 0.3).joints.astype(np.float64)
    return forward_kinematics(motion_to_animation(joints)) if rigid else joints


def rotate(joints: np.ndarray, rotvec) -> np.ndarray:
    """Rotate every frame about the frame-0 root by axis-angle rotvec (3,) or per frame (T, 3)."""
    r = Rotation.from_rotvec(np.array(np.broadcast_to(np.asarray(rotvec, float), (len(joints), 3))))
    pivot = joints[:1, :1]
    return np.einsum("tij,tkj->tki", r.as_matrix(), joints - pivot) + pivot


def heading(joints: np.ndarray, degrees: float) -> np.ndarray:
    """The motion turned about the vertical (y) axis through the frame-0 root by `degrees`."""
    return rotate(joints, [0.0, np.deg2rad(degrees), 0.0])


def crawl(seed: int = 0) -> np.ndarray:
    """A walk with the body pitched forward to lying (90° about x), moving along the floor."""
    j = rotate(synth_joints("walk", seed), [np.pi / 2, 0.0, 0.0])
    j[..., 1] -= j[..., 1].min() - 0.1
    return j


def flip(seed: int = 0) -> np.ndarray:
    """A jump during which the body turns one full somersault (every pitch, upside down included)."""
    j = synth_joints("jump", seed)
    angles = np.linspace(0.0, 2 * np.pi, len(j))
    centre = j[:, :1].copy()
    r = Rotation.from_rotvec(np.stack([angles, 0 * angles, 0 * angles], 1)).as_matrix()
    return np.einsum("tij,tkj->tki", r, j - centre) + centre


def standard_body(joints: np.ndarray) -> np.ndarray:
    """The motion rebuilt on the standard body by the feature extraction (not by the BVH writer):
    every bone at HUMANML3D.bone_lengths, the trunk one rigid piece. (T, 22, 3) -> (T-1, 22, 3)."""
    return features_to_joints(joints_to_features(joints, "humanml3d").astype(np.float64), "humanml3d")


def walk_on_the_standard_body() -> np.ndarray:
    """(T, 22, 3) a walk (~1.3 m/s) on the standard body, its pelvis made one rigid piece."""
    walk = heading(standard_body(synth_joints("walk", 41, rigid=False)), 60)
    return forward_kinematics(motion_to_animation(walk, bone_lengths=BODY))


def bvh_fk(text: str, folder: Path, name: str = "m.bvh") -> tuple[np.ndarray, object]:
    """Joints (T, 22, 3) in skeleton order from the BVH text, by the reader's forward kinematics
    (the text is written to `folder`/`name`, a scratch folder the caller owns)."""
    path = Path(folder) / name
    write_text(path, text)
    anim = read_bvh(path)
    order = [anim.rig.names.index(n) for n in bvh_names("humanml3d")]
    return forward_kinematics(anim)[:, order], anim
