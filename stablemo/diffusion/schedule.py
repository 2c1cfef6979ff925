"""The discrete DDPM noise schedule, its training helpers, and the step grids samplers walk.

Tables are built exactly as diffusers builds them (float32 betas and cumulative products) so a
model trained here samples identically there; everything derived from them for sampling (Karras
sigmas, sigma -> timestep interpolation, solver coefficients) is computed in float64 and only cast
at the point of use. Formulas: Karras et al. 2022 (EDM) Eq. 5 and diffusers' `DPMSolverMultistepScheduler`.
"""

from __future__ import annotations

import math

import torch

from stablemo.errors import StableMoError

BETA_SCHEDULES = ("linear", "scaled_linear", "squaredcos_cap_v2")
PREDICTION_TYPES = ("sample", "epsilon", "v_prediction")


def _betas(num_train_timesteps: int, beta_start: float, beta_end: float, beta_schedule: str) -> torch.Tensor:
    n = num_train_timesteps
    if beta_schedule == "linear":
        return torch.linspace(beta_start, beta_end, n, dtype=torch.float32)
    if beta_schedule == "scaled_linear":  # linear in sqrt(beta) (latent-diffusion style)
        return torch.linspace(beta_start**0.5, beta_end**0.5, n, dtype=torch.float32) ** 2
    if beta_schedule == "squaredcos_cap_v2":  # Nichol & Dhariwal cosine schedule, beta capped at 0.999

        def alpha_bar(u: float) -> float:
            return math.cos((u + 0.008) / 1.008 * math.pi / 2) ** 2

        betas = [min(1 - alpha_bar((i + 1) / n) / alpha_bar(i / n), 0.999) for i in range(n)]
        return torch.tensor(betas, dtype=torch.float32)
    raise StableMoError(f"beta_schedule: expected one of {BETA_SCHEDULES}, got {beta_schedule!r}")


class NoiseSchedule:
    """DDPM forward process q(x_t | x_0) = N(sqrt(abar_t) x_0, (1 - abar_t) I), t = 0 … N-1.

    `betas`, `alphas_cumprod`: float32 (N,) CPU tensors. `sigmas`: the VE noise levels
    sqrt((1 - abar)/abar), float32, increasing in t.
    """

    def __init__(
        self,
        num_train_timesteps: int = 1000,
        beta_start: float = 1e-4,
        beta_end: float = 0.02,
        beta_schedule: str = "linear",
    ) -> None:
        if int(num_train_timesteps) < 2:
            raise StableMoError(f"num_train_timesteps: must be >= 2, got {num_train_timesteps}")
        self.num_train_timesteps = int(num_train_timesteps)
        self.beta_start = float(beta_start)
        self.beta_end = float(beta_end)
        self.beta_schedule = beta_schedule
        self.betas = _betas(self.num_train_timesteps, self.beta_start, self.beta_end, beta_schedule)
        self.alphas_cumprod = torch.cumprod(1.0 - self.betas, dim=0)
        self.sigmas = ((1 - self.alphas_cumprod) / self.alphas_cumprod) ** 0.5
        # float64 views for coefficient arithmetic (values identical to the float32 tables)
        self._abar64 = self.alphas_cumprod.double()
        self._log_sigmas64 = torch.log(self.sigmas).double()

    def config(self) -> dict:
        """Constructor kwargs, as stored in a bundle's `schedule` entry."""
        return {
            "num_train_timesteps": self.num_train_timesteps,
            "beta_start": self.beta_start,
            "beta_end": self.beta_end,
            "beta_schedule": self.beta_schedule,
        }

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.config().items())
        return f"NoiseSchedule({args})"

    # ---- training helpers -------------------------------------------------------------------

    def _coef(self, t: torch.Tensor, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """sqrt(abar_t), sqrt(1 - abar_t) for integer t (B,), shaped to broadcast against `like`."""
        t = torch.as_tensor(t, device=like.device).long().reshape(-1)
        if like.device.type == "cpu" and t.numel() and (int(t.min()) < 0 or int(t.max()) >= self.num_train_timesteps):
            raise StableMoError(f"t: timesteps must lie in [0, {self.num_train_timesteps - 1}]")
        sqrt_abar, sqrt_one_minus = self._tables(like.device)  # on like's device: no host sync on GPUs
        shape = (-1,) + (1,) * (like.dim() - 1)
        a = sqrt_abar[t].to(like.dtype).reshape(shape)
        s = sqrt_one_minus[t].to(like.dtype).reshape(shape)
        return a, s

    def _tables(self, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
        """sqrt(abar), sqrt(1 - abar) in float64 (float32 where float64 is unsupported), per device."""
        cache = self.__dict__.setdefault("_device_tables", {})
        key = str(device)
        if key not in cache:
            dtype = torch.float32 if torch.device(device).type == "mps" else torch.float64
            cache[key] = (self._abar64.sqrt().to(device, dtype), (1 - self._abar64).sqrt().to(device, dtype))
        return cache[key]

    def q_sample(self, x0: torch.Tensor, t: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
        """x_t = sqrt(abar_t) x0 + sqrt(1 - abar_t) noise;  x0, noise: (B, ...), t: (B,) long."""
        a, s = self._coef(t, x0)
        return a * x0 + s * noise

    def predict_x0(
        self, model_output: torch.Tensor, x_t: torch.Tensor, t: torch.Tensor, prediction_type: str
    ) -> torch.Tensor:
        """The model's estimate of x0 at integer timesteps t (B,)."""
        check_prediction_type(prediction_type)
        if prediction_type == "sample":
            return model_output
        a, s = self._coef(t, x_t)
        if prediction_type == "v_prediction":
            return a * x_t - s * model_output
        return (x_t - s * model_output) / a

    def target(self, x0: torch.Tensor, noise: torch.Tensor, t: torch.Tensor, prediction_type: str) -> torch.Tensor:
        """What the network regresses onto for a given parameterisation at timesteps t (B,): x0, the
        noise, or v = sqrt(abar) noise - sqrt(1 - abar) x0 (Salimans & Ho 2022, §4)."""
        check_prediction_type(prediction_type)
        if prediction_type == "sample":
            return x0
        if prediction_type == "epsilon":
            return noise
        a, s = self._coef(t, x0)
        return a * noise - s * x0

    # ---- sampling grids ---------------------------------------------------------------------

    def leading_timesteps(self, steps: int) -> list[int]:
        """DDPM/DDIM grid, diffusers' default 'leading' spacing: k * (N // n) for k = n-1 … 0."""
        _check_steps(steps, self.num_train_timesteps)
        ratio = self.num_train_timesteps // steps
        return [k * ratio for k in range(steps - 1, -1, -1)]

    def karras_sigmas(self, steps: int, rho: float = 7.0) -> torch.Tensor:
        """Karras et al. (2022) eq. 5 between this schedule's sigma_max and sigma_min, then a final 0.

        Returns float64 (steps + 1,): decreasing noise levels the solver steps through.
        """
        _check_steps(steps, self.num_train_timesteps)
        sigma_min, sigma_max = float(self.sigmas[0]), float(self.sigmas[-1])
        ramp = torch.linspace(0, 1, steps, dtype=torch.float64) if steps > 1 else torch.zeros(1, dtype=torch.float64)
        lo, hi = sigma_min ** (1 / rho), sigma_max ** (1 / rho)
        sigmas = (hi + ramp * (lo - hi)) ** rho
        return torch.cat([sigmas, torch.zeros(1, dtype=torch.float64)])

    def sigma_to_t(self, sigma: torch.Tensor) -> torch.Tensor:
        """Fractional timestep whose log-sigma matches, by linear interpolation in log sigma (float64)."""
        sigma = torch.as_tensor(sigma, dtype=torch.float64)
        log_sigma = sigma.clamp_min(1e-10).log()
        log_table = self._log_sigmas64
        # low = largest k with log_sigma_k <= log_sigma, kept <= N-2 so low+1 exists
        low = (log_table[:, None] <= log_sigma.reshape(1, -1)).sum(0) - 1
        low = low.clamp(0, self.num_train_timesteps - 2)
        lo_val, hi_val = log_table[low], log_table[low + 1]
        w = ((lo_val - log_sigma.reshape(-1)) / (lo_val - hi_val)).clamp(0, 1)
        return (low.double() + w).reshape(sigma.shape)

    def karras_timesteps(self, steps: int) -> tuple[list[int], torch.Tensor]:
        """(model timesteps round(t(sigma_i)) for i < steps, float64 sigmas incl. the final 0)."""
        sigmas = self.karras_sigmas(steps)
        # torch.round rounds half to even, as numpy does
        timesteps = torch.round(self.sigma_to_t(sigmas[:-1])).long().tolist()
        return timesteps, sigmas


def check_prediction_type(prediction_type: str) -> None:
    if prediction_type not in PREDICTION_TYPES:
        raise StableMoError(f"prediction_type: expected one of {PREDICTION_TYPES}, got {prediction_type!r}")


def _check_steps(steps: int, num_train_timesteps: int) -> None:
    if not isinstance(steps, int) or isinstance(steps, bool) or not 1 <= steps <= num_train_timesteps:
        raise StableMoError(f"steps: must be an integer in [1, {num_train_timesteps}], got {steps!r}")
