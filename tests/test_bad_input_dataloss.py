"""No data loss: a folder StableMo did not write entirely is never deleted, a replaced folder is the
old or the new one at every instant (footskate.atomicio.replace_dir), leftovers of killed writes
are cleaned by the next run, output names from user text stay inside --out, and two outputs of one
run never share a path."""

from __future__ import annotations

import fcntl
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import make_tiny_bundle

from footskate import atomicio
from stablemo.cli import main
from stablemo.data.synth import writer
from stablemo.data.synth.writer import MANIFEST, write_dataset
from stablemo.errors import StableMoError
from stablemo.outputs import files as outputs_files

REPO = Path(__file__).resolve().parents[1]
STABLEMO = Path(sys.executable).with_name("stablemo")
D = 263


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    """(exit code, stdout, stderr) of the `stablemo` entry point, in process."""
    capsys.readouterr()
    rc = main([str(a) for a in argv])
    out = capsys.readouterr()
    return rc, out.out, out.err


def one_error_line(err: str, *words: str) -> str:
    lines = [line for line in err.strip().splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


def snapshot(folder: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else None) for p in sorted(folder.rglob("*"))}


def make_old(path: Path) -> None:
    """Age a planted leftover like the checkpoint tests do (a sweep needs no age, but be realistic)."""
    old = time.time() - 3600
    os.utime(path, (old, old))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """A small synthetic dataset written by `data synth` (copied per test where it is changed)."""
    root = tmp_path_factory.mktemp("synth") / "data"
    write_dataset(root, num=3, seed=1, workers=1)
    return root


def copy_tree(src: Path, dst: Path) -> Path:
    import shutil

    shutil.copytree(src, dst)
    return dst


# --------------------------------------------------------------------------- data synth: ownership


def test_synth_refuses_its_own_dataset_once_it_holds_other_files(capsys, dataset, tmp_path):
    d = copy_tree(dataset, tmp_path / "d")
    (d / "notes.txt").write_text("my notes")
    (d / "runs" / "exp1").mkdir(parents=True)
    (d / "runs" / "exp1" / "last.ckpt").write_bytes(b"\0" * 100)
    before = snapshot(d)
    rc, _, err = run_cli(capsys, "data", "synth", "--out", d, "--num", "3")
    assert rc == 2
    one_error_line(err, "--out", str(d), "notes.txt", "runs", "nothing was replaced")
    assert snapshot(d) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d"]  # no partial folder left beside it


def test_synth_refuses_a_folder_with_a_planted_marker(capsys, tmp_path):
    d = tmp_path / "Documents"
    d.mkdir()
    (d / "synth.json").write_text("{}")
    (d / "thesis.tex").write_text("\\documentclass{article}")
    for planted in ({}, {"format": "stablemo-folder-files", "version": 1, "entries": {"synth.json": 2}}):
        (d / MANIFEST).write_text(json.dumps(planted))  # an unreadable list, then one missing thesis.tex
        before = snapshot(d)
        rc, _, err = run_cli(capsys, "data", "synth", "--out", d, "--num", "3")
        assert rc == 2
        one_error_line(err, "--out", str(d), "nothing was replaced")
        assert snapshot(d) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["Documents"]


def test_synth_refuses_a_changed_file_and_a_symlink(dataset, tmp_path):
    d = copy_tree(dataset, tmp_path / "d")
    (d / "texts" / "000001.txt").write_text("my own caption, longer than the one written there before\n")
    with pytest.raises(StableMoError, match=r"texts/000001\.txt"):
        write_dataset(d, num=3, seed=1, workers=1)
    d2 = copy_tree(dataset, tmp_path / "d2")
    (d2 / "link").symlink_to(tmp_path)
    with pytest.raises(StableMoError, match="link"):
        write_dataset(d2, num=3, seed=1, workers=1)
    assert (d2 / "link").is_symlink()


def test_synth_replaces_its_own_dataset_with_its_read_cache(capsys, dataset, tmp_path):
    d = copy_tree(dataset, tmp_path / "d")
    assert run_cli(capsys, "data", "check", d)[0] == 0  # writes the read cache into the dataset
    assert (d / ".stablemo_cache").is_dir()
    rc, out, err = run_cli(capsys, "data", "synth", "--out", d, "--num", "5", "--seed", "2")
    assert rc == 0, err
    assert len((d / "all.txt").read_text().split()) == 5 and not (d / ".stablemo_cache").exists()
    listed = json.loads((d / MANIFEST).read_text())["entries"]
    on_disk = {str(p.relative_to(d)) for p in d.rglob("*")} - {MANIFEST}
    assert set(listed) == on_disk
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d"]


def test_synth_num_is_capped_before_anything_is_written(capsys, tmp_path):
    for num in ("1000000000", str(writer.MAX_NUM + 1), "2"):
        rc, _, err = run_cli(capsys, "data", "synth", "--out", tmp_path / "d", "--num", num)
        assert rc == 2
        one_error_line(err, f"--num={num}", str(writer.MAX_NUM))
    with pytest.raises(StableMoError, match=r"num=1000000000: must be in \[3, 100000\]"):
        write_dataset(tmp_path / "d", num=10**9)
    assert list(tmp_path.iterdir()) == []


def test_synth_refuses_what_would_not_fit_on_the_disk(tmp_path, monkeypatch):
    monkeypatch.setattr(writer, "BYTES_PER_MOTION", 10**15)  # a disk this size is nowhere
    with pytest.raises(StableMoError, match=r"--out: .*d: 3 motions need about .* GB free; pass a smaller --num"):
        write_dataset(tmp_path / "d", num=3, flag="--out")
    assert list(tmp_path.iterdir()) == []


def test_synth_reports_progress_on_stderr(capsys, tmp_path, monkeypatch):
    monkeypatch.setattr(writer, "PROGRESS_MIN", 1)  # the real threshold (200 motions) takes too long here
    capsys.readouterr()
    write_dataset(tmp_path / "d", num=30, seed=0, workers=1)  # two chunks: 25, then 5
    err = capsys.readouterr().err.splitlines()
    assert err == ["synth: 25/30 motions (83%)", "synth: 30/30 motions (100%)"]


def test_synth_sigterm_removes_the_partial_folder(tmp_path):
    proc = subprocess.Popen([str(STABLEMO), "data", "synth", "--out", "d", "--num", "2000"], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120  # a stall bound, not a timing assertion
        while time.monotonic() < deadline and proc.poll() is None:
            partial = [p for p in tmp_path.glob(".d.*.partial") if any((p / "texts").glob("*.txt"))]
            if partial:
                break
            time.sleep(0.2)
        assert partial, "the run never started writing"
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 128 + signal.SIGTERM
    assert "interrupted" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_the_next_synth_removes_a_killed_runs_leftovers_only(tmp_path):
    stale = tmp_path / ".d.k2j4x9_q.partial"          # a SIGKILLed build: nobody holds its lock
    old = tmp_path / ".d.ab12cd34.old"                 # a fallback swap killed after its renames
    live = tmp_path / ".d.zz99yy88.partial"            # another process still building (locked)
    foreign = [tmp_path / ".d.partial", tmp_path / ".d.abc.partial", tmp_path / ".e.k2j4x9_q.partial",
               tmp_path / "d.k2j4x9_q.partial"]
    for path in (stale, old, live, *foreign):
        (path / "texts").mkdir(parents=True)
        (path / "texts" / "000000.txt").write_text("x")
        make_old(path)
    holder = os.open(live, os.O_RDONLY)
    fcntl.flock(holder, fcntl.LOCK_EX)
    try:
        write_dataset(tmp_path / "d", num=3, seed=0, workers=1)
    finally:
        os.close(holder)
    assert not stale.exists() and not old.exists()
    assert live.exists() and all(p.exists() for p in foreign)


# --------------------------------------------------------------------------- replace_dir


def folder(path: Path, **files: str) -> Path:
    path.mkdir()
    for name, text in files.items():
        (path / name).write_text(text)
    return path


def test_exchange_swaps_two_folders_in_one_step(tmp_path):
    a, b = folder(tmp_path / "a", one="1"), folder(tmp_path / "b", two="2")
    assert atomicio.exchange(a, b)  # Linux with renameat2 (ext4, tmpfs, btrfs, xfs)
    assert (a / "two").read_text() == "2" and (b / "one").read_text() == "1"


def test_replace_dir_exchanges_so_the_target_always_exists(tmp_path, monkeypatch):
    target, new = folder(tmp_path / "out", old="old"), folder(tmp_path / ".out.abcdefgh.partial", new="new")
    seen = []
    real = atomicio.exchange

    def watched(a, b):
        seen.append((os.path.isdir(a), os.path.isdir(b)))  # both paths exist before ...
        done = real(a, b)
        seen.append((os.path.isdir(a), os.path.isdir(b)))  # ... and after: no instant without a target
        return done

    def no_rename(src, dst):
        raise AssertionError(f"the exchange path renamed {src} -> {dst}")

    monkeypatch.setattr(atomicio, "exchange", watched)
    monkeypatch.setattr(atomicio, "_rename", no_rename)
    atomicio.replace_dir(new, target)
    assert seen == [(True, True), (True, True)]
    assert (target / "new").read_text() == "new" and not (target / "old").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_replace_dir_fallback_without_exchange(tmp_path, monkeypatch):
    monkeypatch.setattr(atomicio, "exchange", lambda a, b: False)
    target, new = folder(tmp_path / "out", old="old"), folder(tmp_path / ".out.abcdefgh.partial", new="new")
    atomicio.replace_dir(new, target)
    assert (target / "new").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


KILL_AT = """
import os, signal, sys
from pathlib import Path
from footskate import atomicio

atomicio.exchange = lambda a, b: False  # a system without renameat2
calls, real = [], atomicio._rename

def rename(src, dst):
    real(src, dst)
    calls.append(dst)
    if len(calls) == int(sys.argv[3]):
        os.kill(os.getpid(), signal.SIGKILL)  # a kill between the steps: no handler runs

atomicio._rename = rename
atomicio.replace_dir(sys.argv[1], sys.argv[2])
"""


@pytest.mark.parametrize("kill_after, survivor", [(1, "old"), (2, "new")])
def test_a_kill_inside_the_fallback_is_recovered_by_the_next_run(tmp_path, kill_after, survivor):
    target, new = folder(tmp_path / "out", old="old"), folder(tmp_path / ".out.abcdefgh.partial", new="new")
    proc = subprocess.run([sys.executable, "-c", KILL_AT, str(new), str(target), str(kill_after)],
                          cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    assert (tmp_path / ".out.replacing").is_file()  # the journal survived the kill
    if kill_after == 1:
        assert not target.exists()  # the gap two renames cannot avoid
    with atomicio.atomic_dir(tmp_path / "next") as tmp:  # a write to another target leaves them alone
        (tmp / "x").write_text("x")
    assert (tmp_path / ".out.replacing").is_file()
    # the next write to the same target repairs it first (atomic_dir calls recover_dir)
    with pytest.raises(FileExistsError):
        with atomicio.atomic_dir(target) as tmp:  # no `replaceable`: it only gets to tidy up
            (tmp / "y").write_text("y")
    assert (target / survivor).read_text() == survivor and len(list(target.iterdir())) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["next", "out"]  # journal, .old, .partial gone


def test_a_file_added_during_the_swap_puts_the_old_folder_back(tmp_path, monkeypatch):
    target = tmp_path / "out"
    with atomicio.atomic_dir(target) as tmp:
        (tmp / "a.txt").write_text("ours")
    real, calls = atomicio.exchange, []

    def late_write(a, b):  # someone writes into the old folder between the check and the swap
        if not calls:
            (target / "theirs.txt").write_text("keep")
        calls.append(1)
        return real(a, b)

    monkeypatch.setattr(atomicio, "exchange", late_write)
    with pytest.raises(FileExistsError, match="theirs.txt"):
        with atomicio.atomic_dir(target, replaceable=lambda p: True) as tmp:
            (tmp / "a.txt").write_text("new")
    assert (target / "theirs.txt").read_text() == "keep" and (target / "a.txt").read_text() == "ours"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


# --------------------------------------------------------------------------- export --overwrite


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory) -> Path:
    """A checkpoint of the precomputed-bundle kind (tests/test_bad_input_writes.py): fast to export."""
    from stablemo.training.checkpoint_io import AtomicCheckpointIO

    path = tmp_path_factory.mktemp("ckpt") / "last.ckpt"
    AtomicCheckpointIO().save_checkpoint({
        "global_step": 3,
        "state_dict": {"student.layer.weight": torch.ones(2, 2)},
        "stablemo": {"bundle": {"kind": "diffusion", "note": "tiny"}, "weights_prefix": "student."},
    }, path)
    return path


def test_export_overwrite_swaps_in_one_step_and_cleans_a_killed_runs_leftovers(capsys, ckpt, tmp_path, monkeypatch):
    out = tmp_path / "bundle"
    assert run_cli(capsys, "export", ckpt, "--out", out)[0] == 0
    # what a kill between the old two renames left: hidden folders and no journal
    for name in (".bundle.k2j4x9_q.old", ".bundle.ab12cd34.partial"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "model.safetensors").write_bytes(b"\0" * 64)
        make_old(tmp_path / name)
    swaps = []
    real = atomicio.exchange
    monkeypatch.setattr(atomicio, "exchange", lambda a, b: swaps.append((Path(a).name, Path(b))) or real(a, b))
    rc, _, err = run_cli(capsys, "export", ckpt, "--out", out, "--overwrite")
    assert rc == 0, err
    assert len(swaps) == 1 and swaps[0][1] == out and swaps[0][0].startswith(".bundle.")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bundle"]
    assert sorted(p.name for p in out.iterdir()) == ["config.json", "model.safetensors"]


def test_export_overwrite_never_deletes_a_folder_named_like_a_bundle_file(capsys, ckpt, tmp_path):
    out = tmp_path / "bundle"
    assert run_cli(capsys, "export", ckpt, "--out", out)[0] == 0
    (out / "model.safetensors").unlink()
    (out / "model.safetensors").mkdir()  # the names are a bundle's; the content is someone's work
    (out / "model.safetensors" / "thesis.tex").write_text("keep")
    before = snapshot(out)
    rc, _, err = run_cli(capsys, "export", ckpt, "--out", out, "--overwrite")
    assert rc == 2
    one_error_line(err, str(out), "nothing replaced")
    assert snapshot(out) == before and sorted(p.name for p in tmp_path.iterdir()) == ["bundle"]


# --------------------------------------------------------------------------- names and collisions


@pytest.fixture(scope="module")
def bundle(tmp_path_factory):
    return make_tiny_bundle(tmp_path_factory.mktemp("gen") / "bundle")


def features_file(tmp_path: Path, frames: int) -> Path:
    path = tmp_path / "in.features.npy"
    np.save(path, np.zeros((frames, D), np.float32))
    return path


@pytest.mark.parametrize("name, what", [
    ("../../escaped", "is a path"), ("/tmp/abs", "is a path"), ("sub/x", "is a path"), ("..", "is a path"),
    ("a\\b", "is a path"), ("", "empty"), (".hidden", "starts with '.'"), ("x" * 300, "at most"),
])
def test_edit_name_must_be_a_plain_file_name(capsys, tmp_path, name, what):
    feats = features_file(tmp_path, 20)
    out = tmp_path / "deep" / "out"
    rc, _, err = run_cli(capsys, "edit", feats, "--keep", "lower_body", "--text", "a person waves", "--out", out,
                         "--name", name, "--bundle", tmp_path / "missing-bundle")  # refused before the bundle
    assert rc == 2
    one_error_line(err, "--name", what)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.features.npy"]


def test_output_names_from_text_never_escape():
    for text in ("../../etc/passwd", "/abs/path", "..", ".", "a\\b\x00c", "ÄÖÜ ∂", "-" * 80, "x" * 500):
        slug = outputs_files.slugify(text)
        assert outputs_files.check_output_name(slug) == slug  # always a plain, visible, short name
        assert slug[0] not in "-." and "/" not in slug


@pytest.mark.parametrize("frames, words", [(0, ["no frames"]), (1, ["1 frame,", "too short", "--frames 8"])])
def test_edit_a_too_short_input_says_so(capsys, bundle, tmp_path, frames, words):
    feats = features_file(tmp_path, frames)
    rc, _, err = run_cli(capsys, "edit", feats, "--keep", "frames=0:1", "--text", "a person walks",
                         "--out", tmp_path / "out", "--bundle", bundle, "--no-render")
    assert rc == 2
    line = one_error_line(err, str(feats), *words)
    assert "too long" not in line
    assert not (tmp_path / "out").exists()


def test_unique_slugs_are_chosen_after_all_slugs_are_known():
    assert outputs_files.unique_slugs(["a person walks", "a person walks", "a person walks 2"]) == [
        "a-person-walks", "a-person-walks-3", "a-person-walks-2"]
    assert outputs_files.unique_slugs(["x", "x-2", "x", "x", "x-3"]) == ["x", "x-2", "x-4", "x-5", "x-3"]
    for texts in (["x"] * 5 + ["x 2", "x-3", "X 4"], ["b", "b-2", "b-2", "b"]):
        slugs = outputs_files.unique_slugs(texts)
        assert len(set(slugs)) == len(texts)


def test_generate_gives_every_prompt_its_own_files(capsys, bundle, tmp_path):
    prompts = ["a person walks", "a person walks", "a person walks 2"]
    out = tmp_path / "out"
    rc, stdout, err = run_cli(capsys, "generate", *prompts, "--frames", "8", "--steps", "1", "--bundle", bundle,
                              "--out", out, "--no-render")
    assert rc == 0, err
    stems = ["a-person-walks", "a-person-walks-3", "a-person-walks-2"]
    files = sorted(f"{s}.{k}.npy" for s in stems for k in ("features", "joints"))
    assert sorted(p.name for p in out.iterdir()) == files  # 3 prompts, 3 motions
    motions = [np.load(out / f"{s}.features.npy") for s in stems]  # prompt i uses seed + i: all differ
    assert not np.array_equal(motions[0], motions[1]) and not np.array_equal(motions[1], motions[2])
    lines = stdout.strip().splitlines()  # the mapping prompt -> files, in prompt order
    assert len(lines) == 3 and all(f"{s}.features.npy" in line for s, line in zip(stems, lines))


def test_footskate_weights_without_footskate_is_an_error(capsys, tmp_path):
    rc, _, err = run_cli(capsys, "generate", "a person walks", "--footskate-weights", tmp_path / "w.safetensors",
                         "--bundle", tmp_path / "missing-bundle", "--out", tmp_path / "out")  # before the bundle
    assert rc == 2
    one_error_line(err, "--footskate-weights", "--footskate")
    from stablemo.inference.hooks import make_hooks

    with pytest.raises(StableMoError, match="footskate_weights: only used with footskate=True"):
        make_hooks(None, footskate_weights="w.safetensors")
    assert make_hooks(None) == []


def test_footskate_refuses_two_outputs_at_one_path(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    joints = tmp_path / "walk.npy"
    np.save(joints, np.random.default_rng(0).normal(size=(30, 22, 3)).astype(np.float32))
    (tmp_path / "sub").mkdir()
    for joints_out in ("X.npy", tmp_path / "X.npy", tmp_path / "sub" / ".." / "X.npy"):
        rc, _, err = run_cli(capsys, "footskate", joints, "--out", tmp_path / "X.npy", "--joints-out", joints_out)
        assert rc == 2
        one_error_line(err, "--joints-out", "same file as --out")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sub", "walk.npy"]


def test_footskate_out_and_joints_out_check_is_exact():
    assert atomicio.same_output("a/b.npy", "a/./b.npy") and atomicio.same_output("b.npy", os.path.abspath("b.npy"))
    assert not atomicio.same_output("a/b.npy", "a/c.npy") and not atomicio.same_output("a/b.npy", "c/b.npy")
