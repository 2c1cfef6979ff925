"""The entry points behind the command, the Python API and the server: inputs checked, the solve, the file."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from stablemo.errors import StableMoError
from stablemo.retarget.names import ROLE_KEYS, conventions, find_roles, load_role_map
from stablemo.retarget.rest import RestRig
from stablemo.retarget.solve import Solved, solve
from stablemo.retarget.source import Source, motion_source, read_source
from stablemo.retarget.target import read_rig

# rig format -> what OUT may be (an FBX skeleton without a skinned mesh: BVH only, see check_written)
OUTPUTS = {"bvh": (".bvh",), "fbx": (".fbx", ".glb", ".bvh"), "gltf": (".glb", ".bvh")}


@dataclass(frozen=True)
class Report:
    """What was written: the file, its format, frames, fps, the scale applied (target units per
    source unit) and the roles found (joint name -> role)."""

    path: Path
    fmt: str
    frames: int
    fps: float
    scale: float
    roles: dict[str, str]

    def summary(self) -> str:
        return (f"{self.frames} frames at {self.fps:g} fps -> {self.path} ({self.fmt}); scale {self.scale:.4g}; "
                f"{len(self.roles)} joints driven, the others at rest")


def _source(motion, source_map) -> Source:
    if isinstance(motion, Source):
        return motion
    if isinstance(motion, (str, os.PathLike)):
        return read_source(motion, _map(source_map, "--source-map"))
    return motion_source(motion)


def _map(role_map, flag: str = "--map") -> dict | None:
    if role_map is None or isinstance(role_map, dict):
        return role_map
    return load_role_map(role_map, flag)


def retarget(motion, rig, role_map=None, fps: float | None = None, source_map=None) -> Solved:
    """motion: path (.npy/.bvh), array (features or joints) or Source; rig: path or RestRig;
    role_map: {Role: joint name} or a YAML path (the target's roles); fps: resample the result;
    source_map: the same for a BVH motion whose names do not tell its roles."""
    target = rig if isinstance(rig, RestRig) else read_rig(rig)
    roles = find_roles(target.names, target.parents, target.rest, target.path, _map(role_map))
    solved = solve(_source(motion, source_map), target, roles, conventions()["contacts"])
    if fps is not None:
        from dataclasses import replace

        from stablemo.bvh.resample import resample

        solved = replace(solved, anim=resample(solved.anim, float(fps)))
    return solved


def check_out(out: str | os.PathLike, rig: str | os.PathLike) -> Path:
    """The output's suffix must be one the target's format is written as: one line before any work."""
    from stablemo.retarget.target import FORMATS

    out, rig = Path(out), Path(rig)
    fmt = FORMATS.get(rig.suffix.lower())
    if fmt is None:
        raise StableMoError(f"--rig: {rig}: expected a .bvh, .gltf, .glb or .fbx rig")
    allowed = OUTPUTS[fmt]
    if out.suffix.lower() not in allowed:
        raise StableMoError(f"--out: {out}: a {rig.suffix.lower()} rig is written as {' or '.join(allowed)}")
    return out


def check_written(out: Path, target: RestRig) -> None:
    """An FBX rig is written back as FBX or GLB only when it is a skinned character (read through
    its GLB); a bare skeleton only as BVH."""
    if target.fmt == "fbx" and "glb" not in target.extra and out.suffix.lower() in (".fbx", ".glb"):
        raise StableMoError(f"--out: {out}: {target.path} has no skinned mesh to write the motion onto; "
                            "write its skeleton's animation as .bvh")


def retarget_file(motion, rig, out, role_map=None, fps: float | None = None, source_map=None) -> Report:
    """Retarget and write OUT atomically: BVH, or for a glTF or skinned FBX character the character
    itself with the animation added (GLB, or FBX through Blender)."""
    from stablemo.io import check_output_file

    out = check_out(out, rig)
    check_output_file(out, "--out")
    target = rig if isinstance(rig, RestRig) else read_rig(rig)
    check_written(out, target)
    return write_result(out, retarget(motion, target, role_map, fps, source_map))


def write_result(out: str | os.PathLike, solved: Solved) -> Report:
    """Write a solve as OUT (atomically): a GLB onto a glTF (or skinned FBX) character's own file,
    FBX through Blender from that GLB, else BVH."""
    out = Path(out)
    check_written(out, solved.target)
    if out.suffix.lower() in (".glb", ".fbx"):
        from stablemo.retarget.gltf_out import character_glb

        data = character_glb(solved)
        if out.suffix.lower() == ".glb":
            from stablemo.io import write_bytes

            write_bytes(out, data)
        else:
            from stablemo.gltf.fbx import glb_to_fbx

            glb_to_fbx(data, out, solved.anim.fps)
        fmt = out.suffix.lower()[1:]
    else:
        from stablemo.bvh.text import format_bvh
        from stablemo.io import write_text

        write_text(out, format_bvh(solved.anim))
        fmt = "bvh"
    names = solved.target.names
    roles = {names[j]: role for j, role in solved.roles.mapped().items()}
    return Report(out, fmt, solved.anim.num_frames, solved.anim.fps, solved.scale, roles)


def rig_from_text(text, role_map=None, where: str = "rig") -> tuple[RestRig, dict | None]:
    """A BVH rig sent as text (the server's /api/retarget), checked to be a humanoid one, with its
    role map checked too: (the rig, the map). One line naming `where` when it is not."""
    import tempfile

    from stablemo.retarget.rest import bvh_rest

    if not isinstance(text, str) or not text.strip():
        raise StableMoError(f"{where}: expected the text of a BVH file")
    if role_map is not None and not (isinstance(role_map, dict) and all(
            isinstance(v, str) or (isinstance(v, list) and all(isinstance(x, str) for x in v)) for v in role_map.values())):
        raise StableMoError("rig_map: expected an object of roles to joint names ({\"LeftUpperLeg\": \"thigh_l\"})")
    unknown = sorted(k for k in (role_map or {}) if k not in ROLE_KEYS)
    if unknown:
        raise StableMoError(f"rig_map: unknown role(s) {unknown}; roles are {', '.join(ROLE_KEYS)}")
    with tempfile.TemporaryDirectory(prefix="stablemo-rig-") as tmp:
        path = Path(tmp) / "rig.bvh"
        from stablemo.io import write_text

        write_text(path, text)
        try:
            rig = bvh_rest(path)
        except StableMoError as err:
            raise StableMoError(str(err).replace(str(path), where)) from None
    from dataclasses import replace

    rig = replace(rig, path=where)
    find_roles(rig.names, rig.parents, rig.rest, where, role_map)  # refused here, before any motion is made
    return rig, role_map


def retarget_bvh_text(joints, rig: RestRig, role_map=None, fps: float | None = None) -> str:
    """A motion's joints (T, J, 3) on `rig`, as BVH text."""
    from stablemo.bvh.text import format_bvh

    return format_bvh(retarget(motion_source(joints, fps=fps), rig, role_map).anim)
