"""`stablemo generate --control`, `stablemo edit`, `stablemo control-file`: as a user runs them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stablemo.cli import main
from stablemo.cli.control_file import canonical_start
from stablemo.control.files import load_control
from stablemo.control.parts import joint_columns, keep_mask, part_joints
from stablemo.errors import StableMoError
from stablemo.motion.features import feature_slices
from stablemo.motion.skeleton import get_skeleton

DEMO = Path(__file__).resolve().parents[1] / "stablemo" / "assets" / "demo_bundle"


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """A generated 80-frame motion on disk (features and joints) and a turned copy of its joints."""
    out = tmp_path_factory.mktemp("clip")
    assert main(["generate", "a person walks in a circle counterclockwise", "--frames", "80", "--seed", "3",
                 "--out", str(out), "--no-render"]) == 0
    stem = out / "a-person-walks-in-a-circle-counterclockwise"
    return stem.with_suffix(".features.npy"), stem.with_suffix(".joints.npy")


def test_parts_cover_every_column_once():
    for name in ("humanml3d", "kit"):
        skel = get_skeleton(name)
        counts = np.zeros(skel.feature_dim, int)
        for part in ("lower_body", "upper_body"):
            for j in part_joints(part, skel):
                counts[joint_columns(j, skel)] += 1
        counts[feature_slices(skel)["contacts"]] += 1
        assert (counts == 1).all(), name


def test_keep_phrases():
    m = keep_mask(["frames=0:10,70:80"], 80, "humanml3d")
    assert m[:10].all() and m[70:].all() and not m[10:70].any()
    m = keep_mask(["lower_body", "frames=0:20"], 80, "humanml3d")
    assert m[:20, :4].all() and not m[20:].any() and not m[:20, joint_columns(20, "humanml3d")].any()
    m = keep_mask(["joints=L_wrist,right_wrist"], 10, "humanml3d")
    assert m[:, joint_columns(20, "humanml3d")].all() and m[:, joint_columns(21, "humanml3d")].all()
    with pytest.raises(StableMoError, match="elbows"):
        keep_mask(["elbows"], 10, "humanml3d")
    with pytest.raises(StableMoError, match="outside"):
        keep_mask(["frames=0:90"], 80, "humanml3d")


def test_control_file_from_a_turned_clip_and_generate_follows_it(clip, tmp_path, capsys):
    _, joints_path = clip
    joints = np.load(joints_path)
    # the same motion turned by 130 degrees and moved: control-file puts it back in the generator's frame
    a = np.deg2rad(130)
    rot = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    moved = joints @ rot.T + np.array([2.0, 0.0, -1.0])
    np.save(tmp_path / "moved.npy", moved)
    ctl = tmp_path / "pelvis.npz"
    assert main(["control-file", str(tmp_path / "moved.npy"), "--joints", "pelvis", "--out", str(ctl)]) == 0
    spec = load_control(ctl, "humanml3d")
    # the start is canonical whatever the heading and place: the same as the unmoved clip's
    np.testing.assert_allclose(spec.positions, canonical_start(joints, "humanml3d"), atol=1e-4)
    np.testing.assert_allclose(spec.positions[0, 0, [0, 2]], 0.0, atol=1e-6)
    assert np.asarray(spec.mask)[:, 0].all() and not np.asarray(spec.mask)[:, 1:].any()
    joints = np.asarray(spec.positions)
    out = tmp_path / "out"
    assert main(["generate", "a person walks forward", "--control", str(ctl), "--out", str(out)]) == 0
    got = np.load(out / "a-person-walks-forward.joints.npy")
    assert got.shape == joints.shape  # the length comes from the file
    err = np.linalg.norm(got[:, 0] - joints[:, 0], axis=-1)
    assert err.mean() < 0.03 and (out / "a-person-walks-forward.gif").is_file()


def test_edit_inbetweens_and_edits_body_parts_exactly(clip, tmp_path):
    feats_path, _ = clip
    src = np.load(feats_path)
    out = tmp_path / "edit"
    assert main(["edit", str(feats_path), "--keep", "frames=0:20", "--keep", "frames=60:80", "--text",
                 "a person jumps in place", "--out", str(out), "--name", "inb", "--no-render"]) == 0
    # the network keeps the known features exactly (tests/test_control.py); what is written is then
    # finished (rigid body, floor), which moves the kept frames' body (root-relative joints, ric) by
    # millimetres, most at the hand-over frames (a knee 3.4 cm there since the free frames' planted feet are
    # anchored: 2.3 cm before)
    ric = feature_slices("humanml3d")["ric"]

    def close(feats, frames, joints=slice(None)):
        diff = np.linalg.norm((feats[frames, ric] - src[frames, ric]).reshape(-1, 21, 3)[:, joints], axis=-1)
        return diff.max() < 0.04 and np.median(diff) < 0.005

    got = np.load(out / "inb.features.npy")
    assert close(got, slice(0, 20)) and close(got, slice(60, 80))
    assert np.abs(got[20:60] - src[20:60]).max() > 1e-2
    assert main(["edit", str(feats_path), "--keep", "lower_body", "--text", "a person waves both hands",
                 "--out", str(out), "--name", "upper", "--no-render"]) == 0
    got = np.load(out / "upper.features.npy")
    lower = keep_mask(["lower_body"], 80, "humanml3d")
    legs = [0, 1, 2, 4, 5, 7, 8, 10, 11]
    assert close(got, slice(None), [j - 1 for j in legs if j])
    assert np.abs(got[~lower] - src[~lower]).max() > 1e-2
    # a continuation: 80 kept frames, 40 new ones
    assert main(["edit", str(feats_path), "--keep", "frames=0:80", "--frames", "120", "--text", "a person jumps",
                 "--out", str(out), "--name", "more", "--no-render"]) == 0
    got = np.load(out / "more.features.npy")
    assert got.shape == (120, 263) and close(got, slice(0, 78))  # the source's last rows were its end


@pytest.mark.parametrize("case,message", [
    ("no-positions", "missing positions"),
    ("joints", "(T, 22, 3)"),
    ("late", "frame 100"),
    ("nan", "NaN"),
    ("empty", "all False"),
])
def test_bad_control_files_are_one_line_errors(tmp_path, capsys, case, message):
    pos = np.zeros((80, 22, 3), np.float32)
    mask = np.zeros((80, 22), bool)
    mask[5, 20] = True
    if case == "no-positions":
        np.savez(tmp_path / "c.npz", mask=mask)
    else:
        if case == "joints":
            pos, mask = pos[:, :21], mask[:, :21]
        elif case == "late":
            pos, mask = np.zeros((120, 22, 3)), np.zeros((120, 22), bool)
            mask[100, 0] = True
        elif case == "nan":
            pos[5, 20] = np.nan
        elif case == "empty":
            mask[:] = False
        np.savez(tmp_path / "c.npz", positions=pos, mask=mask)
    args = ["generate", "a person walks", "--control", str(tmp_path / "c.npz"), "--out", str(tmp_path / "o")]
    if case == "late":
        args += ["--frames", "80"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err and "Traceback" not in err
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_edit_bad_input(tmp_path, capsys):
    np.save(tmp_path / "f.npy", np.zeros((40, 100), np.float32))
    assert main(["edit", str(tmp_path / "f.npy"), "--keep", "lower_body", "--text", "x", "--out", str(tmp_path)]) == 2
    assert "100 columns" in capsys.readouterr().err
    assert main(["edit", str(tmp_path / "none.npy"), "--keep", "root", "--text", "x", "--out", str(tmp_path)]) == 2
    assert "not found" in capsys.readouterr().err


def test_evaluate_with_control_reports_control_errors(tmp_path, capsys):
    """`stablemo evaluate --control` on 40 synthetic clips: the controlled row meets its hints, and
    the same items scored without control are far from them (the errors measure something)."""
    import json

    from stablemo.eval.control import ControlProtocol

    data = tmp_path / "synth"
    assert main(["data", "synth", "--out", str(data), "--num", "40", "--seed", "0"]) == 0
    common = ["--bundle", str(DEMO), "--data", str(data), "--split", "all", "--replications", "1", "--steps", "2",
              "--sampler", "ddim", "--aits", "1", "--no-progress"]
    out = tmp_path / "ctl.json"
    assert main(["evaluate", *common, "--control", "pelvis", "--density", "25%", "--out", str(out)]) == 0
    row = next(v for k, v in json.loads(out.read_text())["rows"].items() if "control pelvis 25%" in k)
    assert row["avg_err"]["mean"] < 0.01 and row["traj_err"]["mean"] == 0.0
    assert {"spikes", "foot_acc", "skate_ratio", "fid", "r3", "stance_speed"} <= set(row)
    # hinted paths walked facing forward, not backwards or sideways where the hinted motion walks forward
    assert row["facing_deg"]["mean"] < 45 and row["unasked_backward"]["mean"] < 0.2
    assert 0 <= row["unasked_sideways"]["mean"] < 0.5
    assert main(["evaluate", "--data", str(data), "--control", "pelvis"]) == 2
    assert "give --bundle" in capsys.readouterr().err
    with pytest.raises(StableMoError, match="density"):
        ControlProtocol("pelvis", "150%")
