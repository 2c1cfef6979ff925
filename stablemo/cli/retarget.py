"""`stablemo retarget MOTION --rig TARGET --out OUT`: a motion onto any humanoid rig.

    stablemo retarget outputs/walk.features.npy --rig character.bvh --out walk_character.bvh
    stablemo retarget outputs/walk.joints.npy --rig character.glb --out walk_character.glb   # the character + the animation
    stablemo retarget mocap.bvh --rig character.fbx --out walk_character.fbx                  # FBX through Blender on PATH
    stablemo retarget outputs/walk.features.npy --rig odd_names.bvh --map odd_names.yaml --out walk.bvh

MOTION: a StableMo motion (.features.npy / .joints.npy) or a BVH. The rig's joints are found by
name (Mixamo, Unreal, Unity, VRM, Rigify, CMU, SMPL/SMPL-X); --map YAML names the ones that are not
({LeftUpperLeg: thigh_L_jnt, ...}). See docs/retarget.md.
"""

from __future__ import annotations

import argparse
import sys


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="stablemo retarget", description=__doc__.split("\n")[0].split(": ", 1)[1])
    p.add_argument("motion", help="a StableMo motion (.features.npy / .joints.npy) or a .bvh")
    p.add_argument("--rig", required=True, help="the target rig: .bvh, .glb/.gltf, or .fbx (needs Blender on PATH)")
    p.add_argument("--out", required=True, help="output: .bvh for a BVH rig; .glb (the character with the motion) or "
                                                ".bvh for a glTF rig; .fbx, .glb or .bvh for an FBX rig")
    p.add_argument("--map", default=None, help="YAML {Role: the rig's joint name} for joints not found by name")
    p.add_argument("--source-map", default=None, help="the same for a BVH MOTION whose joint names do not tell their roles")
    p.add_argument("--fps", type=float, default=None, help="output frame rate (default: the motion's, 20 for HumanML3D)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    from stablemo.checks import check_finite
    from stablemo.retarget.api import check_out, retarget_file

    if args.fps is not None:
        check_finite("--fps", args.fps, low=0.0, high=1000.0, strict=True)
    check_out(args.out, args.rig)
    report = retarget_file(args.motion, args.rig, args.out, role_map=args.map, fps=args.fps, source_map=args.source_map)
    print(f"{args.motion}: {report.summary()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
