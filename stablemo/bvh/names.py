"""Joint names and rest directions of the BVH rigs we write, and name maps for the BVH files we read.

Written rigs use the names animators know from Mixamo-style rigs (Hips, LeftUpLeg, LeftLeg, ...)
without a namespace prefix. Their rest pose is a T-pose: legs and spine along the skeleton's raw
directions, arms straight out along ±x, feet forward (+z), head up; the trunk's branching joints
(hips, upper chest) keep the motion's own measured geometry (see rig.py).

Reading maps a file's joint names onto the HumanML3D joints: a map is {our BVH name: file name}.
Built-in maps: `stablemo` (ours, also Mixamo once a `prefix:` namespace is dropped) and `cmu` (the
widely shared BVH conversion of the CMU mocap database: LHipJoint, LowerBack, Neck1, ...). A YAML
file with the same form (`Hips: pelvis_bone`, ...) covers any other rig.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from stablemo.errors import StableMoError
from stablemo.motion.skeleton import Skeleton, get_skeleton

# skeleton joint index -> BVH joint name
BVH_NAMES: dict[str, tuple[str, ...]] = {
    "humanml3d": (
        "Hips", "LeftUpLeg", "RightUpLeg", "Spine", "LeftLeg", "RightLeg", "Spine1", "LeftFoot",
        "RightFoot", "Spine2", "LeftToeBase", "RightToeBase", "Neck", "LeftShoulder", "RightShoulder",
        "Head", "LeftArm", "RightArm", "LeftForeArm", "RightForeArm", "LeftHand", "RightHand",
    ),
    # KIT (MMM) has no clavicle joint: BLN -> shoulder is the clavicle bone, so the shoulder joint
    # is the upper arm's (LeftArm). Sides follow the skeleton's names (see skeleton.py).
    "kit": (
        "Hips", "Spine", "Spine1", "Neck", "Head",
        "RightArm", "RightForeArm", "RightHand", "LeftArm", "LeftForeArm", "LeftHand",
        "RightUpLeg", "RightLeg", "RightFoot", "RightToeBase", "RightToe_End",
        "LeftUpLeg", "LeftLeg", "LeftFoot", "LeftToeBase", "LeftToe_End",
    ),
}

# joints whose rest direction (bone parent -> joint) differs from the skeleton's raw offsets: the
# raw offsets hang the arms down and put the head in front of the neck (they only orient the 6D
# features); an animator's rest pose is a T-pose with the head above the neck.
_REST_OVERRIDES: dict[str, dict[int, tuple[float, float, float]]] = {
    "humanml3d": {16: (1, 0, 0), 18: (1, 0, 0), 20: (1, 0, 0), 17: (-1, 0, 0), 19: (-1, 0, 0),
                  21: (-1, 0, 0), 15: (0, 1, 0)},
    "kit": {6: (1, 0, 0), 7: (1, 0, 0), 9: (-1, 0, 0), 10: (-1, 0, 0)},
}

# file joint names of the CMU conversion for each of our HumanML3D BVH names
_CMU = {
    "Hips": "Hips", "LeftUpLeg": "LeftUpLeg", "RightUpLeg": "RightUpLeg", "Spine": "LowerBack",
    "LeftLeg": "LeftLeg", "RightLeg": "RightLeg", "Spine1": "Spine", "LeftFoot": "LeftFoot",
    "RightFoot": "RightFoot", "Spine2": "Spine1", "LeftToeBase": "LeftToeBase",
    "RightToeBase": "RightToeBase", "Neck": "Neck", "LeftShoulder": "LeftShoulder",
    "RightShoulder": "RightShoulder", "Head": "Head", "LeftArm": "LeftArm", "RightArm": "RightArm",
    "LeftForeArm": "LeftForeArm", "RightForeArm": "RightForeArm", "LeftHand": "LeftHand",
    "RightHand": "RightHand",
}
NAME_MAPS: dict[str, dict[str, str]] = {
    "stablemo": {n: n for n in BVH_NAMES["humanml3d"]},
    "cmu": _CMU,
}


def bvh_names(skeleton: Skeleton | str) -> tuple[str, ...]:
    return BVH_NAMES[get_skeleton(skeleton).name]


def rest_directions(skeleton: Skeleton | str) -> np.ndarray:
    """(J, 3) unit rest direction of each bone parent -> joint (root: zero)."""
    skel = get_skeleton(skeleton)
    out = np.array(skel.raw_offsets, dtype=np.float64)
    for joint, direction in _REST_OVERRIDES[skel.name].items():
        out[joint] = direction
    return out


def rest_joints(skeleton: Skeleton | str, bone_lengths: np.ndarray | None = None) -> np.ndarray:
    """(J, 3) joint positions of the rest pose (the BVH rig's: `rest_directions` times the bone
    lengths, default the skeleton's), standing on the floor (its lowest joint at height 0) with the
    pelvis above the origin, in the skeleton's unit."""
    skel = get_skeleton(skeleton)
    lengths = np.asarray(skel.bone_lengths if bone_lengths is None else bone_lengths, np.float64)
    directions = rest_directions(skel)
    out = np.zeros((skel.num_joints, 3))
    for j in range(1, skel.num_joints):  # parents come before their children
        out[j] = out[skel.parents[j]] + lengths[j] * directions[j]
    out[:, 1] -= out[:, 1].min()
    return out


def strip_namespace(name: str) -> str:
    """'mixamorig:LeftArm' -> 'LeftArm' (Mixamo and other tools prefix a namespace)."""
    return name.rsplit(":", 1)[-1]


def load_name_map(path: str | Path) -> dict[str, str]:
    """A YAML mapping {our BVH joint name: the file's joint name}, checked against our 22 names."""
    import yaml

    path = Path(path)
    if not path.is_file():
        raise StableMoError(f"--map: {path}: file not found")
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as err:
        raise StableMoError(f"--map: {path}: not readable YAML ({str(err).splitlines()[0]})") from None
    if not isinstance(data, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in data.items()):
        raise StableMoError(f"{path}: expected a mapping of joint names to joint names (Hips: pelvis, ...)")
    ours = set(BVH_NAMES["humanml3d"])
    unknown = sorted(set(data) - ours)
    if unknown:
        raise StableMoError(f"{path}: unknown joint name(s) {unknown}; keys are our BVH names ({', '.join(BVH_NAMES['humanml3d'])})")
    missing = [n for n in BVH_NAMES["humanml3d"] if n not in data]
    if missing:
        raise StableMoError(f"{path}: no entry for {missing}")
    return dict(data)


def resolve_name_map(file_names: list[str], where: str, name_map: dict[str, str] | None = None) -> list[int]:
    """Indices into `file_names` of our 22 HumanML3D joints, in skeleton order.

    Without a map, the built-in maps are tried in order (`stablemo`/Mixamo, then `cmu`) on the
    names with namespaces dropped; the first that finds every joint wins."""
    plain = [strip_namespace(n) for n in file_names]
    candidates = [("--map", name_map)] if name_map is not None else list(NAME_MAPS.items())
    best: tuple[str, list[str]] | None = None
    for label, mapping in candidates:
        index = {}
        for i, name in enumerate(plain):
            index.setdefault(name, i)
        missing = [ours for ours in BVH_NAMES["humanml3d"] if strip_namespace(mapping[ours]) not in index]
        if not missing:
            return [index[strip_namespace(mapping[ours])] for ours in BVH_NAMES["humanml3d"]]
        if best is None or len(missing) < len(best[1]):
            best = (label, missing)
    label, missing = best
    raise StableMoError(
        f"{where}: joint names do not match the {label} name map (missing {', '.join(missing)}); "
        "pass --map NAME_MAP.yaml mapping our names (Hips, LeftUpLeg, ...) to this file's"
    )
