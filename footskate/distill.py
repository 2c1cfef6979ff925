"""The distillation of a V22 from a user's UnderPressure V23 (StableMoFusion Eq. 5), and the
retargeting as a command (footskate.retarget holds the map itself).

    python -m footskate.distill convert IN.npy --out OUT.npy          # joints -> UP23 joints at 100 Hz
    python -m footskate.distill distill --v23 pretrained.tar --data HUMANML3D_DIR --out v22.safetensors

Distilled weights derive from UnderPressure's and fall under its licence: keep them to yourself.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

from footskate.errors import FootskateError, one_line
from footskate.npyio import load_npy, save_npy
from footskate.retarget import HML_FPS, UP_FPS, UPAdapter, resample, to_up_skeleton
from footskate.vgrf import ATTRIBUTION, load_underpressure


def _load_joints(path: Path) -> np.ndarray:
    arr = load_npy(path)
    if arr.ndim not in (3, 4) or arr.shape[-2:] != (22, 3) or not np.isfinite(arr).all():
        raise FootskateError(f"{path}: expected finite HumanML3D joints (T, 22, 3) or (B, T, 22, 3), got {arr.shape}")
    return arr.astype(np.float32)


def distill(v23_path: str, data_dir: str, out: str, steps: int = 3000, seed: int = 0, width: str = "full",
            log=print) -> dict:
    """Eq. 5: regress a V22 onto V23(retarget(P)) on the joints of a dataset (MSLE, as StableMoFusion)."""
    from footskate.train import train

    v23 = load_underpressure(v23_path, quiet=True)
    log(ATTRIBUTION)
    teacher = UPAdapter(v23).eval()

    @torch.no_grad()
    def labels(joints: torch.Tensor, contacts: torch.Tensor | None) -> torch.Tensor:
        return teacher(joints[None])[0]

    return train(data_dir, out, steps=steps, width=width, seed=seed, label_fn=labels, log=log,
                 extra_meta={"teacher": "UnderPressure V23 (user-supplied; licence: research only)"})


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m footskate.distill", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("convert", help="HumanML3D joints (.npy) -> UnderPressure 23-joint skeleton at 100 Hz")
    c.add_argument("input")
    c.add_argument("--out", required=True)
    d = sub.add_parser("distill", help="train a V22 from a user's UnderPressure V23 (paper Eq. 5)")
    d.add_argument("--v23", required=True, help="path to your UnderPressure pretrained.tar")
    d.add_argument("--data", required=True, help="HumanML3D folder (new_joints/)")
    d.add_argument("--out", required=True)
    d.add_argument("--steps", type=int, default=3000)
    d.add_argument("--width", choices=["full", "half"], default="full")
    d.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    try:
        if args.cmd == "convert":
            joints = _load_joints(Path(args.input))
            single = joints.ndim == 3
            x = torch.from_numpy(joints[None] if single else joints)
            up, _ = resample(to_up_skeleton(x), int(UP_FPS / HML_FPS))
            save_npy(Path(args.out), (up[0] if single else up).numpy())
            print(f"wrote {args.out}: {tuple(up.shape[-3:])} UnderPressure joints, z-up, 100 Hz")
        else:
            distill(args.v23, args.data, args.out, args.steps, args.seed, args.width)
    except FootskateError as err:
        print(f"footskate.distill: error: {one_line(str(err))}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
