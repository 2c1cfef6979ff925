"""`stablemo footskate IN.npy --out OUT.npy`: remove foot skating from a motion file.

Joints in (T, J, 3) or (B, T, J, 3) -> joints out. Features in (T, D) or (B, T, D) -> features
out, all groups re-derived from the corrected positions; that conversion is StableMo's, so it
comes in as a `codec` (stablemo.skating.cleanup passes it) and this package stays torch-only.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Protocol

import numpy as np
import torch

from footskate.atomicio import output_file_problem, same_output
from footskate.cleanup import CleanupConfig, cleanup
from footskate.errors import FootskateError, one_line
from footskate.npyio import load_npy, save_npy
from footskate.skeletons import TOPOLOGIES, Topology
from footskate.vgrf import resolve_vgrf


class FeatureCodec(Protocol):
    """Features <-> joints for one skeleton (supplied by StableMo)."""

    feature_dim: int

    def to_joints(self, features: np.ndarray) -> np.ndarray: ...             # (B, T, D) -> (B, T, J, 3)

    def to_features(self, joints: np.ndarray, lengths: np.ndarray) -> np.ndarray: ...  # (B, T, J, 3) -> (B, T, D)


def load_motion(path: Path) -> np.ndarray:
    arr = load_npy(path)
    if not np.issubdtype(arr.dtype, np.floating):
        raise FootskateError(f"{path}: expected floating-point positions or features, found dtype {arr.dtype}")
    bad = int(np.size(arr) - np.count_nonzero(np.isfinite(arr)))
    if bad:
        raise FootskateError(f"{path}: {bad} NaN/Inf value(s) in the motion; nothing to clean")
    return arr


def motion_kind(arr: np.ndarray, topo: Topology, source: str, codec: FeatureCodec | None) -> bool:
    """True for joints, False for features; a wrong shape is named in the skeleton's own terms."""
    if arr.shape[-1] == 3 and arr.ndim in (3, 4):
        # (…, J, 3) is joints: no skeleton has 3 feature channels, so a J mismatch is a joint count
        if arr.shape[-2] != topo.num_joints:
            raise FootskateError(f"{source}: joints: {arr.shape[-2]} given, {topo.num_joints} expected for "
                                 f"skeleton {topo.name} (shape {arr.shape}; --skeleton picks the skeleton)")
        return True
    if arr.ndim not in (2, 3):
        raise FootskateError(f"{source}: expected joints (T, {topo.num_joints}, 3) or features (T, D), got {arr.shape}")
    if codec is None:
        raise FootskateError(f"{source}: feature input needs StableMo (run `stablemo footskate`)")
    if arr.shape[-1] != codec.feature_dim:
        raise FootskateError(f"{source}: {arr.shape[-1]} feature channels, skeleton {topo.name} has {codec.feature_dim}")
    return False


BODY_SPAN_M = (0.2, 5.0)  # metres: the largest extent of a person's joints in any frame, lying or standing


def check_units(joints: np.ndarray, lengths: np.ndarray, topo: Topology, source: str) -> None:
    """Joints in the wrong unit (KIT-ML is millimetres, HumanML3D metres) would be cleaned with every
    threshold off by 1000: named here, before the compute, instead of a silently wrong file."""
    per_frame = np.linalg.norm(joints.max(2) - joints.min(2), axis=-1)            # (B, T) extent of the body
    valid = np.arange(joints.shape[1])[None] < lengths[:, None]
    span = float(np.where(valid, per_frame, 0.0).max()) * topo.unit
    if not BODY_SPAN_M[0] <= span <= BODY_SPAN_M[1]:
        unit = "millimetres" if topo.unit == 0.001 else "metres" if topo.unit == 1.0 else f"units of {topo.unit} m"
        raise FootskateError(f"{source}: the body spans {span:.3g} m read as {unit}, the unit of {topo.name} joints "
                             f"(a person spans {BODY_SPAN_M[0]}-{BODY_SPAN_M[1]} m); convert the joints or pick "
                             f"--skeleton")


def save_finite(path: Path, array: np.ndarray, flag: str) -> None:
    """Never write a non-finite motion: a diverged cleanup is an error, not a file."""
    if not np.isfinite(array).all():
        raise FootskateError(f"{flag}: the cleanup produced NaN/Inf values; nothing written to {path}")
    save_npy(path, array)


def lengths_of(batch: np.ndarray) -> np.ndarray:
    """Valid length per sample: trailing all-zero frames are padding (as StableMo writes batches)."""
    flat = batch.reshape(batch.shape[0], batch.shape[1], -1)
    nonzero = np.abs(flat).sum(-1) > 0
    last = np.where(nonzero.any(1), batch.shape[1] - np.argmax(nonzero[:, ::-1], axis=1), batch.shape[1])
    return np.maximum(last, 2)


def run(args: argparse.Namespace, codec: FeatureCodec | None) -> dict:
    torch.manual_seed(args.seed)
    topo = TOPOLOGIES[args.skeleton]
    arr = load_motion(Path(args.input))
    is_joints = motion_kind(arr, topo, args.input, codec)
    single = arr.ndim == (3 if is_joints else 2)
    batch = arr[None] if single else arr
    if batch.shape[1] < 2:
        raise FootskateError(f"{args.input}: need at least 2 frames")
    lengths = lengths_of(batch)
    joints = batch if is_joints else codec.to_joints(batch.astype(np.float32))
    if is_joints:
        check_units(joints, lengths, topo, args.input)
    vgrf = resolve_vgrf(args.weights, topo)
    if args.contacts in ("vgrf", "gated") and vgrf is None:
        raise FootskateError(f"--contacts {args.contacts}: no vGRF network for skeleton {topo.name} (give --weights)")
    config = CleanupConfig(iters=args.iters, fps=args.fps or topo.fps, up_axis=topo.up_axis, detect=args.contacts)
    metres = torch.from_numpy(np.ascontiguousarray(joints, dtype=np.float32)) * topo.unit
    res = cleanup(metres, topo.parents, topo.feet, lengths=torch.from_numpy(lengths), vgrf=vgrf, config=config)
    out_joints = (res.joints / topo.unit).numpy()
    if is_joints:
        out = out_joints.astype(arr.dtype)
    else:
        out = codec.to_features(out_joints, lengths).astype(arr.dtype)
    if args.joints_out:  # both checked before either is written
        save_finite(Path(args.joints_out), out_joints[0] if single else out_joints, "--joints-out")
    save_finite(Path(args.out), out[0] if single else out, "--out")
    info = {"samples": batch.shape[0], "ranges": res.info["ranges"], "anchored": res.info["anchored_ranges"],
            "seconds": res.info["seconds"],
            "contacts": "heuristic" if vgrf is None or args.contacts == "heuristic" else
                        "vgrf" if args.contacts == "vgrf" else "gated"}
    print(f"footskate: {info['samples']} motion(s), {info['anchored']}/{info['ranges']} contact ranges anchored "
          f"({info['contacts']} contacts), {info['seconds']:.2f}s -> {args.out}")
    return info


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="stablemo footskate", description="remove foot skating from a motion file")
    p.add_argument("input", help="joints (T,J,3)/(B,T,J,3) or features (T,D)/(B,T,D) .npy; zero frames at the end = padding")
    p.add_argument("--out", required=True, help="output .npy (same kind as the input)")
    p.add_argument("--joints-out", default=None, help="also write the corrected joint positions here")
    p.add_argument("--weights", default=None,
                   help="vGRF weights: our .safetensors or your UnderPressure pretrained.tar (default: the shipped "
                        "V22, or V21 for --skeleton kit)")
    p.add_argument("--contacts", choices=["auto", "gated", "vgrf", "heuristic"], default=CleanupConfig.detect,
                   help="contact detection: gated (the vGRF network's contacts where the joint is near its lowest "
                        "point), vgrf (the network alone), heuristic (height and speed), or auto (gated when there "
                        "is a network); the network's vGRF term is used either way")
    p.add_argument("--iters", type=int, default=CleanupConfig.iters)
    p.add_argument("--skeleton", choices=["humanml3d", "kit"], default="humanml3d")
    p.add_argument("--fps", type=float, default=None, help="frame rate (default: the skeleton's)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=0,
                   help="torch CPU threads (0: torch's default); 1 is fastest on a busy machine")
    return p


# flag -> (low, high) inclusive; argparse's float() accepts "nan" and "inf", so finiteness is checked too
RANGES = {"iters": (0, 1_000_000), "fps": (1e-3, 10_000.0), "seed": (0, 2**63 - 1), "threads": (0, 4096)}


def check_number(flag: str, value, low, high) -> None:
    if value is None:
        return
    if not math.isfinite(value) or not low <= value <= high:
        raise FootskateError(f"{flag}: must be a finite number in [{low}, {high}], got {value}")


def check_arguments(args: argparse.Namespace) -> None:
    """Numbers in range and outputs writable, before any file is read or any compute starts."""
    for name, (low, high) in RANGES.items():
        check_number(f"--{name}", getattr(args, name), low, high)
    for flag, path in (("--out", args.out), ("--joints-out", args.joints_out)):
        problem = output_file_problem(path) if path else None
        if problem:
            raise FootskateError(f"{flag}: {problem}")
    if args.joints_out and same_output(args.out, args.joints_out):  # the second write would replace the first
        raise FootskateError(f"--joints-out: {args.joints_out} is the same file as --out {args.out}; give two paths")


def main(argv: list[str] | None = None, codec_factory=None) -> int:
    """Entry point; `codec_factory(skeleton_name) -> FeatureCodec` enables feature files."""
    args = parser().parse_args(argv)
    check_arguments(args)
    if args.threads:
        torch.set_num_threads(args.threads)
    codec = codec_factory(args.skeleton) if codec_factory is not None else None
    run(args, codec)
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except FootskateError as err:
        print(f"footskate: error: {one_line(str(err))}", file=sys.stderr)
        sys.exit(2)
