"""A real client: headless Blender imports our BVH, and its bones' heads are where the joints are,
frame by frame, at every heading, and at the right time: a 20 fps file plays at 20 fps with the
importer's "Update Scene FPS" or "Scale FPS"; our GLB and FBX (the skinned mannequin) come in the
same way (skipped when `blender` is not installed: apt-get install blender)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from stablemo.bench.blender import SCENE_AT_FILE_RATE, blender, blender_heads, blender_import
from stablemo.bench.motions import flip, heading, synth_joints, walk_on_the_standard_body
from stablemo.bvh import write_bvh
from stablemo.bvh.names import bvh_names
from stablemo.gltf.fbx import NUMPY_FALLBACK
from stablemo.motion.skeleton import HUMANML3D

pytestmark = pytest.mark.skipif(shutil.which("blender") is None, reason="blender is not installed")

@pytest.mark.parametrize("degrees", [0, 90, 180, 270])
def test_blender_puts_the_bones_on_the_joints(tmp_path, degrees):
    # a full turn on the spot then a somersault, turned to the heading: every orientation, upside down too
    from stablemo.bvh import forward_kinematics, motion_to_animation

    joints = heading(np.concatenate([synth_joints("turn", 1, angle=360), flip(2)]), degrees)
    joints = forward_kinematics(motion_to_animation(joints))  # the two parts' bones made one rigid body
    path = tmp_path / "m.bvh"
    write_bvh(path, joints)
    heads, fps = blender_heads(path, tmp_path)
    assert fps == pytest.approx(20.0)
    assert heads.shape == joints.shape
    err = np.linalg.norm(heads - joints, axis=-1)
    assert err.max() < 1e-4, (err.mean(), err.max())  # Blender works in float32


def test_blender_follows_stretching_bones(tmp_path):
    joints = heading(synth_joints("jump", 3), 180)
    wobble = 1.0 + 0.1 * np.sin(np.linspace(0, 9, len(joints)))[:, None, None]
    joints = joints[:, :1] + (joints - joints[:, :1]) * wobble  # every bone changes length
    path = tmp_path / "s.bvh"
    write_bvh(path, joints, stretch=True)
    heads, _ = blender_heads(path, tmp_path)
    assert np.linalg.norm(heads - joints, axis=-1).max() < 1e-4


def test_a_20_fps_file_plays_at_20_fps_with_update_scene_fps(tmp_path):
    joints = walk_on_the_standard_body()
    write_bvh(tmp_path / "w.bvh", joints)
    data = blender_import(tmp_path / "w.bvh", tmp_path, SCENE_AT_FILE_RATE)
    assert data["fps"] == pytest.approx(20.0)
    assert (data["first"], data["last"]) == (1.0, float(len(joints)))  # one scene frame per BVH frame
    heads = data["heads"]
    # 1 s into the animation (scene frame 21) the body is where our joints are at frame 20
    assert np.linalg.norm(heads[20] - joints[20], axis=-1).max() < 0.01
    assert np.linalg.norm(heads - joints, axis=-1).max() < 1e-4


def test_scale_fps_keeps_a_24_fps_scene_and_the_motion_s_timing(tmp_path):
    joints = walk_on_the_standard_body()
    write_bvh(tmp_path / "w.bvh", joints)
    data = blender_import(tmp_path / "w.bvh", tmp_path, {"use_fps_scale": True})
    assert data["fps"] == pytest.approx(24.0)  # Blender's default scene rate, untouched
    assert data["last"] - data["first"] == pytest.approx((len(joints) - 1) * 24 / 20)  # the same 5 s, more frames
    heads = data["heads"]
    # 1 s in is scene frame 25 (24 fps) and our frame 20; 0.5 s is scene frame 13 and our frame 10
    assert np.linalg.norm(heads[24] - joints[20], axis=-1).max() < 0.01
    assert np.linalg.norm(heads[12] - joints[10], axis=-1).max() < 0.01


def test_the_importer_defaults_play_20_fps_too_fast_unless_the_file_is_written_at_24(tmp_path):
    joints = walk_on_the_standard_body()
    write_bvh(tmp_path / "w.bvh", joints)
    data = blender_import(tmp_path / "w.bvh", tmp_path, {})
    # the defaults put BVH frame i on scene frame 1 + i of a 24 fps scene: 1.2x too fast, so 1 s in
    # (scene frame 25) shows our frame 24, a walk 1.2 s in, ~25 cm further on
    assert data["fps"] == pytest.approx(24.0) and data["last"] == float(len(joints))
    assert np.linalg.norm(data["heads"][24] - joints[24], axis=-1).max() < 1e-4
    assert np.linalg.norm(data["heads"][24, 0] - joints[20, 0]) > 0.15
    # the way out without touching the importer: write the file at Blender's 24 fps (--fps 24)
    write_bvh(tmp_path / "w24.bvh", joints, fps=24)
    data = blender_import(tmp_path / "w24.bvh", tmp_path, {})
    assert data["fps"] == pytest.approx(24.0)
    assert np.linalg.norm(data["heads"][24] - joints[20], axis=-1).max() < 0.01  # 1 s in: our frame 20


def test_the_readmes_prompt_comes_into_blender_as_the_written_joints(tmp_path):
    """The README's headline prompt, generated as a user does (`stablemo generate --format bvh`, the
    demo teacher): Blender shows the .joints.npy body, one rigid body on the floor."""
    from stablemo.cli import main

    prompt = "a person walks forward, then waves their right hand"
    assert main(["generate", prompt, "--format", "bvh", "--out", str(tmp_path / "out"), "--seed", "0"]) == 0
    stem = tmp_path / "out" / "a-person-walks-forward-then-waves-their-right-hand"
    joints = np.load(stem.with_suffix(".joints.npy"))
    heads, fps = blender_heads(stem.with_suffix(".bvh"), tmp_path)
    assert fps == pytest.approx(20.0) and heads.shape == joints.shape
    err = np.linalg.norm(heads - joints, axis=-1)
    assert err.max() < 0.01 and err.mean() < 0.003
    bones = np.linalg.norm(heads[:, 1:] - heads[:, [max(p, 0) for p in HUMANML3D.parents[1:]]], axis=-1)
    assert np.ptp(bones, axis=0).max() < 1e-3  # limbs of constant length in Blender too
    assert heads[..., 1].min() > -0.01  # nothing below the floor


# Runs inside Blender: each file (GLB, then FBX) imported into an empty scene at the motion's rate,
# then every pose bone's head in world space at every frame of its action
READ_BODIES = NUMPY_FALLBACK + """
import bpy, json
fps = float(fps)
out = {}
for path in files.split(","):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps = round(fps)
    if path.endswith(".fbx"):
        bpy.ops.import_scene.fbx(filepath=path)
    else:
        bpy.ops.import_scene.gltf(filepath=path)
    arm = next(o for o in scene.objects if o.type == "ARMATURE")
    meshes = [o for o in scene.objects if o.type == "MESH"]
    first, last = arm.animation_data.action.frame_range
    frames = []
    for frame in range(int(round(first)), int(round(last)) + 1):
        scene.frame_set(frame)
        frames.append({b.name: list(arm.matrix_world @ b.head) for b in arm.pose.bones})
    out[path] = {"first": first, "frames": frames, "meshes": len(meshes),
                 "skinned": [any(m.type == "ARMATURE" for m in o.modifiers) for o in meshes]}
with open(dst, "w") as f:
    json.dump(out, f)
"""


def test_the_readmes_prompt_as_glb_and_fbx_comes_into_blender_as_the_written_joints(tmp_path):
    """`generate --format glb --format fbx`, as a user runs it: Blender's glTF and FBX importers put
    the mannequin's bones on the .joints.npy body at every frame (one Blender launch writes the FBX,
    one reads both files)."""
    from stablemo.cli import main
    from stablemo.gltf.fbx import site_packages

    prompt = "a person walks forward, then waves their right hand"
    assert main(["generate", prompt, "--format", "glb", "--format", "fbx", "--out", str(tmp_path / "out")]) == 0
    stem = tmp_path / "out" / "a-person-walks-forward-then-waves-their-right-hand"
    joints = np.load(stem.with_suffix(".joints.npy"))
    glb, fbx = stem.with_suffix(".glb"), stem.with_suffix(".fbx")
    dst = tmp_path / "bodies.json"
    blender("import sys\nfiles, dst, fps, site_packages = sys.argv[sys.argv.index('--') + 1:]\n" + READ_BODIES,
            tmp_path, f"{glb},{fbx}", str(dst), "20", site_packages())
    data = json.loads(dst.read_text())
    # the glTF importer keys time 0 on scene frame 0, the FBX importer on frame 1; both one key per frame
    assert (data[str(glb)]["first"], data[str(fbx)]["first"]) == (0.0, 1.0)
    for path in (glb, fbx):
        read = data[str(path)]
        assert (read["meshes"], read["skinned"]) == (1, [True]), path.name  # the body, skinned
        heads = np.array([[frame[name] for name in bvh_names("humanml3d")] for frame in read["frames"]])
        heads = np.stack([heads[..., 0], heads[..., 2], -heads[..., 1]], axis=-1)  # Blender z up -> our y up
        assert heads.shape == joints.shape, path.name  # one key per motion frame, 20 fps
        err = np.linalg.norm(heads - joints, axis=-1)
        assert err.max() < 0.01, (path.name, err.mean(), err.max())
