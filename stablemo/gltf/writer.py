"""Any skeleton with an animation (and optionally a skinned mesh) -> a glTF 2.0 document and its GLB.

Nothing here knows our 22-joint rig: the input is a `stablemo.bvh.Rig` (names, parents, rest
offsets parent -> joint), optional rest rotations per joint (rigs whose bones are not identity at
rest, e.g. a character imported from glTF or FBX), an optional `stablemo.bvh.Animation` (local
rotations per joint, the root's translation or per-joint translations, a frame rate) and optional
`Primitive`s: triangles in the bind pose, each vertex tied to up to four joints.

glTF's frame is ours (y up, the asset faces +z, its left at +x, metres), so positions and rotations
go in unchanged. Choices that keep Khronos' validator free of warnings: the skinned mesh's node sits
at the scene root with no transform of its own (glTF ignores it for skinned meshes), the joints'
root is a second root node, every POSITION and time accessor carries its min/max, rotations are
normalised in float64 before the float32 cast, and every buffer view starts on a 4-byte boundary.
Animation samplers are LINEAR (slerp for rotations) at the animation's frame times, one key per
frame. Quaternions come in as (w, x, y, z) and are written as glTF's (x, y, z, w).
"""

from __future__ import annotations

import json
import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from stablemo.bvh.rig import Animation, Rig
from stablemo.errors import StableMoError

GENERATOR = "StableMo glTF writer"
# glTF component types and buffer-view targets (glTF 2.0 spec, 3.6 and 3.7)
FLOAT, UNSIGNED_BYTE, UNSIGNED_SHORT, UNSIGNED_INT = 5126, 5121, 5123, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
_TYPES = {1: "SCALAR", 3: "VEC3", 4: "VEC4", 16: "MAT4"}
_NUMPY = {FLOAT: np.float32, UNSIGNED_BYTE: np.uint8, UNSIGNED_SHORT: np.uint16, UNSIGNED_INT: np.uint32}


@dataclass(frozen=True)
class Primitive:
    """Triangles of one material, in the bind pose (the rig at rest), skinned to the rig's joints."""

    name: str
    colour: tuple[float, float, float, float]  # linear RGBA base colour
    positions: np.ndarray  # (V, 3) metres, world space at rest
    normals: np.ndarray  # (V, 3) unit
    joints: np.ndarray  # (V, 4) joint indices (the rig's order)
    weights: np.ndarray  # (V, 4) each row sums to 1
    triangles: np.ndarray  # (F, 3) vertex indices, counter-clockwise seen from outside


class _Buffer:
    """The binary chunk: blobs appended on 4-byte boundaries, one buffer view and accessor each."""

    def __init__(self) -> None:
        self.data = bytearray()
        self.views: list[dict] = []
        self.accessors: list[dict] = []

    def add(self, array: np.ndarray, component: int, width: int, target: int | None = None,
            bounds: bool = False) -> int:
        """Append `array` (N, width) or (N,) as one accessor; the accessor's index.
        bounds: write min/max (required for POSITION and animation inputs)."""
        arr = np.ascontiguousarray(array, dtype=_NUMPY[component]).reshape(-1, width)
        pad = -len(self.data) % 4
        self.data.extend(b"\0" * pad)
        view = {"buffer": 0, "byteOffset": len(self.data), "byteLength": arr.nbytes}
        if target is not None:
            view["target"] = target
        self.data.extend(arr.astype(arr.dtype.newbyteorder("<"), copy=False).tobytes())
        self.views.append(view)
        accessor = {"bufferView": len(self.views) - 1, "componentType": component, "count": len(arr),
                    "type": _TYPES[width]}
        if bounds:
            accessor["min"] = [float(v) for v in arr.min(0)]
            accessor["max"] = [float(v) for v in arr.max(0)]
        self.accessors.append(accessor)
        return len(self.accessors) - 1


def _xyzw(q: np.ndarray) -> np.ndarray:
    """(..., 4) (w, x, y, z) -> unit (x, y, z, w) in float64."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return q[..., [1, 2, 3, 0]]


def _matrix(q: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(4, 4) transform of a rotation (w, x, y, z) and a translation (3,)."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    m = np.eye(4)
    m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                 [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                 [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]]
    m[:3, 3] = t
    return m


def rest_world(rig: Rig, rest_rotations: np.ndarray | None = None, rest_root=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(J, 4, 4) each joint's world transform at rest: the root at `rest_root`, every other joint at
    its offset in its parent's frame, turned by `rest_rotations` (J, 4) (w, x, y, z; default identity)."""
    num = rig.num_joints
    rots = np.tile([1.0, 0.0, 0.0, 0.0], (num, 1)) if rest_rotations is None else np.asarray(rest_rotations, float)
    world = np.empty((num, 4, 4))
    for j, p in enumerate(rig.parents):
        local = _matrix(rots[j], rest_root if p < 0 else rig.offsets[j])
        world[j] = local if p < 0 else world[p] @ local
    return world


def _check(rig: Rig, anim: Animation | None, primitives: Sequence[Primitive], rest_rotations) -> None:
    num = rig.num_joints
    if any(p >= j for j, p in enumerate(rig.parents)) or rig.parents[0] != -1 or -1 in rig.parents[1:]:
        raise StableMoError("rig: one root first, every parent before its children")
    if len(set(rig.names)) != num:
        raise StableMoError("rig: joint names must be distinct")
    if rest_rotations is not None and np.shape(rest_rotations) != (num, 4):
        raise StableMoError(f"rest_rotations: expected ({num}, 4), got {np.shape(rest_rotations)}")
    if anim is not None:
        if anim.rig.num_joints != num or anim.rotations.shape != (anim.num_frames, num, 4) or anim.num_frames < 1:
            raise StableMoError(f"animation: expected rotations (T >= 1, {num}, 4) for the rig's joints")
        if not (np.isfinite(anim.fps) and anim.fps > 0):
            raise StableMoError(f"animation: fps={anim.fps!r} must be a positive number")
        arrays = [anim.root, anim.rotations] + ([anim.positions] if anim.positions is not None else [])
        if not all(np.all(np.isfinite(a)) for a in arrays):
            raise StableMoError("animation: contains NaN or Inf")
    for prim in primitives:
        v = len(prim.positions)
        shapes = {"positions": (v, 3), "normals": (v, 3), "joints": (v, 4), "weights": (v, 4)}
        for field, shape in shapes.items():
            if np.shape(getattr(prim, field)) != shape:
                raise StableMoError(f"mesh {prim.name}: {field} must be {shape}, got {np.shape(getattr(prim, field))}")
        if prim.triangles.ndim != 2 or prim.triangles.shape[1] != 3 or prim.triangles.size == 0:
            raise StableMoError(f"mesh {prim.name}: triangles must be (F >= 1, 3)")
        if prim.triangles.min() < 0 or prim.triangles.max() >= v or prim.joints.min() < 0 or prim.joints.max() >= num:
            raise StableMoError(f"mesh {prim.name}: a vertex or joint index is out of range")


def gltf_document(rig: Rig, anim: Animation | None = None, primitives: Sequence[Primitive] = (), *,
                  rest_rotations: np.ndarray | None = None, rest_root=(0.0, 0.0, 0.0),
                  name: str = "motion") -> tuple[dict, bytes]:
    """The glTF JSON (a dict) and its binary buffer. Joints are nodes 0..J-1 in the rig's order, named
    as the rig; the mesh (when `primitives` are given) is the last node, skinned to all joints, with
    inverse bind matrices from the rest pose (`rest_world`). The rest pose is also each joint
    node's own TRS. `anim` (optional) becomes one animation `name`: a rotation channel per joint, a
    translation channel for the root (and for every joint when `anim.positions` is given)."""
    _check(rig, anim, primitives, rest_rotations)
    num = rig.num_joints
    rots = np.tile([1.0, 0.0, 0.0, 0.0], (num, 1)) if rest_rotations is None else np.asarray(rest_rotations, float)
    buf = _Buffer()
    nodes = []
    for j in range(num):
        node = {"name": rig.names[j]}
        translation = np.asarray(rest_root if rig.parents[j] < 0 else rig.offsets[j], dtype=np.float64)
        if np.any(translation != 0):
            node["translation"] = [float(v) for v in translation]
        rotation = _xyzw(rots[j])
        if not np.allclose(rotation, [0, 0, 0, 1], rtol=0, atol=1e-12):
            node["rotation"] = [float(v) for v in rotation]
        kids = rig.children(j)
        if kids:
            node["children"] = kids
        nodes.append(node)
    doc: dict = {"asset": {"version": "2.0", "generator": GENERATOR}, "scene": 0,
                 "scenes": [{"name": name, "nodes": [0]}], "nodes": nodes}
    if primitives:
        world = rest_world(rig, rots, rest_root)  # (J, 4, 4)
        ibm = np.linalg.inv(world)
        ibm[:, 3] = (0.0, 0.0, 0.0, 1.0)  # exactly affine, as the validator asks
        ibm_accessor = buf.add(ibm.transpose(0, 2, 1).reshape(num, 16), FLOAT, 16)  # column-major
        materials, mesh_primitives = [], []
        for prim in primitives:
            index_type = UNSIGNED_SHORT if len(prim.positions) < 65536 else UNSIGNED_INT
            joint_type = UNSIGNED_BYTE if num <= 256 else UNSIGNED_SHORT
            normals = prim.normals / np.linalg.norm(prim.normals, axis=1, keepdims=True)
            weights = prim.weights / prim.weights.sum(1, keepdims=True)
            attributes = {
                "POSITION": buf.add(prim.positions, FLOAT, 3, ARRAY_BUFFER, bounds=True),
                "NORMAL": buf.add(normals, FLOAT, 3, ARRAY_BUFFER),
                "JOINTS_0": buf.add(prim.joints, joint_type, 4, ARRAY_BUFFER),
                "WEIGHTS_0": buf.add(weights, FLOAT, 4, ARRAY_BUFFER),
            }
            indices = buf.add(prim.triangles.reshape(-1), index_type, 1, ELEMENT_ARRAY_BUFFER)
            mesh_primitives.append({"attributes": attributes, "indices": indices, "material": len(materials)})
            materials.append({"name": prim.name, "pbrMetallicRoughness": {
                "baseColorFactor": [float(c) for c in prim.colour], "metallicFactor": 0.0, "roughnessFactor": 0.8}})
        doc["materials"] = materials
        doc["meshes"] = [{"name": f"{name} body", "primitives": mesh_primitives}]
        doc["skins"] = [{"name": f"{name} skin", "joints": list(range(num)), "skeleton": 0,
                         "inverseBindMatrices": ibm_accessor}]
        nodes.append({"name": f"{name} body", "mesh": 0, "skin": 0})
        doc["scenes"][0]["nodes"].append(num)
    if anim is not None:
        doc["animations"] = [_animation(buf, anim, name)]
    if buf.data:
        doc["buffers"] = [{"byteLength": len(buf.data)}]
        doc["bufferViews"] = buf.views
        doc["accessors"] = buf.accessors
    return doc, bytes(buf.data)


def _animation(buf: _Buffer, anim: Animation, name: str) -> dict:
    times = buf.add(np.arange(anim.num_frames) / anim.fps, FLOAT, 1, bounds=True)
    samplers, channels = [], []

    def channel(node: int, path: str, values: np.ndarray, width: int) -> None:
        samplers.append({"input": times, "output": buf.add(values, FLOAT, width), "interpolation": "LINEAR"})
        channels.append({"sampler": len(samplers) - 1, "target": {"node": node, "path": path}})

    for j, p in enumerate(anim.rig.parents):
        if p < 0:
            channel(j, "translation", anim.root, 3)
        elif anim.positions is not None:
            channel(j, "translation", anim.positions[:, j], 3)
        channel(j, "rotation", _xyzw(anim.rotations[:, j]), 4)
    return {"name": name, "samplers": samplers, "channels": channels}


def pack_glb(doc: dict, binary: bytes) -> bytes:
    """A GLB container: the 12-byte header, the JSON chunk (space-padded) and the BIN chunk
    (zero-padded), each a multiple of 4 bytes long."""
    text = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    chunks = struct.pack("<II", len(text), 0x4E4F534A) + text
    if binary:
        binary = binary + b"\0" * (-len(binary) % 4)
        chunks += struct.pack("<II", len(binary), 0x004E4942) + binary
    return struct.pack("<III", 0x46546C67, 2, 12 + len(chunks)) + chunks


def glb_bytes(rig: Rig, anim: Animation | None = None, primitives: Sequence[Primitive] = (), **kwargs) -> bytes:
    """The GLB file's bytes; arguments as gltf_document."""
    doc, binary = gltf_document(rig, anim, primitives, **kwargs)
    return pack_glb(doc, binary)


def read_glb(data: bytes) -> tuple[dict, bytes]:
    """(JSON, binary chunk) of a GLB's bytes; for checking what we wrote, not a general reader."""
    magic, version, length = struct.unpack_from("<III", data, 0)
    if magic != 0x46546C67 or version != 2 or length != len(data):
        raise StableMoError("not a glTF 2.0 binary (GLB) file")
    size, _ = struct.unpack_from("<II", data, 12)
    doc = json.loads(data[20:20 + size].decode("utf-8"))
    binary = b""
    if 20 + size < len(data):
        bsize, _ = struct.unpack_from("<II", data, 20 + size)
        binary = data[28 + size:28 + size + bsize]
    return doc, binary


def accessor_array(doc: dict, binary: bytes, index: int) -> np.ndarray:
    """An accessor of a document we wrote (tightly packed views) as (count, width) or (count,)."""
    acc = doc["accessors"][index]
    view = doc["bufferViews"][acc["bufferView"]]
    width = {v: k for k, v in _TYPES.items()}[acc["type"]]
    dtype = np.dtype(_NUMPY[acc["componentType"]]).newbyteorder("<")
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    arr = np.frombuffer(binary, dtype=dtype, count=acc["count"] * width, offset=start)
    return arr.reshape(acc["count"], width) if width > 1 else arr
