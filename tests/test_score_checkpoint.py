"""scripts/train/score_checkpoint.py: a checkpoint scored as the shipped teacher is (its bundle reads the
shipped length predictor and captions), and bad arguments answered in one line."""

from __future__ import annotations

import importlib.util
import json
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "scripts" / "train" / "score_checkpoint.py"
TEACHER = REPO / "stablemo" / "assets" / "demo_bundle"
STUDENT = REPO / "stablemo" / "assets" / "demo_student"


def _script():
    spec = importlib.util.spec_from_file_location("score_checkpoint", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_attached_bundle_predicts_lengths_and_flags_unknown_prompts(tmp_path):
    from stablemo.inference.pipeline import Pipeline

    bundle = tmp_path / "bundle"
    shutil.copytree(STUDENT, bundle)
    config = json.loads((bundle / "config.json").read_text())
    for key in ("length_predictor", "familiarity"):
        (bundle / config.pop(key)["file"]).unlink()
    (bundle / "config.json").write_text(json.dumps(config))
    bare = Pipeline.from_bundle(bundle)
    assert bare.length_predictor is None and bare.familiarity is None

    _script().attach_text_models(bundle, TEACHER)
    pipe, shipped = Pipeline.from_bundle(bundle), Pipeline.from_bundle(TEACHER)
    texts = ["a person jumps in place twice.", "a man walks in a circle clockwise."]
    assert pipe.text_length_range(texts, 0.9) == shipped.text_length_range(texts, 0.9)
    assert pipe.familiarity is not None and pipe.familiarity.threshold == shipped.familiarity.threshold


def test_a_missing_checkpoint_gets_one_line(tmp_path):
    done = subprocess.run([sys.executable, str(SCRIPT), "missing.ckpt", "--out", "x"], cwd=tmp_path,
                          capture_output=True, text=True)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == ["score_checkpoint.py: checkpoint missing.ckpt not found"]
    assert not (tmp_path / "x").exists()


def test_data_without_statistics_is_refused_before_any_export(tmp_path):
    ckpt = tmp_path / "a.ckpt"
    ckpt.write_bytes(b"")
    done = subprocess.run([sys.executable, str(SCRIPT), str(ckpt), "--out", str(tmp_path / "out"),
                           "--data", str(tmp_path / "nodata")], capture_output=True, text=True)
    assert done.returncode == 2
    assert "is not a dataset folder" in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_a_like_bundle_without_text_models_is_refused_before_any_export(tmp_path):
    ckpt, like = tmp_path / "a.ckpt", tmp_path / "like"
    ckpt.write_bytes(b"")
    like.mkdir()
    (like / "config.json").write_text(json.dumps({"format": "stablemo-bundle"}))
    done = subprocess.run([sys.executable, str(SCRIPT), str(ckpt), "--out", str(tmp_path / "out"), "--like", str(like)],
                          capture_output=True, text=True)
    assert done.returncode == 2
    assert "is not a bundle with a length predictor and captions" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()
