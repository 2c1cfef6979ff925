"""Plausibility limits (stablemo.motion.plausible): a wrong unit, a runaway number or a hostile file is
one line before the compute, at the check where the value is defined, for every entry point."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from stablemo.cli import main
from stablemo.control import JointControl
from stablemo.errors import StableMoError
from stablemo.motion.plausible import MAX_TIMELINE_SECONDS
from stablemo.outputs.render import _View, render_animation
from stablemo.timeline.spec import parse_timeline

DEMO = Path(__file__).resolve().parents[1] / "stablemo" / "assets" / "demo_bundle"
SAMPLE = Path(__file__).resolve().parents[2] / "shared" / "data" / "humanml3d-sample"


def walk(frames: int = 60) -> np.ndarray:
    """A synthetic walk (T, 22, 3) in metres, starting at the origin."""
    from stablemo.data.synth import actions
    from stablemo.data.synth.compose import build

    p = actions.sample_params("walk", np.random.default_rng(0))
    return build([("walk", p)], 0.3, 0.5).joints.astype(np.float64)[:frames]


def pelvis_control(joints: np.ndarray, scale: float = 1.0) -> JointControl:
    mask = np.zeros(joints.shape[:2], bool)
    mask[:, 0] = True
    return JointControl(joints * scale, mask)


def write_control(path: Path, control: JointControl) -> Path:
    np.savez(path, positions=np.asarray(control.positions, np.float32), mask=control.mask)
    return path


def files_in(folder: Path) -> list[Path]:
    return sorted(p for p in folder.rglob("*")) if folder.exists() else []


# --------------------------------------------------------------------------- control targets


def test_a_real_path_passes_and_millimetres_are_named():
    joints = walk()
    targets, keep = pelvis_control(joints).resolve(len(joints), "humanml3d")
    assert keep[:, 0].all() and np.allclose(targets[:, 0], joints[:, 0], atol=1e-6)
    with pytest.raises(StableMoError, match=r"look like millimetres, and humanml3d positions are metres"):
        pelvis_control(joints, 1000.0).resolve(len(joints), "humanml3d")


def test_a_target_farther_than_a_body_can_run_is_refused():
    joints = walk()
    far = joints.copy()
    far[40:, 0, 0] += 1e6  # the pelvis teleports 1000 km away at frame 40
    with pytest.raises(StableMoError, match=r"control.positions: the target of pelvis at frame 40 .* cannot be there"):
        pelvis_control(far).resolve(len(far), "humanml3d")
    # 40 m after 2 s is faster than any sprint (15 m/s + reach): refused; 20 m is a run: followed
    fast = joints.copy()
    fast[40, 0, 2] = 40.0
    with pytest.raises(StableMoError, match="frame 40"):
        pelvis_control(fast).resolve(len(fast), "humanml3d")
    fast[40, 0, 2] = 20.0
    pelvis_control(fast).resolve(len(fast), "humanml3d")


def test_kit_targets_in_metres_are_named():
    from stablemo.motion.skeleton import KIT

    joints = np.zeros((20, KIT.num_joints, 3))
    joints[:, 0, 1] = 0.95  # a pelvis 0.95 m high, given in metres: 0.95 mm for KIT
    joints[:, 0, 2] = np.linspace(0, 1.0, 20)
    control = pelvis_control(joints)
    with pytest.raises(StableMoError, match="look like metres, and kit positions are millimetres"):
        control.resolve(20, "kit")
    pelvis_control(joints, 1000.0).resolve(20, "kit")


def test_control_cli_refuses_millimetres_and_writes_nothing(tmp_path, capsys):
    control = write_control(tmp_path / "mm.npz", pelvis_control(walk(), 1000.0))
    out = tmp_path / "out"
    rc = main(["generate", "a person walks forward", "--control", str(control), "--frames", "60",
               "--steps", "2", "--out", str(out), "--bundle", str(DEMO)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "millimetres" in err and str(control) in err
    assert files_in(out) == []


def test_a_npy_given_as_control_file_is_one_line(tmp_path, capsys):
    np.save(tmp_path / "x.npy", walk())
    rc = main(["generate", "a person walks", "--control", str(tmp_path / "x.npy"), "--frames", "40", "--steps", "1",
               "--out", str(tmp_path / "out"), "--bundle", str(DEMO)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.endswith("a joints .npy is its input, not a control file)") and "Traceback" not in err


# --------------------------------------------------------------------------- timelines


@pytest.mark.parametrize("end", ["1e9", "1e308", str(MAX_TIMELINE_SECONDS + 1)])
def test_timeline_length_is_bounded_before_anything_is_allocated(end):
    with pytest.raises(StableMoError, match=rf"t.txt:2: ends at .* s; a timeline is at most {MAX_TIMELINE_SECONDS:g} s"):
        parse_timeline(f"0 5 a person walks\n5 {end} a person jumps\n", "t.txt")
    assert parse_timeline(f"0 {MAX_TIMELINE_SECONDS:g} a person walks", "t.txt")[-1].end_s == MAX_TIMELINE_SECONDS


def test_timeline_cli_with_a_huge_end_is_one_line(tmp_path, capsys):
    spec = tmp_path / "t.txt"
    spec.write_text("0 1e9 a person walks forward\n")
    rc = main(["generate", "--timeline", str(spec), "--out", str(tmp_path / "out"), "--bundle", str(DEMO)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "at most 600 s" in err
    assert files_in(tmp_path / "out") == []


# --------------------------------------------------------------------------- rendering


def test_render_cost_is_bounded_by_the_image_not_the_extent():
    joints = walk(40)
    travelled = joints.copy()
    travelled[..., 2] *= 60.0  # a long stretched path: grid lines stay bounded
    for motion in (joints + np.array([1e6, 0.0, -3e6]), joints):
        view = _View(motion, __import__("stablemo.motion", fromlist=["HUMANML3D"]).HUMANML3D)
        assert 4 <= len(view.grid) <= 2 * 41 + 2
    # a 40-frame walk keeps the familiar 0.5 m grid
    from stablemo.outputs.render import _grid_spacing

    assert _grid_spacing(6.0, 1.0) == 0.5 and _grid_spacing(1e6, 1.0) >= 1e6 / 40 and _grid_spacing(1e6, 1.0) in (5e4, 1e5)


def test_render_far_away_motion_finishes_and_teleports_are_refused(tmp_path):
    joints = walk(30)
    out = render_animation(joints + np.array([1e6, 0.0, 1e6]), tmp_path / "far.gif")
    assert out.stat().st_size > 0
    broken = joints.copy()
    broken[15:, :, 0] += 1e6
    with pytest.raises(StableMoError, match="faster than a body moves"):
        render_animation(broken, tmp_path / "broken.gif")
    with pytest.raises(StableMoError, match=r"spans 1\.\d+e\+03 m read as metres"):
        render_animation(joints * 1000.0, tmp_path / "mm.gif")
    assert not (tmp_path / "broken.gif").exists() and not (tmp_path / "mm.gif").exists()


@pytest.mark.parametrize("fps, shown", [("0", "0 fps"), ("1e-9", "1e-09 fps"), ("nan", "nan fps"), ("1e6", "1e+06 fps")])
def test_render_fps_out_of_range_is_one_line(tmp_path, capsys, fps, shown):
    np.save(tmp_path / "w.npy", walk(20))
    rc = main(["render", str(tmp_path / "w.npy"), "--out", str(tmp_path / "w.gif"), "--fps", fps])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err == f"stablemo render: error: --fps: {shown} is outside 1-1000 fps"
    assert not (tmp_path / "w.gif").exists()


def test_one_frame_features_render_and_write_bvh(tmp_path, capsys):
    from stablemo.motion import joints_to_features

    feats = joints_to_features(walk(10), "humanml3d")[:1]
    np.save(tmp_path / "one.npy", feats)
    assert main(["render", str(tmp_path / "one.npy"), "--out", str(tmp_path / "one.gif")]) == 0
    assert main(["bvh", str(tmp_path / "one.npy"), "--out", str(tmp_path / "one.bvh")]) == 0
    assert (tmp_path / "one.gif").stat().st_size > 0 and "Frames: 1" in (tmp_path / "one.bvh").read_text()


# --------------------------------------------------------------------------- bundles and BVH files


def copy_demo(tmp_path: Path) -> Path:
    bundle = tmp_path / "bundle"
    shutil.copytree(DEMO, bundle)
    return bundle


@pytest.mark.parametrize("key", ["mean", "std"])
def test_a_bundle_with_huge_statistics_is_refused(tmp_path, capsys, key):
    bundle = copy_demo(tmp_path)
    config = json.loads((bundle / "config.json").read_text())
    config[key][0] = 1e30
    (bundle / "config.json").write_text(json.dumps(config))
    rc = main(["generate", "a person walks", "--bundle", str(bundle), "--frames", "40", "--steps", "1",
               "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and f"config.json: '{key}': 1 value(s) with |x| > 10000" in err
    assert files_in(tmp_path / "out") == []


def test_a_bundle_config_that_is_a_list_is_one_line(tmp_path, capsys):
    bundle = copy_demo(tmp_path)
    (bundle / "config.json").write_text("[1, 2, 3]")
    rc = main(["generate", "a person walks", "--bundle", str(bundle), "--frames", "40", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.endswith("config.json: not a StableMo bundle (a JSON list, not an object)")


def bvh_chain(joints: int) -> str:
    """A flat hierarchy of `joints` joints (the root and its children), one frame."""
    lines = ["HIERARCHY", "ROOT Hips", "{", "OFFSET 0 0 0", "CHANNELS 3 Xposition Yposition Zposition"]
    for j in range(joints - 1):
        lines += [f"JOINT J{j}", "{", "OFFSET 0 0.1 0", "CHANNELS 0", "End Site", "{", "OFFSET 0 0.1 0", "}", "}"]
    lines += ["}", "MOTION", "Frames: 1", "Frame Time: 0.05", "0 1 0"]
    return "\n".join(lines) + "\n"


def test_bvh_with_too_many_joints_is_refused_fast(tmp_path):
    from stablemo.bvh import read_bvh
    from stablemo.motion.plausible import MAX_BVH_JOINTS

    path = tmp_path / "big.bvh"
    path.write_text(bvh_chain(200_000))  # took 69 s (10^5 joints) to fail before, and hung at 10^6
    with pytest.raises(StableMoError, match=f"declares 200000 joints; at most {MAX_BVH_JOINTS}"):
        read_bvh(path)
    path.write_text(bvh_chain(300))
    assert read_bvh(path).rig.num_joints == 300


@pytest.mark.parametrize("frame_time, fps", [("1e300", "1e-300"), ("1e-9", "1e+09")])
def test_bvh_frame_time_out_of_range(tmp_path, capsys, frame_time, fps):
    src = tmp_path / "mocap"
    src.mkdir()
    (src / "a.bvh").write_text(bvh_chain(3).replace("Frame Time: 0.05", f"Frame Time: {frame_time}"))
    rc = main(["data", "import-bvh", str(src), "--out", str(tmp_path / "data")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and f"a.bvh:27: Frame Time {frame_time} s: {fps} fps is outside 1-1000 fps" in err
    assert not (tmp_path / "data").exists()


def test_target_pace_is_the_travel_the_targets_ask_of_the_body():
    from stablemo.motion.plausible import target_pace
    from stablemo.motion.skeleton import get_skeleton

    # a pelvis path at 2 m/s along +x (frames 0..20 at 20 fps), and a pause of 1 s then 1 m more
    frames = np.array([0, 20, 40])
    pts = np.array([[0, 0.9, 0], [2, 0.9, 0], [3, 0.9, 0]], float)
    assert target_pace(frames, np.zeros(3), pts, "humanml3d") == pytest.approx(2.0)
    # a wrist target within reach of the pelvis asks for no travel; 3 m farther in 1 s asks 3 m/s
    assert target_pace(np.array([20]), np.array([21]), np.array([[0.5, 1.2, 0.2]]), "humanml3d") == 0.0
    reach = target_pace(np.array([20]), np.array([21]), np.array([[4.0, 1.2, 0.0]]), "humanml3d")
    far = target_pace(np.array([20]), np.array([21]), np.array([[7.0, 1.2, 0.0]]), "humanml3d")
    assert far - reach == pytest.approx(3.0) and 0.0 < reach < 4.0
    # KIT millimetres are read as such
    assert target_pace(frames, np.zeros(3), pts * 1000, "kit") == pytest.approx(2.0 * get_skeleton("kit").fps / 20)  # 20 frames at 12.5 fps
