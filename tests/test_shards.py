"""`stablemo data shard` and `data check` on shard folders: content, determinism, resume, damage, bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from stablemo.data.cache import load_split
from stablemo.data.layout import get_spec
from stablemo.data.shard_check import check_shards
from stablemo.data.shard_format import MANIFEST, decode_shard, read_manifest, sha256
from stablemo.data.shards import ShardWriter, write_shards
from stablemo.data.stats import compute_stats
from stablemo.errors import StableMoError

SPEC = get_spec("humanml3d")


@pytest.fixture(scope="module")
def sources(tmp_path_factory) -> tuple[Path, Path]:
    from stablemo.data.synth.writer import write_dataset

    base = tmp_path_factory.mktemp("src")
    a = write_dataset(base / "walks", num=24, seed=0, workers=1)
    b = write_dataset(base / "bvh", num=12, seed=5, workers=1)
    (b / "LICENSE").write_text("\nCC-BY-4.0 (the BVH folder's own licence)\nmore text\n")
    return a, b


def files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def test_shards_hold_every_clip_with_manifest_checksums_licences_and_merged_stats(sources, tmp_path):
    a, b = sources
    out = tmp_path / "shards"
    manifest, kept = write_shards([str(a), str(b)], str(out), clips_per_shard=5, licences=None, progress=False)
    assert kept == 0 and (out / MANIFEST).is_file() and not (out / ".partial").exists()
    assert json.loads((out / MANIFEST).read_text()) == manifest
    # every clip of every split, ids prefixed by their source, features and captions bit-identical
    m = read_manifest(str(out))
    for split in ("train", "val", "test"):
        want = {}
        for src in (a, b):
            data = load_split(src, split, SPEC, cache=False, progress=False)
            want.update({f"{src.name}:{i}": (data.motion(k), data.captions[k]) for k, i in enumerate(data.ids)})
        got = {}
        for info in m.shards(split):
            blob = (out / info.file).read_bytes()
            assert len(blob) == info.bytes and sha256(blob) == info.sha256
            clips = decode_shard(blob, info.file, SPEC)
            assert len(clips) == info.clips <= 5
            got.update({i: (clips.motion(k), clips.captions[k]) for k, i in enumerate(clips.ids)})
        assert list(got) == list(want)  # source order, then split-file order
        for clip_id, (motion, captions) in want.items():
            assert np.array_equal(got[clip_id][0], motion) and got[clip_id][1] == captions, clip_id
    # provenance and licences: the LICENSE file's first line, else "unknown"
    srcs = {s["name"]: s for s in manifest["sources"]}
    assert srcs["walks"]["licence"] == "unknown" and srcs["walks"]["licence_from"] == "none"
    assert srcs["bvh"]["licence"] == "CC-BY-4.0 (the BVH folder's own licence)" and srcs["bvh"]["licence_from"] == "LICENSE"
    assert srcs["walks"]["generator"]["seed"] == 0 and srcs["bvh"]["generator"]["seed"] == 5
    assert srcs["walks"]["clips"]["train"] + srcs["bvh"]["clips"]["train"] == manifest["splits"]["train"]["clips"]
    assert srcs["walks"]["sha256"] != srcs["bvh"]["sha256"]
    # two sources: Mean/Std computed over the merged train split as compute_stats does
    trains = [load_split(s, "train", SPEC, cache=False, progress=False) for s in (a, b)]
    mean, std = compute_stats([d.motion(k) for d in trains for k in range(len(d))], SPEC.feature_dim)
    np.testing.assert_allclose(m.mean, mean, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(m.std, std, rtol=1e-5, atol=1e-6)
    assert m.body is not None and m.body.shape == (SPEC.num_joints,) and (m.body[1:] > 0).all()
    assert check_shards(str(out)).ok
    # an option names the licence of every source
    opt, _ = write_shards([str(a), str(b)], str(tmp_path / "opt"), clips_per_shard=5, licences=["ours", "theirs"],
                          progress=False)
    assert [s["licence"] for s in opt["sources"]] == ["ours", "theirs"]


def test_single_source_keeps_its_statistics(sources, tmp_path):
    a, _ = sources
    write_shards([str(a)], str(tmp_path / "one"), clips_per_shard=7, progress=False)
    m = read_manifest(str(tmp_path / "one"))
    assert np.array_equal(m.mean, np.load(a / "Mean.npy")) and np.array_equal(m.std, np.load(a / "Std.npy"))
    ids = [i for info in m.shards("train") for i in decode_shard((tmp_path / "one" / info.file).read_bytes(),
                                                                 info.file, SPEC).ids]
    assert ids == (a / "train.txt").read_text().split()  # one source: ids as they are


def test_same_input_gives_byte_identical_shards_and_manifest(sources, tmp_path):
    a, b = sources
    write_shards([str(a), str(b)], str(tmp_path / "x"), clips_per_shard=6, progress=False)
    write_shards([str(a), str(b)], str(tmp_path / "y"), clips_per_shard=6, workers=2, progress=False)  # in parallel
    x, y = files(tmp_path / "x"), files(tmp_path / "y")
    assert list(x) == list(y) and len(x) > 4 and all(x[k] == y[k] for k in x)


def test_killed_run_continues_keeping_verified_shards(sources, tmp_path, monkeypatch):
    a, b = sources
    whole = tmp_path / "whole"
    write_shards([str(a), str(b)], str(whole), clips_per_shard=5, progress=False)
    out = tmp_path / "out"
    real = ShardWriter.write_shard
    calls = []

    def dies_at_the_fourth(self, split, index, clips):
        calls.append((split, index))
        if len(calls) == 4:
            raise KeyboardInterrupt  # killed while writing shard 4
        return real(self, split, index, clips)

    monkeypatch.setattr(ShardWriter, "write_shard", dies_at_the_fourth)
    with pytest.raises(KeyboardInterrupt):
        write_shards([str(a), str(b)], str(out), clips_per_shard=5, progress=False)
    monkeypatch.setattr(ShardWriter, "write_shard", real)
    assert sorted(p.name for p in out.glob("*.tar")) == ["train-00000.tar", "train-00001.tar", "train-00002.tar"]
    assert not (out / MANIFEST).exists()  # unfinished: no manifest, and readers say so
    with pytest.raises(StableMoError, match="unfinished .*run it again"):
        read_manifest(str(out))
    assert not check_shards(str(out)).ok
    # damage one finished shard: the next run rewrites it (checksum), keeps the other two
    with open(out / "train-00001.tar", "r+b") as f:
        f.seek(700)
        f.write(b"\xff\xff")
    _, kept = write_shards([str(a), str(b)], str(out), clips_per_shard=5, progress=False)
    assert kept == 2
    assert files(out) == files(whole)  # as if never interrupted
    # other options: an unfinished run is discarded, not mixed in
    calls.clear()
    monkeypatch.setattr(ShardWriter, "write_shard", dies_at_the_fourth)
    with pytest.raises(KeyboardInterrupt):
        write_shards([str(a)], str(tmp_path / "other"), clips_per_shard=5, progress=False)
    monkeypatch.setattr(ShardWriter, "write_shard", real)
    _, kept = write_shards([str(a)], str(tmp_path / "other"), clips_per_shard=4, progress=False)
    assert kept == 0 and check_shards(str(tmp_path / "other")).ok


def test_check_names_damaged_missing_and_truncated_shards(sources, tmp_path):
    a, _ = sources
    out = tmp_path / "s"
    write_shards([str(a)], str(out), clips_per_shard=4, progress=False)
    data = (out / "train-00001.tar").read_bytes()
    (out / "train-00001.tar").write_bytes(data[:1000] + bytes([data[1000] ^ 1]) + data[1001:])
    (out / "train-00002.tar").write_bytes(data[: len(data) // 2])
    (out / "val-00000.tar").unlink()
    report = check_shards(str(out))
    problems = "\n".join(report.problems)
    assert len(report.problems) == 3, problems
    assert "train-00001.tar: sha256 differs" in problems
    assert "train-00002.tar: " in problems and "the manifest says" in problems
    assert "val-00000.tar: not found" in problems
    manifest = json.loads((out / MANIFEST).read_text())
    manifest["stats"]["std"][3] = -1.0
    (out / MANIFEST).write_text(json.dumps(manifest))
    assert check_shards(str(out)).problems == [f"{out / MANIFEST}: stats.std must be 263 finite values > 0"]


def test_cli_shards_checks_and_refuses_bad_input_in_one_line(sources, tmp_path, capsys):
    from stablemo.cli.data import main

    a, b = sources
    assert main(["shard", str(a), str(b), "--out", str(tmp_path / "s"), "--clips-per-shard", "10",
                 "--licence", "CC0"]) == 0
    assert "(train 28 clips, val 2 clips, test 6 clips)" in capsys.readouterr().out
    assert main(["check", str(tmp_path / "s")]) == 0
    out = capsys.readouterr().out
    assert "problems: none" in out and "licence: CC0 (--licence)" in out
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "notes.txt").write_text("mine")
    for args, message in [
        ((str(tmp_path / "missing"), "--out", str(tmp_path / "o1")), "missing: dataset folder not found"),
        ((str(a), "--out", str(a / "shards")), "inside a source folder"),
        ((str(a), str(b), "--out", str(tmp_path / "o2"), "--licence", "x", "y", "z"), "--licence: give one licence"),
        ((str(a), "--out", str(tmp_path / "junk")), "did not write (e.g. notes.txt)"),
        ((str(a), "--out", str(tmp_path / "s")), "already holds finished shards"),
        ((str(a), "--out", str(tmp_path / "o3"), "--clips-per-shard", "0"), "--clips-per-shard=0: must be >= 1"),
        ((str(a), "--out", str(tmp_path / "o3"), "--workers", "0"), "--workers=0: must be >= 1"),
    ]:
        with pytest.raises(StableMoError) as err:
            main(["shard", *args])
        assert message in str(err.value) and "\n" not in str(err.value), (args, str(err.value))
    assert not any((tmp_path / name).exists() for name in ("o1", "o2", "o3"))
    assert sorted(p.name for p in (tmp_path / "junk").iterdir()) == ["notes.txt"]


def test_bad_clips_stop_the_command_or_are_skipped_and_listed(tmp_path):
    from stablemo.data.synth.writer import write_dataset

    src = write_dataset(tmp_path / "src", num=8, seed=3, workers=1)
    bad = (src / "train.txt").read_text().split()[2]
    motion = np.load(src / "new_joint_vecs" / f"{bad}.npy")
    motion[5, 7] = np.nan
    np.save(src / "new_joint_vecs" / f"{bad}.npy", motion)
    with pytest.raises(StableMoError, match=rf"{bad}.npy: 1 NaN/Inf value\(s\), first in frame 5"):
        write_shards([str(src)], str(tmp_path / "strict"), clips_per_shard=4, progress=False)
    assert not (tmp_path / "strict" / MANIFEST).exists()
    manifest, _ = write_shards([str(src)], str(tmp_path / "lax"), clips_per_shard=4, skip_bad=True, progress=False)
    assert len(manifest["skipped"]) == 1 and f"{bad}.npy" in manifest["skipped"][0]
    listed = len((src / "train.txt").read_text().split())
    assert manifest["splits"]["train"]["clips"] == listed - 1 and manifest["sources"][0]["clips"]["train"] == listed - 1
    assert check_shards(str(tmp_path / "lax")).ok
