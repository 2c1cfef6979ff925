"""Consistency distillation: boundary conditions, initial equality, grids, deterministic PCM, masked loss."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from stablemo.diffusion.schedule import NoiseSchedule
from stablemo.distill.consistency import (
    CLEAN,
    boundary_scalings,
    ddim_grid,
    ddim_jump,
    lcm_consistency,
    lower_edge,
    masked_pseudo_huber,
    phase_edges,
)
from stablemo.distill.sampling import lcm_timesteps, pcm_path, sample_lcm, sample_pcm
from stablemo.distill.student import ConsistencyStudent
from stablemo.inference.bundle import save_bundle
from stablemo.nets.model import MotionDiffusionModel

D = 263
TINY = {
    "denoiser": {"name": "unet", "input_dim": D, "base_channels": 16, "channel_mults": [1, 2], "time_dim": 32,
                 "num_groups": 4, "num_heads": 2, "dropout": 0.0},
    "text": {"encoder": "minilm", "latent_dim": 32, "num_layers": 1, "num_heads": 2, "ff_dim": 64, "dropout": 0.0},
}


def tiny_teacher(seed: int = 0) -> MotionDiffusionModel:
    torch.manual_seed(seed)
    model = MotionDiffusionModel(**TINY)
    # the output layer is zero-initialised; give it weights so the teacher's predictions vary
    torch.nn.init.normal_(model.denoiser.out.weight, std=0.05)
    return model.eval()


@pytest.fixture(scope="module")
def teacher_bundle(tmp_path_factory):
    model = tiny_teacher()
    config = {
        "kind": "diffusion", "model": TINY, "schedule": NoiseSchedule().config(), "prediction_type": "sample",
        "dataset": "humanml3d", "skeleton": "humanml3d", "fps": 20, "mean": [0.0] * D, "std": [1.0] * D,
        "min_length": 40, "max_length": 196,
    }
    return save_bundle(tmp_path_factory.mktemp("b") / "teacher", config, model.state_dict())


def test_grids_match_the_published_values():
    assert ddim_grid(1000, 50)[:3] == [19, 39, 59] and ddim_grid(1000, 50)[-1] == 999
    assert phase_edges(1000, 50, 4) == [CLEAN, 239, 499, 739, 999]
    assert lcm_timesteps(1000, 50, 1) == [999]
    assert lcm_timesteps(1000, 50, 2) == [999, 499]
    assert lcm_timesteps(1000, 50, 4) == [999, 759, 499, 259]
    edges = phase_edges(1000, 50, 4)
    assert pcm_path(edges, 4) == [999, 739, 499, 239, CLEAN]
    assert pcm_path(edges, 2) == [999, 499, CLEAN]
    assert pcm_path(edges, 1) == [999, CLEAN]
    t = torch.tensor([1, 19, 239, 240, 500, 999])
    assert lower_edge(t, edges).tolist() == [CLEAN, CLEAN, CLEAN, 239, 499, 739]


def test_boundary_conditions_hold_exactly():
    schedule = NoiseSchedule()
    x = torch.randn(3, 8, 5)
    x0 = torch.randn(3, 8, 5)
    zero = torch.zeros(3, dtype=torch.long)
    c_skip, c_out = boundary_scalings(zero)
    assert torch.all(c_skip == 1) and torch.all(c_out == 0)
    assert torch.equal(lcm_consistency(x, x0, zero), x)
    # PCM: a jump to the same level is the identity, a jump to CLEAN returns the x0 estimate
    t = torch.tensor([239, 499, 739])
    assert torch.allclose(ddim_jump(schedule, x, x0, t, t), x, atol=1e-6)
    clean = torch.full((3,), CLEAN)
    assert torch.allclose(ddim_jump(schedule, x, x0, t, clean), x0, atol=1e-6)
    # and the jump of the exact forward state with its own x0 lands on the forward state of the edge
    eps = torch.randn_like(x0)
    a = schedule.alphas_cumprod
    x_t = a[t].sqrt()[:, None, None] * x0 + (1 - a[t]).sqrt()[:, None, None] * eps
    s = torch.tensor([0, 239, 499])
    x_s = a[s].sqrt()[:, None, None] * x0 + (1 - a[s]).sqrt()[:, None, None] * eps
    assert torch.allclose(ddim_jump(schedule, x_t, x0, t, s), x_s, atol=1e-5)


def test_student_equals_teacher_at_initialisation():
    teacher = tiny_teacher()
    student = ConsistencyStudent(TINY)
    student.model.load_state_dict(teacher.state_dict())
    student.eval()
    x = torch.randn(2, 16, D)
    t = torch.tensor([999, 259])
    mask = torch.ones(2, 16, dtype=torch.bool)
    mask[1, 12:] = False
    text, text_mask = teacher.encode_text(["a person walks", "a person jumps"])
    with torch.no_grad():
        ref = teacher(x, t, text, text_mask, mask)
        for w in (0.0, 1.5, 7.0):
            out = student(x, t, torch.full((2,), w), text, text_mask, mask)
            assert torch.equal(out, ref)
    assert float(ref.abs().max()) > 0  # the comparison is not between two zero tensors


def test_masked_loss_ignores_padding():
    pred = torch.randn(2, 12, D)
    target = torch.randn(2, 12, D)
    mask = torch.ones(2, 12, dtype=torch.bool)
    mask[0, 7:] = False
    base = masked_pseudo_huber(pred, target, mask, 0.03)
    pred2, target2 = pred.clone(), target.clone()
    pred2[0, 7:] = 1e3
    target2[0, 7:] = -1e3
    assert torch.equal(masked_pseudo_huber(pred2, target2, mask, 0.03), base)
    pred2[0, 6] += 1.0  # a valid frame does count
    assert masked_pseudo_huber(pred2, target2, mask, 0.03) > base


def test_pcm_sampling_is_deterministic_and_draws_no_noise():
    schedule = NoiseSchedule()
    edges = phase_edges(1000, 50, 4)
    denoise = lambda x, t: torch.tanh(x) * 0.5  # noqa: E731  (a fixed smooth "network")
    x = torch.randn(2, 8, 4, generator=torch.Generator().manual_seed(1))
    a = sample_pcm(denoise, x, schedule, pcm_path(edges, 4))
    b = sample_pcm(denoise, x.clone(), schedule, pcm_path(edges, 4))
    assert torch.equal(a, b)
    # a one-phase path returns the network's x0 at the top step
    assert torch.equal(sample_pcm(denoise, x, schedule, [999, CLEAN]), denoise(x, None))


def test_lcm_sampling_uses_fresh_noise_between_steps():
    schedule = NoiseSchedule()
    denoise = lambda x, t: torch.zeros_like(x)  # noqa: E731
    x = torch.randn(1, 8, 4)
    draws = []

    def noise(like):
        z = torch.randn_like(like)
        draws.append(z)
        return z

    sample_lcm(denoise, x, schedule, [999, 759, 499, 259], noise)
    assert len(draws) == 3


def test_distillation_loss_decreases_on_a_tiny_set(teacher_bundle):
    from stablemo.training.distill_module import ConsistencyDistillation

    module = ConsistencyDistillation(teacher=str(teacher_bundle), mode="lcm", ddim_steps=10, huber_c=0.03)
    # the student starts as the teacher, whose consistency error is already small; move it away so
    # there is something to learn (the target network stays the teacher)
    with torch.no_grad():
        torch.nn.init.normal_(module.student.model.denoiser.out.weight, std=0.3, generator=torch.Generator().manual_seed(5))
    gen = torch.Generator().manual_seed(0)
    batch = {"motion": torch.randn(4, 16, D, generator=gen), "mask": torch.ones(4, 16, dtype=torch.bool),
             "text": ["a person walks", "a person jumps", "a person waves", "a person runs"]}
    batch["mask"][2, 10:] = False
    batch["motion"][2, 10:] = 0
    opt = torch.optim.Adam([p for p in module.student.parameters() if p.requires_grad], lr=1e-3)
    losses = []
    for _ in range(40):
        loss = module.distillation_loss(batch, torch.Generator().manual_seed(3))["loss"]
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.5 * losses[0], losses


def test_student_bundle_samples_through_the_pipeline(teacher_bundle, tmp_path):
    from stablemo.inference.pipeline import Pipeline
    from stablemo.training.distill_module import ConsistencyDistillation

    for mode in ("lcm", "pcm"):
        module = ConsistencyDistillation(teacher=str(teacher_bundle), mode=mode, ddim_steps=50, phases=4)
        config, state = module.bundle()
        path = save_bundle(tmp_path / mode, config, state)
        pipe = Pipeline.from_bundle(path)
        for steps in (1, 2, 4):
            out = pipe.generate(["a person walks"], [40], steps=steps, seed=0)
            again = pipe.generate(["a person walks"], [40], steps=steps, seed=0)
            feats = out.feature_list()[0]
            assert feats.shape == (40, D) and np.isfinite(feats).all()
            np.testing.assert_array_equal(feats, again.feature_list()[0])


def test_student_bundle_records_its_teachers_weights(teacher_bundle):
    """after_ship.sh tells a student distilled from an earlier teacher by this record, not by file times."""
    import hashlib

    from stablemo.training.distill_module import ConsistencyDistillation

    config, _ = ConsistencyDistillation(teacher=str(teacher_bundle), mode="lcm", ddim_steps=50).bundle()
    weights = (teacher_bundle / "model.safetensors").read_bytes()
    assert config["training"]["teacher_weights_sha256"] == hashlib.sha256(weights).hexdigest()


def test_student_pipeline_clears_the_shared_text_cache(teacher_bundle, tmp_path):
    """AITS times each sentence with cold text caches; a student's pipeline must reach its encoder."""
    from stablemo.inference.pipeline import Pipeline
    from stablemo.training.distill_module import ConsistencyDistillation

    module = ConsistencyDistillation(teacher=str(teacher_bundle), mode="lcm", ddim_steps=50)
    config, state = module.bundle()
    pipe = Pipeline.from_bundle(save_bundle(tmp_path / "lcm", config, state))
    frozen = pipe.model.model.text.frozen
    pipe.generate(["a person waves twice"], [40], steps=1, seed=0)
    assert "a person waves twice" in frozen._cache
    pipe.clear_text_caches()
    assert len(frozen._cache) == 0
    misses = frozen.misses
    pipe.generate(["a person waves twice"], [40], steps=1, seed=0)
    assert frozen.misses == misses + 1


def test_guidance_embedding_can_learn_faster(teacher_bundle):
    from stablemo.training.distill_module import ConsistencyDistillation

    module = ConsistencyDistillation(teacher=str(teacher_bundle), mode="lcm", ddim_steps=50, lr=1e-4, w_lr_scale=20)
    (opt,), _ = module.configure_optimizers()
    rest, w = opt.param_groups
    assert len(w["params"]) == 1 and w["params"][0] is module.student.w_proj.weight
    assert w["initial_lr"] == pytest.approx(2e-3) and rest["initial_lr"] == pytest.approx(1e-4)  # before warm-up
    assert all(p is not module.student.w_proj.weight for p in rest["params"])
    trainable = [p for p in module.student.parameters() if p.requires_grad]
    assert len(rest["params"]) + 1 == len(trainable)


def test_student_inference_is_the_students_own_with_the_teachers_lengths():
    """A student config copied from a teacher with an inference section (sampler dpmpp_2m_sde) must
    name the student's sampler, or the bundle would not load; lengths and fps stay the teacher's."""
    from stablemo.inference.config import student_inference

    config = {"kind": "consistency", "consistency": {"mode": "lcm", "steps": 1, "w": 1.5},
              "inference": {"sampler": "dpmpp_2m_sde", "steps": 10, "cfg": 2.5, "min_length": 40,
                            "max_length": 196, "fps": 20.0}}
    got = student_inference(config)
    assert (got.sampler, got.steps, got.cfg) == ("lcm", 1, 2.5)
    assert (got.min_length, got.max_length, got.fps) == (40, 196, 20.0)


def attach_data(module, mean, std) -> None:
    """What setup() reads from a Trainer: its data module's feature statistics."""
    from types import SimpleNamespace

    module._trainer = SimpleNamespace(datamodule=SimpleNamespace(mean=mean, std=std))


def test_distillation_needs_the_teachers_statistics(teacher_bundle):
    from stablemo.errors import StableMoError
    from stablemo.training.distill_module import ConsistencyDistillation

    module = ConsistencyDistillation(teacher=str(teacher_bundle), mode="lcm", ddim_steps=50)
    attach_data(module, np.zeros(D, np.float32), np.ones(D, np.float32))
    module.setup("fit")  # the teacher's own statistics
    std = np.ones(D, np.float32)
    std[7] = 1.01
    attach_data(module, np.zeros(D, np.float32), std)
    with pytest.raises(StableMoError, match="the dataset's std differs from the teacher's"):
        module.setup("fit")


def test_bone_length_term_pulls_the_students_bones_to_the_bodys_and_refuses_the_other_terms(teacher_bundle):
    """geometry: {bone_lengths: w} adds w x the student's bone-length error (its clean estimate's
    bones against the data clip's, m²) to the consistency loss; training with it shortens the
    error, and terms that compare with the clip itself are refused."""
    from stablemo.data.synth import generate_motion
    from stablemo.data.synth.writer import motion_rng
    from stablemo.errors import StableMoError
    from stablemo.motion import joints_to_features
    from stablemo.training.distill_module import ConsistencyDistillation

    with pytest.raises(StableMoError, match="distillation takes only bone_lengths and rotations, got positions"):
        ConsistencyDistillation(teacher=str(teacher_bundle), geometry={"positions": 1.0})
    plain = ConsistencyDistillation(teacher=str(teacher_bundle), mode="lcm", ddim_steps=10)
    module = ConsistencyDistillation(teacher=str(teacher_bundle), mode="lcm", ddim_steps=10,
                                     geometry={"bone_lengths": 10.0})
    # real clips (the fixture's statistics are 0 / 1: model space is the features themselves)
    clips = [joints_to_features(generate_motion(motion_rng(0, i)).joints)[:40] for i in range(2)]
    batch = {"motion": torch.tensor(np.stack(clips), dtype=torch.float32), "mask": torch.ones(2, 40, dtype=torch.bool),
             "text": ["a person walks", "a person jumps"]}
    batch["mask"][1, 30:] = False
    out = module.distillation_loss(batch, torch.Generator().manual_seed(0))
    same = plain.distillation_loss(batch, torch.Generator().manual_seed(0))
    torch.testing.assert_close(out["consistency"], same["loss"])  # the same draws, the same consistency loss
    torch.testing.assert_close(out["loss"], out["consistency"] + 10.0 * out["bone_lengths"])
    opt = torch.optim.Adam([p for p in module.student.parameters() if p.requires_grad], lr=1e-3)
    bones = []
    for _ in range(30):
        out = module.distillation_loss(batch, torch.Generator().manual_seed(1))
        opt.zero_grad()
        out["loss"].backward()
        opt.step()
        bones.append(out["bone_lengths"].item())
    assert bones[0] > 1e-3 and bones[-1] < 0.5 * bones[0], bones  # the random tiny teacher's bones: far off
