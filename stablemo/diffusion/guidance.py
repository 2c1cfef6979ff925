"""Small wrappers between a network and the samplers: output -> x0 conversion, classifier-free guidance.

The samplers see one contract, `denoise(x_t (B,T,D), t (B,) long) -> (B,T,D)`; everything that
depends on how the network was trained (parameterisation, conditioning, guidance, precision)
lives here, not inside the solvers.
"""

from __future__ import annotations

import contextlib
from typing import Callable

import torch
import torch.nn.functional as F

from stablemo.diffusion.schedule import check_prediction_type
from stablemo.nets.layers import PLANNED_TIMESTEPS

# network(x (B,T,D), t (B,), text (B,L,C), text_mask (B,L), motion_mask (B,T), memo=dict) -> (B,T,D);
# memo is a dict kept for one fixed text, where the network may store text-only intermediates
Network = Callable[..., torch.Tensor]


def to_x0(output: torch.Tensor, x: torch.Tensor, alpha: float, sigma: float, prediction_type: str) -> torch.Tensor:
    """x0 estimate from a raw network output at state x = alpha x0 + sigma eps (facts §2)."""
    check_prediction_type(prediction_type)
    if prediction_type == "sample":
        return output
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
    The conditioning tensors are concatenated once here, not at every step, and each of them has
    its own memo, so the network's text-only work (attention contexts) runs once per request.

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
    ) -> None:
        self.network = network
        self.scale = float(scale)
        self.batched = batched
        self.dtype = dtype
        self.motion_mask = motion_mask
        length = max(text.shape[1], null_text.shape[1])
        self.cond = _pad_tokens(text, text_mask, length)
        self.uncond = _pad_tokens(null_text, null_mask, length)
        if batched and self.scale != 1.0:
            self.both = (
                torch.cat([self.cond[0], self.uncond[0]]),
                torch.cat([self.cond[1], self.uncond[1]]),
                torch.cat([motion_mask, motion_mask]),
            )
        self.memos = {"cond": {}, "uncond": {}, "both": {}}

    def plan(self, timesteps) -> None:
        """The sampler's timesteps for this request, in order (the samplers call this first)."""
        for memo in self.memos.values():
            memo[PLANNED_TIMESTEPS] = tuple(int(t) for t in timesteps)

    def _run(self, x, t, text, text_mask, motion_mask, memo: dict) -> torch.Tensor:
        with precision_context(x.device, self.dtype):
            out = self.network(x, t, text, text_mask, motion_mask, memo=memo)
        return out.float()

    def __call__(self, x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        if self.scale == 1.0:  # guidance off: the conditional pass alone
            return self._run(x, t, *self.cond, self.motion_mask, self.memos["cond"])
        if self.batched:
            out = self._run(torch.cat([x, x]), torch.cat([t, t]), *self.both, self.memos["both"])
            cond, uncond = out.chunk(2)
        else:
            cond = self._run(x, t, *self.cond, self.motion_mask, self.memos["cond"])
            uncond = self._run(x, t, *self.uncond, self.motion_mask, self.memos["uncond"])
        return uncond + self.scale * (cond - uncond)
