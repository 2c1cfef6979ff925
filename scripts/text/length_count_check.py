"""Does a motion with the text's length do what the text counts? Jumps at the text's length vs at 6 s.

    .venv/bin/python scripts/text/length_count_check.py [--bundle stablemo/assets/demo_bundle] [--seeds 0 1 2 3]

For each prompt, each seed and two lengths (none asked for: the bundle's length predictor, and the
old fixed default of 6 s), generates a motion and scores it with the behaviour suite's checks
(stablemo.eval.behaviour): the number of jumps (flights, both feet off the ground) of the jump
prompts, and the order of walking and waving in the README's prompt. Prints one row per prompt
and length (docs/inference.md, "How long a motion is").
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

PROMPTS = {  # text -> the synthetic parts it asks for (stablemo.eval.behaviour.table)
    "a person jumps in place twice": [("jump", {"count": 2})],
    "a person jumps in place three times": [("jump", {"count": 3})],
    "a person walks forward, then waves their right hand": [("walk", {"speed_label": "normal"}),
                                                            ("wave", {"hand": "right"})],
}
OLD_DEFAULT_S = 6.0


def main(argv=None) -> int:
    from stablemo.eval.behaviour.checks import score
    from stablemo.eval.behaviour.table import Part, Prompt, expected
    from stablemo.inference.bundle import DEMO_BUNDLE
    from stablemo.inference.pipeline import Pipeline, Request

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bundle", default=str(DEMO_BUNDLE))
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    args = ap.parse_args(argv)
    pipe = Pipeline.from_bundle(args.bundle)
    print(f"| prompt | length | {' | '.join(f'seed {s}' for s in args.seeds)} |")
    print(f"|---|---|{'---|' * len(args.seeds)}")
    for text, raw in PROMPTS.items():
        parts = tuple(Part(a, p) for a, p in raw)
        attribute = "order" if len(parts) > 1 else "count"
        prompt = Prompt(text, parts, {attribute: expected(attribute, parts)}, "suite")
        for label, length in (("text", None), ("6 s", round(OLD_DEFAULT_S * pipe.fps))):
            out = pipe.generate(Request([text] * len(args.seeds), length, seed=list(args.seeds)))
            verdicts = [score(prompt, j, pipe.fps)[attribute] for j in out.joint_list()]
            shown = " | ".join(f"{v.measured} {'ok' if v.passed else 'wrong'}" for v in verdicts)
            frames = sorted(set(out.lengths))
            print(f"| {text} ({attribute}) | {label}: {', '.join(map(str, frames))} frames | {shown} |", flush=True)
    return 0


if __name__ == "__main__":
    from stablemo.errors import run_script

    sys.exit(run_script(main, "/".join(Path(__file__).parts[-2:]), sys.argv[1:]))
