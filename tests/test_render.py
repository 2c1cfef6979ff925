"""Rendering: GIF/strip/contact sheet files, camera orientation, CLI auto-detection and errors."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from stablemo.cli import main as cli_main
from stablemo.errors import StableMoError
from stablemo.motion import HUMANML3D, KIT, joints_to_features
from stablemo.motion.quaternion import qrot_np
from stablemo.cli import render as render_cli
from stablemo.outputs import render


def walk(num_frames: int = 24, skeleton=HUMANML3D) -> np.ndarray:
    """Rest pose (target offsets) walking forward along +z while turning, legs swinging."""
    unit = 1000.0 if skeleton.units == "mm" else 1.0
    rest = np.zeros((skeleton.num_joints, 3))
    for chain in skeleton.kinematic_chains:
        for parent, child in zip(chain[:-1], chain[1:]):
            rest[child] = rest[parent] + skeleton.target_offsets[child]
    rest[:, 1] -= rest[:, 1].min()
    t = np.arange(num_frames) / skeleton.fps
    joints = np.repeat(rest[None], num_frames, axis=0)
    for side, sign in ((skeleton.feet_left, 1.0), (skeleton.feet_right, -1.0)):
        joints[:, list(side), 2] += sign * 0.15 * unit * np.sin(2 * np.pi * t)[:, None]
    heading = 0.3 * t
    quat = np.stack([np.cos(heading / 2), 0 * t, np.sin(heading / 2), 0 * t], -1)
    joints = qrot_np(np.broadcast_to(quat[:, None], joints.shape[:-1] + (4,)), joints)
    joints[:, :, 2] += 1.2 * unit * t[:, None]
    return joints


def _colours_present(img: Image.Image) -> tuple[bool, bool]:
    rgb = np.asarray(img.convert("RGB")).astype(int)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    reddish = ((r > 150) & (g < 100) & (b < 100)).sum() > 20
    bluish = ((b > 150) & (r < 100)).sum() > 20
    return reddish, bluish


def test_camera_is_y_up_and_sees_the_front():
    right, up, back = render._camera()
    assert up[1] > 0.9  # world up is screen up
    assert back[2] > 0.5  # the viewer is on the +z side, where the body faces at frame 0
    view = render._View(walk(4), HUMANML3D)
    head, foot = view.project(np.array([[0.0, 1.7, 0.0], [0.0, 0.0, 0.0]]))
    assert head[1] > foot[1]


def test_gif_animation(tmp_path):
    joints = walk(24)
    out = render.render_animation(joints, tmp_path / "walk.gif", HUMANML3D, title="walk")
    with Image.open(out) as gif:
        assert gif.format == "GIF" and gif.n_frames == 24
        assert gif.info["duration"] == 50  # 20 fps
        gif.seek(12)
        red, blue = _colours_present(gif)
        assert red and blue  # right and left limbs in their own colours
        frame12 = np.asarray(gif.convert("RGB")).copy()
        gif.seek(0)
        assert not np.array_equal(np.asarray(gif.convert("RGB")), frame12)  # it moves
    assert [p.name for p in tmp_path.iterdir()] == ["walk.gif"]  # no temporary left behind


def test_strip_and_contact_sheet(tmp_path):
    joints = walk(30)
    s4 = render.render_strip(joints, tmp_path / "s4.png", HUMANML3D, num_frames=4)
    s8 = render.render_strip(joints, tmp_path / "s8.png", HUMANML3D, num_frames=8, title="eight")
    with Image.open(s4) as a, Image.open(s8) as b:
        assert a.format == "PNG" and b.width > 1.8 * a.width
        assert all(_colours_present(b))
    sheet = render.render_contact_sheet([joints, joints[:20], joints[::-1]],
                                        ["a walk", "a shorter walk", "backwards"], tmp_path / "sheet.png",
                                        HUMANML3D, frames_per_row=5)
    one = render.render_contact_sheet([joints], ["a walk"], tmp_path / "one.png", HUMANML3D, frames_per_row=5)
    with Image.open(sheet) as grid, Image.open(one) as single:
        assert grid.width == single.width and grid.height > 2.5 * single.height
    with pytest.raises(StableMoError, match="titles"):
        render.render_contact_sheet([joints], ["a", "b"], tmp_path / "x.png", HUMANML3D)


def test_kit_renders(tmp_path):
    out = render.render_animation(walk(10, KIT), tmp_path / "kit.gif", KIT)
    with Image.open(out) as gif:
        assert gif.n_frames == 10 and gif.info["duration"] == 80  # 12.5 fps


def test_mp4_needs_ffmpeg(tmp_path):
    joints = walk(8)
    if shutil.which("ffmpeg") is None:
        with pytest.raises(StableMoError, match="ffmpeg"):
            render.render_animation(joints, tmp_path / "a.mp4", HUMANML3D)
        assert not (tmp_path / "a.mp4").exists()
    else:  # through matplotlib's FFMpegWriter: every frame, at the motion's rate, H.264 in yuv420p
        out = render.render_animation(joints, tmp_path / "a.mp4", HUMANML3D, title="a title makes an odd height")
        assert out.stat().st_size > 1000 and sorted(p.name for p in tmp_path.iterdir()) == ["a.mp4"]
        if shutil.which("ffprobe"):
            import subprocess

            probe = subprocess.run(["ffprobe", "-v", "error", "-count_frames", "-show_entries",
                                    "stream=nb_read_frames,r_frame_rate,codec_name,pix_fmt", "-of", "default=nw=1",
                                    str(out)], capture_output=True, text=True, check=True).stdout
            assert "nb_read_frames=8" in probe and "r_frame_rate=20/1" in probe
            assert "codec_name=h264" in probe and "pix_fmt=yuv420p" in probe


def test_bad_inputs_leave_no_file(tmp_path):
    joints = walk(8)
    bad = joints.copy()
    bad[3, 2, 0] = np.nan
    with pytest.raises(StableMoError, match="NaN"):
        render.render_animation(bad, tmp_path / "a.gif", HUMANML3D)
    with pytest.raises(StableMoError, match=r"\(T, 22, 3\)"):
        render.render_animation(joints[:, :21], tmp_path / "a.gif", HUMANML3D)
    with pytest.raises(StableMoError, match="format"):
        render.render_animation(joints, tmp_path / "a.avi", HUMANML3D)
    assert list(tmp_path.iterdir()) == []


def test_cli_features_and_joints(tmp_path, capsys):
    joints = walk(20)
    np.save(tmp_path / "joints.npy", joints.astype(np.float32))
    np.save(tmp_path / "feats.npy", joints_to_features(joints, HUMANML3D))
    assert render_cli.main([str(tmp_path / "joints.npy"), "--out", str(tmp_path / "j.gif"), "--frames"]) == 0
    assert (tmp_path / "j.gif").exists() and (tmp_path / "j_frames.png").exists()
    assert cli_main(["render", str(tmp_path / "feats.npy"), "--out", str(tmp_path / "f.gif"), "--fps", "10"]) == 0
    with Image.open(tmp_path / "f.gif") as gif:
        assert gif.n_frames == 19 and gif.info["duration"] == 100  # features have T-1 frames
    # KIT is detected from the width
    kit = walk(12, KIT)
    np.save(tmp_path / "kit.npy", joints_to_features(kit, KIT))
    assert render_cli.main([str(tmp_path / "kit.npy"), "--out", str(tmp_path / "k.gif")]) == 0
    assert "skeleton kit" in capsys.readouterr().out
    # a batch needs --index
    np.save(tmp_path / "batch.npy", np.stack([joints_to_features(joints, HUMANML3D)] * 3))
    with pytest.raises(StableMoError, match="--index"):
        render_cli.main([str(tmp_path / "batch.npy"), "--out", str(tmp_path / "b.gif")])
    with pytest.raises(StableMoError, match="out of range"):
        render_cli.main([str(tmp_path / "batch.npy"), "--index", "3", "--out", str(tmp_path / "b.gif")])
    assert render_cli.main([str(tmp_path / "batch.npy"), "--index", "1", "--out", str(tmp_path / "b.gif")]) == 0


def test_cli_errors(tmp_path, capsys):
    np.save(tmp_path / "wrong.npy", np.zeros((10, 100), np.float32))
    with pytest.raises(StableMoError, match="wrong.npy"):
        render_cli.main([str(tmp_path / "wrong.npy"), "--out", str(tmp_path / "w.gif")])
    with pytest.raises(StableMoError, match="not found"):
        render_cli.main([str(tmp_path / "missing.npy"), "--out", str(tmp_path / "m.gif")])
    np.save(tmp_path / "j.npy", walk(5).astype(np.float32))
    with pytest.raises(StableMoError, match="kit"):
        render_cli.main([str(tmp_path / "j.npy"), "--skeleton", "kit", "--out", str(tmp_path / "k.gif")])
    (tmp_path / "junk.npy").write_text("not numpy")
    assert cli_main(["render", str(tmp_path / "junk.npy"), "--out", str(tmp_path / "x.gif")]) == 2
    assert "junk.npy" in capsys.readouterr().err
    assert not any(p.suffix == ".gif" for p in tmp_path.iterdir())


@pytest.mark.skipif(not (Path(__file__).resolve().parents[2] / "shared/data/humanml3d-sample").exists(), reason="sample absent")
def test_real_clip_feet_on_floor(tmp_path):
    sample = Path(__file__).resolve().parents[2] / "shared/data/humanml3d-sample"
    joints, skel = render.load_motion(sample / "new_joint_vecs/012314.npy")
    assert skel is HUMANML3D and joints.shape == (170, 22, 3)
    assert abs(joints[..., 1].min()) < 1e-3  # floor at y = 0
    out = render.render_strip(joints, tmp_path / "clip.png", skel, num_frames=4)
    assert out.exists()
