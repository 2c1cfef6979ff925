"""Does a streamed prompt happen once? Each prompt of a timeline, streamed as the server streams it
(stablemo.timeline.stream_timeline: each prompt's span generated whole, sent out in 2-s chunks),
against the same prompt generated alone at the same length, and against the old per-chunk stream
(stablemo.timeline.stream with the text playing at each chunk's middle, which starts the prompt
again in every chunk).

    OMP_NUM_THREADS=1 python scripts/long_motion/stream_prompts.py --out /tmp/stream_prompts [--bundle DIR] [--seeds 8] [--steps N]

Per segment, mean over the seeds: turn (degrees the body's facing turns, from the hips and
shoulders of the finished joints, what the page shows) and travel (metres of the root's path on
the floor). A single prompt of seed s, segment i uses seed 100 s + i
(as scripts/long_motion/report.py). Seams (stablemo.timeline.seams): at every join of the streamed
motion (where a window's new rows begin, and where a chunk begins), the largest root and foot
acceleration over the motion's own inside 99th percentile. Writes report.json and report.md.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from stablemo.errors import run_script
from stablemo.inference.bundle import DEMO_STUDENT
from stablemo.inference.pipeline import Pipeline
from stablemo.io import write_text
from stablemo.motion.skeleton import get_skeleton
from stablemo.timeline import segment_frames, stream_timeline
from stablemo.timeline.seams import seam_report
from stablemo.timeline.spec import check_segments

TIMELINES = [
    [(0, 4, "a person turns left, then walks"), (4, 8, "a person walks forward"), (8, 12, "a person turns right")],
    [(0, 4, "a person walks forward"), (4, 8, "a person turns left, then walks"), (8, 11, "a person jumps in place"),
     (11, 15, "a person turns right")],
]
CHUNK_S = 2.0


def facing_turn(joints: np.ndarray, skeleton: str) -> float:
    """Degrees the body's facing turns over joints (T, J, 3), left negative (as the root's yaw
    velocity channel): the facing is the floor direction at right angles to the hips and shoulders
    (the joints the features' facing is read from), unwrapped frame to frame."""
    r_hip, l_hip, r_sh, l_sh = get_skeleton(skeleton).face_joints
    across = (joints[:, r_hip] - joints[:, l_hip]) + (joints[:, r_sh] - joints[:, l_sh])  # (T, 3)
    forward = np.stack([-across[:, 2], across[:, 0]], -1)  # up x across on the floor: (x, z)
    angle = np.unwrap(np.arctan2(forward[:, 0], forward[:, 1]))
    return -math.degrees(float(angle[-1] - angle[0]))


def measures(joints: np.ndarray, skeleton: str) -> dict:
    """The finished joints (T, J, 3) of one segment -> turn (degrees, the body's facing, what the
    page shows) and travel (m, the root's path on the floor)."""
    travel = float(np.linalg.norm(np.diff(joints[:, 0, [0, 2]], axis=0), axis=-1).sum())
    return {"turn": facing_turn(joints, skeleton), "travel": travel}


def old_stream(pipe, segments, seed: int, steps=None):
    """The stream the server made before: one 2-s chunk per text, the text playing at its middle."""
    frames = segment_frames(check_segments(segments), pipe.fps)
    total = frames[-1][1] / pipe.fps
    ends = np.array([s[1] for s in segments])
    count = math.ceil(total / CHUNK_S - 1e-9)
    texts = [segments[min(int(np.searchsorted(ends, (i + 0.5) * CHUNK_S, side="right")), len(segments) - 1)][2]
             for i in range(count)]
    chunks = list(pipe.stream(texts, chunk_seconds=CHUNK_S, seed=seed, max_chunks=count, steps=steps))
    return np.concatenate([c.joints for c in chunks])


def run(pipe, seeds, steps=None, plan: bool = True) -> dict:
    rows, seams = [], []
    for t, segments in enumerate(TIMELINES):
        frames = segment_frames(check_segments(segments), pipe.fps)
        per = [{"timeline": t + 1, "text": s[2], "seconds": s[1] - s[0], "streamed": [], "alone": [], "old": []}
               for s in segments]
        for seed in seeds:
            stream = stream_timeline(pipe, segments, chunk_seconds=CHUNK_S, seed=seed, steps=steps, plan=plan)
            chunks = list(stream.chunks)
            joints = np.concatenate([c.joints for c in chunks])
            old_j = old_stream(pipe, segments, seed, steps)
            for i, (a, b) in enumerate(frames):
                # alone: a timeline of that one prompt at the same length (a prompt that says an order is
                # made in its parts there too, stablemo.timeline.compose.plan_timeline)
                alone = pipe.generate_timeline([(0.0, (b - a) / pipe.fps, segments[i][2])], seed=seed * 100 + i,
                                               steps=steps, plan=plan)
                per[i]["streamed"].append(measures(joints[a:b], pipe.skeleton))
                per[i]["old"].append(measures(old_j[a:b], pipe.skeleton))
                per[i]["alone"].append(measures(alone.joints, pipe.skeleton))
            window_joins = [w.new_start for w in stream.plan.windows if w.new_start > 0]
            chunk_joins = [c.start for c in chunks if c.start > 0 and c.start not in window_joins]
            rep = seam_report(joints, window_joins + chunk_joins, pipe.fps, pipe.skeleton)
            inside = rep["inside_p99"]
            for j in rep["joins"]:
                seams.append({"timeline": t + 1, "seed": seed, "frame": j["frame"],
                              "kind": "window" if j["frame"] in window_joins else "chunk",
                              "ratio": max(j["root"] / inside["root"], j["foot"] / inside["foot"])})
        for row in per:
            for kind in ("streamed", "alone", "old"):
                row[kind] = {k: float(np.mean([v[k] for v in row[kind]])) for k in ("turn", "travel")}
            rows.append(row)
    return {"segments": rows, "seams": seams}


def to_markdown(result: dict) -> str:
    steps = result["steps"] or "the bundle's"
    lines = [(f"Model: {result['bundle']}, {steps} steps, seeds {result['seeds']}, {CHUNK_S:g}-s chunks, overlap and "
              "settle as the server streams"), "",
             "| timeline | prompt | s | turn deg: streamed / alone / old stream | travel m: streamed / alone / old stream |",
             "|---|---|---|---|---|"]
    for r in result["segments"]:
        s, a, o = r["streamed"], r["alone"], r["old"]
        lines.append(f"| {r['timeline']} | {r['text']} | {r['seconds']:g} | {s['turn']:+.0f} / {a['turn']:+.0f} / "
                     f"{o['turn']:+.0f} | {s['travel']:.2f} / {a['travel']:.2f} / {o['travel']:.2f} |")
    lines += ["", "| joins | count | within 2x inside p99 | mean worst ratio | max worst ratio |", "|---|---|---|---|---|"]
    for kind in ("window", "chunk"):
        ratios = [s["ratio"] for s in result["seams"] if s["kind"] == kind]
        if ratios:
            lines.append(f"| {kind} | {len(ratios)} | {np.mean(np.array(ratios) <= 2):.0%} | {np.mean(ratios):.2f} | "
                         f"{np.max(ratios):.2f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bundle", default=str(DEMO_STUDENT))
    p.add_argument("--seeds", type=int, default=8)
    p.add_argument("--steps", type=int, default=None, help="sampler steps (default: the bundle's)")
    p.add_argument("--whole", action="store_true", help="segments whole (plan=False), as before segments were planned")
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)
    pipe = Pipeline.from_bundle(args.bundle)
    result = {"bundle": Path(args.bundle).name, "steps": args.steps, "seeds": list(range(args.seeds)),
              "planned": not args.whole, **run(pipe, range(args.seeds), args.steps, not args.whole)}
    write_report(Path(args.out), result, to_markdown(result))


def write_report(out: Path, result: dict, markdown: str) -> None:
    """A long-motion script's report: out/report.json (every number), out/report.md, printed."""
    write_text(out / "report.json", json.dumps(result, indent=1) + "\n")
    write_text(out / "report.md", markdown)
    print(markdown)


if __name__ == "__main__":
    sys.exit(run_script(main, "/".join(Path(__file__).parts[-2:]), sys.argv[1:]))
