"""BVH out and in, and AMASS-style SMPL poses, for StableMo motions.

Writing (any heading, turning, lying or flipping motions; forward kinematics of the file gives the
motion's joints back):

    from stablemo.bvh import export_motion, write_bvh, bvh_text
    fit = write_bvh("walk.bvh", motion)           # motion: features (T, 263)/(T, 251) or joints (T, J, 3)
    fit.max_m, fit.warning("walk.bvh")            # how far the file's joints are; a line past 3 cm, else None
    write_bvh("walk.bvh", motion, fps=60, units="cm", bone_lengths=body)
    export = export_motion(motion, fps=30)        # export.bvh(): the file's text; export.fit: as above
    text = bvh_text(motion, fps=30)               # the text alone

    keyword arguments: skeleton ("humanml3d" | "kit", default from the shape), fps (output frame
    rate; rotations resampled by slerp; default the source rate), source_fps (default the
    skeleton's: 20 / 12.5), units ("m" default, "cm", "mm"), bone_lengths ((J,) the body's bones in
    the skeleton's units, e.g. a bundle's `body.bone_lengths`; default each bone's median length in
    the motion), stretch (False: rigid bones; True: per-joint translations too, exact where bones
    change length, but limbs then come apart at the joints when posed by hand or retargeted).

SMPL: `write_smpl_npz(path, anim, up="z")` (stablemo.bvh.smpl), an AMASS-style pose file.

Reading: `read_bvh(path) -> Animation`, `forward_kinematics(anim) -> (T, J, 3)`;
`stablemo data import-bvh` turns a folder of BVH files into a HumanML3D-layout dataset
(stablemo/data/bvh_import.py). See docs/bvh.md.
"""

from stablemo.bvh.fit import Fit, measure_fit
from stablemo.bvh.resample import resample
from stablemo.bvh.rig import Animation, Rig, forward_kinematics, joints_to_animation
from stablemo.bvh.text import format_bvh, read_bvh
from stablemo.bvh.writer import (
    Export,
    bvh_text,
    export_motion,
    motion_joints,
    motion_to_animation,
    write_bvh,
)

__all__ = [
    "Animation", "Export", "Fit", "Rig", "bvh_text", "export_motion", "format_bvh", "forward_kinematics",
    "joints_to_animation", "measure_fit", "motion_joints", "motion_to_animation", "read_bvh", "resample",
    "write_bvh",
]
