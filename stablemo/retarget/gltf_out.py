"""A retargeted motion written onto a glTF character: the user's own GLB (mesh, materials, skin,
every node and animation it had; for an FBX character the GLB Blender made of it) with one
animation added that drives its skeleton's nodes; a .gltf rig (whose buffers live in other files)
gives a GLB of its skeleton alone, through our glTF writer (stablemo.gltf).

The solve's rotations are world-axis local rotations (the BVH convention); a glTF node has a rest
orientation of its own, so each becomes G_parent^-1 L G_joint (G: world rest orientations of the
node's parent node and of the node). The skeleton root's translation is its world place in its
parent node's frame (the armature node's scale, e.g. 0.01 from an FBX in centimetres, included).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from stablemo.errors import StableMoError
from stablemo.gltf.writer import gltf_document, pack_glb, read_glb
from stablemo.retarget.gltf_rig import node_matrix
from stablemo.retarget.solve import Solved

ANIMATION_NAME = "stablemo retarget"
FLOAT = 5126


def _to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) w-first -> (..., 3, 3)."""
    flat = q.reshape(-1, 4)[:, [1, 2, 3, 0]]
    return Rotation.from_quat(flat).as_matrix().reshape(q.shape[:-1] + (3, 3))


def _world_rest(doc: dict) -> tuple[dict[int, int], list[np.ndarray]]:
    """Each node's parent node and its (4, 4) world rest matrix."""
    nodes = doc["nodes"]
    parent = {c: i for i, node in enumerate(nodes) for c in node.get("children", [])}
    world: list[np.ndarray | None] = [None] * len(nodes)

    def of(i: int) -> np.ndarray:
        if world[i] is None:
            above = of(parent[i]) if i in parent else np.eye(4)
            world[i] = above @ node_matrix(nodes[i])
        return world[i]

    return parent, [of(i) for i in range(len(nodes))]


def node_tracks(solved: Solved, doc: dict) -> tuple[np.ndarray, np.ndarray]:
    """(rotations (T, J, 4) x, y, z, w in each joint node's own frame, root translation (T, 3))."""
    parent, world = _world_rest(doc)
    node_of = solved.target.extra["nodes"]
    rot = [w[:3, :3] / np.linalg.norm(w[:3, :3], axis=0, keepdims=True) for w in world]  # scale out
    local = _to_matrix(solved.anim.rotations)  # (T, J, 3, 3) world-axis locals
    out = np.empty(local.shape)
    for j, node in enumerate(node_of):
        g_parent = rot[parent[node]] if node in parent else np.eye(3)
        out[:, j] = g_parent.T @ local[:, j] @ rot[node]
    quats = Rotation.from_matrix(out.reshape(-1, 3, 3)).as_quat().reshape(out.shape[:2] + (4,))
    root = node_of[0]
    above = world[parent[root]] if root in parent else np.eye(4)
    homogeneous = np.concatenate([solved.anim.root, np.ones((len(solved.anim.root), 1))], axis=1)  # (T, 4)
    translation = (np.linalg.inv(above) @ homogeneous.T).T[:, :3]
    return quats, translation


def _skinned_meshes_at_root(doc: dict) -> None:
    """Move skinned mesh nodes whose parents do not transform them to their scene's root: nothing
    moves in any viewer, and Khronos' validator stops warning about the layout Blender's exporter
    writes (the mesh under an identity armature node). Under a transforming parent the mesh stays:
    glTF says such a parent is ignored, but not every engine does."""
    parent = {c: i for i, n in enumerate(doc["nodes"]) for c in n.get("children", [])}
    for i, node in enumerate(doc["nodes"]):
        if "skin" not in node or "mesh" not in node or i not in parent:
            continue
        above, n = np.eye(4), i
        while n in parent:
            n = parent[n]
            above = node_matrix(doc["nodes"][n]) @ above
        if not np.allclose(above, np.eye(4), atol=1e-9):
            continue
        above = doc["nodes"][parent[i]]
        above["children"] = [c for c in above["children"] if c != i]
        if not above["children"]:
            del above["children"]
        top = parent[i]
        while top in parent:
            top = parent[top]
        for scene in doc.get("scenes", []):
            if top in scene.get("nodes", []):
                scene["nodes"].append(i)


def _to_trs(node: dict) -> None:
    """Replace a node's `matrix` by the translation, rotation and scale it holds (no shear in a rig)."""
    if "matrix" not in node:
        return
    m = node_matrix(node)
    node.pop("matrix")
    scale = np.linalg.norm(m[:3, :3], axis=0)
    rotation = Rotation.from_matrix(m[:3, :3] / scale).as_quat()
    node["translation"], node["rotation"], node["scale"] = m[:3, 3].tolist(), rotation.tolist(), scale.tolist()


def _append(doc: dict, binary: bytearray, values: np.ndarray, width: int, bounds: bool = False) -> int:
    """Append float32 values (count, width) to the binary chunk as a new view and accessor."""
    data = np.ascontiguousarray(values, dtype="<f4")
    binary.extend(b"\0" * (-len(binary) % 4))
    views, accessors = doc.setdefault("bufferViews", []), doc.setdefault("accessors", [])
    views.append({"buffer": 0, "byteOffset": len(binary), "byteLength": data.nbytes})
    binary.extend(data.tobytes())
    accessor = {"bufferView": len(views) - 1, "componentType": FLOAT, "count": len(data),
                "type": {1: "SCALAR", 3: "VEC3", 4: "VEC4"}[width]}
    if bounds:
        flat = data.reshape(len(data), -1)
        accessor["min"], accessor["max"] = flat.min(0).tolist(), flat.max(0).tolist()
    accessors.append(accessor)
    return len(accessors) - 1


def onto_glb(data: bytes, solved: Solved, where: str) -> bytes:
    """The GLB `data` (the target's own file) with the retargeted animation added."""
    try:
        doc, chunk = read_glb(data)
    except StableMoError as err:
        raise StableMoError(f"{where}: {err}") from None
    buffers = doc.get("buffers") or []
    if buffers and "uri" in buffers[0]:
        raise StableMoError(f"{where}: its first buffer is an external file; write the rig as a self-contained GLB")
    binary = bytearray(chunk[:buffers[0]["byteLength"]] if buffers else b"")
    quats, translation = node_tracks(solved, doc)
    _skinned_meshes_at_root(doc)
    for node in solved.target.extra["nodes"]:  # an animated node must hold TRS, not a matrix (glTF 2.0, 5.25)
        _to_trs(doc["nodes"][node])
    anim = solved.anim
    times = _append(doc, binary, np.arange(anim.num_frames) / anim.fps, 1, bounds=True)
    samplers, channels = [], []
    for j, node in enumerate(solved.target.extra["nodes"]):
        if j == 0:
            samplers.append({"input": times, "output": _append(doc, binary, translation, 3), "interpolation": "LINEAR"})
            channels.append({"sampler": len(samplers) - 1, "target": {"node": node, "path": "translation"}})
        q = quats[:, j] / np.linalg.norm(quats[:, j], axis=-1, keepdims=True)
        samplers.append({"input": times, "output": _append(doc, binary, q, 4), "interpolation": "LINEAR"})
        channels.append({"sampler": len(samplers) - 1, "target": {"node": node, "path": "rotation"}})
    doc.setdefault("animations", []).append({"name": ANIMATION_NAME, "samplers": samplers, "channels": channels})
    binary.extend(b"\0" * (-len(binary) % 4))
    if buffers:
        buffers[0]["byteLength"] = len(binary)
    else:
        doc["buffers"] = [{"byteLength": len(binary)}]
    return pack_glb(doc, bytes(binary))


def character_glb(solved: Solved) -> bytes:
    """The GLB bytes of the retargeted motion: onto the character's own GLB (a .glb rig, or the GLB
    Blender made of an FBX character), or for a .gltf rig its skeleton alone with the animation."""
    source = Path(solved.target.path)
    if "glb" in solved.target.extra:
        return onto_glb(solved.target.extra["glb"], solved, str(source))
    if source.suffix.lower() == ".glb":
        return onto_glb(source.read_bytes(), solved, str(source))
    # the skeleton alone, in world axes at rest (identity rest rotations), as our writer takes it
    return pack_glb(*gltf_document(solved.anim.rig, solved.anim, name=ANIMATION_NAME))
