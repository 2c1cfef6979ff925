"""Issue #18, writes: nothing we did not write is ever deleted, every write goes through the one
atomic helper (footskate.atomicio, re-exported by stablemo.io), stale checkpoint temp files are
cleaned, and bad --out arguments / footskate inputs give one line (exit 2) before any compute."""

from __future__ import annotations

import ast
import fcntl
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from stablemo.cli import main

REPO = Path(__file__).resolve().parents[1]
STABLEMO = Path(sys.executable).with_name("stablemo")


def run_cli(capsys, *argv: str) -> tuple[int, str]:
    """(exit code, stderr) of the real `stablemo` entry point, in process."""
    capsys.readouterr()
    rc = main([str(a) for a in argv])
    return rc, capsys.readouterr().err


def one_error_line(err: str, *words: str) -> str:
    lines = [line for line in err.strip().splitlines() if line.strip()]
    assert len(lines) == 1, err
    for word in words:
        assert word in lines[0], lines[0]
    assert "Traceback" not in err
    return lines[0]


def snapshot(folder: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else None) for p in sorted(folder.rglob("*"))}


# ------------------------------------------------------------------------------- a tiny checkpoint


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory) -> Path:
    """A checkpoint of the precomputed-bundle kind (what ConsistencyDistillation saves): exportable
    without any training, which keeps these tests fast."""
    from stablemo.training.checkpoint_io import AtomicCheckpointIO

    path = tmp_path_factory.mktemp("ckpt") / "last.ckpt"
    checkpoint = {
        "global_step": 3,
        "state_dict": {"student.layer.weight": torch.ones(2, 2)},
        "stablemo": {"bundle": {"kind": "diffusion", "note": "tiny"}, "weights_prefix": "student."},
    }
    AtomicCheckpointIO().save_checkpoint(checkpoint, path)
    return path


def export(capsys, ckpt: Path, out, *extra: str) -> tuple[int, str]:
    return run_cli(capsys, "export", ckpt, "--out", out, *extra)


# ------------------------------------------------------------------------------- item 1: export


def test_export_refuses_a_folder_that_is_not_a_bundle(capsys, ckpt, tmp_path):
    target = tmp_path / "v"
    (target / "sub").mkdir(parents=True)
    (target / "important.txt").write_text("x")
    (target / "sub" / "data.bin").write_bytes(b"\0\1")
    before = snapshot(target)
    for extra in ((), ("--overwrite",)):
        rc, err = export(capsys, ckpt, target, *extra)
        assert rc == 2
        one_error_line(err, "--out", str(target), "not a StableMo bundle")
        assert snapshot(target) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v"]  # no temp folders left beside it


def test_export_refuses_a_regular_file_and_the_current_folder(capsys, ckpt, tmp_path, monkeypatch):
    file = tmp_path / "notes.txt"
    file.write_text("keep")
    rc, err = export(capsys, ckpt, file, "--overwrite")
    assert rc == 2 and file.read_text() == "keep"
    one_error_line(err, "--out", "not a folder")

    rc, err = export(capsys, ckpt, file / "bundle")  # under a regular file
    assert rc == 2
    one_error_line(err, "--out", "not a folder")

    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)  # empty: only the "current folder" rule can refuse it
    for out in (".", "..", str(work)):
        rc, err = export(capsys, ckpt, out, "--overwrite")
        assert rc == 2, out
        one_error_line(err, "--out", "current folder")
    assert list(work.iterdir()) == [] and sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt", "work"]


def test_export_overwrite_replaces_only_a_bundle(capsys, ckpt, tmp_path):
    out = tmp_path / "bundle"
    assert export(capsys, ckpt, out)[0] == 0
    config = json.loads((out / "config.json").read_text())
    assert config["format"] == "stablemo-bundle" and config["note"] == "tiny"

    rc, err = export(capsys, ckpt, out)  # an existing bundle is not replaced by accident either
    assert rc == 2
    one_error_line(err, "--out", "--overwrite")

    (out / "config.json").write_text(json.dumps(dict(config, note="old")))
    assert export(capsys, ckpt, out, "--overwrite")[0] == 0
    assert json.loads((out / "config.json").read_text())["note"] == "tiny"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bundle"]

    (out / "my_notes.txt").write_text("mine")  # a bundle holding someone's file: not ours to delete
    rc, err = export(capsys, ckpt, out, "--overwrite")
    assert rc == 2 and (out / "my_notes.txt").read_text() == "mine"
    one_error_line(err, "--out", "my_notes.txt")


def test_export_checks_out_before_reading_the_checkpoint(capsys, tmp_path):
    (tmp_path / "x.txt").write_text("x")
    rc, err = export(capsys, tmp_path / "missing.ckpt", tmp_path)
    assert rc == 2
    one_error_line(err, "--out", "not a StableMo bundle")


# ------------------------------------------------------------------------------- item 2: one helper


def test_footskate_never_follows_a_planted_temp_symlink(capsys, tmp_path):
    shared = tmp_path / "shared"
    shared.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    for name in (".o.npy.tmp.npy", ".o.npy.tmp"):  # the fixed temp names used before
        (shared / name).symlink_to(victim)
    src = tmp_path / "in.npy"
    np.save(src, walking_joints())
    rc, err = run_cli(capsys, "footskate", src, "--out", shared / "o.npy", "--contacts", "heuristic", "--iters", "2")
    assert rc == 0, err
    assert victim.read_bytes() == b"precious"  # the link target was not written through
    out = shared / "o.npy"
    assert out.is_file() and not out.is_symlink() and np.load(out).shape == (30, 22, 3)
    assert sorted(p.name for p in shared.iterdir()) == [".o.npy.tmp", ".o.npy.tmp.npy", "o.npy"]


# Call patterns that write or rename outside the helper. A destination argument is allowed only
# when it is the file object of a `with atomic_open(...) as f` block.
RAW_CALLS = {
    ("os", "replace"), ("os", "rename"), ("os", "renames"), ("os", "link"), ("os", "symlink"), ("os", "truncate"),
    ("shutil", "move"), ("shutil", "copy"), ("shutil", "copy2"), ("shutil", "copyfile"), ("shutil", "copytree"),
    ("tempfile", "mkstemp"), ("tempfile", "mkdtemp"), ("tempfile", "NamedTemporaryFile"), ("pickle", "dump"),
}
RAW_METHODS = {"write_text", "write_bytes", "rename", "symlink_to", "hardlink_to"}
ANY_FORM = {"save_file", "open_memmap"}  # safetensors' file writer: use safetensors.torch.save -> bytes
# callee -> index of its destination argument (keyword name in brackets)
DESTINATIONS = {
    ("np", "save"): (0, "file"), ("np", "savez"): (0, "file"), ("np", "savez_compressed"): (0, "file"),
    ("np", "savetxt"): (0, "fname"), ("torch", "save"): (1, "f"), ("json", "dump"): (1, "fp"),
    ("*", "savefig"): (0, "fname"), ("*", "tofile"): (0, "fid"), ("*", "to_csv"): (0, "path_or_buf"),
    ("*", "save"): (0, "fp"),
}
WRITE_FLAGS = {"O_WRONLY", "O_RDWR", "O_CREAT", "O_TRUNC", "O_APPEND"}
SCANNED = ("stablemo", "footskate", "scripts")
HELPER = "footskate/atomicio.py"
# Raw writes in files owned by other work on issue #18, reported to their owners (path -> count).
# A count may only go down.
ELSEWHERE: dict[str, int] = {
    "footskate/train.py": 1,  # the --log file is appended line by line
    # hard links of a benchmark corpus inside its atomic_dir build (2), and a copy of the packages
    # into the benchmark's own temporary folder (1)
    "scripts/bench/shard_throughput.py": 3,
}


def _callee(func: ast.expr) -> tuple[str, str] | None:
    if isinstance(func, ast.Name):
        return ("", func.id)
    if isinstance(func, ast.Attribute):
        owner = func.value
        name = owner.id if isinstance(owner, ast.Name) else owner.attr if isinstance(owner, ast.Attribute) else ""
        return (name, func.attr)
    return None


def _argument(call: ast.Call, index: int, keyword: str) -> ast.expr | None:
    for kw in call.keywords:
        if kw.arg == keyword:
            return kw.value
    return call.args[index] if len(call.args) > index else None


def _write_mode(call: ast.Call, index: int, default: str = "r") -> bool:
    mode = _argument(call, index, "mode")
    if mode is None:
        return any(c in default for c in "wax+")
    if not (isinstance(mode, ast.Constant) and isinstance(mode.value, str)):
        return True  # a computed mode: cannot be shown harmless
    return any(c in mode.value for c in "wax+")


def _atomic_names(tree: ast.AST) -> set[str]:
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.With, ast.AsyncWith)):
            for item in node.items:
                call = item.context_expr
                if (isinstance(call, ast.Call) and (_callee(call.func) or ("", ""))[1] == "atomic_open"
                        and isinstance(item.optional_vars, ast.Name)):
                    names.add(item.optional_vars.id)
    return names


def _raw_write(call: ast.Call, allowed: set[str]) -> str | None:
    callee = _callee(call.func)
    if callee is None:
        return None
    owner, name = callee
    if (owner, name) in RAW_CALLS or name in ANY_FORM:
        return f"{owner}.{name}" if owner else name
    if isinstance(call.func, ast.Attribute) and name in RAW_METHODS:
        return f".{name}"
    if (owner, name) in (("", "open"), ("io", "open"), ("codecs", "open"), ("os", "fdopen")) and _write_mode(call, 1):
        return f"{name}(…, mode)"
    if name == "memmap" and _write_mode(call, 2, default="r+"):  # numpy's default mode writes
        return "np.memmap(mode)"
    if isinstance(call.func, ast.Attribute) and name == "open" and owner not in ("io", "os", "codecs") \
            and _write_mode(call, 0):
        return ".open(mode)"
    if owner == "os" and name == "open" and any(
            isinstance(n, ast.Attribute) and n.attr in WRITE_FLAGS for a in call.args[1:2] for n in ast.walk(a)):
        return "os.open(write flags)"
    spec = DESTINATIONS.get((owner, name))
    if spec is None and owner not in ("np", "numpy", "torch", "json"):
        spec = DESTINATIONS.get(("*", name))
    if spec is None or not isinstance(call.func, ast.Attribute):
        return None
    target = _argument(call, *spec)
    if target is None or (isinstance(target, ast.Name) and target.id in allowed):
        return None
    return f"{owner}.{name} to a path"


def raw_writes(path: Path, label: str) -> list[str]:
    tree = ast.parse(path.read_text(), str(path))
    found = []

    def visit(node: ast.AST, allowed: set[str]) -> None:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            allowed = allowed | _atomic_names(node)
        if isinstance(node, ast.Call):
            what = _raw_write(node, allowed)
            if what:
                found.append(f"{label}:{node.lineno}: {what}")
        for child in ast.iter_child_nodes(node):
            visit(child, allowed)

    visit(tree, _atomic_names(tree))
    return found


def test_the_scanner_sees_raw_writes(tmp_path):
    sample = tmp_path / "probe.py"
    sample.write_text(  # a file of known raw writes, one per line
        "import numpy as np, torch, os, json\n"
        "np.save(path, a)\n"
        "torch.save(obj, out / 'x.ckpt')\n"
        "fig.savefig(tmp, format='png')\n"
        "os.replace(a, b)\n"
        "open(p, 'w')\n"
        "Path(p).write_text('x')\n"
        "save_file(t, str(p))\n"
        "image.save(tmp, format='GIF')\n"
        "with atomic_open(p) as f:\n"
        "    np.save(f, a)\n"
        "open(p).read()\n"
        "np.memmap(p, dtype='f4', mode='w+')\n"
        "np.memmap(p, dtype='f4', mode='r')\n"
        "os.open(p, os.O_RDONLY)\n"
        "os.open(p, os.O_WRONLY | os.O_CREAT)\n"
    )
    lines = [int(hit.split(":")[1]) for hit in raw_writes(sample, "probe.py")]
    assert lines == [2, 3, 4, 5, 6, 7, 8, 9, 13, 16]


def test_no_write_bypasses_the_atomic_helper():
    """Every write goes through footskate.atomicio (atomic_open / atomic_path / atomic_dir /
    write_text / write_bytes, or stablemo.io.save_npy built on them)."""
    hits: dict[str, list[str]] = {}
    for top in SCANNED:
        for path in sorted((REPO / top).rglob("*.py")):
            rel = str(path.relative_to(REPO))
            if rel != HELPER:
                for hit in raw_writes(path, rel):
                    hits.setdefault(rel, []).append(hit)
    unexpected = [h for rel, found in hits.items() if len(found) > ELSEWHERE.get(rel, 0) for h in found]
    assert not unexpected, "writes that bypass footskate.atomicio:\n" + "\n".join(unexpected)


# ------------------------------------------------------------------------------- item 3: .partial


def test_stale_checkpoint_partials_are_removed_when_a_run_starts(tmp_path):
    sys.path.insert(0, str(REPO / "tests"))
    try:
        from test_training import tiny_config, write_random_dataset
    finally:
        sys.path.pop(0)
    data = write_random_dataset(tmp_path / "data", num=10, splits=(8, 1))
    folder = tmp_path / "run" / "checkpoints"
    folder.mkdir(parents=True)
    old = time.time() - 3600
    stale = folder / ".last.ckpt.k2j4x9_q.partial"      # a hard-killed save: nobody holds its lock
    live = folder / ".step=3.ckpt.ab12cd34.partial"    # another process still writing it (locked)
    young = folder / ".last.ckpt.zz99yy88.partial"     # just created: not judged yet
    foreign = [folder / ".notes.partial", folder / "last.ckpt.abcdefgh.partial", folder / ".x.ckpt.partial"]
    for path in (stale, live, young, *foreign):
        path.write_bytes(b"\0" * 64)
        if path is not young:
            os.utime(path, (old, old))
    holder = open(live, "rb")
    fcntl.flock(holder, fcntl.LOCK_EX)
    try:
        cfg = tiny_config(tmp_path / "run", data, **{"trainer.max_steps": 1})
        assert main(["fit", "--config", str(cfg)]) == 0
    finally:
        holder.close()
    assert not stale.exists()
    assert live.exists() and young.exists() and all(p.exists() for p in foreign)
    assert (folder / "last.ckpt").is_file()


def test_stale_partials_go_when_a_run_starts_before_any_save(tmp_path):
    """The checkpoint callback's setup (a run's start, before its first save) cleans the folder."""
    from lightning.pytorch import LightningModule, Trainer

    from stablemo.training.callbacks import FinalStepCheckpoint

    folder = tmp_path / "checkpoints"
    folder.mkdir()
    stale = folder / ".last.ckpt.k2j4x9_q.partial"
    stale.write_bytes(b"\0" * 64)
    old = time.time() - 3600
    os.utime(stale, (old, old))
    trainer = Trainer(default_root_dir=tmp_path, logger=False, enable_progress_bar=False, max_steps=1)
    FinalStepCheckpoint(dirpath=folder).setup(trainer, LightningModule(), "fit")
    assert not stale.exists()


# ------------------------------------------------------------------------------- item 7: --out


def walking_joints(frames: int = 30, joints: int = 22) -> np.ndarray:
    rng = np.random.default_rng(0)
    x = rng.normal(scale=0.1, size=(1, joints, 3)) + np.linspace(0, 1, frames)[:, None, None] * [1.0, 0.0, 0.0]
    x[..., 1] += 1.0
    return x.astype(np.float32)


@pytest.fixture
def joints_file(tmp_path) -> Path:
    path = tmp_path / "walk.npy"
    np.save(path, walking_joints())
    return path


def _bad_outs(tmp_path: Path) -> list[tuple[Path, str]]:
    (tmp_path / "somefile").write_text("x")
    (tmp_path / "adir").mkdir()
    return [(tmp_path / "somefile" / "x.gif", "not a folder"), (tmp_path / "adir", "existing folder")]


def test_render_out_is_checked_before_anything_is_read(capsys, tmp_path):
    missing = tmp_path / "missing.npy"  # a check after reading would complain about this instead
    for out, reason in _bad_outs(tmp_path):
        rc, err = run_cli(capsys, "render", missing, "--out", out)
        assert rc == 2
        one_error_line(err, "--out", str(out), reason)


def test_render_out_under_a_file_or_at_a_folder_with_a_real_input(capsys, tmp_path, joints_file):
    for out, reason in _bad_outs(tmp_path):
        rc, err = run_cli(capsys, "render", joints_file, "--out", out)
        assert rc == 2
        one_error_line(err, "--out", reason)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["adir", "somefile", "walk.npy"]


def _read_only_run(folder: Path, *argv: str) -> subprocess.CompletedProcess:
    """Run `stablemo argv` with `folder` on a read-only file system (a private mount namespace)."""
    folder.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0:
        folder.chmod(0o555)  # unprivileged: a folder we may not write in is the same refusal path
        return subprocess.run([str(STABLEMO), *argv], capture_output=True, text=True, timeout=300)
    if shutil.which("unshare") is None:
        pytest.skip("needs unshare to mount a read-only file system")
    script = 'mount -t tmpfs -o ro none "$0" && exec "$@"'
    proc = subprocess.run(["unshare", "--mount", "sh", "-c", script, str(folder), str(STABLEMO), *argv],
                          capture_output=True, text=True, timeout=300)
    if "mount" in proc.stderr and "stablemo" not in proc.stderr:
        pytest.skip(f"cannot mount a read-only file system here: {proc.stderr.strip()}")
    return proc


@pytest.mark.parametrize("command", ["render", "export"])
def test_out_on_a_read_only_file_system(tmp_path, joints_file, ckpt, command):
    ro = tmp_path / "ro"
    out = ro / ("x.gif" if command == "render" else "bundle")
    source = joints_file if command == "render" else ckpt
    proc = _read_only_run(ro, command, str(source), "--out", str(out))
    assert proc.returncode == 2, proc.stderr
    reason = "read-only file system" if os.geteuid() == 0 else "no permission"
    one_error_line(proc.stderr, "--out", str(out), reason)


# ------------------------------------------------------------------------------- footskate: items 4, 7, 8


def footskate(capsys, src, out, *extra) -> tuple[int, str]:
    return run_cli(capsys, "footskate", src, "--out", out, "--contacts", "heuristic", "--iters", "3", *extra)


def test_footskate_names_bad_inputs_in_one_line(capsys, tmp_path):
    out = tmp_path / "out.npy"
    npz = tmp_path / "m.npz"
    np.savez(npz, joints=walking_joints())
    rc, err = footskate(capsys, npz, out)
    assert rc == 2
    one_error_line(err, str(npz), ".npz")

    text = tmp_path / "notes.npy"
    text.write_text("not an array\n")
    rc, err = footskate(capsys, text, out)
    assert rc == 2 and "allow_pickle" not in err
    one_error_line(err, str(text), "not a .npy file")

    kit_like = tmp_path / "kit_like.npy"
    np.save(kit_like, walking_joints(joints=21))
    rc, err = footskate(capsys, kit_like, out)
    assert rc == 2 and "feature channels" not in err
    one_error_line(err, "joints: 21 given, 22 expected")
    assert not out.exists()


def test_footskate_names_joints_in_the_wrong_unit(capsys, tmp_path):
    """KIT-ML joints are millimetres, HumanML3D's metres: the other unit is one line, no file."""
    out = tmp_path / "out.npy"
    metres = tmp_path / "kit_in_metres.npy"
    np.save(metres, walking_joints(joints=21))
    rc, err = footskate(capsys, metres, out, "--skeleton", "kit")
    assert rc == 2
    one_error_line(err, str(metres), "millimetres", "kit")
    mm = tmp_path / "humanml3d_in_mm.npy"
    np.save(mm, walking_joints() * 1000)
    rc, err = footskate(capsys, mm, out)
    assert rc == 2
    one_error_line(err, str(mm), "metres")
    assert not out.exists()
    np.save(mm, walking_joints(joints=21) * 1000)                  # the right unit for KIT: cleaned
    rc, err = footskate(capsys, mm, out, "--skeleton", "kit")
    assert rc == 0 and out.exists()


def test_footskate_out_checks_come_before_compute(capsys, tmp_path, joints_file):
    folder = tmp_path / "adir"
    folder.mkdir()
    rc, err = footskate(capsys, joints_file, folder)
    assert rc == 2
    one_error_line(err, "--out", "existing folder")
    rc, err = footskate(capsys, tmp_path / "missing.npy", joints_file / "x.npy")
    assert rc == 2
    one_error_line(err, "--out", "not a folder")
    rc, err = footskate(capsys, joints_file, tmp_path / "o.npy", "--joints-out", folder)
    assert rc == 2 and not (tmp_path / "o.npy").exists()
    one_error_line(err, "--joints-out")


@pytest.mark.parametrize("flag,value", [("--fps", "nan"), ("--fps", "inf"), ("--fps", "0"), ("--fps", "-20"),
                                        ("--iters", "-1"), ("--seed", "-1"), ("--threads", "-2")])
def test_footskate_numbers_must_be_finite_and_in_range(capsys, tmp_path, joints_file, flag, value):
    out = tmp_path / "out.npy"
    rc, err = footskate(capsys, joints_file, out, flag, value)
    assert rc == 2 and not out.exists()
    one_error_line(err, flag)


def test_footskate_never_reads_or_writes_a_non_finite_motion(capsys, tmp_path, monkeypatch):
    out = tmp_path / "out.npy"
    nan = walking_joints()
    nan[4, 3, 1] = np.nan
    np.save(tmp_path / "nan.npy", nan)
    rc, err = footskate(capsys, tmp_path / "nan.npy", out)
    assert rc == 2
    one_error_line(err, "nan.npy", "NaN")

    from footskate import command

    real = command.cleanup

    def diverging(*args, **kwargs):  # a cleanup whose optimisation blew up
        result = real(*args, **kwargs)
        result.joints[:, 5] = float("nan")
        return result

    monkeypatch.setattr(command, "cleanup", diverging)
    np.save(tmp_path / "walk.npy", walking_joints())
    rc, err = footskate(capsys, tmp_path / "walk.npy", out, "--joints-out", tmp_path / "j.npy")
    assert rc == 2 and not out.exists() and not (tmp_path / "j.npy").exists()
    one_error_line(err, "NaN/Inf", "nothing written")


def test_export_cfg_sets_the_bundles_guidance_and_a_bad_one_is_one_line(capsys, ckpt, tmp_path):
    out = tmp_path / "bundle"
    assert export(capsys, ckpt, out, "--cfg", "1.5")[0] == 0
    assert json.loads((out / "config.json").read_text())["inference"]["cfg"] == 1.5
    assert export(capsys, ckpt, tmp_path / "plain")[0] == 0  # without: the paper's
    assert json.loads((tmp_path / "plain" / "config.json").read_text())["inference"]["cfg"] == 2.5
    for bad in ("nan", "-1", "101"):
        rc, err = export(capsys, ckpt, tmp_path / f"bad{bad}", "--cfg", bad)
        assert rc == 2 and not (tmp_path / f"bad{bad}").exists()
        one_error_line(err, "--cfg")


def test_export_steps_sets_the_bundles_sampler_steps_and_a_bad_one_is_one_line(capsys, ckpt, tmp_path):
    out = tmp_path / "bundle"
    assert export(capsys, ckpt, out, "--steps", "4")[0] == 0
    inference = json.loads((out / "config.json").read_text())["inference"]
    assert inference["steps"] == 4 and inference["cfg"] == 2.5  # the rest as without it
    assert export(capsys, ckpt, tmp_path / "plain")[0] == 0  # without: the paper's 10
    assert json.loads((tmp_path / "plain" / "config.json").read_text())["inference"]["steps"] == 10
    for bad in ("0", "-3", "1001"):  # a non-number is argparse's own refusal, as for every option
        rc, err = export(capsys, ckpt, tmp_path / f"bad{bad}", "--steps", bad)
        assert rc == 2 and not (tmp_path / f"bad{bad}").exists()
        one_error_line(err, "--steps")
