"""The small checks every entry point shares, each one clear error naming the argument or field:
numbers (finite, in range, whole, a seed), and where and in what precision the network runs
(devices and dtypes from user arguments: a device this torch build lacks, fp16 on a CPU, an
unknown name). The CLI, the Python API and the server call these, never their own copies.
"""

from __future__ import annotations

import math
import numbers

import torch

from stablemo.errors import StableMoError

DTYPES = {"fp32": torch.float32, "float32": torch.float32, "bf16": torch.bfloat16, "bfloat16": torch.bfloat16,
          "fp16": torch.float16, "float16": torch.float16}


def resolve_dtype(dtype, device: torch.device) -> torch.dtype:
    """Network precision: default fp16 on CUDA, fp32 on CPU; fp16 is refused on CPU (slow, inexact)."""
    if dtype is None:
        return torch.float16 if device.type == "cuda" else torch.float32
    if isinstance(dtype, str):
        if dtype not in DTYPES:
            raise StableMoError(f"dtype: expected one of {sorted(DTYPES)}, got {dtype!r}")
        dtype = DTYPES[dtype]
    if dtype not in (torch.float32, torch.bfloat16, torch.float16):
        raise StableMoError(f"dtype: expected float32, bfloat16 or float16, got {dtype}")
    if dtype == torch.float16 and device.type == "cpu":
        raise StableMoError("dtype: float16 is for CUDA; use bf16 or fp32 on the CPU")
    return dtype


def resolve_device(device) -> torch.device:
    """The device to run on (default: cuda if available); one clear error for one that is not here."""
    if device is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        raise StableMoError(f"device: unknown device {device!r}; use cpu or cuda") from None
    available = ["cpu"] + (["cuda"] if torch.cuda.is_available() else []) + \
        (["mps"] if getattr(torch.backends, "mps", None) and torch.backends.mps.is_available() else [])
    if dev.type not in available:
        raise StableMoError(f"device: {dev.type} is not available in this torch build "
                            f"(available: {', '.join(available)})")
    if dev.type == "cuda" and dev.index is not None and dev.index >= torch.cuda.device_count():
        raise StableMoError(f"device: {device} does not exist ({torch.cuda.device_count()} CUDA device(s))")
    return dev


def check_finite(name: str, value, low: float | None = None, high: float | None = None, strict: bool = False) -> float:
    """A finite number within [low, high] (low excluded when strict), else one clear error."""
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise StableMoError(f"{name}: expected a number, got {value!r}") from None
    if not math.isfinite(value):
        raise StableMoError(f"{name}: must be a finite number, got {value}")
    if low is not None and (value < low or (strict and value == low)):
        raise StableMoError(f"{name}: must be {'>' if strict else '>='} {low:g}, got {value:g}")
    if high is not None and value > high:
        raise StableMoError(f"{name}: must be <= {high:g}, got {value:g}")
    return value


def check_weight(name: str, value) -> float:
    """A loss weight or noise scale from a config: an int or float (not a bool, not a string), finite
    and >= 0, else one clear error. Stricter than check_finite, which reads any float()-able value."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise StableMoError(f"{name}: must be a finite number >= 0, got {value!r}")
    return float(value)


def check_positive_int(name: str, value) -> int:
    if isinstance(value, bool) or not (isinstance(value, numbers.Integral)
                                       or (isinstance(value, float) and value.is_integer())):
        raise StableMoError(f"{name}: expected a whole number, got {value!r}")
    if int(value) < 1:
        raise StableMoError(f"{name}: must be >= 1, got {value}")
    return int(value)


MAX_SEED = 2**63 - 1  # torch generators take a 64-bit seed; sample i of a request uses seed + i


def check_seed(name: str, value, count: int = 1) -> int:
    """A whole-number seed in [0, 2^63 - 1 - (count - 1)], so that seed + i stays a valid seed."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise StableMoError(f"{name}: expected a whole number, got {value!r}")
    if not 0 <= int(value) <= MAX_SEED - (count - 1):
        raise StableMoError(f"{name}: must be in [0, {MAX_SEED - (count - 1)}], got {value}")
    return int(value)
