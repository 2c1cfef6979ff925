"""BVH in: malformed files are one error naming the file and line; name maps (ours, Mixamo, CMU,
YAML); `stablemo data import-bvh` builds a dataset that `data check` accepts; features -> BVH ->
import -> features round trip."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stablemo.bvh import (
    bvh_text,
    format_bvh,
    forward_kinematics,
    motion_to_animation,
    read_bvh,
)
from stablemo.bvh.names import NAME_MAPS, bvh_names
from stablemo.bvh.rig import Animation, Rig
from stablemo.errors import StableMoError
from stablemo.motion import features_to_joints, joints_to_features

SAMPLE = Path(__file__).resolve().parents[2] / "shared" / "data" / "humanml3d-sample"

SMALL = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT Spine
  {
    OFFSET 0 0.1 0
    CHANNELS 3 Zrotation Yrotation Xrotation
    End Site
    {
      OFFSET 0 0.1 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.05
0 1 0 0 0 0 0 0 0
0 1 0 0 0 90 0 0 0
"""


def walk_joints(seed: int = 0, action: str = "walk") -> np.ndarray:
    from stablemo.data.synth import actions
    from stablemo.data.synth.compose import build

    p = actions.sample_params(action, np.random.default_rng(seed))
    joints = build([(action, p)], 0.3, 0.5).joints.astype(np.float64)
    return forward_kinematics(motion_to_animation(joints))  # on rigid bones, as mocap


def test_small_file_reads_and_moves(tmp_path):
    path = tmp_path / "s.bvh"
    path.write_text(SMALL)
    anim = read_bvh(path)
    assert anim.rig.names == ("Hips", "Spine") and anim.fps == pytest.approx(20.0)
    pos = forward_kinematics(anim)  # (2, 2, 3); End Sites are not joints
    np.testing.assert_allclose(pos[0], [[0, 1, 0], [0, 1.1, 0]], atol=1e-12)
    # frame 1: the hips turn 90° about x (their last channel), which carries the spine to +z
    np.testing.assert_allclose(pos[1], [[0, 1, 0], [0, 1, 0.1]], atol=1e-12)


def _lines(text: str) -> list[str]:
    return text.splitlines()


def _edit(text: str, line: int, new: str | None) -> str:
    lines = _lines(text)
    if new is None:
        del lines[line - 1]
    else:
        lines[line - 1] = new
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("edit, where, message", [
    (lambda t: _edit(t, 20, "0 1 0 0 0 0 0 0"), 20, "8 values, the hierarchy declares 9 channels"),
    (lambda t: _edit(t, 20, None), 17, "Frames: 2 but the file has 1 frame lines"),
    (lambda t: t + "0 1 0 0 0 0 0 0 0\n", 17, "Frames: 2 but the file has 3 frame lines"),
    (lambda t: _edit(t, 20, "0 1 0 0 nan 0 0 0 0"), 20, "NaN or Inf"),
    (lambda t: _edit(t, 20, "0 1 0 0 x 0 0 0 0"), 20, "not a number"),
    (lambda t: _edit(t, 9, "    CHANNELS 3 Zrotation Yrotation"), 9, "channels ['Zrotation', 'Yrotation', 'End']"),
    (lambda t: _edit(t, 10, "    Begin Site"), 10, "expected JOINT, End Site or '}', found 'Begin'"),
    (lambda t: _edit(t, 9, "    CHANNEL 3 Zrotation Yrotation Xrotation"), 9, "expected CHANNELS"),
    (lambda t: _edit(t, 9, "    CHANNELS 3 Zrotation Wrotation Xrotation"), 9, "channels"),
    (lambda t: _edit(t, 8, "    OFFSET 0 nan 0"), 8, "not finite"),
    (lambda t: _edit(t, 18, "Frame Time: 0"), 18, "not a positive number"),
    (lambda t: _edit(t, 16, "MOTIONS"), None, "no MOTION section"),
    (lambda t: _edit(t, 15, None), 14, "file ends where the end of joint Hips was expected"),
])
def test_malformed_files_name_the_file_and_line(tmp_path, edit, where, message):
    path = tmp_path / "bad.bvh"
    path.write_text(edit(SMALL))
    with pytest.raises(StableMoError) as info:
        read_bvh(path)
    text = str(info.value)
    assert text.startswith(f"{path}:{where}: " if where else f"{path}: "), text
    assert message in text and "\n" not in text


def _renamed(anim: Animation, names: dict[str, str], extra_child_of: str | None = None) -> Animation:
    """The animation with its joints renamed, optionally with one extra joint (a finger) added."""
    rig = anim.rig
    new_names = [names.get(n, n) for n in rig.names]
    parents, offsets, rotations, ends = list(rig.parents), rig.offsets, anim.rotations, dict(rig.end_sites)
    if extra_child_of is not None:
        parent = new_names.index(extra_child_of)
        new_names.append("LeftFingerBase")
        parents.append(parent)
        offsets = np.vstack([offsets, [0.05, 0.0, 0.0]])
        rotations = np.concatenate([rotations, rotations[:, :1] * 0 + np.array([1.0, 0, 0, 0])], axis=1)
        ends[len(parents) - 1] = np.array([0.02, 0.0, 0.0])
        ends.pop(parent, None)
    return Animation(Rig(tuple(new_names), tuple(parents), offsets, ends), anim.root, rotations, anim.fps)


@pytest.mark.parametrize("style", ["mixamo", "cmu"])
def test_name_maps_find_our_joints(tmp_path, style):
    from stablemo.data.bvh_import import bvh_joints

    joints = walk_joints(1)
    anim = motion_to_animation(joints)
    if style == "mixamo":
        renamed = _renamed(anim, {n: f"mixamorig:{n}" for n in bvh_names("humanml3d")}, "mixamorig:LeftHand")
    else:
        renamed = _renamed(anim, NAME_MAPS["cmu"], "LeftHand")
    path = tmp_path / f"{style}.bvh"
    path.write_text(format_bvh(renamed))
    assert np.linalg.norm(bvh_joints(path) - joints, axis=-1).max() < 1e-5


def test_unknown_names_ask_for_a_map_and_a_yaml_map_works(tmp_path):
    from stablemo.data.bvh_import import bvh_joints
    from stablemo.bvh.names import load_name_map

    joints = walk_joints(2)
    ours = bvh_names("humanml3d")
    odd = {n: f"bone_{i:02d}" for i, n in enumerate(ours)}
    path = tmp_path / "odd.bvh"
    path.write_text(format_bvh(_renamed(motion_to_animation(joints), odd)))
    with pytest.raises(StableMoError, match=r"odd\.bvh: joint names do not match.*--map"):
        bvh_joints(path)
    yaml_path = tmp_path / "map.yaml"
    yaml_path.write_text("".join(f"{k}: {v}\n" for k, v in odd.items()))
    got = bvh_joints(path, load_name_map(yaml_path))
    assert np.linalg.norm(got - joints, axis=-1).max() < 1e-5
    yaml_path.write_text("Hips: bone_00\nElbow: x\n")
    with pytest.raises(StableMoError, match=r"map\.yaml: unknown joint name\(s\) \['Elbow'\]"):
        load_name_map(yaml_path)


def test_z_up_files_are_turned_upright(tmp_path):
    from stablemo.data.bvh_import import bvh_joints

    joints = walk_joints(3)
    zup = joints @ np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]).T  # (x, y, z) -> (x, -z, y)
    path = tmp_path / "z.bvh"
    path.write_text(bvh_text(zup))
    assert np.linalg.norm(bvh_joints(path, up="z") - joints, axis=-1).max() < 1e-5


def test_import_builds_a_dataset_that_data_check_accepts(tmp_path, capsys):
    from stablemo.cli import main
    from stablemo.data.check import check_dataset

    src = tmp_path / "mocap"
    (src / "sub").mkdir(parents=True)
    long = np.concatenate([walk_joints(4, "circle"), walk_joints(5, "circle")[1:] + [0, 0, 0]])  # > 196 frames
    motions = {"walk_forward_01.bvh": walk_joints(6), "sub/circle.bvh": long, "jump_02.bvh": walk_joints(7, "jump")}
    for name, joints in motions.items():
        (src / name).write_text(bvh_text(joints, fps=60))  # imported back at 20 fps
    texts = tmp_path / "texts.csv"
    texts.write_text("file,text\nwalk_forward_01.bvh,a person walks forward\nsub/circle.bvh,a person walks in circles\n"
                     "circle,someone circles twice\njump_02,a person jumps\n")
    out = tmp_path / "dataset"
    assert main(["data", "import-bvh", str(src), "--out", str(out), "--texts", str(texts)]) == 0
    ids = sorted(p.stem for p in (out / "new_joint_vecs").glob("*.npy"))
    assert ids == ["jump_02", "sub_circle_00", "sub_circle_01", "walk_forward_01"]
    caps = (out / "texts" / "sub_circle_01.txt").read_text().splitlines()
    assert [c.split("#")[0] for c in caps] == ["a person walks in circles", "someone circles twice"]
    assert all(len(np.load(out / "new_joint_vecs" / f"{i}.npy")) <= 196 for i in ids)
    report = check_dataset(out, "humanml3d", cache=False)
    assert report.ok, report.problems
    splits = {s: (out / f"{s}.txt").read_text().split() for s in ("train", "val", "test", "all")}
    assert sorted(splits["train"] + splits["val"] + splits["test"]) == splits["all"] == ids
    # the extraction was the project's: features of the first clip equal extracting its joints directly
    direct = joints_to_features(motions["walk_forward_01.bvh"], "humanml3d")
    np.testing.assert_allclose(np.load(out / "new_joint_vecs" / "walk_forward_01.npy"), direct, atol=2e-3)
    # a second import into the same folder is refused before anything is read
    assert main(["data", "import-bvh", str(src), "--out", str(out)]) == 2
    assert "not empty" in capsys.readouterr().err


@pytest.mark.parametrize("problem, message", [
    ("empty", "no .bvh files"),
    ("caption", "no caption for 1 file(s)"),
    ("broken", "b.bvh:20: 8 values"),
])
def test_import_errors_write_nothing(tmp_path, capsys, problem, message):
    from stablemo.cli import main

    src = tmp_path / "in"
    src.mkdir()
    if problem != "empty":
        (src / "a.bvh").write_text(bvh_text(walk_joints(8)))
        (src / "b.bvh").write_text(_edit(SMALL, 20, "0 1 0 0 0 0 0 0") if problem == "broken" else bvh_text(walk_joints(9)))
    texts = tmp_path / "t.csv"
    texts.write_text("file,text\na,a person walks\n")
    argv = ["data", "import-bvh", str(src), "--out", str(tmp_path / "out")]
    assert main(argv + (["--texts", str(texts)] if problem == "caption" else [])) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_round_trip_features_bvh_import_features(tmp_path):
    if not SAMPLE.is_dir():
        pytest.skip("the HumanML3D sample clip is not available")
    from stablemo.bvh import write_bvh
    from stablemo.data.bvh_import import import_bvh_dir

    feats = np.load(SAMPLE / "new_joint_vecs" / "012314.npy")
    reference = np.load(SAMPLE / "features_from_new_joints.npy")  # the official extraction of its joints
    (tmp_path / "in").mkdir()
    write_bvh(tmp_path / "in" / "a.bvh", feats)
    write_bvh(tmp_path / "in" / "b.bvh", feats, fps=60, units="cm")
    clips = import_bvh_dir(tmp_path / "in", tmp_path / "out")
    rot = np.zeros(263, bool)
    rot[67:193] = True  # the 6D rotations are the float-sensitive dims (sample README: ~1e-3)
    for clip in clips:
        assert clip.features.shape == reference.shape
        diff = np.abs(clip.features - reference)
        assert diff[:, ~rot].max() < 1e-4 and diff[:, rot].max() < 1e-3
    joints = np.load(tmp_path / "out" / "new_joints" / "a.npy")
    np.testing.assert_allclose(joints, features_to_joints(clips[0].features, "humanml3d"), atol=1e-6)
