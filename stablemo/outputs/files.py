"""What a generated motion becomes on disk: file names from prompt text, and the files themselves.

`slugify`/`unique_slugs` turn prompts into distinct file stems that can never leave the output
folder; `write_motion` writes a motion's features, joints and chosen formats (GIF/MP4, BVH, GLB,
FBX), each atomically. `stablemo generate`, `edit`, the timeline path and the server's downloads share them.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from stablemo.errors import StableMoError


def slugify(text: str, max_len: int = 60) -> str:
    """A file name stem from user text: only [a-z0-9-], never empty, never '.', '..' or a path."""
    slug = re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")[:max_len].rstrip("-")
    return slug or "motion"


def unique_slugs(texts: list[str]) -> list[str]:
    """One distinct file stem per text, in order. The first text of each slug keeps it; a repeat
    gets the first `<slug>-N` (N = 2, 3, ...) that no text's own slug and no earlier pick took, so
    "x", "x", "x 2" -> x, x-3, x-2 (never two prompts writing the same files)."""
    slugs = [slugify(text) for text in texts]
    taken = set(slugs)
    seen: set[str] = set()
    out = []
    for slug in slugs:
        if slug in seen:
            n = 2
            while f"{slug}-{n}" in taken:
                n += 1
            taken.add(f"{slug}-{n}")
            out.append(f"{slug}-{n}")
        else:
            seen.add(slug)
            out.append(slug)
    return out


NAME_MAX = 200  # bytes; the longest suffix (".features.npy") and the temp name's must still fit 255


def check_output_name(name: str, flag: str = "--name") -> str:
    """A user-given file name stem: one plain name inside --out, so the outputs never land elsewhere.
    Refused: empty, a path (any separator, '..', absolute), a hidden name, control characters."""
    if not name or not name.strip():
        raise StableMoError(f"{flag}: empty name")
    seps = {"/", "\\", os.sep, os.altsep or "/"}
    if any(sep in name for sep in seps) or os.path.isabs(name) or name in (".", ".."):
        raise StableMoError(f"{flag}: {name!r} is a path; give a plain file name (the files go into --out)")
    if name.startswith("."):
        raise StableMoError(f"{flag}: {name!r} starts with '.'; give a plain, visible file name")
    if any(ord(c) < 32 or ord(c) == 127 for c in name):
        raise StableMoError(f"{flag}: {name!r} holds control characters; give a plain file name")
    if len(os.fsencode(name)) > NAME_MAX:
        raise StableMoError(f"{flag}: name is {len(os.fsencode(name))} bytes long; at most {NAME_MAX}")
    return name


def write_motion(out: Path, slug: str, feats, joints, pipe, formats: list[str], title: str,
                 targets=None, warn=None) -> list[str]:
    """Features, joints and each of `formats` (gif, mp4: an animation; bvh; glb, fbx: the skinned
    mannequin) of one motion; the names written.
    targets: joint-control targets (positions, mask) drawn in the animation. warn: called with one
    line for a written file that is more than 3 cm from the motion (stablemo.bvh.fit); the library
    prints nothing itself."""
    from stablemo.io import save_npy

    save_npy(out / f"{slug}.features.npy", feats)
    save_npy(out / f"{slug}.joints.npy", joints)
    written = [f"{slug}.features.npy", f"{slug}.joints.npy"]
    for fmt in formats:
        if fmt in ("glb", "fbx"):
            _write_body(out / f"{slug}.{fmt}", joints, pipe, warn)
        elif fmt == "bvh":
            from stablemo.bvh import write_bvh

            # the bundle's body: the joints were built on it, so the file's bones are exactly theirs
            fit = write_bvh(out / f"{slug}.bvh", joints, skeleton=pipe.skeleton, source_fps=pipe.fps,
                            bone_lengths=pipe.finish.bone_lengths)
            warning = fit.warning(str(out / f"{slug}.bvh"), "`stablemo bvh --stretch` follows them exactly")
            if warning and warn is not None:
                warn(warning)
        else:
            from stablemo.outputs.render import render_animation

            render_animation(joints, out / f"{slug}.{fmt}", pipe.skeleton, fps=pipe.fps, title=title,
                             targets=targets)
        written.append(f"{slug}.{fmt}")
    return written


def _write_body(path: Path, joints, pipe, warn=None) -> None:
    """The motion on our skinned mannequin as GLB, or as FBX through Blender (stablemo.gltf.fbx),
    in the stick figures' colours; the same fit warning as the BVH (they share the rig)."""
    from stablemo.gltf import motion_glb
    from stablemo.outputs.render import COLOURS

    data, fit = motion_glb(joints, skeleton=pipe.skeleton, source_fps=pipe.fps, bone_lengths=pipe.finish.bone_lengths,
                           colours=COLOURS)
    if path.suffix == ".fbx":
        from stablemo.gltf.fbx import glb_to_fbx

        glb_to_fbx(data, path, pipe.fps)
    else:
        from stablemo.io import write_bytes

        write_bytes(path, data)
    warning = fit.warning(str(path), "the joints .npy is exact")
    if warning and warn is not None:
        warn(warning)
