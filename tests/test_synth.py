"""Synthetic dataset: physics of the generated motions, captions vs measured motion, the written folder."""

from __future__ import annotations

import re

import numpy as np
import pytest

from stablemo.data.synth import ACTIONS, compose, generate_motion, write_dataset
from stablemo.data.synth import actions as synth_actions
from stablemo.data.synth import captions as synth_captions
from stablemo.data.synth.body import BONE_LENGTHS, bone_lengths
from stablemo.data.synth.writer import motion_rng
from stablemo.errors import StableMoError
from stablemo.motion import features_to_joints, joints_to_features
from stablemo.skating.metrics import foot_skating_ratio

N_SAMPLE = 60
FPS = 20


@pytest.fixture(scope="module")
def sample():
    """The first motions of the default dataset (`stablemo data synth` uses seed 0)."""
    return [generate_motion(motion_rng(0, i)) for i in range(N_SAMPLE)]


def _gallery(seed: int = 0):
    """One single-action motion per action (and per seed offset)."""
    out = []
    for i, name in enumerate(ACTIONS):
        rng = np.random.default_rng([seed, i])
        params = synth_actions.sample_params(name, rng)
        out.append((name, params, compose.build([(name, params)])))
    return out


@pytest.fixture(scope="module")
def gallery():
    return _gallery(0) + _gallery(1)


# --------------------------------------------------------------------------- physics


def test_lengths_in_range(sample):
    for m in sample:
        assert 40 <= len(m.joints) - 1 <= 196  # feature frames
        assert m.joints.shape[1:] == (22, 3) and m.joints.dtype == np.float32
        assert m.contacts.shape == (len(m.joints), 4)


def test_bone_lengths_constant(sample, gallery):
    for j in [m.joints for m in sample] + [b.joints for _, _, b in gallery]:
        err = np.abs(bone_lengths(j.astype(np.float64)) - BONE_LENGTHS[1:])
        assert err.max() < 2e-5


def test_no_floor_penetration_and_on_the_floor(sample, gallery):
    for j in [m.joints for m in sample] + [b.joints for _, _, b in gallery]:
        y = j[..., 1]
        assert y.min() >= 0.0
        # the lowest foot joint touches the floor in every frame except flights
        lowest = y[:, [7, 8, 10, 11]].min(1)
        assert np.median(lowest) < 0.01


def test_canonical_start(sample):
    for m in sample:
        j = m.joints[0].astype(np.float64)
        assert np.allclose(j[0, [0, 2]], 0.0, atol=1e-6)
        across = (j[2] - j[1]) + (j[17] - j[16])
        fwd = np.cross([0, 1, 0], across)
        assert np.arctan2(fwd[0], fwd[2]) == pytest.approx(0.0, abs=1e-5)
        assert j[1, 0] > j[2, 0]  # left hip at +x when facing +z


def test_planted_feet_no_skating(sample, gallery):
    motions = [m.joints for m in sample] + [b.joints for _, _, b in gallery]
    ratios = np.array([foot_skating_ratio(j)[0] for j in motions])
    assert ratios.max() < 0.01, ratios.max()
    # ground-truth contacts: a foot part in contact is within 1 cm of its flat-foot height and does
    # not slide (the first moments of a heel-off and the last of a heel strike count as contact)
    for m in sample:
        j = m.joints.astype(np.float64)
        for joint, ch in ((7, 0), (10, 1), (8, 2), (11, 3)):
            c = m.contacts[:, ch]
            both = c[1:] & c[:-1]
            if both.any():
                assert np.linalg.norm(np.diff(j[:, joint][:, [0, 2]], axis=0), axis=-1)[both].max() < 0.005
                assert np.ptp(j[c, joint, 1]) < 0.0105


def test_smooth_trajectories(sample):
    for m in sample:
        root = m.joints[:, 0].astype(np.float64)
        vel = np.diff(root, axis=0) * FPS
        acc = np.diff(vel, axis=0) * FPS
        speed = np.linalg.norm(vel[:, [0, 2]], axis=-1)
        assert speed.max() < 4.5  # m/s: nobody sprints faster here
        assert np.abs(acc[:, [0, 2]]).max() < 25.0  # m/s^2: no velocity jumps between parts
        assert np.linalg.norm(vel[0]) < 0.3 and np.linalg.norm(vel[-1]) < 0.3  # starts and ends at rest


def test_features_round_trip(sample):
    for m in sample[:8]:
        feats = joints_to_features(m.joints)
        rec = features_to_joints(feats)
        assert np.abs(rec - m.joints[:-1]).max() < 1e-3


def test_contacts_agree_with_feature_bits(sample):
    agree, swapped, frames = 0.0, 0.0, 0
    for m in sample:
        bits = joints_to_features(m.joints)[:, -4:] > 0.5
        gt = m.contacts[: len(bits)]
        agree += (bits == gt).sum()
        swapped += (bits == gt[:, [2, 3, 0, 1]]).sum()
        frames += bits.size
        # contact channels are in HumanML3D order: a standing-still start has all four down
        assert gt[0].all()
    assert agree / frames >= 0.9
    assert swapped / frames < agree / frames - 0.04  # left/right order matters


def test_determinism(sample):
    again = generate_motion(motion_rng(0, 5))
    assert np.array_equal(again.joints, sample[5].joints)
    assert again.captions == sample[5].captions
    other = generate_motion(motion_rng(1, 5))
    assert not (other.joints.shape == sample[5].joints.shape and np.array_equal(other.joints, sample[5].joints))


# --------------------------------------------------------------------------- captions vs motion


def _yaw(j: np.ndarray) -> np.ndarray:
    across = (j[:, 2] - j[:, 1]) + (j[:, 17] - j[:, 16])
    fwd = np.cross([0.0, 1.0, 0.0], across)
    return np.unwrap(np.arctan2(fwd[:, 0], fwd[:, 2]))


def _runs(mask: np.ndarray) -> int:
    m = mask.astype(int)
    return int(((m[1:] - m[:-1]) == 1).sum() + m[0])


_NUM = {"one": 1, "two": 2, "three": 3, "four": 4, "five": 5}


def _count_in(text: str) -> int:
    if m := re.search(r"\b(once|twice|(one|two|three|four|five) times)\b", text):
        return {"once": 1, "twice": 2}.get(m.group(1)) or _NUM[m.group(2)]
    if m := re.search(r"\b(two|three|four|five) (?:\w+ )?(jumps|hops|squats|punches|claps)\b", text):
        return _NUM[m.group(1)]
    return 1


def _side_in(text: str) -> str:
    found = set(re.findall(r"\b(left|right)\b", text))
    assert len(found) == 1, text
    return found.pop()


def _measure(action: str, j: np.ndarray, text: str) -> None:
    """Assert that what `text` says about this action is what the joints do."""
    j = j.astype(np.float64)
    yaw = _yaw(j)
    root = j[:, 0]
    y0 = yaw[0]
    fwd0 = np.array([np.sin(y0), np.cos(y0)])
    left0 = np.array([np.cos(y0), -np.sin(y0)])
    disp = root[-1, [0, 2]] - root[0, [0, 2]]
    speed = np.linalg.norm(np.diff(root[:, [0, 2]], axis=0), axis=-1) * FPS
    turned = np.rad2deg(yaw[-1] - yaw[0])
    feet_y = j[:, [7, 8, 10, 11], 1]
    if action in ("walk", "jog", "run"):
        assert disp @ fwd0 > 1.0 and abs(disp @ left0) < 0.2 * (disp @ fwd0)
        assert abs(turned) < 10
        top = np.percentile(speed, 90)
        if action == "walk":
            label = ("slow" if re.search(r"slow|stroll", text) else
                     "fast" if re.search(r"quick|brisk|fast", text) else "normal")
            assert {"slow": (0.5, 1.05), "normal": (0.95, 1.5), "fast": (1.45, 2.0)}[label][0] <= top
            assert top <= {"slow": (0.5, 1.05), "normal": (0.95, 1.5), "fast": (1.45, 2.0)}[label][1]
        else:
            assert (1.8 <= top <= 2.7) if action == "jog" else top >= 2.8
        if re.search(r"\bwav", text):  # "walks forward while waving the left hand"
            _measure("wave", j, text)
    elif action == "walk_backward":
        assert "back" in text and disp @ fwd0 < -0.6 and abs(turned) < 10
    elif action == "walk_sideways":
        sign = 1 if _side_in(text) == "left" else -1
        assert sign * (disp @ left0) > 0.3 and abs(disp @ fwd0) < 0.15 and abs(turned) < 10
    elif action == "turn":
        sign = 1 if _side_in(text) == "left" else -1
        angle = 180 if re.search(r"around|180|half", text) else 90
        assert sign * turned == pytest.approx(angle, abs=15)
        assert np.linalg.norm(disp) < 0.15
    elif action == "circle":
        ccw = "counterclockwise" in text or "to the left" in text
        assert (1 if ccw else -1) * turned == pytest.approx(360, abs=25)
        assert np.linalg.norm(disp) < 0.4
    elif action in ("jump", "jump_forward"):
        flights = _runs(feet_y.min(1) > 0.03)
        assert flights == _count_in(text)
        if action == "jump":
            assert np.linalg.norm(disp) < 0.1
        else:
            assert disp @ fwd0 > 0.4 * flights
    elif action == "hop":
        stance = 0 if _side_in(text) == "left" else 1
        free_toe = j[:, 11 - stance, 1]
        stance_toe = j[:, 10 + stance, 1]
        assert free_toe.max() > 0.25
        assert _runs((stance_toe > 0.03) & (free_toe > 0.1)) == _count_in(text)
    elif action == "kick":
        kick = 0 if _side_in(text) == "left" else 1
        assert j[:, 7 + kick, 1].max() > 0.35 and j[:, 8 - kick, 1].max() < 0.1
        assert ((j[:, 7 + kick, [0, 2]] - root[:, [0, 2]]) @ fwd0).max() > 0.4  # kicks forward
    elif action == "squat":
        assert _runs(root[:, 1] < root[0, 1] - 0.2) == _count_in(text)
    elif action == "crouch":
        assert _runs(root[:, 1] < root[0, 1] - 0.25) == 1
    elif action == "bow":
        head_fwd = (j[:, 15, [0, 2]] - root[:, [0, 2]]) @ fwd0
        assert head_fwd.max() > 0.3 and root[:, 1].min() > root[0, 1] - 0.1
    elif action == "wave":
        hands = {"left": [0], "right": [1], "both": [0, 1]}[
            "both" if "both" in text else _side_in(text)]
        for s in (0, 1):
            raised = (j[:, 20 + s, 1] > j[:, 16 + s, 1]).any()
            assert raised == (s in hands)
    elif action == "raise_arms":
        hands = [0, 1] if "both" in text else [0 if _side_in(text) == "left" else 1]
        for s in (0, 1):
            lifted = (j[:, 20 + s, 1] > j[:, 16 + s, 1] - 0.1).any()
            assert lifted == (s in hands)
    elif action == "punch":
        reach = np.stack([(j[:, 20 + s, [0, 2]] - root[:, [0, 2]]) @ fwd0 for s in (0, 1)])
        punches = sum(_runs(reach[s] > 0.45) for s in (0, 1))
        assert punches == _count_in(text)
        if "alternat" not in text and "both" not in text and "left and right" not in text and punches:
            side = _side_in(text) if re.search(r"\b(left|right)\b", text) else None
            if side:
                assert (reach[0 if side == "left" else 1] > 0.45).any()
                assert not (reach[1 if side == "left" else 0] > 0.45).any()
    elif action == "clap":
        gap = np.linalg.norm(j[:, 20] - j[:, 21], axis=-1)
        assert _runs(gap < 0.12) == _count_in(text)
    elif action == "stand":
        assert np.linalg.norm(disp) < 0.05 and speed.max() < 0.3
    else:
        raise AssertionError(f"no check for {action}")


def test_captions_match_motion_single_actions(gallery):
    for name, params, built in gallery:
        rng = np.random.default_rng(0)
        texts = synth_captions.captions_for([(name, params)], rng, num=3)
        assert len(set(texts)) == 3
        for text in texts:
            _measure(name, built.joints, text)


def test_sub_captions_match_their_parts(sample):
    checked = 0
    for m in sample:
        if len(m.parts) == 1:
            for text in m.captions:
                _measure(m.parts[0].action, m.joints, text)
            continue
        assert len(m.sub_captions) == len(m.parts)
        for part, (text, start, end) in zip(m.parts, m.sub_captions):
            a, b = int(round(start * FPS)), int(round(end * FPS))
            assert (a, b) == (part.start, min(part.end, len(m.joints) - 1))
            _measure(part.action, m.joints[a:b + 1], text)
            checked += 1
    assert checked > 10


def test_walk_while_waving():
    params = dict(speed_label="normal", speed=1.2, duration=3.0, first_foot=0, waving="left")
    built = compose.build([("walk", params)])
    for text in synth_captions.captions_for([("walk", params)], np.random.default_rng(3)):
        assert "wav" in text and "left" in text
        _measure("walk", built.joints, text)


def test_tagger():
    line = synth_captions.caption_line("a man walks forward quickly, then turns left and waves with his right hand.")
    text, tokens, start, end = line.split("#")
    assert (start, end) == ("0.00", "0.00")
    assert tokens.split() == ["a/DET", "man/NOUN", "walk/VERB", "forward/ADV", "quickly/ADV", "then/ADV",
                              "turn/VERB", "left/ADJ", "and/CCONJ", "wave/VERB", "with/ADP", "his/DET",
                              "right/ADJ", "hand/NOUN"]
    assert "squat/NOUN" in synth_captions.tag("someone does two squats")
    assert "punch/VERB" in synth_captions.tag("a person punches twice")
    assert synth_captions.tag("she waves while walking").split()[2:] == ["while/SCONJ", "walk/VERB"]


def test_every_action_named_in_captions():
    rng = np.random.default_rng(0)
    for name in ACTIONS:
        for text in synth_captions.captions_for([(name, synth_actions.sample_params(name, rng))], rng):
            assert text.endswith(".") and len(text.split()) >= 3
    assert len(ACTIONS) >= 15


# --------------------------------------------------------------------------- the written folder


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    root = tmp_path_factory.mktemp("synth") / "data"
    write_dataset(root, num=30, seed=4, workers=1)
    return root


def test_written_layout(written):
    from stablemo.data.stats import compute_stats

    ids = (written / "all.txt").read_text().split()
    assert len(ids) == 30 and ids[0] == "000000"
    split = {s: set((written / f"{s}.txt").read_text().split()) for s in ("train", "val", "test", "train_val")}
    assert split["train"].isdisjoint(split["val"]) and split["train"].isdisjoint(split["test"])
    assert split["train"] | split["val"] | split["test"] == set(ids)
    assert split["train_val"] == split["train"] | split["val"]
    feats = []
    for cid in ids:
        f = np.load(written / "new_joint_vecs" / f"{cid}.npy")
        j = np.load(written / "new_joints" / f"{cid}.npy")
        c = np.load(written / "contacts" / f"{cid}.npy")
        assert f.shape[1] == 263 and f.dtype == np.float32 and 40 <= len(f) <= 196
        assert j.shape == (len(f), 22, 3) and c.shape == (len(f), 4)
        assert np.abs(features_to_joints(f) - j).max() < 1e-3
        lines = (written / "texts" / f"{cid}.txt").read_text().splitlines()
        assert len(lines) >= 3 and all(len(line.split("#")) == 4 for line in lines)
        feats.append(f)
    mean, std = compute_stats(feats, 263)
    assert np.allclose(np.load(written / "Mean.npy"), mean, atol=1e-5)
    assert np.allclose(np.load(written / "Std.npy"), std, rtol=1e-4)


def test_written_passes_data_check(written):
    from stablemo.data.check import check_dataset

    report = check_dataset(written, cache=False)
    assert report.ok, report.problems


def test_written_loads_in_datamodule(written):
    from stablemo.data.datamodule import MotionDataModule

    dm = MotionDataModule(data_dir=str(written), batch_size=4, cache=False)
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    assert batch["motion"].shape[0] == 4 and batch["motion"].shape[2] == 263
    assert all(isinstance(t, str) and t for t in batch["text"])


def test_write_is_deterministic_across_workers(written, tmp_path):
    other = tmp_path / "again"
    write_dataset(other, num=30, seed=4, workers=2)
    for path in sorted(p for p in written.rglob("*") if p.is_file() and ".stablemo_cache" not in str(p)):
        rel = path.relative_to(written)
        assert (other / rel).read_bytes() == path.read_bytes(), rel


def test_write_refuses_foreign_folder(tmp_path):
    (tmp_path / "mine.txt").write_text("keep me")
    with pytest.raises(StableMoError):
        write_dataset(tmp_path, num=2)
    assert (tmp_path / "mine.txt").read_text() == "keep me"
    with pytest.raises(StableMoError):
        write_dataset(tmp_path / "x", num=2)  # too few for train/val/test
    assert not (tmp_path / "x").exists()


def test_cli_synth(tmp_path):
    from stablemo.cli import main

    assert main(["data", "synth", "--out", str(tmp_path / "d"), "--num", "3", "--seed", "1"]) == 0
    assert len((tmp_path / "d" / "all.txt").read_text().split()) == 3
    assert main(["data", "synth", "--out", str(tmp_path / "d"), "--num", "3", "--seed", "1"]) == 0  # replaces it
