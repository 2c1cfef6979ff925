"""Sample hooks: one interface for everything that edits a sample while it is being denoised.

At each step the sampler predicts the clean motion x0; the pipeline then hands a `StepState` to
every hook of the request that is active at that step, in the request's order, each hook seeing
the previous one's result, and the sampler continues from the edited x0. Foot-skate correction
(StableMoFusion*, stablemo.skating.hook) is such a hook; so is joint control (stablemo.control.guidance, added by the
pipeline for `Request.control`, after the request's own hooks). In-painting edits x_t as well as
x0, so it is the samplers' `inpaint` argument rather than a hook (stablemo.diffusion.inpainting).

Hooks work in torch on the sample's device, in the model's normalised feature space, and receive
the motion mask and lengths with the sample.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Protocol, Sequence

import torch


@dataclass
class StepState:
    """step: index in the sampler's loop (0-based) of `steps`; t: its model timestep;
    x0: (B, T, D) normalised float32 prediction; mask: (B, T) bool; lengths: valid frames per sample."""

    step: int
    steps: int
    t: int
    x0: torch.Tensor
    mask: torch.Tensor
    lengths: list[int]


class SampleHook(Protocol):
    def active(self, step: int, steps: int) -> bool:
        """Whether the hook runs at this step of a `steps`-step loop."""

    def __call__(self, state: StepState) -> torch.Tensor | None:
        """The edited x0 (B, T, D), or None to leave it as it is."""


def resolve_steps(indices: Iterable[int], steps: int) -> set[int]:
    """Step indices, negative ones counted from the end (-1 = last); out-of-range ones dropped."""
    return {i + steps if i < 0 else i for i in indices} & set(range(steps))


class AtSteps:
    """Base for hooks that run at chosen step indices (None = every step; -1 = the last)."""

    def __init__(self, steps: Sequence[int] | None):
        self.steps = None if steps is None else tuple(int(s) for s in steps)

    def active(self, step: int, steps: int) -> bool:
        return self.steps is None or step in resolve_steps(self.steps, steps)


def apply_hooks(hooks: Sequence[SampleHook], state: StepState) -> torch.Tensor | None:
    """Run the active hooks in order on state.x0; the final x0, or None when none edited it."""
    edited = False
    for hook in hooks:
        if not hook.active(state.step, state.steps):
            continue
        with torch.enable_grad():  # a hook may optimise (foot-skate cleanup)
            out = hook(StepState(state.step, state.steps, state.t, state.x0.clone(), state.mask, state.lengths))
        if out is not None:
            state.x0, edited = out.to(state.x0.device, state.x0.dtype), True
    return state.x0 if edited else None


__all__ = ["AtSteps", "SampleHook", "StepState", "apply_hooks", "resolve_steps"]
