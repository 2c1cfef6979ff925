"""BVH out: forward kinematics of the written file gives the joints back at any heading, for turning,
jumping, crawling and flipping motions; rotations do not depend on the heading; resampling; the
command (the SMPL pose file: test_bvh_smpl.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_generate_cli import bundle  # noqa: F401  (the generate tests' tiny random-weight bundle)

from stablemo.bench.motions import bvh_fk, crawl, flip, heading, synth_joints
from stablemo.bvh import (
    bvh_text,
    forward_kinematics,
    motion_to_animation,
    read_bvh,
    write_bvh,
)
from stablemo.bvh.names import bvh_names
from stablemo.errors import StableMoError
from stablemo.motion import features_to_joints, joints_to_features

SAMPLE = Path(__file__).resolve().parents[2] / "shared" / "data" / "humanml3d-sample"


def errors(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.linalg.norm(a - b, axis=-1)


@pytest.mark.parametrize("degrees", [0, 90, 180, 270, 137])
def test_fk_of_the_file_gives_the_joints_back_at_any_heading(tmp_path, degrees):
    joints = heading(synth_joints("walk", 1), degrees)
    fk, _ = bvh_fk(bvh_text(joints), tmp_path)
    # the only error left is the file's 6 decimals
    assert errors(fk, joints).max() < 1e-5


@pytest.mark.parametrize("motion", ["turn", "circle", "jump", "crawl", "flip"])
def test_fk_of_the_file_gives_the_joints_back_for_turning_jumping_crawling_flipping(tmp_path, motion):
    joints = {"turn": lambda: synth_joints("turn", 2, angle=360), "circle": lambda: synth_joints("circle", 3),
              "jump": lambda: synth_joints("jump", 4), "crawl": crawl, "flip": flip}[motion]()
    fk, _ = bvh_fk(bvh_text(joints), tmp_path)
    assert errors(fk, joints).max() < 1e-5
    # the generator's own (slightly non-rigid) joints: within the 1 cm mean / 3 cm max
    raw = {"turn": lambda: synth_joints("turn", 2, rigid=False, angle=360), "jump": lambda: synth_joints("jump", 4, rigid=False)}
    if motion in raw:
        loose = raw[motion]()
        err = errors(bvh_fk(bvh_text(loose), tmp_path)[0], loose)
        assert err.mean() <= 0.01 and err.max() <= 0.03
    # the body really went where the test says (the file is not trivially right)
    if motion == "flip":
        up = joints[:, 12] - joints[:, 0]
        assert up[:, 1].min() < -0.2  # head below the pelvis at some frame
    if motion == "crawl":
        assert np.abs((joints[:, 12] - joints[:, 0])[:, 1]).max() < 0.15  # the trunk stays horizontal


def test_real_clip_from_features_at_four_headings(tmp_path):
    if not SAMPLE.is_dir():
        pytest.skip("the HumanML3D sample clip is not available")
    feats = np.load(SAMPLE / "new_joint_vecs" / "012314.npy")
    joints = np.load(SAMPLE / "new_joints" / "012314.npy").astype(np.float64)
    fk, _ = bvh_fk(bvh_text(feats), tmp_path)
    assert errors(fk, joints).max() < 1e-5
    for degrees in (90, 180, 270):
        turned = heading(joints, degrees)
        fk, _ = bvh_fk(bvh_text(turned), tmp_path)
        assert errors(fk, turned).max() < 1e-5


def test_joint_rotations_do_not_depend_on_the_heading():
    joints = synth_joints("walk", 5)
    base = motion_to_animation(joints).rotations
    for degrees in (90, 180, 270):
        turned = motion_to_animation(heading(joints, degrees)).rotations
        # every joint below the root turns exactly as at heading 0 (same quaternion up to sign)
        dots = np.abs((base[:, 1:] * turned[:, 1:]).sum(-1))
        assert dots.min() > 1 - 1e-9
        assert np.abs((base[:, 0] * turned[:, 0]).sum(-1)).min() < 0.95  # the root did turn


def test_rotations_are_continuous_on_a_full_circle():
    joints = synth_joints("circle", 6)  # walks through every heading
    q = motion_to_animation(joints).rotations  # (T, J, 4)
    step = 2 * np.degrees(np.arccos(np.clip(np.abs((q[1:] * q[:-1]).sum(-1)), 0.0, 1.0)))  # (T-1, J)
    # 20 fps walking: no joint turns by more than ~30 degrees between frames; a twist flip would be ~180
    assert step.max() < 45.0
    # consecutive quaternions stay in one hemisphere (a slerp between them takes the short way)
    assert ((q[1:] * q[:-1]).sum(-1)).min() > 0


def test_joints_that_are_not_rigid_stay_within_a_centimetre(tmp_path):
    # generated motions: bone lengths vary per frame and the hip/chest triangles are not rigid
    rng = np.random.default_rng(0)
    joints = synth_joints("walk", 7)
    noisy = joints + rng.normal(0.0, 0.004, size=joints.shape)
    fk, _ = bvh_fk(bvh_text(noisy), tmp_path)
    err = errors(fk, noisy)
    assert err.mean() <= 0.01 and err.max() <= 0.03
    assert err.max() > 1e-4  # with fixed bone lengths the noise cannot be matched exactly


def test_stretch_follows_bones_that_change_length(tmp_path):
    # bones lengthen and shorten by up to 8 cm, as in the demo model's samples
    rng = np.random.default_rng(1)
    joints = heading(synth_joints("jump", 7), 180)
    wobble = 1.0 + 0.15 * np.sin(np.linspace(0, 6, len(joints)))[:, None, None] * rng.uniform(-1, 1, (1, 22, 1))
    stretched = joints[:, :1] + (joints - joints[:, :1]) * wobble
    rigid, _ = bvh_fk(bvh_text(stretched), tmp_path)
    exact, anim = bvh_fk(bvh_text(stretched, stretch=True), tmp_path)
    assert errors(rigid, stretched).max() > 0.03  # rigid bones cannot follow
    assert errors(exact, stretched).max() < 1e-5
    assert anim.positions is not None
    # same rotations as rigid bones would need where the lengths do not change
    still = bvh_fk(bvh_text(joints, stretch=True), tmp_path)[0]
    assert errors(still, joints).max() < 1e-5


def test_features_and_their_joints_give_the_same_file():
    feats = joints_to_features(synth_joints("jump", 8), "humanml3d")
    assert bvh_text(feats) == bvh_text(features_to_joints(feats.astype(np.float64), "humanml3d"))


@pytest.mark.parametrize("fps", [30, 60, 120])
def test_resampling_keeps_the_source_frames_and_the_bones(tmp_path, fps):
    joints = heading(synth_joints("turn", 9, angle=180), 180)
    fk, anim = bvh_fk(bvh_text(joints, fps=fps), tmp_path)
    assert anim.fps == pytest.approx(fps)
    step = {30: (3, 2), 60: (3, 1), 120: (6, 1)}[fps]  # (output frames, input frames) of one shared instant
    shared = np.arange(0, len(fk), step[0])
    assert errors(fk[shared], joints[shared // step[0] * step[1]]).max() < 1e-5
    assert len(fk) == (len(joints) - 1) * fps // 20 + 1
    # in-between frames: the same rigid bones, moving by no more than the source frames around them
    lengths = np.linalg.norm(np.diff(fk[:, [0, 1, 4, 7]], axis=1), axis=-1)  # pelvis-hip-knee-ankle
    assert np.ptp(lengths, axis=0).max() < 1e-5
    speed = np.linalg.norm(np.diff(fk, axis=0), axis=-1).max() * fps
    assert speed <= np.linalg.norm(np.diff(joints, axis=0), axis=-1).max() * 20 * 1.5


def kit_features() -> np.ndarray:
    """(T, 251) features of a KIT-shaped body, built from a HumanML3D motion's corresponding joints."""
    joints = synth_joints("walk", 10)
    kit_from_h3d = [0, 3, 6, 12, 15, 17, 19, 21, 16, 18, 20, 2, 5, 8, 11, 11, 1, 4, 7, 10, 10]
    kit = joints[:, kit_from_h3d] * 1000.0  # millimetres
    kit[:, [15, 20]] += np.array([0.0, 0.0, 50.0])  # toes beyond the metatarsals
    return joints_to_features(kit, "kit")


def test_kit_features(tmp_path):
    from stablemo.motion import KIT

    feats = kit_features()
    target = features_to_joints(feats.astype(np.float64), "kit") / 1000.0  # the BVH is in metres
    path = tmp_path / "kit.bvh"
    write_bvh(path, feats)
    anim = read_bvh(path)
    assert anim.fps == pytest.approx(KIT.fps)
    order = [anim.rig.names.index(n) for n in bvh_names("kit")]
    # the constructed toes are not rigid with the feet (a fixed world offset): 0.06 mm
    assert errors(forward_kinematics(anim)[:, order], target).max() < 2e-4


def test_bvh_command_writes_bvh(tmp_path, capsys):
    from stablemo.cli.bvh import main

    joints = heading(synth_joints("jump", 11), 200)
    src = tmp_path / "m.joints.npy"
    np.save(src, joints.astype(np.float32))
    assert main([str(src), "--out", str(tmp_path / "m.bvh"), "--units", "cm", "--fps", "60"]) == 0
    out = capsys.readouterr()
    assert "joints within 0.00 cm on average, 0.00 cm at most" in out.out and out.err == ""
    anim = read_bvh(tmp_path / "m.bvh")
    assert anim.fps == pytest.approx(60) and anim.num_frames == (len(joints) - 1) * 3 + 1
    order = [anim.rig.names.index(n) for n in bvh_names("humanml3d")]
    assert errors(forward_kinematics(anim)[::3, order] / 100.0, joints).max() < 1e-5


def test_bvh_command_warns_once_on_stderr_when_the_file_misses_the_motion(tmp_path, capsys):
    from stablemo.cli.bvh import main

    joints = synth_joints("jump", 11)
    grow = 1 + 0.2 * np.linspace(0, 1, len(joints))[:, None, None]  # every bone 20% longer by the end
    np.save(tmp_path / "m.npy", (joints[:, :1] + (joints - joints[:, :1]) * grow).astype(np.float32))
    assert main([str(tmp_path / "m.npy"), "--out", str(tmp_path / "m.bvh")]) == 0
    out = capsys.readouterr()
    (line,) = out.err.splitlines()
    assert line.startswith(f"warning: {tmp_path / 'm.bvh'} is up to ") and line.endswith("(see docs/bvh.md)")
    assert "--stretch follows them exactly" in line
    assert main([str(tmp_path / "m.npy"), "--out", str(tmp_path / "m.bvh"), "--stretch"]) == 0
    assert capsys.readouterr().err == ""  # stretched bones are exact


@pytest.mark.parametrize("argv, message", [
    (["{src}", "--out", "{tmp}/m.txt"], "name a .bvh or .npz file"),
    (["{tmp}/none.npy", "--out", "{tmp}/m.bvh"], "none.npy: file not found"),
    (["{bad}", "--out", "{tmp}/m.bvh"], "bad.npy: motion: shape (5, 7)"),
    (["{nan}", "--out", "{tmp}/m.bvh"], "nan.npy: motion: contains NaN"),
    (["{src}", "--out", "{tmp}/m.bvh", "--fps", "0"], "--fps: must be > 0"),
    (["{kit}", "--out", "{tmp}/m.npz"], "SMPL order needs the 22-joint HumanML3D skeleton"),
    (["{still}", "--out", "{tmp}/m.bvh"], "still.npy: joints: bone pelvis -> L_hip has zero length"),
    (["{src}", "--out", "{tmp}/m.bvh", "--up", "z"], "--up: only for an .npz"),
    (["{src}", "--out", "{tmp}/m.npz", "--up", "x"], "--up='x': choose z (AMASS, the default) or y"),
    (["{src}", "--out", "{tmp}/m.npz", "--stretch"], "--stretch: only for a .bvh"),
    (["{src}", "--out", "{tmp}/m.npz", "--units", "cm"], "--units cm: only for a .bvh"),
])
def test_bvh_command_bad_input_is_one_line(tmp_path, capsys, argv, message):
    from stablemo.cli import main

    src = tmp_path / "m.npy"
    np.save(src, synth_joints("walk", 12).astype(np.float32))
    np.save(tmp_path / "bad.npy", np.zeros((5, 7), np.float32))
    nan = synth_joints("walk", 12)
    nan[3, 4, 1] = np.nan
    np.save(tmp_path / "nan.npy", nan)
    np.save(tmp_path / "kit.npy", kit_features())
    np.save(tmp_path / "still.npy", np.zeros((30, 22, 3), np.float32))
    subs = {"still": tmp_path / "still.npy", "src": src, "tmp": tmp_path, "bad": tmp_path / "bad.npy",
            "nan": tmp_path / "nan.npy", "kit": tmp_path / "kit.npy"}
    assert main(["bvh", *[a.format(**subs) for a in argv]]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err
    assert not list(tmp_path.glob("m.bvh")) and not list(tmp_path.glob("m.npz"))


def test_write_bvh_rejects_bad_motion():
    with pytest.raises(StableMoError, match="NaN"):
        bvh_text(np.full((10, 22, 3), np.nan))
    with pytest.raises(StableMoError, match=r"shape \(10, 4\)"):
        bvh_text(np.zeros((10, 4)))


def test_generate_writes_bvh_beside_the_animation(tmp_path, bundle):  # noqa: F811  (the imported fixture)
    from stablemo.cli import generate

    out = tmp_path / "out"
    assert generate.main(["a person walks", "--frames", "16", "--steps", "2", "--bundle", str(bundle), "--out", str(out),
                          "--format", "bvh", "--format", "gif", "--format", "bvh"]) == 0
    assert sorted(p.name for p in out.iterdir()) == [
        "a-person-walks.bvh", "a-person-walks.features.npy", "a-person-walks.gif", "a-person-walks.joints.npy"]
    anim = read_bvh(out / "a-person-walks.bvh")
    assert anim.num_frames == 16 and anim.fps == pytest.approx(20.0)
    # gif stays the default, and --no-render still writes the arrays only
    assert generate.main(["a person runs", "--frames", "16", "--steps", "2", "--bundle", str(bundle), "--out", str(out),
                          "--no-render", "--format", "bvh"]) == 0
    assert not (out / "a-person-runs.bvh").exists()
