"""Joint positions -> a BVH rig and its local rotations (closed-form IK), and forward kinematics.

Why our own IK rather than the features' 6D rotation channels: HumanML3D stores, for every bone,
the shortest world-space rotation from the bone's raw rest axis to its direction (motion/features.py,
`swing_rotations`). Such a rotation carries nothing beyond the bone's direction (which the ric
positions give exactly), and its twist depends on where the body faces: joint rotations built from
those swings (parent swing^-1 * child swing) differ by up to 180° for the same pose turned to
heading 90/180/270 (clip 012314: ankles, elbows, collars; scripts/bvh/report.py), and their twist is
undefined where a bone points against its raw axis in world space. Here every rotation is taken
relative to the parent's own frame instead, so no rotation below the root depends on the heading:

- a joint with one child (most joints): the shortest rotation, in the parent joint's frame, from the
  child's rest direction to where the child is. It is singular only when a bone points straight
  against its rest direction relative to its parent (a thigh straight up along the trunk, a knee
  folded 180°, a foot pointing back along the shin), which a body does not do. The chain is solved
  from the root outwards and each bone aims from the *solved* parent position, so errors do not add
  up along a chain.
- a joint with several children (the hips, the upper chest): the least-squares rotation (Kabsch) of
  the rest offsets of its children onto where they are; the rest offsets are the motion's own,
  measured in a trunk frame (up = the spine child, x = left minus right child) and averaged.
- leaves (hands, toes, head): identity (they follow their parent).

Bone lengths are the body's when the caller knows it (a bundle's `body.bone_lengths`), else each
bone's median length over the motion; on a motion whose bones keep one length (mocap, HumanML3D,
generated motions after the rigid-body step) both are that length and the file is exact. The root
position is written as is. A motion whose bones change length (the network's raw output: knees and
forearms by up to ~7 cm) is missed by rigid bones by about that much (stablemo.bvh.fit measures
it), and `stretch` adds per-joint translations that follow the changing lengths exactly (a file
some retargeting tools ignore, and whose limbs come apart at the joints when posed by hand).
Quaternions are (w, x, y, z), shapes carried in comments.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from stablemo.errors import StableMoError
from stablemo.motion.quaternion import qbetween_np, qinv_np, qmul_np, qrot_np
from stablemo.motion.skeleton import Skeleton, get_skeleton

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
END_SITE_FRACTION = 0.5  # a leaf's End Site continues its bone by half the bone's length


@dataclass(frozen=True)
class Rig:
    """A BVH hierarchy: names, parents (root: -1, parents before children), rest offsets
    (J, 3) parent -> joint in the rig's units (root: zero) and End Site offsets of the leaves."""

    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: np.ndarray  # (J, 3)
    end_sites: dict[int, np.ndarray]  # leaf joint -> (3,)

    @property
    def num_joints(self) -> int:
        return len(self.names)

    def children(self, joint: int) -> list[int]:
        return [c for c, p in enumerate(self.parents) if p == joint]


@dataclass
class Animation:
    """A rig in motion: root positions (T, 3) and local joint rotations (T, J, 4), at `fps`.
    `positions` (T, J, 3), when given, are per-joint local translations (files with position
    channels on non-root joints); otherwise every joint sits at its rest offset."""

    rig: Rig
    root: np.ndarray  # (T, 3)
    rotations: np.ndarray  # (T, J, 4)
    fps: float
    positions: np.ndarray | None = None  # (T, J, 3)

    @property
    def num_frames(self) -> int:
        return len(self.root)


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> unit quaternions (..., 4) (w, x, y, z), w >= 0."""
    flat = Rotation.from_matrix(m.reshape(-1, 3, 3)).as_quat()  # (N, 4) x, y, z, w
    q = flat[:, [3, 0, 1, 2]].reshape(m.shape[:-2] + (4,))
    return np.where(q[..., :1] < 0, -q, q)


def kabsch(rest: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Least-squares rotation R (T, 4) with R rest_i ~ target_i. rest (K, 3), target (T, K, 3)."""
    h = np.einsum("ki,tkj->tij", rest, target)  # (T, 3, 3) cross-covariance
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(np.einsum("tij,tjk->tik", u, vt)))  # no reflections
    fix = np.ones(h.shape[:-1])
    fix[:, 2] = np.where(d == 0, 1.0, d)
    r = np.einsum("tji,tj,tkj->tik", vt, fix, u)  # V diag(1, 1, d) U^T
    return matrix_to_quat(r)


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 1e-12, n, 1.0)


def _trunk_frame(x: np.ndarray, joint: int, up: int, plus: int, minus: int) -> np.ndarray:
    """(T, 3, 3) world frame of a branching joint, columns x, y, z: y towards the `up` child,
    x from the `minus` to the `plus` child (made orthogonal), z = x × y."""
    y = _unit(x[:, up] - x[:, joint])
    lateral = x[:, plus] - x[:, minus]
    xa = _unit(lateral - (lateral * y).sum(-1, keepdims=True) * y)
    z = np.cross(xa, y)
    return np.stack([xa, y, z], axis=-1)


def median_lengths(joints: np.ndarray, skeleton: Skeleton | str) -> np.ndarray:
    """(J,) each bone's median length parent -> joint over the motion (root 0). joints (T, J, 3)."""
    parents = np.array(get_skeleton(skeleton).parents)
    bones = joints[:, 1:] - joints[:, parents[1:]]  # (T, J-1, 3)
    return np.concatenate([[0.0], np.median(np.linalg.norm(bones, axis=-1), axis=0)])


def build_rig(joints: np.ndarray, skeleton: Skeleton | str, names: tuple[str, ...], rest_dirs: np.ndarray,
              lengths: np.ndarray | None = None) -> Rig:
    """Rest offsets of `lengths` (J,) (default: the motion's median bone lengths) along the rest
    directions; the branching joints' children keep the motion's own directions. joints (T, J, 3)."""
    skel = get_skeleton(skeleton)
    parents = np.array(skel.parents)
    num = skel.num_joints
    lengths = median_lengths(joints, skel) if lengths is None else np.asarray(lengths, dtype=np.float64)
    scale = max(float(lengths.max()), 1e-300)
    for j in range(1, num):
        if lengths[j] <= 1e-6 * scale:
            raise StableMoError(
                f"joints: bone {skel.joint_names[parents[j]]} -> {skel.joint_names[j]} has zero length; not a body?")
    offsets = lengths[:, None] * rest_dirs
    for joint in range(num):
        kids = [c for c in range(num) if parents[c] == joint]
        if len(kids) < 2:
            continue
        up, plus, minus = _branch_roles(kids, rest_dirs, skel.name, joint)
        frame = _trunk_frame(joints, joint, up, plus, minus)  # (T, 3, 3)
        for c in kids:
            local = np.einsum("tji,tj->ti", frame, joints[:, c] - joints[:, joint])  # (T, 3)
            offsets[c] = lengths[c] * _unit(local.mean(0))
    end_sites = {
        j: END_SITE_FRACTION * lengths[j] * rest_dirs[j]
        for j in range(num) if j > 0 and not np.any(parents == j)
    }
    return Rig(tuple(names), tuple(int(p) for p in parents), offsets, end_sites)


def _branch_roles(kids: list[int], rest_dirs: np.ndarray, name: str, joint: int) -> tuple[int, int, int]:
    """The up child (rest +y) and the +x / -x children of a branching joint."""
    try:
        up = next(c for c in kids if rest_dirs[c][1] > 0.5)
        plus = next(c for c in kids if rest_dirs[c][0] > 0.5)
        minus = next(c for c in kids if rest_dirs[c][0] < -0.5)
    except StopIteration:
        raise ValueError(f"{name}: joint {joint} branches without an up, a +x and a -x child") from None
    return up, plus, minus


def solve_rotations(joints: np.ndarray, rig: Rig, stretch: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """Local rotations (T, J, 4) that put the rig's joints on `joints` (T, J, 3), and with
    `stretch` the per-frame local translations (T, J, 3) that make every joint exact (bones whose
    length changes from frame to frame, as in generated motions); else None (rigid bones)."""
    t, num = joints.shape[:2]
    local = np.broadcast_to(IDENTITY, (t, num, 4)).copy()
    world = np.empty((t, num, 4))
    pos = np.empty((t, num, 3))
    pos[:, 0] = joints[:, 0]
    translations = np.broadcast_to(rig.offsets, (t, num, 3)).copy() if stretch else None
    for j in range(num):  # parents come before children
        p = rig.parents[j]
        parent_world = world[:, p] if p >= 0 else np.broadcast_to(IDENTITY, (t, 4))
        if p >= 0 and stretch:
            translations[:, j] = qrot_np(qinv_np(parent_world), joints[:, j] - pos[:, p])
            pos[:, j] = joints[:, j]
        elif p >= 0:
            pos[:, j] = pos[:, p] + qrot_np(parent_world, np.broadcast_to(rig.offsets[j], (t, 3)))
        kids = rig.children(j)
        if len(kids) == 1:
            c = kids[0]
            aim = qrot_np(qinv_np(parent_world), joints[:, c] - pos[:, j])  # (T, 3) in the parent frame
            local[:, j] = qbetween_np(np.broadcast_to(rig.offsets[c], aim.shape), aim)
        elif len(kids) > 1:
            rot = kabsch(rig.offsets[kids], joints[:, kids] - pos[:, j, None])  # (T, 4) world
            local[:, j] = qmul_np(qinv_np(parent_world), rot)
        world[:, j] = qmul_np(parent_world, local[:, j])
    # one hemisphere per frame, continuous in time: a slerp between frames then takes the short way
    if not np.all(np.isfinite(local)):
        frame = int(np.argwhere(~np.isfinite(local))[0, 0])
        raise StableMoError(f"joints: degenerate pose at frame {frame} (coinciding joints)")
    return continuous_hemisphere(local), translations


def continuous_hemisphere(q: np.ndarray) -> np.ndarray:
    """Flip q_t to -q_t where that is closer to q_{t-1} (same rotation). q (T, ..., 4)."""
    out = q.copy()
    dots = (out[1:] * out[:-1]).sum(-1)
    flips = np.cumsum(dots < 0, axis=0) % 2  # each sign change toggles the following frames
    out[1:] *= np.where(flips[..., None] == 1, -1.0, 1.0)
    return out


def forward_kinematics(anim: Animation) -> np.ndarray:
    """World joint positions (T, J, 3) of an animation."""
    rig = anim.rig
    t = anim.num_frames
    world = np.empty((t, rig.num_joints, 4))
    pos = np.empty((t, rig.num_joints, 3))
    for j, p in enumerate(rig.parents):
        if p < 0:
            world[:, j] = anim.rotations[:, j]
            pos[:, j] = anim.root
            continue
        offset = anim.positions[:, j] if anim.positions is not None else np.broadcast_to(rig.offsets[j], (t, 3))
        pos[:, j] = pos[:, p] + qrot_np(world[:, p], offset)
        world[:, j] = qmul_np(world[:, p], anim.rotations[:, j])
    return pos


def joints_to_animation(joints: np.ndarray, skeleton: Skeleton | str, fps: float, stretch: bool = False,
                        bone_lengths: np.ndarray | None = None) -> Animation:
    """The writer's core: joints (T, J, 3) of `skeleton` -> a T-pose rig and its animation.
    stretch: also per-joint translations, so that bones may change length and every joint is exact.
    bone_lengths: (J,) the rig's bones (parent -> joint, root 0, the joints' units), checked by the
    caller; default the motion's median lengths."""
    from stablemo.bvh.names import bvh_names, rest_directions

    skel = get_skeleton(skeleton)
    x = np.asarray(joints, dtype=np.float64)
    if x.ndim != 3 or x.shape[1:] != (skel.num_joints, 3):
        raise StableMoError(f"joints: expected (T, {skel.num_joints}, 3) for {skel.name}, got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise StableMoError("joints: contain NaN or Inf")
    rig = build_rig(x, skel, bvh_names(skel), rest_directions(skel), bone_lengths)
    rotations, translations = solve_rotations(x, rig, stretch)
    return Animation(rig, x[:, 0].copy(), rotations, float(fps), translations)
