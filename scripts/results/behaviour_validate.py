"""The behaviour checks on ground truth: each must pass on the synthetic generator's own motion of
a prompt and fail on a motion wrong in its attribute only (stablemo.eval.behaviour.truth).

    python scripts/results/behaviour_validate.py [--seeds 4] [--lengths natural 6 9.8]

Prints, per attribute, how many checks passed on the truth and how many passed on wrong motions
(which should be none), and every exception; exit 1 if there is one. docs/evaluation.md quotes it.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter

from stablemo.eval.behaviour import truth
from stablemo.eval.behaviour.checks import score
from stablemo.eval.behaviour.runner import frames_for, parse_lengths
from stablemo.eval.behaviour.table import ATTRIBUTES, load_prompts
from stablemo.inference.config import InferenceConfig


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--lengths", nargs="+", default=["natural", "6", "9.8"])
    args = p.parse_args(argv)
    config = InferenceConfig()
    lengths = parse_lengths(args.lengths)
    counts, started, exceptions = Counter(), time.perf_counter(), 0
    for prompt in load_prompts():
        for token in lengths:
            frames = frames_for(token, prompt, config.fps, config.min_length, config.max_length)
            for seed in range(args.seeds):
                for attribute, verdict in score(prompt, truth.truth_joints(prompt, seed, frames), config.fps).items():
                    counts[attribute, "truth"] += 1
                    counts[attribute, "truth passed"] += verdict.passed
                    if not verdict.passed:
                        exceptions += 1
                        print(f"truth fails: {prompt.text!r} {token} seed {seed} {attribute}: {verdict.measured}")
                for attribute in prompt.tests:
                    verdict = score(prompt, truth.wrong_joints(prompt, attribute, seed, frames), config.fps)[attribute]
                    counts[attribute, "wrong"] += 1
                    counts[attribute, "wrong passed"] += verdict.passed
                    if verdict.passed:
                        exceptions += 1
                        print(f"wrong passes: {prompt.text!r} {token} seed {seed} {attribute}: {verdict.measured} "
                              f"({truth.wrong_parts(prompt, attribute)})")
    print(f"{'attribute':<10} {'truth passed':>14} {'wrong passed':>14}")
    for a in ATTRIBUTES:
        print(f"{a:<10} {counts[a, 'truth passed']:>6} / {counts[a, 'truth']:<5} {counts[a, 'wrong passed']:>6} / {counts[a, 'wrong']:<5}")
    total = lambda key: sum(counts[a, key] for a in ATTRIBUTES)
    print(f"{'all':<10} {total('truth passed'):>6} / {total('truth'):<5} {total('wrong passed'):>6} / {total('wrong'):<5}"
          f"  ({args.seeds} seeds, lengths {' '.join(lengths)}; {time.perf_counter() - started:.0f} s)")
    return 1 if exceptions else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
