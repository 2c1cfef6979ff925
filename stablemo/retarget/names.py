"""Which joint of a rig plays which humanoid role, from its names (and its rest pose for sides).

Roles are Unity Humanoid's (Hips, Spine..., Neck..., Head, LeftUpperLeg, ..., RightHand); the word
tables live in stablemo/assets/retarget/humanoid.yaml. Conventions read: Mixamo (`mixamorig:
LeftUpLeg`), Unreal mannequin (`thigh_l`, `spine_01`), Unity Humanoid (`LeftUpperLeg`), VRM
(`J_Bip_L_UpperLeg`), Rigify (`thigh.L`, `DEF-thigh.L`, the metarig's `spine.00N` trunk), CMU/BVH
(`LeftUpLeg`, `LowerBack`), SMPL/SMPL-X (`L_Hip`, `left_hip`), 3ds Max biped (`Bip01 L Thigh`).
A joint with no side word takes its side from where it sits at rest (+x is the body's left, as in
HumanML3D, Blender and glTF). Every joint that plays no role (fingers, twist bones, props, IK
targets) stays at rest. A YAML map `{Role: joint name}` (Spine/Neck: a name or a list) overrides
any role; the rest are still found by name.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stablemo.errors import StableMoError

CONVENTIONS_YAML = Path(__file__).resolve().parents[1] / "assets" / "retarget" / "humanoid.yaml"
SIDES = ("Left", "Right")
LIMBS = {"leg": ("UpperLeg", "LowerLeg", "Foot"), "arm": ("UpperArm", "LowerArm", "Hand")}
_WORDS = re.compile(r"[A-Z]+(?=[A-Z][a-z])|[A-Z]?[a-z]+|[A-Z]+|\d+")
_SIDE_WORDS = {"left": "Left", "l": "Left", "right": "Right", "r": "Right"}


@functools.lru_cache(maxsize=1)
def conventions() -> dict:
    import yaml

    return yaml.safe_load(CONVENTIONS_YAML.read_text(encoding="utf-8"))


@dataclass(frozen=True)
class Roles:
    """Joint indices of a humanoid rig: hips, the spine chain (hips excluded, upwards; its last is
    the chest the arms hang from), the neck chain (may be empty), head, and per side
    {"Left"/"Right": {UpperLeg, LowerLeg, Foot, Toes?, Shoulder?, UpperArm, LowerArm, Hand}}."""

    hips: int
    spine: tuple[int, ...]
    neck: tuple[int, ...]
    head: int
    sides: dict[str, dict[str, int]]

    def joint(self, side: str, role: str) -> int | None:
        return self.sides[side].get(role)

    def mapped(self) -> dict[int, str]:
        """joint index -> role name, for messages and docs."""
        out = {self.hips: "Hips", self.head: "Head"}
        out.update({j: f"Spine[{i}]" for i, j in enumerate(self.spine)})
        out.update({j: f"Neck[{i}]" for i, j in enumerate(self.neck)})
        for side, roles in self.sides.items():
            out.update({j: side + role for role, j in roles.items()})
        return out


def words(name: str) -> list[str]:
    """'mixamorig:LeftUpLeg' -> ['left', 'up', 'leg']: namespace dropped, camelCase and separators cut."""
    return [w.lower() for w in _WORDS.findall(name.rsplit(":", 1)[-1])]


def read_name(name: str) -> tuple[str | None, str, str]:
    """(side or None, the body-part key with trailing numbers, the key without them)."""
    prefixes = set(conventions()["prefixes"])
    ws = [w for w in words(name) if w not in prefixes]
    while ws and ws[0].isdigit():  # what a prefix numbered (Bip01_)
        ws.pop(0)
    side = None
    for i in (0, len(ws) - 1):
        if 0 <= i < len(ws) and ws[i] in _SIDE_WORDS and len(ws) > 1:
            side = _SIDE_WORDS[ws.pop(i)]
            break
    ws = [w for w in ws if w != "c"]  # VRM's centre marker (J_Bip_C_Hips)
    key = "".join(ws)
    while ws and ws[-1].isdigit():
        ws.pop()
    return side, key, "".join(ws)


def _depths(parents) -> list[int]:
    depth = []
    for p in parents:
        depth.append(0 if p < 0 else depth[p] + 1)
    return depth


def is_ancestor(parents, a: int, b: int) -> bool:
    """a is b or above b."""
    while b >= 0:
        if b == a:
            return True
        b = parents[b]
    return False


def find_roles(names, parents, rest: np.ndarray, where: str, override: dict | None = None,
               flag: str = "--map") -> Roles:
    """Roles of a rig: names (J,), parents (J,) (-1 root, parents first), rest (J, 3) world rest
    positions (for sides of unsided names). override: {Role: name or [names]} from a YAML map.
    A rig lacking a required role, or whose roles do not form a body, is one line naming what and
    the option (`flag`) that names the joints."""
    names = list(names)
    conv = conventions()
    by_name = {n: i for i, n in enumerate(names)}
    depth = _depths(parents)
    # a generated Rigify rig holds control and mechanism copies of every bone: read its deform bones
    deform = [i for i, n in enumerate(names) if n.rsplit(":", 1)[-1].startswith("DEF-")]
    candidates = deform or list(range(len(names)))
    plain = {i: names[i].rsplit(":", 1)[-1].removeprefix("DEF-") for i in candidates}
    found: dict[str, list[int]] = {}
    taken: set[int] = set()
    for fixed in conv["exact"].values():  # conventions named joint by joint
        table = {role: [v] if isinstance(v, str) else list(v) for role, v in fixed.items()}
        index = {n: i for i, n in plain.items()}
        if all(n in index for vs in table.values() for n in vs):
            for role, vs in table.items():
                found[role] = [index[n] for n in vs]
            taken.update(j for js in found.values() for j in js)
            break
    read = {i: read_name(plain[i]) for i in candidates}
    hips_x, hips_hits = None, []
    for role, keys in conv["center"].items():
        if role in found:
            continue
        chain = role in ("Spine", "Neck")
        hits = [i for key in keys for i in sorted(candidates, key=lambda i: (depth[i], i))
                if i not in taken and read[i][0] is None and (read[i][2] if chain else read[i][1]) == key]
        if hits:
            found[role] = sorted(set(hits), key=lambda i: depth[i]) if chain else hits[:1]
            taken.update(found[role])
            if role == "Hips":
                hips_hits = hits
    # the hips carry the spine: where several joints read as hips (Daz and Character Creator have a
    # `hip` above a `pelvis` that holds only the thighs) the first one above the head wins
    if "Hips" in found and "Head" in found:
        above = [i for i in hips_hits if is_ancestor(parents, i, found["Head"][0])]
        if above and above[0] != found["Hips"][0]:
            taken.discard(found["Hips"][0])
            found["Hips"] = above[:1]
            taken.add(above[0])
    if "Hips" in found:
        hips_x = rest[found["Hips"][0], 0]
    sides: dict[str, dict[str, int]] = {"Left": {}, "Right": {}}
    for role, keys in conv["sided"].items():
        for side in SIDES:
            for key in keys:
                hits = [i for i in sorted(candidates, key=lambda i: (depth[i], i))
                        if i not in taken and (read[i][1] == key or read[i][0] is None and read[i][2] == key)
                        and _side_of(read[i][0], rest[i, 0], hips_x) == side]
                if hits:
                    sides[side][role] = hits[0]
                    taken.add(hits[0])
                    break
    if override:
        _apply_override(override, by_name, found, sides, where, flag)
    return _check(names, parents, found, sides, where, flag)


def _side_of(named: str | None, x: float, hips_x: float | None) -> str | None:
    if named is not None:
        return named
    if hips_x is None or abs(x - hips_x) < 1e-9:
        return None
    return "Left" if x > hips_x else "Right"


ROLE_KEYS = ("Hips", "Spine", "Chest", "UpperChest", "Neck", "Head") + tuple(
    side + role for side in SIDES for role in ("UpperLeg", "LowerLeg", "Foot", "Toes", "Shoulder", "UpperArm",
                                               "LowerArm", "Hand"))


def _apply_override(override: dict, by_name: dict, found: dict, sides: dict, where: str, flag: str) -> None:
    for key, value in override.items():
        values = [value] if isinstance(value, str) else list(value)
        missing = [v for v in values if v not in by_name]
        if missing:
            raise StableMoError(f"{flag}: {key}: no joint named {missing[0]!r} in {where}")
        joints = [by_name[v] for v in values]
        if key in ("Chest", "UpperChest"):
            found.setdefault("Spine", [])
            found["Spine"] = [j for j in found["Spine"] if j not in joints] + joints
        elif key in ("Hips", "Spine", "Neck", "Head"):
            found[key] = joints
        else:
            side = "Left" if key.startswith("Left") else "Right"
            sides[side][key[len(side):]] = joints[0]


def load_role_map(path: str | Path, flag: str = "--map") -> dict:
    """A YAML map {Role: joint name (or a list for Spine/Neck)}; roles as in ROLE_KEYS; errors name `flag`."""
    import yaml

    from stablemo.errors import yaml_error_line

    path = Path(path)
    if not path.is_file():
        raise StableMoError(f"{flag}: {path}: file not found")
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as err:
        raise StableMoError(f"{flag}: {yaml_error_line(path, err)}") from None
    except UnicodeDecodeError:
        raise StableMoError(f"{flag}: {path}: not UTF-8 text") from None
    if not isinstance(data, dict) or not all(
            isinstance(v, str) or (isinstance(v, list) and v and all(isinstance(x, str) for x in v))
            for v in data.values()):
        raise StableMoError(f"{flag}: {path}: expected a mapping of roles to joint names (LeftUpperLeg: thigh_l, ...)")
    unknown = sorted(str(k) for k in data if k not in ROLE_KEYS)
    if unknown:
        raise StableMoError(f"{flag}: {path}: unknown role(s) {unknown}; roles are {', '.join(ROLE_KEYS)}")
    return data


def _check(names, parents, found: dict, sides: dict, where: str, flag: str) -> Roles:
    required = conventions()["required"]
    missing = [r for r in required if r in conventions()["center"] and not found.get(r)]
    missing += [side + r for side in SIDES for r in required if r in conventions()["sided"] and r not in sides[side]]
    if missing:
        raise StableMoError(f"{where}: not a humanoid rig that can be retargeted: no joint found for "
                            f"{', '.join(missing)}; pass {flag} MAP.yaml naming them (docs/retarget.md)")
    hips, head = found["Hips"][0], found["Head"][0]
    # the trunk: spine joints between the hips and the head, neck joints between the spine and the head
    spine = [j for j in found["Spine"] if is_ancestor(parents, hips, j) and j != hips and is_ancestor(parents, j, head)]
    if not spine:
        raise StableMoError(f"{where}: not a humanoid rig that can be retargeted: no spine joint between "
                            f"{names[hips]} and {names[head]}; pass {flag} MAP.yaml naming them")
    neck = [j for j in found.get("Neck", []) if is_ancestor(parents, spine[-1], j) and j != spine[-1]
            and is_ancestor(parents, j, head) and j != head]
    for side in SIDES:  # optional roles that do not fit the body are left at rest, not refused
        s = sides[side]
        if "Toes" in s and not is_ancestor(parents, s["Foot"], s["Toes"]) or s.get("Toes") == s["Foot"]:
            s.pop("Toes")
        if "Shoulder" in s and not (is_ancestor(parents, spine[-1], s["Shoulder"]) and s["Shoulder"] != spine[-1]
                                    and is_ancestor(parents, s["Shoulder"], s["UpperArm"]) and s["Shoulder"] != s["UpperArm"]):
            s.pop("Shoulder")
    chains = [(hips, spine[0])] + list(zip(spine, spine[1:] + (neck or [head])))
    for side in SIDES:
        s = sides[side]
        chains += [(hips, s["UpperLeg"]), (s["UpperLeg"], s["LowerLeg"]), (s["LowerLeg"], s["Foot"]),
                   (spine[-1], s["UpperArm"]), (s["UpperArm"], s["LowerArm"]), (s["LowerArm"], s["Hand"])]
        chains += [(s["Foot"], s["Toes"])] if "Toes" in s else []
        chains += [(spine[-1], s["Shoulder"]), (s["Shoulder"], s["UpperArm"])] if "Shoulder" in s else []
    for a, b in chains:
        if a == b or not is_ancestor(parents, a, b):
            raise StableMoError(f"{where}: not a humanoid rig that can be retargeted: {names[b]} does not hang "
                                f"below {names[a]}; pass {flag} MAP.yaml to say which joint is which")
    return Roles(hips, tuple(spine), tuple(neck), head, {side: dict(sides[side]) for side in SIDES})
