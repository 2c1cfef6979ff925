"""Our own low-poly mannequin, built from a rig's rest pose: one capsule per bone, rigidly skinned.

No third-party asset: every shape is made here from the rig's joint positions at rest. Each bone
parent -> child is a capsule whose two hemispherical caps are centred on the two joints, skinned
with weight 1 to the parent joint (the joint whose rotation moves that bone). A sphere turned about
its own centre is itself, so when a joint bends the caps of the bones meeting there stay closed:
no gaps, no stretching, at the price of rigid (wooden-mannequin) joints. Leaves get a shape of
their own: the head an ellipsoid with a nose (the facing is visible), hands a flat paddle, toes a
short cap. Thicknesses are by bone name (the names of stablemo.bvh.names, the same for HumanML3D
and KIT; an unknown name gets a limb's); the torso is wider than deep.

Colours: the caller's {side: "#rrggbb"} for "left", "right" and "center" (stablemo.outputs.render's,
so the body matches the stick figures), one glTF primitive per colour.
"""

from __future__ import annotations

import numpy as np

from stablemo.bvh.rig import Rig
from stablemo.gltf.writer import Primitive, rest_world

# bone (named by its child joint, side prefix dropped) -> (radius m, width / depth of the section)
BONE_SHAPES: dict[str, tuple[float, float]] = {
    "UpLeg": (0.085, 1.0),    # pelvis -> hip
    "Leg": (0.068, 1.0),      # thigh
    "Foot": (0.050, 1.0),     # shin
    "ToeBase": (0.042, 1.25),  # foot
    "Toe_End": (0.035, 1.25),
    "Spine": (0.100, 1.35),
    "Spine1": (0.100, 1.35),
    "Spine2": (0.110, 1.35),
    "Neck": (0.050, 1.0),
    "Shoulder": (0.050, 1.0),  # collar
    "Arm": (0.050, 1.0),      # collar -> shoulder (KIT: neck -> shoulder)
    "ForeArm": (0.046, 1.0),  # upper arm
    "Hand": (0.038, 1.0),     # forearm
    "Head": (0.045, 1.0),     # neck -> head
}
DEFAULT_SHAPE = (0.04, 1.0)
PELVIS_BONES = ("UpLeg",)  # drawn in the centre colour: they are the pelvis, not the legs
# the foot (ankle -> toe joint): its capsule's toe end is raised by its radius (at rest, across the
# bone towards +y) and reaches past the toe joint, so a foot whose toe joint is on the floor has its
# sole there instead of sinking a radius into it; SOLE is how far the sole is below a flat foot's joints
SOLE_BONES = ("ToeBase",)
TOE_REACH = 0.015
SOLE = max(BONE_SHAPES["Foot"][0], BONE_SHAPES["ToeBase"][0])  # the shin's and the foot's caps round the ankle
HEAD_RADII = (0.085, 0.11, 0.10)  # x, y, z half-axes of the head
HEAD_LIFT = 0.075  # the head's centre above the head joint
HAND = (0.09, 0.045, 0.018)  # length along the forearm, half-width, half-thickness
SEGMENTS, CAP_RINGS = 10, 3  # around a capsule, and rings per cap (low-poly on purpose)


def part_of(name: str) -> tuple[str, str]:
    """('left' | 'right' | 'center', the name without its side)."""
    for side in ("Left", "Right"):
        if name.startswith(side):
            return side.lower(), name[len(side):]
    return "center", name


def srgb_to_linear(hex_colour: str) -> tuple[float, float, float, float]:
    """'#rrggbb' -> linear RGBA (glTF base colours are linear; viewers show them as the sRGB hex)."""
    c = np.array([int(hex_colour[i:i + 2], 16) for i in (1, 3, 5)]) / 255.0
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return (*(float(v) for v in lin), 1.0)


def _frame(axis: np.ndarray, lateral=(1.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors across `axis`: u as close to `lateral` as possible, v = axis x u."""
    ref = np.asarray(lateral, float)
    if abs(ref @ axis) > 0.9:
        ref = np.array([0.0, 0.0, 1.0])
    u = ref - (ref @ axis) * axis
    u /= np.linalg.norm(u)
    return u, np.cross(axis, u)


def capsule(a: np.ndarray, b: np.ndarray, radius: float, aspect: float = 1.0,
            lateral=(1.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3), triangles (F, 3)) of a capsule whose caps are centred on a and b; its
    section is `aspect` times wider along `lateral` than across (an ellipse; the caps follow it)."""
    axis = np.asarray(b, float) - np.asarray(a, float)
    length = np.linalg.norm(axis)
    axis = axis / length if length > 1e-9 else np.array([0.0, 1.0, 0.0])
    u, v = _frame(axis, lateral)
    theta = np.arange(SEGMENTS) * 2 * np.pi / SEGMENTS
    ring = np.cos(theta)[:, None] * (aspect * radius * u) + np.sin(theta)[:, None] * (radius * v)  # (S, 3)
    # latitudes from the a-pole to the b-pole, the equators at a and at b (one equator when a is b:
    # a sphere); the poles are single points
    if length > 1e-9:
        phis = np.concatenate([np.linspace(-np.pi / 2, 0, CAP_RINGS + 1)[1:], np.linspace(0, np.pi / 2, CAP_RINGS + 1)[:-1]])
        centres = [a] * CAP_RINGS + [b] * CAP_RINGS
    else:
        phis = np.linspace(-np.pi / 2, np.pi / 2, 2 * CAP_RINGS + 1)[1:-1]
        centres = [a] * len(phis)
    rings = [c + radius * np.sin(phi) * axis + np.cos(phi) * ring for phi, c in zip(phis, centres)]
    verts = np.concatenate([[a - radius * axis], *rings, [b + radius * axis]])
    last = len(verts) - 1
    idx = np.arange(SEGMENTS)
    nxt = (idx + 1) % SEGMENTS
    tris = [np.stack([np.zeros(SEGMENTS, int), 1 + nxt, 1 + idx], 1)]
    for r in range(len(rings) - 1):
        lo, hi = 1 + r * SEGMENTS, 1 + (r + 1) * SEGMENTS
        tris.append(np.stack([lo + idx, lo + nxt, hi + nxt], 1))
        tris.append(np.stack([lo + idx, hi + nxt, hi + idx], 1))
    top = 1 + (len(rings) - 1) * SEGMENTS
    tris.append(np.stack([np.full(SEGMENTS, last), top + idx, top + nxt], 1))
    return verts, _outward(verts, np.concatenate(tris))


def _outward(verts: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Triangles wound counter-clockwise seen from outside (a closed shape's signed volume > 0)."""
    p = verts[tris]  # (F, 3, 3)
    volume = np.einsum("fi,fi->", p[:, 0], np.cross(p[:, 1], p[:, 2]))
    return tris if volume > 0 else tris[:, ::-1]


def vertex_normals(verts: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(V, 3) unit area-weighted normals of a closed triangle mesh."""
    p = verts[tris]
    face = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])  # (F, 3), length = 2 * area
    normals = np.zeros_like(verts)
    for k in range(3):
        np.add.at(normals, tris[:, k], face)
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)


def _ellipsoid(centre: np.ndarray, radii) -> tuple[np.ndarray, np.ndarray]:
    """A unit sphere (a capsule of zero length) squashed to half-axes `radii` (x, y, z)."""
    verts, tris = capsule(np.zeros(3), np.zeros(3), 1.0)
    return centre + verts * np.asarray(radii), tris


def mannequin(rig: Rig, colours: dict[str, str], rest_rotations: np.ndarray | None = None,
              rest_root=(0.0, 0.0, 0.0)) -> list[Primitive]:
    """The body of a humanoid rig at rest (one Primitive per colour of `colours`: left, right,
    center), skinned to the rig's joints; rest_rotations / rest_root as stablemo.gltf.writer."""
    world = rest_world(rig, rest_rotations, rest_root)
    pos = world[:, :3, 3]  # (J, 3) rest joint positions
    parts: dict[str, list[tuple[np.ndarray, np.ndarray, int]]] = {side: [] for side in ("left", "right", "center")}
    for j, p in enumerate(rig.parents):
        side, kind = part_of(rig.names[j])
        if p >= 0:
            radius, aspect = BONE_SHAPES.get(kind, DEFAULT_SHAPE)
            end = pos[j]
            if kind in SOLE_BONES:  # the sole passes through the toe joint, which the floor step puts on y = 0
                along = (pos[j] - pos[p]) / np.linalg.norm(pos[j] - pos[p])
                up = np.array([0.0, 1.0, 0.0]) - along[1] * along
                end = pos[j] + TOE_REACH * along + radius * up / max(np.linalg.norm(up), 1e-9)
            shape = capsule(pos[p], end, radius, aspect)
            parts["center" if kind in PELVIS_BONES else side].append((*shape, p))
        if rig.children(j) or p < 0 or kind in SOLE_BONES:
            continue
        bone = pos[j] - pos[p]
        along = bone / np.linalg.norm(bone)
        if kind == "Head":
            head = _ellipsoid(pos[j] + np.array([0.0, HEAD_LIFT, 0.0]), HEAD_RADII)
            nose_at = pos[j] + np.array([0.0, HEAD_LIFT * 0.8, HEAD_RADII[2] * 0.9])
            nose = capsule(nose_at, nose_at + np.array([0.0, 0.0, 0.03]), 0.02)
            parts[side].extend([(*head, j), (*nose, j)])
        elif kind == "Hand":
            length, half_width, half_thick = HAND
            # flat across the palm: wide in the body's forward direction at rest
            hand = capsule(pos[j] + along * half_width, pos[j] + along * (length - half_width), half_thick,
                           half_width / half_thick, lateral=(0.0, 0.0, 1.0))
            parts[side].append((*hand, j))
        else:  # toes and any other leaf: a short cap continuing its bone
            radius, aspect = BONE_SHAPES.get(kind, DEFAULT_SHAPE)
            tip = capsule(pos[j], pos[j] + along * radius, radius * 0.85, aspect)
            parts[side].append((*tip, j))
    primitives = []
    for side, shapes in parts.items():
        if not shapes:
            continue
        verts, tris, joints, base = [], [], [], 0
        for v, t, joint in shapes:
            verts.append(v)
            tris.append(t + base)
            joints.append(np.full(len(v), joint))
            base += len(v)
        verts_all = np.concatenate(verts)
        tris_all = np.concatenate(tris)
        normals = np.concatenate([vertex_normals(v, t) for v, t, _ in shapes])
        skin = np.zeros((len(verts_all), 4), dtype=np.int64)
        skin[:, 0] = np.concatenate(joints)
        weights = np.zeros((len(verts_all), 4))
        weights[:, 0] = 1.0  # rigid: each shape follows one joint
        primitives.append(Primitive(side, srgb_to_linear(colours[side]), verts_all.astype(np.float32),
                                    normals.astype(np.float32), skin, weights, tris_all))
    return primitives
