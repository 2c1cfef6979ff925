"""The joint-control table of docs/results.md: OmniControl / MotionLCM's protocol on the synthetic benchmark.

    python scripts/control/report.py --bundle stablemo/assets/demo_bundle --student LCM=bundles/demo_lcm \
        --data data/synth --replications 3 --max-items 128 --out docs/data/results/results_control.json

`--controlnet NAME=DIR` adds a ControlNet bundle (stablemo.control.controlnet; docs/control.md), scored at its
own steps with the hint alone and with the hint plus the guidance refinement (Request.control_guidance);
`--rows pelvis:100%,none:100%` limits the rows (default: all).

For each model (the teacher at its 10 steps, each student at 1 step) it scores the uncontrolled
model and the model with hints from the test motions (`stablemo evaluate --control J --density D`):
pelvis at 100% / 25% / 5 / 2 / 1 frames, a wrist at 25%, whole-pose keyframes on 4 frames. The
uncontrolled row is scored against the same hints (its errors say how far free generation is from
the test motions; its spike share is the model's own baseline). AITS of controlled vs uncontrolled
generation is measured side by side (alternating, batch 1, dense pelvis hints) and printed as a
ratio. Prints the markdown table; `--out` keeps the numbers as JSON; `--render JSON` prints the table
of such a file again.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

ROWS = [("none", "100%"), ("pelvis", "100%"), ("pelvis", "25%"), ("pelvis", "5"), ("pelvis", "2"), ("pelvis", "1"),
        ("left_wrist", "25%"), ("keyframes", "4")]
COLS = [("fid", "FID"), ("r3", "R@3"), ("diversity", "Div."), ("skate_ratio", "Skate"), ("foot_acc", "Foot acc."),
        ("traj_err", "Traj. err"), ("loc_err", "Loc. err"), ("avg_err", "Avg. err (m)"), ("spikes", "Spikes"),
        ("facing_deg", "Facing err °"), ("unasked_backward", "Backward"), ("unasked_sideways", "Sideways"),
        ("stance_speed", "Stance v cm/s")]


def _rows(pipe, name: str, steps: int, data, evaluator, args, guidance: bool = True) -> dict:
    from stablemo.eval.evaluate import evaluate
    from stablemo.eval.control import ControlProtocol
    from stablemo.inference.pipeline import Request

    out = {}
    lo, hi = pipe.min_length, pipe.max_length
    for joint, density in _selected(args.rows):
        if joint == "none" and not guidance:
            continue  # the uncontrolled row does not depend on the refinement: scored once, with the "+ guidance" model
        # the uncontrolled model is scored against the pelvis hints (errors: free generation vs the test motion)
        protocol = ControlProtocol("pelvis" if joint == "none" else joint, density, pipe.skeleton)
        use = joint != "none"

        def generate(texts, lengths, seeds, controls=None):
            gen = [min(max(n, lo), hi) for n in lengths]
            res = pipe.generate(Request(texts, gen, seed=seeds, steps=steps, control=controls if use else None,
                                        control_guidance=guidance, face_travel=args.face_travel))
            return res.features, res.joints

        t0 = time.time()
        result = evaluate(data, evaluator, generate, replications=args.replications, seed=args.seed,
                          max_items=args.max_items, skeleton=pipe.skeleton, row_name=name, progress=False,
                          control=protocol, footskate=True)
        key = f"{name} | {'uncontrolled' if joint == 'none' else f'{joint} {density}'}"
        out[key] = {"model": result["rows"][name], "real": result["rows"]["Real motion"]}
        print(f"{key}: {time.time() - t0:.0f} s", flush=True)
    return out


def _selected(rows: str | None) -> list[tuple[str, str]]:
    if not rows:
        return ROWS
    picked = [tuple(r.split(":", 1)) for r in rows.split(",")]
    bad = [r for r in picked if r not in ROWS]
    if bad:
        raise SystemExit(f"--rows: {bad} not among {ROWS}")
    return picked


def _aits_ratio(pipe, steps: int, texts: list[str], length: int, repeats: int, guidance: bool = True) -> dict:
    """Controlled (dense pelvis from a generated circle) vs uncontrolled time per motion, alternating."""
    from stablemo.control.files import control_from_joints, density_frames

    src = pipe.generate(["a person walks in a circle counterclockwise"], length, seed=123, steps=steps).joint_list()[0]
    spec = control_from_joints(src, [0], density_frames("100%", length))
    times = {"free": [], "control": []}
    for _ in range(repeats):
        for text in texts:
            for mode in ("free", "control"):
                t0 = time.perf_counter()
                pipe.generate([text], length, seed=0, steps=steps, control=spec if mode == "control" else None,
                              control_guidance=guidance)
                times[mode].append(time.perf_counter() - t0)
    free, ctl = float(np.median(times["free"])), float(np.median(times["control"]))
    return {"free_s": free, "control_s": ctl, "ratio": ctl / free}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bundle", default="stablemo/assets/demo_bundle")
    p.add_argument("--student", action="append", default=[], help="NAME=DIR, scored at 1 step")
    p.add_argument("--data", default="data/synth")
    p.add_argument("--evaluator", default=None)
    p.add_argument("--replications", type=int, default=3)
    p.add_argument("--max-items", type=int, default=128)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--aits-repeats", type=int, default=3)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--no-teacher", action="store_true", help="score only the students")
    p.add_argument("--controlnet", action="append", default=[],
                   help="NAME=DIR: a ControlNet bundle, scored at its own steps without and with the guidance refinement")
    p.add_argument("--no-face-travel", dest="face_travel", action="store_false",
                   help="leave the body's facing to the network along a hinted path (Request.face_travel=False): the A/B of the steering")
    p.add_argument("--rows", default=None, help="comma-separated joint:density rows to score (default: all)")
    p.add_argument("--out", default=None)
    p.add_argument("--render", default=None, metavar="JSON",
                   help="only print the markdown table of a JSON this script wrote (scripts/results/make_results.py "
                        "uses it for docs/results.md)")
    args = p.parse_args(argv)
    if args.render:
        print(markdown(json.loads(Path(args.render).read_text())))
        return 0
    torch.set_num_threads(args.threads)

    from stablemo.data import MotionDataset
    from stablemo.eval.evaluate import default_evaluator
    from stablemo.eval.text_motion import load_text_motion_evaluator
    from stablemo.inference.pipeline import Pipeline

    data = MotionDataset.from_folder(args.data, "test", "humanml3d", crop="eval", seed=args.seed, progress=False)
    evaluator = load_text_motion_evaluator(args.evaluator or default_evaluator(args.data), "humanml3d", None)
    models = [] if args.no_teacher else [("teacher (10 steps)", args.bundle, None)]
    models += [(f"{name} student (1 step)", path, 1) for name, path in (s.split("=", 1) for s in args.student)]
    models = [(name, path, steps, True) for name, path, steps in models]
    for name, path in (s.split("=", 1) for s in args.controlnet):
        models += [(f"{name} + ControlNet", path, None, False), (f"{name} + ControlNet + guidance", path, None, True)]
    report = {"settings": vars(args), "rows": {}, "aits": {}}
    sentences = ["a person walks forward", "a person jumps in place twice", "a person waves with the right hand",
                 "a person runs forward", "a person turns left", "a person kicks with the left leg"]
    for name, path, steps, guidance in models:
        pipe = Pipeline.from_bundle(path)
        steps = steps or pipe.inference.steps
        report["aits"][name] = _aits_ratio(pipe, steps, sentences, 120, args.aits_repeats, guidance)
        print(f"{name}: AITS {report['aits'][name]}", flush=True)
        report["rows"].update(_rows(pipe, name, steps, data, evaluator, args, guidance))
        if args.out:
            from stablemo.io import write_text

            write_text(args.out, json.dumps(report, indent=2) + "\n")
    print(markdown(report))
    return 0


def markdown(report: dict) -> str:
    head = "| model | control | " + " | ".join(h for _, h in COLS) + " |"
    lines = [head, "|" + "---|" * (len(COLS) + 2)]
    for key, row in report["rows"].items():
        model, control = key.split(" | ")
        cells = []
        for col, _ in COLS:
            cell = row["model"].get(col)
            cells.append(f"{cell['mean']:.3f} ± {cell['conf95']:.3f}" if cell else "-")
        lines.append(f"| {model} | {control} | " + " | ".join(cells) + " |")
    real = next(iter(report["rows"].values()))["real"]
    lines.append("| real motion | - | " + " | ".join(
        f"{real[c]['mean']:.3f}" if c in real else "-" for c, _ in COLS) + " |")
    for name, a in report["aits"].items():
        lines.append(f"\nAITS {name}: uncontrolled {a['free_s']:.3f} s, dense pelvis control {a['control_s']:.3f} s "
                     f"({a['ratio']:.2f}x), 120 frames, batch 1, median of alternating runs.")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
