"""The benchmark behind `stablemo evaluate` (stablemo.cli.evaluate states the protocol): reference and
scored passes per replication, FID, R-precision, MM-Dist, Diversity, MModality, control and foot metrics."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from tqdm import tqdm

from stablemo.errors import StableMoError
from stablemo.eval import metrics
from stablemo.eval.text_motion import (  # noqa: F401 (re-exported: the evaluator adapters)
    GuoTextMotionEvaluator,
    OurEvaluator,
    load_text_motion_evaluator,
)
from stablemo.inference.bundle import EVALUATOR_SYNTH
from stablemo.motion import features_to_joints
from stablemo.skating.metrics import foot_skating_ratio

REAL_ROW = "Real motion"
# StableMo's evaluator of the synthetic benchmark, shipped so that `stablemo evaluate` runs out of the
# box (made by scripts/train/make_evaluator_asset.sh: data synth seed 0, configs/evaluator_synth.yaml)
SYNTH_EVALUATOR = EVALUATOR_SYNTH
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


def dtype_name(dtype: torch.dtype) -> str:
    """torch.bfloat16 -> "bf16" (the --dtype spelling)."""
    return {torch.float32: "fp32", torch.bfloat16: "bf16", torch.float16: "fp16"}.get(dtype, str(dtype))


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


