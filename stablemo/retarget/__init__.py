"""Retarget a motion onto any humanoid rig: `stablemo retarget MOTION --rig TARGET --out OUT`.

    from stablemo.retarget import retarget, retarget_file
    solved = retarget("walk.features.npy", "character.bvh")     # or arrays, or a BVH motion
    solved.anim                                                # the rig in motion (stablemo.bvh.Animation)
    report = retarget_file("walk.features.npy", "character.glb", "walk_on_character.glb", role_map="map.yaml")

MOTION: a StableMo motion (features or joints .npy, or an array) or a BVH. TARGET: a BVH,
glTF/GLB or FBX (through Blender on PATH) rig; the joint roles come from its names
(stablemo.retarget.names), a YAML map overrides them. The solve: stablemo.retarget.solve. Output in
the target's format: BVH for BVH rigs; for glTF and FBX characters the character itself with the
animation added (GLB; FBX through Blender), or BVH. See docs/retarget.md.
"""

from stablemo.retarget.api import Report, retarget, retarget_file

__all__ = ["Report", "retarget", "retarget_file"]
