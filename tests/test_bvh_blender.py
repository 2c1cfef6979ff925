"""A real client: headless Blender imports our BVH, and its bones' heads are where the joints are,
frame by frame, at every heading (skipped when `blender` is not installed: apt-get install blender)."""

from __future__ import annotations

import json
import shutil
import subprocess

import numpy as np
import pytest

from stablemo.bvh import write_bvh
from stablemo.bvh.names import bvh_names

pytestmark = pytest.mark.skipif(shutil.which("blender") is None, reason="blender is not installed")

# Runs inside Blender: import with no axis conversion, then every pose bone's head in world space per frame.
READ_BONES = """
import bpy, json, sys
src, dst = sys.argv[sys.argv.index("--") + 1:]
bpy.ops.wm.read_factory_settings(use_empty=True)
# Debian's Blender 3.4 runs on Python 3.11, where its BVH importer's open(path, "rU") is an error
# ("invalid mode: 'rU'"); Blender's own builds bundle Python 3.10. Drop the obsolete "U".
import builtins, io_anim_bvh.import_bvh as importer
importer.open = lambda file, mode="r", *a, **k: builtins.open(file, mode.replace("U", ""), *a, **k)
bpy.ops.import_anim.bvh(filepath=src, axis_forward="-Z", axis_up="Y", global_scale=1.0,
                        rotate_mode="NATIVE", update_scene_fps=True, update_scene_duration=True)
scene = bpy.context.scene
arm = next(o for o in scene.objects if o.type == "ARMATURE")
out = {"fps": scene.render.fps / scene.render.fps_base, "frames": []}
first, last = (int(round(v)) for v in arm.animation_data.action.frame_range)
for frame in range(first, last + 1):
    scene.frame_set(frame)
    out["frames"].append({b.name: list(arm.matrix_world @ b.head) for b in arm.pose.bones})
with open(dst, "w") as f:
    json.dump(out, f)
"""


def blender_heads(bvh_path, tmp_path) -> tuple[np.ndarray, float]:
    """(T, 22, 3) bone heads in BVH coordinates (y up) in our joint order, and the scene's fps."""
    script, dst = tmp_path / "read_bones.py", tmp_path / "heads.json"
    script.write_text(READ_BONES)
    run = subprocess.run(["blender", "-b", "--factory-startup", "--python-exit-code", "1", "--python", str(script),
                          "--", str(bvh_path), str(dst)], check=False, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    data = json.loads(dst.read_text())
    heads = np.array([[frame[name] for name in bvh_names("humanml3d")] for frame in data["frames"]])
    # the importer maps BVH (x, y, z) to Blender (x, -z, y) for axis_up=Y, axis_forward=-Z
    return np.stack([heads[..., 0], heads[..., 2], -heads[..., 1]], axis=-1), data["fps"]


@pytest.mark.parametrize("degrees", [0, 90, 180, 270])
def test_blender_puts_the_bones_on_the_joints(tmp_path, degrees):
    from test_bvh import flip, heading, synth_joints

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
    from test_bvh import heading, synth_joints

    joints = heading(synth_joints("jump", 3), 180)
    wobble = 1.0 + 0.1 * np.sin(np.linspace(0, 9, len(joints)))[:, None, None]
    joints = joints[:, :1] + (joints - joints[:, :1]) * wobble  # every bone changes length
    path = tmp_path / "s.bvh"
    write_bvh(path, joints, stretch=True)
    heads, _ = blender_heads(path, tmp_path)
    assert np.linalg.norm(heads - joints, axis=-1).max() < 1e-4
