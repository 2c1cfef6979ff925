"""Denoisers behind one interface.

Every denoiser maps ``forward(x (B,T,D), t (B,), text (B,L,C), text_mask (B,L) bool,
motion_mask (B,T) bool) -> (B,T,D)``, exposes ``length_multiple`` (T must be a multiple of it),
and is exactly padding invariant on valid frames. Build one by name, as YAML configs do:
``build_denoiser("unet", input_dim=263, text_dim=256, cross_attention=True, norm="frame")``.
"""

from __future__ import annotations

import importlib
import inspect

from torch import nn

from stablemo.errors import StableMoError

# name -> (module, class): imports stay lazy so building one variant does not load the others
DENOISERS: dict[str, tuple[str, str]] = {
    "unet": ("stablemo.nets.unet", "CondUNet1D"),
    "dit": ("stablemo.nets.dit", "DiT"),
    "retnet": ("stablemo.nets.retnet", "RetNet"),
}


def denoiser_class(name: str) -> type[nn.Module]:
    if name not in DENOISERS:
        raise StableMoError(f"denoiser name: unknown {name!r}; choose from {sorted(DENOISERS)}")
    module, cls = DENOISERS[name]
    return getattr(importlib.import_module(module), cls)


def build_denoiser(name: str, **config) -> nn.Module:
    """Build a denoiser by name; unknown keyword arguments are reported by name."""
    cls = denoiser_class(name)
    accepted = set(inspect.signature(cls.__init__).parameters) - {"self"}
    unknown = sorted(set(config) - accepted)
    if unknown:
        raise StableMoError(f"denoiser {name!r}: unknown option(s) {unknown}; accepted: {sorted(accepted)}")
    if "input_dim" not in config:
        raise StableMoError(f"denoiser {name!r}: input_dim is required (feature width, e.g. 263)")
    try:
        return cls(**config)
    except (TypeError, ValueError, RuntimeError) as err:
        # a value of the wrong type or sign ("base_channels: abc", "channel_mults: 5", -4 channels)
        # fails deep inside torch: the option set is what the user can fix
        raise StableMoError(f"denoiser {name!r}: these options do not build a network "
                            f"({type(err).__name__}: {err}); options: {config}") from None


__all__ = ["DENOISERS", "build_denoiser", "denoiser_class"]
