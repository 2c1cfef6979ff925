"""scripts/results/kinematic_report.py and its library (stablemo.bench.kinematic_report) on a tiny model."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import make_tiny_bundle

from stablemo.bench import kinematic_report as report
from stablemo.errors import StableMoError

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "results" / "kinematic_report.py"


def test_prompts_cover_every_category_with_distinct_captions():
    items = report.prompts(8, seed=0)
    assert len(items) == 72 >= report.MIN_PROMPTS
    assert len({p.text for p in items}) == 72
    for category, actions in report.CATEGORIES.items():
        mine = [p for p in items if p.category == category]
        assert len(mine) == 8 and {p.action for p in mine} == set(actions), category
    assert [p.text for p in report.prompts(8, seed=0)] == [p.text for p in items]     # seeded
    with pytest.raises(StableMoError, match="--prompts-per-category"):
        report.check_prompts(7)                                                        # 63 < 64


def test_report_rows_on_a_tiny_model(tmp_path):
    """Raw and final rows per length; a finishing step that lifts the body 2 cm shows 2 cm in the
    stance height, the floor percentile and the feet's displacement, nothing in the bone lengths."""
    from stablemo.inference.pipeline import Pipeline

    torch.set_num_threads(1)
    pipe = Pipeline.from_bundle(make_tiny_bundle(tmp_path / "bundle"))

    class Lifted:  # what a pipeline with a finishing step hands out: final = raw lifted by 2 cm
        skeleton, inference = pipe.skeleton, pipe.inference

        def generate(self, texts, lengths, seed):
            gen = pipe.generate(texts, lengths, seed=seed, finish=False)
            gen.raw_features, gen.raw_joints = gen.features, gen.joints
            gen.joints = gen.joints + torch.tensor([0.0, 0.02, 0.0]) * gen.mask[..., None, None]
            return gen

    result = report.run([("tiny", Lifted())], [24], per_category=8, seeds=1, log=lambda *_: None)
    rows = result["rows"]
    assert [(r["frames"], r["output"]) for r in rows] == [(24, "raw"), (24, "final")]
    # each model's sampling is recorded: a student bundle's default steps are not in its label
    assert result["settings"]["sampling"] == {"tiny": {"sampler": pipe.inference.sampler,
                                                       "steps": pipe.inference.steps, "cfg": pipe.inference.cfg}}
    raw, final = rows[0]["summary"], rows[1]["summary"]
    assert final["floor_p1_mean"] == pytest.approx(raw["floor_p1_mean"] + 2.0, abs=1e-3)
    assert final["bone_change_max"] == pytest.approx(raw["bone_change_max"], abs=1e-3)
    for part in ("feet", "hands", "head"):
        assert final[f"moved_{part}"] == pytest.approx(2.0, abs=1e-3) and f"moved_{part}" not in raw
    assert len(rows[0]["per_motion"]["bone_change"]) == 72
    assert np.isfinite(raw["stance_height_median"])
    assert final["stance_height_median"] == pytest.approx(raw["stance_height_median"] + 2.0, abs=1e-3)
    table = report.render(rows)
    lines = table.splitlines()
    assert len(lines) == 4 and lines[0].startswith("| Model | Frames | Output | Bone Δ max (cm)")
    assert "| tiny | 24 | final |" in table and "FID" not in table          # no evaluator: no FID column


def test_script_refuses_bad_arguments_in_one_line():
    """Each refused before any model is loaded: one line on stderr, exit code 2 (the script run as
    a user runs it; nothing imports a script)."""
    for argv, said in ((["--models", "teacher,nope"], "--models"), (["--prompts-per-category", "5"], "64 prompts"),
                       (["--frames", "12x"], "--frames"), (["--seeds", "0"], "--seeds"),
                       (["--bundle", "no-equals-sign"], "expected LABEL=PATH"),
                       (["--bundle", "cand=/nonexistent/bundle"], "is not a bundle folder"),
                       (["--models", "", "--no-evaluator"], "nothing to score")):
        done = subprocess.run([sys.executable, str(SCRIPT), *argv], capture_output=True, text=True, timeout=120)
        assert done.returncode == 2, (argv, done.stderr)
        assert said in done.stderr and len(done.stderr.strip().splitlines()) == 1, (argv, done.stderr)


def test_summary_reads_the_right_categories():
    cats = ["stand", "jump", "walk", "kick"]
    row = {"bone_change": [1.0, 3.0, 2.0, 0.0], "floor_p1": [-1.0, -4.0, 0.0, 0.0], "below_floor": [0.1] * 4,
           "stance_height": [1.0, 9.0, 3.0, float("nan")], "stance_speed": [5.0, float("nan"), 15.0, 10.0],
           "foot_acc": [1.0] * 4, "airborne": [0.0, 0.4, 0.1, 0.2]}
    s = report.summary({"row": row, "categories": cats})
    assert s["bone_change_max"] == 3.0 and s["bone_change_median"] == 1.5
    assert s["floor_p1_mean"] == -1.25 and s["floor_p1_worst"] == -4.0
    assert s["stance_height_median"] == 2.0                  # stand and walk only
    assert s["stance_speed"] == 10.0                         # NaN (no contact) left out
    assert s["airborne_jump"] == 0.4 and s["airborne_stance"] == pytest.approx(0.05)
    assert json.loads(json.dumps(s)) == s


FID_PARTS = Path(__file__).resolve().parents[1] / "scripts" / "results" / "finish_fid_parts.py"


def test_fid_parts_script_scores_four_ways_of_one_generation(tmp_path):
    """scripts/results/finish_fid_parts.py: raw, raw recomputed, final with the network's rotation
    columns, final, all from one generation; bad arguments are one line each."""
    import importlib.util

    from stablemo.inference.pipeline import Pipeline
    from stablemo.motion.features import feature_slices

    spec = importlib.util.spec_from_file_location("finish_fid_parts", FID_PARTS)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    torch.set_num_threads(1)
    pipe = Pipeline.from_bundle(make_tiny_bundle(tmp_path / "bundle"))
    ways = module.ways(pipe, ["a person walks.", "a person jumps."], [0, 1], 24, 1)  # one motion a chunk
    assert list(ways) == list(module.WAYS)
    rot = feature_slices(pipe.skeleton)["rot6d"]
    raw, recomputed, mixed, final = ways.values()
    assert torch.equal(mixed[..., rot], raw[..., rot])
    others = torch.ones(raw.shape[-1], dtype=torch.bool)
    others[rot] = False
    assert torch.equal(mixed[..., others], final[..., others])
    assert torch.equal(recomputed[..., :3], raw[..., :3]) and not torch.equal(final, raw)
    for argv, said in ((["--models", "nope"], "--models"), (["--frames", "1a"], "--frames"),
                       (["--seeds", "0"], "--seeds"), (["--first-seed", "-1"], "--first-seed"),
                       (["--out", str(FID_PARTS)], "--out")):
        done = subprocess.run([sys.executable, str(FID_PARTS), *argv], capture_output=True, text=True, timeout=120)
        assert done.returncode == 2, (argv, done.stderr)
        assert said in done.stderr and len(done.stderr.strip().splitlines()) == 1, (argv, done.stderr)
