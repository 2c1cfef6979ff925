"""Headless Blender for the measurement scripts and the tests: the runner (a Python script run
inside `blender -b`), the script that makes the Rigify metarig and a custom armature, the joint
list of that armature, and Blender's reading of a BVH file (every bone's head at every frame).
Callers check `shutil.which("blender")` first."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np

from stablemo.bvh.names import bvh_names
from stablemo.errors import StableMoError
from stablemo.io import write_text

__all__ = [
    "MAKE_RIGS",
    "READ_BONES",
    "SCENE_AT_FILE_RATE",
    "blender",
    "blender_heads",
    "blender_import",
    "custom_spec",
]

# Runs inside Blender: the Rigify metarig (when the add-on is there) and an armature from a joint
# list, each exported to BVH and FBX at rest.
MAKE_RIGS = """
import bpy, sys, json, addon_utils
out, spec = sys.argv[sys.argv.index("--") + 1:]
spec = json.load(open(spec))

def export(name):
    bpy.ops.object.mode_set(mode="OBJECT")
    bpy.ops.export_anim.bvh(filepath=f"{out}/{name}.bvh", frame_start=1, frame_end=1, root_transform_only=False)
    bpy.ops.export_scene.fbx(filepath=f"{out}/{name}.fbx", use_selection=True, add_leaf_bones=False, bake_anim=False)

bpy.ops.wm.read_factory_settings(use_empty=True)
if addon_utils.enable("rigify", default_set=True) is not None:  # a Blender without Rigify: the custom rig only
    bpy.ops.object.armature_human_metarig_add()
    export("metarig")
    # the metarig as a character: a body skinned to it (envelope weights), exported to FBX with its mesh
    arm = bpy.context.active_object
    bpy.ops.mesh.primitive_cylinder_add(radius=0.15, depth=1.7, location=(0, 0, 0.85), vertices=12)
    body = bpy.context.active_object
    body.select_set(True)
    arm.select_set(True)
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.parent_set(type="ARMATURE_ENVELOPE")
    bpy.ops.export_scene.fbx(filepath=f"{out}/character.fbx", use_selection=True, add_leaf_bones=False,
                             bake_anim=False)

bpy.ops.wm.read_factory_settings(use_empty=True)
arm = bpy.data.objects.new("Armature", bpy.data.armatures.new("Armature"))
bpy.context.scene.collection.objects.link(arm)
bpy.context.view_layer.objects.active = arm
arm.select_set(True)
bpy.ops.object.mode_set(mode="EDIT")
bones = []
for name, parent, head, tail in spec:
    b = arm.data.edit_bones.new(name)
    b.head, b.tail = head, tail
    if parent >= 0:
        b.parent = bones[parent]
        b.use_connect = False
    bones.append(b)
export("custom")
"""


def blender(script: str, folder: Path, *args: str, timeout: float = 300) -> None:
    """Run `script` inside headless Blender (written to `folder`/script.py; `args` after "--"), for at
    most `timeout` seconds. StableMoError with the tail of Blender's output when it exits non-zero."""
    path = Path(folder) / "script.py"
    write_text(path, script)
    run = subprocess.run(["blender", "-b", "--factory-startup", "--python-exit-code", "1", "--python", str(path),
                          "--", *args], capture_output=True, text=True, timeout=timeout, check=False)
    if run.returncode != 0:
        raise StableMoError(f"blender exited with code {run.returncode}:\n{run.stdout[-3000:]}{run.stderr[-3000:]}")


def custom_spec(walk: np.ndarray) -> list:
    """An armature in Blender's axes (z up, facing -y), standing on the floor: SMPL-X names, 1.25x legs,
    arms 40 degrees down, finger and twist bones; each bone from its joint to its first child
    (leaves: along the parent)."""
    from dataclasses import replace

    from stablemo.bvh import motion_to_animation
    from stablemo.retarget.variants import variant_rig

    rig, index = variant_rig("smplx", legs=1.25, a_pose_deg=40, body=motion_to_animation(walk).rig.offsets)
    offsets = rig.offsets.copy()
    for toe in (index[10], index[11]):  # feet as modelled, toes 25 degrees below the ankles, not a T-pose's level feet
        offsets[toe] = np.linalg.norm(offsets[toe]) * np.array([0.0, -np.sin(np.radians(25)), np.cos(np.radians(25))])
    rest = replace(rig, offsets=offsets).rest
    rest = rest - [0.0, rest[:, 1].min(), 0.0]  # standing on the floor
    blender_xyz = np.stack([rest[:, 0], -rest[:, 2], rest[:, 1]], axis=-1)  # y up, +z front -> z up, -y front
    spec = []
    for j, p in enumerate(rig.parents):
        kids = [c for c, q in enumerate(rig.parents) if q == j]
        tail = blender_xyz[kids[0]] if kids else blender_xyz[j] + 0.5 * (blender_xyz[j] - blender_xyz[p])
        if np.linalg.norm(tail - blender_xyz[j]) < 1e-3:
            tail = blender_xyz[j] + [0.0, 0.0, 0.05]
        spec.append([rig.names[j], p, blender_xyz[j].tolist(), tail.tolist()])
    return spec


# Runs inside Blender: import with no axis conversion and the given importer options, then every
# pose bone's head in world space at every whole scene frame of the action.
READ_BONES = """
import bpy, json, sys
src, dst, options = sys.argv[sys.argv.index("--") + 1:]
bpy.ops.wm.read_factory_settings(use_empty=True)
# Debian's Blender 3.4 runs on Python 3.11, where its BVH importer's open(path, "rU") is an error
# ("invalid mode: 'rU'"); Blender's own builds bundle Python 3.10. Drop the obsolete "U".
import builtins, io_anim_bvh.import_bvh as importer
importer.open = lambda file, mode="r", *a, **k: builtins.open(file, mode.replace("U", ""), *a, **k)
bpy.ops.import_anim.bvh(filepath=src, axis_forward="-Z", axis_up="Y", global_scale=1.0, rotate_mode="NATIVE",
                        **json.loads(options))
scene = bpy.context.scene
arm = next(o for o in scene.objects if o.type == "ARMATURE")
first, last = arm.animation_data.action.frame_range
out = {"fps": scene.render.fps / scene.render.fps_base, "first": first, "last": last, "frames": []}
for frame in range(int(round(first)), int(last + 1e-6) + 1):
    scene.frame_set(frame)
    out["frames"].append({b.name: list(arm.matrix_world @ b.head) for b in arm.pose.bones})
with open(dst, "w") as f:
    json.dump(out, f)
"""
# the importer's "Update Scene FPS": the scene takes the file's rate, one BVH frame per scene frame
SCENE_AT_FILE_RATE = {"update_scene_fps": True, "update_scene_duration": True}


def blender_import(bvh_path, folder, options: dict) -> dict:
    """Blender's reading of the file: {"fps": the scene's, "first"/"last": the action's frame range,
    "heads": (N, 22, 3) bone heads at the whole scene frames first..last in BVH coordinates (y up),
    our joint order}. Blender's files go to `folder`."""
    dst = Path(folder) / "heads.json"
    blender(READ_BONES, folder, str(bvh_path), str(dst), json.dumps(options))
    data = json.loads(dst.read_text())
    heads = np.array([[frame[name] for name in bvh_names("humanml3d")] for frame in data.pop("frames")])
    # the importer maps BVH (x, y, z) to Blender (x, -z, y) for axis_up=Y, axis_forward=-Z
    data["heads"] = np.stack([heads[..., 0], heads[..., 2], -heads[..., 1]], axis=-1)
    return data


def blender_heads(bvh_path, folder) -> tuple[np.ndarray, float]:
    """(T, 22, 3) bone heads, one per BVH frame (the scene at the file's rate), and the scene's fps."""
    data = blender_import(bvh_path, folder, SCENE_AT_FILE_RATE)
    return data["heads"], data["fps"]
