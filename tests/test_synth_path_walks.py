"""Synthetic path walks (stablemo/data/synth/path_walks.py): a forward walk along a random curved
path in any direction, facing where it goes, on the floor, and the dataset option that mixes them in."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from stablemo.data.synth import compose, write_dataset
from stablemo.data.synth.body import BONE_LENGTHS, bone_lengths
from stablemo.data.synth.writer import is_path_walk, motion_rng
from stablemo.errors import StableMoError
from stablemo.eval.heading import facing_vs_travel
from stablemo.motion.heading import travel
from stablemo.skating.metrics import foot_skating_ratio

FPS = 20


@pytest.fixture(scope="module")
def walks():
    return [compose.generate_path_walk(motion_rng(3, i)) for i in range(40)]


def _walking(j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Over the moving frames of joints j (T, 22, 3) (stablemo.eval.heading): the angle between facing
    and travel (degrees) and the direction of travel (radians) over 5 frames, so that a U-turn's
    span is not averaged away."""
    ft = facing_vs_travel(torch.from_numpy(j)[None], [len(j)], "humanml3d")
    way, _ = travel(torch.from_numpy(j[None, :, 0][..., [0, 2]]), torch.tensor([len(j)]), FPS, window_s=5 / FPS)
    moving = ft["moving"][0]
    return ft["angle"][0][moving].numpy(), way[0][moving].numpy()


def test_path_walks_are_one_rigid_body_on_the_floor_without_skating(walks):
    for m in walks:
        j = m.joints.astype(np.float64)
        assert 40 <= len(j) - 1 <= 196
        assert np.abs(bone_lengths(j) - BONE_LENGTHS[1:]).max() < 2e-5
        assert j[..., 1].min() >= 0.0 and np.median(j[:, [7, 8, 10, 11], 1].min(1)) < 0.01
        assert m.actions == ["walk_path"]
    ratios = np.array([foot_skating_ratio(m.joints)[0] for m in walks])
    assert ratios.max() < 0.01, ratios.max()


def test_path_walks_face_where_they_walk(walks):
    every = np.concatenate([_walking(m.joints.astype(np.float64))[0] for m in walks])
    assert np.median(every) < 10.0, np.median(every)
    assert np.percentile(every, 95) < 30.0, np.percentile(every, 95)


def test_path_walks_start_in_every_direction_and_bend(walks):
    quadrants, turned = set(), 0
    for m in walks:
        j = m.joints.astype(np.float64)
        xz = j[:, 0, [0, 2]]
        far = np.nonzero(np.linalg.norm(xz - xz[0], axis=-1) > 1.0)[0]
        d = xz[far[0]] - xz[0]
        quadrants.add((bool(d[0] > 0), bool(d[1] > 0)))
        turned += np.ptp(np.unwrap(_walking(j)[1])) > np.radians(45)
    assert len(quadrants) == 4  # ahead, behind, left and right of the body's first heading
    assert turned >= 10  # many paths bend while walking, not only at the start


def test_captions_say_the_turn_and_the_way_back(walks):
    for m in walks:
        p = m.parts[0].params
        text = " ".join(m.captions)
        assert "walk" in text
        if p["spot_turn"]:
            side = "left" if p["spot_turn"] > 0 else "right"
            assert all(f"turns to the {side}" in c or f"turns around to the {side}" in c for c in m.captions)
        if any(abs(a) >= np.radians(150) for _, a in p["segments"]):
            assert any("back" in c for c in m.captions)
            # it does come back: the walking directions span more than 140 degrees
            assert np.ptp(np.unwrap(_walking(m.joints.astype(np.float64))[1])) > np.radians(140)


def test_a_dataset_with_path_walks_keeps_the_other_motions_file_for_file(tmp_path):
    plain, mixed = tmp_path / "plain", tmp_path / "mixed"
    write_dataset(plain, num=12, seed=2, workers=1)
    write_dataset(mixed, num=12, seed=2, workers=1, path_walks=0.5)
    walks = [i for i in range(12) if is_path_walk(2, i, 0.5)]
    assert 0 < len(walks) < 12
    for i in range(12):
        name = f"new_joint_vecs/{i:06d}.npy"
        same = (plain / name).read_bytes() == (mixed / name).read_bytes()
        assert same == (i not in walks), i
        if i in walks:
            assert "walk" in (mixed / "texts" / f"{i:06d}.txt").read_text()
    meta = json.loads((mixed / "synth.json").read_text())
    assert meta["path_walks"] == 0.5 and meta["action_counts"]["walk_path"] == len(walks)
    assert "path_walks" not in json.loads((plain / "synth.json").read_text())
    with pytest.raises(StableMoError, match="path_walks"):
        write_dataset(tmp_path / "bad", num=3, path_walks=1.5)
    assert not (tmp_path / "bad").exists()


def test_cli_path_walks_share_is_checked(tmp_path, capsys):
    from stablemo.cli import main

    assert main(["data", "synth", "--out", str(tmp_path / "d"), "--num", "3", "--path-walks", "-0.1"]) == 2
    assert "--path-walks" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()


def test_datamodule_normalises_with_another_folders_stats(tmp_path):
    from stablemo.data.datamodule import MotionDataModule

    base, new = tmp_path / "base", tmp_path / "new"
    write_dataset(base, num=5, seed=0, workers=1)
    write_dataset(new, num=5, seed=0, workers=1, path_walks=1.0)
    own = MotionDataModule(data_dir=str(new), batch_size=2, cache=False)
    theirs = MotionDataModule(data_dir=str(new), batch_size=2, cache=False, stats_dir=str(base))
    reference = MotionDataModule(data_dir=str(base), batch_size=2, cache=False)
    assert np.array_equal(theirs.mean, reference.mean) and np.array_equal(theirs.std, reference.std)
    assert not np.allclose(own.mean, reference.mean)
    theirs.setup("fit")
    batch = next(iter(theirs.train_dataloader()))
    raw = np.load(new / "new_joint_vecs" / f"{batch['id'][0]}.npy")
    n = int(batch["length"][0])
    # the clip may be cropped: find its window, normalised with the base's stats
    x = batch["motion"][0, :n].numpy() * theirs.std + theirs.mean
    hits = [s for s in range(len(raw) - n + 1) if np.allclose(raw[s:s + n], x, atol=1e-4)]
    assert hits
    missing = MotionDataModule(data_dir=str(new), batch_size=2, cache=False, stats_dir=str(tmp_path / "nowhere"))
    with pytest.raises(StableMoError, match="nowhere"):
        _ = missing.mean
