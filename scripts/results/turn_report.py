"""Turns as said (docs/inference.md): how far the shipped models turn prompts that size a turn, given
the prompt whole (the network's own turn) and as `stablemo generate` makes them (the angle read from
the words, stablemo.text.turns, and the body turned by it, stablemo.control.turn), and what that
costs the feet.

    python scripts/results/turn_report.py [--out docs/data/results/turns] [--seeds 4]

The prompts are written apart from the training captions and the behaviour suite (other verbs,
subjects and ways to say an angle). Per prompt and model, over the seeds at the text's own length:
the facing's turn (the behaviour suite's heading_change, degrees, + = left), the factor the root's
turn needed on the network's own output (turn_scale, 1 where it is left alone), and the stance
foot's speed (cm/s) and the feet's acceleration (m/s^2) of the finished motions
(stablemo.eval.kinematics). Writes turns.json, turns.md (the table) and turns.png (the facing's turn
over time of three prompts, seed 0: whole in grey, as said in red, the asked angle dotted).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from stablemo.control.turn import said_turns, turn_scale
from stablemo.errors import run_script
from stablemo.eval.behaviour.measures import heading_change
from stablemo.eval.kinematics import foot_acceleration, stance_speed
from stablemo.inference.bundle import DEMO_BUNDLE, DEMO_STUDENT
from stablemo.inference.pipeline import Pipeline, Request
from stablemo.io import write_text
from stablemo.outputs.render import save_png
from stablemo.text.turns import asked_turn

PROMPTS = [
    "a man pivots to the left.",
    "the woman turns ninety degrees clockwise.",
    "a soldier does an about-face.",
    "someone turns around over the right shoulder.",
    "a dancer spins around to face the opposite direction.",
    "a woman walks a full circle to the right.",
    "a man walks in a counterclockwise circle.",
    "a person makes a three-quarter turn to the left.",
]
PICTURED = [0, 3, 5]  # prompts drawn in turns.png (seed 0, each model)
MODELS = {"teacher": DEMO_BUNDLE, "1-step student": DEMO_STUDENT}


def measure(pipe: Pipeline, seeds: int) -> tuple[list[dict], dict]:
    texts = [t for t in PROMPTS for _ in range(seeds)]
    seed = [s for _ in PROMPTS for s in range(seeds)]
    lengths = pipe.text_lengths(texts)
    whole = pipe.generate(Request(texts, lengths, seed=seed))
    said = pipe.generate(Request(texts, lengths, seed=seed, plan=True))
    turns = said_turns(texts, [(0, n) for n in lengths])
    k = turn_scale(whole.raw_features, lengths, [None if t is None else t.resolve(n) for t, n in zip(turns, lengths)],
                   pipe.skeleton, pipe.fps).numpy()
    n = torch.tensor(lengths)
    rows = []
    for i, text in enumerate(PROMPTS):
        sl = slice(i * seeds, (i + 1) * seeds)
        asked = asked_turn(text)
        row = {"text": text, "asked": None if asked is None else {"degrees": asked.degrees, "side": asked.side},
               "frames": lengths[sl.start]}
        for name, gen in (("whole", whole), ("said", said)):
            joints = gen.joints[sl]
            row[name] = {"turn_deg": [round(heading_change(j, pipe.fps), 1) for j in gen.joint_list()[sl]],
                         "stance_speed_cm_s": float(np.mean(stance_speed(joints, n[sl], pipe.skeleton))),
                         "foot_acc_m_s2": float(np.mean(foot_acceleration(joints, n[sl], pipe.skeleton)))}
        row["scale"] = [round(float(x), 2) for x in k[sl]]
        rows.append(row)
    pictures = {i: (whole.joint_list()[i * seeds], said.joint_list()[i * seeds]) for i in PICTURED}
    return rows, pictures


def table(results: dict) -> str:
    out = ["| model | prompt | asked | turn, whole (deg) | turn, as said (deg) | scale k | stance foot, whole -> said (cm/s) "
           "| foot acc., whole -> said (m/s^2) |", "|---|---|---|---|---|---|---|---|"]
    for model, rows in results.items():
        for r in rows:
            a = r["asked"]
            asked = "–" if a is None else f"{a['degrees']:g}" + (f" {a['side']}" if a["side"] else "")
            w, s = r["whole"], r["said"]
            out.append(f"| {model} | {r['text']} | {asked} | {', '.join(f'{x:+.0f}' for x in w['turn_deg'])} "
                       f"| {', '.join(f'{x:+.0f}' for x in s['turn_deg'])} | {', '.join(f'{x:g}' for x in r['scale'])} "
                       f"| {w['stance_speed_cm_s']:.1f} -> {s['stance_speed_cm_s']:.1f} "
                       f"| {w['foot_acc_m_s2']:.2f} -> {s['foot_acc_m_s2']:.2f} |")
    return "\n".join(out) + "\n"


def picture(drawn: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stablemo.eval.behaviour.measures import facing

    fig, axes = plt.subplots(len(drawn), len(PICTURED), figsize=(4.2 * len(PICTURED), 3.2 * len(drawn)), squeeze=False)
    for row, (model, pics) in zip(axes, drawn.items()):
        for ax, i in zip(row, PICTURED):
            for j, colour, label in ((pics[i][0], "0.55", "whole"), (pics[i][1], "tab:red", "as said")):
                yaw = np.rad2deg(facing(j, 20.0))
                ax.plot(np.arange(len(j)) / 20.0, yaw - yaw[0], color=colour,
                        label=f"{label}: turned {heading_change(j, 20.0):+.0f} deg")
            asked = asked_turn(PROMPTS[i])
            if asked is not None:
                sign = {"left": 1, "right": -1}.get(asked.side, np.sign(heading_change(pics[i][1], 20.0)) or 1)
                ax.axhline(sign * asked.degrees, color="tab:red", ls=":", lw=1, label=f"asked {sign * asked.degrees:+.0f} deg")
            ax.set_title(f"{model}: {PROMPTS[i]}", fontsize=9)
            ax.legend(fontsize=7, loc="best")
            ax.set_xlabel("time (s)")
            ax.set_ylabel("facing turned (deg, + = left)")
    fig.tight_layout()
    save_png(fig, path, dpi=80)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="docs/data/results/turns", help="folder for turns.json, turns.md, turns.png")
    ap.add_argument("--seeds", type=int, default=4, help="motions per prompt and model")
    args = ap.parse_args(argv)
    if args.seeds < 1:
        raise SystemExit("turn_report.py: --seeds must be at least 1")
    out = Path(args.out)
    results, drawn = {}, {}
    for model, bundle in MODELS.items():
        print(f"{model}: {len(PROMPTS)} prompts x {args.seeds} seeds", flush=True)
        results[model], drawn[model] = measure(Pipeline.from_bundle(bundle), args.seeds)
    text = table(results)
    print(text)
    write_text(out / "turns.json", json.dumps({"prompts": PROMPTS, "seeds": args.seeds, "results": results}, indent=1) + "\n")
    write_text(out / "turns.md", text)
    picture(drawn, out / "turns.png")
    print(f"wrote {out}/turns.json, turns.md, turns.png")
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main, "turn_report.py", sys.argv[1:]))
