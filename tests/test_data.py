"""Dataset layer: layout parsing, cache, items, crops, batches, DataModule, bad input, `data check`."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from stablemo.data import MotionDataModule, MotionDataset, get_spec
from stablemo.data.cache import load_split
from stablemo.data.collate import pad_motions
from stablemo.data.dataset import crop_window
from stablemo.data.layout import parse_caption_line
from stablemo.data.stats import (
    apply_feat_bias,
    compute_stats,
    denormalize,
    feature_groups,
    same_statistics,
)
from stablemo.errors import StableMoError

WHOLE = "a person walks forward#a/DET person/NOUN walk/VERB forward/ADV#0.0#0.0"
WHOLE2 = "someone strolls ahead#someone/PRON stroll/VERB ahead/ADV#nan#nan"


def write_dataset(root: Path, dataset: str = "humanml3d", clips: dict | None = None, seed: int = 0,
                  splits: dict | None = None) -> Path:
    """A small dataset in the HumanML3D layout. clips: id -> (frames, caption lines)."""
    spec = get_spec(dataset)
    rng = np.random.default_rng(seed)
    if clips is None:
        clips = {f"{i:06d}" if dataset == "humanml3d" else f"{i:05d}": (int(n), [WHOLE, WHOLE2])
                 for i, n in enumerate(rng.integers(spec.min_length, 199, size=12))}
    (root / "new_joint_vecs").mkdir(parents=True, exist_ok=True)
    (root / "texts").mkdir(exist_ok=True)
    for clip_id, (frames, lines) in clips.items():
        feats = rng.normal(2.0, 3.0, size=(frames, spec.feature_dim)).astype(np.float32)
        np.save(root / "new_joint_vecs" / f"{clip_id}.npy", feats)
        (root / "texts" / f"{clip_id}.txt").write_text("\n".join(lines) + "\n")
    np.save(root / "Mean.npy", np.full(spec.feature_dim, 2.0, np.float32))
    np.save(root / "Std.npy", np.linspace(1.0, 3.0, spec.feature_dim).astype(np.float32))
    ids = list(clips)
    if splits is None:
        n = len(ids)
        splits = {"train": ids[: 2 * n // 3] or ids, "val": ids[2 * n // 3 : 5 * n // 6] or ids,
                  "test": ids[5 * n // 6 :] or ids}
    for name, members in splits.items():
        (root / f"{name}.txt").write_text("".join(f"{i}\n" for i in members))
    return root


def raw(root: Path, clip_id: str) -> np.ndarray:
    return np.load(root / "new_joint_vecs" / f"{clip_id}.npy")


# --- layout and captions ---------------------------------------------------------------------------

def test_caption_line_parsing():
    cap = parse_caption_line("a man jumps.#a/DET man/NOUN jump/VERB#1.5#4.0", "x:1")
    assert cap.text == "a man jumps." and cap.tokens == "a/DET man/NOUN jump/VERB"
    assert not cap.whole_clip and cap.frames() == (30, 80)
    assert parse_caption_line("walks#walk/VERB#nan#nan", "x:1").whole_clip
    assert parse_caption_line("walks#walk/VERB#0.0#0.0", "x:1").whole_clip
    for bad, msg in [("only#two", "malformed"), ("#tok/X#0#0", "empty caption"), ("a#b#zero#1", "not a number"),
                     ("a#b#-1#2", ">= 0")]:
        with pytest.raises(StableMoError, match=msg) as err:
            parse_caption_line(bad, "file.txt:3")
        assert "file.txt:3" in str(err.value)


@pytest.mark.parametrize("dataset,dim", [("humanml3d", 263), ("kit", 251)])
def test_both_layouts_load_with_their_width(tmp_path, dataset, dim):
    root = write_dataset(tmp_path, dataset)
    ds = MotionDataset.from_folder(root, "train", dataset, progress=False)
    item = ds[0]
    assert item["motion"].shape[1] == dim and item["motion"].dtype == torch.float32
    assert item["text"] in ("a person walks forward", "someone strolls ahead")
    assert len(ds) == len((root / "train.txt").read_text().split())


def test_length_filter_and_sub_captions(tmp_path):
    clips = {
        "000001": (39, [WHOLE]),  # too short for HumanML3D (min 40): dropped with its sub-captions
        "000002": (200, [WHOLE]),  # T >= 200: dropped
        "000003": (150, [WHOLE, "turns left#turn/VERB left/ADV#1.0#4.0",  # frames [20, 80): kept
                         "waves#wave/VERB#0.5#2.0",  # 30 frames < 40: dropped
                         "runs#run/VERB#5.0#20.0"]),  # [100, 400) clipped to [100, 150): 50 frames kept
        "000004": (120, ["kicks#kick/VERB#1.0#3.5"]),  # only a sub-caption: no whole-clip item
        "000005": (40, [WHOLE]),  # exactly min: kept
        "000006": (90, ["hops#hop/VERB#0.0#2.5", "jumps#jump/VERB#0.0#2.5"]),  # from 0: still a sub-caption
    }
    root = write_dataset(tmp_path, clips=clips, splits={"train": list(clips)})
    ds = MotionDataset.from_folder(root, "train", crop="none", progress=False)
    assert ds.items.ids == ["000003", "000003#20-80", "000003#100-150", "000004#20-70", "000005", "000006#0-50",
                            "000006#0-50.1"]
    by_id = {ds.items.ids[i]: ds[i] for i in range(len(ds))}
    assert by_id["000003#20-80"]["text"] == "turns left"
    assert by_id["000003#20-80"]["tokens"] == ["turn/VERB", "left/ADV"]
    std = apply_feat_bias(np.linspace(1.0, 3.0, 263).astype(np.float32), 5.0)
    expected = (raw(root, "000003")[20:80] - 2.0) / std
    np.testing.assert_allclose(by_id["000003#20-80"]["motion"].numpy(), expected, rtol=1e-5, atol=1e-5)
    assert by_id["000003#100-150"]["length"] == 50


def test_kit_uses_its_min_length_and_20fps_captions(tmp_path):
    clips = {"00001": (24, [WHOLE]), "00002": (23, [WHOLE]), "00003": (100, [WHOLE, "sits#sit/VERB#1.0#2.5"])}
    root = write_dataset(tmp_path, "kit", clips=clips, splits={"train": list(clips)})
    ds = MotionDataset.from_folder(root, "train", "kit", crop="none", progress=False)
    assert ds.items.ids == ["00001", "00003", "00003#20-50"]


# --- statistics ------------------------------------------------------------------------------------

def test_feat_bias_and_normalisation(tmp_path):
    root = write_dataset(tmp_path)
    dm = MotionDataModule(str(root), batch_size=4, feat_bias=5.0)
    base = np.linspace(1.0, 3.0, 263).astype(np.float32)
    expected = base.copy()
    expected[0:4] /= 5.0
    expected[259:263] /= 5.0
    np.testing.assert_allclose(dm.std, expected, rtol=1e-6)
    np.testing.assert_allclose(dm.mean, 2.0)
    assert dm.std.dtype == np.float32 and dm.std.shape == (263,)
    ds = MotionDataset.from_folder(root, "test", crop="none", progress=False)
    item = ds[0]
    np.testing.assert_allclose(denormalize(item["motion"], dm.mean, dm.std).numpy(),
                               raw(root, item["id"]),
                               rtol=1e-5, atol=1e-4)


def test_compute_stats_averages_std_within_groups():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(500, 263)) * np.linspace(0.5, 2.0, 263)
    mean, std = compute_stats([x[:200], x[200:]], 263)
    np.testing.assert_allclose(mean, x.mean(0), atol=1e-5)
    for group in feature_groups(263):
        np.testing.assert_allclose(std[group], x.std(0)[group].mean(), rtol=1e-4)
    assert [g.start for g in feature_groups(251)] == [0, 1, 3, 4, 64, 184, 247]


# --- crops, padding, masks -------------------------------------------------------------------------

def test_train_crop_only_when_longer():
    rng = np.random.default_rng(0)
    assert crop_window(150, "train", 196, 4, rng) == (0, 150)
    offsets = {crop_window(199, "train", 196, 4, rng) for _ in range(200)}
    assert {length for _, length in offsets} == {196} and {o for o, _ in offsets} == {0, 1, 2, 3}


def test_eval_crop_rule():
    rng = np.random.default_rng(0)
    lengths = [crop_window(103, "eval", 196, 4, rng)[1] for _ in range(3000)]
    assert set(lengths) == {100, 96}
    share_full = lengths.count(100) / len(lengths)
    assert abs(share_full - 2 / 3) < 0.03
    assert crop_window(199, "eval", 196, 4, rng)[1] in (196, 192)


def test_pad_multiple_and_mask():
    motions = [torch.ones(5, 3), torch.ones(17, 3) * 2]
    motion, mask, length = pad_motions(motions, pad_multiple=16)
    assert motion.shape == (2, 32, 3) and mask.shape == (2, 32) and mask.dtype == torch.bool
    assert length.tolist() == [5, 17] and mask.sum(1).tolist() == [5, 17]
    assert torch.all(motion[0, 5:] == 0) and torch.all(motion[1, 17:] == 0) and torch.all(motion[1, :17] == 2)
    assert pad_motions([torch.ones(16, 3)], 16)[0].shape[1] == 16
    assert pad_motions([torch.ones(7, 3)], 1)[0].shape[1] == 7
    as_numpy = pad_motions([m.numpy() for m in motions], pad_multiple=16)
    assert all(torch.equal(a, b) for a, b in zip(as_numpy, (motion, mask, length)))
    grad = [torch.ones(5, 3, requires_grad=True)]
    padded = pad_motions(grad, 4)[0]
    padded.sum().backward()  # tensors that need gradients are padded with torch, keeping the graph
    assert torch.equal(grad[0].grad, torch.ones(5, 3))


@pytest.mark.parametrize("dataset", ["humanml3d", "kit"])
def test_datamodule_batches(tmp_path, dataset):
    root = write_dataset(tmp_path, dataset)
    dm = MotionDataModule(str(root), dataset=dataset, batch_size=3, pad_multiple=8, max_length=64)
    dm.setup("fit")
    batches = list(dm.train_dataloader())
    assert sum(len(b["id"]) for b in batches) == len(dm.datasets["train"])
    for b in batches:
        B, T, D = b["motion"].shape
        assert D == dm.feature_dim and T % 8 == 0 and T == -(-int(b["length"].max()) // 8) * 8
        assert b["length"].max() <= 64  # every clip is longer than 64 frames in this data: all are cropped
        assert torch.equal(b["mask"], torch.arange(T)[None] < b["length"][:, None])
        assert torch.all(b["motion"][~b["mask"]] == 0)
        assert len(b["text"]) == B and all(isinstance(t, str) and t for t in b["text"])
    val = next(iter(dm.val_dataloader()))  # evaluation crop: multiples of unit_length 4, capped at max_length
    assert all(n % 4 == 0 and n <= 64 for n in val["length"].tolist())


# --- determinism -----------------------------------------------------------------------------------

def _epoch(dm, epoch):
    loader = dm.train_dataloader()
    loader.sampler.set_epoch(epoch)
    return [(b["id"], b["text"], b["motion"]) for b in loader]


def _same(a, b):
    return all(x[0] == y[0] and x[1] == y[1] and torch.equal(x[2], y[2]) for x, y in zip(a, b)) and len(a) == len(b)


def test_order_captions_and_crops_depend_only_on_seed_and_epoch(tmp_path):
    root = write_dataset(tmp_path)
    make = lambda seed, workers=0: MotionDataModule(str(root), batch_size=4, max_length=48, seed=seed,  # noqa: E731
                                                     num_workers=workers)
    dm_a, dm_b = make(7), make(7)
    dm_a.setup("fit"), dm_b.setup("fit")
    first = _epoch(dm_a, 0)
    assert _same(first, _epoch(dm_b, 0))  # a fresh run reproduces epoch 0
    assert _same(_epoch(dm_a, 3), _epoch(dm_b, 3))  # and resuming at epoch 3 reproduces epoch 3
    assert not _same(first, _epoch(dm_a, 1))  # epochs differ
    dm_c = make(8)
    dm_c.setup("fit")
    assert not _same(first, _epoch(dm_c, 0))  # seeds differ
    dm_w = make(7, workers=2)
    dm_w.setup("fit")
    assert _same(first, _epoch(dm_w, 0))  # worker processes do not change the data


def test_val_batches_identical_every_epoch(tmp_path):
    root = write_dataset(tmp_path)
    dm = MotionDataModule(str(root), batch_size=4, seed=3)
    dm.setup("fit")
    loader = dm.val_dataloader()
    a = [(b["id"], b["text"], b["motion"]) for b in loader]
    loader.sampler.set_epoch(5)
    assert _same(a, [(b["id"], b["text"], b["motion"]) for b in loader])


# --- cache -----------------------------------------------------------------------------------------

def test_cache_is_reused_and_invalidated(tmp_path):
    root = write_dataset(tmp_path)
    spec = get_spec("humanml3d")
    first = load_split(root, "train", spec, progress=False)
    assert not first.from_cache
    cache_dir = root / ".stablemo_cache"
    assert (cache_dir / "train.humanml3d.json").is_file()
    second = load_split(root, "train", spec, progress=False)
    assert second.from_cache and isinstance(second.features, np.memmap)
    assert second.ids == first.ids and second.captions == first.captions
    for i, clip_id in enumerate(second.ids):
        np.testing.assert_array_equal(second.motion(i), raw(root, clip_id))
    # Changing a feature file (size differs) invalidates the cache.
    clip_id = second.ids[0]
    np.save(root / "new_joint_vecs" / f"{clip_id}.npy", np.zeros((60, 263), np.float32))
    third = load_split(root, "train", spec, progress=False)
    assert not third.from_cache and third.lengths[0] == 60
    assert len(list(cache_dir.glob("train.humanml3d.*.f32"))) == 1  # the stale data file is gone
    # Editing a caption file (same size, new mtime) invalidates it too.
    text = root / "texts" / f"{clip_id}.txt"
    text.write_text(text.read_text().replace("walks", "talks"))
    os.utime(text, ns=(time.time_ns() + 10**9, time.time_ns() + 10**9))
    fourth = load_split(root, "train", spec, progress=False)
    assert not fourth.from_cache and fourth.captions[0][0].text == "a person talks forward"


def test_cached_split_pickles_by_file_name(tmp_path):
    import pickle

    root = write_dataset(tmp_path)
    data = load_split(root, "train", get_spec("humanml3d"), progress=False)
    blob = pickle.dumps(data)
    assert len(blob) < data.features.nbytes / 10  # spawn-started workers do not copy the features
    copy = pickle.loads(blob)
    assert isinstance(copy.features, np.memmap)
    np.testing.assert_array_equal(copy.motion(2), data.motion(2))


def test_unwritable_cache_dir_falls_back_to_memory(tmp_path):
    root = write_dataset(tmp_path / "data")
    (tmp_path / "a_file").write_text("")
    with pytest.warns(UserWarning, match="cannot write the dataset cache"):
        data = load_split(root, "train", get_spec("humanml3d"), cache_dir=tmp_path / "a_file" / "cache",
                          progress=False)
    assert not isinstance(data.features, np.memmap) and len(data.ids) == 8
    np.testing.assert_array_equal(data.motion(3), raw(root, data.ids[3]))


def test_read_only_dataset_uses_user_cache(tmp_path, monkeypatch):
    root = write_dataset(tmp_path / "data")
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: False if Path(p) == root else real_access(p, mode))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    load_split(root, "train", get_spec("humanml3d"), progress=False)
    assert not (root / ".stablemo_cache").exists()
    assert len(list((tmp_path / "xdg" / "stablemo" / "datasets").glob("*/train.humanml3d.json"))) == 1
    assert load_split(root, "train", get_spec("humanml3d"), progress=False).from_cache


def test_damaged_cache_is_rebuilt(tmp_path):
    root = write_dataset(tmp_path)
    spec = get_spec("humanml3d")
    load_split(root, "train", spec, progress=False)
    data_file = next((root / ".stablemo_cache").glob("train.humanml3d.*.f32"))
    with open(data_file, "r+b") as f:
        f.truncate(100)
    again = load_split(root, "train", spec, progress=False)
    assert not again.from_cache
    np.testing.assert_array_equal(again.motion(0), raw(root, again.ids[0]))
    (root / ".stablemo_cache" / "train.humanml3d.json").write_text("{not json")
    assert not load_split(root, "train", spec, progress=False).from_cache


def test_cache_dir_option_and_no_cache(tmp_path):
    root = write_dataset(tmp_path / "data")
    spec = get_spec("humanml3d")
    load_split(root, "val", spec, cache_dir=tmp_path / "c", progress=False)
    assert (tmp_path / "c" / "val.humanml3d.json").is_file() and not (root / ".stablemo_cache").exists()
    assert load_split(root, "val", spec, cache_dir=tmp_path / "c", progress=False).from_cache
    data = load_split(root, "val", spec, cache=False, progress=False)
    assert not data.from_cache and not (root / ".stablemo_cache").exists()
    np.testing.assert_array_equal(data.motion(1), raw(root, data.ids[1]))


# --- bad input -------------------------------------------------------------------------------------

def _break(root: Path, case: str) -> Path:
    """Damage clip 000003 (listed in train) in one way; returns the path the error must name."""
    feat = root / "new_joint_vecs" / "000003.npy"
    text = root / "texts" / "000003.txt"
    if case == "width":
        np.save(feat, np.zeros((80, 251), np.float32))
    elif case == "ndim":
        np.save(feat, np.zeros((80, 22, 3), np.float32))
    elif case == "nan":
        a = np.zeros((80, 263), np.float32)
        a[10, 5] = np.nan
        np.save(feat, a)
    elif case == "inf":
        a = np.zeros((80, 263), np.float32)
        a[3, 0] = np.inf
        np.save(feat, a)
    elif case == "truncated":
        feat.write_bytes(feat.read_bytes()[:1000])
    elif case == "not_npy":
        feat.write_text("this is not numpy")
    elif case == "pickle":
        np.save(feat, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    elif case == "empty_file":
        feat.write_bytes(b"")
    elif case == "complex":
        np.save(feat, np.zeros((80, 263), np.complex64))
    elif case == "directory":
        feat.unlink()
        feat.mkdir()
    elif case == "missing_features":
        feat.unlink()
    elif case == "missing_text":
        text.unlink()
        return text
    elif case == "empty_text":
        text.write_text("\n\n")
        return text
    elif case == "blank_line":
        text.write_text(WHOLE + "\n\n" + WHOLE2 + "\n")
        return text
    elif case == "malformed":
        text.write_text(WHOLE + "\nno hashes here\n")
        return text
    elif case == "bad_time":
        text.write_text("walks#walk/VERB#soon#later\n")
        return text
    return feat


BAD_CASES = ["width", "ndim", "nan", "inf", "truncated", "not_npy", "pickle", "empty_file", "complex", "directory",
             "missing_features", "missing_text",
             "empty_text", "blank_line", "malformed", "bad_time"]


@pytest.mark.parametrize("case", BAD_CASES)
def test_bad_clip_raises_one_clear_error(tmp_path, case):
    root = write_dataset(tmp_path, splits={"train": [f"{i:06d}" for i in range(12)]})
    culprit = _break(root, case)
    with pytest.raises(StableMoError) as err:
        MotionDataset.from_folder(root, "train", progress=False)
    assert str(culprit) in str(err.value)
    assert "\n" not in str(err.value) and "pickle" not in str(err.value).replace("allow_pickle=False", "")
    assert not list((root / ".stablemo_cache").glob("*.json"))  # nothing half-built is committed


@pytest.mark.parametrize("case", BAD_CASES)
def test_bad_clip_skipped_with_counted_warning(tmp_path, case):
    root = write_dataset(tmp_path, splits={"train": [f"{i:06d}" for i in range(12)]})
    culprit = _break(root, case)
    for attempt in range(2):  # the second read comes from the cache and warns again
        with pytest.warns(UserWarning, match="skipped 1 bad clip") as rec:
            ds = MotionDataset.from_folder(root, "train", skip_bad=True, crop="none", progress=False)
        assert str(culprit) in str(rec[0].message)
        assert "000003" not in ds.data.ids and len(ds.data.ids) == 11
        assert ds.data.from_cache == (attempt == 1)
    # Without skip_bad the cached problem still raises.
    with pytest.raises(StableMoError, match="000003"):
        MotionDataset.from_folder(root, "train", progress=False)


def test_missing_folder_split_and_stats(tmp_path):
    with pytest.raises(StableMoError, match="dataset folder not found"):
        MotionDataset.from_folder(tmp_path / "nope", "train")
    root = write_dataset(tmp_path / "d")
    with pytest.raises(StableMoError, match="extra.txt: split file not found"):
        MotionDataset.from_folder(root, "extra")
    (root / "Std.npy").unlink()
    with pytest.raises(StableMoError, match="Std.npy: file not found"):
        MotionDataModule(str(root)).std
    np.save(root / "Std.npy", np.ones(251, np.float32))
    with pytest.raises(StableMoError, match=r"Std.npy: expected shape \(263,\)"):
        MotionDataModule(str(root)).std
    std = np.ones(263, np.float32)
    std[7] = 0
    np.save(root / "Std.npy", std)
    with pytest.raises(StableMoError, match="Std.npy: std must be > 0"):
        MotionDataModule(str(root)).std
    with pytest.raises(StableMoError, match="dataset='amass'"):
        MotionDataModule(str(root), dataset="amass")
    with pytest.raises(StableMoError, match="pad_multiple=0"):
        MotionDataModule(str(root), pad_multiple=0)


def test_split_listing_twice_or_empty(tmp_path):
    root = write_dataset(tmp_path)
    (root / "train.txt").write_text("000001\n000002\n000001\n")
    with pytest.raises(StableMoError, match=r"train.txt:3: id '000001' listed twice"):
        load_split(root, "train", get_spec("humanml3d"), progress=False)
    (root / "train.txt").write_text("\n")
    with pytest.raises(StableMoError, match="train.txt: split file lists no ids"):
        load_split(root, "train", get_spec("humanml3d"), progress=False)


def test_no_usable_items_is_an_error(tmp_path):
    root = write_dataset(tmp_path, clips={"000001": (20, [WHOLE])}, splits={"train": ["000001"]})
    dm = MotionDataModule(str(root))
    with pytest.raises(StableMoError, match="train.txt: no usable items"):
        dm.setup("fit")


# --- data check ------------------------------------------------------------------------------------

def test_data_check_clean_dataset(tmp_path, capsys):
    from stablemo.cli import main as cli

    clips = {f"{i:06d}": (n, [WHOLE, WHOLE2, "turns#turn/VERB#0.5#3.0"]) for i, n in
             enumerate([30, 45, 80, 120, 150, 199, 210, 60, 90])}
    ids = list(clips)
    root = write_dataset(tmp_path, clips=clips, splits={"train": ids[:5], "val": ids[5:7], "test": ids[7:]})
    assert cli(["data", "check", str(root)]) == 0
    out = capsys.readouterr().out
    lines = {line.split()[0]: line.split()[1:] for line in out.splitlines() if line.startswith("  ") and line.split()}
    # split: listed, readable, items, sub-caption items, too short, too long
    # The window [10, 60) is clipped to [10, 45) = 35 frames in the 45-frame clip: too short for an item.
    assert lines["train"] == ["5", "5", "7", "3", "1", "0"]
    assert lines["val"] == ["2", "2", "2", "1", "0", "1"]
    assert lines["test"] == ["2", "2", "4", "2", "0", "0"]
    assert "problems: none" in out and "vocabulary 8 words" in out
    assert "caption lines per motion: min 3, mean 3.0" in out
    assert "20-39 | " in out and "(dropped: too short)" in out and ">=200 |" in out


def test_data_check_reports_every_problem(tmp_path, capsys):
    from stablemo.cli import main as cli

    root = write_dataset(tmp_path, splits={"train": [f"{i:06d}" for i in range(8)],
                                           "val": ["000008", "000009", "000099"], "test": ["000010", "000011"]})
    _break(root, "nan")
    (root / "texts" / "000005.txt").write_text("bad line\n")
    (root / "texts" / "000006.txt").write_text("a person waves##0.0#0.0\n")
    np.save(root / "new_joint_vecs" / "000010.npy", np.zeros((50, 251), np.float32))
    (root / "test.txt").write_text("000010\n000011\n000001\n")
    # all.txt repeats every clip (each bad one is reported once) and adds one listed nowhere else.
    (root / "all.txt").write_text("".join(f"{i:06d}\n" for i in range(12)) + "000099\n000077\n")
    assert cli(["data", "check", str(root)]) == 1
    out = capsys.readouterr().out
    assert "problems (6):" in out
    assert "000077.npy: listed in all.txt but the feature file does not exist" in out
    assert "1 caption(s) have no word/POS tokens" in out
    assert sorted(p.name for p in (root / ".stablemo_cache").glob("*.json")) == [
        "test.humanml3d.json", "train.humanml3d.json", "val.humanml3d.json"]
    assert "000003.npy: 1 NaN/Inf value(s), first in frame 10" in out
    assert "000005.txt:1: malformed caption line" in out
    assert "000099.npy: listed in val.txt but the feature file does not exist" in out
    assert "000010.npy: expected features of shape (T, 263)" in out
    assert "train.txt: 1 id(s) also in test.txt (e.g. 000001)" in out
    assert cli(["data", "check", str(tmp_path / "absent")]) == 2


def test_data_check_kit(tmp_path, capsys):
    from stablemo.cli.data import main

    root = write_dataset(tmp_path, "kit")
    assert main(["check", str(root), "--dataset", "kit"]) == 0
    assert "kit: 251-d features, 12.5 fps, clips used when 24 <= frames < 200" in capsys.readouterr().out
    assert main(["check", str(root)]) == 1  # 251-d files are wrong for HumanML3D
    out = capsys.readouterr().out
    assert "expected features of shape (T, 263) for humanml3d" in out
    assert "Mean.npy is 251-d: this looks like a kit folder (--dataset kit)" in out


# --- Lightning integration: epoch seeding through the Trainer, resume ----------------------------------

class _Recorder:
    """A tiny LightningModule (built lazily so importing this file stays cheap) that records batch ids."""

    @staticmethod
    def make():
        import lightning as L

        class Rec(L.LightningModule):
            def __init__(self):
                super().__init__()
                self.layer = torch.nn.Linear(263, 1)
                self.seen: list[tuple[int, list[str], list[str]]] = []

            def training_step(self, batch, batch_idx):
                self.seen.append((self.current_epoch, batch["id"], batch["text"]))
                x = (batch["motion"] * batch["mask"][..., None]).sum(1) / batch["length"][:, None]
                return self.layer(x).pow(2).mean()

            def configure_optimizers(self):
                return torch.optim.SGD(self.parameters(), lr=0.01)

        return Rec()


def _fit(root, tmp, epochs, ckpt=None):
    import lightning as L

    model = _Recorder.make()
    trainer = L.Trainer(max_epochs=epochs, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, limit_val_batches=0, default_root_dir=tmp,
                        callbacks=[L.pytorch.callbacks.ModelCheckpoint(dirpath=tmp, save_top_k=-1, every_n_epochs=1)])
    trainer.fit(model, datamodule=MotionDataModule(str(root), batch_size=4, seed=11), ckpt_path=ckpt)
    return model.seen


@pytest.mark.filterwarnings("ignore")  # Lightning's notes about tiny datasets, checkpoint dirs, deprecations
def test_trainer_epochs_reshuffle_and_resume_reproduces_order(tmp_path):
    root = write_dataset(tmp_path / "data")
    full = _fit(root, tmp_path / "a", epochs=3)
    epochs = [[e for e in full if e[0] == k] for k in range(3)]
    assert all(epochs) and epochs[0] != epochs[1] != epochs[2]  # Lightning calls set_epoch: new order each epoch
    assert sorted(i for e in epochs[0] for i in e[1]) == sorted(i for e in epochs[1] for i in e[1])
    assert _fit(root, tmp_path / "b", epochs=3) == full  # same seed, same run
    ckpt = next((tmp_path / "a").glob("epoch=0-*.ckpt"))
    resumed = _fit(root, tmp_path / "c", epochs=3, ckpt=str(ckpt))
    assert resumed == epochs[1] + epochs[2]  # resuming after epoch 0 replays epochs 1 and 2 exactly


# --- the real HumanML3D clip (outside the repo; skipped when absent) -------------------------------------

SAMPLE = Path(__file__).resolve().parents[2] / "shared" / "data" / "humanml3d-sample"


@pytest.mark.skipif(not SAMPLE.is_dir(), reason="../shared/data/humanml3d-sample not present")
def test_real_clip_and_statistics(tmp_path):
    root = tmp_path / "h3d"
    (root / "new_joint_vecs").mkdir(parents=True)
    (root / "texts").mkdir()
    (root / "new_joint_vecs" / "012314.npy").write_bytes((SAMPLE / "new_joint_vecs" / "012314.npy").read_bytes())
    for name in ("Mean.npy", "Std.npy"):
        (root / name).write_bytes((SAMPLE / name).read_bytes())
    (root / "texts" / "012314.txt").write_text(WHOLE + "\n" + "turns#turn/VERB#2.0#6.0\n")
    (root / "train.txt").write_text("012314\n")
    dm = MotionDataModule(str(root), batch_size=2, pad_multiple=16)
    dm.setup("fit")
    dataset_std = np.load(SAMPLE / "Std.npy")
    np.testing.assert_allclose(dm.std[4:259], dataset_std[4:259])
    np.testing.assert_allclose(dm.std[:4] * 5, dataset_std[:4], rtol=1e-6)
    np.testing.assert_allclose(dm.std[259:] * 5, dataset_std[259:], rtol=1e-6)
    batch = next(iter(dm.train_dataloader()))
    assert sorted(batch["id"]) == ["012314", "012314#40-120"] and batch["motion"].shape == (2, 176, 263)
    full = batch["motion"][batch["id"].index("012314")]
    np.testing.assert_allclose(denormalize(full[:170], dm.mean, dm.std).numpy(),
                               np.load(SAMPLE / "new_joint_vecs" / "012314.npy"), atol=1e-5)


def test_npz_disguised_as_npy(tmp_path):
    root = write_dataset(tmp_path, splits={"train": [f"{i:06d}" for i in range(12)]})
    for path in (root / "new_joint_vecs" / "000004.npy", root / "Mean.npy"):
        with open(path, "wb") as f:
            np.savez(f, a=np.ones(3))
    with pytest.raises(StableMoError, match=r"000004.npy: an .npz archive, not a .npy file"):
        load_split(root, "train", get_spec("humanml3d"), progress=False)
    with pytest.raises(StableMoError, match=r"Mean.npy: an .npz archive, not a .npy file"):
        MotionDataModule(str(root)).mean


def test_stats_file_that_is_not_npy(tmp_path):
    root = write_dataset(tmp_path)
    (root / "Mean.npy").write_text("mean values")
    with pytest.raises(StableMoError, match=r"Mean.npy: not a .npy file \(no NUMPY header\)"):
        MotionDataModule(str(root)).mean


def test_data_check_lists_the_first_problems_only(tmp_path):
    from stablemo.data.check import check_dataset, format_report

    root = write_dataset(tmp_path, "kit")
    report = check_dataset(root, "humanml3d")
    assert len(report.problems) == 14  # Mean.npy, Std.npy and 12 clips of the wrong width
    text = format_report(report, max_problems=3)
    assert text.count("\n  - ") - len(report.notes) == 3 and "... and 11 more (--all-problems lists them)" in text


def test_windows_line_endings_and_byte_order_mark(tmp_path):
    root = write_dataset(tmp_path, clips={"000001": (60, [WHOLE]), "000002": (70, [WHOLE])},
                         splits={"train": ["000001", "000002"]})
    (root / "train.txt").write_bytes(b"\xef\xbb\xbf000001\r\n000002\r\n")
    (root / "texts" / "000002.txt").write_bytes(b"\xef\xbb\xbf" + (WHOLE2 + "\r\n" + WHOLE + "\r\n").encode())
    ds = MotionDataset.from_folder(root, "train", crop="none", progress=False)
    assert ds.items.ids == ["000001", "000002"]
    assert [c.text for c in ds.items.captions[1]] == ["someone strolls ahead", "a person walks forward"]


def test_same_statistics_accepts_round_trips_and_rejects_other_statistics():
    gen = np.random.default_rng(0)
    std = apply_feat_bias(gen.uniform(0.01, 3.0, 263).astype(np.float32), 5.0)
    as_json = [float(v) for v in std]  # how a bundle's config keeps them
    assert same_statistics(as_json, torch.from_numpy(std))
    assert same_statistics(std, std.astype(np.float64) * (1 + 5e-5))  # float32 and checkpoint round trips
    other = std.copy()
    other[100] *= 1.001  # one channel 0.1 % off: another dataset's statistics
    assert not same_statistics(as_json, other)
    assert not same_statistics(std, std[:-1])  # another feature width
    assert not same_statistics(None, std) and not same_statistics(std, None)
