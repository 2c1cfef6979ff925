"""FBX rigs through Blender on PATH: `blender -b` imports the FBX and exports its armature's rest
pose as a one-frame BVH, which stablemo.retarget.target reads like any BVH rig.

Why Blender on PATH and not `bpy` the module: the Debian package (`apt-get install blender`, what
CI installs) gives the command, not an importable module, and PyPI's `bpy` wheels pin one Python
version each; an FBX SDK has no Python 3.11+ wheels. The subprocess costs ~1-2 s of Blender start.
"""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
import tempfile
from pathlib import Path

from stablemo.errors import StableMoError, one_line
from stablemo.retarget.rest import bvh_rest

TIMEOUT_S = 180.0

# runs inside Blender: the FBX's first armature, posed at rest, out as a one-frame BVH (Blender's
# exporter keeps Blender's axes: z up, the character's front -y; stablemo.retarget.solve.up_axes)
FBX_TO_BVH = """
import bpy, sys
src, dst = sys.argv[sys.argv.index("--") + 1:]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_scene.fbx(filepath=src)
arms = [o for o in bpy.context.scene.objects if o.type == "ARMATURE"]
if not arms:
    print("STABLEMO: no armature in the FBX")
    sys.exit(3)
arm = arms[0]
arm.data.pose_position = "REST"
for o in bpy.context.scene.objects:
    o.select_set(o is arm)
bpy.context.view_layer.objects.active = arm
bpy.ops.export_anim.bvh(filepath=dst, frame_start=1, frame_end=1, global_scale=1.0, root_transform_only=False)
"""


def blender_or_error(what: str) -> str:
    exe = shutil.which("blender")
    if exe is None:
        raise StableMoError(f"{what}: reading FBX needs Blender on PATH (apt-get install blender); "
                            "or export the rig from your tool as BVH or glTF")
    return exe


def fbx_rest(path: Path):
    """The FBX rig at rest, as stablemo.retarget.rest.RestRig (fmt "fbx", units as Blender imports: metres)."""
    exe = blender_or_error(f"--rig: {path}")
    with tempfile.TemporaryDirectory(prefix="stablemo-fbx-") as tmp:
        dst = Path(tmp) / "rest.bvh"
        try:
            run = subprocess.run([exe, "-b", "--factory-startup", "--python-exit-code", "2", "--python-expr",
                                  FBX_TO_BVH, "--", str(Path(path).resolve()), str(dst)],
                                 capture_output=True, text=True, timeout=TIMEOUT_S, check=False)
        except subprocess.TimeoutExpired:
            raise StableMoError(f"--rig: {path}: Blender did not read the FBX within {TIMEOUT_S:g} s") from None
        if run.returncode != 0 or not dst.is_file():
            said = [line for line in (run.stdout + run.stderr).splitlines() if "STABLEMO:" in line or "Error" in line]
            reason = one_line(said[-1].replace("STABLEMO: ", "")) if said else f"exit code {run.returncode}"
            raise StableMoError(f"--rig: {path}: Blender could not read it as an FBX rig ({reason})")
        return dataclasses.replace(bvh_rest(dst, fmt="fbx"), path=str(path))
