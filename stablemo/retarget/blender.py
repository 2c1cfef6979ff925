"""FBX rigs through Blender on PATH. One `blender -b` run imports the FBX and writes its armature
at rest both as a GLB (Blender's glTF exporter: the skeleton's nodes, and the skinned mesh when the
FBX has one) and as a one-frame BVH. A skinned character is then read as that GLB
(stablemo.retarget.gltf_rig), so the retargeted motion can be written onto the character itself
(GLB, or FBX again through stablemo.gltf.fbx); a skeleton without a mesh is read as the BVH (its
animation is written as BVH).

Why Blender on PATH and not `bpy` the module: the Debian package (`apt-get install blender`, what
CI installs) gives the command, not an importable module, and PyPI's `bpy` wheels pin one Python
version each; an FBX SDK has no Python 3.11+ wheels. One run costs 2-3 s (Blender's start).
"""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
import tempfile
from pathlib import Path

from stablemo.errors import StableMoError, one_line
from stablemo.retarget.rest import RestRig, bvh_rest

TIMEOUT_S = 180.0

# runs inside Blender: the FBX's first armature at rest, out as a GLB (y up, glTF's axes) and as a
# one-frame BVH (Blender's exporter keeps Blender's axes: z up, the character's front -y;
# stablemo.retarget.frames.up_axes). Blender's glTF exporter needs numpy: ours when it has none.
FBX_TO_RIGS = """
import bpy, sys
src, glb, bvh, site_packages = sys.argv[sys.argv.index("--") + 1:]
try:
    import numpy
except ImportError:
    sys.path.append(site_packages)
    import numpy
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_scene.fbx(filepath=src)
arms = [o for o in bpy.context.scene.objects if o.type == "ARMATURE"]
if not arms:
    print("STABLEMO: no armature in the FBX")
    sys.exit(3)
arm = arms[0]
arm.data.pose_position = "REST"
bpy.ops.export_scene.gltf(filepath=glb, export_format="GLB", export_animations=False)
for o in bpy.context.scene.objects:
    o.select_set(o is arm)
bpy.context.view_layer.objects.active = arm
bpy.ops.export_anim.bvh(filepath=bvh, frame_start=1, frame_end=1, global_scale=1.0, root_transform_only=False)
"""


def blender_or_error(what: str) -> str:
    exe = shutil.which("blender")
    if exe is None:
        raise StableMoError(f"{what}: reading FBX needs Blender on PATH (apt-get install blender); "
                            "or export the rig from your tool as BVH or glTF")
    return exe


def fbx_rest(path: Path) -> RestRig:
    """The FBX rig at rest (fmt "fbx"): a skinned character as its GLB's skeleton, with the GLB's
    bytes in extra["glb"]; a bare skeleton as its BVH (metres, z up)."""
    from stablemo.gltf.fbx import site_packages
    from stablemo.retarget.gltf_rig import read_gltf_rig

    exe = blender_or_error(f"--rig: {path}")
    with tempfile.TemporaryDirectory(prefix="stablemo-fbx-") as tmp:
        glb, bvh = Path(tmp) / "rest.glb", Path(tmp) / "rest.bvh"
        try:
            run = subprocess.run([exe, "-b", "--factory-startup", "--python-exit-code", "2", "--python-expr",
                                  FBX_TO_RIGS, "--", str(Path(path).resolve()), str(glb), str(bvh), site_packages()],
                                 capture_output=True, text=True, timeout=TIMEOUT_S, check=False)
        except subprocess.TimeoutExpired:
            raise StableMoError(f"--rig: {path}: Blender did not read the FBX within {TIMEOUT_S:g} s") from None
        if run.returncode != 0 or not bvh.is_file():
            said = [line for line in (run.stdout + run.stderr).splitlines() if "STABLEMO:" in line or "Error" in line]
            reason = one_line(said[-1].replace("STABLEMO: ", "")) if said else f"exit code {run.returncode}"
            raise StableMoError(f"--rig: {path}: Blender could not read it as an FBX rig ({reason})")
        try:
            rig = read_gltf_rig(glb)
        except StableMoError:  # no skinned mesh: the skeleton alone, from the BVH
            return dataclasses.replace(bvh_rest(bvh, fmt="fbx"), path=str(path))
        return dataclasses.replace(rig, fmt="fbx", path=str(path), extra={**rig.extra, "glb": glb.read_bytes()})
