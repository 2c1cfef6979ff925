"""Named feature groups for editing: which columns of the feature vector belong to a body part.

A joint's columns are its root-relative position (ric), its 6D rotation and its local velocity;
the root owns the first four columns (rotation velocity, planar velocity, height) and its local
velocity; the lower body also owns the foot contacts. `--keep` phrases:

    lower_body | upper_body | root | contacts | joints=L_wrist,R_wrist | frames=0:40,160:196

Column groups are combined by union, frames by union; given both, the kept entries are the
kept columns at the kept frames.
"""

from __future__ import annotations

import numpy as np

from stablemo.control.files import joint_index, parse_frames
from stablemo.errors import StableMoError
from stablemo.motion.features import feature_slices
from stablemo.motion.skeleton import get_skeleton

LOWER_BODY = {
    "humanml3d": (0, 1, 2, 4, 5, 7, 8, 10, 11),  # pelvis, hips, knees, ankles, feet
    "kit": (0, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20),  # root, hips, knees, ankles, metatarsals, toes
}


def joint_columns(joint: int, skeleton) -> np.ndarray:
    """Feature columns of one joint (root: its 4 root channels and its local velocity)."""
    skel = get_skeleton(skeleton)
    sl = feature_slices(skel)
    cols = [np.arange(sl["local_vel"].start + 3 * joint, sl["local_vel"].start + 3 * joint + 3)]
    if joint == 0:
        cols.append(np.arange(0, 4))
    else:
        cols.append(np.arange(sl["ric"].start + 3 * (joint - 1), sl["ric"].start + 3 * joint))
        cols.append(np.arange(sl["rot6d"].start + 6 * (joint - 1), sl["rot6d"].start + 6 * joint))
    return np.concatenate(cols)


def part_joints(part: str, skeleton) -> tuple[int, ...]:
    skel = get_skeleton(skeleton)
    lower = LOWER_BODY[skel.name]
    if part == "lower_body":
        return lower
    if part == "upper_body":
        return tuple(j for j in range(skel.num_joints) if j not in lower)
    raise StableMoError(f"part {part!r}: unknown (lower_body or upper_body)")


def keep_mask(phrases: list[str], length: int, skeleton) -> np.ndarray:
    """The (length, D) bool mask of kept entries for `--keep` phrases (see the module docstring)."""
    skel = get_skeleton(skeleton)
    D = skel.feature_dim
    columns = np.zeros(D, bool)
    frames = np.zeros(length, bool)
    any_columns = any_frames = False
    for phrase in phrases:
        text = phrase.strip()
        if text.startswith("frames="):
            frames |= parse_frames(text[len("frames="):], length, f"--keep {text}")
            any_frames = True
            continue
        any_columns = True
        if text in ("lower_body", "upper_body"):
            joints = part_joints(text, skel)
            for j in joints:
                columns[joint_columns(j, skel)] = True
            if text == "lower_body":
                columns[feature_slices(skel)["contacts"]] = True
        elif text == "root":
            columns[joint_columns(0, skel)] = True
        elif text == "contacts":
            columns[feature_slices(skel)["contacts"]] = True
        elif text.startswith("joints="):
            for name in text[len("joints="):].split(","):
                columns[joint_columns(joint_index(name, skel), skel)] = True
        else:
            raise StableMoError(f"--keep {text!r}: unknown (use lower_body, upper_body, root, contacts, "
                                "joints=NAME,..., frames=A:B,...)")
    if not any_columns:
        columns[:] = True
    if not any_frames:
        frames[:] = True
    mask = frames[:, None] & columns[None, :]
    if not mask.any():
        raise StableMoError("--keep: keeps nothing")
    return mask
