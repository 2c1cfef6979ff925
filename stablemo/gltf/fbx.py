"""FBX out through Blender: our GLB, imported by Blender's own glTF importer and exported by its FBX
exporter, in a `blender -b` subprocess. Optional: Blender on PATH (Debian/Ubuntu: `apt-get install
blender`); without it the caller gets one line saying so, before any compute (`check_blender`).

Why Blender and not an FBX SDK: FBX is a closed format whose SDK we cannot ship, and Blender's
exporter is what the animation tools users load FBX into are tested against. Why through the GLB:
one pipeline (the rig, the mannequin, the skin and the animation are made once, in stablemo.gltf).
The scene runs at the motion's frame rate, so each motion frame is one FBX key (baked, not
simplified); Blender's axis conversion writes y up, -z forward, as FBX tools expect. About 2-4 s per
file (Blender's start-up dominates).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from pathlib import Path

from stablemo.errors import StableMoError

# Blender's glTF add-on needs numpy, which Debian's blender package does not pull in; Blender runs
# on the system's Python, so when it has none of its own it borrows ours (the same Python version
# on Debian 12: 3.11), appended after its own paths so that nothing of Blender's is shadowed.
# Scripts run by Blender start with these lines; `site_packages` is site_packages() below.
NUMPY_FALLBACK = """
import sys
try:
    import numpy
except ImportError:
    sys.path.append(site_packages)
    import numpy
"""
# runs inside Blender: argv after "--" is GLB path, FBX path, frames per second, our site-packages
_SCRIPT = """
import bpy, sys
src, dst, fps, site_packages = sys.argv[sys.argv.index("--") + 1:]
fps = float(fps)
""" + NUMPY_FALLBACK + """
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
# a whole number of frames per second: 12.5 fps is 25 / 2
scene.render.fps, scene.render.fps_base = (round(fps), 1.0) if abs(fps - round(fps)) < 1e-6 else (round(2 * fps), 2.0)
bpy.ops.import_scene.gltf(filepath=src)
actions = [a for a in bpy.data.actions]
if actions:
    first, last = min(a.frame_range[0] for a in actions), max(a.frame_range[1] for a in actions)
    scene.frame_start, scene.frame_end = int(round(first)), int(round(last))
bpy.ops.export_scene.fbx(filepath=dst, object_types={"ARMATURE", "MESH"}, add_leaf_bones=False,
                         bake_anim=True, bake_anim_use_all_actions=False, bake_anim_use_nla_strips=False,
                         bake_anim_force_startend_keying=True, bake_anim_simplify_factor=0.0,
                         axis_forward="-Z", axis_up="Y")
"""
TIMEOUT_S = 300.0


def site_packages() -> str:
    """The folder our numpy is installed in (for Blender's Python when it has none)."""
    import numpy

    return str(Path(numpy.__file__).resolve().parents[1])


def blender_path() -> str | None:
    return shutil.which("blender")


def check_blender(flag: str = "--format fbx") -> str:
    """Blender's path, or one line saying that FBX needs it."""
    exe = blender_path()
    if exe is None:
        raise StableMoError(f"{flag}: FBX is written through Blender, which is not on PATH "
                            "(Debian/Ubuntu: apt-get install blender); GLB needs nothing")
    return exe


def glb_to_fbx(glb: bytes, fbx_path: str | os.PathLike, fps: float, timeout: float = TIMEOUT_S) -> Path:
    """Write the FBX of a GLB's bytes (atomically: Blender writes a temporary file that replaces
    `fbx_path` once complete). fps: the animation's frame rate (one FBX key per frame)."""
    from stablemo.io import atomic_path, write_bytes, write_text

    exe = check_blender()
    fbx_path = Path(fbx_path)
    with tempfile.TemporaryDirectory(prefix="stablemo-fbx-") as tmp:
        src, script = Path(tmp) / "motion.glb", Path(tmp) / "to_fbx.py"
        write_bytes(src, glb)
        write_text(script, _SCRIPT)
        with atomic_path(fbx_path, suffix=".fbx") as dst:
            try:
                run = subprocess.run([exe, "-b", "--factory-startup", "--python-exit-code", "1", "--python", str(script),
                                      "--", str(src), str(dst), repr(float(fps)), site_packages()],
                                     capture_output=True, text=True, timeout=timeout, check=False)
            except subprocess.TimeoutExpired:
                raise StableMoError(f"{fbx_path}: Blender did not finish the FBX in {timeout:g} s") from None
            if run.returncode != 0 or Path(dst).stat().st_size == 0:
                tail = (run.stderr.strip() or run.stdout.strip()).splitlines()[-1:] or ["no output"]
                raise StableMoError(f"{fbx_path}: Blender could not write the FBX ({tail[0]})")
    return fbx_path
