"""Issue 18, training and data side: exact resume, out-of-range data, unloadable checkpoints and text
encoders, and the messages of `fit` after a resume. Each goes through the real CLI where a user would."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from test_training import tiny_config, write_random_dataset

from stablemo.cli import main as cli
from stablemo.training.checkpoint_io import load_checkpoint_file

REPO = Path(__file__).resolve().parents[1]


def _run_cli(args: list[str], capsys) -> tuple[int, list[str]]:
    """Exit code and the non-empty stderr lines of `stablemo ARGS`."""
    capsys.readouterr()
    code = cli(args)
    err = capsys.readouterr().err
    return code, [line for line in err.splitlines() if line.strip()]


def _error_lines(lines: list[str]) -> list[str]:
    assert not any("Traceback" in line for line in lines), "\n".join(lines)
    return [line for line in lines if ": error: " in line]


def _fresh_text_caches() -> None:
    """What a new process starts with: no cached text features (the frozen encoders are shared
    module-wide, so in-process runs would otherwise reuse each other's)."""
    from stablemo.text import encoders

    for encoder in list(encoders._ENCODERS.values()):
        encoder.clear_cache()


@pytest.fixture(scope="module")
def synth_data(tmp_path_factory) -> Path:
    """The synthetic benchmark's captions (many lengths, repeated phrasings), 60 motions."""
    from stablemo.data.synth import write_dataset

    return write_dataset(tmp_path_factory.mktemp("synth") / "synth", 60, 0, workers=1)


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory) -> Path:
    return write_random_dataset(tmp_path_factory.mktemp("data") / "tiny")


PHRASES = ["jump", "a person walks", "someone runs forward quickly, then stops and looks around",
           "a man waves his right hand above his head twice", "the person kicks",
           "a figure turns left, takes three steps and sits down on a chair"]


@pytest.fixture(scope="module")
def repeated_captions_data(tmp_path_factory) -> Path:
    """Few captions of many lengths, each used by several clips: every batch after the first ones
    holds captions that an earlier, differently padded batch already encoded."""
    root = write_random_dataset(tmp_path_factory.mktemp("data") / "repeated")
    for i, path in enumerate(sorted((root / "texts").glob("*.txt"))):
        lines = [f"{PHRASES[(i + k) % len(PHRASES)]}#{PHRASES[(i + k) % len(PHRASES)].split()[0]}/X#0.0#0.0"
                 for k in (0, 3)]
        path.write_text("\n".join(lines) + "\n")
    return root


def _weights_equal(a: dict, b: dict) -> None:
    assert a["global_step"] == b["global_step"]
    for key in a["state_dict"]:
        assert torch.equal(a["state_dict"][key], b["state_dict"][key]), key
    ema_a, ema_b = a["stablemo"]["ema"], b["stablemo"]["ema"]
    assert ema_a["num_updates"] == ema_b["num_updates"] == a["global_step"]
    for key in ema_a["shadow"]:
        assert torch.equal(ema_a["shadow"][key], ema_b["shadow"][key]), key
    opt_a, opt_b = a["optimizer_states"][0]["state"], b["optimizer_states"][0]["state"]
    for idx in opt_a:
        for name in ("exp_avg", "exp_avg_sq"):
            assert torch.equal(opt_a[idx][name], opt_b[idx][name]), (idx, name)
    assert a["lr_schedulers"] == b["lr_schedulers"]


# ---------------------------------------------------------------------------------------------- item 5


@pytest.mark.parametrize("every", [3, 4], ids=["periodic_save", "final_step_save"])
def test_resume_in_a_new_process_is_bit_exact(repeated_captions_data, tmp_path, capsys, every):
    """8 steps straight == 3 steps, then `--ckpt_path last` to 8, each fit starting like a new process
    (empty text cache). Failed before, for two reasons, each enough on its own:
    - every=4: the 3-step last.ckpt is written when training ends (3 is not a multiple of 4), and its
      loop state counted the epoch as finished: the resumed run started the next epoch (other batches);
    - both: the text cache kept the features of a caption from whichever padded batch encoded it
      first, which differ in the last bits between the two histories."""
    straight, split = tmp_path / "straight", tmp_path / "split"
    over = {"trainer.max_steps": 8, "checkpoint.every_n_train_steps": every}
    _fresh_text_caches()
    assert _run_cli(["fit", "--config", str(tiny_config(straight, repeated_captions_data, **over))], capsys)[0] == 0
    cfg = tiny_config(split, repeated_captions_data, **over)
    _fresh_text_caches()
    assert _run_cli(["fit", "--config", str(cfg), "--trainer.max_steps=3"], capsys)[0] == 0
    _fresh_text_caches()
    assert _run_cli(["fit", "--config", str(cfg), "--ckpt_path=last"], capsys)[0] == 0
    a = load_checkpoint_file(straight / "checkpoints" / "last.ckpt")
    b = load_checkpoint_file(split / "checkpoints" / "last.ckpt")
    assert a["global_step"] == 8
    _weights_equal(a, b)


def test_text_features_do_not_depend_on_the_batch_or_the_cache():
    """The cause of the resume difference, pinned: a caption's frozen features are the same bits alone,
    in a padded batch, and from the cache."""
    from stablemo.text import get_encoder

    encoder = get_encoder("minilm")
    captions = ["a person walks forward, then turns around and walks back to where they started", "jump", ""]
    encoder.clear_cache()
    batched = encoder.encode(captions)
    encoder.clear_cache()
    for caption, features in zip(captions, batched):
        assert torch.equal(encoder.encode([caption])[0], features), caption
    assert torch.equal(encoder.encode(captions[::-1])[2], batched[0])  # now from the cache


@pytest.mark.slow  # three fresh processes, 60 optimiser steps each way: ~1-3 min on 2 busy cores
def test_resume_25_then_60_in_new_processes_matches_60_straight(synth_data, tmp_path):
    """The issue's recipe: 25 steps, resume with `--ckpt_path last` to 60 (mid-epoch), vs 60 straight."""
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONWARNINGS="ignore")

    def fit(*args: str) -> None:
        proc = subprocess.run([sys.executable, "-m", "stablemo.cli", "fit", *args], cwd=REPO, env=env,
                              capture_output=True, text=True, timeout=900)
        assert proc.returncode == 0, proc.stderr[-3000:]

    # step 25 is not a multiple of 20: the 25-step last.ckpt is the final-step save, as in the issue
    over = {"trainer.max_steps": 60, "checkpoint.every_n_train_steps": 20}
    straight, split = tmp_path / "straight", tmp_path / "split"
    fit("--config", str(tiny_config(straight, synth_data, **over)))
    cfg = tiny_config(split, synth_data, **over)
    fit("--config", str(cfg), "--trainer.max_steps=25")
    fit("--config", str(cfg), "--ckpt_path=last")
    _weights_equal(load_checkpoint_file(straight / "checkpoints" / "last.ckpt"),
                   load_checkpoint_file(split / "checkpoints" / "last.ckpt"))


# ---------------------------------------------------------------------------------------------- item 6


def _copy_data(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns(".stablemo_cache"))
    return dst


def test_huge_finite_feature_values_are_reported_and_refused(tiny_data, tmp_path, capsys):
    root = _copy_data(tiny_data, tmp_path / "data")
    bad = root / "new_joint_vecs" / "000002.npy"  # in train.txt
    x = np.load(bad)
    x[7, 11] = 3e38  # finite in float32; (x - mean) / std overflows
    np.save(bad, x)
    capsys.readouterr()
    assert cli(["data", "check", str(root)]) == 1
    report = capsys.readouterr().out
    assert "problems: none" not in report
    assert f"{bad}: 1 value(s) with |x| > 10000 (largest 3e+38), first in frame 7" in report

    code, lines = _run_cli(["fit", "--config", str(tiny_config(tmp_path / "run", root))], capsys)
    errors = _error_lines(lines)
    assert code == 2 and len(errors) == 1 and str(bad) in errors[0] and "|x| > 10000" in errors[0], lines
    assert not (tmp_path / "run" / "checkpoints").exists()  # refused before any step


def test_tiny_or_huge_std_is_reported_and_refused(tiny_data, tmp_path, capsys):
    root = _copy_data(tiny_data, tmp_path / "data")
    std = np.load(root / "Std.npy")
    std[40] = 1e-9
    np.save(root / "Std.npy", std)
    capsys.readouterr()
    assert cli(["data", "check", str(root)]) == 1
    report = capsys.readouterr().out
    assert f"{root / 'Std.npy'}: 1 value(s) below 1e-08 (dim 40 is 1e-09)" in report
    code, lines = _run_cli(["fit", "--config", str(tiny_config(tmp_path / "run", root))], capsys)
    errors = _error_lines(lines)
    assert code == 2 and len(errors) == 1 and "Std.npy: 1 value(s) below 1e-08" in errors[0], lines

    std[40] = 5e5
    np.save(root / "Std.npy", std)
    assert cli(["data", "check", str(root)]) == 1
    assert f"{root / 'Std.npy'}: 1 value(s) with |x| > 10000 (dim 40 is 500000)" in capsys.readouterr().out


def test_skip_bad_warns_once_and_also_skips_out_of_range_clips(tiny_data, tmp_path, capsys):
    root = _copy_data(tiny_data, tmp_path / "data")
    nan_clip, huge_clip = root / "new_joint_vecs" / "000001.npy", root / "new_joint_vecs" / "000004.npy"
    x = np.load(nan_clip)
    x[3, 3] = np.nan
    np.save(nan_clip, x)
    x = np.load(huge_clip)
    x[0, 0] = -2e5
    np.save(huge_clip, x)
    cfg = tiny_config(tmp_path / "run", root, **{"trainer.max_steps": 1})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code, lines = _run_cli(["fit", "--config", str(cfg), "--data.skip_bad=true"], capsys)
    assert code == 0, lines
    messages = [str(w.message) for w in caught]
    skipped = [m for m in messages if "skipped 1 bad clip" in m]
    assert len(skipped) == 1 and str(nan_clip) in skipped[0], messages  # printed twice before
    out_of_range = [m for m in messages if "out-of-range" in m]
    assert len(out_of_range) == 1 and str(huge_clip) in out_of_range[0], messages


# ---------------------------------------------------------------------------------------------- item 7


def test_fit_ckpt_path_that_is_not_a_loadable_checkpoint(tiny_data, tmp_path, capsys):
    cfg = tiny_config(tmp_path / "run", tiny_data, **{"trainer.max_steps": 2})
    evil = tmp_path / "evil.ckpt"
    torch.save({"state_dict": {}, "payload": Path("/etc/passwd")}, evil)  # needs unpickling a class
    code, lines = _run_cli(["fit", "--config", str(cfg), "--ckpt_path", str(evil)], capsys)
    assert code == 2 and len(lines) == 1, lines
    assert str(evil) in lines[0] and "weights_only" in lines[0] and "Traceback" not in lines[0]
    assert "weights_only=False" not in lines[0]  # torch's advice to load it unsafely is not passed on

    assert _run_cli(["fit", "--config", str(cfg)], capsys)[0] == 0
    truncated = tmp_path / "truncated.ckpt"
    truncated.write_bytes((tmp_path / "run" / "checkpoints" / "last.ckpt").read_bytes()[:4096])
    code, lines = _run_cli(["fit", "--config", str(cfg), "--ckpt_path", str(truncated)], capsys)
    assert code == 2 and len(lines) == 1 and str(truncated) in lines[0], lines

    # the same file as `last`: read by the Trainer's checkpoint IO, also one line
    shutil.copy(truncated, tmp_path / "run" / "checkpoints" / "last.ckpt")
    code, lines = _run_cli(["fit", "--config", str(cfg), "--ckpt_path", "last"], capsys)
    errors = _error_lines(lines)
    assert code == 2 and len(errors) == 1 and "last.ckpt" in errors[0], lines


def _encoder_folder_with_pickled_bin(folder: Path) -> Path:
    from stablemo.text import minilm_path

    shutil.copytree(minilm_path(), folder, ignore=shutil.ignore_patterns("model.safetensors"))
    # a pickle that weights_only refuses (an arbitrary class), where transformers looks for weights
    torch.save({"embeddings.word_embeddings.weight": Path("/etc/passwd")}, folder / "pytorch_model.bin")
    return folder / "pytorch_model.bin"


def test_text_encoder_folder_with_a_pickled_bin_is_refused(tmp_path):
    from stablemo.errors import StableMoError
    from stablemo.text import FrozenTextEncoder, minilm_path

    pickled = _encoder_folder_with_pickled_bin(tmp_path / "enc")
    with pytest.raises(StableMoError) as err:
        FrozenTextEncoder(str(tmp_path / "enc"))
    message = str(err.value)
    assert str(pickled) in message and "refused" in message and "\n" not in message

    # a .bin of plain tensors is still read (weights_only), it holds nothing to unpickle
    from safetensors.torch import load_file

    plain = tmp_path / "plain"
    shutil.copytree(minilm_path(), plain, ignore=shutil.ignore_patterns("model.safetensors"))
    torch.save(load_file(minilm_path() / "model.safetensors"), plain / "pytorch_model.bin")
    assert FrozenTextEncoder(str(plain), cache_size=0).encode(["a person walks"])[0].shape[1] == 384


def test_bundle_whose_text_encoder_holds_a_pickled_bin(tmp_path, capsys):
    pickled = _encoder_folder_with_pickled_bin(tmp_path / "enc")
    bundle = tmp_path / "bundle"
    shutil.copytree(REPO / "stablemo" / "assets" / "demo_bundle", bundle)
    config = json.loads((bundle / "config.json").read_text())
    config["model"]["text"]["encoder"] = str(tmp_path / "enc")
    (bundle / "config.json").write_text(json.dumps(config))
    code, lines = _run_cli(["generate", "a person walks", "--bundle", str(bundle), "--out", str(tmp_path / "o")],
                           capsys)
    assert code == 2 and len(lines) == 1 and str(pickled) in lines[0], lines


# ---------------------------------------------------------------------------------------------- item 8


def test_nan_right_after_resume_names_the_checkpoint_it_resumed_from(tiny_data, tmp_path, capsys, monkeypatch):
    """Resumed with other checkpoint settings (as after a kill), the checkpoint callback restores no
    state of its own: the message said "none written yet" although the run started from last.ckpt."""
    from stablemo.training.module import DiffusionModule

    cfg = tiny_config(tmp_path / "run", tiny_data, **{"trainer.max_steps": 3})
    assert _run_cli(["fit", "--config", str(cfg)], capsys)[0] == 0
    last = tmp_path / "run" / "checkpoints" / "last.ckpt"
    assert load_checkpoint_file(last)["global_step"] == 3
    before = last.read_bytes()

    original = DiffusionModule.training_step

    def poisoned(self, batch, batch_idx):
        return original(self, dict(batch, motion=batch["motion"] * float("nan")), batch_idx)

    monkeypatch.setattr(DiffusionModule, "training_step", poisoned)
    code, lines = _run_cli(["fit", "--config", str(cfg), "--ckpt_path", "last", "--trainer.max_steps=6",
                            "--checkpoint.every_n_train_steps=5"], capsys)
    errors = _error_lines(lines)
    assert code == 2 and len(errors) == 1, lines
    assert "diverged at step 3" in errors[0] and "none written yet" not in errors[0]
    assert f"Last good checkpoint: {last}" in errors[0], errors[0]
    assert last.read_bytes() == before


def test_fit_ckpt_path_file_still_brings_its_hyperparameters(tiny_data, tmp_path, capsys):
    """`--ckpt_path FILE` still merges the checkpoint's hyperparameters into the config (LightningCLI's
    behaviour, now read through the safe loader): a guard for the override, passes before and after."""
    cfg = tiny_config(tmp_path / "run", tiny_data, **{"trainer.max_steps": 2})
    assert _run_cli(["fit", "--config", str(cfg), "--model.lr=0.002"], capsys)[0] == 0
    ckpt = tmp_path / "run" / "checkpoints" / "last.ckpt"
    assert _run_cli(["fit", "--config", str(cfg), "--ckpt_path", str(ckpt), "--trainer.max_steps=3"], capsys)[0] == 0
    resumed = load_checkpoint_file(ckpt)
    assert resumed["global_step"] == 3 and resumed["hyper_parameters"]["lr"] == 0.002


@pytest.mark.parametrize("extra, needles", [
    (["--model.lr", "abc"], ["model.lr: Expected a <class 'float'>", "abc"]),
    (["--model.model.denoiser.name", "foo"], ["denoiser name: unknown 'foo'"]),  # raised inside jsonargparse's instantiation
    (["--trainer.max_stepz", "3"], ["unrecognized arguments", "max_stepz"]),
])
def test_fit_bad_settings_are_one_line(extra, needles, capsys):
    rc, lines = _run_cli(["fit", "--config", str(REPO / "configs" / "synth_small.yaml"), *extra], capsys)
    assert rc == 2 and len(lines) == 1 and "usage:" not in lines[0], lines
    assert all(n in lines[0] for n in needles), lines


def test_fit_config_that_is_not_a_config_is_named_in_one_line(tmp_path, capsys):
    notes = tmp_path / "notes.txt"
    notes.write_text("just some\nlines of text\n")
    rc, lines = _run_cli(["fit", "--config", str(notes)], capsys)
    assert rc == 2 and len(lines) == 1 and str(notes) in lines[0] and "just some" not in lines[0], lines
    rc, lines = _run_cli(["fit", "--config", str(tmp_path / "missing.yaml")], capsys)
    assert rc == 2 and len(lines) == 1 and "--config: File does not exist" in lines[0], lines
