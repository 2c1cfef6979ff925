"""A StableMo motion -> a GLB: the BVH writer's rig and rotations (stablemo.bvh), our mannequin
skinned to it, the animation at the motion's own frame rate. Behind `generate --format glb`, the
server's GLB download and the page's body.

The rig is the one `stablemo.bvh.export_motion` builds (T-pose rest, the body's bone lengths, metres,
one rotation per joint per frame); the file's joints are the BVH's, so the same `Fit` says how far
they are from the motion. The rest pose stands on the floor: the root is lifted so that the lowest
joint of the T-pose is at y = 0, which is where the mesh is bound.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from stablemo.bvh.fit import Fit
from stablemo.bvh.names import rest_joints
from stablemo.bvh.rig import Animation, forward_kinematics, joints_to_animation
from stablemo.bvh.writer import Export, export_motion
from stablemo.gltf.mannequin import SOLE, mannequin
from stablemo.gltf.writer import glb_bytes
from stablemo.motion.skeleton import Skeleton, get_skeleton

# without colours from the caller every part is one neutral mannequin grey
NEUTRAL = "#b9b3a9"


def _palette(colours: dict[str, str] | None) -> dict[str, str]:
    return {side: NEUTRAL for side in ("left", "right", "center")} if colours is None else colours


def rest_root(anim: Animation) -> np.ndarray:
    """(3,) where the root stands at rest: lifted so that the T-pose's flat feet stand on the floor."""
    still = Animation(anim.rig, np.zeros((1, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (1, anim.rig.num_joints, 1)), anim.fps)
    return np.array([0.0, SOLE - forward_kinematics(still)[0, :, 1].min(), 0.0])


def animation_glb(anim: Animation, colours: dict[str, str] | None = None, name: str = "motion") -> bytes:
    """The GLB of an animation of one of our rigs in metres (stablemo.bvh): mannequin, skin, animation."""
    root = rest_root(anim)
    body = mannequin(anim.rig, _palette(colours), rest_root=root)
    return glb_bytes(anim.rig, anim, body, rest_root=root, name=name)


def export_glb(export: Export, colours: dict[str, str] | None = None, name: str = "motion") -> bytes:
    """The GLB of a motion already made ready for BVH (`export_motion(..., units="m")`), e.g. the
    server's, which has it at hand: the same rig and rotations."""
    return animation_glb(export.anim, colours, name)


def motion_glb(motion, *, skeleton: Skeleton | str | None = None, source_fps: float | None = None,
               bone_lengths=None, colours: dict[str, str] | None = None, name: str = "motion") -> tuple[bytes, Fit]:
    """(the GLB's bytes, how far its joints are from the motion's). motion: features or joints,
    numpy or torch; skeleton, source_fps, bone_lengths as stablemo.bvh.export_motion (the file is
    in metres at the motion's own rate); colours: {"left", "right", "center": "#rrggbb"}."""
    export = export_motion(motion, skeleton=skeleton, source_fps=source_fps, bone_lengths=bone_lengths, units="m")
    return export_glb(export, colours, name), export.fit


def write_glb(path: str | os.PathLike, motion, **kwargs) -> Fit:
    """Write a motion as GLB (atomically); keyword arguments as motion_glb. Returns the fit."""
    from stablemo.io import write_bytes

    data, fit = motion_glb(motion, **kwargs)
    write_bytes(Path(path), data)
    return fit


def standing_glb(skeleton: Skeleton | str, bone_lengths=None, colours: dict[str, str] | None = None) -> bytes:
    """A one-frame GLB of the body in the rig's rest pose (stablemo.bvh.names.rest_joints, the
    T-pose the page's stick figure shows before its first motion), its flat feet's soles on the
    floor: the page's body before its first motion. bone_lengths: (J,) in the skeleton's units
    (default the skeleton's standard body)."""
    skel = get_skeleton(skeleton)
    per_metre = 1000.0 if skel.units == "mm" else 1.0
    joints = rest_joints(skel, bone_lengths) / per_metre
    joints[:, 1] += SOLE  # the lowest joints are the flat feet's: the soles go on the floor, not into it
    anim = joints_to_animation(joints[None], skel, skel.fps)
    return animation_glb(anim, colours, name="rest")
