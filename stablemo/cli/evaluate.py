"""`stablemo evaluate`: the field's text-to-motion benchmark with 95% intervals over replications.

    stablemo evaluate --bundle DIR --data DIR [--evaluator DIR|CKPT] [--replications 20]
        [--steps 10 --sampler dpmpp_2m_sde --cfg 2.5] [--dtype fp32|bf16|fp16] [--footskate] [--multimodality]
        [--no-kinematics] [--split test --seed 0 --out results.json --csv results.csv]

    stablemo evaluate --behaviour [--bundle DIR --seeds 4 --lengths ... --out ...]   (= stablemo behaviour)

Protocol: Guo et al. 2022 (docs/evaluation.md). Each replication r makes two passes over the split's items with
the evaluation crop rule and one random caption per item (the data set's per-epoch randomness):
pass 2r gives the reference statistics, pass 2r+1 the captions and lengths that are scored. The
"Real motion" row scores pass 2r+1's real motions (so its FID measures crop/caption noise, ≈ 0);
the model row generates one motion per scored caption at that length. Items are shuffled per pass
before forming the R-precision batches of 32. Without --bundle only the real motions are scored
(a check of the evaluator itself). A bundle is scored twice from the same generations: its row is what
the user receives (the rigid body on the floor), the row marked [raw] the network's output before that
step. Beside FID and R-precision every row gets the kinematic measures (stablemo.eval.kinematics:
bone-length change, floor penetration, stance-foot height and speed, foot acceleration, airborne share).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from stablemo.checks import check_finite, check_positive_int, check_seed
from stablemo.errors import StableMoError
from stablemo.eval import metrics
from stablemo.eval.control import CONTROL_CHOICES
from stablemo.eval.evaluate import (
    default_evaluator,
    dtype_name,
    evaluate,
    format_csv,
    format_table,
    generation_outputs,
)
from stablemo.eval.text_motion import load_text_motion_evaluator


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="stablemo evaluate", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--behaviour", action="store_true",
                   help="run the behaviour suite instead (prompts checked from the joints; the options of "
                        "`stablemo behaviour`, no --data)")
    p.add_argument("--bundle", help="inference bundle to evaluate (omit to score only the real motions)")
    p.add_argument("--data", required=True, help="dataset folder (HumanML3D layout)")
    p.add_argument("--evaluator",
                   help="our evaluator (.ckpt or exported folder) or the published archive folder / finest.tar "
                        "(default on the synthetic benchmark's data: the packaged stablemo/assets/evaluator_synth)")
    p.add_argument("--glove", help="folder with our_vab_data.npy and our_vab_words.pkl|txt (published evaluator)")
    p.add_argument("--dataset", choices=["humanml3d", "kit"], help="default: the bundle's, else humanml3d")
    p.add_argument("--split", default="test")
    p.add_argument("--replications", type=int, default=20)
    p.add_argument("--steps", type=int, default=None, help="default: the bundle's inference config (10)")
    p.add_argument("--sampler", default=None, help="default: the bundle's inference config (dpmpp_2m_sde)")
    p.add_argument("--cfg", type=float, default=None, help="default: the bundle's inference config (2.5)")
    p.add_argument("--footskate", action="store_true",
                   help="generate with foot-skate correction inside denoising (StableMoFusion*) and report the skating ratio")
    p.add_argument("--skate-ratio", action="store_true", help="report the foot-skating ratio (no correction)")
    p.add_argument("--control", default=None,
                   choices=CONTROL_CHOICES,
                   help="joint control (OmniControl / MotionLCM protocol): hints from the test motions at this joint "
                        "('all': the six together; 'keyframes': whole poses); reports Traj./Loc./Avg. err, the "
                        "share of hinted frames with an acceleration spike, foot acceleration and skating")
    p.add_argument("--density", default="100%", help="with --control: share of frames (100%%, 25%%) or a count (5, 2, 1)")
    p.add_argument("--no-control-guidance", dest="control_guidance", action="store_false",
                   help="with --control: no guidance refinement (a ControlNet bundle follows the hints alone)")
    p.add_argument("--multimodality", action="store_true", help="also report MultiModality (100 captions × 30)")
    p.add_argument("--mm-captions", type=int, default=metrics.MM_CAPTIONS)
    p.add_argument("--mm-generations", type=int, default=metrics.MM_GENERATIONS)
    p.add_argument("--aits", type=int, default=10, help="sentences timed one by one for AITS (0: skip)")
    p.add_argument("--batch-size", type=int, default=32, help="generation and embedding batch size")
    p.add_argument("--max-items", type=int, default=None, help="score at most this many items per pass")
    p.add_argument("--feat-bias", type=float, default=5.0, help="feat_bias of the data statistics")
    p.add_argument("--device", default=None)
    p.add_argument("--dtype", choices=["fp32", "bf16", "fp16"], default=None,
                   help="network precision (default: fp32 on the CPU, fp16 on CUDA; fp16 is CUDA-only); "
                        "the solver, guidance and evaluator stay float32")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-kinematics", dest="kinematics", action="store_false",
                   help="leave out the kinematic measures (bone length, floor, stance feet, airborne share)")
    p.add_argument("--out", help="write the results as JSON here")
    p.add_argument("--csv", help="write the results as CSV here (one line per method and metric)")
    p.add_argument("--no-progress", action="store_true")
    return p


def _check_numbers(args) -> None:
    """Numeric flags: finite and in range, before anything is loaded."""
    for flag, value in (("--replications", args.replications), ("--mm-captions", args.mm_captions),
                        ("--mm-generations", args.mm_generations), ("--batch-size", args.batch_size)):
        check_positive_int(flag, value)
    if args.steps is not None:
        check_positive_int("--steps", args.steps)
    if args.max_items is not None:
        check_positive_int("--max-items", args.max_items)
    if args.aits < 0:
        raise StableMoError(f"--aits: must be >= 0, got {args.aits}")
    if args.cfg is not None:
        check_finite("--cfg", args.cfg, low=0.0, high=100.0)
    check_finite("--feat-bias", args.feat_bias, low=0.0, strict=True)
    check_seed("--seed", args.seed)


def _check_precision(args):
    """--dtype against --device, before anything is loaded: fp16 is CUDA-only."""
    if args.dtype is None:
        return None
    if not args.bundle:
        raise StableMoError("--dtype: sets the precision of the generating network; give --bundle")
    from stablemo.checks import resolve_device, resolve_dtype

    try:
        return resolve_dtype(args.dtype, resolve_device(args.device))
    except StableMoError as err:
        raise StableMoError(f"--{err}") from None


def main(argv: list[str]) -> int:
    if "--behaviour" in argv:  # another protocol with its own options: the behaviour command parses them
        from stablemo.cli.behaviour import main as behaviour

        return behaviour([a for a in argv if a != "--behaviour"])
    args = _parser().parse_args(argv)
    _check_numbers(args)
    dtype = _check_precision(args)
    evaluator_path = args.evaluator or default_evaluator(args.data)
    if args.control is not None and not args.bundle:
        raise StableMoError("--control: evaluates a model's joint control; give --bundle")
    from stablemo.io import check_output_file

    for flag, path in (("--out", args.out), ("--csv", args.csv)):
        if path:
            check_output_file(path, flag)
    from stablemo.data import MotionDataset

    torch.manual_seed(args.seed)
    pipe = None
    dataset_name = args.dataset or "humanml3d"
    if args.bundle:
        from stablemo.inference.pipeline import Pipeline

        pipe = Pipeline.from_bundle(args.bundle, device=args.device, dtype=dtype)
        dataset_name = args.dataset or pipe.config.get("dataset", "humanml3d")
    data = MotionDataset.from_folder(args.data, args.split, dataset_name, feat_bias=args.feat_bias, crop="eval",
                                     seed=args.seed, progress=not args.no_progress)
    evaluator = load_text_motion_evaluator(evaluator_path, dataset_name, args.glove)
    if evaluator.feature_dim != data.spec.feature_dim:
        raise StableMoError(f"--evaluator: expects {evaluator.feature_dim}-d features, the data has {data.spec.feature_dim}")

    generate = None
    control = None
    row_name = "model"
    if pipe is not None:
        from stablemo.inference.hooks import make_hooks
        from stablemo.inference.pipeline import Request

        inference = pipe.inference
        steps = args.steps or inference.steps
        cfg = inference.cfg if args.cfg is None else args.cfg
        sampler = args.sampler or inference.sampler
        precision = "" if pipe.dtype == torch.float32 else f", {dtype_name(pipe.dtype)}"
        row_name = f"{Path(args.bundle).name} ({sampler}, {steps} steps, cfg {cfg:g}{precision})"
        if args.footskate:
            row_name += " + footskate"
        if args.control:
            from stablemo.eval.control import ControlProtocol

            control = ControlProtocol(args.control, args.density, pipe.skeleton)
            row_name += f" + control {args.control} {args.density}" + ("" if args.control_guidance else " (no guidance)")
        lo, hi = pipe.min_length, pipe.max_length
        hooks = make_hooks(pipe, footskate=args.footskate)  # StableMoFusion*: correction inside denoising

        def generate(texts, lengths, seeds, controls=None):
            # Evaluation crops can be shorter than the model's minimum: generate at the minimum and
            # keep the first `length` frames (the scored length is always the requested one).
            gen_lengths = [min(max(n, lo), hi) for n in lengths]
            out = pipe.generate(Request(texts, gen_lengths, seed=seeds, sampler=sampler, steps=steps, cfg=cfg,
                                        hooks=hooks, control=controls, control_guidance=args.control_guidance))
            return generation_outputs(out)  # what the user receives and the network's raw output

    result = evaluate(data, evaluator, generate, replications=args.replications, seed=args.seed,
                      batch_size=args.batch_size, max_items=args.max_items,
                      footskate=args.footskate or args.skate_ratio or control is not None,
                      skeleton=data.spec.skeleton, multimodality=args.multimodality, mm_captions=args.mm_captions,
                      mm_generations=args.mm_generations, row_name=row_name, progress=not args.no_progress,
                      control=control, kinematic_measures=args.kinematics)
    aits = None
    if pipe is not None and args.aits > 0:
        rng = np.random.default_rng(args.seed)
        picks = rng.choice(len(data), min(args.aits, len(data)), replace=False)
        items = [data[int(i)] for i in picks]
        sync = torch.cuda.synchronize if pipe.device.type == "cuda" else None
        controls = None
        if control is not None:  # AITS of controlled generation: each sentence with its own motion's hints
            feats = [torch.as_tensor(it["motion"]) * torch.from_numpy(data.std) + torch.from_numpy(data.mean)
                     for it in items]
            controls = dict(zip([it["text"] for it in items], control.hints(feats, rng)))
        generate_one, reset = metrics.pipeline_method(pipe, steps, cfg, sampler, args.seed, controls=controls)
        aits = metrics.average_inference_time(generate_one, [it["text"] for it in items],
                                              [it["length"] for it in items], synchronize=sync, reset=reset)
    result["settings"].update(
        bundle=args.bundle, data=args.data, split=args.split, dataset=dataset_name,
        steps=steps if pipe else None, sampler=sampler if pipe else None, cfg=cfg if pipe else None,
        device=str(pipe.device) if pipe else None, dtype=dtype_name(pipe.dtype) if pipe else None,
        aits_sentences=args.aits if pipe else 0,
    )
    result["aits"] = aits
    print(f"evaluator: {evaluator.name}; split {args.split}, {result['settings']['items']} items, "
          f"{args.replications} replication(s), mean ± 95% interval")
    print(format_table(result, aits))
    from stablemo.io import write_text

    if args.out:
        write_text(args.out, json.dumps(result, indent=2) + "\n")
        print(f"wrote {args.out}")
    if args.csv:
        write_text(args.csv, format_csv(result))
        print(f"wrote {args.csv}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
