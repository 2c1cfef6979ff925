"""glTF 2.0 / GLB out: any skeleton with an animation, and our own skinned mannequin.

Motions (features (T, 263)/(T, 251) or joints (T, J, 3)):

    from stablemo.gltf import write_glb, motion_glb
    fit = write_glb("walk.glb", motion, bone_lengths=body, colours=COLOURS)  # metres, the motion's fps
    data, fit = motion_glb(motion)               # the bytes and how far the file's joints are (stablemo.bvh.fit)

Any rig (the writer knows nothing of ours; a retargeted character is written the same way):

    from stablemo.gltf import glb_bytes, gltf_document, mannequin, Primitive
    data = glb_bytes(rig, anim, primitives, rest_rotations=None, rest_root=(0, 0, 0), name="motion")
        rig: stablemo.bvh.Rig (names, parents, rest offsets parent -> joint, metres)
        anim: stablemo.bvh.Animation or None (root (T, 3), local rotations (T, J, 4) w-first,
              fps, optional per-joint translations (T, J, 3))
        primitives: Primitive(name, colour, positions, normals, joints, weights, triangles) in the
              rest pose, or () for a skeleton alone; mannequin(rig, colours) builds ours

FBX (through Blender on PATH): stablemo.gltf.fbx.glb_to_fbx. See docs/gltf.md.
"""

from stablemo.gltf.mannequin import mannequin
from stablemo.gltf.motion import (
    animation_glb,
    export_glb,
    motion_glb,
    standing_glb,
    write_glb,
)
from stablemo.gltf.writer import (
    Primitive,
    glb_bytes,
    gltf_document,
    pack_glb,
    read_glb,
    rest_world,
)

__all__ = [
    "Primitive", "animation_glb", "export_glb", "glb_bytes", "gltf_document", "mannequin", "motion_glb",
    "pack_glb", "read_glb", "rest_world", "standing_glb", "write_glb",
]
