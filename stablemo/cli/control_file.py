"""`stablemo control-file`: a control file (.npz) from any joints array.

    stablemo control-file clip.joints.npy --joints pelvis --out path.npz                 # dense pelvis path
    stablemo control-file clip.joints.npy --joints left_wrist --density 25% --out wrist.npz
    stablemo control-file clip.joints.npy --joints all --frames 0,60,120,179 --out keys.npz   # keyframes

The joints are put in the generator's frame first unless `--as-is`: the first frame's pelvis moves
to x = z = 0 and the body is turned to face +z at frame 0 (as HumanML3D's recovered joints are).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from stablemo.control.files import (
    control_from_joints,
    density_frames,
    joint_index,
    parse_frames,
    save_control,
)
from stablemo.errors import StableMoError
from stablemo.io import check_output_file, load_npy
from stablemo.motion.skeleton import get_skeleton, skeleton_for_shape


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="stablemo control-file", description="Write a joint-control file from joints.")
    p.add_argument("joints", help="joints .npy (T, 22, 3) or (T, 21, 3)")
    p.add_argument("--joints", dest="names", default="pelvis",
                   help="comma-separated joints: pelvis, left_foot, right_foot, head, left_wrist, right_wrist, a "
                        "skeleton name (L_knee) or index; 'all' for keyframes (default pelvis)")
    frames = p.add_mutually_exclusive_group()
    frames.add_argument("--density", default=None, help="share of frames (100%%, 25%%) or a count (5), evenly spaced")
    frames.add_argument("--frames", default=None, help="frames: 0,60,120 or ranges 0:40 (default: every frame)")
    p.add_argument("--as-is", action="store_true", help="take the positions as they are (already in the generator's frame)")
    p.add_argument("--out", required=True, help="the control file to write (.npz)")
    return p


def canonical_start(joints: np.ndarray, skeleton) -> np.ndarray:
    """Joints moved so the pelvis starts at x = z = 0 and the body faces +z at frame 0."""
    skel = get_skeleton(skeleton)
    r_hip, l_hip, r_sh, l_sh = skel.face_joints
    across = (joints[0, r_hip] - joints[0, l_hip]) + (joints[0, r_sh] - joints[0, l_sh])
    forward = np.cross([0.0, 1.0, 0.0], across)
    forward[1] = 0.0
    norm = np.linalg.norm(forward)
    if norm < 1e-8:
        raise StableMoError("joints: cannot tell the facing direction at frame 0 (hips and shoulders are degenerate)")
    forward /= norm
    angle = np.arctan2(forward[0], forward[2])  # rotate about y by -angle to face +z
    c, s = np.cos(-angle), np.sin(-angle)
    rot = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    out = joints - joints[0, 0] * np.array([1.0, 0.0, 1.0])
    return out @ rot.T


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    path = Path(args.joints)
    joints = load_npy(path)
    skel = skeleton_for_shape(joints.shape) if joints.ndim == 3 else None
    if skel is None or joints.shape[-1] != 3:
        raise StableMoError(f"{path}: expected joints (T, 22, 3) or (T, 21, 3), got shape {joints.shape}")
    if len(joints) < 1:  # checked here, where the file is read: every use below indexes frame 0
        raise StableMoError(f"{path}: no frames (shape {joints.shape})")
    if not np.isfinite(joints).all():
        raise StableMoError(f"{path}: joints hold NaN or Inf")
    out = check_output_file(args.out, "--out")
    if out.suffix != ".npz":
        raise StableMoError(f"--out: {out}: a control file ends in .npz")
    T = len(joints)
    names = [n for n in args.names.split(",") if n.strip()]
    if names == ["all"]:
        sel = list(range(skel.num_joints))
    else:
        sel = [joint_index(n, skel) for n in names]
    if args.density is not None:
        frames = density_frames(args.density, T)
    elif args.frames is not None:
        frames = parse_frames(args.frames, T)
    else:
        frames = np.ones(T, bool)
    positions = joints.astype(np.float64) if args.as_is else canonical_start(joints.astype(np.float64), skel)
    save_control(out, control_from_joints(positions, sel, frames))
    print(f"{out}: {int(frames.sum())} of {T} frames x {len(sel)} joint(s) ({', '.join(skel.joint_names[j] for j in sel)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
