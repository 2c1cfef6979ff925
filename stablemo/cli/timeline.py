"""`stablemo generate --timeline FILE`: one motion of the timeline's whole length.

    stablemo generate --timeline walk_jump.txt --out outputs --format gif --format bvh

Writes <stem>.features.npy, <stem>.joints.npy and each --format (as `stablemo generate`), plus
<stem>.timeline.json (segments with their frames, the windows the motion was made of, and the root
and foot acceleration at each join beside the motion's inside 99th percentile).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from stablemo.errors import StableMoError


def run_timeline(args, bundle: Path, out: Path) -> int:
    """The --timeline path of `stablemo generate` (args: its parsed arguments, numbers already checked)."""
    from stablemo.inference.hooks import make_hooks
    from stablemo.inference.pipeline import Pipeline
    from stablemo.io import check_output_file, write_text
    from stablemo.outputs.files import slugify, write_motion
    from stablemo.timeline import generate_timeline, read_timeline
    from stablemo.timeline.seams import seam_report

    for flag, value in (("prompt", args.prompt), ("--prompts", args.prompts), ("--seconds", args.seconds),
                        ("--frames", args.frames), ("--control", args.control)):
        if value:
            raise StableMoError(f"--timeline: {flag} cannot be combined with a timeline (the file gives the texts "
                                "and the times)")
    segments = read_timeline(args.timeline)
    slug = slugify(Path(args.timeline).stem)
    formats = [] if args.no_render else list(dict.fromkeys(args.format or ["gif"]))
    for suffix in ["features.npy", "joints.npy", "timeline.json"] + formats:
        check_output_file(out / f"{slug}.{suffix}", "--out")
    pipe = Pipeline.from_bundle(bundle, device=args.device, dtype=args.dtype)
    hooks = make_hooks(pipe, footskate=args.footskate, footskate_weights=args.footskate_weights)
    motion = generate_timeline(pipe, segments, seed=args.seed, steps=args.steps, sampler=args.sampler, cfg=args.cfg,
                               hooks=hooks, source=str(args.timeline), progress=True, plan=not args.whole)
    title = " | ".join(s.text for s in segments)
    written = write_motion(out, slug, motion.features, motion.joints, pipe, formats, title[:120],
                           warn=lambda line: print(line, file=sys.stderr))
    info = {"fps": pipe.fps, "frames": len(motion.features),
            "segments": [{"start_s": s.start_s, "end_s": s.end_s, "text": s.text, "frames": list(f)}
                         for s, f in zip(segments, motion.frames)],
            "windows": [vars(w) for w in motion.windows],
            # acceleration peaks at each join (m/s^2) and the motion's own inside 99th percentile
            "seams": seam_report(motion.joints, motion.join_spans, pipe.fps, pipe.skeleton)}
    write_text(out / f"{slug}.timeline.json", json.dumps(info, indent=1) + "\n")
    written.append(f"{slug}.timeline.json")
    print(f"{args.timeline}: {len(segments)} segments, {len(motion.features)} frames "
          f"({len(motion.features) / pipe.fps:g} s) -> {out}/{{{', '.join(written)}}}")
    return 0


__all__ = ["run_timeline"]
