"""Issue #39's targets on the demo models: the network's raw output against what the user receives.

Prompts come from the synthetic vocabulary (stablemo.data.synth: its actions, parameters and caption
paraphrases), `per_category` per category of CATEGORIES, each generated with `seeds` seeds in one
Pipeline.generate call per model and length. Every motion is measured twice from the same generation,
raw (the network's output) and final (after the finishing step: the rigid body on the floor), with
stablemo.eval.kinematics; the final rows add how far the end effectors moved raw -> final. FID and
R@3 come from the packaged synthetic evaluator: R@3 over batches of 32 distinct prompts, FID against
synthetic ground-truth clips of the same actions (each prompt's own plan and `seeds - 1` more drawn
for its action, at their natural lengths), so it compares raw with final rather than with a paper.
The script is scripts/results/kinematic_report.py.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from stablemo.errors import StableMoError
from stablemo.eval import kinematics, metrics
from stablemo.eval.evaluate import embed_motions, embed_texts, generation_outputs
from stablemo.inference.bundle import DEMO_BUNDLE, DEMO_STUDENT

# docs/results.md's section on these measures (scripts/results/make_results.py renders it before the
# joint-control sections); the table of this report joins it once the finishing step has landed
RESULTS_SECTION = """
## Kinematic measures: a rigid body on the floor

FID and R-precision do not see whether a generated motion keeps one rigid body standing on the floor.
`stablemo evaluate` reports beside them, for the real motions, for the network's raw output (rows
marked `[raw]`) and for what the user receives (after the finishing step: the rigid body on the floor):
bone-length change within a motion (cm), the lowest foot joint's 1st-percentile height and the share
of frames more than 1 cm below the floor, the stance foot's median height (cm) and horizontal speed
(cm/s, skating), foot acceleration (m/s²) and the share of airborne frames. Definitions, the contact
rule and the values measured on ground-truth motions: docs/evaluation.md ("Kinematic measures").
`python scripts/results/kinematic_report.py --summary docs/data/results/kinematics.json` measures
the kinematic targets on the demo teacher and the 1-step student (72 prompts x 4 seeds, 120 and 196
frames, raw against final) and keeps the table below. Its FID and R@3 columns are one draw of 288
motions; the step's change of them measured pair by pair on 864 others: docs/inference.md ("The
finishing step: one rigid body on the floor").
"""
SUMMARY_FILE = Path(__file__).resolve().parents[2] / "docs" / "data" / "results" / "kinematics.json"


def compact(result: dict) -> dict:
    """The table's numbers and the settings of a `run` result, without the per-motion values."""
    rows = [{k: r[k] for k in ("model", "frames", "output", "seconds", "summary")} for r in result["rows"]]
    return {"rows": rows, "settings": result["settings"]}


def results_section(path: Path = SUMMARY_FILE) -> str:
    """The section of docs/results.md: the text, and the table of the last kept summary if there is one."""
    if not path.is_file():
        return RESULTS_SECTION
    data = json.loads(path.read_text())
    s = data.get("settings", {})
    note = (f"\n{s.get('prompts', '?')} prompts x {s.get('seeds', '?')} seeds per row, each model's own sampler; "
            f"measured {s.get('measured', '?')} ({s.get('threads', '?')} threads).\n\n")
    return RESULTS_SECTION + note + render(data["rows"]) + "\n"

# category -> the synthetic actions its prompts describe
CATEGORIES = {
    "walk": ("walk", "walk_backward"), "run": ("run", "jog"), "jump": ("jump", "jump_forward", "hop"),
    "turn": ("turn",), "wave": ("wave",), "kick": ("kick",), "squat": ("squat",),
    "side step": ("walk_sideways",), "stand": ("stand",),
}
# the shipped demo models by the name scripts take them under: (table label, bundle)
DEMO_MODELS = {"teacher": ("Teacher (demo bundle)", DEMO_BUNDLE), "student": ("1-step student", DEMO_STUDENT)}
STANCE_CATEGORIES = ("stand", "walk")  # where the feet should rest on the floor most of the time
JUMP_CATEGORIES = ("jump",)  # where they must leave it
MIN_PROMPTS = 64


def parse_frames(text: str, flag: str = "--frames") -> list[int]:
    """Comma-separated motion lengths in frames -> [int], else one line naming the flag."""
    try:
        return [int(x) for x in text.split(",")]
    except ValueError:
        raise StableMoError(f"{flag}: expected comma-separated whole numbers, got {text!r}") from None


def check_prompts(per_category: int) -> int:
    """At least MIN_PROMPTS prompts in all, else one line naming the flag."""
    if per_category * len(CATEGORIES) < MIN_PROMPTS:
        raise StableMoError(f"--prompts-per-category: {per_category} x {len(CATEGORIES)} categories is fewer than "
                            f"the {MIN_PROMPTS} prompts the report stands on")
    return per_category


@dataclass(frozen=True)
class Prompt:
    category: str
    action: str
    params: dict
    text: str


def prompts(per_category: int = 8, seed: int = 0) -> list[Prompt]:
    """`per_category` distinct captions per category, parameters drawn by the synthetic generator."""
    from stablemo.data.synth import actions, captions

    rng = np.random.default_rng(seed)
    out: list[Prompt] = []
    for category, names in CATEGORIES.items():
        seen: set[str] = set()
        for tries in range(200 * per_category):
            if len(seen) == per_category:
                break
            action = names[tries % len(names)]
            params = actions.sample_params(action, rng)
            text = captions.part_caption(action, params, rng)
            if text not in seen:
                seen.add(text)
                out.append(Prompt(category, action, params, text))
        if len(seen) < per_category:
            raise StableMoError(f"--prompts-per-category: the vocabulary of {category!r} has fewer than "
                                f"{per_category} captions")
    return out


def reference_features(items: list[Prompt], per_prompt: int, seed: int = 0) -> list[torch.Tensor]:
    """Synthetic ground truth of the prompts' actions: each prompt's own plan and per_prompt - 1 more
    drawn for its action; (L_i, 263) de-normalised features at natural lengths."""
    from stablemo.data.synth import actions
    from stablemo.data.synth.compose import build
    from stablemo.motion import joints_to_features

    rng = np.random.default_rng([seed, 1])
    out = []
    for p in items:
        plans = [p.params] + [actions.sample_params(p.action, rng) for _ in range(per_prompt - 1)]
        for params in plans:
            joints = build([(p.action, params)]).joints
            out.append(torch.from_numpy(joints_to_features(joints, "humanml3d")).float())
    return out


def reference_statistics(evaluator, items: list[Prompt], per_prompt: int, seed: int = 0):
    """The evaluator's embedding statistics of reference_features(items, per_prompt, seed): what FID
    compares with."""
    return metrics.embedding_statistics(embed_motions(evaluator, reference_features(items, per_prompt, seed), 64))


def fid_r3(evaluator, features, text_emb, reference_stats) -> tuple[float, float]:
    """FID against reference_stats and R@3 against the texts' embeddings text_emb (in the features'
    order: seed-major, so each batch of 32 holds distinct prompts) of features, (B, T, D) or a list."""
    emb = embed_motions(evaluator, [x.float().cpu() for x in features], 64)
    return (metrics.frechet_distance(*metrics.embedding_statistics(emb), *reference_stats),
            float(metrics.r_precision(text_emb, emb).r_precision[2]))


def score(pipe, items: list[Prompt], seeds: int, frames: int, evaluator, reference_stats) -> dict:
    """One model at one length: {"raw": {...}, "final": {...}, "seconds": s} with per-motion measures,
    displacement groups (final), FID and R@3 (when an evaluator is given)."""
    texts = [p.text for _ in range(seeds) for p in items]  # seed-major: each batch of 32 holds distinct prompts
    seed_list = [s for s in range(seeds) for _ in items]
    start = time.perf_counter()
    gen = pipe.generate(texts, [frames] * len(texts), seed=seed_list)
    seconds = time.perf_counter() - start
    features, joints, raw_features, raw_joints = generation_outputs(gen)
    lengths = [frames] * len(texts)
    out = {"seconds": seconds, "categories": [p.category for _ in range(seeds) for p in items]}
    text_emb = None
    if evaluator is not None:  # no word/POS tokens: our evaluator reads the text, Guo et al.'s tags it itself
        text_emb = embed_texts(evaluator, texts, [[] for _ in texts], 64)
    for name, f, j in (("raw", raw_features, raw_joints), ("final", features, joints)):
        row = {k: v.tolist() for k, v in kinematics.measure(j, lengths, pipe.skeleton).items()}
        if evaluator is not None:
            row["fid"], row["r3"] = fid_r3(evaluator, f, text_emb, reference_stats)
        out[name] = row
    for part, ids in kinematics.end_effector_groups(pipe.skeleton).items():
        out["final"][f"moved_{part}"] = kinematics.displacement(raw_joints, joints, lengths, pipe.skeleton,
                                                                ids).tolist()
    return out


# ----------------------------------------------------------------------------- the table


def _select(values, categories, keep) -> np.ndarray:
    v = np.asarray(values, np.float64)
    return v[[c in keep for c in categories]] if keep else v


def _stat(values, how: str) -> float:
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return float("nan")
    return float({"max": np.max, "median": np.median, "mean": np.mean, "min": np.min}[how](v))


def summary(result: dict) -> dict[str, float]:
    """The table's numbers of one scored row (result["raw"] or result["final"] with its categories)."""
    row, cats = result["row"], result["categories"]
    out = {
        "bone_change_max": _stat(row["bone_change"], "max"),
        "bone_change_median": _stat(row["bone_change"], "median"),
        "floor_p1_mean": _stat(row["floor_p1"], "mean"),
        "floor_p1_worst": _stat(row["floor_p1"], "min"),
        "below_floor": _stat(row["below_floor"], "mean"),
        "stance_height_median": _stat(_select(row["stance_height"], cats, STANCE_CATEGORIES), "median"),
        "stance_speed": _stat(row["stance_speed"], "mean"),
        "airborne_jump": _stat(_select(row["airborne"], cats, JUMP_CATEGORIES), "mean"),
        "airborne_stance": _stat(_select(row["airborne"], cats, STANCE_CATEGORIES), "mean"),
        "foot_acc": _stat(row["foot_acc"], "mean"),
    }
    for key in ("moved_feet", "moved_hands", "moved_head"):
        if key in row:
            out[key] = _stat(row[key], "mean")
    for key in ("fid", "r3"):
        if key in row:
            out[key] = row[key]
    return out


TABLE = [  # (summary key, header, format)
    ("bone_change_max", "Bone Δ max (cm)", "{:.2f}"), ("bone_change_median", "Bone Δ median (cm)", "{:.2f}"),
    ("floor_p1_mean", "Lowest foot p1 (cm), mean", "{:+.2f}"), ("floor_p1_worst", "worst", "{:+.2f}"),
    ("below_floor", "Frames < −1 cm", "{:.1%}"),
    ("stance_height_median", "Stance foot height, stand/walk (cm)", "{:+.2f}"),
    ("stance_speed", "Stance foot speed (cm/s)", "{:.1f}"), ("foot_acc", "Foot acc. (m/s²)", "{:.2f}"),
    ("airborne_jump", "Airborne, jumps", "{:.1%}"), ("airborne_stance", "Airborne, stand/walk", "{:.1%}"),
    ("moved_feet", "Moved raw→final: feet (cm)", "{:.2f}"), ("moved_hands", "hands (cm)", "{:.2f}"),
    ("moved_head", "head (cm)", "{:.2f}"), ("fid", "FID vs synth GT", "{:.3f}"), ("r3", "R@3", "{:.3f}"),
]


def render(results: list[dict]) -> str:
    """results: [{"model", "frames", "output", "summary"}] -> one markdown table, a row each."""
    keys = [(k, h, f) for k, h, f in TABLE if any(k in r["summary"] for r in results)]
    lines = ["| Model | Frames | Output | " + " | ".join(h for _, h, _ in keys) + " |",
             "|---|---|---|" + "---|" * len(keys)]
    for r in results:
        cells = []
        for key, _, fmt in keys:
            value = r["summary"].get(key)
            cells.append("–" if value is None or not np.isfinite(value) else fmt.format(value))
        lines.append(f"| {r['model']} | {r['frames']} | {r['output']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def run(models: list[tuple[str, object]], frames: list[int], per_category: int = 8, seeds: int = 4,
        evaluator=None, seed: int = 0, log=print) -> dict:
    """Score every (model name, Pipeline) at every length; returns {"rows": [...], "settings": {...}}."""
    check_prompts(per_category)
    items = prompts(per_category, seed)
    reference_stats = None
    if evaluator is not None:
        reference_stats = reference_statistics(evaluator, items, seeds, seed)
    rows = []
    for name, pipe in models:
        for n in frames:
            log(f"== {name}, {len(items)} prompts x {seeds} seeds, {n} frames")
            result = score(pipe, items, seeds, n, evaluator, reference_stats)
            log(f"   generated in {result['seconds']:.1f} s")
            for output in ("raw", "final"):
                rows.append({"model": name, "frames": n, "output": output, "seconds": result["seconds"],
                             "summary": summary({"row": result[output], "categories": result["categories"]}),
                             "per_motion": result[output]})
    # each model's sampler, steps and guidance: a row names its model by label only, and a student's
    # bundle may default to any number of steps
    sampling = {name: {k: getattr(pipe.inference, k) for k in ("sampler", "steps", "cfg")} for name, pipe in models}
    settings = {"prompts": len(items), "per_category": per_category, "seeds": seeds, "frames": frames,
                "categories": {k: list(v) for k, v in CATEGORIES.items()}, "texts": [p.text for p in items],
                "evaluator": getattr(evaluator, "name", None), "sampling": sampling}
    return {"rows": rows, "settings": settings}
