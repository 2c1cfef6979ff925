"""Does a followed path turn the body? Facing against travel along drawn pelvis paths (issue #41).

    python scripts/control/heading_check.py --model student --paths 3 --rng 200 --seeds 0,1
    python scripts/control/heading_check.py --model controlnet --no-guidance ...

For each text and path family (stablemo.eval.paths: straight, arc, s_curve, out_and_back; random
parameters from --rng, never the same draws as the ones the steering was tuned on), it generates
the text freely (its pelvis heights, pace and stance-foot speed are the reference, as the page takes
the motion on screen's), then along the path with the pelvis a target at every frame, with
the body steered toward the path (Request.face_travel) and, with --ab, also without. Reports per
family: the median over motions of the median facing-vs-travel angle (stablemo.eval.heading), the
worst motion's, the pelvis path error (cm, mean and max over frames), the stance-foot speed against
the free motion's, the standing foot's speed (stablemo.eval.kinematics.standing_foot_speed, which has no
contact speed bound; median over motions, beside the free motions'), and the shares of moving
frames walked backwards / sideways. --json keeps them.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np
import torch

from stablemo.control.pace import timed_path
from stablemo.eval.heading import heading_measures
from stablemo.eval.kinematics import stance_speed, standing_foot_speed
from stablemo.eval.paths import FAMILIES, family_path, path_control
from stablemo.inference.bundle import DEMO_BUNDLE, DEMO_CONTROLNET, DEMO_STUDENT
from stablemo.inference.pipeline import Pipeline, Request
from stablemo.motion.skeleton import get_skeleton

MODELS = {"student": DEMO_STUDENT, "teacher": DEMO_BUNDLE, "controlnet": DEMO_CONTROLNET}


def _speed(joints: torch.Tensor, n: int, fps: float) -> float:
    xz = joints[:n, 0][:, [0, 2]]
    return float((xz[-1] - xz[0]).norm() / ((n - 1) / fps))


def run(pipe, text, family, args, seeds, face_travel):
    fps = pipe.fps
    T = args.frames
    free = pipe.generate(Request([text] * len(seeds), T, seed=seeds))
    lengths = torch.tensor([T] * len(seeds))
    free_stance = stance_speed(free.joints, lengths, pipe.skeleton)
    free_standing = standing_foot_speed(free.joints, lengths, pipe.skeleton)
    speed = args.speed or float(np.median([_speed(j, T, fps) for j in free.joints]))
    per_metre = get_skeleton(pipe.skeleton).per_metre
    rng = np.random.default_rng(args.rng)
    rows = []
    for p in range(args.paths):
        drawn = family_path(family, rng, T, fps, speed)
        paths = [drawn if args.timing == "constant" else
                 timed_path(drawn, free.joints[i, :, 0][:, [0, 2]].numpy(), T, per_metre)
                 for i in range(len(seeds))]
        controls = [path_control(paths[i], free.joints[i, :, 0, 1].numpy(), free.joints.shape[2]) for i in range(len(seeds))]
        out = pipe.generate(Request([text] * len(seeds), T, seed=seeds, control=controls,
                                    control_guidance=args.guidance, face_travel=face_travel))
        m = heading_measures(out.joints, lengths, pipe.skeleton)
        err = (out.joints[:, :, 0][..., [0, 2]] - torch.tensor(np.stack(paths), dtype=out.joints.dtype)).norm(dim=-1)  # (B, T)
        stance = stance_speed(out.joints, lengths, pipe.skeleton)
        standing = standing_foot_speed(out.joints, lengths, pipe.skeleton)
        for i in range(len(seeds)):
            rows.append({"path": p, "seed": seeds[i], "facing": float(m["facing_deg"][i]), "backward": float(m["backward"][i]),
                             "sideways": float(m["sideways"][i]), "err_mean": float(err[i].mean() * 100),
                             "err_max": float(err[i].max() * 100), "stance": float(stance[i]),
                             "free_stance": float(free_stance[i]), "standing_foot": float(standing[i]),
                             "free_standing_foot": float(free_standing[i])})
    return speed, rows


def summary(rows):
    f = np.array([r["facing"] for r in rows])
    ratio = np.nanmean([r["stance"] for r in rows]) / np.nanmean([r["free_stance"] for r in rows])
    return {"facing_median": float(np.nanmedian(f)), "facing_worst": float(np.nanmax(f)),
                "err_mean": float(np.mean([r["err_mean"] for r in rows])), "err_max": float(np.max([r["err_max"] for r in rows])),
                "stance_ratio": float(ratio), "standing_foot": float(np.nanmedian([r["standing_foot"] for r in rows])),
                "free_standing_foot": float(np.nanmedian([r["free_standing_foot"] for r in rows])),
                "backward": float(np.nanmean([r["backward"] for r in rows])),
                "sideways": float(np.nanmean([r["sideways"] for r in rows]))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", choices=sorted(MODELS), default="student")
    ap.add_argument("--bundle", default=None, help="a bundle folder instead of --model's shipped one (e.g. a new ControlNet)")
    ap.add_argument("--texts", default="a person walks forward")
    ap.add_argument("--families", default=",".join(FAMILIES))
    ap.add_argument("--paths", type=int, default=3, help="paths per family")
    ap.add_argument("--rng", type=int, default=200, help="seed of the path parameters")
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--speed", type=float, default=None, help="path speed (m/s); default the free motion's")
    ap.add_argument("--timing", choices=["motion", "constant"], default="motion",
                    help="walk each path at the free motion's own pace (the page's way) or at one speed")
    ap.add_argument("--no-guidance", dest="guidance", action="store_false")
    ap.add_argument("--ab", action="store_true", help="also without steering (face_travel=False)")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    torch.manual_seed(0)
    pipe = Pipeline.from_bundle(args.bundle or MODELS[args.model])
    seeds = [int(s) for s in args.seeds.split(",")]
    out = {}
    print(f"{args.bundle or args.model} guidance={args.guidance} timing={args.timing} frames={args.frames} rng={args.rng} seeds={seeds}")
    print("| text | path | steered | facing median (deg) | worst | path err mean / max (cm) | stance speed / free | "
          "standing foot, free (cm/s) | backward | sideways |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for text in [t.strip() for t in args.texts.split("|")]:
        for family in args.families.split(","):
            for steer in ([False, True] if args.ab else [True]):
                speed, rows = run(pipe, text, family, args, seeds, steer)
                s = summary(rows)
                out[f"{text} | {family} | {steer}"] = {"summary": s, "rows": rows, "speed": speed}
                print(f"| {text} ({speed:.2f} m/s) | {family} | {'yes' if steer else 'no'} | {s['facing_median']:.1f} | {s['facing_worst']:.1f} | "
                      f"{s['err_mean']:.1f} / {s['err_max']:.1f} | {s['stance_ratio']:.2f} | "
                      f"{s['standing_foot']:.0f}, {s['free_standing_foot']:.0f} | {s['backward']:.2f} | "
                      f"{s['sideways']:.2f} |", flush=True)
    if args.json:
        from stablemo.io import write_text
        write_text(args.json, json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
