"""`stablemo evaluate`: the field's text-to-motion benchmark with 95% intervals over replications.

    stablemo evaluate --bundle DIR --data DIR [--evaluator DIR|CKPT] [--replications 20]
        [--steps 10 --sampler dpmpp_2m_sde --cfg 2.5] [--dtype fp32|bf16|fp16] [--footskate] [--multimodality]
        [--split test --seed 0 --out results.json]

Protocol (facts-humanml3d.md §6–8). Each replication r makes two passes over the split's items with
the evaluation crop rule and one random caption per item (the data set's per-epoch randomness):
pass 2r gives the reference statistics, pass 2r+1 the captions and lengths that are scored. The
"Real motion" row scores pass 2r+1's real motions (so its FID measures crop/caption noise, ≈ 0);
the model row generates one motion per scored caption at that length. Items are shuffled per pass
before forming the R-precision batches of 32. Without --bundle only the real motions are scored
(a check of the evaluator itself).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from tqdm import tqdm

from stablemo.errors import StableMoError
from stablemo.inference.config import check_finite, check_positive_int, check_seed
from stablemo.eval import metrics
from stablemo.skating.metrics import foot_skating_ratio
from stablemo.motion import features_to_joints
from stablemo.eval.text_motion import (  # noqa: F401 (re-exported: the evaluator adapters)
    GuoTextMotionEvaluator,
    OurEvaluator,
    load_text_motion_evaluator,
)

REAL_ROW = "Real motion"
# StableMo's evaluator of the synthetic benchmark, shipped so that `stablemo evaluate` runs out of the
# box (made by scripts/train/make_evaluator_asset.sh: data synth seed 0, configs/evaluator_synth.yaml)
SYNTH_EVALUATOR = Path(__file__).resolve().parents[1] / "assets" / "evaluator_synth"
COLUMNS = [  # (json key, table header, lower/higher/closer-is-better hint only for readers)
    ("r1", "R@1"), ("r2", "R@2"), ("r3", "R@3"), ("fid", "FID"), ("mm_dist", "MM-Dist"),
    ("diversity", "Diversity"), ("multimodality", "MModality"), ("skate_ratio", "Skate"),
    ("foot_acc", "Foot acc."), ("traj_err", "Traj. err"), ("loc_err", "Loc. err"), ("avg_err", "Avg. err"),
    ("spikes", "Spikes"),
]

# generate(texts, lengths, seeds) -> (features (B,T,D) raw, zero-padded; joints (B,T,J,3) or None)
GenerateFn = Callable[[list[str], list[int], list[int]], tuple[torch.Tensor, "torch.Tensor | None"]]


# ----------------------------------------------------------------------------- data passes


@dataclass
class Pass:
    texts: list[str]
    tokens: list[list[str]]
    lengths: list[int]
    features: list[torch.Tensor]  # raw (L_i, D)


def read_pass(dataset, epoch: int, order: np.ndarray) -> Pass:
    items = [dataset[(int(i), epoch)] for i in order]
    mean, std = torch.from_numpy(dataset.mean), torch.from_numpy(dataset.std)
    return Pass(
        texts=[it["text"] for it in items],
        tokens=[list(it["tokens"]) for it in items],
        lengths=[int(it["length"]) for it in items],
        features=[it["motion"] * std + mean for it in items],
    )


def _pad(features: list[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    lengths = torch.tensor([len(f) for f in features])
    out = torch.zeros(len(features), int(lengths.max()), features[0].shape[-1])
    for i, f in enumerate(features):
        out[i, : len(f)] = f
    return out, lengths


def embed_motions(evaluator, features: list[torch.Tensor], batch_size: int) -> np.ndarray:
    """(N, E) embeddings in input order; batches are formed by length so little time goes to padding."""
    order = np.argsort([len(f) for f in features], kind="stable")
    out = np.zeros((len(features), 0))
    for s in range(0, len(features), batch_size):
        idx = order[s : s + batch_size]
        x, lengths = _pad([features[i] for i in idx])
        emb = evaluator.embed_motion(x, lengths)
        if out.shape[1] == 0:
            out = np.zeros((len(features), emb.shape[1]))
        out[idx] = emb
    return out


def embed_texts(evaluator, texts: list[str], tokens: list[list[str]], batch_size: int) -> np.ndarray:
    return np.concatenate([evaluator.embed_text(texts[s : s + batch_size], tokens[s : s + batch_size])
                           for s in range(0, len(texts), batch_size)])


def _control_metrics(joints: list[torch.Tensor], hints: list, reference: list[torch.Tensor]) -> dict[str, float]:
    """Control errors (metres) of generated joints (L_i, J, 3) against their hints, and the share
    of hinted frames with a root/foot acceleration spike above the reference motions' 99th percentile."""
    from stablemo.eval.control import acceleration_spikes, control_errors

    padded, _ = _padded_joints(joints)
    targets, masks = torch.zeros_like(padded), torch.zeros(padded.shape[:3], dtype=torch.bool)
    for i, hint in enumerate(hints):
        n = len(hint.positions)
        targets[i, :n] = torch.as_tensor(np.asarray(hint.positions, np.float32))
        masks[i, :n] = torch.as_tensor(np.asarray(hint.mask))
    errors = control_errors(padded, targets, masks)
    errors["spikes"] = acceleration_spikes(padded, masks, reference)
    return errors


def _padded_joints(joints: list[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    padded, lengths = _pad([j.reshape(len(j), -1) for j in joints])
    return padded.reshape(len(joints), padded.shape[1], -1, 3), lengths


def _skate(joints: list[torch.Tensor]) -> float:
    padded, lengths = _padded_joints(joints)
    return float(foot_skating_ratio(padded, lengths=lengths).mean())


def _foot_acceleration(joints: list[torch.Tensor]) -> float:
    from stablemo.skating.metrics import foot_acceleration

    padded, lengths = _padded_joints(joints)
    return float(foot_acceleration(padded, lengths=lengths).mean())


# ----------------------------------------------------------------------------- protocol


def evaluate(
    dataset,
    evaluator,
    generate: GenerateFn | None = None,
    *,
    replications: int = 20,
    seed: int = 0,
    batch_size: int = 32,
    max_items: int | None = None,
    footskate: bool = False,
    skeleton: str = "humanml3d",
    multimodality: bool = False,
    mm_captions: int = metrics.MM_CAPTIONS,
    mm_generations: int = metrics.MM_GENERATIONS,
    row_name: str = "model",
    progress: bool = True,
    control=None,
) -> dict:
    """Run the benchmark; returns {"rows": {row: {metric: Interval.to_dict()}}, "settings": {...}}.

    control: a `stablemo.eval.control.ControlProtocol`: hints from the scored motions are passed to
    `generate(texts, lengths, seeds, controls=[JointControl, ...])`, and the control errors, the
    feet's acceleration and the skating ratio are reported."""
    if replications < 1:
        raise StableMoError(f"--replications: must be >= 1, got {replications}")
    n_items = len(dataset) if max_items is None else min(len(dataset), int(max_items))
    if n_items < metrics.R_PRECISION_BATCH:
        raise StableMoError(f"data: {n_items} item(s); R-precision needs at least {metrics.R_PRECISION_BATCH}")
    div_pairs = min(metrics.DIVERSITY_PAIRS, n_items - 1)
    joints_of = None
    if footskate:
        from stablemo.motion import get_skeleton

        skel = get_skeleton(skeleton)
        if skel.name != "humanml3d":
            raise StableMoError("--footskate: the skating ratio is defined for the HumanML3D skeleton (metres, y up)")

        def joints_of(feats: list[torch.Tensor]) -> list[torch.Tensor]:
            return [features_to_joints(f[None].float(), skel)[0] for f in feats]

    rows: dict[str, dict[str, list[float]]] = {REAL_ROW: {}}
    if generate is not None:
        rows[row_name] = {}

    def add(row: str, key: str, value: float) -> None:
        rows[row].setdefault(key, []).append(float(value))

    for r in tqdm(range(replications), desc="replications", disable=not progress):
        rng = np.random.default_rng([seed, r])
        ref_order = rng.permutation(len(dataset))[:n_items]
        order = rng.permutation(len(dataset))[:n_items]
        ref = read_pass(dataset, 2 * r, ref_order)
        cur = read_pass(dataset, 2 * r + 1, order)
        ref_stats = metrics.embedding_statistics(embed_motions(evaluator, ref.features, batch_size))
        text_emb = embed_texts(evaluator, cur.texts, cur.tokens, batch_size)

        candidates = [(REAL_ROW, cur.features, None)]
        if generate is not None:
            gen_feats, gen_joints, hints = [], [], []
            for s in range(0, n_items, batch_size):
                sl = slice(s, s + batch_size)
                seeds = [int(x) for x in rng.integers(0, 2**31 - 1, size=len(cur.texts[sl]))]
                if control is not None:
                    batch_hints = control.hints(cur.features[sl], rng)
                    hints += batch_hints
                    feats, joints = generate(cur.texts[sl], cur.lengths[sl], seeds, controls=batch_hints)
                else:
                    feats, joints = generate(cur.texts[sl], cur.lengths[sl], seeds)
                gen_feats += [feats[i, :n].float().cpu() for i, n in enumerate(cur.lengths[sl])]
                if joints is not None:
                    gen_joints += [joints[i, :n].float().cpu() for i, n in enumerate(cur.lengths[sl])]
            candidates.append((row_name, gen_feats, gen_joints or None))
            if control is not None:
                real_joints = [features_to_joints(f[None].float(), control.skeleton)[0] for f in cur.features]
                for key, value in _control_metrics(gen_joints, hints, real_joints).items():
                    add(row_name, key, value)

        for row, feats, joints in candidates:
            emb = embed_motions(evaluator, feats, batch_size)
            match = metrics.r_precision(text_emb, emb)
            for k in range(3):
                add(row, f"r{k + 1}", match.r_precision[k])
            add(row, "mm_dist", match.mm_dist)
            add(row, "fid", metrics.frechet_distance(*metrics.embedding_statistics(emb), *ref_stats))
            add(row, "diversity", metrics.diversity(emb, rng, div_pairs))
            if joints_of is not None:
                row_joints = joints if joints is not None else joints_of(feats)
                add(row, "skate_ratio", _skate(row_joints))
                if control is not None:  # the data's own jitter beside the controlled model's
                    add(row, "foot_acc", _foot_acceleration(row_joints))

        if generate is not None and multimodality:
            picks = rng.choice(n_items, min(mm_captions, n_items), replace=False)
            mm_emb = []
            for i in picks:
                seeds = [int(x) for x in rng.integers(0, 2**31 - 1, size=mm_generations)]
                feats, _ = generate([cur.texts[i]] * mm_generations, [cur.lengths[i]] * mm_generations, seeds)
                mm_emb.append(embed_motions(evaluator, [f[: cur.lengths[i]].float().cpu() for f in feats], batch_size))
            add(row_name, "multimodality", metrics.multimodality(np.stack(mm_emb), rng))

    result_rows = {row: {k: metrics.replication_interval(v).to_dict() for k, v in cols.items()}
                   for row, cols in rows.items()}
    settings = {"replications": replications, "seed": seed, "items": n_items, "diversity_pairs": div_pairs,
                "r_precision_batch": metrics.R_PRECISION_BATCH, "evaluator": getattr(evaluator, "name", "")}
    if multimodality:
        settings.update(mm_captions=mm_captions, mm_generations=mm_generations)
    return {"rows": result_rows, "settings": settings}


def format_table(result: dict, aits: float | None = None) -> str:
    """The paper's table layout: one row per method, mean±interval per metric."""
    present = [(k, h) for k, h in COLUMNS if any(k in row for row in result["rows"].values())]
    header = ["Method"] + [h for _, h in present] + (["AITS (s)"] if aits is not None else [])
    lines = []
    for name, row in result["rows"].items():
        cells = [name] + [f"{row[k]['mean']:.3f}±{row[k]['conf95']:.3f}" if k in row else "-" for k, _ in present]
        if aits is not None:
            cells.append(f"{aits:.3f}" if name != REAL_ROW else "-")
        lines.append(cells)
    widths = [max(len(str(c)) for c in col) for col in zip(header, *lines)]
    fmt = lambda cells: "  ".join(str(c).ljust(w) for c, w in zip(cells, widths))  # noqa: E731
    return "\n".join([fmt(header), fmt(["-" * w for w in widths])] + [fmt(c) for c in lines])


# ----------------------------------------------------------------------------- CLI


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="stablemo evaluate", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
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
                   choices=["pelvis", "left_foot", "right_foot", "head", "left_wrist", "right_wrist", "all", "keyframes"],
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
    p.add_argument("--out", help="write the results as JSON here")
    p.add_argument("--no-progress", action="store_true")
    return p


def dtype_name(dtype: torch.dtype) -> str:
    """torch.bfloat16 -> "bf16" (the --dtype spelling)."""
    return {torch.float32: "fp32", torch.bfloat16: "bf16", torch.float16: "fp16"}.get(dtype, str(dtype))


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


def default_evaluator(data: str | Path) -> Path:
    """The packaged synthetic-benchmark evaluator, for data written by `stablemo data synth` only:
    scoring HumanML3D or KIT with it would print numbers no one else can compare with."""
    from stablemo.data.synth.writer import MARKER

    if not (Path(data) / MARKER).is_file():
        raise StableMoError(f"--evaluator: required for {data} (not the synthetic benchmark: no {MARKER}); give "
                            "the published Guo et al. evaluator folder (see docs/evaluation.md) or a StableMo one")
    if not (SYNTH_EVALUATOR / "config.json").is_file():
        raise StableMoError(f"--evaluator: the packaged evaluator {SYNTH_EVALUATOR} is missing (a broken install?); "
                            "pass one explicitly")
    return SYNTH_EVALUATOR


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
    args = _parser().parse_args(argv)
    _check_numbers(args)
    dtype = _check_precision(args)
    evaluator_path = args.evaluator or default_evaluator(args.data)
    if args.control is not None and not args.bundle:
        raise StableMoError("--control: evaluates a model's joint control; give --bundle")
    if args.out:
        from stablemo.io import check_output_file

        check_output_file(args.out, "--out")
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
            return out.features, out.joints

    result = evaluate(data, evaluator, generate, replications=args.replications, seed=args.seed,
                      batch_size=args.batch_size, max_items=args.max_items,
                      footskate=args.footskate or args.skate_ratio or control is not None,
                      skeleton=data.spec.skeleton, multimodality=args.multimodality, mm_captions=args.mm_captions,
                      mm_generations=args.mm_generations, row_name=row_name, progress=not args.no_progress,
                      control=control)
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
    if args.out:
        from stablemo.io import write_text

        write_text(args.out, json.dumps(result, indent=2) + "\n")
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
