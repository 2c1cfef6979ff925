"""`stablemo generate`: outputs per prompt, and one clear error for each kind of bad input."""

import numpy as np
import pytest
from conftest import make_tiny_bundle

from stablemo import cli
from stablemo.cli import generate
from stablemo.errors import StableMoError
from stablemo.inference import bundle as bundle_module
from stablemo.outputs import files as outputs_files

D = 263


@pytest.fixture(scope="module")
def bundle(tmp_path_factory):
    return make_tiny_bundle(tmp_path_factory.mktemp("gen") / "bundle")


def test_writes_features_joints_and_animation_per_prompt(bundle, tmp_path, capsys):
    prompts = tmp_path / "prompts.txt"
    prompts.write_text("# a comment\na person jumps\n\na person jumps\n")
    out = tmp_path / "out"
    rc = generate.main(["a person walks forward and waves", "--prompts", str(prompts), "--frames", "12",
                        "--steps", "2", "--bundle", str(bundle), "--out", str(out), "--seed", "3"])
    assert rc == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted([
        "a-person-walks-forward-and-waves.features.npy", "a-person-walks-forward-and-waves.joints.npy",
        "a-person-walks-forward-and-waves.gif",
        "a-person-jumps.features.npy", "a-person-jumps.joints.npy", "a-person-jumps.gif",
        "a-person-jumps-2.features.npy", "a-person-jumps-2.joints.npy", "a-person-jumps-2.gif",
    ])  # no temporary files left behind
    feats = np.load(out / "a-person-jumps.features.npy")
    joints = np.load(out / "a-person-jumps.joints.npy")
    assert feats.shape == (12, D) and feats.dtype == np.float32 and joints.shape == (12, 22, 3)
    # same prompt, different seed (seed + i) -> a different motion
    assert not np.allclose(feats, np.load(out / "a-person-jumps-2.features.npy"))
    assert "12 frames" in capsys.readouterr().out


def test_seed_reproducible_and_seconds_flag(bundle, tmp_path):
    args = ["a person runs", "--seconds", "0.8", "--steps", "2", "--bundle", str(bundle), "--no-render"]
    generate.main(args + ["--out", str(tmp_path / "a")])
    generate.main(args + ["--out", str(tmp_path / "b")])
    a = np.load(tmp_path / "a" / "a-person-runs.features.npy")
    assert a.shape == (16, D)  # 0.8 s at 20 fps
    assert np.array_equal(a, np.load(tmp_path / "b" / "a-person-runs.features.npy"))
    assert not (tmp_path / "a" / "a-person-runs.gif").exists()


@pytest.mark.parametrize(
    "argv, message",
    [
        (["   "], "prompt 1: empty prompt"),
        ([], "give a text prompt or --prompts FILE"),
        (["walk", "--frames", "100"], r"--frames 100: 100 frames is outside this model's range \[8, 40\]"),
        (["walk", "--seconds", "0.2"], r"--seconds 0.2: 4 frames is outside"),
        (["walk", "--seconds", "-1"], "--seconds: must be > 0"),
        (["walk", "--steps", "0"], "--steps: must be >= 1"),
        (["walk", "--prompts", "/nonexistent/prompts.txt"], "prompts file not found"),
        (["walk", "--sampler", "euler", "--frames", "16"], "sampler: unknown 'euler'"),
        (["walk", "--raw", "--timeline", "/nonexistent/t.txt"], "--raw: not with --timeline"),
    ],
)
def test_bad_input_errors(bundle, tmp_path, argv, message):
    with pytest.raises(StableMoError, match=message):
        generate.main(argv + ["--bundle", str(bundle), "--out", str(tmp_path)])
    assert not any(tmp_path.iterdir())  # nothing written


def test_missing_bundles(tmp_path, monkeypatch, capsys):
    with pytest.raises(StableMoError, match="--bundle: .*nope: bundle folder not found"):
        generate.main(["walk", "--bundle", str(tmp_path / "nope")])
    monkeypatch.setattr(bundle_module, "DEMO_BUNDLE", tmp_path / "demo_bundle")
    with pytest.raises(StableMoError, match=r"packaged demo model is missing .*demo_bundle.*stablemo export"):
        generate.main(["walk"])
    # through the console entry point: one line on stderr, exit code 2
    assert cli.main(["generate", "walk", "--bundle", str(tmp_path / "nope")]) == 2
    assert "stablemo generate: error:" in capsys.readouterr().err


def test_slugs_are_safe_and_unique():
    assert outputs_files.slugify("A person: walks / forward!!") == "a-person-walks-forward"
    assert outputs_files.slugify("???") == "motion"
    assert outputs_files.unique_slugs(["Jump", "jump", "JUMP"]) == ["jump", "jump-2", "jump-3"]


def test_footskate_flag_cleans_inside_denoising(bundle, tmp_path):
    base = ["a person walks", "--frames", "24", "--steps", "3", "--bundle", str(bundle), "--no-render", "--seed", "1"]
    generate.main(base + ["--out", str(tmp_path / "plain")])
    generate.main(base + ["--out", str(tmp_path / "clean"), "--footskate"])
    plain = np.load(tmp_path / "plain" / "a-person-walks.features.npy")
    clean = np.load(tmp_path / "clean" / "a-person-walks.features.npy")
    assert clean.shape == plain.shape == (24, D) and np.isfinite(clean).all()
    assert not np.allclose(clean, plain)  # the hook ran and changed the motion
    # consistent features: contact bits are re-derived, so they are exactly 0 or 1
    assert set(np.unique(clean[:, 259:263])) <= {0.0, 1.0}


def test_run_script_turns_bad_input_into_one_line_and_exit_2(capsys):
    from stablemo.errors import StableMoError, run_script

    def bad(argv):
        raise StableMoError(f"{argv[0]}: bundle folder not found")

    assert run_script(bad, "script.py", ["/nope"]) == 2
    assert capsys.readouterr().err.strip() == "script.py: error: /nope: bundle folder not found"
    assert run_script(lambda argv: {"report": 1}, "script.py") == 0   # a report dict is success
    assert run_script(lambda argv: 3, "script.py") == 3


def test_raw_writes_the_networks_own_output_and_the_default_the_rigid_body(bundle, tmp_path):
    """Without --raw every written motion keeps its bones' lengths and stands on the floor; --raw
    writes what the (here untrained) network made, whose bones change length."""
    import torch

    from stablemo.motion.rigid import bone_lengths_of
    from stablemo.motion.skeleton import HUMANML3D

    def spread(path):
        lengths = bone_lengths_of(torch.from_numpy(np.load(path)), "humanml3d").numpy()[:, 1:]
        return np.ptp(lengths, axis=0).max()

    args = ["a person walks", "--frames", "24", "--steps", "2", "--bundle", str(bundle), "--no-render"]
    assert generate.main(args + ["--out", str(tmp_path / "done")]) == 0
    assert generate.main(args + ["--raw", "--out", str(tmp_path / "raw")]) == 0
    done, raw = (tmp_path / d / "a-person-walks.joints.npy" for d in ("done", "raw"))
    assert spread(done) < 1e-5 and spread(raw) > 1e-3
    for path, far in ((done, False), (raw, True)):  # on the bundle's body, or not
        lengths = bone_lengths_of(torch.from_numpy(np.load(path)), "humanml3d").numpy()[0]
        assert (np.abs(lengths - HUMANML3D.bone_lengths).max() > 0.01) == far
    assert np.load(done)[..., 1].min() > -1e-3  # nothing below the floor
