"""The hook factory: the sample hooks (stablemo.diffusion.hooks) a request asks for by options."""

from __future__ import annotations

from stablemo.diffusion.hooks import SampleHook


def make_hooks(pipeline, *, footskate: bool = False, footskate_weights=None) -> list[SampleHook]:
    """The hooks a request asks for by options (the CLI flags of `generate` and `evaluate`, and the
    Python API), in the order they apply. A hook with other settings (steps, iterations) is built
    directly, e.g. `stablemo.skating.hook.FootskateHook(pipe, steps=(-2, -1))`."""
    from stablemo.skating.cleanup import check_footskate_options

    check_footskate_options(footskate, footskate_weights)  # weights without the hook: an error, not ignored
    hooks: list[SampleHook] = []
    if footskate:
        from stablemo.skating.hook import FootskateHook

        hooks.append(FootskateHook(pipeline, weights=footskate_weights))
    return hooks
