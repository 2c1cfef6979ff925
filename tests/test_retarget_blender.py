"""A real client makes the rigs and plays the result: headless Blender builds the Rigify human
metarig (its own rig: other names, proportions, a 7-joint trunk, z up) and an armature of other
names, 1.25x legs and A-pose arms, exports both to BVH and FBX; we retarget motions onto each, and
Blender imports what we wrote: its bones' heads are where the solve put the joints, frame by frame.
The same for a GLB character (our mannequin, rest rotations on every node) with the animation we
add to its file (skipped when `blender` is not installed: apt-get install blender)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from stablemo.bench.blender import MAKE_RIGS, blender, custom_spec
from stablemo.bench.motions import synth_joints
from stablemo.gltf.fbx import NUMPY_FALLBACK
from stablemo.retarget import retarget
from stablemo.retarget.api import write_result
from stablemo.retarget.measure import flipped_joints, heading_error, stance_speed

pytestmark = pytest.mark.skipif(shutil.which("blender") is None, reason="blender is not installed")

# Runs inside Blender: import each file, then every pose bone's head at every frame of its action.
READ_HEADS = """
import bpy, sys, json
jobs = json.load(open(sys.argv[sys.argv.index("--") + 1]))
import builtins, io_anim_bvh.import_bvh as importer  # Debian's Python 3.11 refuses the importer's "rU"
importer.open = lambda file, mode="r", *a, **k: builtins.open(file, mode.replace("U", ""), *a, **k)
for src, dst in jobs:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    # no axis conversion: the heads come out in the file's own axes
    bpy.ops.import_anim.bvh(filepath=src, axis_forward="Y", axis_up="Z", update_scene_fps=True,
                            update_scene_duration=True)
    scene = bpy.context.scene
    arm = next(o for o in scene.objects if o.type == "ARMATURE")
    first, last = arm.animation_data.action.frame_range
    frames = []
    for frame in range(int(round(first)), int(last + 1e-6) + 1):
        scene.frame_set(frame)
        frames.append({b.name: list(arm.matrix_world @ b.head) for b in arm.pose.bones})
    json.dump({"fps": scene.render.fps / scene.render.fps_base, "frames": frames}, open(dst, "w"))
"""


@pytest.fixture(scope="module")
def rigs(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("rigs")
    (out / "spec.json").write_text(json.dumps(custom_spec(synth_joints("walk", 3))))
    blender(MAKE_RIGS, out, str(out), str(out / "spec.json"))
    return out


def motions() -> dict[str, np.ndarray]:
    from stablemo.inference.bundle import DEMO_BUNDLE
    from stablemo.inference.pipeline import Pipeline

    out = Pipeline.from_bundle(DEMO_BUNDLE).generate(["a person walks forward and turns around"], 120, seed=1, steps=4)
    found = {"synth walk": synth_joints("walk", 3), "demo model": out.joints[0].double().numpy()}
    sample = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "humanml3d-sample" / "new_joints" / "012314.npy"
    if sample.is_file():
        found["HumanML3D 012314"] = np.load(sample).astype(np.float64)
    return found


def test_blender_plays_the_retargeted_motion_on_rigs_it_made(rigs, tmp_path):
    jobs, solved = [], {}
    for label, joints in motions().items():
        for rig in ("metarig.bvh", "custom.bvh", "metarig.fbx", "custom.fbx"):
            if not (rigs / rig).is_file():
                continue  # no Rigify in this Blender
            if rig.endswith(".fbx") and label != "demo model":
                continue  # each FBX costs a Blender start: one motion is enough to show the path
            out = tmp_path / f"{label.replace(' ', '_')}-{rig.replace('.', '_')}.bvh"
            s = retarget(joints, rigs / rig)
            write_result(out, s)
            speed = stance_speed(s)
            assert speed["target_m_s"] <= speed["source_m_s"] + 0.02, (label, rig, speed)
            flips = flipped_joints(s)
            assert flips.pop("bent") > 0 and not any(flips.values()), (label, rig, flips)
            assert heading_error(s) <= 5.0
            solved[str(out)] = s
            jobs.append([str(out), str(out) + ".json"])
    (tmp_path / "jobs.json").write_text(json.dumps(jobs))
    blender(READ_HEADS, tmp_path, str(tmp_path / "jobs.json"))
    for path, s in solved.items():
        data = json.loads(Path(path + ".json").read_text())
        assert data["fps"] == pytest.approx(s.anim.fps)
        names = [n for n in s.target.names if n in data["frames"][0]]
        assert len(names) >= 40 if "metarig" in path else len(names) == s.target.num_joints
        heads = np.array([[frame[n] for n in names] for frame in data["frames"]])
        want = s.positions[:, [s.target.names.index(n) for n in names]]
        assert heads.shape == want.shape
        err = np.linalg.norm(heads - want, axis=-1)
        assert err.max() < 1e-3, (path, err.max())  # Blender works in float32
        ankles = [s.target.names.index(n) for n in ("foot.L", "foot.R", "left_ankle", "right_ankle") if n in names]
        upright = s.positions @ s.axes  # y up (a BVH rig from Blender is z up, an FBX read as GLB y up)
        assert len(ankles) == 2 and upright[:, ankles, 1].min() > 0.0, path  # the ankles above the floor


# Runs inside Blender: import a GLB at the scene rate of its animation, then every pose bone's head
# at every frame of the active action (glTF's y up comes in as Blender's z up).
READ_GLB = """
import bpy, sys, json
src, dst, fps, site_packages = sys.argv[sys.argv.index("--") + 1:]
""" + NUMPY_FALLBACK + """
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.context.scene.render.fps = int(float(fps))
bpy.ops.import_scene.gltf(filepath=src)
scene = bpy.context.scene
arm = next(o for o in scene.objects if o.type == "ARMATURE")
action = arm.animation_data.action
frames = []
for frame in range(int(action.frame_range[0]), int(action.frame_range[1]) + 1):
    scene.frame_set(frame)
    frames.append({b.name: list(arm.matrix_world @ b.head) for b in arm.pose.bones})
json.dump({"action": action.name, "frames": frames}, open(dst, "w"))
"""


def test_blender_plays_the_animation_we_add_to_a_glb_character(tmp_path):
    from test_retarget import glb_character

    from stablemo.gltf.fbx import site_packages

    walk = synth_joints("walk", 3)
    path, _ = glb_character(tmp_path, walk)
    s = retarget(walk, path)
    write_result(tmp_path / "out.glb", s)
    blender(READ_GLB, tmp_path, str(tmp_path / "out.glb"), str(tmp_path / "heads.json"), "20", site_packages())
    data = json.loads((tmp_path / "heads.json").read_text())
    assert data["action"].startswith("stablemo retarget")
    heads = np.array([[frame[n] for n in s.target.names] for frame in data["frames"]])  # every joint, by name
    heads = np.stack([heads[..., 0], heads[..., 2], -heads[..., 1]], axis=-1)  # Blender z up -> glTF y up
    assert heads.shape == s.positions.shape
    assert np.linalg.norm(heads - s.positions, axis=-1).max() < 1e-4


# Runs inside Blender: import an FBX at the motion's frame rate, then every pose bone's head at every
# frame of its action.
READ_FBX = """
import bpy, sys, json
src, dst, fps = sys.argv[sys.argv.index("--") + 1:]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.context.scene.render.fps = int(float(fps))
bpy.ops.import_scene.fbx(filepath=src)
scene = bpy.context.scene
arm = next(o for o in scene.objects if o.type == "ARMATURE")
action = arm.animation_data.action
frames = []
for frame in range(int(action.frame_range[0]), int(action.frame_range[1]) + 1):
    scene.frame_set(frame)
    frames.append({b.name: list(arm.matrix_world @ b.head) for b in arm.pose.bones})
json.dump({"meshes": sum(o.type == "MESH" for o in scene.objects), "frames": frames}, open(dst, "w"))
"""


def test_an_fbx_character_gets_the_motion_as_fbx(rigs, tmp_path):
    """The skinned metarig as an FBX character: one command writes it back as FBX with the motion
    (read through the GLB Blender makes of it, written through stablemo.gltf.fbx), and Blender plays
    it with the character's own mesh: bone heads where the solve put them."""
    if not (rigs / "character.fbx").is_file():
        pytest.skip("this Blender has no Rigify add-on (the character is the metarig)")
    walk = synth_joints("walk", 3)
    s = retarget(walk, rigs / "character.fbx")
    assert s.target.fmt == "fbx" and "glb" in s.target.extra
    write_result(tmp_path / "walk.fbx", s)
    blender(READ_FBX, tmp_path, str(tmp_path / "walk.fbx"), str(tmp_path / "heads.json"), "20")
    data = json.loads((tmp_path / "heads.json").read_text())
    assert data["meshes"] == 1
    names = list(s.target.names)
    heads = np.array([[frame[n] for n in names] for frame in data["frames"]])
    heads = np.stack([heads[..., 0], heads[..., 2], -heads[..., 1]], axis=-1)  # Blender z up -> glTF y up
    assert heads.shape == s.positions.shape
    assert np.linalg.norm(heads - s.positions, axis=-1).max() < 1e-3
    # the same character as GLB: Blender's own layout (its mesh under the armature node) draws a
    # validator warning; the file we write has the skinned mesh at the root and none
    from stablemo.gltf import validator

    write_result(tmp_path / "walk.glb", s)
    if validator.available() is None:
        report = validator.validate([tmp_path / "walk.glb"])[0]
        assert (report["errors"], report["warnings"]) == (0, 0), report["messages"]
