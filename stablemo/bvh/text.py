"""BVH text: write an Animation, parse a file back into one. Errors name the file and line.

Conventions written (rigid bones; with stretch, every joint also gets position channels): y up, units of the motion (metres for HumanML3D unless scaled), the root's
OFFSET is zero and its position channels hold its world position (so readers that add the OFFSET
and readers that do not agree), rotation channels `Zrotation Xrotation Yrotation` on every joint
(M = Rz Rx Ry, the Mixamo order; a heading is then the last, innermost angle and an upright body
never meets gimbal lock), angles unwrapped over time so that players interpolating between frames
never spin through 360°. Joint data follow the hierarchy's depth-first order, as BVH requires.

Read: any channel order, position channels on any joint (their values replace the OFFSET, the
usual reading), `End Site`s, "{" on its own line or not. bvhio (PyPI) was tried for both: its reader
waits forever on a file with fewer frame lines than `Frames:` says, accepts NaN, and a short frame
line is an IndexError naming no line; its writer builds a Python object per joint per frame and drops
channels that barely move. The grammar is small; scipy does the Euler algebra.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from stablemo.bvh.rig import Animation, Rig
from stablemo.errors import StableMoError
from stablemo.motion.plausible import MAX_BVH_JOINTS, check_fps

ROOT_CHANNELS = ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
JOINT_CHANNELS = ("Zrotation", "Xrotation", "Yrotation")
STRETCH_CHANNELS = ROOT_CHANNELS  # joints of an animation with per-joint translations
_EULER = "ZXY"  # scipy intrinsic order matching JOINT_CHANNELS
_POS = {"Xposition": 0, "Yposition": 1, "Zposition": 2}
_ROT = {"Xrotation": "X", "Yrotation": "Y", "Zrotation": "Z"}


def depth_first(rig: Rig) -> list[int]:
    order, stack = [], [0]
    while stack:
        j = stack.pop()
        order.append(j)
        stack.extend(reversed(rig.children(j)))
    return order


def quat_to_euler(q: np.ndarray, order: str = _EULER) -> np.ndarray:
    """(T, J, 4) (w, x, y, z) -> (T, J, 3) degrees in `order` (intrinsic), unwrapped over T."""
    t, j = q.shape[:2]
    with warnings.catch_warnings():  # gimbal lock: scipy still returns an exact decomposition
        warnings.simplefilter("ignore", UserWarning)
        e = Rotation.from_quat(q.reshape(-1, 4)[:, [1, 2, 3, 0]]).as_euler(order, degrees=True)
    return np.unwrap(e.reshape(t, j, 3), period=360.0, axis=0)


def format_bvh(anim: Animation, precision: int = 6) -> str:
    """The BVH text of an animation (root position + ZXY rotations on every joint)."""
    rig = anim.rig
    order = depth_first(rig)
    lines = ["HIERARCHY"]

    def emit(j: int, depth: int) -> None:
        pad = "  " * depth
        kind = "ROOT" if rig.parents[j] < 0 else "JOINT"
        moves = rig.parents[j] < 0 or anim.positions is not None
        channels = ROOT_CHANNELS if rig.parents[j] < 0 else STRETCH_CHANNELS if moves else JOINT_CHANNELS
        off = rig.offsets[j] if rig.parents[j] >= 0 else np.zeros(3)
        lines.extend([f"{pad}{kind} {rig.names[j]}", f"{pad}{{", f"{pad}  OFFSET {_vec(off, precision)}",
                      f"{pad}  CHANNELS {len(channels)} {' '.join(channels)}"])
        kids = rig.children(j)
        for c in kids:
            emit(c, depth + 1)
        if not kids:
            end = rig.end_sites.get(j, np.zeros(3))
            lines.extend([f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET {_vec(end, precision)}", f"{pad}  }}"])
        lines.append(f"{pad}}}")

    emit(0, 0)
    euler = quat_to_euler(anim.rotations[:, order])  # (T, J, 3) in Z, X, Y order
    if anim.positions is None:
        data = np.concatenate([anim.root, euler.reshape(len(euler), -1)], axis=1)  # (T, 3 + 3J)
    else:  # every joint: its translation, then its rotation
        moves = anim.positions[:, order].copy()
        moves[:, 0] = anim.root
        data = np.concatenate([moves, euler], axis=2).reshape(len(euler), -1)  # (T, 6J)
    lines += ["MOTION", f"Frames: {len(data)}", f"Frame Time: {1.0 / anim.fps:.8f}"]
    row = " ".join([f"%.{precision}f"] * data.shape[1])
    frames = "\n".join(row % tuple(values) for values in data.tolist())
    return "\n".join(lines) + "\n" + frames + "\n"


def _vec(v: np.ndarray, precision: int) -> str:
    return " ".join(f"{float(x):.{precision}f}" for x in v)


# --------------------------------------------------------------------------- reading


class _Tokens:
    """Tokens of the HIERARCHY part with their line numbers, for messages naming the line."""

    def __init__(self, lines: list[str], path: Path):
        self.path = path
        self.items = [(tok, n + 1) for n, line in enumerate(lines) for tok in line.split()]
        self.pos = 0

    def fail(self, message: str, line: int | None = None) -> StableMoError:
        if line is None:
            line = self.items[min(self.pos, len(self.items) - 1)][1] if self.items else 1
        return StableMoError(f"{self.path}:{line}: {message}")

    def next(self, what: str) -> tuple[str, int]:
        if self.pos >= len(self.items):
            raise self.fail(f"file ends where {what} was expected")
        item = self.items[self.pos]
        self.pos += 1
        return item

    def expect(self, word: str) -> int:
        tok, line = self.next(repr(word))
        if tok != word:
            raise self.fail(f"expected {word!r}, found {tok!r}", line)
        return line

    def number(self, what: str) -> float:
        tok, line = self.next(what)
        try:
            value = float(tok)
        except ValueError:
            raise self.fail(f"{what}: {tok!r} is not a number", line) from None
        if not math.isfinite(value):
            raise self.fail(f"{what}: {tok} is not finite", line)
        return value


def read_bvh(path: str | Path) -> Animation:
    """Parse a BVH file into an Animation (file units, file frame rate)."""
    path = Path(path)
    if not path.is_file():
        raise StableMoError(f"{path}: file not found")
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except UnicodeDecodeError as err:
        raise StableMoError(f"{path}: not a text file (byte {err.start} is not UTF-8)") from None
    except OSError as err:
        raise StableMoError(f"{path}: cannot read ({err.strerror})") from None
    lines = text.splitlines()
    motion_at = next((i for i, line in enumerate(lines) if line.strip() == "MOTION"), None)
    if motion_at is None:
        raise StableMoError(f"{path}: no MOTION section; not a BVH file?")
    # bound the hierarchy before tokenising it: a file of a million joints is refused in a second,
    # not parsed for minutes (and a deep chain would exhaust the parser's recursion)
    declared = sum(1 for line in lines[:motion_at] if line.lstrip().startswith(("JOINT", "ROOT")))
    if declared > MAX_BVH_JOINTS:
        raise StableMoError(f"{path}: the hierarchy declares {declared} joints; at most {MAX_BVH_JOINTS} are read "
                            "(a full-body rig with fingers and face has a few hundred)")
    tokens = _Tokens(lines[:motion_at], path)
    tokens.expect("HIERARCHY")
    names: list[str] = []
    seen: set[str] = set()
    parents: list[int] = []
    offsets: list[np.ndarray] = []
    channels: list[list[str]] = []
    end_sites: dict[int, np.ndarray] = {}

    def joint(parent: int) -> None:
        name, line = tokens.next("a joint name")
        if name in seen:
            raise tokens.fail(f"joint name {name!r} appears twice", line)
        index = len(names)
        names.append(name)
        seen.add(name)
        parents.append(parent)
        tokens.expect("{")
        tokens.expect("OFFSET")
        offsets.append(np.array([tokens.number("OFFSET") for _ in range(3)]))
        tok, line = tokens.next("CHANNELS")
        if tok != "CHANNELS":
            raise tokens.fail(f"joint {name}: expected CHANNELS, found {tok!r}", line)
        count = tokens.number("CHANNELS count")
        if count != int(count) or not 0 <= count <= 6:
            raise tokens.fail(f"joint {name}: channel count {count:g} (expected 0-6)", line)
        chans = [tokens.next("a channel name")[0] for _ in range(int(count))]
        bad = [c for c in chans if c not in _POS and c not in _ROT]
        if bad or len(set(chans)) != len(chans):
            raise tokens.fail(f"joint {name}: channels {chans} (each of X/Y/Z position/rotation at most once)", line)
        channels.append(chans)
        while True:
            tok, line = tokens.next(f"the end of joint {name}")
            if tok == "JOINT":
                joint(index)
            elif tok == "End":
                tokens.expect("Site")
                tokens.expect("{")
                tokens.expect("OFFSET")
                end_sites[index] = np.array([tokens.number("End Site OFFSET") for _ in range(3)])
                tokens.expect("}")
            elif tok == "}":
                return
            else:
                raise tokens.fail(f"joint {name}: expected JOINT, End Site or '}}', found {tok!r}", line)

    tokens.expect("ROOT")
    joint(-1)
    if tokens.pos != len(tokens.items):
        raise tokens.fail(f"unexpected {tokens.items[tokens.pos][0]!r} after the root joint's closing brace")
    rig = Rig(tuple(names), tuple(parents), np.array(offsets), end_sites)
    data, fps = _motion(lines, motion_at, sum(len(c) for c in channels), path)
    return _animation(rig, channels, data, fps)


def _header(lines: list[str], n: int, key: str, path: Path) -> str:
    if n >= len(lines) or not lines[n].strip().startswith(key):
        raise StableMoError(f"{path}:{n + 1}: expected '{key}' after MOTION")
    return lines[n].strip()[len(key):].strip()


def _motion(lines: list[str], at: int, width: int, path: Path) -> tuple[np.ndarray, float]:
    count_text = _header(lines, at + 1, "Frames:", path)
    try:
        frames = int(count_text)
    except ValueError:
        raise StableMoError(f"{path}:{at + 2}: Frames: {count_text!r} is not a whole number") from None
    if frames < 1:
        raise StableMoError(f"{path}:{at + 2}: Frames: {frames} (need at least 1)")
    time_text = _header(lines, at + 2, "Frame Time:", path)
    try:
        dt = float(time_text)
    except ValueError:
        dt = float("nan")
    if not math.isfinite(dt) or dt <= 0:
        raise StableMoError(f"{path}:{at + 3}: Frame Time: {time_text!r} is not a positive number of seconds")
    check_fps(1.0 / dt, f"{path}:{at + 3}: Frame Time {time_text} s")
    body = lines[at + 3:]
    while body and not body[-1].strip():
        body.pop()
    if len(body) != frames:
        raise StableMoError(f"{path}:{at + 2}: Frames: {frames} but the file has {len(body)} frame lines")
    data = np.empty((frames, width))
    for i, line in enumerate(body):
        values = line.split()
        where = f"{path}:{at + 4 + i}"
        if len(values) != width:
            raise StableMoError(f"{where}: {len(values)} values, the hierarchy declares {width} channels")
        try:
            data[i] = [float(v) for v in values]
        except ValueError:
            raise StableMoError(f"{where}: a value is not a number") from None
        if not np.all(np.isfinite(data[i])):
            raise StableMoError(f"{where}: NaN or Inf in the frame")
    return data, 1.0 / dt


def _animation(rig: Rig, channels: list[list[str]], data: np.ndarray, fps: float) -> Animation:
    t, num = len(data), rig.num_joints
    rotations = np.zeros((t, num, 4))
    rotations[..., 0] = 1.0
    positions = np.broadcast_to(rig.offsets, (t, num, 3)).copy()
    has_positions = False
    col = 0
    for j, chans in enumerate(channels):
        cols = {c: col + k for k, c in enumerate(chans)}
        col += len(chans)
        for c, axis in _POS.items():
            if c in cols:
                positions[:, j, axis] = data[:, cols[c]]
                has_positions |= j > 0
        rot = [c for c in chans if c in _ROT]
        if rot:
            order = "".join(_ROT[c] for c in rot)  # uppercase: intrinsic, in channel order
            angles = data[:, [cols[c] for c in rot]]
            xyzw = Rotation.from_euler(order, angles, degrees=True).as_quat()
            rotations[:, j] = xyzw[:, [3, 0, 1, 2]]
    return Animation(rig, positions[:, 0].copy(), rotations, fps, positions if has_positions else None)
