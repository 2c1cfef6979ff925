"""A glTF 2.0 / GLB file's skeleton at rest: the node tree of its first skin.

Only the JSON part is read (node names, children, TRS or matrix, skins[0].joints): a skeleton's
rest pose is its nodes' transforms, no buffer is needed. pygltflib (PyPI, maintained) was
considered: it parses the same JSON into dataclasses but decodes no accessor either, so it would
add a dependency and save none of this file's work (the tree walk and the world transforms).
The rest pose is the nodes' own transforms (what an animation replaces), not the inverse bind
matrices; glTF is y up, metres, +z forward, as HumanML3D.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from stablemo.errors import StableMoError
from stablemo.retarget.rest import RestRig, leaf_end_sites

GLB_MAGIC = b"glTF"
JSON_CHUNK = 0x4E4F534A


def read_json(path: Path) -> dict:
    """The glTF JSON of a .gltf or .glb file."""
    data = path.read_bytes()
    if data[:4] == GLB_MAGIC:
        if len(data) < 20:
            raise StableMoError(f"{path}: truncated GLB header")
        version, length = struct.unpack_from("<II", data, 4)
        chunk_len, chunk_type = struct.unpack_from("<II", data, 12)
        if version != 2 or chunk_type != JSON_CHUNK or 20 + chunk_len > min(length, len(data)):
            raise StableMoError(f"{path}: not a glTF 2.0 GLB (version {version}, first chunk not JSON or cut short)")
        text = data[20:20 + chunk_len]
    else:
        text = data
    try:
        doc = json.loads(text.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise StableMoError(f"{path}: not glTF JSON ({str(err).splitlines()[0]})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("nodes"), list):
        raise StableMoError(f"{path}: no nodes; not a glTF scene")
    return doc


def node_matrix(node: dict) -> np.ndarray:
    """(4, 4) local transform of a node (matrix, or translation * rotation * scale)."""
    try:
        if "matrix" in node:
            m = np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T  # column-major in the file
        else:
            m = np.eye(4)
            m[:3, :3] = (Rotation.from_quat(np.array(node.get("rotation", [0, 0, 0, 1]), dtype=np.float64)).as_matrix()
                         * np.array(node.get("scale", [1, 1, 1]), dtype=np.float64))
            m[:3, 3] = np.array(node.get("translation", [0, 0, 0]), dtype=np.float64)
    except (TypeError, ValueError) as err:  # wrong lengths, strings, a zero quaternion
        raise StableMoError(f"node {node.get('name', '?')!r}: not a transform ({err})") from None
    if not np.all(np.isfinite(m)):
        raise StableMoError(f"node {node.get('name', '?')!r}: a transform with NaN or Inf")
    return m


def _parents(nodes: list, path: Path) -> dict[int, int]:
    """node -> its parent; a child index out of range, a node with two parents or a loop is one line."""
    parent: dict[int, int] = {}
    for i, node in enumerate(nodes):
        if not isinstance(node, dict):
            raise StableMoError(f"{path}: nodes[{i}] is not an object")
        for c in node.get("children", []):
            if not isinstance(c, int) or not 0 <= c < len(nodes) or c in parent or c == i:
                raise StableMoError(f"{path}: nodes[{i}].children: {c!r} is not a node of its own (glTF: a tree)")
            parent[c] = i
    for i in range(len(nodes)):  # a loop never reaches a root
        seen, n = set(), i
        while n in parent:
            if n in seen:
                raise StableMoError(f"{path}: the nodes' children form a loop (at nodes[{n}]); glTF nodes form trees")
            seen.add(n)
            n = parent[n]
    return parent


def read_gltf_rig(path: str | Path) -> RestRig:
    path = Path(path)
    doc = read_json(path)
    nodes = doc["nodes"]
    skins = doc.get("skins") or []
    if not isinstance(skins, list) or not skins or not isinstance(skins[0], dict) or not skins[0].get("joints"):
        raise StableMoError(f"{path}: no skin; a rig to retarget onto is a skinned character")
    parent = _parents(nodes, path)
    world: dict[int, np.ndarray] = {}

    def world_of(i: int) -> np.ndarray:
        chain = []
        while i not in world:
            chain.append(i)
            if i not in parent:
                break
            i = parent[i]
        for n in reversed(chain):
            above = world.get(parent[n], np.eye(4)) if n in parent else np.eye(4)
            world[n] = above @ node_matrix(nodes[n])
        return world[chain[0]] if chain else world[i]

    joints = skins[0]["joints"]
    joints = list(dict.fromkeys(joints)) if isinstance(joints, list) else [None]
    if not all(isinstance(j, int) and 0 <= j < len(nodes) for j in joints):
        raise StableMoError(f"{path}: skins[0].joints names a node that does not exist")
    members = set(joints)

    def joint_parent(n: int) -> int | None:
        while n in parent:
            n = parent[n]
            if n in members:
                return n
        return None

    depth = {}
    for n in joints:
        d, m = 0, n
        while (m := joint_parent(m)) is not None:
            d += 1
        depth[n] = d
    order = sorted(joints, key=lambda n: (depth[n], joints.index(n)))
    roots = [n for n in order if joint_parent(n) is None]
    if len(roots) != 1:
        raise StableMoError(f"{path}: the skin's joints form {len(roots)} trees; expected one skeleton")
    index = {n: i for i, n in enumerate(order)}
    parents = tuple(-1 if joint_parent(n) is None else index[joint_parent(n)] for n in order)
    try:
        mats = np.stack([world_of(n) for n in order])  # (J, 4, 4)
    except StableMoError as err:
        raise StableMoError(f"{path}: {err}") from None
    pos = mats[:, :3, 3]
    offsets = pos - np.where(np.array(parents)[:, None] >= 0, pos[[max(p, 0) for p in parents]], 0.0)
    basis = mats[:, :3, :3] / np.linalg.norm(mats[:, :3, :3], axis=1, keepdims=True)  # scale out of the columns
    quat = Rotation.from_matrix(basis).as_quat()[:, [3, 0, 1, 2]]
    names = []
    for n in order:
        name = str(nodes[n].get("name") or f"node{n}")
        names.append(name if name not in names else f"{name}.{n}")
    return RestRig(tuple(names), parents, offsets, leaf_end_sites(parents, offsets), quat, "gltf", str(path),
                   {"nodes": order})
