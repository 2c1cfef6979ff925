"""Issues 26 (item 3) and 27: the packaged synthetic-benchmark evaluator, `stablemo evaluate --dtype`,
scripts/results/make_results.py (checksums, --quick, the precision table), run folders that hold their
checkpoints and logs."""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import yaml

from stablemo.bench import results as mr
from stablemo.errors import StableMoError
from stablemo.eval.evaluate import SYNTH_EVALUATOR
from stablemo.cli.evaluate import main as evaluate_main

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "stablemo" / "assets" / "demo_bundle"
MAKE_RESULTS = REPO / "scripts" / "results" / "make_results.py"


def _args(*flags: str, **options) -> argparse.Namespace:
    """make_results' parsed options before apply_defaults: every option the quick/full defaults
    fill is unset (None), the rest at make_results' defaults."""
    args = argparse.Namespace(bundle="stablemo/assets/demo_bundle", quick=False, no_distill=False, replications=None,
                              max_items=None, ddpm_items=96, ddpm_replications=None, aits_sentences=None,
                              dtype="fp32", low_precision="bf16", paper_aits_repeats=None, cfg=2.5, seed=0,
                              out=None, json=None)
    for flag in flags:
        setattr(args, flag, True)
    for key, value in options.items():
        setattr(args, key, value)
    return mr.apply_defaults(args)


@pytest.fixture(scope="module")
def synth(tmp_path_factory) -> Path:
    """40 clips of the synthetic benchmark (split `all` holds 40 >= one R-precision batch)."""
    from stablemo.cli import main

    out = tmp_path_factory.mktemp("synth") / "synth"
    assert main(["data", "synth", "--out", str(out), "--num", "40", "--seed", "0"]) == 0
    return out


# ---------------------------------------------------------------------------------- evaluator asset


def test_packaged_evaluator_is_small_and_loads():
    from stablemo.eval.text_motion import OurEvaluator

    files = {p.name: p.stat().st_size for p in SYNTH_EVALUATOR.iterdir()}
    assert set(files) == {"config.json", "model.safetensors"}
    assert sum(files.values()) < 8 * 2**20  # a few MB in the wheel, not a training checkpoint
    ev = OurEvaluator(SYNTH_EVALUATOR)
    assert ev.feature_dim == 263
    # trained statistics, not the untrained module's zeros/ones
    assert float(ev.model.std.min()) > 0 and not torch.allclose(ev.model.mean, torch.zeros(263))


def test_evaluate_runs_out_of_the_box_and_in_bf16(synth, tmp_path, capsys):
    """No --evaluator on synthetic data: the packaged one. --dtype bf16 really changes the numbers
    (the network ran in bf16) and only a little; the row and the JSON say which precision."""
    common = ["--bundle", str(DEMO), "--data", str(synth), "--split", "all", "--replications", "1", "--steps", "1",
              "--sampler", "ddim", "--aits", "0", "--no-progress"]
    results = {}
    for dtype in ("fp32", "bf16"):
        out = tmp_path / f"{dtype}.json"
        assert evaluate_main([*common, "--dtype", dtype, "--out", str(out)]) == 0
        results[dtype] = json.loads(out.read_text())
    printed = capsys.readouterr().out
    assert "stablemo evaluator (evaluator_synth)" in printed
    assert results["bf16"]["settings"]["dtype"] == "bf16" and results["fp32"]["settings"]["dtype"] == "fp32"
    row32 = results["fp32"]["rows"]["demo_bundle (ddim, 1 steps, cfg 1.5)"]
    row16 = results["bf16"]["rows"]["demo_bundle (ddim, 1 steps, cfg 1.5, bf16)"]
    assert row16["fid"]["mean"] != row32["fid"]["mean"]
    assert abs(row16["fid"]["mean"] / row32["fid"]["mean"] - 1) < 0.2
    assert results["bf16"]["rows"]["Real motion"] == results["fp32"]["rows"]["Real motion"]  # same items and seeds


def test_evaluate_refuses_bad_precision_and_a_missing_evaluator_before_loading(tmp_path):
    missing = str(tmp_path / "no_data")  # never read: the argument errors come first
    with pytest.raises(StableMoError, match="^--dtype: "):
        evaluate_main(["--data", missing, "--dtype", "bf16"])  # precision of what? no --bundle
    if not torch.cuda.is_available():
        with pytest.raises(StableMoError, match="^--dtype: float16 is for CUDA"):
            evaluate_main(["--bundle", str(DEMO), "--data", missing, "--dtype", "fp16"])
    with pytest.raises(SystemExit):
        evaluate_main(["--data", missing, "--bundle", str(DEMO), "--dtype", "int8"])
    (tmp_path / "humanml3d").mkdir()  # not written by `stablemo data synth`: no default evaluator
    with pytest.raises(StableMoError, match="^--evaluator: required for .*no synth.json"):
        evaluate_main(["--data", str(tmp_path / "humanml3d")])


# ---------------------------------------------------------------------------------- make_results


def test_folder_checksums_say_which_part_changed(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "a" / "x.npy").write_bytes(b"1")
    (tmp_path / "b" / "y.npy").write_bytes(b"2")
    (tmp_path / "Mean.npy").write_bytes(b"3")
    before = mr.folder_checksums(tmp_path)
    assert set(before) == {"*", "Mean.npy", "a/", "b/"}
    assert before == mr.folder_checksums(tmp_path)
    (tmp_path / "b" / "y.npy").write_bytes(b"22")
    after = mr.folder_checksums(tmp_path)
    assert [k for k in before if before[k] != after[k]] == ["*", "b/"]


def test_quick_mode_defaults_and_explicit_flags():
    quick = _args("quick")
    assert (quick.replications, quick.max_items, quick.ddpm_replications, quick.paper_aits_repeats) == (2, 64, 0, 0)
    assert quick.no_distill and quick.out == "outputs/results_quick.md" and quick.json == "outputs/results_quick.json"
    assert _args("quick", replications=5).replications == 5
    full = _args()
    assert (full.replications, full.max_items, full.out) == (20, 128, "docs/results.md")
    assert full.json == "docs/data/results/results.json"


def test_make_results_refuses_bad_arguments_before_any_compute(tmp_path):
    """Run as users run it (a process): each bad argument is one line naming it, exit status 1."""
    cases = [(["--replications", "0"], "--replications: ")]
    if not torch.cuda.is_available():
        cases.append((["--low-precision", "fp16"], "--low-precision: "))
    for argv, message in cases:
        done = subprocess.run([sys.executable, str(MAKE_RESULTS), *argv, "--out", str(tmp_path / "x.md")],
                              capture_output=True, text=True, cwd=REPO, check=False)
        assert done.returncode != 0 and message in done.stderr, done.stderr[-2000:]
        assert "Traceback" not in done.stderr
    assert not (tmp_path / "x.md").exists()


def _row(fids, r3s):
    from stablemo.eval.metrics import replication_interval

    return {"fid": replication_interval(fids).to_dict(), "r3": replication_interval(r3s).to_dict()}


def test_precision_table_pairs_replications_and_checks_the_target():
    args = _args(low_precision="bf16")
    pairs = mr.precision_runs(args, [("LCM", "bundles/demo_lcm")])
    labels = [r.label for pair in pairs for r in pair]
    assert labels == [mr.TEACHER_ROW, mr.TEACHER_ROW + ", bf16", "LCM student, 1 step", "LCM student, 1 step, bf16"]
    raw = {"rows": {
        labels[0]: {"row": _row([0.10, 0.20], [0.95, 0.96])},
        labels[1]: {"row": _row([0.101, 0.202], [0.95, 0.955])},   # ratio 1.01 in both replications: met
        labels[2]: {"row": _row([0.20, 0.30], [0.90, 0.90])},
        labels[3]: {"row": _row([0.22, 0.33], [0.90, 0.90])},      # ratio 1.10: not met
    }, "aits": {labels[0]: 0.1, labels[1]: 0.2, labels[2]: 0.01, labels[3]: 0.02},
        "paper_aits": {"command": "stablemo bench aits ...", "model": "paper",
                       "rows": {"fp32": {"aits": 3.0}, "bf16": {"aits": 1.5}}}}
    text = mr.render_precision(raw, pairs, args)
    teacher_line = next(line for line in text.splitlines() if line.startswith(f"| {mr.TEACHER_ROW} | bf16"))
    assert "1.010 ± 0.000" in teacher_line and "-0.003 ± 0.003" in teacher_line and teacher_line.endswith("| yes |")
    lcm_line = next(line for line in text.splitlines() if line.startswith("| LCM student, 1 step | bf16"))
    assert "1.100 ± 0.000" in lcm_line and lcm_line.endswith("| no |") and "| 2.00 |" in lcm_line
    assert "fp32 3.000 s, bf16 1.500 s per sentence (0.50× the fp32 time)" in text
    # the note counts what the table found, and the network's size is read from the bundle scored
    assert "(both means within: 1 of 2 rows)" in text and "(2.0 M parameters, " in text


def test_ddpm_table_states_the_claim_from_its_rows_once_both_are_measured():
    args = _args()
    ddpm, sde = (r.label for r in mr.ddpm_runs(args))
    raw = {"ddpm": {mr.REAL_ROW: {"row": _row([0.05], [0.99])}, ddpm: {"row": _row([0.20], [0.95])}}, "ddpm_aits": {}}
    assert "Table 5's claim" in mr.render_ddpm(raw, args) and "of its time" not in mr.render_ddpm(raw, args)
    raw["ddpm"][sde] = {"row": _row([0.25], [0.96])}
    raw["ddpm_aits"] = {ddpm: 20.0, sde: 0.2}
    assert "FID is 1.25× the 1000-step DDPM's (R@3 +0.010) at 0.0100 of its time" in mr.render_ddpm(raw, args)


def test_control_tables_rewrite_only_the_control_sections(tmp_path):
    """--control-tables: the joint-control sections come from docs/data/results/*.json again (with the
    dense-pelvis summary); the measured sections around them are kept byte for byte; a file without
    them is one error."""
    out = tmp_path / "results.md"
    before, after = "# Results\n\n## Samplers\n\n| a | b |\n", "\n## Provenance\n\n| env | x |\n"
    out.write_text(before + "\n## Joint control by guidance (old)\n\nstale numbers\n" + after)
    cmd = [sys.executable, str(MAKE_RESULTS), "--control-tables", "--out"]
    done = subprocess.run([*cmd, str(out)], capture_output=True, text=True, cwd=REPO, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    text = out.read_text()
    assert text.startswith(before) and text.endswith(after) and "stale numbers" not in text
    assert "| model | control | FID |" in text  # the tables, rendered by scripts/control/report.py --render
    # a table of models since replaced says which (its settings' "models"); a table of today's does not
    import json
    settings = [json.loads(p.read_text()).get("settings") for p in (REPO / "docs/data/results").glob("*.json")]
    replaced = [s["models"] for s in settings if isinstance(s, dict) and isinstance(s.get("models"), str)]
    assert text.count("**Measured on") == len(replaced) and all(f"**Measured on {m}.**" in text for m in replaced)
    summary = text[text.index("## Dense pelvis control"):]
    assert "| guidance only, teacher (10 steps) |" in summary and "| ControlNet, 1-step student |" in summary
    bare = tmp_path / "bare.md"
    bare.write_text(before + after)
    done = subprocess.run([*cmd, str(bare)], capture_output=True, text=True, cwd=REPO, check=False)
    assert done.returncode != 0 and "no joint-control sections" in done.stderr, done.stderr[-2000:]
    assert bare.read_text() == before + after


@pytest.mark.slow
def test_make_results_quick_end_to_end(tmp_path):
    """--quick on 240 clips (36 test items): every table that applies is written, checksums and
    environment recorded, and --resume keeps every row (no rescoring) on an unchanged setup."""
    from stablemo.cli import main

    synth = tmp_path / "synth"
    assert main(["data", "synth", "--out", str(synth), "--num", "240", "--seed", "0"]) == 0
    out = tmp_path / "results.md"
    argv = ["--quick", "--data", str(synth), "--student", "LCM=" + str(tmp_path / "no_student"),
            "--max-items", "32", "--replications", "1", "--aits-sentences", "2", "--out", str(out)]
    env_cmd = [sys.executable, str(MAKE_RESULTS), *argv]
    first = subprocess.run(env_cmd, capture_output=True, text=True, cwd=REPO, check=False)
    assert first.returncode == 0, first.stderr[-2000:]
    text = out.read_text()
    assert "## Samplers and consistency students" in text and "## Low precision (bf16) against fp32" in text
    assert "Partial" not in text and "skipping the LCM student" in first.stdout
    raw = json.loads(out.with_suffix(".json").read_text())
    assert raw["complete"] and raw["environment"]["torch"] == torch.__version__
    assert re.fullmatch(r"[0-9a-f]{64}", raw["checksums"]["data"]["*"])
    second = subprocess.run([*env_cmd, "--resume"], capture_output=True, text=True, cwd=REPO, check=False)
    assert second.returncode == 0 and "== Teacher" not in second.stdout
    assert "6 of the 6 rows were kept" in out.read_text()


# ---------------------------------------------------------------------------------- run folders


def test_no_config_pins_checkpoint_or_log_folders():
    for path in sorted((REPO / "configs").rglob("*.yaml")):
        config = yaml.safe_load(path.read_text()) or {}
        assert "dirpath" not in (config.get("checkpoint") or {}), path
        assert "logger" not in (config.get("trainer") or {}), path


def test_documented_checkpoint_paths_are_where_the_configs_write():
    roots = {(yaml.safe_load(p.read_text()) or {}).get("trainer", {}).get("default_root_dir")
             for p in (REPO / "configs").rglob("*.yaml")}
    texts = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md")), *sorted((REPO / "configs").rglob("*.yaml")),
             *sorted((REPO / "scripts").rglob("*.sh"))]
    found = 0
    for path in texts:
        for match in re.finditer(r"((?:runs|outputs)/[\w/.-]+?)/checkpoints/", path.read_text()):
            found += 1
            assert match.group(1) in roots, f"{path.name}: {match.group(0)} is not a config's run folder"
    assert found >= 5


def test_run_folder_holds_checkpoints_and_logs_and_resumes(tmp_path):
    sys.path.insert(0, str(REPO / "tests"))
    from test_training import TINY_MODEL, write_random_dataset

    from stablemo.training.checkpoint_io import load_checkpoint_file
    from stablemo.cli.train import main_fit

    data = write_random_dataset(tmp_path / "data", num=12, splits=(8, 2))
    config = {"seed_everything": 0,
              "trainer": {"accelerator": "cpu", "devices": 1, "max_steps": 2, "limit_val_batches": 0,
                          "log_every_n_steps": 1, "default_root_dir": str(tmp_path / "from_config"),
                          "enable_progress_bar": False, "enable_model_summary": False},
              "checkpoint": {"every_n_train_steps": 2},
              "model": {"model": TINY_MODEL, "ema_decay": 0.9, "lr": 1e-3},
              "data": {"data_dir": str(data), "batch_size": 4, "pad_multiple": 2, "max_length": 64}}
    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump(config))
    run = tmp_path / "moved"
    main_fit(["--config", str(cfg), "--trainer.default_root_dir", str(run)])
    assert (run / "checkpoints" / "last.ckpt").is_file() and (run / "logs" / "version_0" / "metrics.csv").is_file()
    assert not (tmp_path / "from_config").exists()
    main_fit(["--config", str(cfg), "--trainer.default_root_dir", str(run), "--trainer.max_steps", "3",
              "--ckpt_path", "last"])
    assert load_checkpoint_file(run / "checkpoints" / "last.ckpt")["global_step"] == 3
    resumed_steps = [line.split(",")[1] for line in (run / "logs" / "version_1" / "metrics.csv").read_text().splitlines()[1:]]
    assert resumed_steps == ["2"]  # continued from last.ckpt's step 2, not restarted at 0
