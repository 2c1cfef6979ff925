"""Small wrappers between a network and the samplers: output -> x0 conversion, classifier-free guidance.

The samplers see one contract, `denoise(x_t (B,T,D), t (B,) long) -> (B,T,D)`; everything that
depends on how the network was trained (parameterisation, conditioning, guidance, precision)
lives here, not inside the solvers.
"""

from __future__ import annotations

import contextlib
from typing import Protocol

import torch
import torch.nn.functional as F

from stablemo.diffusion.schedule import check_prediction_type


class Network(Protocol):
    """What guidance needs of a network (MotionDiffusionModel): per-request conditioning, then steps."""

    def prepare(self, text, text_mask, motion_mask, time_cond=None, timesteps=()): ...

    def denoise(self, x: torch.Tensor, t: torch.Tensor, ctx) -> torch.Tensor: ...


def to_x0(output: torch.Tensor, x: torch.Tensor, alpha: float, sigma: float, prediction_type: str) -> torch.Tensor:
    """x0 estimate from a raw network output at state x = alpha x0 + sigma eps (Ho et al. 2020, Eq. 15)."""
    check_prediction_type(prediction_type)
    if prediction_type == "sample":
        return output
    if prediction_type == "v_prediction":  # x0 = alpha x - sigma v (Salimans & Ho 2022)
        return alpha * x - sigma * output
    return (x - sigma * output) / alpha


def _pad_tokens(text: torch.Tensor, mask: torch.Tensor, length: int) -> tuple[torch.Tensor, torch.Tensor]:
    extra = length - text.shape[1]
    if extra == 0:
        return text, mask
    return F.pad(text, (0, 0, 0, extra)), F.pad(mask, (0, extra), value=False)


def precision_context(device: torch.device | str, dtype: torch.dtype | None):
    """Autocast for the network only: fp16/bf16 matmuls and convs, everything else stays float32."""
    if dtype is None or dtype == torch.float32:
        return contextlib.nullcontext()
    return torch.autocast(device_type=torch.device(device).type, dtype=dtype)


class CFGDenoiser:
    """Classifier-free guidance, out = u + scale (c - u) on raw network outputs.

    Guidance on x0 equals guidance on eps (an affine map whose weights sum to 1), so it is applied
    before any x0 conversion. With `batched=True` the conditional and unconditional halves run as
    one forward of batch 2B (the paper's "parallel CFG"); with `batched=False` as two forwards.
    The network's per-request conditioning (text contexts, AdaGN tables for the planned
    `timesteps`) is prepared once here, in the network's precision, not at every step.

    text/null_text: (B,L,C) / (B,L',C) with masks (B,L)/(B,L') bool; motion_mask: (B,T) bool.
    """

    def __init__(
        self,
        network: Network,
        text: torch.Tensor,
        text_mask: torch.Tensor,
        null_text: torch.Tensor,
        null_mask: torch.Tensor,
        motion_mask: torch.Tensor,
        scale: float = 2.5,
        batched: bool = True,
        dtype: torch.dtype | None = None,
        timesteps=(),
    ) -> None:
        self.network = network
        self.scale = float(scale)
        self.batched = batched
        self.dtype = dtype
        length = max(text.shape[1], null_text.shape[1])
        cond = _pad_tokens(text, text_mask, length)
        uncond = _pad_tokens(null_text, null_mask, length)
        with precision_context(motion_mask.device, dtype):
            if self.scale == 1.0:  # guidance off: the conditional pass alone
                self.ctx = {"cond": network.prepare(*cond, motion_mask, timesteps=timesteps)}
            elif batched:
                both = torch.cat([cond[0], uncond[0]]), torch.cat([cond[1], uncond[1]])
                self.ctx = {"both": network.prepare(*both, torch.cat([motion_mask, motion_mask]), timesteps=timesteps)}
            else:
                self.ctx = {"cond": network.prepare(*cond, motion_mask, timesteps=timesteps),
                            "uncond": network.prepare(*uncond, motion_mask, timesteps=timesteps)}

    def _run(self, x, t, ctx) -> torch.Tensor:
        with precision_context(x.device, self.dtype):
            out = self.network.denoise(x, t, ctx)
        return out.float()

    def __call__(self, x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        if self.scale == 1.0:
            return self._run(x, t, self.ctx["cond"])
        if self.batched:
            cond, uncond = self._run(torch.cat([x, x]), torch.cat([t, t]), self.ctx["both"]).chunk(2)
        else:
            cond = self._run(x, t, self.ctx["cond"])
            uncond = self._run(x, t, self.ctx["uncond"])
        return uncond + self.scale * (cond - uncond)
