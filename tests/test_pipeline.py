"""Pipeline: exact per-sample batching, seeds, parallel CFG, precision, hooks, text caching, bundles."""

import numpy as np
import pytest
import torch
from torch import nn

from stablemo.bench.aits import baseline_denoiser
from stablemo.diffusion.guidance import CFGDenoiser
from stablemo.diffusion.hooks import AtSteps
from stablemo.diffusion.schedule import NoiseSchedule
from stablemo.errors import StableMoError
from stablemo.inference.config import InferenceConfig
from stablemo.inference.pipeline import Pipeline

D = 263  # HumanML3D features, so joints can be recovered


class FakeModel(nn.Module):
    """A small padding-invariant text-conditioned network with the MotionDiffusionModel interface."""

    length_multiple = 4

    def __init__(self, hidden: int = 16, text_dim: int = 8):
        super().__init__()
        torch.manual_seed(0)
        self.embed = nn.Embedding(128, text_dim)
        self.inp = nn.Linear(D, hidden)
        self.time = nn.Linear(1, hidden)
        self.txt = nn.Linear(text_dim, hidden)
        self.conv = nn.Conv1d(hidden, hidden, 3, padding=1)
        self.out = nn.Linear(hidden, D)
        self.encode_calls: list[list[str]] = []
        self.forward_batches: list[int] = []
        self.seen_dtype = None

    def encode_text(self, texts):
        self.encode_calls.append(list(texts))
        L = max(1, max(len(s) for s in texts))
        tokens = torch.zeros(len(texts), L, dtype=torch.long)
        mask = torch.zeros(len(texts), L, dtype=torch.bool)
        for i, s in enumerate(texts):
            tokens[i, : len(s)] = torch.tensor([ord(c) % 128 for c in s], dtype=torch.long)
            mask[i, : len(s)] = True
        return self.embed(tokens) * mask[..., None], mask

    def prepare(self, text, text_mask, motion_mask, time_cond=None, timesteps=()):
        return (text, text_mask, motion_mask)

    def denoise(self, x, t, ctx):
        return self(x, t, *ctx)

    def forward(self, x, t, text, text_mask, motion_mask):
        self.forward_batches.append(x.shape[0])
        m = motion_mask[..., None]
        pooled = (text * text_mask[..., None]).sum(1) / text_mask.sum(1, keepdim=True).clamp(min=1)
        h = self.inp(x)
        self.seen_dtype = h.dtype
        h = h + (self.time(t[:, None].float() / 1000) + self.txt(pooled))[:, None]
        h = torch.where(m, torch.tanh(h), torch.zeros((), dtype=h.dtype))
        h = self.conv(h.transpose(1, 2)).transpose(1, 2)
        h = torch.where(m, h, torch.zeros((), dtype=h.dtype))
        return torch.where(m, self.out(torch.tanh(h)), torch.zeros((), dtype=h.dtype))


def make_pipeline(**kw):
    rng = np.random.default_rng(0)
    return Pipeline(FakeModel(), NoiseSchedule(), mean=rng.normal(size=D) * 0.1, std=rng.uniform(0.5, 1.5, size=D),
                    inference=InferenceConfig(min_length=4, max_length=64), device="cpu", **kw)


PROMPTS = ["a person walks forward", "jumps", "someone waves with the left hand"]
LENGTHS = [20, 13, 40]


# Batched and single runs differ by float rounding only: BLAS picks kernels by shape, and 4 sampler
# steps carry it on (an AMD EPYC box: up to 2.5e-4 in 11 of 31560 features; Intel: under 1e-5). A
# sample mixed up with its neighbour would be off by O(1).
@pytest.mark.parametrize("sampler", ["dpmpp_2m_sde", "ddim"])
def test_batched_equals_per_sample(sampler):
    pipe = make_pipeline()
    batch = pipe.generate(PROMPTS, LENGTHS, steps=4, sampler=sampler, seed=[5, 6, 7])
    for i, (text, n, s) in enumerate(zip(PROMPTS, LENGTHS, [5, 6, 7])):
        single = pipe.generate([text], [n], steps=4, sampler=sampler, seed=s)
        torch.testing.assert_close(batch.features[i, :n], single.features[0, :n], rtol=1e-4, atol=1e-4)
        torch.testing.assert_close(batch.joints[i, :n], single.joints[0, :n], rtol=1e-4, atol=1e-4)
    # chunking the request does not change anything either
    chunked = pipe.generate(PROMPTS, LENGTHS, steps=4, sampler=sampler, seed=[5, 6, 7], batch_size=2)
    torch.testing.assert_close(chunked.features, batch.features, rtol=1e-4, atol=1e-4)


def test_outputs_are_trimmed_denormalised_and_padded_with_zeros():
    pipe = make_pipeline()
    out = pipe.generate(PROMPTS, LENGTHS, steps=3, seed=1)
    assert out.features.shape == (3, 40, D) and out.joints.shape == (3, 40, 22, 3) and out.mask.shape == (3, 40)
    assert [f.shape for f in out.feature_list()] == [(20, D), (13, D), (40, D)]
    assert [j.shape for j in out.joint_list()] == [(20, 22, 3), (13, 22, 3), (40, 22, 3)]
    torch.testing.assert_close(out.raw_features[0, :20], out.normalized[0, :20] * pipe.std + pipe.mean)
    assert (out.features[1, 13:] == 0).all() and (out.joints[1, 13:] == 0).all()
    assert out.seeds == [1, 2, 3] and out.info["sampler"] == "dpmpp_2m_sde"


def test_seed_determinism():
    pipe = make_pipeline()
    a = pipe.generate(PROMPTS, LENGTHS, steps=3, seed=3)
    b = pipe.generate(PROMPTS, LENGTHS, steps=3, seed=3)
    c = pipe.generate(PROMPTS, LENGTHS, steps=3, seed=4)
    assert torch.equal(a.features, b.features)
    assert not torch.allclose(a.features[0], c.features[0])
    # an int seed gives sample i the seed + i
    d = pipe.generate(PROMPTS, LENGTHS, steps=3, seed=[3, 4, 5])
    assert torch.equal(a.features, d.features)


def test_parallel_cfg_equals_two_separate_passes():
    pipe = make_pipeline()
    pipe.model.forward_batches.clear()
    fused = pipe.generate(PROMPTS, LENGTHS, steps=4, cfg=2.5, seed=0)
    assert pipe.model.forward_batches == [6] * 4  # one forward of 2B per step
    pipe.model.forward_batches.clear()
    serial = baseline_denoiser(text_cache=True, parallel_cfg=False)  # the paper's baseline, as the bench runs it
    split = pipe.generate(PROMPTS, LENGTHS, steps=4, cfg=2.5, seed=0, denoiser=serial)
    assert pipe.model.forward_batches == [3] * 8
    # one forward of 2B against two of B: rounding only (as above; AMD EPYC: 2.5e-4 in 2 of 31560)
    torch.testing.assert_close(fused.features, split.features, rtol=1e-4, atol=5e-4)
    # guidance changes the result; cfg = 1 runs the conditional half only
    pipe.model.forward_batches.clear()
    plain = pipe.generate(PROMPTS, LENGTHS, steps=4, cfg=1.0, seed=0)
    assert pipe.model.forward_batches == [3] * 4
    assert not torch.allclose(plain.features, fused.features)


def test_cfg_denoiser_combines_halves():
    model = FakeModel()
    text, tmask = model.encode_text(["walk", "run fast"])
    null, nmask = model.encode_text([""])
    null, nmask = null.expand(2, -1, -1), nmask.expand(2, -1)
    mask = torch.ones(2, 8, dtype=torch.bool)
    x, t = torch.randn(2, 8, D), torch.tensor([10, 500])
    guided = CFGDenoiser(model, text, tmask, null, nmask, mask, scale=3.0)(x, t)
    cond = model(x, t, text, tmask, mask)
    uncond = model(x, t, null, nmask, mask)
    torch.testing.assert_close(guided, uncond + 3.0 * (cond - uncond), rtol=1e-5, atol=1e-6)


def test_text_encoded_once_per_request_and_null_once_per_pipeline():
    pipe = make_pipeline()
    pipe.generate(PROMPTS, LENGTHS, steps=5, seed=0)
    pipe.generate(["turns left"], [16], steps=5, seed=0)
    assert pipe.model.encode_calls == [PROMPTS, [""], ["turns left"]]


def test_bf16_runs_network_only_in_low_precision():
    pipe = make_pipeline()
    ref = pipe.generate(PROMPTS, LENGTHS, steps=3, seed=0)
    low = pipe.generate(PROMPTS, LENGTHS, steps=3, seed=0, dtype="bf16")
    assert pipe.model.seen_dtype == torch.bfloat16
    assert low.normalized.dtype == torch.float32 and torch.isfinite(low.features).all()
    assert low.info["dtype"] == "bfloat16"
    assert not torch.equal(low.features, ref.features)
    assert (low.normalized - ref.normalized).abs().max() < 0.1  # same sample, bf16 rounding only


class Recorder(AtSteps):
    """A hook that records what it sees and returns `value` (or leaves x0 when None)."""

    def __init__(self, steps, value=None, calls=None):
        super().__init__(steps)
        self.value, self.calls = value, calls if calls is not None else []

    def __call__(self, state):
        assert torch.is_grad_enabled()
        self.calls.append((self, state.step, state.t, tuple(state.x0.shape), tuple(state.mask.shape),
                           list(state.lengths), state.x0.clone()))
        return None if self.value is None else torch.full_like(state.x0, self.value)


def test_hook_runs_at_chosen_steps_and_edits_x0():
    pipe = make_pipeline()
    hook = Recorder([-1], value=0.0)
    out = pipe.generate(PROMPTS, LENGTHS, steps=5, seed=0, hooks=[hook])
    calls = [c[1:6] for c in hook.calls]
    assert [c[0] for c in calls] == [4] and calls[0][1] == 0
    assert calls[0][2:] == ((3, 40, D), (3, 40), LENGTHS)
    # the last step returns the (edited) x0 estimate: zero in model space, the mean in feature space
    assert out.normalized.abs().max() == 0
    torch.testing.assert_close(out.raw_features[0, :20], pipe.mean.expand(20, D))


def test_hooks_compose_in_the_requested_order():
    """Each active hook sees the previous one's x0; inactive ones are skipped."""
    pipe = make_pipeline()
    calls: list = []
    first, second, idle = Recorder(None, value=1.0, calls=calls), Recorder([-1], value=None, calls=calls), Recorder([], 5.0, calls)
    out = pipe.generate(PROMPTS, LENGTHS, steps=3, seed=0, hooks=[first, second, idle])
    order = [(c[0], c[1]) for c in calls]
    assert order == [(first, 0), (first, 1), (first, 2), (second, 2)]
    assert (calls[-1][6] == 1.0).all()  # the second hook saw the first one's edit
    assert torch.allclose(out.normalized[0, :20], torch.ones(20, D))


def test_bad_requests_raise_clear_errors():
    pipe = make_pipeline()
    with pytest.raises(StableMoError, match=r"texts\[1\]: empty prompt"):
        pipe.generate(["walk", "  "], [16, 16])
    with pytest.raises(StableMoError, match=r"lengths\[0\]: 100 frames is outside"):
        pipe.generate(["walk"], [100])
    with pytest.raises(StableMoError, match=r"lengths\[0\]: 2 frames"):
        pipe.generate(["walk"], 2)
    with pytest.raises(StableMoError, match="sampler: unknown"):
        pipe.generate(["walk"], [16], sampler="euler")
    with pytest.raises(StableMoError, match="seed: 1 seeds for 2"):
        pipe.generate(["walk", "run"], [16, 16], seed=[1])
    with pytest.raises(StableMoError, match="float16 is for CUDA"):
        pipe.generate(["walk"], [16], dtype="fp16")


# ---- bundles -----------------------------------------------------------------------------------


def tiny_bundle_config():
    return {
        "model": {
            "denoiser": {"name": "unet", "input_dim": D, "base_channels": 16, "channel_mults": [1, 2],
                         "time_dim": 32, "num_groups": 4, "num_heads": 2, "dropout": 0.0},
            "text": {"encoder": "minilm", "latent_dim": 32, "num_layers": 1, "num_heads": 2, "ff_dim": 64,
                     "dropout": 0.0},
        },
        "schedule": {"num_train_timesteps": 1000, "beta_start": 1e-4, "beta_end": 0.02, "beta_schedule": "linear"},
        "prediction_type": "sample",
        "dataset": "humanml3d",
        "skeleton": "humanml3d",
        "fps": 20,
        "mean": [0.0] * D,
        "std": [1.0] * D,
        "min_length": 8,
        "max_length": 64,
        "kind": "diffusion",
    }


@pytest.fixture(scope="module")
def tiny_bundle(tmp_path_factory):
    model_mod = pytest.importorskip("stablemo.nets.model")
    from stablemo.inference.bundle import save_bundle

    config = tiny_bundle_config()
    torch.manual_seed(0)
    model = model_mod.MotionDiffusionModel(**config["model"])
    for p in model.parameters():  # the output conv is zero-initialised; give the net a real output
        nn.init.normal_(p, std=0.05)
    return save_bundle(tmp_path_factory.mktemp("b") / "tiny", config, model.state_dict())


def test_from_bundle_generates_with_the_real_model(tiny_bundle):
    pipe = Pipeline.from_bundle(tiny_bundle, device="cpu")
    out = pipe.generate(["a person walks forward", "a person jumps"], [24, 11], steps=3, seed=[0, 1])
    assert out.features.shape == (2, 24, D) and torch.isfinite(out.joints).all()
    single = pipe.generate(["a person jumps"], [11], steps=3, seed=1)
    torch.testing.assert_close(out.features[1, :11], single.features[0, :11], rtol=1e-4, atol=1e-4)


def test_from_bundle_errors(tmp_path, tiny_bundle):
    import json
    import shutil

    with pytest.raises(StableMoError, match="bundle folder not found"):
        Pipeline.from_bundle(tmp_path / "nope")
    student = tmp_path / "student"
    shutil.copytree(tiny_bundle, student)
    config = json.loads((student / "config.json").read_text())
    config["kind"] = "hypothetical"
    (student / "config.json").write_text(json.dumps(config))
    with pytest.raises(StableMoError, match="bundle kind 'hypothetical' is not supported"):
        Pipeline.from_bundle(student)


def test_clearing_text_caches_can_keep_the_null_prompt():
    pipe = make_pipeline()
    pipe.generate(["jumps"], [8], steps=2, seed=0)
    pipe.model.encode_calls.clear()
    pipe.clear_text_caches(keep_null=True)  # AITS: the prompt is encoded again, the model's null prompt is not
    pipe.generate(["jumps"], [8], steps=2, seed=0)
    assert pipe.model.encode_calls == [["jumps"]]
    pipe.model.encode_calls.clear()
    pipe.clear_text_caches()
    pipe.generate(["jumps"], [8], steps=2, seed=0)
    assert sorted(pipe.model.encode_calls) == [[""], ["jumps"]]


def test_inference_config_comes_from_the_bundle_or_its_older_keys():
    from stablemo.errors import StableMoError

    stated = {"inference": {"sampler": "ddim", "steps": 20, "cfg": 3.0, "min_length": 8, "max_length": 64, "fps": 20.0}}
    assert InferenceConfig.from_bundle(stated) == InferenceConfig("ddim", 20, 3.0, 8, 64, 20.0)
    legacy_student = {"kind": "consistency", "min_length": 40, "max_length": 196, "fps": 20,
                      "consistency": {"mode": "pcm", "steps": 4, "w": 1.5}}
    assert InferenceConfig.from_bundle(legacy_student) == InferenceConfig("pcm", 4, 2.5, 40, 196, 20.0)
    assert InferenceConfig.from_bundle({}) == InferenceConfig()  # the paper's: SDE-DPM-Solver++, 10 steps, CFG 2.5
    for bad in ({"steps": 0}, {"cfg": float("nan")}, {"min_length": 50, "max_length": 40}, {"bogus": 1}):
        with pytest.raises(StableMoError, match="config.json: '?inference"):
            InferenceConfig.from_bundle({"inference": bad})


def test_shipped_demo_bundle_states_its_inference_config():
    import json

    from stablemo.inference.bundle import DEMO_BUNDLE as DEFAULT_BUNDLE

    config = json.loads((DEFAULT_BUNDLE / "config.json").read_text())
    # guidance 1.5, chosen on the val split (docs/training.md); the rest as derived from its other keys
    assert InferenceConfig.from_bundle(config) == InferenceConfig("dpmpp_2m_sde", 10, 1.5, 40, 196, 20.0)
    derived = InferenceConfig.from_bundle({k: v for k, v in config.items() if k != "inference"}).to_dict()
    assert config["inference"] == {**derived, "cfg": 1.5}
