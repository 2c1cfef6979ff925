"""`stablemo bvh IN.npy --out OUT.bvh|OUT.npz`: a features or joints file as BVH or an AMASS-style SMPL-X pose.

    stablemo bvh outputs/walk.features.npy --out walk.bvh              # 20 fps, metres
    stablemo bvh outputs/walk.joints.npy --out walk.bvh --fps 60 --units cm
    stablemo bvh outputs/walk.features.npy --out walk.bvh --stretch     # bones follow the motion's changing lengths
    stablemo bvh outputs/walk.features.npy --out walk.npz               # AMASS-style SMPL-X pose, z up
    stablemo bvh outputs/walk.features.npy --out walk.npz --up y        # ... in the motion's own y-up frame

It prints how far the file's joints are from the motion's (forward kinematics at the source rate),
and a warning on stderr when a joint is more than 3 cm off (stablemo.bvh.fit).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from stablemo.errors import StableMoError


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="stablemo bvh", description=__doc__.split("\n")[0].split(": ", 1)[1])
    p.add_argument("input", help="features (T, 263) / (T, 251) or joints (T, J, 3) .npy")
    p.add_argument("--out", required=True, help="output file: .bvh, or .npz for an AMASS-style SMPL-X pose")
    p.add_argument("--fps", type=float, default=None, help="output frame rate, e.g. 24, 30, 60, 120 (default: the motion's, 20 for HumanML3D)")
    p.add_argument("--source-fps", type=float, default=None, help="the input's frame rate (default: the skeleton's)")
    p.add_argument("--skeleton", default=None, choices=["humanml3d", "kit"], help="default: from the array's shape")
    p.add_argument("--units", default=None, choices=["m", "cm", "mm"], help="BVH length unit (default m; an .npz is in metres)")
    p.add_argument("--stretch", action="store_true",
                   help="BVH only: position channels on every joint, so that bones may change length and every joint "
                        "is exact; limbs then come apart at the joints when posed or retargeted (default: rigid bones)")
    p.add_argument("--up", default=None, metavar="{z,y}",
                   help=".npz only: the file's up axis, z (AMASS, default) or y (the motion's own frame)")
    return p


def _check_options(args, is_bvh: bool) -> None:
    """Options that only one of the two outputs has: one line naming the option, before any work."""
    from stablemo.checks import check_finite

    for flag in ("fps", "source_fps"):
        value = getattr(args, flag)
        if value is not None:
            check_finite(f"--{flag.replace('_', '-')}", value, low=0.0, high=1000.0, strict=True)
    if is_bvh and args.up is not None:
        raise StableMoError("--up: only for an .npz (a BVH is y up; Blender's importer converts its axes)")
    if args.up is not None:
        from stablemo.bvh.smpl import check_up

        check_up(args.up, "--up")
    if not is_bvh and args.stretch:
        raise StableMoError("--stretch: only for a .bvh (an SMPL pose has rotations only; its bones keep one length)")
    if not is_bvh and args.units not in (None, "m"):
        raise StableMoError(f"--units {args.units}: only for a .bvh (an SMPL pose file is in metres)")


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    from stablemo.io import check_output_file, load_npy

    out = Path(args.out)
    if out.suffix.lower() not in (".bvh", ".npz"):
        raise StableMoError(f"--out: {out}: name a .bvh or .npz file")
    is_bvh = out.suffix.lower() == ".bvh"
    _check_options(args, is_bvh)
    check_output_file(out, "--out")
    motion = load_npy(args.input)
    from stablemo.bvh.writer import export_motion

    try:
        export = export_motion(motion, skeleton=args.skeleton, fps=args.fps, source_fps=args.source_fps,
                               units=args.units or "m", stretch=args.stretch)
    except StableMoError as err:
        raise StableMoError(f"{args.input}: {err}") from None
    if is_bvh:
        from stablemo.io import write_text

        write_text(out, export.bvh())
    else:
        from stablemo.bvh.smpl import write_smpl_npz

        write_smpl_npz(out, export.anim, args.up or "z")
    anim, fit = export.anim, export.fit
    print(f"{args.input}: {anim.num_frames} frames at {anim.fps:g} fps -> {out}; {fit.summary()}")
    warning = fit.warning(str(out), "--stretch follows them exactly (see docs/bvh.md)" if is_bvh else "")
    if warning:
        print(warning, file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
