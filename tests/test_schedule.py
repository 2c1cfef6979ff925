"""NoiseSchedule: tables, training helpers, and the step grids (vs diffusers where it is installed)."""

import pytest
import torch

from stablemo.diffusion.guidance import to_x0
from stablemo.diffusion.schedule import NoiseSchedule
from stablemo.errors import StableMoError


def test_tables_match_closed_form():
    s = NoiseSchedule()
    assert s.betas.dtype == torch.float32 and s.alphas_cumprod.shape == (1000,)
    assert s.betas[0].item() == pytest.approx(1e-4) and s.betas[-1].item() == pytest.approx(0.02)
    expected = torch.cumprod(1 - torch.linspace(1e-4, 0.02, 1000, dtype=torch.float64), 0)
    torch.testing.assert_close(s.alphas_cumprod.double(), expected, rtol=1e-5, atol=1e-7)
    # as diffusers' DPMSolverMultistepScheduler computes them: sigma_min = 0.0100013, sigma_max = 157.40727
    assert s.sigmas[0].item() == pytest.approx(0.0100013, rel=1e-5)
    assert s.sigmas[-1].item() == pytest.approx(157.40727, rel=1e-6)


def test_karras_grid_for_ten_steps_matches_the_facts_sheet():
    timesteps, sigmas = NoiseSchedule().karras_timesteps(10)
    assert timesteps == [999, 937, 864, 775, 663, 511, 301, 102, 18, 0]
    expected = [157.40727, 85.71073, 44.04765, 21.10560, 9.27474, 3.65264, 1.24636, 0.349706, 0.0739303, 0.0100013, 0]
    assert sigmas.dtype == torch.float64
    torch.testing.assert_close(sigmas, torch.tensor(expected, dtype=torch.float64), rtol=5e-6, atol=1e-9)  # sheet values have 6-7 digits


@pytest.mark.parametrize("steps", [1, 2, 1000])
def test_grid_edge_cases(steps):
    s = NoiseSchedule()
    timesteps, sigmas = s.karras_timesteps(steps)
    assert len(timesteps) == steps and sigmas.shape == (steps + 1,)
    assert timesteps[0] == 999 and sigmas[-1] == 0
    assert all(a >= b for a, b in zip(timesteps, timesteps[1:]))  # duplicates allowed, never increasing
    assert bool((sigmas[:-1] > sigmas[1:]).all())  # the solver's sigmas strictly decrease
    leading = s.leading_timesteps(steps)
    assert len(leading) == steps and leading[-1] == 0
    assert len(set(leading)) == steps


def test_sigma_to_t_inverts_the_table():
    s = NoiseSchedule()
    t = s.sigma_to_t(s.sigmas.double())
    torch.testing.assert_close(t, torch.arange(1000, dtype=torch.float64), atol=1e-3, rtol=0)
    mid = s.sigma_to_t(torch.sqrt(s.sigmas[10].double() * s.sigmas[11].double()))
    assert 10 < mid.item() < 11


def test_q_sample_predict_x0_and_target_roundtrip():
    s = NoiseSchedule()
    gen = torch.Generator().manual_seed(0)
    x0, noise = torch.randn(4, 8, 3, generator=gen), torch.randn(4, 8, 3, generator=gen)
    t = torch.tensor([0, 10, 500, 999])
    xt = s.q_sample(x0, t, noise)
    abar = s.alphas_cumprod[t].double()
    manual = abar.sqrt()[:, None, None] * x0.double() + (1 - abar).sqrt()[:, None, None] * noise.double()
    torch.testing.assert_close(xt.double(), manual, rtol=1e-6, atol=1e-6)
    # an exact eps prediction recovers x0; an exact x0 prediction is returned unchanged
    torch.testing.assert_close(s.predict_x0(noise, xt, t, "epsilon"), x0, rtol=1e-3, atol=2e-3)
    assert s.predict_x0(x0, xt, t, "sample") is x0
    assert s.target(x0, noise, t, "sample") is x0 and s.target(x0, noise, t, "epsilon") is noise
    # v = alpha eps - sigma x0; an exact v prediction recovers x0 at every noise level, and the
    # sampler-side conversion (to_x0 with scalar alpha, sigma) agrees with the schedule's
    v = s.target(x0, noise, t, "v_prediction")
    manual_v = abar.sqrt()[:, None, None] * noise.double() - (1 - abar).sqrt()[:, None, None] * x0.double()
    torch.testing.assert_close(v.double(), manual_v, rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(s.predict_x0(v, xt, t, "v_prediction"), x0, rtol=1e-5, atol=1e-5)
    for i in range(4):
        a, sg = float(abar[i].sqrt()), float((1 - abar[i]).sqrt())
        torch.testing.assert_close(to_x0(v[i], xt[i], a, sg, "v_prediction"), x0[i], rtol=1e-5, atol=1e-5)


def test_bad_arguments_raise_clear_errors():
    s = NoiseSchedule()
    with pytest.raises(StableMoError, match="steps"):
        s.karras_timesteps(0)
    with pytest.raises(StableMoError, match="steps"):
        s.leading_timesteps(1001)
    with pytest.raises(StableMoError, match="prediction_type"):
        s.target(torch.zeros(1), torch.zeros(1), torch.zeros(1, dtype=torch.long), "v")
    with pytest.raises(StableMoError, match="beta_schedule"):
        NoiseSchedule(beta_schedule="quadratic")
    with pytest.raises(StableMoError, match="t:"):
        s.q_sample(torch.zeros(1, 2), torch.tensor([1000]), torch.zeros(1, 2))


@pytest.mark.parametrize("beta_schedule", ["linear", "scaled_linear", "squaredcos_cap_v2"])
def test_tables_match_diffusers(beta_schedule):
    diffusers = pytest.importorskip("diffusers")
    ref = diffusers.DDPMScheduler(num_train_timesteps=1000, beta_schedule=beta_schedule)
    s = NoiseSchedule(beta_schedule=beta_schedule)
    torch.testing.assert_close(s.betas, ref.betas, rtol=1e-6, atol=1e-9)
    torch.testing.assert_close(s.alphas_cumprod, ref.alphas_cumprod, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("steps", [1, 2, 5, 10, 20, 25, 50, 79, 100, 1000])
def test_karras_timesteps_and_sigmas_match_diffusers(steps):
    diffusers = pytest.importorskip("diffusers")
    ref = diffusers.DPMSolverMultistepScheduler(
        num_train_timesteps=1000, beta_schedule="linear", algorithm_type="sde-dpmsolver++", use_karras_sigmas=True
    )
    ref.set_timesteps(steps)
    timesteps, sigmas = NoiseSchedule().karras_timesteps(steps)
    assert timesteps == ref.timesteps.tolist()
    torch.testing.assert_close(sigmas, ref.sigmas.double(), rtol=1e-6, atol=1e-12)


@pytest.mark.parametrize("steps", [1, 2, 10, 1000])
@pytest.mark.parametrize("name", ["DDIMScheduler", "DDPMScheduler"])
def test_leading_timesteps_match_diffusers(name, steps):
    diffusers = pytest.importorskip("diffusers")
    ref = getattr(diffusers, name)(num_train_timesteps=1000, beta_schedule="linear")
    ref.set_timesteps(steps)
    assert NoiseSchedule().leading_timesteps(steps) == ref.timesteps.tolist()

