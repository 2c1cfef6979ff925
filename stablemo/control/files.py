"""Control files: `.npz` with `positions` (T, J, 3) float and `mask` (T, J) bool.

Positions are global joint positions in the dataset's units (HumanML3D metres) in the
generator's frame: y up, the motion starts at the origin (pelvis x = z = 0 at frame 0) facing +z,
as HumanML3D's recovered joints and `stablemo generate`'s `.joints.npy` are. Keyframes and
in-betweening use the same file (all joints at a few frames).

`control_from_joints` writes one from any joints array (a real clip, a generated motion): pick
joints by name and frames by list, range or density (the OmniControl protocol's 100% / 25% / 5 /
2 / 1 frames).
"""

from __future__ import annotations

import re
import zipfile
from pathlib import Path

import numpy as np

from stablemo.control.spec import JointControl
from stablemo.errors import StableMoError
from stablemo.motion.skeleton import get_skeleton

# the controllable joints of the protocol, by the names users write (HumanML3D / KIT indices)
JOINT_ALIASES = {
    "humanml3d": {"pelvis": 0, "root": 0, "left_foot": 10, "right_foot": 11, "head": 15,
                  "left_wrist": 20, "right_wrist": 21},
    "kit": {"pelvis": 0, "root": 0, "left_foot": 20, "right_foot": 15, "head": 4,
            "left_wrist": 10, "right_wrist": 7},
}


def joint_index(name: str, skeleton) -> int:
    """A joint by protocol name (pelvis, left_wrist, …), skeleton name (L_wrist) or index."""
    skel = get_skeleton(skeleton)
    key = name.strip()
    aliases = JOINT_ALIASES[skel.name]
    if key.lower() in aliases:
        return aliases[key.lower()]
    if key in skel.joint_names:
        return skel.joint_names.index(key)
    if key.isdigit() and int(key) < skel.num_joints:
        return int(key)
    raise StableMoError(f"joint {name!r}: unknown for the {skel.name} skeleton (use {', '.join(aliases)}, "
                        f"a joint name such as {skel.joint_names[1]}, or an index 0-{skel.num_joints - 1})")


def parse_frames(spec: str, length: int, what: str = "--frames") -> np.ndarray:
    """Frames by ranges and indices, e.g. '0:40,160:196' or '0,50,100' (ranges end-exclusive, an
    open end runs to the motion's end), as a (length,) bool mask; out-of-range frames are an error.
    Shares and counts of evenly spaced frames are `density_frames`."""
    keep = np.zeros(length, bool)
    for part in spec.split(","):
        part = part.strip()
        m = re.fullmatch(r"(\d*):(\d*)", part)
        if m:
            a = int(m.group(1) or 0)
            b = int(m.group(2)) if m.group(2) else length
            if not 0 <= a < b <= length:
                raise StableMoError(f"{what}: range {part!r} is outside the motion's frames 0:{length}")
            keep[a:b] = True
        elif part.isdigit():
            if int(part) >= length:
                raise StableMoError(f"{what}: frame {part} is outside the motion's frames 0-{length - 1}")
            keep[int(part)] = True
        else:
            raise StableMoError(f"{what}: cannot read {part!r} (use ranges 0:40, frames 0,50,100)")
    return keep


def density_frames(density: str, length: int) -> np.ndarray:
    """The protocol's densities: 'P%' of the frames evenly spaced, or N frames evenly spaced. (length,) bool."""
    text = density.strip()
    keep = np.zeros(length, bool)
    try:
        if text.endswith("%"):
            share = float(text[:-1]) / 100.0
            if not 0 < share <= 1:
                raise ValueError
            count = max(1, int(round(share * length)))
        else:
            count = int(text)
            if count < 1:
                raise ValueError
    except ValueError:
        raise StableMoError(f"--density: expected a share such as 100% or 25%, or a frame count such as 5, "
                            f"got {density!r}") from None
    count = min(count, length)
    keep[np.unique(np.round(np.linspace(0, length - 1, count)).astype(int))] = True
    return keep


def control_from_joints(joints: np.ndarray, joints_sel: list[int], frames: np.ndarray) -> JointControl:
    """A JointControl holding `joints` (T, J, 3) at the chosen joints and frames ((T,) bool)."""
    mask = np.zeros(joints.shape[:2], bool)
    mask[np.ix_(np.flatnonzero(frames), np.asarray(joints_sel, int))] = True
    return JointControl(np.asarray(joints, np.float32), mask)


def save_control(path, control: JointControl) -> Path:
    from stablemo.io import atomic_open

    path = Path(path)
    with atomic_open(path) as f:
        np.savez(f, positions=np.asarray(control.positions, np.float32), mask=np.asarray(control.mask, bool))
    return path


def load_control(path, skeleton) -> JointControl:
    """A control file, checked for its keys, shapes and dtypes (values are checked per request)."""
    file = Path(path)
    skel = get_skeleton(skeleton)
    if not file.is_file():
        raise StableMoError(f"{file}: control file not found")
    if not zipfile.is_zipfile(file):
        # np.load would return a plain array for a .npy (and try pickle for anything else)
        raise StableMoError(f"{file}: not an .npz control file (write one with `stablemo control-file`; "
                            "a joints .npy is its input, not a control file)")
    try:
        with np.load(file, allow_pickle=False) as data:
            keys = set(data.files)
            missing = {"positions", "mask"} - keys
            if missing:
                raise StableMoError(f"{file}: missing {' and '.join(sorted(missing))!s} (a control file holds "
                                    f"'positions' (T, {skel.num_joints}, 3) and 'mask' (T, {skel.num_joints}))")
            positions, mask = data["positions"], data["mask"]
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as err:
        raise StableMoError(f"{file}: not a readable .npz control file ({err})") from None
    if positions.ndim != 3 or positions.shape[1:] != (skel.num_joints, 3):
        raise StableMoError(f"{file}: positions have shape {positions.shape}; the {skel.name} skeleton needs "
                            f"(T, {skel.num_joints}, 3)")
    if mask.shape != positions.shape[:2]:
        raise StableMoError(f"{file}: mask has shape {mask.shape}, expected {positions.shape[:2]}")
    try:
        return JointControl(positions, mask)
    except StableMoError as err:
        raise StableMoError(f"{file}: {err}") from None
