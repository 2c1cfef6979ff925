"""Write docs/results.md: the demo model on the synthetic benchmark, samplers, students and precisions.

One command from a clean clone (after `bash scripts/setup.sh`) regenerates every table:

    OMP_NUM_THREADS=1 .venv/bin/python scripts/results/make_results.py --resume      # docs/results.md, hours on 2 cores
    OMP_NUM_THREADS=1 .venv/bin/python scripts/results/make_results.py --quick       # CI-sized check, minutes

What it needs it makes, by seed: the synthetic data (`stablemo data synth --num 2000 --seed 0`
when `--data` is absent) and the LCM/PCM students (`scripts/train/distill_demo.sh lcm|pcm` when their
bundles are absent; not in `--quick`, which scores the students it finds). The evaluator is the
packaged `stablemo/assets/evaluator_synth` (scripts/train/make_evaluator_asset.sh made it). Checksums of
the data, bundles and evaluator, and the environment (versions, CPU, threads, git commit), are
printed and recorded in the report.

Tables, each computed by one `run_*` function and written by one `render_*` function:
  samplers   every sampler of the teacher and the students at 1/2/4 steps (`--dtype`, default fp32)
  ratios     students and 1-step DDIM against the teacher's 10-step SDE row
  precision  the teacher's 10-step SDE row and the 1-step students in `--low-precision` (bf16)
             beside fp32, paired per replication, with the paper UNet's AITS of both precisions
             from `stablemo bench aits` in the notes
  ddpm       Table 5's claim: 1000 DDPM steps vs 10 SDE steps on `--ddpm-items` items

Every row is scored by the same evaluator on the same test split with the same replication seeds
(so rows are paired replication by replication). AITS (batch 1, model loaded, each sentence
encoding its own text) is measured for every row in this one run, after the quality rows,
round-robin sentence by sentence (never taken from an earlier run, even with `--resume`).
The report (markdown, and its JSON: `--json`, docs/data/results/results.json for docs/results.md)
is rewritten after every row, marked partial until the last one; `--resume` keeps each row whose
own settings (checksums of data, bundle and evaluator, sampler, steps, precision, replications,
items, seed) are unchanged.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import subprocess
import sys
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import torch

from stablemo.errors import StableMoError, run_script
from stablemo.eval import metrics
from stablemo.eval.evaluate import REAL_ROW, SYNTH_EVALUATOR, evaluate, load_text_motion_evaluator
from stablemo.inference.config import PAPER_CFG
from stablemo.io import check_output_file, write_text

REPO = Path(__file__).resolve().parents[2]
COLUMNS = [("r1", "R@1 ↑"), ("r3", "R@3 ↑"), ("fid", "FID ↓"), ("mm_dist", "MM-Dist ↓"), ("diversity", "Diversity →")]
TEACHER_ROW = "Teacher, SDE-DPM-Solver++ 2M, 10 steps"
DEFAULT_STUDENTS = ["LCM=bundles/demo_lcm", "PCM=bundles/demo_pcm"]
SYNTH = {"num": 2000, "seed": 0}  # the benchmark's data: `stablemo data synth --num 2000 --seed 0`
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


def environment() -> dict[str, str]:
    """What the numbers depend on besides the code: versions, CPU, threads, commit."""
    import lightning

    from stablemo.fast import gemm_backend

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    commit = _git("rev-parse", "HEAD")
    dirty = _git("status", "--porcelain", "--untracked-files=no")
    return {
        "date (UTC)": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M"),
        "commit": (commit or "unknown") + (" (with uncommitted changes)" if dirty else ""),
        "python": platform.python_version(), "torch": torch.__version__, "numpy": np.__version__,
        "lightning": lightning.__version__, "os": f"{platform.system()} {platform.release()}",
        "cpu": f"{cpu}, {os.cpu_count()} logical cores", "torch threads": str(torch.get_num_threads()),
        "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "unset"), "GEMM backend": gemm_backend(),
    }


def _git(*args: str) -> str:
    try:
        return subprocess.run(["git", *args], check=False, cwd=REPO, capture_output=True, text=True, timeout=30).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""


def ensure_data(path: Path) -> None:
    """The synthetic benchmark at `path`, generated by seed when it is not there yet."""
    if (path / "Mean.npy").is_file():
        return
    if path.exists() and any(path.iterdir()):
        raise StableMoError(f"--data {path}: exists but holds no dataset (no Mean.npy)")
    from stablemo.cli import main as stablemo

    print(f"== generating the synthetic data in {path} (--num {SYNTH['num']} --seed {SYNTH['seed']})", flush=True)
    if stablemo(["data", "synth", "--out", str(path), "--num", str(SYNTH["num"]), "--seed", str(SYNTH["seed"])]):
        raise StableMoError(f"--data {path}: generating the synthetic data failed")


def ensure_student(name: str, path: Path, distill: bool) -> bool:
    """A student bundle at `path`, distilled by scripts/train/distill_demo.sh when missing (if allowed)."""
    if (path / "config.json").is_file():
        return True
    mode = name.lower()
    default = REPO / "bundles" / f"demo_{mode}"
    if not distill or mode not in ("lcm", "pcm") or path.resolve() != default.resolve():
        print(f"== skipping the {name} student: {path} is missing", flush=True)
        return False
    print(f"== distilling the {name} student into {path} (scripts/train/distill_demo.sh {mode}; on a shared 2-core CPU "
          "LCM took 50 min, PCM (adversarial, twice the updates) longer)", flush=True)
    env = dict(os.environ)
    venv_cli = Path(sys.executable).parent / "stablemo"
    if venv_cli.is_file():
        env["STABLEMO"] = str(venv_cli)
    subprocess.run(["bash", str(REPO / "scripts" / "train" / "distill_demo.sh"), mode], cwd=REPO, env=env, check=True)
    return True


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


def run_paper_aits(args, raw: dict, save, ctx_out_of_time: bool = False) -> None:
    """The paper UNet (random weights) in fp32 and low precision, parallel CFG, from `stablemo bench
    aits` in this process: the speed side of the precision table (the demo network is too small
    for bf16 to pay off)."""
    if not args.paper_aits_repeats or args.low_precision == "none":
        return
    from tempfile import TemporaryDirectory

    from stablemo.cli.bench import main as bench

    argv = ["aits", "--random-weights", "--skip-ddpm", "--skip-student", "--repeats", str(args.paper_aits_repeats),
            "--threads", str(torch.get_num_threads()), "--seed", str(args.seed)]
    previous = raw.get("paper_aits")
    if previous and previous.get("command") == "stablemo bench " + " ".join(argv) and \
            all("cpu" in r for r in previous["rows"].values()):
        return  # a self-contained side-by-side measurement: kept by --resume with the same settings
    if ctx_out_of_time:
        return
    print("== paper UNet AITS (stablemo bench aits)", flush=True)
    with TemporaryDirectory() as tmp:
        bench([*argv, "--json", f"{tmp}/bench.json"])
        result = json.loads(Path(f"{tmp}/bench.json").read_text())
    rows = {r["dtype"]: r for r in result["rows"] if r["parallel_cfg"] and r["text_cache"]}
    raw["paper_aits"] = {"command": "stablemo bench " + " ".join(argv), "commit": _git("rev-parse", "HEAD"),
                         "date": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M"),
                         "rows": {d: {"aits": r["aits"], "cpu": r["cpu"], "seconds": r["seconds"], "name": r["name"]}
                                  for d, r in rows.items()},
                         "model": result.get("model", "")}
    save()


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


def render_precision(raw: dict, pairs: list[tuple[Run, Run]], args) -> str:
    aits = raw.get("aits", {})
    lines = []
    for ref_run, low_run in pairs:
        ref, low = _row(raw, ref_run.label), _row(raw, low_run.label)
        if ref is None or low is None:
            continue
        ratio = paired(low, ref, "fid", lambda a, b: a / b)
        d_r3 = paired(low, ref, "r3", lambda a, b: a - b)
        met = ratio.mean <= FID_RATIO_TARGET and abs(d_r3.mean) <= R3_TARGET
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
             f"and |ΔR@3| ≤ {R3_TARGET:g} (met: both means within). The demo network is small (1.6 M parameters, "
             f"32–64 channels): its AITS column shows the cost of casting, not the speed of {low} on a "
             "paper-sized network, which the next note gives.")]
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
"""


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


RESULTS_DATA = REPO / "docs" / "data" / "results"  # the JSON of the measured tables
CONTROL_TABLES = [  # (JSON in docs/data/results/, heading, how it was made)
    ("results_control.json", "Joint control by guidance (teacher and 1-step student)",
     "`python scripts/control/report.py --student LCM=bundles/demo_lcm --replications 3 --max-items 96`; the "
     "`+ --footskate` rows: `stablemo evaluate --bundle B --data data/synth --replications 3 --max-items 96 "
     "--control pelvis --density 100% --footskate`. Method and reading: docs/control.md. The AITS lines are that "
     "run's, with 100 pose iterations at the last step; with the 40 used since, measured side by side the same "
     "way: 1.72x (teacher) and 2.39x (student)."),
    ("controlnet_results.json", "Motion ControlNet on the 1-step student",
     "`python scripts/control/report.py --no-teacher --student LCM=stablemo/assets/demo_student --controlnet "
     "\"LCM 1-step=stablemo/assets/demo_controlnet\" --rows none:100%,pelvis:100%,pelvis:25%,pelvis:5,pelvis:1 "
     "--replications 3 --max-items 96 --out docs/data/results/controlnet_results.json` (the shipped pelvis ControlNet, "
     "`configs/control/controlnet_lcm_pelvis_synth.yaml`). Training and reading: docs/control.md."),
    ("controlnet_teacher_results.json", "Motion ControlNet on the teacher (10 steps)",
     "`python scripts/control/report.py --no-teacher --controlnet \"teacher 10-step=bundles/demo_pelvis_control\" "
     "--rows pelvis:100%,pelvis:5 --replications 2 --max-items 64 --out docs/data/results/controlnet_teacher_results.json` "
     "(`configs/control/controlnet_teacher_pelvis_synth.yaml`, exported to bundles/demo_pelvis_control). "
     "Training and reading: docs/control.md."),
]


def control_markdown(path: Path) -> str:
    """The table of one scripts/control/report.py JSON, rendered by that script (`--render`)."""
    done = subprocess.run([sys.executable, str(REPO / "scripts" / "control" / "report.py"), "--render", str(path)],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise StableMoError(f"{path}: scripts/control/report.py --render failed: {done.stderr.strip()[-500:]}")
    return done.stdout.rstrip("\n")


def render_control(out_dir: Path) -> str:
    """The joint-control tables, from the JSON that scripts/control/report.py wrote into docs/data/results/ (their
    runs take hours here, so they are kept as measured, not re-run by this script), then the
    dense-pelvis summary (guidance, ControlNet, both)."""
    parts, reports = [], {}
    for name, heading, how in CONTROL_TABLES:
        path = out_dir / name
        if path.is_file():
            report = reports[name] = json.loads(path.read_text())
            settings = report.get("settings", {})
            parts.append(f"\n## {heading}\n\n{how} Synthetic test split, hints from the scored motions "
                         f"(OmniControl / MotionLCM protocol), mean ± 95% interval over "
                         f"{settings.get('replications', 3)} replications of {settings.get('max_items', 96)} "
                         f"items; errors in metres.\n\n{control_markdown(path)}\n")
    return "".join(parts) + render_control_summary(reports)


# (JSON, row key, label) of the dense-pelvis summary: guidance only, ControlNet teacher, ControlNet 1-step (+ guidance)
CONTROL_SUMMARY = [
    ("results_control.json", "teacher (10 steps) | pelvis 100%", "guidance only, teacher (10 steps)"),
    ("controlnet_teacher_results.json", "teacher 10-step + ControlNet | pelvis 100%", "ControlNet, teacher (10 steps)"),
    ("controlnet_results.json", "LCM student (1 step) | uncontrolled", "1-step student, uncontrolled"),
    ("controlnet_results.json", "LCM 1-step + ControlNet | pelvis 100%", "ControlNet, 1-step student"),
    ("controlnet_results.json", "LCM 1-step + ControlNet + guidance | pelvis 100%",
     "ControlNet + one guidance refinement, 1-step student"),
]


def render_control_summary(reports: dict) -> str:
    """One table, dense pelvis paths: each way of controlling, its control errors, quality and AITS."""
    cols = [("avg_err", "Avg. err (m)"), ("traj_err", "Traj. err"), ("loc_err", "Loc. err"), ("fid", "FID"),
            ("r3", "R@3"), ("skate_ratio", "Skate")]
    lines = []
    for name, key, label in CONTROL_SUMMARY:
        row = reports.get(name, {}).get("rows", {}).get(key)
        if row is None:
            continue
        cells = [f"{row['model'][c]['mean']:.3f} ± {row['model'][c]['conf95']:.3f}" if c in row["model"] else "-"
                 for c, _ in cols]
        aits = reports[name].get("aits", {}).get(key.split(" | ")[0])
        timing = "-" if aits is None else f"{aits['free_s' if 'uncontrolled' in key else 'control_s']:.3f}"
        settings = reports[name].get("settings", {})
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {timing} | "
                     f"{settings.get('replications', 3)} x {settings.get('max_items', 96)} |")
    if not lines:
        return ""
    head = "| control (pelvis, 100% of frames) | " + " | ".join(h for _, h in cols) + " | AITS (s) | scored |"
    return ("\n## Dense pelvis control: guidance, ControlNet, both\n\nFrom the tables above (each row keeps its own "
            "run's protocol, in the last column: replications x items); AITS: 120 frames, batch 1, the demo "
            "network, median of alternating runs inside that run. Times from different runs (machine, load) "
            "are not comparable across rows: the ratios inside each run are, and `stablemo bench aits` gives "
            "the paper UNet's side by side (docs/control.md).\n\n" + head + "\n|" + "---|" * (len(cols) + 3) + "\n"
            + "\n".join(lines) + "\n")


def rewrite_control_sections(out: Path) -> None:
    """Replace the joint-control sections of an existing results file by a fresh render of the JSON
    in docs/data/results/ (`--control-tables`), leaving every other section as it was measured."""
    text = out.read_text()
    start, end = text.find("\n## Joint control by guidance"), text.find("\n## Provenance")
    if start < 0 or end < start:
        raise StableMoError(f"{out}: no joint-control sections to replace (run make_results first)")
    write_text(out, text[:start] + render_control(RESULTS_DATA) + text[end:])


def render(args, argv, raw: dict, runs: list[Run], pairs, minutes: float, done: int, total: int) -> str:
    cmd = "python scripts/results/make_results.py " + " ".join(argv)
    status = "" if done == total else (
        f"\n**Partial: {done} of {total} rows so far (the run is still going, or was stopped: `--resume` continues it). "
        f"Not scored yet: {'; '.join(raw.get('missing', []))}.**\n")
    if raw.get("skipped_students"):
        status += ("\n**Not in these tables: the " + ", ".join(f"{n} student (`{p}` missing; `bash scripts/train/distill_demo.sh "
                   f"{n.lower()}` makes it, or this script without `--no-distill`)" for n, p in raw["skipped_students"])
                   + ".**\n")
    return f"""# Results on the synthetic benchmark

Generated by `scripts/results/make_results.py` (do not edit by hand). Command (from a clean clone: `bash
scripts/setup.sh`, then this; it generates the data and distils the students it needs):

```bash
OMP_NUM_THREADS=1 {cmd}
```
{status}
This invocation took {minutes:.0f} min{f" ({raw['kept']} of the {total} rows were kept from an earlier invocation with the same row settings, `--resume`)" if raw.get('kept') else ""}.
Model: `{args.bundle}` (the demo CondUNet1D, see `configs/demo.yaml`). Evaluator: `{args.evaluator}`
(StableMo's contrastive text–motion evaluator trained on the same synthetic data,
`configs/evaluator_synth.yaml`, exported by `scripts/train/make_evaluator_asset.sh`). Test split with the
evaluation crops; mean ± 95% interval over {args.replications} replications; CFG {args.cfg:g}; network
precision {args.dtype} unless a row says otherwise. AITS: average inference time per sentence, batch 1,
model loaded, every sentence encoding its own text (cold caches), over {args.aits_sentences} test
sentences timed round-robin across the rows. Items scored per replication: {args.max_items or 'the whole test split'}.
Machine and versions: see Provenance at the end.

{render_samplers(raw, runs)}{render_ratios(raw, runs)}{render_precision(raw, pairs, args)}{render_ddpm(raw, args)}{render_control(RESULTS_DATA)}{render_provenance(raw)}"""


# ----------------------------------------------------------------------------- main


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bundle", default="stablemo/assets/demo_bundle")
    p.add_argument("--data", default="data/synth", help="the synthetic benchmark (generated by seed when absent)")
    p.add_argument("--evaluator", default=str(SYNTH_EVALUATOR.relative_to(REPO)))
    p.add_argument("--student", action="append", default=None, metavar="NAME=DIR",
                   help=f"consistency student bundle (default: {' '.join(DEFAULT_STUDENTS)}, distilled when absent)")
    p.add_argument("--no-distill", action="store_true", help="skip missing students instead of distilling them")
    p.add_argument("--quick", action="store_true",
                   help="CI-sized: 2 replications of 64 items, 4 AITS sentences, no DDPM or paper-UNet rows, "
                        "no distillation; writes outputs/results_quick.md unless --out is given")
    p.add_argument("--replications", type=int, help=f"default {FULL['replications']} ({QUICK['replications']} with --quick)")
    p.add_argument("--max-items", type=int,
                   help=f"items scored per replication (default {FULL['max_items']}, {QUICK['max_items']} with --quick)")
    p.add_argument("--ddpm-items", type=int, default=96)
    p.add_argument("--ddpm-replications", type=int, help="0: leave out the 1000-step DDPM table (default 1, 0 with --quick)")
    p.add_argument("--aits-sentences", type=int, help=f"default {FULL['aits_sentences']} ({QUICK['aits_sentences']} with --quick)")
    p.add_argument("--dtype", choices=["fp32", "bf16", "fp16"], default="fp32",
                   help="network precision of the samplers table (fp16: CUDA only)")
    p.add_argument("--low-precision", choices=["bf16", "fp16", "none"], default="bf16",
                   help="precision of the low-precision table's rows, beside fp32 (none: leave it out)")
    p.add_argument("--paper-aits-repeats", type=int,
                   help="sentences per row of the paper UNet's `stablemo bench aits` (0: leave it out; default 3, 0 with --quick)")
    p.add_argument("--cfg", type=float, default=PAPER_CFG)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None, help="default: docs/results.md (outputs/results_quick.md with --quick)")
    p.add_argument("--json", default=None, help="the numbers and settings of every row, what --resume reads (default: "
                   "docs/data/results/results.json for docs/results.md, else OUT with the suffix .json)")
    p.add_argument("--resume", action="store_true", help="keep the rows of the --json file whose settings are unchanged")
    p.add_argument("--control-tables", action="store_true",
                   help="only re-render OUT's joint-control sections from the JSON in docs/data/results/ (scripts/control/report.py "
                        "writes them); every other section stays as measured")
    p.add_argument("--budget-min", type=float, default=None,
                   help="start no new row after this many minutes; the rows done get their AITS and tables "
                        "(marked partial) and a later --resume scores the rest")
    args = p.parse_args(argv)
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
    from stablemo.checks import check_finite, check_positive_int, check_seed
    from stablemo.checks import resolve_device, resolve_dtype

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


def main(argv: list[str]) -> int:
    args = parse_args(argv)
    if args.control_tables:
        rewrite_control_sections(Path(args.out))
        return 0
    check_args(args)
    torch.manual_seed(args.seed)
    started = time.time()
    ensure_data(Path(args.data))
    students, skipped = [], []
    for spec in DEFAULT_STUDENTS if args.student is None else args.student:
        name, sep, path = spec.partition("=")
        if not sep or not name or not path:
            raise StableMoError(f"--student {spec!r}: expected NAME=DIR")
        if ensure_student(name, Path(path), distill=not args.no_distill):
            students.append((name, path))
        else:
            skipped.append((name, path))

    ctx = Context(args)
    runs = sampler_runs(args, students)
    pairs = precision_runs(args, students)
    raw: dict = {"environment": environment(), "checksums": {}, "rows": {}, "ddpm": {}, "aits": {}, "ddpm_aits": {},
                 "skipped_students": skipped}
    # every row this invocation reports, with the key its numbers depend on
    expected = {"rows": {r.label: ctx.key(r, args.max_items, args.replications) for r in runs + [x for p in pairs for x in p]},
                "ddpm": {r.label: ctx.key(r, args.ddpm_items, args.ddpm_replications) for r in ddpm_runs(args)}
                if args.ddpm_replications else {}}
    expected["rows"][REAL_ROW] = ctx.key(None, args.max_items, args.replications)
    if args.ddpm_replications:
        expected["ddpm"][REAL_ROW] = ctx.key(None, args.ddpm_items, args.ddpm_replications)
    json_path = Path(args.json)
    if args.resume and json_path.is_file():
        previous = json.loads(json_path.read_text())
        for section, keys in expected.items():  # only rows whose settings are unchanged
            raw[section] = {label: entry for label, entry in previous.get(section, {}).items()
                            if isinstance(entry, dict) and label in keys and entry.get("key") == keys[label]}
        raw["ddpm_aits"] = {k: v for k, v in previous.get("ddpm_aits", {}).items() if k in raw["ddpm"]}
        if previous.get("paper_aits"):
            raw["paper_aits"] = previous["paper_aits"]  # run_paper_aits decides whether it still holds
    total = sum(1 for keys in expected.values() for label in keys if label != REAL_ROW)

    def rows_done() -> int:
        return sum(1 for section, keys in expected.items() for label in keys
                   if label != REAL_ROW and raw[section].get(label, {}).get("key") == keys[label])

    raw["kept"] = rows_done()

    def save() -> None:
        raw["checksums"] = ctx.checksums
        done = rows_done()
        raw["complete"] = done == total
        raw["missing"] = [label + (" (Table 5 subset)" if section == "ddpm" else "")
                          for section, keys in expected.items() for label in keys
                          if label != REAL_ROW and raw[section].get(label, {}).get("key") != keys[label]]
        write_text(args.out, render(args, argv, raw, runs, pairs, (time.time() - started) / 60, done, total))
        write_text(json_path, json.dumps(raw, indent=2) + "\n")

    for what, digest in ctx.checksums["data"].items():
        print(f"sha256 data {what}: {digest}")
    print(f"sha256 evaluator: {ctx.checksums['evaluator']['*']}")
    run_precision(ctx, raw, pairs, save)  # first: the precision rows and their speed note
    run_paper_aits(args, raw, save, ctx.out_of_time())
    run_samplers(ctx, raw, runs, save)
    run_ddpm(ctx, raw, save)
    done = [r for r in runs + [x for p in pairs for x in p] if r.label in raw["rows"]]
    timed = list({r.label: r for r in done}.values())
    print(f"== AITS of {len(timed)} rows, side by side over {len(ctx.timing_items)} sentences", flush=True)
    raw["aits"] = ctx.aits(timed)
    save()
    for name, table in ctx.checksums.items():
        print(f"sha256 {name}: {table['*']}")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main, "/".join(Path(__file__).parts[-2:]), sys.argv[1:]))
