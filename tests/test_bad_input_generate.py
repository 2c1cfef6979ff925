"""Issue #18 for generation: numbers checked before the compute, no non-finite motion ever written,
one line (exit 2) for every bad argument through the real console entry point."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch
from safetensors.torch import load_file, save_file

from stablemo import cli
from stablemo.errors import StableMoError
from stablemo.inference.bundle import DEMO_BUNDLE as DEFAULT_BUNDLE

FAST = ["--frames", "40", "--steps", "1", "--no-render"]


def run_cli(capsys, argv) -> tuple[int, str]:
    rc = cli.main(argv)
    err = capsys.readouterr().err.strip()
    return rc, err


def assert_one_line(rc: int, err: str, *needles: str) -> None:
    assert rc == 2
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in err, err


@pytest.fixture
def no_model(monkeypatch):
    """Fail the test if a bundle is loaded: the argument must be refused before any compute."""
    from stablemo.inference.pipeline import Pipeline

    def refuse(*args, **kwargs):
        raise AssertionError("the model was loaded before the bad argument was refused")

    monkeypatch.setattr(Pipeline, "from_bundle", classmethod(refuse))


@pytest.mark.parametrize("flag, value, message", [
    ("--cfg", "nan", "--cfg: must be a finite number"),
    ("--cfg", "inf", "--cfg: must be a finite number"),
    ("--cfg", "-1", "--cfg: must be >= 0"),
    ("--seconds", "nan", "--seconds: must be a finite number"),
    ("--seconds", "inf", "--seconds: must be a finite number"),
    ("--seed", "99999999999999999999", "--seed: must be in [0, 9223372036854775807]"),
    ("--seed", "-1", "--seed: must be in [0,"),
])
def test_generate_refuses_non_finite_numbers_before_loading(capsys, tmp_path, no_model, flag, value, message):
    argv = ["generate", "a person walks", flag, value, "--no-render", "--out", str(tmp_path / "o")]
    assert_one_line(*run_cli(capsys, argv), message)
    assert not (tmp_path / "o").exists()


def test_python_api_refuses_non_finite_and_out_of_range_settings():
    from stablemo.inference.pipeline import Pipeline

    pipe = Pipeline.from_bundle(DEFAULT_BUNDLE)
    for kwargs, message in [(dict(cfg=float("nan")), "cfg: must be a finite number"),
                            (dict(cfg=float("inf")), "cfg: must be a finite number"),
                            (dict(steps=0), "steps: must be >= 1"),
                            (dict(steps=2.5), "steps: expected a whole number"),
                            (dict(batch_size=0), "batch_size: must be >= 1"),
                            (dict(sampler="ddpm", steps=2000), "steps"),
                            (dict(seed=2**63 - 1), r"seed: must be in \[0, 9223372036854775806\]"),  # 2 prompts: seed + 1 overflows
                            (dict(seed=[0, -5]), r"seed\[1\]: must be in")]:
        with pytest.raises(StableMoError, match=message):
            pipe.generate(["a person walks", "a person runs"], [40, 40], **kwargs)
    with pytest.raises(StableMoError, match=r"hooks\[0\]: function is not a sample hook"):
        pipe.generate(["a person walks"], [40], hooks=[lambda state: None])
    with pytest.raises(StableMoError, match=r"lengths\[0\]: expected a whole number"):
        pipe.generate(["a person walks"], [40.5])


def test_a_non_finite_result_is_an_error_naming_the_prompt():
    """A hook (or diverged weights) that produces NaN: an error, never a returned motion."""
    from stablemo.diffusion.hooks import AtSteps
    from stablemo.inference.pipeline import Pipeline

    class Poison(AtSteps):
        def __call__(self, state):
            x0 = state.x0.clone()
            x0[1] = float("nan")
            return x0

    pipe = Pipeline.from_bundle(DEFAULT_BUNDLE)
    with pytest.raises(StableMoError, match=r"prompt 2 \('a person jumps'\): the model produced non-finite values"):
        pipe.generate(["a person walks", "a person jumps"], [40, 40], steps=2, hooks=[Poison([-1])])


def _copy_bundle(tmp_path, edit_weights=None, edit_config=None):
    bundle = tmp_path / "bundle"
    shutil.copytree(DEFAULT_BUNDLE, bundle)
    if edit_weights:
        weights = load_file(str(bundle / "model.safetensors"))
        edit_weights(weights)
        save_file(weights, str(bundle / "model.safetensors"))
    if edit_config:
        config = json.loads((bundle / "config.json").read_text())
        edit_config(config)
        (bundle / "config.json").write_text(json.dumps(config))
    return bundle


def test_bundle_with_nan_weights_is_refused_at_load_and_nothing_is_written(capsys, tmp_path):
    def poison(weights):
        name = next(k for k, v in weights.items() if v.is_floating_point())
        weights[name] = torch.full_like(weights[name], float("nan"))

    bundle = _copy_bundle(tmp_path, edit_weights=poison)
    out = tmp_path / "o"
    assert_one_line(*run_cli(capsys, ["generate", "walk", "--bundle", str(bundle), "--out", str(out)] + FAST),
                    "model.safetensors", "NaN/Inf")
    assert not out.exists() or not any(out.iterdir())


def test_bundle_mean_std_errors_name_config_json(capsys, tmp_path):
    bundle = _copy_bundle(tmp_path, edit_config=lambda c: c.update(mean=c["mean"][:100]))
    assert_one_line(*run_cli(capsys, ["generate", "walk", "--bundle", str(bundle), "--out", str(tmp_path / "o")] + FAST),
                    "config.json", "'mean' has 100 values", "263")
    bundle2 = _copy_bundle(tmp_path / "b2", edit_config=lambda c: c.update(std=[0.0] * len(c["std"])))
    assert_one_line(*run_cli(capsys, ["generate", "walk", "--bundle", str(bundle2), "--out", str(tmp_path / "o")] + FAST),
                    "config.json", "'std' holds values <= 0")


def test_prompts_file_with_non_utf8_bytes(capsys, tmp_path, no_model):
    prompts = tmp_path / "prompts.txt"
    prompts.write_bytes(b"a person walks\n\xff\xfe jumps\n")
    assert_one_line(*run_cli(capsys, ["generate", "--prompts", str(prompts), "--out", str(tmp_path / "o")]),
                    "prompts.txt", "not UTF-8")


@pytest.mark.skipif(torch.cuda.is_available(), reason="needs a torch build without CUDA")
def test_device_that_this_torch_build_lacks(capsys, tmp_path):
    assert_one_line(*run_cli(capsys, ["generate", "walk", "--device", "cuda", "--out", str(tmp_path / "o")] + FAST),
                    "device: cuda is not available", "available: cpu")
    assert_one_line(*run_cli(capsys, ["generate", "walk", "--device", "tpu9", "--out", str(tmp_path / "o")] + FAST),
                    "device: unknown device 'tpu9'")


def test_out_problems_are_found_before_the_model_loads(capsys, tmp_path, no_model):
    regular = tmp_path / "file.txt"
    regular.write_text("x")
    assert_one_line(*run_cli(capsys, ["generate", "walk", "--out", str(regular / "sub")]), "--out")
    assert_one_line(*run_cli(capsys, ["generate", "walk", "--out", str(regular)]), "--out")
    # an existing folder where one of the output files should go
    out = tmp_path / "o"
    (out / "walk.joints.npy").mkdir(parents=True)
    assert_one_line(*run_cli(capsys, ["generate", "walk", "--out", str(out)]), "--out", "walk.joints.npy")
    assert regular.read_text() == "x"


def test_evaluate_and_bench_refuse_non_finite_numbers_before_loading(capsys, tmp_path, no_model):
    assert_one_line(*run_cli(capsys, ["evaluate", "--bundle", str(DEFAULT_BUNDLE), "--data", str(tmp_path),
                                      "--evaluator", str(tmp_path), "--cfg", "nan"]), "--cfg: must be a finite number")
    assert_one_line(*run_cli(capsys, ["evaluate", "--data", str(tmp_path), "--evaluator", str(tmp_path),
                                      "--replications", "0"]), "--replications: must be >= 1")
    assert_one_line(*run_cli(capsys, ["bench", "aits", "--cfg", "inf"]), "--cfg: must be a finite number")
    assert_one_line(*run_cli(capsys, ["bench", "aits", "--steps", "0"]), "--steps: must be >= 1")


def test_demo_generation_never_builds_the_compiled_kernels(monkeypatch, tmp_path):
    """#19 item 7: the 1.6 M-parameter demo has no layer wide enough for the kernels; its first
    convolution reads the 263 features but writes 32 channels and once triggered a 30 s build."""
    from stablemo.fast import kernels

    def no_build():
        raise AssertionError("the demo asked for the compiled kernels")

    monkeypatch.setattr(kernels, "kernels", no_build)
    assert cli.main(["generate", "a person jumps", "--out", str(tmp_path)] + FAST) == 0
    assert np.isfinite(np.load(tmp_path / "a-person-jumps.features.npy")).all()


def test_generate_out_on_a_read_only_file_system(tmp_path):
    from test_bad_input_writes import _read_only_run

    ro = tmp_path / "ro"
    proc = _read_only_run(ro, "generate", "a person walks", "--out", str(ro / "o"), "--steps", "1", "--no-render")
    assert proc.returncode == 2, proc.stderr
    assert_one_line(2, proc.stderr.strip(), "--out", str(ro / "o"))


def test_export_of_a_pickled_checkpoint_is_one_line(capsys, tmp_path):
    """torch's weights_only refusal spans many lines and advises weights_only=False: the CLI keeps
    one line with the reason, for every command."""
    import collections

    evil = tmp_path / "evil.ckpt"
    torch.save({"state_dict": collections.OrderedDict(), "x": collections.Counter("ab")}, evil)
    rc, err = run_cli(capsys, ["export", str(evil), "--out", str(tmp_path / "b")])
    assert_one_line(rc, err, "evil.ckpt")
    assert "weights_only=False" not in err and "\x1b[" not in err
