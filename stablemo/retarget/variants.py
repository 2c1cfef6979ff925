"""Humanoid rigs made from our body with other names, proportions, units and rest poses: what the
tests and docs/retarget.md measure retargeting on when no character file is at hand.

`variant_rig(convention, legs=1.25, arms=1.0, scale=1.0, a_pose_deg=45, units="cm", extras=True)`
-> (RestRig, {our joint index: the variant's}); `rig_bvh(rig)` its BVH text. Conventions: the name
tables below (Mixamo, Unreal mannequin, Unity Humanoid, VRM, SMPL, SMPL-X, CMU, 3ds Max biped).
Extras are what real rigs carry beyond the body: finger joints under the hands, a twist bone under
each upper arm, CMU's hip joints between the pelvis and the thighs, Unreal's root bone on the floor.
"""

from __future__ import annotations

import numpy as np

from stablemo.bvh.names import bvh_names, rest_directions
from stablemo.motion.skeleton import HUMANML3D
from stablemo.retarget.rest import RestRig, identity_orient, leaf_end_sites

_OURS = bvh_names("humanml3d")


def _sided(template: str) -> tuple[str, ...]:
    """22 names from a template of our order with {S} for the side letter and {Side} for the word."""
    parts = template.split()
    out = []
    for i, part in enumerate(parts):
        side = "Left" if _OURS[i].startswith("Left") else "Right" if _OURS[i].startswith("Right") else ""
        out.append(part.format(S=side[:1], s=side[:1].lower(), Side=side, side=side.lower()))
    return tuple(out)


CONVENTIONS: dict[str, tuple[str, ...]] = {
    "mixamo": tuple(f"mixamorig:{n}" for n in _OURS),
    "unreal": _sided("pelvis thigh_{s} thigh_{s} spine_01 calf_{s} calf_{s} spine_02 foot_{s} foot_{s} spine_03 "
                     "ball_{s} ball_{s} neck_01 clavicle_{s} clavicle_{s} head upperarm_{s} upperarm_{s} "
                     "lowerarm_{s} lowerarm_{s} hand_{s} hand_{s}"),
    "unity": _sided("Hips {Side}UpperLeg {Side}UpperLeg Spine {Side}LowerLeg {Side}LowerLeg Chest {Side}Foot "
                    "{Side}Foot UpperChest {Side}Toes {Side}Toes Neck {Side}Shoulder {Side}Shoulder Head "
                    "{Side}UpperArm {Side}UpperArm {Side}LowerArm {Side}LowerArm {Side}Hand {Side}Hand"),
    "vrm": _sided("J_Bip_C_Hips J_Bip_{S}_UpperLeg J_Bip_{S}_UpperLeg J_Bip_C_Spine J_Bip_{S}_LowerLeg "
                  "J_Bip_{S}_LowerLeg J_Bip_C_Chest J_Bip_{S}_Foot J_Bip_{S}_Foot J_Bip_C_UpperChest "
                  "J_Bip_{S}_ToeBase J_Bip_{S}_ToeBase J_Bip_C_Neck J_Bip_{S}_Shoulder J_Bip_{S}_Shoulder "
                  "J_Bip_C_Head J_Bip_{S}_UpperArm J_Bip_{S}_UpperArm J_Bip_{S}_LowerArm J_Bip_{S}_LowerArm "
                  "J_Bip_{S}_Hand J_Bip_{S}_Hand"),
    "smpl": _sided("pelvis {S}_Hip {S}_Hip Spine1 {S}_Knee {S}_Knee Spine2 {S}_Ankle {S}_Ankle Spine3 {S}_Foot "
                   "{S}_Foot Neck {S}_Collar {S}_Collar Head {S}_Shoulder {S}_Shoulder {S}_Elbow {S}_Elbow "
                   "{S}_Wrist {S}_Wrist"),
    "smplx": _sided("pelvis {side}_hip {side}_hip spine1 {side}_knee {side}_knee spine2 {side}_ankle {side}_ankle "
                    "spine3 {side}_foot {side}_foot neck {side}_collar {side}_collar head {side}_shoulder "
                    "{side}_shoulder {side}_elbow {side}_elbow {side}_wrist {side}_wrist"),
    "cmu": _sided("Hips {Side}UpLeg {Side}UpLeg LowerBack {Side}Leg {Side}Leg Spine {Side}Foot {Side}Foot Spine1 "
                  "{Side}ToeBase {Side}ToeBase Neck {Side}Shoulder {Side}Shoulder Head {Side}Arm {Side}Arm "
                  "{Side}ForeArm {Side}ForeArm {Side}Hand {Side}Hand"),
    # Daz Genesis and Character Creator: a `hip` above the pelvis (CC: CC_Base_Hip, CC_Base_Pelvis);
    # here the hips joint is `hip` and the extras add the pelvis below it (see variant_rig)
    "daz": _sided("hip {s}ThighBend {s}ThighBend abdomenLower {s}Shin {s}Shin abdomenUpper {s}Foot {s}Foot chestUpper "
                  "{s}Toe {s}Toe neckLower {s}Collar {s}Collar head {s}ShldrBend {s}ShldrBend {s}ForearmBend "
                  "{s}ForearmBend {s}Hand {s}Hand"),
    "cc": _sided("CC_Base_Hip CC_Base_{S}_Thigh CC_Base_{S}_Thigh CC_Base_Waist CC_Base_{S}_Calf CC_Base_{S}_Calf "
                 "CC_Base_Spine01 CC_Base_{S}_Foot CC_Base_{S}_Foot CC_Base_Spine02 CC_Base_{S}_ToeBase "
                 "CC_Base_{S}_ToeBase CC_Base_NeckTwist01 CC_Base_{S}_Clavicle CC_Base_{S}_Clavicle CC_Base_Head "
                 "CC_Base_{S}_Upperarm CC_Base_{S}_Upperarm CC_Base_{S}_Forearm CC_Base_{S}_Forearm CC_Base_{S}_Hand "
                 "CC_Base_{S}_Hand"),
    "biped": tuple(n for n in _sided(
        "Bip01_Pelvis Bip01_{S}_Thigh Bip01_{S}_Thigh Bip01_Spine Bip01_{S}_Calf Bip01_{S}_Calf Bip01_Spine1 "
        "Bip01_{S}_Foot Bip01_{S}_Foot Bip01_Spine2 Bip01_{S}_Toe0 Bip01_{S}_Toe0 Bip01_Neck Bip01_{S}_Clavicle "
        "Bip01_{S}_Clavicle Bip01_Head Bip01_{S}_UpperArm Bip01_{S}_UpperArm Bip01_{S}_Forearm Bip01_{S}_Forearm "
        "Bip01_{S}_Hand Bip01_{S}_Hand")),
}
UNITS = {"m": 1.0, "cm": 100.0}
LEG_JOINTS = (4, 5, 7, 8, 10, 11)  # knees, ankles, toes: their bones are the legs
ARM_JOINTS = (18, 19, 20, 21)  # elbows, wrists
ARM_CHAINS = {16: (18, 20), 17: (19, 21)}  # upper arm -> the joints below it


def _rot_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def variant_rig(convention: str = "mixamo", legs: float = 1.0, arms: float = 1.0, scale: float = 1.0,
                a_pose_deg: float = 0.0, units: str = "m", extras: bool = True,
                body: np.ndarray | None = None) -> tuple[RestRig, dict[int, int]]:
    """A rig of our 22 joints renamed, its legs and arms scaled, arms lowered by `a_pose_deg`,
    everything scaled and in `units`. body: (22, 3) T-pose offsets parent -> joint in metres, our
    joint order (e.g. `motion_to_animation(joints).rig.offsets`, a motion's own body); default
    HumanML3D's bone lengths along the rest directions (a wider chest than a real one: the collar
    bones point sideways)."""
    if body is None:
        body = rest_directions(HUMANML3D) * HUMANML3D.bone_lengths[:, None]
    offsets = np.array(body, dtype=np.float64)
    offsets[list(LEG_JOINTS)] *= legs
    offsets[list(ARM_JOINTS)] *= arms
    for upper, below in ARM_CHAINS.items():  # the arms hang from the shoulders by a_pose_deg
        turn = _rot_z(-a_pose_deg if offsets[below[0], 0] > 0 else a_pose_deg)
        offsets[list(below)] = offsets[list(below)] @ turn.T
    names = list(CONVENTIONS[convention])
    parents = list(HUMANML3D.parents)
    index = {i: i for i in range(len(names))}
    if extras:
        def add(name: str, parent: int, offset) -> int:
            names.append(name)
            parents.append(parent)
            nonlocal offsets
            offsets = np.vstack([offsets, offset])
            return len(names) - 1

        for hand in (20, 21):
            reach = offsets[hand] / max(np.linalg.norm(offsets[hand]), 1e-9)
            first = add(f"{names[hand]}Index1", hand, 0.04 * reach)
            add(f"{names[hand]}Index2", first, 0.03 * reach)
        for upper in (16, 17):
            add(f"{names[upper]}_twist_01", upper, 0.5 * offsets[ARM_CHAINS[upper][0]])
        if convention in ("daz", "cc"):  # a pelvis under the hip holding the thighs, the spine beside it
            pelvis = add("pelvis" if convention == "daz" else "CC_Base_Pelvis", 0, np.zeros(3))
            parents[1] = parents[2] = pelvis
        if convention == "unreal":  # a root bone on the floor above the pelvis
            height = -min(_world(offsets, parents)[:, 1])
            names.insert(0, "root")
            parents = [-1] + [p + 1 if p >= 0 else 0 for p in parents]
            offsets = np.vstack([[0.0, 0.0, 0.0], offsets])
            offsets[1] = (0.0, height, 0.0)
            index = {i: j + 1 for i, j in index.items()}
    offsets = offsets * scale * UNITS[units]
    order = _parents_first(parents)
    where = {old: new for new, old in enumerate(order)}
    parents = tuple(-1 if parents[o] < 0 else where[parents[o]] for o in order)
    offsets = offsets[order]
    rig = RestRig(tuple(names[o] for o in order), parents, offsets, leaf_end_sites(parents, offsets),
                  identity_orient(len(order)), "bvh", f"<{convention} variant>")
    return rig, {ours: where[j] for ours, j in index.items()}


def _world(offsets: np.ndarray, parents) -> np.ndarray:
    out = np.zeros_like(offsets)
    for j, p in enumerate(parents):
        out[j] = offsets[j] + (out[p] if p >= 0 else 0.0)
    return out


def _parents_first(parents) -> list[int]:
    order, placed = [], set()
    while len(order) < len(parents):
        for j, p in enumerate(parents):
            if j not in placed and (p < 0 or p in placed):
                order.append(j)
                placed.add(j)
    return order


def rig_bvh(rig: RestRig) -> str:
    """The rig at rest as a one-frame BVH file's text."""
    from stablemo.bvh.rig import Animation
    from stablemo.bvh.text import format_bvh

    rotations = np.tile([1.0, 0.0, 0.0, 0.0], (1, rig.num_joints, 1))
    return format_bvh(Animation(rig.bvh_rig(), rig.offsets[:1].copy(), rotations, 30.0))
