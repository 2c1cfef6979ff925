"""`stablemo render FILE.npy --out FILE.gif [--frames] [--skeleton humanml3d|kit] [--fps N] [--title T]`:
features (T, D) or joints (T, J, 3) as a stick-figure animation (stablemo.outputs.render)."""

from __future__ import annotations

import argparse
from pathlib import Path

from stablemo.errors import StableMoError
from stablemo.io import check_output_file
from stablemo.motion.plausible import check_fps
from stablemo.outputs.render import load_motion, render_animation, render_strip


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="stablemo render", description="Render motion features or joints as a stick-figure animation.")
    parser.add_argument("file", help="motion .npy: features (T, D) or joints (T, J, 3)")
    parser.add_argument("--out", required=True, help="output animation, .gif (or .mp4 with ffmpeg)")
    parser.add_argument("--frames", action="store_true", help="also write a PNG strip of frames beside --out (<out>_frames.png)")
    parser.add_argument("--num-frames", type=int, default=8, help="frames in the strip (default 8)")
    parser.add_argument("--skeleton", choices=["humanml3d", "kit"], default=None, help="default: from the array shape")
    parser.add_argument("--fps", type=float, default=None, help="playback rate (default: the skeleton's, 20 for HumanML3D)")
    parser.add_argument("--title", default=None)
    parser.add_argument("--index", type=int, default=None, help="item to render when FILE holds a batch (N, T, D) or (N, T, J, 3)")
    args = parser.parse_args(argv)
    out = check_output_file(args.out, "--out")  # before the motion is read or a frame drawn
    if args.fps is not None:
        check_fps(args.fps, "--fps")
    strip = out.with_name(out.stem + "_frames.png")
    if args.frames:
        check_output_file(strip, "--frames")
        if args.num_frames < 1:
            raise StableMoError(f"--num-frames: must be >= 1, got {args.num_frames}")
    joints, skel = load_motion(args.file, args.skeleton, args.index)
    title = args.title if args.title is not None else Path(args.file).stem
    out = render_animation(joints, out, skel, fps=args.fps, title=title)
    print(f"wrote {out} ({len(joints)} frames, skeleton {skel.name})")
    if args.frames:
        render_strip(joints, strip, skel, num_frames=args.num_frames, title=title)
        print(f"wrote {strip}")
    return 0
