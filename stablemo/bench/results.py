"""The results report of scripts/results/make_results.py (docs/results.md): its rows, how they are
scored, their checksums and the tables rendered from them. Library functions only: the script parses
the options (then apply_defaults and check_args here), makes the data and students it needs, measures
the paper UNet's AITS and renders the joint-control sections.

Every row is scored by the same evaluator on the same test split with the same replication seeds
(so rows are paired replication by replication); a row is kept by `--resume` only while its key
(Context.key: checksums of data, bundle and evaluator, sampler, steps, precision, replications,
items, seed) is unchanged.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stablemo.errors import StableMoError
from stablemo.eval import metrics
from stablemo.eval.evaluate import REAL_ROW, evaluate, load_text_motion_evaluator
from stablemo.io import check_output_file

COLUMNS = [("r1", "R@1 ↑"), ("r3", "R@3 ↑"), ("fid", "FID ↓"), ("mm_dist", "MM-Dist ↓"), ("diversity", "Diversity →")]
TEACHER_ROW = "Teacher, SDE-DPM-Solver++ 2M, 10 steps"
# the precision table's targets: low-precision FID <= 1.02x fp32, R@3 within 0.01
FID_RATIO_TARGET, R3_TARGET = 1.02, 0.01
FULL = {"replications": 20, "max_items": 128, "aits_sentences": 20, "ddpm_replications": 1, "paper_aits_repeats": 3}
QUICK = {"replications": 2, "max_items": 64, "aits_sentences": 4, "ddpm_replications": 0, "paper_aits_repeats": 0}


# ----------------------------------------------------------------------------- provenance


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def folder_checksums(folder: str | Path) -> dict[str, str]:
    """sha256 of each top-level file, of each subfolder (over its files' relative paths and sha256
    in sorted order) and of the whole folder ("*"): short enough to print, fine enough to say which
    part differs when a regenerated folder does not match."""
    folder = Path(folder)
    # hidden entries are not data: the loader's memory-mapped cache (.stablemo_cache/) appears at first use
    files = sorted(p for p in folder.rglob("*")
                   if p.is_file() and not any(part.startswith(".") for part in p.relative_to(folder).parts))
    lines = {p.relative_to(folder).as_posix(): sha256_file(p) for p in files}
    groups: dict[str, list[str]] = {}
    out: dict[str, str] = {}
    for rel, digest in lines.items():
        head, _, rest = rel.partition("/")
        if rest:
            groups.setdefault(head + "/", []).append(f"{rel} {digest}\n")
        else:
            out[rel] = digest
    for name, entries in groups.items():
        out[name] = hashlib.sha256("".join(entries).encode()).hexdigest()
    out["*"] = hashlib.sha256("".join(f"{r} {d}\n" for r, d in lines.items()).encode()).hexdigest()
    return dict(sorted(out.items()))


# ----------------------------------------------------------------------------- options


def apply_defaults(args):
    """Fill the options left unset (None) of make_results' parsed `args` with the defaults of a full
    run (FULL) or of `--quick` (QUICK); `--quick` also means no distillation and writes
    outputs/results_quick.md. --json defaults to docs/data/results/results.json for
    docs/results.md, else to --out with the suffix .json. Returns `args`."""
    for k, v in (QUICK if args.quick else FULL).items():
        if getattr(args, k) is None:
            setattr(args, k, v)
    args.no_distill = args.no_distill or args.quick
    args.out = args.out or ("outputs/results_quick.md" if args.quick else "docs/results.md")
    if args.json is None:
        args.json = ("docs/data/results/results.json" if Path(args.out) == Path("docs/results.md")
                     else str(Path(args.out).with_suffix(".json")))
    return args


def check_args(args) -> None:
    """Every argument checked before any compute (one line naming it)."""
    from stablemo.checks import check_finite, check_positive_int, check_seed, resolve_device, resolve_dtype

    for flag in ("replications", "max_items", "ddpm_items", "aits_sentences"):
        check_positive_int(f"--{flag.replace('_', '-')}", getattr(args, flag))
    for flag in ("ddpm_replications", "paper_aits_repeats"):
        if getattr(args, flag) < 0:
            raise StableMoError(f"--{flag.replace('_', '-')}: must be >= 0, got {getattr(args, flag)}")
    check_finite("--cfg", args.cfg, low=0.0, high=100.0)
    check_seed("--seed", args.seed)
    device = resolve_device(None)
    for flag in ("dtype", "low_precision"):
        value = getattr(args, flag)
        if value != "none":
            try:
                resolve_dtype(value, device)
            except StableMoError as err:
                raise StableMoError(f"--{flag.replace('_', '-')}: {err}") from None
    for flag in ("bundle", "evaluator"):
        if not Path(getattr(args, flag)).exists():
            raise StableMoError(f"--{flag} {getattr(args, flag)}: not found")
    check_output_file(args.out, "--out")
    check_output_file(args.json, "--json")


# ----------------------------------------------------------------------------- rows


@dataclass(frozen=True)
class Run:
    """One scored configuration: a bundle sampled with `sampler` (None: the student's own) for
    `steps` steps with the network in `dtype`."""

    name: str  # the row name in fp32 ("Teacher, DDIM, 4 steps")
    bundle: str
    steps: int
    sampler: str | None
    dtype: str = "fp32"

    @property
    def label(self) -> str:
        return self.name if self.dtype == "fp32" else f"{self.name}, {self.dtype}"


class Context:
    """What the rows share: data, evaluator, pipelines (one per bundle and precision), checksums."""

    def __init__(self, args):
        from stablemo.data import MotionDataset

        self.args = args
        self.started = time.time()
        self.pipes: dict[tuple[str, str], object] = {}
        self.checksums = {"data": folder_checksums(args.data), "evaluator": folder_checksums(args.evaluator)
                          if Path(args.evaluator).is_dir() else {"*": sha256_file(Path(args.evaluator))}}
        self.data = MotionDataset.from_folder(args.data, "test", "humanml3d", crop="eval", seed=args.seed,
                                              progress=False)
        self.evaluator = load_text_motion_evaluator(args.evaluator, "humanml3d")
        rng = np.random.default_rng(args.seed)
        self.timing_items = [self.data[int(i)] for i in rng.choice(len(self.data), args.aits_sentences, replace=False)]

    def out_of_time(self) -> bool:
        return self.args.budget_min is not None and time.time() - self.started > 60 * self.args.budget_min

    def pipe(self, bundle: str, dtype: str):
        if (bundle, dtype) not in self.pipes:
            from stablemo.inference.pipeline import Pipeline

            self.pipes[(bundle, dtype)] = Pipeline.from_bundle(bundle, dtype=dtype)
            self.checksums.setdefault(f"bundle {bundle}", folder_checksums(bundle))
        return self.pipes[(bundle, dtype)]

    def key(self, run: Run | None, items: int | None, replications: int) -> dict:
        """Everything a row's numbers depend on; a row is kept by --resume only if this is unchanged."""
        key = {"data": self.checksums["data"]["*"], "evaluator": self.checksums["evaluator"]["*"],
               "items": items, "replications": replications, "seed": self.args.seed, "cfg": self.args.cfg}
        if run is not None:
            self.pipe(run.bundle, run.dtype)
            key.update(bundle=self.checksums[f"bundle {run.bundle}"]["*"], steps=run.steps, sampler=run.sampler,
                       dtype=run.dtype)
        return key

    def score(self, raw: dict, section: str, run: Run, items: int | None, replications: int, save) -> bool:
        """Score `run` into raw[section][run.label] (and the real motions into raw[section][REAL_ROW])
        unless a row with the same key is there already or the time budget is spent; True if scored."""
        rows = raw.setdefault(section, {})
        key = self.key(run, items, replications)
        if rows.get(run.label, {}).get("key") == key:
            return False
        if self.out_of_time():
            print(f"== {run.label} ({section}): left for a later --resume (--budget-min {self.args.budget_min:g} spent)")
            return False
        print(f"== {run.label} ({section})", flush=True)
        pipe = self.pipe(run.bundle, run.dtype)
        lo, hi = pipe.min_length, pipe.max_length

        def generate(texts, lengths, seeds):
            # evaluation crops can be shorter than the model's minimum: generate at the minimum and
            # score the first `length` frames
            out = pipe.generate(texts, [min(max(n, lo), hi) for n in lengths], steps=run.steps, cfg=self.args.cfg,
                                sampler=run.sampler, seed=seeds)
            return out.features, out.joints

        result = evaluate(self.data, self.evaluator, generate, replications=replications, seed=self.args.seed,
                          max_items=items, row_name=run.label, progress=True)
        rows[REAL_ROW] = {"key": self.key(None, items, replications), "row": result["rows"][REAL_ROW]}
        rows[run.label] = {"key": key, "row": result["rows"][run.label]}
        save()
        return True

    def aits(self, runs: list[Run], sentences: list[dict] | None = None) -> dict[str, float]:
        """AITS of every run {label: seconds}, side by side, every sentence with cold text caches."""
        items = self.timing_items if sentences is None else sentences
        methods = {r.label: metrics.pipeline_method(self.pipe(r.bundle, r.dtype), r.steps, self.args.cfg, r.sampler)
                   for r in runs}
        return metrics.average_inference_times(methods, [it["text"] for it in items], [it["length"] for it in items])


# ----------------------------------------------------------------------------- tables: compute


def sampler_runs(args, students: list[tuple[str, str]]) -> list[Run]:
    t = args.bundle
    runs = [Run(TEACHER_ROW, t, 10, "dpmpp_2m_sde"), Run("Teacher, DPM-Solver++ 2M (ODE), 10 steps", t, 10, "dpmpp_2m"),
            Run("Teacher, DDIM, 10 steps", t, 10, "ddim"), Run("Teacher, DDIM, 4 steps", t, 4, "ddim"),
            Run("Teacher, DDIM, 1 step", t, 1, "ddim")]
    for name, path in students:
        runs += [Run(f"{name} student, {s} step{'s' if s > 1 else ''}", path, s, None) for s in (1, 2, 4)]
    return [Run(r.name, r.bundle, r.steps, r.sampler, args.dtype) for r in runs]


def precision_runs(args, students: list[tuple[str, str]]) -> list[tuple[Run, Run]]:
    """(fp32, low precision) pairs: the teacher's default row and every student's 1-step row."""
    if args.low_precision == "none":
        return []
    base = [Run(TEACHER_ROW, args.bundle, 10, "dpmpp_2m_sde")]
    base += [Run(f"{name} student, 1 step", path, 1, None) for name, path in students]
    return [(r, Run(r.name, r.bundle, r.steps, r.sampler, args.low_precision)) for r in base]


def run_samplers(ctx: Context, raw: dict, runs: list[Run], save) -> None:
    # cheapest first (network calls per sentence), so that a --budget-min run completes the most rows
    for run in sorted(runs, key=lambda r: r.steps * (1 if r.sampler is None else 2)):
        ctx.score(raw, "rows", run, ctx.args.max_items, ctx.args.replications, save)


def run_precision(ctx: Context, raw: dict, pairs: list[tuple[Run, Run]], save) -> None:
    # the fp32 rows are the samplers table's own when it ran in fp32 (same key: kept, not rescored)
    for pair in pairs:
        for run in pair:
            ctx.score(raw, "rows", run, ctx.args.max_items, ctx.args.replications, save)


def run_ddpm(ctx: Context, raw: dict, save) -> None:
    """Table 5's claim on a subset: 1000 DDPM steps vs 10 SDE steps on the same items and seeds."""
    args = ctx.args
    if not args.ddpm_replications:
        return
    for run in ddpm_runs(args):
        scored = ctx.score(raw, "ddpm", run, args.ddpm_items, args.ddpm_replications, save)
        if run.label in raw["ddpm"] and (scored or run.label not in raw["ddpm_aits"]):
            raw["ddpm_aits"][run.label] = ctx.aits([run], ctx.timing_items[:2])[run.label]
            save()


def ddpm_runs(args) -> list[Run]:
    return [Run("Teacher, DDPM, 1000 steps", args.bundle, 1000, "ddpm"), Run(TEACHER_ROW, args.bundle, 10, "dpmpp_2m_sde")]


# ----------------------------------------------------------------------------- tables: render


def cell(row: dict, key: str) -> str:
    if key not in row:
        return "–"
    if len(row[key]["values"]) < 2:  # one replication has no interval
        return f"{row[key]['mean']:.3f}"
    return f"{row[key]['mean']:.3f} ± {row[key]['conf95']:.3f}"


def metric_table(rows: list[tuple[str, dict, float | None]]) -> str:
    header = "| Method | " + " | ".join(h for _, h in COLUMNS) + " | AITS (s) |"
    lines = [header, "|" + "---|" * (len(COLUMNS) + 2)]
    for name, row, t in rows:
        lines.append(f"| {name} | " + " | ".join(cell(row, k) for k, _ in COLUMNS) + f" | {'–' if t is None else f'{t:.4f}'} |")
    return "\n".join(lines)


def _row(raw: dict, label: str, section: str = "rows") -> dict | None:
    entry = raw.get(section, {}).get(label)
    return entry["row"] if entry else None


def render_samplers(raw: dict, runs: list[Run]) -> str:
    rows = [(r.label, _row(raw, r.label), raw.get("aits", {}).get(r.label)) for r in runs if _row(raw, r.label)]
    if not rows:
        return ""
    real = _row(raw, REAL_ROW)
    return "## Samplers and consistency students\n\n" + metric_table([("Real motion", real, None)] + rows) + "\n"


def render_ratios(raw: dict, runs: list[Run]) -> str:
    """Each student row and the teacher's 1-step DDIM against the teacher's 10-step SDE row: FID and
    AITS ratios (the distillation targets: 1 step FID <= 1.5x, 4 steps <= 1.1x, 1-step AITS <= 1/8)."""
    teacher = next((r for r in runs if r.name == TEACHER_ROW), None)
    aits = raw.get("aits", {})
    if teacher is None or _row(raw, teacher.label) is None or teacher.label not in aits:
        return ""
    teacher_fid = _row(raw, teacher.label)["fid"]["mean"]
    lines = []
    for r in [r for r in runs if r.sampler is None] + [r for r in runs if r.name == "Teacher, DDIM, 1 step"]:
        if _row(raw, r.label) is not None and r.label in aits:
            lines.append(f"| {r.label} | {_row(raw, r.label)['fid']['mean'] / teacher_fid:.2f} | "
                         f"{aits[r.label] / aits[teacher.label]:.3f} |")
    if not lines:
        return ""
    return ("\n### Against the teacher's 10-step SDE-DPM-Solver++ row\n\n"
            "| Method | FID / teacher FID | AITS / teacher AITS |\n|---|---|---|\n" + "\n".join(lines) + "\n")


def paired(low: dict, ref: dict, key: str, op) -> metrics.Interval:
    """Per-replication op(low, ref) over replications (rows share items, seeds and reference statistics)."""
    return metrics.replication_interval([op(a, b) for a, b in zip(low[key]["values"], ref[key]["values"])])


def _parameters(bundle: str) -> str:
    """"2.0 M parameters": the bundle's weights counted from its file (what was scored, not a constant)."""
    from safetensors import safe_open

    from stablemo.inference.bundle import WEIGHTS_NAME

    with safe_open(str(Path(bundle) / WEIGHTS_NAME), "pt") as weights:
        n = sum(int(np.prod(weights.get_slice(k).get_shape())) for k in weights.keys())
    return f"{n / 1e6:.1f} M parameters"


def render_precision(raw: dict, pairs: list[tuple[Run, Run]], args) -> str:
    aits = raw.get("aits", {})
    lines, mets = [], []
    for ref_run, low_run in pairs:
        ref, low = _row(raw, ref_run.label), _row(raw, low_run.label)
        if ref is None or low is None:
            continue
        ratio = paired(low, ref, "fid", lambda a, b: a / b)
        d_r3 = paired(low, ref, "r3", lambda a, b: a - b)
        met = ratio.mean <= FID_RATIO_TARGET and abs(d_r3.mean) <= R3_TARGET
        mets.append(met)
        t_ref, t_low = aits.get(ref_run.label), aits.get(low_run.label)
        speed = f"{t_low / t_ref:.2f}" if t_ref and t_low else "–"
        lines.append(f"| {ref_run.name} | fp32 | {cell(ref, 'r3')} | {cell(ref, 'fid')} | {_seconds(t_ref)} | | | | |")
        lines.append(f"| {low_run.name} | {low_run.dtype} | {cell(low, 'r3')} | {cell(low, 'fid')} | {_seconds(t_low)} | "
                     f"{_interval(ratio, 3)} | {_interval(d_r3, 3, signed=True)} | {speed} | {'yes' if met else 'no'} |")
    if not lines:
        return ""
    low = args.low_precision
    notes = [(f"Rows in pairs: fp32, then {low} on the same items, captions, seeds and reference statistics, "
             f"so the ratio and the difference are taken replication by replication (mean ± 95% interval over "
             f"{args.replications} replications). {low}: the network under autocast (matrix products and "
             "convolutions in low precision, Linear weights cast once and cached; stablemo.fast); the solver, "
             f"guidance, x0 conversion and the evaluator stay float32. Target: FID ratio ≤ {FID_RATIO_TARGET:g} "
             f"and |ΔR@3| ≤ {R3_TARGET:g} (both means within: {sum(mets)} of {len(mets)} rows). The demo network "
             f"is small ({_parameters(args.bundle)}, 32–128 channels): its AITS column shows the cost of casting, "
             f"not the speed of {low} on a paper-sized network, which the next note gives.")]
    paper = raw.get("paper_aits")
    if paper and "fp32" in paper["rows"] and low in paper["rows"]:
        a32, alow = paper["rows"]["fp32"]["aits"], paper["rows"][low]["aits"]
        notes.append(f"Speed at the paper's size: {paper['model'] or 'the paper UNet'}, batch 1, 196 frames, 10 steps, "
                     f"parallel CFG, text cache, by `{paper['command']}` ({paper.get('date', '?')} UTC): fp32 "
                     f"{a32:.3f} s, {low} {alow:.3f} s per sentence ({alow / a32:.2f}× the fp32 time)"
                     + (f"; CPU time per sentence (best repeat, all threads; steadier than wall time when other "
                        f"processes share the cores): fp32 {paper['rows']['fp32']['cpu']:.3f} s, {low} "
                        f"{paper['rows'][low]['cpu']:.3f} s ({paper['rows'][low]['cpu'] / paper['rows']['fp32']['cpu']:.2f}×)"
                        if "cpu" in paper["rows"]["fp32"] else "") + ".")
    header = ("| Method | Precision | R@3 ↑ | FID ↓ | AITS (s) | FID / fp32 FID | R@3 − fp32 R@3 | "
              "AITS / fp32 AITS | Target met |\n|---|---|---|---|---|---|---|---|---|")
    return (f"\n## Low precision ({low}) against fp32\n\n" + header + "\n" + "\n".join(lines) + "\n\n"
            + "\n\n".join(notes) + "\n")


def _seconds(t: float | None) -> str:
    return "–" if t is None else f"{t:.4f}"


def _interval(iv: metrics.Interval, digits: int, signed: bool = False) -> str:
    fmt = f"{{:{'+' if signed else ''}.{digits}f}}"
    return f"{fmt.format(iv.mean)} ± {iv.half_width:.{digits}f}" if len(iv.values) > 1 else fmt.format(iv.mean)


def render_ddpm(raw: dict, args) -> str:
    rows = [(r.label, _row(raw, r.label, "ddpm"), raw.get("ddpm_aits", {}).get(r.label)) for r in ddpm_runs(args)
            if _row(raw, r.label, "ddpm")]
    if not rows:
        return ""
    rows.insert(0, ("Real motion", _row(raw, REAL_ROW, "ddpm"), None))
    return f"""
## Table 5's claim: 10 SDE-DPM-Solver++ steps vs 1000 DDPM steps

The same {args.ddpm_items} test items and seeds, {args.ddpm_replications} replication(s) (1000 steps are
expensive on a CPU); AITS over 2 sentences.

{metric_table(rows)}
{ddpm_comparison(raw, args)}"""


def ddpm_comparison(raw: dict, args) -> str:
    """The claim in words, from the two rows: the 10-step sampler's FID and R@3 against the 1000-step
    DDPM's, and its share of the time (empty until both rows and their AITS are measured)."""
    labels = [r.label for r in ddpm_runs(args)]  # the 1000-step DDPM row, then the 10-step one
    ddpm, sde = (_row(raw, label, "ddpm") for label in labels)
    times = [raw.get("ddpm_aits", {}).get(label) for label in labels]
    if not (ddpm and sde) or None in times:
        return ""
    return (f"\nThe 10-step sampler's FID is {sde['fid']['mean'] / ddpm['fid']['mean']:.2f}× the 1000-step DDPM's "
            f"(R@3 {sde['r3']['mean'] - ddpm['r3']['mean']:+.3f}) at {times[1] / times[0]:.4f} of its time per sentence.\n")


def render_provenance(raw: dict) -> str:
    env = "\n".join(f"| {k} | {v} |" for k, v in raw.get("environment", {}).items())
    sums = []
    for what, table in raw.get("checksums", {}).items():
        for name, digest in table.items():
            sums.append(f"| {what} | `{name}` | `{digest[:16]}` |")
    return ("\n## Provenance\n\nEnvironment of this invocation:\n\n| | |\n|---|---|\n" + env + "\n\n"
            "sha256 (first 16 hex digits; the full ones are in this report's JSON, "
            "docs/data/results/results.json for docs/results.md) of what was scored: "
            "each top-level file, each subfolder (over its files' paths and sha256, sorted) and the whole "
            "folder (`*`). Data generated by `stablemo data synth --num 2000 --seed 0`.\n\n"
            "| What | File or folder | sha256 |\n|---|---|---|\n" + "\n".join(sums) + "\n")
