"""`stablemo bvh IN.npy --out OUT.bvh|OUT.npz`: a features or joints file as BVH or SMPL-order pose.

    stablemo bvh outputs/walk.features.npy --out walk.bvh              # 20 fps, metres
    stablemo bvh outputs/walk.joints.npy --out walk.bvh --fps 60 --units cm
    stablemo bvh outputs/walk.features.npy --out walk.bvh --stretch     # bones follow the motion's changing lengths
    stablemo bvh outputs/walk.features.npy --out walk.npz               # SMPL 24-joint axis-angle + root

It prints how far the file's joints are from the motion's (forward kinematics at the source rate).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from stablemo.errors import StableMoError


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="stablemo bvh", description=__doc__.split("\n")[0].split(": ", 1)[1])
    p.add_argument("input", help="features (T, 263) / (T, 251) or joints (T, J, 3) .npy")
    p.add_argument("--out", required=True, help="output file: .bvh, or .npz for an SMPL-order pose")
    p.add_argument("--fps", type=float, default=None, help="output frame rate, e.g. 30, 60, 120 (default: the motion's, 20 for HumanML3D)")
    p.add_argument("--source-fps", type=float, default=None, help="the input's frame rate (default: the skeleton's)")
    p.add_argument("--skeleton", default=None, choices=["humanml3d", "kit"], help="default: from the array's shape")
    p.add_argument("--units", default="m", choices=["m", "cm", "mm"], help="BVH length unit (default m)")
    p.add_argument("--stretch", action="store_true",
                   help="position channels on every joint, so that bones may change length and every joint is "
                        "exact (generated motions); default: rigid bones of the motion's median lengths")
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    from stablemo.checks import check_finite
    from stablemo.io import check_output_file, load_npy

    for flag in ("fps", "source_fps"):
        value = getattr(args, flag)
        if value is not None:
            check_finite(f"--{flag.replace('_', '-')}", value, low=0.0, high=1000.0, strict=True)
    out = Path(args.out)
    if out.suffix.lower() not in (".bvh", ".npz"):
        raise StableMoError(f"--out: {out}: name a .bvh or .npz file")
    check_output_file(out, "--out")
    motion = load_npy(args.input)
    from stablemo.bvh.resample import resample
    from stablemo.bvh.rig import forward_kinematics
    from stablemo.bvh.writer import UNITS, motion_joints, motion_to_animation

    is_bvh = out.suffix.lower() == ".bvh"
    try:
        joints, skel = motion_joints(motion, args.skeleton)
        anim = motion_to_animation(joints, skeleton=skel, source_fps=args.source_fps,
                                   units=args.units if is_bvh else "m", stretch=args.stretch and is_bvh)
    except StableMoError as err:
        raise StableMoError(f"{args.input}: {err}") from None
    metres = 1.0 / UNITS[args.units if is_bvh else "m"]
    err = np.linalg.norm(forward_kinematics(anim) * metres - joints / (1000.0 if skel.units == "mm" else 1.0), axis=-1)
    if args.fps is not None:
        anim = resample(anim, args.fps)
    if out.suffix.lower() == ".npz":
        from stablemo.bvh.smpl import write_smpl_npz

        write_smpl_npz(out, anim)
    else:
        from stablemo.bvh.text import format_bvh
        from stablemo.io import write_text

        write_text(out, format_bvh(anim))
    fit = f"joints within {err.mean() * 100:.2f} cm on average, {err.max() * 100:.2f} cm at most"
    hint = " (the motion's bones change length; --stretch follows them)" if err.max() > 0.03 and is_bvh else ""
    print(f"{args.input}: {anim.num_frames} frames at {anim.fps:g} fps -> {out}; {fit}{hint}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
