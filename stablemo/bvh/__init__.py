"""BVH out and in, and SMPL-order poses, for StableMo motions.

Writing (any heading, turning, lying or flipping motions; forward kinematics of the file gives the
motion's joints back):

    from stablemo.bvh import write_bvh, bvh_text
    write_bvh("walk.bvh", motion)                 # motion: features (T, 263)/(T, 251) or joints (T, J, 3)
    write_bvh("walk.bvh", motion, fps=60, units="cm")
    text = bvh_text(motion, fps=30)               # the file's text, e.g. for a download response

    keyword arguments: skeleton ("humanml3d" | "kit", default from the shape), fps (output frame
    rate; rotations resampled by slerp; default the source rate), source_fps (default the
    skeleton's: 20 / 12.5), units ("m" default, "cm", "mm"), stretch (False: rigid bones of the
    motion's median lengths; True: per-joint translations too, exact where bones change length).

Reading: `read_bvh(path) -> Animation`, `forward_kinematics(anim) -> (T, J, 3)`;
`stablemo data import-bvh` turns a folder of BVH files into a HumanML3D-layout dataset
(stablemo/data/bvh_import.py). See docs/bvh.md.
"""

from stablemo.bvh.resample import resample
from stablemo.bvh.rig import Animation, Rig, forward_kinematics, joints_to_animation
from stablemo.bvh.text import format_bvh, read_bvh
from stablemo.bvh.writer import bvh_text, motion_joints, motion_to_animation, write_bvh

__all__ = [
    "Animation", "Rig", "bvh_text", "format_bvh", "forward_kinematics", "joints_to_animation",
    "motion_joints", "motion_to_animation", "read_bvh", "resample", "write_bvh",
]
