"""Read the rig a motion is retargeted onto, at rest (stablemo.retarget.rest.RestRig):

- BVH: stablemo.bvh.read_bvh; the OFFSETs are the rest pose (T-pose, A-pose, whatever the file says).
- glTF / GLB: stablemo.retarget.gltf_rig (the node tree of the first skin).
- FBX: converted by Blender on PATH to a GLB (a skinned character) or a BVH (a bare skeleton),
  read as above (stablemo.retarget.blender).
"""

from __future__ import annotations

from pathlib import Path

from stablemo.errors import StableMoError
from stablemo.retarget.blender import fbx_rest
from stablemo.retarget.gltf_rig import read_gltf_rig
from stablemo.retarget.rest import RestRig, bvh_rest

FORMATS = {".bvh": "bvh", ".gltf": "gltf", ".glb": "gltf", ".fbx": "fbx"}


def read_rig(path: str | Path) -> RestRig:
    """A rig file (.bvh, .gltf, .glb, .fbx) at rest; one line naming the file when it cannot be read."""
    path = Path(path)
    fmt = FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise StableMoError(f"--rig: {path}: expected a .bvh, .gltf, .glb or .fbx rig")
    if not path.is_file():
        raise StableMoError(f"--rig: {path}: file not found")
    if fmt == "bvh":
        return bvh_rest(path)
    if fmt == "gltf":
        return read_gltf_rig(path)
    return fbx_rest(path)
