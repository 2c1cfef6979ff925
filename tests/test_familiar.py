"""An unknown prompt gets a warning (issue #40): the bundle's training captions and the threshold."""

from __future__ import annotations

import json
import shutil

import pytest
import torch

from stablemo.errors import StableMoError
from stablemo.inference.bundle import DEMO_BUNDLE, DEMO_STUDENT
from stablemo.inference.pipeline import Pipeline, Request
from stablemo.text.familiar import Familiarity, deduplicate


@pytest.fixture(scope="module")
def student():
    return Pipeline.from_bundle(DEMO_STUDENT)


def test_prompts_outside_the_vocabulary_are_named_and_those_inside_are_not(student):
    # none of these is in the lists the threshold was chosen on (scripts/text/familiarity.py)
    outside = ["a person plays the guitar", "asdf qwerty zzz", "someone is baking bread", "a person flies a kite"]
    inside = ["a person walks forward, then waves their right hand", "a person jumps in place twice",
              "someone walks backwards slowly", "the man side steps to the right", "a person claps three times"]
    named = student.unfamiliar(outside + inside)
    assert [u.text for u in named] == outside
    assert all(u.similarity < u.threshold and u.closest in student.familiarity.captions for u in named)
    out = student.generate(Request(["a person plays the guitar", "a person runs forward"], 40, seed=0))
    assert [u["text"] for u in out.info["unfamiliar"]] == ["a person plays the guitar"]


def test_generate_warns_in_one_line(tmp_path, capsys):
    from stablemo.cli import main

    assert main(["generate", "a person plays the guitar", "a person walks forward", "--bundle", str(DEMO_STUDENT),
                 "--frames", "40", "--out", str(tmp_path), "--no-render"]) == 0
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning:")]
    assert len(err) == 1 and "'a person plays the guitar' is unlike" in err[0]


def test_every_shipped_model_carries_the_captions():
    for bundle in (DEMO_BUNDLE, DEMO_STUDENT):
        config = json.loads((bundle / "config.json").read_text())
        assert config["familiarity"]["captions"] > 1000 and 0 < config["familiarity"]["threshold"] < 1


def test_a_broken_familiarity_entry_is_one_line(tmp_path):
    bundle = tmp_path / "b"
    shutil.copytree(DEMO_STUDENT, bundle)
    config = json.loads((bundle / "config.json").read_text())
    config["familiarity"]["threshold"] = 5
    (bundle / "config.json").write_text(json.dumps(config))
    with pytest.raises(StableMoError, match="familiarity"):
        Pipeline.from_bundle(bundle)
    (bundle / "familiar.safetensors").unlink()
    config["familiarity"]["threshold"] = 0.65
    (bundle / "config.json").write_text(json.dumps(config))
    with pytest.raises(StableMoError, match="does not hold"):
        Pipeline.from_bundle(bundle)


def test_deduplication_keeps_one_of_each_near_copy_and_covers_all():
    e = torch.nn.functional.normalize(torch.tensor([[1.0, 0, 0], [0.99, 0.05, 0], [0, 1.0, 0], [0, 0.98, 0.1]]), dim=-1)
    kept = deduplicate(e, 0.9)
    assert kept == [0, 2]
    assert float((e @ e[kept].T).max(1).values.min()) >= 0.9


def test_saved_captions_load_back(tmp_path, student):
    fam = Familiarity(student.familiarity.embeddings[:5], student.familiarity.captions[:5], 0.5)
    entry = fam.write(tmp_path)
    back = Familiarity.load(tmp_path, entry)
    assert back.captions == fam.captions and torch.allclose(back.embeddings, fam.embeddings, atol=2e-3)


def test_a_bundle_written_from_a_config_with_captions_does_not_claim_them(tmp_path):
    """A student or ControlNet exported from its teacher's config must not name captions it does not hold."""
    from safetensors.torch import load_file

    from stablemo.inference.bundle import save_bundle

    config = json.loads((DEMO_STUDENT / "config.json").read_text())
    out = save_bundle(tmp_path / "copy", config, load_file(DEMO_STUDENT / "model.safetensors"))
    assert "familiarity" not in json.loads((out / "config.json").read_text())
    assert Pipeline.from_bundle(out).familiarity is None
