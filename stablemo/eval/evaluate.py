"""The benchmark behind `stablemo evaluate` (stablemo.cli.evaluate states the protocol): reference and
scored passes per replication, FID, R-precision, MM-Dist, Diversity, MModality, control and foot metrics,
and the kinematic measures (stablemo.eval.kinematics) of every row: the real motions, the network's raw
output and what the user receives."""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from tqdm import tqdm

from stablemo.errors import StableMoError
from stablemo.eval import kinematics, metrics
from stablemo.eval.text_motion import (  # noqa: F401 (re-exported: the evaluator adapters)
    GuoTextMotionEvaluator,
    OurEvaluator,
    load_text_motion_evaluator,
)
from stablemo.inference.bundle import EVALUATOR_SYNTH
from stablemo.motion import features_to_joints, get_skeleton
from stablemo.skating.metrics import foot_skating_ratio

REAL_ROW = "Real motion"
# StableMo's evaluator of the synthetic benchmark, shipped so that `stablemo evaluate` runs out of the
# box (made by scripts/train/make_evaluator_asset.sh: data synth seed 0, configs/evaluator_synth.yaml)
SYNTH_EVALUATOR = EVALUATOR_SYNTH
COLUMNS = [  # (json key, table header, lower/higher/closer-is-better hint only for readers)
    ("r1", "R@1"), ("r2", "R@2"), ("r3", "R@3"), ("fid", "FID"), ("mm_dist", "MM-Dist"),
    ("diversity", "Diversity"), ("multimodality", "MModality"), ("skate_ratio", "Skate"),
    ("foot_acc", "Foot acc."), ("traj_err", "Traj. err"), ("loc_err", "Loc. err"), ("avg_err", "Avg. err"),
    ("spikes", "Spikes"), ("facing_deg", "Facing err °"), ("unasked_backward", "Backward"),
    ("unasked_sideways", "Sideways"),
    # kinematics.MEASURES (foot_acc above): units in the headers, definitions in docs/evaluation.md
    ("bone_change", "Bone Δ cm"), ("floor_p1", "Floor p1 cm"), ("below_floor", "Below floor"),
    ("stance_height", "Stance h cm"), ("stance_speed", "Stance v cm/s"), ("airborne", "Airborne"),
]
RAW_SUFFIX = " [raw]"  # the row of the network's output before the finishing step (rigid body, floor)

# generate(texts, lengths, seeds) -> (features (B,T,D) de-normalised, zero-padded; joints (B,T,J,3) or
# None): what the user receives; or the 4-tuple (features, joints, raw_features, raw_joints) adding the
# network's output before the finishing step, scored as its own row (row name + RAW_SUFFIX)
GenerateFn = Callable[[list[str], list[int], list[int]], tuple]


def generation_outputs(gen) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """(features, joints, raw_features, raw_joints) of a Pipeline Generation; the raw pair is the
    final one where the generation holds no separate raw output (finish=False, or a pipeline from
    before the finishing step)."""
    raw_features, raw_joints = getattr(gen, "raw_features", None), getattr(gen, "raw_joints", None)
    return (gen.features, gen.joints, gen.features if raw_features is None else raw_features,
            gen.joints if raw_joints is None else raw_joints)


def _outputs(out) -> tuple:
    """A generate function's answer -> (features, joints, raw_features, raw_joints), raw None if absent."""
    if isinstance(out, tuple) and len(out) == 2:
        return (*out, None, None)
    if isinstance(out, tuple) and len(out) == 4:
        return out
    raise StableMoError("generate: expected (features, joints) or (features, joints, raw_features, raw_joints), "
                        f"got {type(out).__name__}{f' of {len(out)}' if isinstance(out, tuple) else ''}")


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


def _control_metrics(joints: list[torch.Tensor], hints: list, reference: list[torch.Tensor],
                     skeleton="humanml3d") -> dict[str, float]:
    """Control errors (metres) of generated joints (L_i, J, 3) against their hints, the share
    of hinted frames with a root/foot acceleration spike above the reference motions' 99th
    percentile, and where the body faces against where it travels (stablemo.eval.heading): the
    mean over motions of the median difference (degrees) between its facing-vs-travel angle and the
    hinted motion's (`reference`, the same items: the path is walked as that motion walked it), and
    the shares of moving frames walked backwards / sideways where the hinted motion walks forward
    there: not asked for."""
    from stablemo.eval.control import acceleration_spikes, control_errors
    from stablemo.eval.heading import facing_error, heading_measures

    padded, _ = _padded_joints(joints)
    targets, masks = torch.zeros_like(padded), torch.zeros(padded.shape[:3], dtype=torch.bool)
    for i, hint in enumerate(hints):
        n = len(hint.positions)
        targets[i, :n] = torch.as_tensor(np.asarray(hint.positions, np.float32))
        masks[i, :n] = torch.as_tensor(np.asarray(hint.mask))
    errors = control_errors(padded, targets, masks)
    errors["spikes"] = acceleration_spikes(padded, masks, reference, skeleton)
    lengths = torch.tensor([min(len(j), len(r)) for j, r in zip(joints, reference)])
    ref, _ = _padded_joints([r[:n] for r, n in zip(reference, lengths)])
    gen, _ = _padded_joints([j[:n] for j, n in zip(joints, lengths)])
    unasked = heading_measures(gen, lengths, skeleton, reference=ref)
    with np.errstate(all="ignore"):  # a batch where nothing moves: NaN, not a warning
        errors["facing_deg"] = float(np.nanmean(facing_error(gen, ref, lengths, skeleton)))
        errors["unasked_backward"] = float(np.nanmean(unasked["backward"]))
        errors["unasked_sideways"] = float(np.nanmean(unasked["sideways"]))
    return errors


def _padded_joints(joints: list[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    padded, lengths = _pad([j.reshape(len(j), -1) for j in joints])
    return padded.reshape(len(joints), padded.shape[1], -1, 3), lengths


def _skate(joints: list[torch.Tensor]) -> float:
    padded, lengths = _padded_joints(joints)
    return float(foot_skating_ratio(padded, lengths=lengths).mean())


def _kinematics(joints: list[torch.Tensor], skeleton, chunk: int = 256) -> dict[str, float]:
    """kinematics.MEASURES of motions (L_i, J, 3), each averaged over the motions where it is defined;
    measured `chunk` motions at a time (float64 copies of a whole HumanML3D test pass run to GBs)."""
    parts = []
    for s in range(0, len(joints), chunk):
        padded, lengths = _padded_joints(joints[s : s + chunk])
        parts.append(kinematics.measure(padded, lengths, skeleton))
    return kinematics.summarise({k: np.concatenate([p[k] for p in parts]) for k in parts[0]})


def _joints_of(features: list[torch.Tensor], skeleton) -> list[torch.Tensor]:
    """Joints (L_i, J, 3) of de-normalised features (L_i, D), recovered in one padded batch (the
    root's integration is causal: padding never reaches a valid frame)."""
    padded, lengths = _pad([f.float() for f in features])
    joints = features_to_joints(padded, skeleton)
    return [joints[i, :n] for i, n in enumerate(lengths.tolist())]


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
    kinematic_measures: bool = True,
) -> dict:
    """Run the benchmark; returns {"rows": {row: {metric: Interval.to_dict()}}, "settings": {...}}.

    Rows: the real motions, `row_name` (what generate returns to the user) and, when generate also
    returns the network's raw output, `row_name + RAW_SUFFIX` (every metric of it, MultiModality aside).
    kinematic_measures: the kinematic measures (stablemo.eval.kinematics) of every row.
    control: a `stablemo.eval.control.ControlProtocol`: hints from the scored motions are passed to
    `generate(texts, lengths, seeds, controls=[JointControl, ...])`, and the control errors, the
    feet's acceleration and the skating ratio are reported."""
    if replications < 1:
        raise StableMoError(f"--replications: must be >= 1, got {replications}")
    n_items = len(dataset) if max_items is None else min(len(dataset), int(max_items))
    if n_items < metrics.R_PRECISION_BATCH:
        raise StableMoError(f"data: {n_items} item(s); R-precision needs at least {metrics.R_PRECISION_BATCH}")
    div_pairs = min(metrics.DIVERSITY_PAIRS, n_items - 1)
    skel = get_skeleton(skeleton)
    if footskate and skel.name != "humanml3d":
        raise StableMoError("--footskate: the skating ratio is defined for the HumanML3D skeleton (metres, y up)")
    kinematic_measures = kinematic_measures or control is not None  # control reports the feet's acceleration
    raw_row = row_name + RAW_SUFFIX

    rows: dict[str, dict[str, list[float]]] = {REAL_ROW: {}}

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
            gen_feats, gen_joints, raw_feats, raw_joints, hints = [], [], [], [], []

            def keep(out: list, batch, lengths: list[int]) -> None:
                if batch is not None:
                    out += [batch[i, :n].float().cpu() for i, n in enumerate(lengths)]

            for s in range(0, n_items, batch_size):
                sl = slice(s, s + batch_size)
                seeds = [int(x) for x in rng.integers(0, 2**31 - 1, size=len(cur.texts[sl]))]
                if control is not None:
                    batch_hints = control.hints(cur.features[sl], rng)
                    hints += batch_hints
                    out = generate(cur.texts[sl], cur.lengths[sl], seeds, controls=batch_hints)
                else:
                    out = generate(cur.texts[sl], cur.lengths[sl], seeds)
                feats, joints, feats_raw, joints_raw = _outputs(out)
                for store, batch in ((gen_feats, feats), (gen_joints, joints), (raw_feats, feats_raw),
                                     (raw_joints, joints_raw)):
                    keep(store, batch, cur.lengths[sl])
            candidates.append((row_name, gen_feats, gen_joints or None))
            if raw_feats:  # after the final row, which readers look up by its name first
                candidates.append((raw_row, raw_feats, raw_joints or None))
            for row, _, _ in candidates:
                rows.setdefault(row, {})
            if control is not None:
                real_joints = [features_to_joints(f[None].float(), control.skeleton)[0] for f in cur.features]
                for row, feats, joints in candidates[1:]:  # does the finishing step move the hinted joints?
                    row_joints = joints if joints is not None else _joints_of(feats, skel)
                    for key, value in _control_metrics(row_joints, hints, real_joints, skel).items():
                        add(row, key, value)

        for row, feats, joints in candidates:
            emb = embed_motions(evaluator, feats, batch_size)
            match = metrics.r_precision(text_emb, emb)
            for k in range(3):
                add(row, f"r{k + 1}", match.r_precision[k])
            add(row, "mm_dist", match.mm_dist)
            add(row, "fid", metrics.frechet_distance(*metrics.embedding_statistics(emb), *ref_stats))
            add(row, "diversity", metrics.diversity(emb, rng, div_pairs))
            if footskate or kinematic_measures:
                row_joints = joints if joints is not None else _joints_of(feats, skel)
                if footskate:
                    add(row, "skate_ratio", _skate(row_joints))
                if kinematic_measures:  # the real row gives the data's own values (and jitter) beside the model's
                    for key, value in _kinematics(row_joints, skel).items():
                        add(row, key, value)

        if generate is not None and multimodality:
            picks = rng.choice(n_items, min(mm_captions, n_items), replace=False)
            mm_emb = []
            for i in picks:
                seeds = [int(x) for x in rng.integers(0, 2**31 - 1, size=mm_generations)]
                feats = _outputs(generate([cur.texts[i]] * mm_generations, [cur.lengths[i]] * mm_generations, seeds))[0]
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


def format_csv(result: dict) -> str:
    """One line per (row, metric): method, metric, mean, conf95, replications (spreadsheet input)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["method", "metric", "mean", "conf95", "replications"])
    for name, row in result["rows"].items():
        for key, cell in row.items():
            writer.writerow([name, key, repr(cell["mean"]), repr(cell["conf95"]), len(cell["values"])])
    return out.getvalue()


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


