"""What the finishing step (stablemo.inference.finish: rigid body, floor, features again) costs
against the 1-step student's generation it follows, at 196 frames, batched, on this CPU.

    OMP_NUM_THREADS=2 .venv/bin/python scripts/bench/finish_cost.py [--bundle DIR] [--batch 32]
        [--frames 196] [--rounds 12] [--threads 2]

Each round generates the batch without finishing (the network, its sampler, joints recovery) and
then finishes that output (handed the generation's joints, as Pipeline.generate does), so both run
under the same load; the number to read is the median over rounds of finish time / generation
time, in process CPU time (what the step costs, whatever else runs on the machine) and in wall
time. AITS-style: the text cache is warm, as it is after the
first request. Issue #39's target: <= 10 % for the student.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import torch

from stablemo.checks import check_positive_int
from stablemo.errors import run_script
from stablemo.inference.bundle import DEMO_STUDENT
from stablemo.inference.pipeline import Pipeline

PROMPTS = ("a person walks forward", "a person jumps in place", "a person waves with the right hand",
           "a person runs in a circle", "a person squats down", "a person kicks with the left leg",
           "a person turns left", "a person side steps to the right")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--bundle", default=str(DEMO_STUDENT))
    p.add_argument("--batch", type=int, default=32)
    p.add_argument("--frames", type=int, default=196)
    p.add_argument("--rounds", type=int, default=12)
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)
    for name in ("batch", "frames", "rounds", "threads"):
        check_positive_int(f"--{name}", getattr(args, name))
    torch.set_num_threads(args.threads)
    pipe = Pipeline.from_bundle(args.bundle)
    texts = [PROMPTS[i % len(PROMPTS)] for i in range(args.batch)]
    pipe.generate(texts, args.frames, seed=0)  # warm: text cache, kernels
    cpu, wall = [], []
    for r in range(args.rounds):
        w0, c0 = time.perf_counter(), time.process_time()
        raw = pipe.generate(texts, args.frames, seed=r, finish=False)
        w1, c1 = time.perf_counter(), time.process_time()
        pipe.finish(raw.features, raw.lengths, raw_joints=raw.joints)  # as Pipeline.generate: its joints are at hand
        w2, c2 = time.perf_counter(), time.process_time()
        cpu.append((c2 - c1) / (c1 - c0))
        wall.append((w2 - w1) / (w1 - w0))
        print(f"round {r + 1}/{args.rounds}: generate {w1 - w0:.3f} s, finish {w2 - w1:.3f} s wall "
              f"({wall[-1]:.3f}); cpu ratio {cpu[-1]:.3f}", flush=True)
    print(f"finish / generation ({args.batch} x {args.frames} frames, {args.threads} threads, {args.rounds} rounds): "
          f"median cpu {statistics.median(cpu):.3f}, wall {statistics.median(wall):.3f} "
          f"(range cpu {min(cpu):.3f}-{max(cpu):.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main, "finish_cost.py"))
