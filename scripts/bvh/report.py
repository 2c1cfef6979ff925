"""BVH writer report: forward kinematics of the written file against the motion's joints (mean / max
over joints and frames) at headings 0/90/180/270 for the real HumanML3D clip, synthetic turning,
circling, jumping, crawling and flipping motions, the same on the standard body, and the demo
models' samples (as generated: one rigid body; and the network's raw output); rotations'
independence of the heading; Blender's bone heads and its frame rate per import option; the
writer's time per frame. A motion with a body is written on it (bone_lengths=), else on its
median bone lengths.

    OMP_NUM_THREADS=1 .venv/bin/python scripts/bvh/report.py [--no-demo] [--no-blender]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT.parent / "shared" / "data" / "humanml3d-sample"


def fk_error(joints: np.ndarray, tmp: Path, stretch: bool = False, body=None) -> np.ndarray:
    from stablemo.bench.motions import bvh_fk
    from stablemo.bvh import bvh_text

    fk, _ = bvh_fk(bvh_text(joints, stretch=stretch, bone_lengths=None if stretch else body), tmp)
    return np.linalg.norm(fk - joints, axis=-1)


PROMPTS = ["a person walks forward", "a person turns around to the left", "a person jumps in place twice",
           "a person walks in a clockwise circle", "a person bows"]


def motions(demo: bool) -> dict[str, tuple[np.ndarray, np.ndarray | None]]:
    """name -> (joints (T, 22, 3), the body's bone lengths or None)."""
    from stablemo.bench.motions import BODY, crawl, flip, standard_body, synth_joints
    from stablemo.motion import features_to_joints

    out = {}
    if SAMPLE.is_dir():
        out["real clip 012314 (features), on the standard body"] = (features_to_joints(
            np.load(SAMPLE / "new_joint_vecs" / "012314.npy").astype(np.float64), "humanml3d"), BODY)
    out["synth turn 360 (generator joints)"] = (synth_joints("turn", 2, rigid=False, angle=360), None)
    out["synth circle (generator joints)"] = (synth_joints("circle", 3, rigid=False), None)
    out["synth jump (generator joints)"] = (synth_joints("jump", 4, rigid=False), None)
    for action in ("walk", "turn", "jump", "circle"):
        out[f"synth {action} (extracted onto the standard body)"] = (
            standard_body(synth_joints(action, 21, rigid=False)), BODY)
    out["crawl (walk pitched 90 deg)"] = (crawl(), None)
    out["flip (jump + somersault)"] = (flip(), None)
    if demo:
        import torch

        from stablemo.inference.pipeline import Pipeline, Request

        torch.set_num_threads(1)
        for bundle in ("demo_bundle", "demo_student"):
            pipe = Pipeline.from_bundle(ROOT / "stablemo" / "assets" / bundle, device="cpu")
            result = pipe.generate(Request(PROMPTS, 120, seed=0))
            body = pipe.finish.bone_lengths
            for text, joints, raw in zip(PROMPTS, result.joint_list(), result.raw_joints):
                out[f"{bundle}: {text!r}"] = (np.asarray(joints, np.float64), body)
                if bundle == "demo_bundle":
                    out[f"{bundle}, raw network output: {text!r}"] = (raw[:len(joints)].numpy().astype(np.float64), None)
    return out


def heading_dependence() -> None:
    """The same poses at another heading: how far apart are the joint rotations? Ours against
    rotations built the way HumanML3D's 6D channels are (each bone's shortest world-space swing from
    its raw axis, joint rotation = parent swing^-1 * child swing)."""
    from stablemo.bench.motions import heading, synth_joints
    from stablemo.bvh import motion_to_animation
    from stablemo.motion import HUMANML3D as skel
    from stablemo.motion.quaternion import qbetween_np, qinv_np, qmul_np

    joints = (np.load(SAMPLE / "new_joints" / "012314.npy").astype(np.float64) if SAMPLE.is_dir()
              else synth_joints("walk", 1))
    parents = skel.parents

    def feature_style(x: np.ndarray) -> dict[int, np.ndarray]:
        swing = {}
        for c in range(1, skel.num_joints):
            d = x[:, c] - x[:, parents[c]]
            swing[c] = qbetween_np(np.broadcast_to(skel.raw_offsets[c], d.shape), d / np.linalg.norm(d, axis=-1, keepdims=True))
        out = {}
        for p in range(1, skel.num_joints):
            kids = [c for c in range(skel.num_joints) if parents[c] == p]
            if len(kids) == 1:
                out[p] = qmul_np(qinv_np(swing[p]), swing[kids[0]])
        return out

    def angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.degrees(2 * np.arccos(np.clip(np.abs((a * b).sum(-1)), 0.0, 1.0)))

    base_theirs, base_ours = feature_style(joints), motion_to_animation(joints).rotations
    print("\nsame poses turned to another heading: largest change of a joint's rotation (deg)")
    for deg in (90, 180, 270):
        turned = heading(joints, deg)
        theirs = feature_style(turned)
        worst = max((angle(theirs[p], base_theirs[p]).max(), skel.joint_names[p]) for p in theirs)
        ours = angle(motion_to_animation(turned).rotations[:, 1:], base_ours[:, 1:]).max()
        print(f"  heading {deg:3d}: ours {ours:.2e}; from world-space swings {worst[0]:.1f} ({worst[1]})")


def blender(tmp: Path) -> None:
    import shutil

    if shutil.which("blender") is None:
        print("\nblender: not installed")
        return
    from stablemo.bench.blender import blender_heads
    from stablemo.bench.motions import flip, heading, synth_joints
    from stablemo.bvh import forward_kinematics, motion_to_animation, write_bvh

    base = np.concatenate([synth_joints("turn", 1, angle=360), flip(2)])
    print("\nBlender (bpy import_anim.bvh, bone heads per frame), turn + somersault:")
    for deg in (0, 90, 180, 270):
        joints = forward_kinematics(motion_to_animation(heading(base, deg)))
        write_bvh(tmp / "b.bvh", joints)
        heads, _ = blender_heads(tmp / "b.bvh", tmp)
        err = np.linalg.norm(heads - joints, axis=-1)
        print(f"  heading {deg:3d}: mean {err.mean() * 1000:.4f} mm, max {err.max() * 1000:.4f} mm")
    blender_rate(tmp)


def blender_rate(tmp: Path) -> None:
    """Where Blender puts 1 s of a 20 fps walk, per import option (and a file written at 24 fps)."""
    from stablemo.bench.blender import SCENE_AT_FILE_RATE, blender_import
    from stablemo.bench.motions import walk_on_the_standard_body
    from stablemo.bvh import write_bvh

    joints = walk_on_the_standard_body()
    print("\nBlender's clock: a 20 fps walk, the scene frame 1 s in against our frame 20 (1 s)")
    cases = [("Update Scene FPS", SCENE_AT_FILE_RATE, 20), ("Scale FPS (24 fps scene)", {"use_fps_scale": True}, 20),
             ("defaults (24 fps scene)", {}, 20), ("defaults, file written at --fps 24", {}, 24)]
    for label, options, rate in cases:
        write_bvh(tmp / "w.bvh", joints, fps=None if rate == 20 else rate)
        data = blender_import(tmp / "w.bvh", tmp, options)
        one_second = round(data["fps"])  # scene frames after the first
        err = np.linalg.norm(data["heads"][one_second] - joints[20], axis=-1).max()
        print(f"  {label:36s} scene {data['fps']:g} fps, {len(data['heads'])} frames; 1 s in: {err * 100:.2f} cm "
              "from our 1 s pose")


def speed() -> None:
    from stablemo.bench.motions import synth_joints
    from stablemo.bvh import bvh_text, format_bvh, motion_to_animation

    joints = np.concatenate([synth_joints("circle", 3)] * 2)  # ~250 frames
    print(f"\nwriter speed ({len(joints)} frames, 1 thread, best of 5):")
    anim = motion_to_animation(joints)
    for label, fn in [
        ("joints -> rig + rotations (IK)", lambda: motion_to_animation(joints)),
        ("BVH text from the rotations", lambda: format_bvh(anim)),
        ("total joints -> BVH text, 20 fps", lambda: bvh_text(joints)),
        ("total joints -> BVH text, 60 fps", lambda: bvh_text(joints, fps=60)),
    ]:
        best = min(_time(fn) for _ in range(5))
        print(f"  {label:36s} {best / len(joints) * 1e6:7.1f} us per source frame")


def _time(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--no-demo", action="store_true", help="skip the demo model's samples")
    parser.add_argument("--no-blender", action="store_true")
    args = parser.parse_args()
    from stablemo.bench.motions import heading

    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        print("FK(BVH) - joints, mm: mean / max at headings 0, 90, 180, 270")
        from stablemo.motion import HUMANML3D

        parents = list(HUMANML3D.parents[1:])
        for name, (joints, body) in motions(not args.no_demo).items():
            lengths = np.linalg.norm(joints[:, 1:] - joints[:, parents], axis=-1)  # (T, 21)
            change = np.abs(lengths - np.median(lengths, axis=0)).max() * 1000
            for stretch in (False, True):
                cells = []
                for deg in (0, 90, 180, 270):
                    err = fk_error(heading(joints, deg), tmp, stretch, body) * 1000
                    cells.append(f"{err.mean():7.3f} / {err.max():7.3f}")
                label = f"{name} [{'stretch' if stretch else f'rigid; bones vary {change:.1f} mm'}]"
                print(f"  {label:100s} " + "   ".join(cells))
        heading_dependence()
        if not args.no_blender:
            blender(tmp)
        speed()
    return 0


if __name__ == "__main__":
    sys.exit(main())
