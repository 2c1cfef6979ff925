"""Joint topologies footskate needs (from the formats' public code; no dependency on stablemo).

Feet are given in contact order [L_heel, L_toe, R_heel, R_toe] (heel = ankle joint, toe = the
toe/ball joint), matching stablemo's `feet_left + feet_right`.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Topology:
    name: str
    parents: tuple[int, ...]
    feet: tuple[int, int, int, int]
    up_axis: int
    fps: float
    unit: float = 1.0   # metres per data unit (the cleanup's thresholds are in metres)

    @property
    def num_joints(self) -> int:
        return len(self.parents)


# HumanML3D (SMPL-22): pelvis, l_hip, r_hip, spine1, l_knee, r_knee, spine2, l_ankle, r_ankle,
# spine3, l_foot, r_foot, neck, l_collar, r_collar, head, l_shoulder, r_shoulder, l_elbow,
# r_elbow, l_wrist, r_wrist. y-up, metres, 20 fps.
HUMANML3D = Topology(
    name="humanml3d",
    parents=(-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19),
    feet=(7, 10, 8, 11), up_axis=1, fps=20.0)

# KIT-ML (21 joints), y-up, ~millimetres after HumanML3D's processing, 12.5 fps.
KIT = Topology(
    name="kit",
    parents=(-1, 0, 1, 2, 3, 3, 5, 6, 3, 8, 9, 0, 11, 12, 13, 14, 0, 16, 17, 18, 19),
    feet=(19, 20, 14, 15), up_axis=1, fps=12.5, unit=0.001)

# UnderPressure's 23-joint skeleton (its `data.py` TOPOLOGY), z-up, 100 Hz. Contact joints: ankle (heel) and
# "foot" (toe segment origin).
UP23 = Topology(
    name="underpressure",
    parents=(-1, 0, 1, 2, 3, 4, 5, 4, 7, 8, 9, 4, 11, 12, 13, 0, 15, 16, 17, 0, 19, 20, 21),
    feet=(21, 22, 17, 18), up_axis=2, fps=100.0)

TOPOLOGIES = {t.name: t for t in (HUMANML3D, KIT, UP23)}


def topology_for(num_joints: int) -> Topology:
    for topo in TOPOLOGIES.values():
        if topo.num_joints == num_joints:
            return topo
    raise KeyError(num_joints)
