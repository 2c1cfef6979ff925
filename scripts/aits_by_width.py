"""The 1-step student / 10-step teacher AITS ratio as a function of the network's width.

The demo config (configs/demo.yaml) with its UNet's base_channels replaced, random weights (speed
only), timed as `stablemo bench aits` times its varied-length line: sentences of a test set's
spread of lengths, teacher (SDE-DPM-Solver++ 2M, parallel CFG) and 1-step LCM student side by
side, each sentence encoding its own prompt. Shows from which size on the calls stop being
overhead-bound and the ratio approaches 1/10:

    .venv/bin/python scripts/aits_by_width.py --widths 32 64 128 192 --threads 2
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path
from types import SimpleNamespace

import torch
import yaml

from stablemo import bench
from stablemo.diffusion.schedule import NoiseSchedule
from stablemo.model import MotionDiffusionModel
from stablemo.pipeline import Pipeline
from stablemo.inference_config import PAPER_CFG, PAPER_STEPS

DEMO_CONFIG = Path(__file__).resolve().parents[1] / "configs" / "demo.yaml"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--widths", type=int, nargs="+", default=[32, 64, 128, 192])
    p.add_argument("--steps", type=int, default=PAPER_STEPS)
    p.add_argument("--cfg", type=float, default=PAPER_CFG)
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    kwargs = yaml.safe_load(DEMO_CONFIG.read_text())["model"]["model"]
    dim = int(kwargs["denoiser"]["input_dim"])
    timing = SimpleNamespace(cfg=args.cfg, steps=args.steps, seed=args.seed)
    print(f"{'base channels':>13} {'parameters':>11} {'teacher s':>10} {'student s':>10} {'ratio':>6}")
    for width in args.widths:
        model_kwargs = copy.deepcopy(kwargs)
        model_kwargs["denoiser"]["base_channels"] = width
        torch.manual_seed(args.seed)
        model = MotionDiffusionModel(**model_kwargs)
        params = sum(q.numel() for q in model.parameters() if q.requires_grad) / 1e6  # trainable: not the frozen encoder
        teacher = Pipeline(model, NoiseSchedule(), mean=[0.0] * dim, std=[1.0] * dim, prediction_type="sample",
                           skeleton="humanml3d", config={"model": model_kwargs})
        student = bench._student_pipeline(teacher, fast=True)
        for pipe in (teacher, student):  # kernels and the encoder loaded before timing
            pipe.generate(["warm up"], [bench.VARIED_LENGTHS[0]], steps=2, cfg=args.cfg, seed=args.seed)
        result = bench.varied_length_aits(teacher, student, timing)
        print(f"{width:>13} {params:>9.2f} M {result['teacher']:>10.4f} {result['student']:>10.4f} "
              f"{result['student'] / result['teacher']:>6.3f}", flush=True)


if __name__ == "__main__":
    main()
