"""Write docs/results.md: the demo model on the synthetic benchmark, samplers, students and precisions.

One command from a clean clone (after `bash scripts/setup.sh`) regenerates every table:

    OMP_NUM_THREADS=1 .venv/bin/python scripts/results/make_results.py --resume      # docs/results.md, hours on 2 cores
    OMP_NUM_THREADS=1 .venv/bin/python scripts/results/make_results.py --quick       # CI-sized check, minutes

What it needs it makes, by seed: the synthetic data (`stablemo data synth --num 2000 --seed 0 --rest tight`
when `--data`, default data/synth_tight, is absent) and the LCM/PCM students
(`scripts/train/distill_demo.sh lcm|pcm` when their bundles are absent; not in `--quick`, which scores
the students it finds). The evaluator is the
packaged `stablemo/assets/evaluator_synth` (scripts/train/make_evaluator_asset.sh made it). Checksums of
the data, bundles and evaluator, and the environment (versions, CPU, threads, git commit), are
printed and recorded in the report.

Tables, each computed by one `run_*` function and written by one `render_*` function (the rows,
their scoring and those functions are stablemo.bench.results'; this script parses the options,
makes what is missing and writes the report):
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
import json
import os
import platform
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import torch

from stablemo.bench.kinematic_report import results_section
from stablemo.bench.results import (
    FULL,
    QUICK,
    Context,
    Run,
    apply_defaults,
    check_args,
    ddpm_runs,
    precision_runs,
    render_ddpm,
    render_precision,
    render_provenance,
    render_ratios,
    render_samplers,
    run_ddpm,
    run_precision,
    run_samplers,
    sampler_runs,
)
from stablemo.errors import StableMoError, run_script
from stablemo.eval.behaviour.report import results_section as behaviour_section
from stablemo.eval.evaluate import REAL_ROW, SYNTH_EVALUATOR
from stablemo.inference.config import PAPER_CFG
from stablemo.io import write_text

REPO = Path(__file__).resolve().parents[2]
DEFAULT_STUDENTS = ["LCM=bundles/demo_lcm", "PCM=bundles/demo_pcm"]
# the benchmark's data: `stablemo data synth --num 2000 --seed 0 --rest tight`, the clips without the idle
# rest around their actions, which the packaged evaluator was trained on (the demo models train on the
# same clips with the rest, `--rest varied`: docs/training.md, "The synthetic data and the demo recipe")
SYNTH = {"num": 2000, "seed": 0, "rest": "tight"}


# -------------------------------------------------------------------- provenance, data and students


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

    print(f"== generating the synthetic data in {path} (--num {SYNTH['num']} --seed {SYNTH['seed']} "
          f"--rest {SYNTH['rest']})", flush=True)
    if stablemo(["data", "synth", "--out", str(path), "--num", str(SYNTH["num"]), "--seed", str(SYNTH["seed"]),
                 "--rest", SYNTH["rest"]]):
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


# ---------------------------------------------------------------------------- the paper UNet's AITS


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


# ------------------------------------------------------ joint-control sections and the whole report


RESULTS_DATA = REPO / "docs" / "data" / "results"  # the JSON of the measured tables
CONTROL_TABLES = [  # (JSON in docs/data/results/, heading, how it was made)
    ("results_control.json", "Joint control by guidance (teacher and 1-step student)",
     "`python scripts/control/report.py --replications 3 --max-items 96` (the teacher) and `... --no-teacher "
     "--student LCM=stablemo/assets/demo_student` (the student); the `+ --footskate` rows: `stablemo evaluate "
     "--bundle B --data data/synth --replications 3 --max-items 96 --control pelvis --density 100% --footskate`. "
     "Method and reading: docs/control.md. AITS of dense pelvis control against free generation, alternating "
     "runs of one process: teacher 1.21x, student 1.25x. Measured 2026-12-07 on the models shipped that day."),
    ("controlnet_results.json", "Motion ControlNet on the 1-step student",
     "`python scripts/control/report.py --no-teacher --student LCM=stablemo/assets/demo_student --controlnet "
     "\"LCM 1-step=stablemo/assets/demo_controlnet\" --rows none:100%,pelvis:100%,pelvis:25%,pelvis:5,pelvis:1 "
     "--replications 3 --max-items 96 --out docs/data/results/controlnet_results.json` (the shipped pelvis ControlNet, "
     "root only, its steps on the floor toward the next target: `configs/control/controlnet_lcm_pelvis_floor.yaml` "
     "with `configs/control/controlnet_lcm_pelvis_toward.yaml`, then `configs/control/pelvis_toward_clip.yaml`). "
     "Training and reading: docs/control.md. Measured 2026-12-07."),
    ("controlnet_teacher_results.json", "Motion ControlNet on the teacher (10 steps)",
     "`python scripts/control/report.py --no-teacher --controlnet \"teacher 10-step=bundles/demo_pelvis_control\" "
     "--rows pelvis:100%,pelvis:5 --replications 2 --max-items 64 --out docs/data/results/controlnet_teacher_results.json` "
     "(`configs/control/controlnet_teacher_pelvis_synth.yaml`, exported to bundles/demo_pelvis_control). "
     "Training and reading: docs/control.md."),
    ("control_facing.json", "Facing along hinted paths, 1-step student and its ControlNet (body steered)",
     "`python scripts/control/report.py --no-teacher --student LCM=stablemo/assets/demo_student --controlnet "
     "\"LCM 1-step=stablemo/assets/demo_controlnet\" --rows none:100%,pelvis:100%,pelvis:5 --replications 2 "
     "--max-items 64 --out docs/data/results/control_facing.json`, measured 2026-12-07 (the root-only ControlNet "
     "stepping toward the next target). "
     "Facing err: the median over moving frames of the difference between the generated and the hinted motion's "
     "facing-against-travel angles (degrees); Backward / Sideways: shares of moving frames walked so where the "
     "hinted motion walks forward (stablemo.eval.heading). Paths of test motions start facing +z: drawn paths, "
     "which start anywhere, are measured in docs/control.md."),
    ("control_facing_unsteered.json", "Facing along hinted paths, the same with the facing left to the network",
     "The same command with `--no-face-travel` (Request.face_travel=False), the A/B of the steering; measured "
     "with the table above."),
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
            # a table measured on models that have since been replaced says which (scripts/control/report.py
            # does not write this: a new run's table is of the models it names)
            if settings.get("models"):
                how = f"{how} **Measured on {settings['models']}.**"
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
        if settings.get("models"):  # measured on models since replaced: say so here as in its table
            label = f"{label} (on {settings['models'].split(' (')[0]})"
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

{render_samplers(raw, runs)}{render_ratios(raw, runs)}{render_precision(raw, pairs, args)}{render_ddpm(raw, args)}{results_section()}{behaviour_section(RESULTS_DATA)}{render_control(RESULTS_DATA)}{render_provenance(raw)}"""


# ----------------------------------------------------------------------------- main


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bundle", default="stablemo/assets/demo_bundle")
    # the benchmark's own folder: data/synth holds what the demo recipe trains on (varied idle rest),
    # while the benchmark and the packaged evaluator are the tight-rest clips
    p.add_argument("--data", default="data/synth_tight", help="the synthetic benchmark (generated by seed when absent)")
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
    return apply_defaults(p.parse_args(argv))


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
