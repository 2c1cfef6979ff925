"""The hook factory: the sample hooks (stablemo.diffusion.hooks) a request asks for by options."""

from __future__ import annotations

from typing import Sequence

from stablemo.diffusion.hooks import SampleHook


def make_hooks(pipeline, *, footskate: bool = False, footskate_weights=None, footskate_iters: int | None = None,
               footskate_steps: Sequence[int] | None = None) -> list[SampleHook]:
    """The hooks a request asks for by options (the CLI flags of `generate` and `evaluate`, and the
    Python API), in the order they apply."""
    from stablemo.skating.cleanup import check_footskate_options

    check_footskate_options(footskate, footskate_weights)  # weights without the hook: an error, not ignored
    hooks: list[SampleHook] = []
    if footskate:
        from stablemo.skating.hook import DEFAULT_HOOK_STEPS, FootskateHook

        hooks.append(FootskateHook(pipeline, weights=footskate_weights, iters=footskate_iters,
                                   steps=DEFAULT_HOOK_STEPS if footskate_steps is None else footskate_steps))
    return hooks
