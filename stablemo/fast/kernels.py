"""The compiled CPU kernels of `cpu_kernels.cpp` (the networks) and `motion_kernels.cpp` (the
finishing step), each compiled on first use (torch.utils.cpp_extension).

Compilation needs a C++ compiler and ninja and takes ~30 s once; the library is cached under
torch's extensions folder (TORCH_EXTENSIONS_DIR), in a folder named for this CPU's instruction set
since it is built with -march=native. Where it cannot be built, `kernels()` returns None after one
warning and the callers keep their PyTorch path. STABLEMO_FUSED_KERNELS=0 turns it off (A/B runs).
"""

from __future__ import annotations

import functools
import hashlib
import os
import platform
import shutil
import sys
import time
import warnings
from pathlib import Path

SOURCE = Path(__file__).with_name("cpu_kernels.cpp")
FLAGS = ["-O3", "-march=native", "-ffast-math", "-fopenmp"]  # fast-math: glibc's vectorised expf
MOTION_SOURCE = Path(__file__).with_name("motion_kernels.cpp")
# the finishing step's kernel repeats its PyTorch twin's arithmetic: no contraction into FMAs, no reordering
MOTION_FLAGS = ["-O3", "-march=native", "-ffp-contract=off", "-fopenmp"]


def enabled() -> bool:
    return os.environ.get("STABLEMO_FUSED_KERNELS", "1") != "0"


def _cpu_tag() -> str:
    """A short hash of the CPU's feature flags: a -march=native build must not run on another CPU."""
    try:
        flags = next((line for line in Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("flags")), "")
    except OSError:
        flags = ""
    return hashlib.sha1(f"{platform.machine()} {flags}".encode()).hexdigest()[:10]


# A build takes ~30 s. torch's builder guards its folder with a `lock` file and waits for it to go
# away; a build killed mid-way (Ctrl-C, a timeout) leaves the file behind, and every later process
# then waits forever. A lock far older than any build is removed.
STALE_LOCK_SECONDS = 600


def clear_stale_lock(build_dir: Path, max_age: float = STALE_LOCK_SECONDS) -> bool:
    """Remove `build_dir/lock` if it is older than `max_age` seconds; True if one was removed."""
    lock = build_dir / "lock"
    try:
        age = time.time() - lock.stat().st_mtime
    except FileNotFoundError:
        return False
    if age <= max_age:
        return False
    lock.unlink(missing_ok=True)
    warnings.warn(f"stablemo: removed a stale build lock ({lock}, {age / 60:.0f} min old) left by an "
                  "interrupted build of the fused CPU kernels", stacklevel=2)
    return True


@functools.lru_cache(maxsize=None)
def kernels():
    """The compiled module (with `frame_norm_act`), or None where it cannot be built or is turned off."""
    return _build("stablemo_cpu_kernels", SOURCE, FLAGS)


@functools.lru_cache(maxsize=None)
def motion_kernels():
    """The finishing step's compiled module (with `body_columns`), or None as kernels()."""
    return _build("stablemo_motion_kernels", MOTION_SOURCE, MOTION_FLAGS)


def _build(stem: str, source: Path, flags: list[str]):
    if not enabled() or sys.platform != "linux":
        return None
    from torch.utils.cpp_extension import load

    if shutil.which("ninja") is None:  # the `ninja` wheel's binary, when its venv is not on PATH
        try:
            import ninja

            os.environ["PATH"] = ninja.BIN_DIR + os.pathsep + os.environ.get("PATH", "")
        except ImportError:
            pass
    name = f"{stem}_{_cpu_tag()}"
    try:
        from torch.utils.cpp_extension import _get_build_directory

        build_dir = Path(_get_build_directory(name, False))
        clear_stale_lock(build_dir)
        if not (build_dir / f"{name}.so").is_file():
            print(f"stablemo: compiling fused CPU kernels (once, ~30 s): {name}", file=sys.stderr)
    except Exception:  # the notice is a courtesy; the build below reports real problems
        pass
    try:
        return load(name, [str(source)], extra_cflags=flags, extra_ldflags=["-fopenmp"], verbose=False)
    except Exception as err:  # no compiler, no ninja, unsupported platform: keep the PyTorch path
        warnings.warn(f"stablemo: fused CPU kernels unavailable, using PyTorch ops instead ({err})", stacklevel=2)
        return None
