"""A motion asked for without a length gets the text's (stablemo.text.length): the predictor, its
file in a bundle, and every way of asking for a motion without a length."""

from __future__ import annotations

import json
import shutil

import pytest
import torch

from stablemo.errors import StableMoError
from stablemo.inference.bundle import DEMO_BUNDLE, DEMO_CONTROLNET, DEMO_STUDENT, load_bundle, save_bundle
from stablemo.inference.pipeline import Pipeline, Request
from stablemo.text.encoders import get_encoder
from stablemo.text.familiar import sentence_embeddings
from stablemo.text.length import ENTRY, FILE, LengthBins, LengthFit, LengthPredictor

# the tiny bundle's range (tests/conftest.py): 8-40 frames, a UNet of length multiple 2
SHORT, LONG = ["a person waves", "someone waves a hand", "a man bows"], ["a person walks in a big circle",
                                                                         "someone walks around a circle"]


@pytest.fixture(scope="module")
def toy():
    """A predictor trained on five captions: the waves and the bow are 12 frames, circles 36."""
    encoder = get_encoder()
    texts = SHORT + LONG
    emb = sentence_embeddings(encoder, texts)
    frames = torch.tensor([12] * len(SHORT) + [36] * len(LONG))
    settings = LengthFit(bin_frames=4, hidden=16, dropout=0.0, lr=0.01, weight_decay=0.01, batch_size=4,
                         max_epochs=60, patience=60, seed=0, windows=(1,))
    predictor, fit = LengthPredictor.fit((emb, frames), (emb, frames), LengthBins(8, 40, 4), encoder.name, settings)
    return predictor, fit, emb, frames, settings


@pytest.fixture()
def tiny(tmp_path):
    from conftest import make_tiny_bundle

    return make_tiny_bundle(tmp_path / "tiny")


def with_predictor(bundle, predictor) -> None:
    config = json.loads((bundle / "config.json").read_text())
    config[ENTRY] = predictor.write(bundle, {"note": "test"})
    (bundle / "config.json").write_text(json.dumps(config))


def test_bins_cover_the_range_and_name_their_middle():
    bins = LengthBins(40, 196, 4)
    assert bins.count == 40
    assert bins.of(torch.tensor([1, 40, 43, 44, 196, 500])).tolist() == [0, 0, 0, 1, 39, 39]
    assert bins.frames(torch.tensor([0, 1, 39])).tolist() == [42, 46, 196]  # the last bin is 196 alone
    with pytest.raises(StableMoError, match="length bins"):
        LengthBins(50, 40, 4)


def test_training_is_seeded_and_learns_the_lengths(toy):
    predictor, fit, emb, frames, settings = toy
    assert predictor.mode_frames(emb).tolist() == [14] * len(SHORT) + [38] * len(LONG)  # the bins' middles
    again, _ = LengthPredictor.fit((emb, frames), (emb, frames), predictor.bins, predictor.encoder, settings)
    assert all(torch.equal(a, b) for a, b in zip(predictor.net.state_dict().values(), again.net.state_dict().values()))
    numbers = predictor.measure(emb, frames)
    assert numbers["within_one_bin"] == 1.0 and numbers["median_abs_error_frames"] == 2.0 and 1 <= fit["epoch"] <= 60


def test_the_predictor_goes_through_a_bundle_and_sets_the_length(toy, tiny):
    predictor = toy[0]
    with_predictor(tiny, predictor)
    assert (tiny / FILE).stat().st_size < 64_000
    pipe = Pipeline.from_bundle(tiny, fast=False)
    back = pipe.length_predictor
    assert back.bins == predictor.bins and back.encoder == "minilm"
    texts = ["a person waves", "a person walks in a big circle"]
    assert pipe.text_lengths(texts) == [14, 38]  # at the network's multiple of 2
    out = pipe.generate(texts, steps=2)  # no lengths: each text's own
    assert out.lengths == [14, 38] and out.info["lengths_from"] == ["text", "text"]
    assert [len(j) for j in out.joint_list()] == [14, 38]
    out = pipe.generate(texts, [20, None], steps=2)  # a given length wins; None is the text's
    assert out.lengths == [20, 38] and out.info["lengths_from"] == ["given", "text"]
    assert pipe.generate(Request(texts, 24, steps=2)).lengths == [24, 24]


def test_a_bundle_without_a_predictor_takes_the_default_length(tiny):
    pipe = Pipeline.from_bundle(tiny, fast=False)
    assert pipe.length_predictor is None and pipe.text_lengths(["a person waves"]) == [pipe.inference.default_frames]
    out = pipe.generate(["a person waves"], steps=2)
    assert out.lengths == [40] and out.info["lengths_from"] == ["default"]  # 6 s, capped at the tiny range's 40


def test_a_bundle_written_from_a_config_with_a_predictor_does_not_claim_it(toy, tiny, tmp_path):
    """A student exported from its teacher's config holds no length.safetensors: no entry naming it."""
    with_predictor(tiny, toy[0])
    bundle = load_bundle(tiny)
    out = save_bundle(tmp_path / "copy", bundle.config, bundle.state_dict)
    assert ENTRY not in json.loads((out / "config.json").read_text()) and not (out / FILE).exists()
    assert Pipeline.from_bundle(out, fast=False).length_predictor is None


def test_exporting_over_a_bundle_with_a_predictor_replaces_it_whole(toy, tiny):
    """`stablemo export ... --overwrite` onto a bundle a later step gave a predictor: the new bundle
    replaces it (the added file goes with the old one); a file nobody wrote there still refuses."""
    with_predictor(tiny, toy[0])
    bundle = load_bundle(tiny)
    save_bundle(tiny, bundle.config, bundle.state_dict, overwrite=True)
    assert not (tiny / FILE).exists() and ENTRY not in json.loads((tiny / "config.json").read_text())
    (tiny / "notes.txt").write_text("mine")
    with pytest.raises(StableMoError, match="exists|not a bundle|holds|changed"):
        save_bundle(tiny, bundle.config, bundle.state_dict, overwrite=True)
    assert (tiny / "notes.txt").read_text() == "mine"


def test_a_broken_predictor_is_one_line_naming_the_file(toy, tiny):
    from safetensors.torch import load_file, save_file

    with_predictor(tiny, toy[0])
    path = tiny / FILE
    tensors = load_file(path)
    tensors["out.bias"][3] = float("nan")
    save_file(tensors, path)
    with pytest.raises(StableMoError, match=rf"^{path}: the length predictor's weights hold NaN/Inf"):
        Pipeline.from_bundle(tiny, fast=False)
    path.write_bytes(b"\x10\x00\x00\x00\x00\x00\x00\x00{not a header}")
    with pytest.raises(StableMoError, match=rf"^{path}: unreadable safetensors file"):
        Pipeline.from_bundle(tiny, fast=False)
    save_file({"out.bias": tensors["out.bias"]}, path)
    with pytest.raises(StableMoError, match=rf"^{path}: expected tensors"):
        Pipeline.from_bundle(tiny, fast=False)
    path.unlink()
    with pytest.raises(StableMoError, match="length_predictor' names length.safetensors, which the bundle does not hold"):
        Pipeline.from_bundle(tiny, fast=False)


def test_a_predictor_of_another_encoder_or_range_is_refused(toy, tiny):
    with_predictor(tiny, toy[0])
    config = json.loads((tiny / "config.json").read_text())
    for change, said in (({"encoder": "clip"}, "reads text encoder 'clip'"), ({"width": 5}, "expected tensors"),
                         ({"min_frames": "8"}, "must be an object"), ({"window": 2}, "window must be an odd")):
        (tiny / "config.json").write_text(json.dumps({**config, ENTRY: {**config[ENTRY], **change}}))
        with pytest.raises(StableMoError, match=said):
            Pipeline.from_bundle(tiny, fast=False)


def test_nearest_length_keeps_the_range_and_the_multiple():
    from stablemo.inference.config import InferenceConfig

    inf = InferenceConfig(min_length=40, max_length=196)
    assert [inf.nearest_length(n, 8) for n in (10, 43, 44, 100, 196, 300)] == [40, 40, 48, 104, 192, 192]
    assert inf.nearest_length(41, 1) == 41
    assert InferenceConfig(min_length=9, max_length=11).nearest_length(30, 8) == 11  # no multiple of 8 in range


# ---- the shipped models -----------------------------------------------------------------------


@pytest.fixture(scope="module")
def teacher():
    return Pipeline.from_bundle(DEMO_BUNDLE)


def test_the_shipped_teacher_gives_more_counts_more_time(teacher):
    texts = ["a person jumps in place once", "a person jumps in place twice", "a person jumps in place three times",
             "a person walks forward"]
    once, twice, thrice, walk = lengths = teacher.text_lengths(texts)
    # training clips: one jump 40-45 frames, two 56-71, three 80-97, a walk forward 61-114 (median 88)
    assert once < twice < thrice and twice < walk
    assert 56 <= twice <= 71 and 80 <= thrice <= 97
    assert all(n % teacher.length_multiple == 0 for n in lengths) and teacher.length_multiple == 4


def test_every_shipped_model_carries_the_same_predictor():
    entries = [json.loads((b / "config.json").read_text())[ENTRY] for b in (DEMO_BUNDLE, DEMO_STUDENT, DEMO_CONTROLNET)]
    assert all(e == entries[0] for e in entries)
    # one constant length for every text (the train split's most common bin) measured 0.17 and 21 frames
    assert entries[0]["test"]["within_one_bin"] > 0.3 and entries[0]["test"]["median_abs_error_frames"] <= 12
    assert all((b / FILE).read_bytes() == (DEMO_BUNDLE / FILE).read_bytes() for b in (DEMO_STUDENT, DEMO_CONTROLNET))


def test_generate_without_a_length_says_the_text_chose_it(tmp_path, capsys):
    import numpy as np

    from stablemo.cli import main

    assert main(["generate", "a person jumps in place twice", "--bundle", str(DEMO_STUDENT), "--out", str(tmp_path),
                 "--no-render"]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    frames = Pipeline.from_bundle(DEMO_STUDENT).text_lengths(["a person jumps in place twice"])[0]
    assert f"{frames} frames ({frames / 20:g} s, length from the text)" in line
    assert len(np.load(next(tmp_path.glob("*joints.npy")))) == frames
    assert main(["generate", "a person jumps in place twice", "--bundle", str(DEMO_STUDENT), "--out",
                 str(tmp_path / "given"), "--no-render", "--seconds", "5"]) == 0
    # 5 s is longer than a double jump takes: the jumps, then standing (tests/test_plan.py)
    assert "100 frames (5 s; in parts: 'a person jumps in place twice' 3.2 s, 'a person stands still.' 1.8 s) ->" \
        in capsys.readouterr().out


def test_the_server_takes_the_text_length_when_none_or_auto_is_given():
    from stablemo.serve.models import ModelSet

    models = ModelSet({"student": DEMO_STUDENT})
    frames = models.models["student"].pipeline.text_lengths(["a person claps twice"])[0]
    for body in ({}, {"seconds": None}, {"seconds": "auto"}, {"frames": "auto"}):
        spec, _ = models.parse({"text": "a person claps twice", **body})
        assert (spec.frames, spec.length_from) == (frames, "text")
    spec, _ = models.parse({"text": "a person claps twice", "seconds": 3})
    assert (spec.frames, spec.length_from) == (60, "given")
    with pytest.raises(StableMoError, match="seconds: expected a number"):
        models.parse({"text": "a person claps twice", "seconds": "soon"})
    motion, _ = models.generate(models.parse({"text": "a person claps twice", "frames": "auto"})[0])
    assert len(motion.joints) == frames


def test_copied_demo_bundle_without_the_file_entry_falls_back(tmp_path):
    bundle = tmp_path / "b"
    shutil.copytree(DEMO_STUDENT, bundle)
    (bundle / FILE).unlink()
    config = json.loads((bundle / "config.json").read_text())
    del config[ENTRY]
    (bundle / "config.json").write_text(json.dumps(config))
    pipe = Pipeline.from_bundle(bundle)
    assert pipe.text_lengths(["a person jumps in place twice"]) == [120]


def test_the_script_trains_on_a_data_folder_and_mends_a_bundles_predictor(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    from stablemo.cli import main

    assert main(["data", "synth", "--out", str(tmp_path / "data"), "--num", "24", "--seed", "0"]) == 0
    from safetensors.torch import load_file, save_file

    bundle = tmp_path / "student"
    shutil.copytree(DEMO_STUDENT, bundle)
    tensors = load_file(bundle / FILE)
    tensors["hidden.bias"][0] = float("nan")  # a broken predictor, which the script writes again
    save_file(tensors, bundle / FILE)
    script = Path(__file__).resolve().parents[1] / "scripts/text/length_predictor.py"
    run = subprocess.run([sys.executable, str(script), "--data", str(tmp_path / "data"), str(bundle)],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "test: {'n': " in run.stdout and "actions whose lengths grow with the count" in run.stdout
    entry = json.loads((bundle / "config.json").read_text())[ENTRY]
    assert entry["fit"]["data"] == str(tmp_path / "data") and entry["val"]["n"] > 0 and entry["test"]["n"] > 0
    assert entry["window"] == entry["fit"]["window"] in (1, 3, 5)
    pipe = Pipeline.from_bundle(bundle)
    assert pipe.length_predictor.bins == LengthBins(40, 196, 4)
    assert 40 <= pipe.text_lengths(["a person claps twice"])[0] <= 196
