"""Skeleton definitions of HumanML3D (22 joints, SMPL body) and KIT-ML (21 joints, MMM).

Numbers follow HumanML3D's `paramUtil.py` / `motion_representation.ipynb` (KIT: text-to-motion's
`utils/motion_process.py`). Parents are derived from the kinematic
chains (each chain starts at an already-placed joint). Conventions: y up, body faces +z after
canonicalisation, left side at +x.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from stablemo.errors import StableMoError

# HumanML3D's motions are 20 fps and at most 196 frames (9.8 s): the defaults of a model's length
# range and frame rate (a bundle states its own in its inference config).
MAX_FRAMES, FPS = 196, 20.0


@dataclass(frozen=True, eq=False)
class Skeleton:
    name: str
    joint_names: tuple[str, ...]
    kinematic_chains: tuple[tuple[int, ...], ...]  # order matters for IK/FK and for the 6D features
    raw_offsets: np.ndarray  # (J, 3) unit rest directions parent -> joint (root: zero)
    bone_lengths: np.ndarray  # (J,) target lengths parent -> joint (root: 0), dataset units
    feet_left: tuple[int, int]
    feet_right: tuple[int, int]
    face_joints: tuple[int, int, int, int]  # [r_hip, l_hip, r_shoulder, l_shoulder]: HumanML3D's face_joint_indx order
    leg_bones: tuple[int, int]  # child joints of the two bones whose lengths set the scale
    contact_threshold: float  # squared per-frame displacement
    fps: float
    units: str = "m"
    # two-bone limbs (upper, middle, end): hip-knee-ankle and shoulder-elbow-wrist; the rigid body
    # step (stablemo.motion.rigid) solves them by IK so hands and feet stay where they were generated
    ik_limbs: tuple[tuple[int, int, int], ...] = ()
    parents: tuple[int, ...] = field(init=False)

    def __post_init__(self) -> None:
        num = len(self.joint_names)
        parents = [-2] * num
        parents[0] = -1
        for chain in self.kinematic_chains:
            if parents[chain[0]] == -2:
                raise ValueError(f"{self.name}: chain {chain} starts at a joint not yet placed")
            for parent, child in zip(chain[:-1], chain[1:]):
                parents[child] = parent
        if -2 in parents:
            raise ValueError(f"{self.name}: joints {[i for i, p in enumerate(parents) if p == -2]} are in no chain")
        object.__setattr__(self, "parents", tuple(parents))
        for arr in (self.raw_offsets, self.bone_lengths):
            arr.setflags(write=False)

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    @property
    def feature_dim(self) -> int:
        # root 4 + ric 3(J-1) + rot6d 6(J-1) + local velocity 3J + contacts 4
        return 12 * self.num_joints - 1

    @property
    def target_offsets(self) -> np.ndarray:
        """(J, 3) rest offsets parent -> joint: raw direction times target length."""
        return self.raw_offsets * self.bone_lengths[:, None]

    @property
    def legs(self) -> dict[str, tuple[int, int, int]]:
        """Each side's leg among ik_limbs: {"left"/"right": (hip, knee, ankle)}, the limb whose end
        carries that side's contact joints (HumanML3D: the ankle is one of them; KIT: its
        metatarsal and toe hang below the ankle)."""
        out = {}
        for limb in self.ik_limbs:
            below = {limb[2]}
            for j in range(self.num_joints):  # chains list parents before children
                if self.parents[j] in below:
                    below.add(j)
            for side, feet in (("left", self.feet_left), ("right", self.feet_right)):
                if below & set(feet):
                    out[side] = limb
        return out

    @property
    def per_metre(self) -> float:
        """Skeleton units per metre (HumanML3D metres: 1; KIT-ML millimetres: 1000)."""
        return 1000.0 if self.units == "mm" else 1.0

    @property
    def contact_joints(self) -> tuple[int, int, int, int]:
        """Joints whose contacts are stored, in feature order [L_a, L_b, R_a, R_b]."""
        return (*self.feet_left, *self.feet_right)

    def side_of_chain(self, chain_index: int) -> str:
        """'left', 'right' or 'center' for rendering colours, from the chain's second joint name."""
        name = self.joint_names[self.kinematic_chains[chain_index][1]]
        return "left" if name.startswith("L_") else "right" if name.startswith("R_") else "center"

    def __repr__(self) -> str:
        return f"Skeleton({self.name!r}, joints={self.num_joints}, feature_dim={self.feature_dim})"


def _raw_offsets(num: int, directions: dict[tuple[int, int, int], tuple[int, ...]]) -> np.ndarray:
    out = np.zeros((num, 3))
    out[1:] = (0.0, -1.0, 0.0)  # "−y: others"
    for direction, joints in directions.items():
        out[list(joints)] = direction
    return out


HUMANML3D = Skeleton(
    name="humanml3d",
    joint_names=(
        "pelvis", "L_hip", "R_hip", "spine1", "L_knee", "R_knee", "spine2", "L_ankle", "R_ankle",
        "spine3", "L_foot", "R_foot", "neck", "L_collar", "R_collar", "head", "L_shoulder",
        "R_shoulder", "L_elbow", "R_elbow", "L_wrist", "R_wrist",
    ),
    kinematic_chains=((0, 2, 5, 8, 11), (0, 1, 4, 7, 10), (0, 3, 6, 9, 12, 15), (9, 14, 17, 19, 21), (9, 13, 16, 18, 20)),
    raw_offsets=_raw_offsets(
        22, {(1, 0, 0): (1, 13), (-1, 0, 0): (2, 14), (0, 1, 0): (3, 6, 9, 12), (0, 0, 1): (10, 11, 15)}
    ),
    # Rounded to 4 decimals (.1031, .1099, …) these would move joints
    # by ~1e-4 m. The reference clip 012314's joints (`new_joints`, made by FK with the exact target
    # offsets) keep every bone at one length to 2e-6 m; these are those lengths (median over frames).
    bone_lengths=np.array(
        [0.0, 0.1030740, 0.1098834, 0.1315682, 0.3936232, 0.3901882, 0.1431902, 0.4324330,
         0.4256434, 0.0573647, 0.1433818, 0.1494191, 0.2193600, 0.1374868, 0.1433828, 0.1030392,
         0.1316140, 0.1229844, 0.2568399, 0.2630919, 0.2660118, 0.2698763]
    ),
    feet_left=(7, 10),
    feet_right=(8, 11),
    face_joints=(2, 1, 17, 16),
    leg_bones=(5, 8),
    contact_threshold=0.002,
    fps=20.0,
    units="m",
    ik_limbs=((1, 4, 7), (2, 5, 8), (16, 18, 20), (17, 19, 21)),
)

# KIT-ML (MMM). Sides follow text-to-motion's KIT fid_l / face_joint_indx conventions (chain 0-11-… is the
# right leg, 0-16-… the left, 3-5-… the right arm, 3-8-… the left arm: contacts store [19, 20]
# first as the left pair). MMM's own marker names (root BP BT BLN BUN LS LE LW RS RE RW LH LK LA
# LMrot LF RH RK RA RMrot RF) call those sides the other way round, and the raw offsets put
# joints 5 and 11 at +x; raw offsets only orient the 6D features, so this changes no number.
#
# Target bone lengths (millimetres): the official pipeline measures them on KIT clip 03950 frame 0,
# which is not available to us. We use the HumanML3D target skeleton above, ×1000, mapped
# segment by segment (thigh, shank, upper arm, forearm, head; the trunk split pelvis→BP→BT→BLN
# takes spine1, spine2+spine3, neck; the shoulder takes the collar→shoulder span; the foot is
# split ankle→metatarsal 100 mm, metatarsal→toe 50 mm). Only the lengths matter: extraction
# rescales every clip to them (scale from bones 17 and 18) and re-places each joint along its
# measured bone direction.
KIT = Skeleton(
    name="kit",
    joint_names=(
        "root", "BP", "BT", "BLN", "BUN",
        "R_shoulder", "R_elbow", "R_wrist", "L_shoulder", "L_elbow", "L_wrist",
        "R_hip", "R_knee", "R_ankle", "R_metatarsal", "R_toe",
        "L_hip", "L_knee", "L_ankle", "L_metatarsal", "L_toe",
    ),
    kinematic_chains=((0, 11, 12, 13, 14, 15), (0, 16, 17, 18, 19, 20), (0, 1, 2, 3, 4), (3, 5, 6, 7), (3, 8, 9, 10)),
    raw_offsets=_raw_offsets(
        21, {(0, 1, 0): (1, 2, 3, 4), (1, 0, 0): (5, 11), (-1, 0, 0): (8, 16), (0, 0, 1): (14, 15, 19, 20)}
    ),
    bone_lengths=np.array(
        [0.0, 131.6, 200.6, 219.4, 103.0, 180.0, 260.0, 268.0, 180.0, 260.0, 268.0,
         106.5, 392.0, 429.0, 100.0, 50.0, 106.5, 392.0, 429.0, 100.0, 50.0]
    ),
    feet_left=(19, 20),
    feet_right=(14, 15),
    face_joints=(11, 16, 5, 8),
    leg_bones=(17, 18),
    contact_threshold=0.05,
    fps=12.5,
    units="mm",
    ik_limbs=((16, 17, 18), (11, 12, 13), (8, 9, 10), (5, 6, 7)),
)

SKELETONS = {"humanml3d": HUMANML3D, "t2m": HUMANML3D, "kit": KIT}


def get_skeleton(name: str | Skeleton) -> Skeleton:
    if isinstance(name, Skeleton):
        return name
    try:
        return SKELETONS[str(name).lower()]
    except KeyError:
        raise StableMoError(f"skeleton {name!r}: unknown (choose humanml3d or kit)") from None


def skeleton_for_shape(shape: tuple[int, ...]) -> Skeleton | None:
    """The skeleton whose feature width (D) or joint count (J, 3) matches the trailing shape."""
    for skel in (HUMANML3D, KIT):
        if shape[-1] == skel.feature_dim or (len(shape) >= 2 and shape[-2:] == (skel.num_joints, 3)):
            return skel
    return None
