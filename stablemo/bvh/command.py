"""`stablemo bvh IN.npy --out OUT.bvh|OUT.npz`: a features or joints file as BVH or SMPL-order pose.

    stablemo bvh outputs/walk.features.npy --out walk.bvh              # 20 fps, metres
    stablemo bvh outputs/walk.joints.npy --out walk.bvh --fps 60 --units cm
    stablemo bvh outputs/walk.features.npy --out walk.npz               # SMPL 24-joint axis-angle + root
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from stablemo.errors import StableMoError


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="stablemo bvh", description=__doc__.split("\n")[0].split(": ", 1)[1])
    p.add_argument("input", help="features (T, 263) / (T, 251) or joints (T, J, 3) .npy")
    p.add_argument("--out", required=True, help="output file: .bvh, or .npz for an SMPL-order pose")
    p.add_argument("--fps", type=float, default=None, help="output frame rate, e.g. 30, 60, 120 (default: the motion's, 20 for HumanML3D)")
    p.add_argument("--source-fps", type=float, default=None, help="the input's frame rate (default: the skeleton's)")
    p.add_argument("--skeleton", default=None, choices=["humanml3d", "kit"], help="default: from the array's shape")
    p.add_argument("--units", default="m", choices=["m", "cm", "mm"], help="BVH length unit (default m)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    from stablemo.inference_config import check_finite
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
    from stablemo.bvh.writer import motion_to_animation

    try:
        anim = motion_to_animation(motion, skeleton=args.skeleton, fps=args.fps, source_fps=args.source_fps,
                                   units=args.units if out.suffix.lower() == ".bvh" else "m")
    except StableMoError as err:
        raise StableMoError(f"{args.input}: {err}") from None
    if out.suffix.lower() == ".npz":
        from stablemo.bvh.smpl import write_smpl_npz

        write_smpl_npz(out, anim)
    else:
        from stablemo.bvh.text import format_bvh
        from stablemo.io import write_text

        write_text(out, format_bvh(anim))
    print(f"{args.input}: {anim.num_frames} frames at {anim.fps:g} fps -> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
