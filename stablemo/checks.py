"""Where and in what precision the network runs: devices and dtypes from user arguments, checked
with one clear error each (a device this torch build lacks, fp16 on a CPU, an unknown name).
"""

from __future__ import annotations

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
