"""No raw tracebacks and no misleading messages: each input a tester found ending in a traceback is
one error line naming the argument or file; a full disk or a Ctrl-C is one line too; refusals of
pickled files never advise weights_only=False; a resumed run trains at the lr it was given."""

from __future__ import annotations

import argparse
import errno
import os
import pickle
import re
from pathlib import Path

import numpy as np
import pytest
import torch

from stablemo import cli
from stablemo.errors import one_line
from stablemo.training.checkpoint_io import load_checkpoint_file

REPO = Path(__file__).resolve().parents[1]
DEMO_BUNDLE = REPO / "stablemo" / "assets" / "demo_bundle"
NETS_CONFIG = REPO / "configs" / "nets" / "unet_baseline.yaml"
# torch's advice in any of its wordings: "weights_only=False", "`weights_only` set to `False`"
UNSAFE_ADVICE = re.compile(r"weights_only`?\s*(=|set to|to)\s*`?False", re.IGNORECASE)


def run(capsys, argv) -> tuple[int, str]:
    rc = cli.main([str(a) for a in argv])
    return rc, capsys.readouterr().err.strip()


def assert_error_line(rc: int, err: str, command: str, *needles: str, code: int = 2) -> None:
    assert rc == code, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert err.startswith(f"stablemo {command}: error: "), err
    for needle in needles:
        assert needle in err, err


# ---------------------------------------------------------------------------------------------- pickles


class _Evil:
    def __reduce__(self):
        return (os.system, ("true",))


def _pickled_files(folder: Path) -> dict[str, Path]:
    """Files weights_only refuses, one per wording of torch's refusal."""
    files = {"namespace": folder / "namespace.ckpt", "legacy": folder / "legacy.ckpt",
             "code": folder / "code.ckpt", "raw": folder / "raw.pkl"}
    torch.save({"state_dict": {}, "x": argparse.Namespace(a=1)}, files["namespace"])
    torch.save({"x": argparse.Namespace(a=1)}, files["legacy"], _use_new_zipfile_serialization=False)
    torch.save({"x": _Evil()}, files["code"])  # "Trying to load unsupported GLOBAL posix.system ..."
    files["raw"].write_bytes(pickle.dumps({"x": argparse.Namespace(a=1)}, protocol=4))  # "Unsupported operand"
    return files


def test_one_line_drops_the_weights_only_false_advice_of_every_refusal(tmp_path):
    for kind, path in _pickled_files(tmp_path).items():
        with pytest.raises(Exception) as caught:
            torch.load(path, weights_only=True)
        raw = str(caught.value)
        assert UNSAFE_ADVICE.search(raw), kind  # what torch says (the test would mean nothing otherwise)
        for message in (raw, f"{path}: not a loadable checkpoint ({type(caught.value).__name__}: {raw})",
                        f"{path}: not a weights-only torch checkpoint ({raw})"):
            line = one_line(message)
            assert not UNSAFE_ADVICE.search(line) and "\n" not in line and "\x1b[" not in line, (kind, line)
            assert "safe loading (weights_only) refuses" in line, (kind, line)
        assert one_line(f"x ({raw})").endswith(")") and "Check the documentation" not in one_line(raw)
    assert "GLOBAL argparse.Namespace" in one_line(str(_load_error(tmp_path / "namespace.ckpt")))
    assert "posix.system" in one_line(str(_load_error(tmp_path / "code.ckpt")))


def _load_error(path: Path) -> Exception:
    try:
        torch.load(path, weights_only=True)
    except Exception as err:  # noqa: BLE001 - the refusal itself is under test
        return err
    raise AssertionError(f"{path} loaded")


def test_no_command_advises_weights_only_false_for_a_pickled_file(tmp_path, capsys):
    files = _pickled_files(tmp_path)
    motion = tmp_path / "walk.features.npy"
    np.save(motion, np.zeros((8, 263), np.float32))
    for kind, path in files.items():
        commands = [
            ("export", [path, "--out", tmp_path / "bundle"]),
            ("fit", ["--config", REPO / "configs" / "demo.yaml", "--ckpt_path", path]),
            ("footskate", [motion, "--out", tmp_path / "clean.npy", "--weights", path]),
        ]
        for command, args in commands:
            rc, err = run(capsys, [command, *args])
            assert_error_line(rc, err, command, path.name)
            assert not UNSAFE_ADVICE.search(err), (kind, command, err)
        with pytest.raises(Exception) as caught:
            load_checkpoint_file(path)
        assert not UNSAFE_ADVICE.search(one_line(str(caught.value)))
    assert not (tmp_path / "bundle").exists() and not (tmp_path / "clean.npy").exists()


# ---------------------------------------------------------------------------------------------- inputs


def test_bench_aits_frames_beyond_the_model_is_one_line_before_compute(capsys):
    base = ["bench", "aits", "--bundle", DEMO_BUNDLE, "--random-weights", "--repeats", "1", "--steps", "1"]
    rc, err = run(capsys, [*base, "--frames", "1000000"])
    assert_error_line(rc, err, "bench", "--frames", "1000000")
    rc, err = run(capsys, [*base, "--frames", "5000"])  # within any network's bound, beyond this bundle's
    assert_error_line(rc, err, "bench", "--frames", "5000", "[40, 196]")


@pytest.mark.parametrize("content, needles", [
    ("name: unet\nbase_channels: abc\n", ["cfg.yaml", "'unet'", "base_channels"]),
    ("name: unet\nchannel_mults: 5\n", ["cfg.yaml", "channel_mults"]),
    ("name: unet\nbase_channels: -4\n", ["cfg.yaml", "base_channels"]),
    ("name: nosuch\n", ["unknown 'nosuch'"]),
    ("- 1\n- 2\n", ["cfg.yaml", "no model description"]),
    ("name: unet\nbase_channels: [\n", ["cfg.yaml: line 3", "not valid YAML"]),
])
def test_nets_summary_bad_config_is_one_line(tmp_path, capsys, content, needles):
    config = tmp_path / "cfg.yaml"
    config.write_text(content)
    rc, err = run(capsys, ["nets", "summary", "--config", config, "--length", "8"])
    assert_error_line(rc, err, "nets", *needles)
    assert "<unicode string>" not in err


@pytest.mark.parametrize("flag, value", [
    ("--length", "0"), ("--length", "-1"), ("--length", "100000000"), ("--text-length", "-1"),
    ("--text-length", "0"), ("--input-dim", "0"), ("--text-dim", "-5"), ("--depth", "-1"), ("--seed", "-1"),
])
def test_nets_summary_bad_sizes_are_one_line(capsys, flag, value):
    rc, err = run(capsys, ["nets", "summary", "--config", NETS_CONFIG, flag, value])
    assert_error_line(rc, err, "nets", flag, value)


def test_control_file_of_zero_frames_is_one_line(tmp_path, capsys):
    joints = tmp_path / "empty.joints.npy"
    np.save(joints, np.zeros((0, 22, 3), np.float32))
    for extra in ([], ["--as-is"]):
        rc, err = run(capsys, ["control-file", joints, "--out", tmp_path / "c.npz", *extra])
        assert_error_line(rc, err, "control-file", "empty.joints.npy", "no frames")
    assert not (tmp_path / "c.npz").exists()


def test_bvh_of_one_frame_writes_and_of_zero_frames_is_one_line(tmp_path, capsys):
    from stablemo.motion import features_to_joints, get_skeleton

    rng = np.random.default_rng(0)
    features = (rng.normal(size=(2, 263)) * 0.1).astype(np.float32)
    joints = features_to_joints(features, get_skeleton("humanml3d")).astype(np.float32)
    for name, array in (("one.joints.npy", joints[:1]), ("one.features.npy", features[:1])):
        np.save(tmp_path / name, array)
        for out in ("one.bvh", "one.npz"):
            rc, err = run(capsys, ["bvh", tmp_path / name, "--out", tmp_path / out])
            assert rc == 0 and "Traceback" not in err, err
    for name, shape in (("zero.joints.npy", (0, 22, 3)), ("zero.features.npy", (0, 263))):
        np.save(tmp_path / name, np.zeros(shape, np.float32))
        rc, err = run(capsys, ["bvh", tmp_path / name, "--out", tmp_path / "zero.bvh"])
        assert_error_line(rc, err, "bvh", name, "no frames")
    assert not (tmp_path / "zero.bvh").exists()


def _tiny_fit_config(tmp_path: Path, data: Path) -> Path:
    from test_training import (
        tiny_config,  # the training tests' tiny model and run folder
    )

    return tiny_config(tmp_path / "run", data)


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory) -> Path:
    from test_training import write_random_dataset

    return write_random_dataset(tmp_path_factory.mktemp("data") / "tiny")


@pytest.mark.parametrize("flag, value", [("--trainer.max_steps", "-5"), ("--trainer.max_epochs", "-7")])
def test_fit_trainer_values_lightning_refuses_are_one_line(tmp_path, capsys, tiny_data, flag, value):
    config = _tiny_fit_config(tmp_path, tiny_data)
    rc, err = run(capsys, ["fit", "--config", config, f"{flag}={value}"])
    err = err.splitlines()[-1] if err.startswith("Seed set") else err  # LightningCLI's seed_everything note
    assert_error_line(rc, err, "fit", flag, value)
    assert not (tmp_path / "run" / "checkpoints").exists()


def test_broken_yaml_config_names_the_file_and_line(tmp_path, capsys):
    broken = tmp_path / "broken.yaml"
    broken.write_text("trainer:\n  max_steps: [\n")
    for argv in (["--config", broken], [f"--config={broken}"],
                 ["--config", REPO / "configs" / "demo.yaml", "--config", broken]):
        rc, err = run(capsys, ["fit", *argv])
        assert_error_line(rc, err, "fit", f"--config: {broken}: line 3", "not valid YAML")
        assert "<unicode string>" not in err


# ---------------------------------------------------------------------------------------------- the machine


class _FullDisk:
    """A file object whose writes fail as on a full disk after `room` bytes: OSError(ENOSPC), no file name."""

    def __init__(self, f, room: int = 64):
        self._f, self._room = f, room

    def write(self, data) -> int:
        if self._room < len(data):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self._room -= len(data)
        return self._f.write(data)

    def __getattr__(self, name):
        return getattr(self._f, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return self._f.__exit__(*exc)


@pytest.fixture
def full_disk(monkeypatch):
    """Every atomic write (the project's only way to write) fails with ENOSPC after a few bytes."""
    from footskate import atomicio

    real_fdopen = os.fdopen
    monkeypatch.setattr(atomicio.os, "fdopen", lambda fd, *a, **k: _FullDisk(real_fdopen(fd, *a, **k)))


def test_full_disk_during_generate_is_one_line_naming_the_file(tmp_path, capsys, full_disk):
    out = tmp_path / "out"
    rc, err = run(capsys, ["generate", "a person walks", "--frames", "40", "--steps", "1", "--no-render",
                           "--out", out])
    err = err.splitlines()[-1] if err else err  # the sampler's progress bar shares stderr
    assert_error_line(rc, err, "generate", str(out), ".npy", "no space left on device", code=1)
    assert not out.exists() or not [p for p in out.rglob("*") if p.is_file()]  # no partial file


def test_full_disk_during_checkpointing_is_one_line_naming_the_file(tmp_path, capsys, tiny_data, full_disk):
    config = _tiny_fit_config(tmp_path, tiny_data)
    rc, err = run(capsys, ["fit", "--config", config, "--trainer.max_steps=3"])
    lines = [line for line in err.splitlines() if line.startswith("stablemo fit")]
    assert "Traceback" not in err, err
    assert len(lines) == 1 and lines[0] == err.splitlines()[-1], err
    assert_error_line(rc, lines[0], "fit", str(tmp_path / "run" / "checkpoints"), ".ckpt",
                      "no space left on device", code=1)
    checkpoints = tmp_path / "run" / "checkpoints"
    assert not checkpoints.exists() or not list(checkpoints.iterdir())  # neither a checkpoint nor a temp file


def test_ctrl_c_is_one_interrupted_line_with_exit_130(tmp_path, capsys, monkeypatch):
    from stablemo.bvh import writer

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    np.save(tmp_path / "m.npy", np.zeros((4, 263), np.float32))
    monkeypatch.setattr(writer, "motion_joints", interrupted)
    rc, err = run(capsys, ["bvh", tmp_path / "m.npy", "--out", tmp_path / "m.bvh"])
    assert (rc, err) == (130, "stablemo bvh: interrupted")
    assert not (tmp_path / "m.bvh").exists()


def test_ctrl_c_during_fit_is_one_interrupted_line_with_exit_130(tmp_path, capsys, tiny_data, monkeypatch):
    import signal

    from stablemo.training.module import DiffusionModule

    step = DiffusionModule.training_step

    def interrupted_at_step_2(self, batch, batch_idx):
        if self.global_step == 2:
            raise KeyboardInterrupt
        return step(self, batch, batch_idx)

    monkeypatch.setattr(DiffusionModule, "training_step", interrupted_at_step_2)
    config = _tiny_fit_config(tmp_path, tiny_data)
    handler = signal.getsignal(signal.SIGINT)
    try:
        rc, err = run(capsys, ["fit", "--config", config, "--trainer.max_steps=5"])
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # Lightning had left it ignored
    finally:
        signal.signal(signal.SIGINT, handler)
    assert rc == 130 and err.splitlines()[-1] == "stablemo fit: interrupted", err
    assert "Traceback" not in err
    checkpoints = tmp_path / "run" / "checkpoints"
    assert not [p for p in checkpoints.iterdir() if p.name.startswith(".")] if checkpoints.exists() else True


# ---------------------------------------------------------------------------------------------- resume lr


def test_resume_with_a_new_lr_trains_at_it(tmp_path, tiny_data):
    """--model.lr given when resuming is the optimiser's lr (the checkpoint's was kept before), so
    a diverged run resumed "with a lower --model.lr", as the guard's message advises, takes it."""
    from stablemo.cli.train import main_fit

    config = _tiny_fit_config(tmp_path, tiny_data)  # lr 1e-3
    last = tmp_path / "run" / "checkpoints" / "last.ckpt"
    assert main_fit(["--config", str(config), "--trainer.max_steps=3"]) == 0
    before = load_checkpoint_file(last)
    assert before["optimizer_states"][0]["param_groups"][0]["lr"] == pytest.approx(1e-3)
    assert main_fit(["--config", str(config), "--ckpt_path=last", "--trainer.max_steps=4", "--model.lr=1e-9"]) == 0
    after = load_checkpoint_file(last)
    assert after["global_step"] == 4 and after["hyper_parameters"]["lr"] == 1e-9
    group = after["optimizer_states"][0]["param_groups"][0]
    assert group["lr"] == pytest.approx(1e-9, rel=1e-6) and group["initial_lr"] == 1e-9
    assert after["lr_schedulers"][0]["base_lrs"] == [1e-9]
    # one AdamW step moves a weight by about lr (its update is normalised): 1e-9, not 1e-3
    moved = max((after["state_dict"][k] - v).abs().max().item()
                for k, v in before["state_dict"].items() if v.is_floating_point() and k.startswith("model."))
    assert 0 < moved < 1e-6


def test_standalone_footskate_refuses_a_pickle_in_one_line_without_unsafe_advice(tmp_path):
    """`python -m footskate.command` (no stablemo) cleans torch's refusal as the stablemo CLI does:
    one line naming the file and the refused global, never the weights_only=False advice."""
    import subprocess
    import sys

    import torch

    bad = tmp_path / "bad.pt"
    torch.save({"x": _Pickled()}, bad)
    joints = tmp_path / "j.npy"
    np.save(joints, np.zeros((20, 22, 3), np.float32) + np.linspace(0, 1.7, 22)[None, :, None])
    proc = subprocess.run([sys.executable, "-m", "footskate.command", str(joints), "--out", str(tmp_path / "o.npy"),
                           "--weights", str(bad)], capture_output=True, text=True, timeout=120,
                          cwd=Path(__file__).resolve().parents[1])
    err = proc.stderr.strip()
    assert proc.returncode == 2 and len(err.splitlines()) == 1 and str(bad) in err, err
    assert "refuses" in err and "weights_only=False" not in err and "Re-running" not in err
    assert not (tmp_path / "o.npy").exists()


class _Pickled:
    pass
