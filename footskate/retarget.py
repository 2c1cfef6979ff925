"""HumanML3D (22 joints, y-up, 20 fps) -> UnderPressure's 23-joint skeleton (z-up, 100 Hz), and
the distillation of a V22 from a user's V23 (StableMoFusion Eq. 5) as a command.

The retargeting is a fixed, differentiable map, so V23 can also stand in for V22 inside the
cleanup (`UPAdapter`): joint correspondence (facts §4; UP's spine_4 is the midpoint of spine_3 and
the neck), (x, y, z) -> (x, -z, y), a per-sequence scale from the leg length, a height offset that
puts the lowest toe at UP's toe height, linear resampling 20 -> 100 Hz, and back to 20 Hz by
taking every 5th output frame.

    python -m footskate.retarget convert IN.npy --out OUT.npy          # joints -> UP23 joints at 100 Hz
    python -m footskate.retarget distill --v23 pretrained.tar --data HUMANML3D_DIR --out v22.safetensors

Distilled weights derive from UnderPressure's and fall under its licence: keep them to yourself.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch
from torch import nn

from footskate.errors import FootskateError
from footskate.npyio import load_npy, save_npy
from footskate.vgrf import ATTRIBUTION, VGRFNet, load_underpressure

# HumanML3D joint index -> UnderPressure joint index (UP's 4 = spine_4 has no counterpart).
HML_TO_UP = (0, 19, 15, 1, 20, 16, 2, 21, 17, 3, 22, 18, 5, 11, 7, 6, 12, 8, 13, 9, 14, 10)
UP_LEG = 0.84       # m, pelvis height minus ankle height of UP's rest skeleton (0.93 - 0.09)
UP_TOE_HEIGHT = 0.015
UP_FPS, HML_FPS = 100.0, 20.0


def _valid(lengths: torch.Tensor | None, b: int, t: int, device) -> torch.Tensor:
    if lengths is None:
        return torch.ones(b, t, dtype=torch.bool, device=device)
    return torch.arange(t, device=device)[None, :] < lengths.to(device)[:, None]


def to_up_skeleton(joints: torch.Tensor, lengths: torch.Tensor | None = None) -> torch.Tensor:
    """(B, T, 22, 3) HumanML3D y-up metres -> (B, T, 23, 3) UP z-up metres, same frame rate."""
    if joints.shape[-2:] != (22, 3):
        raise FootskateError(f"joints: expected (..., 22, 3) HumanML3D positions, got {tuple(joints.shape)}")
    b, t = joints.shape[:2]
    valid = _valid(lengths, b, t, joints.device).to(joints.dtype)
    count = valid.sum(1).clamp(min=1)
    leg = ((joints[:, :, [4, 5]] - joints[:, :, [1, 2]]).norm(dim=-1)
           + (joints[:, :, [7, 8]] - joints[:, :, [4, 5]]).norm(dim=-1)).mean(-1)        # (B, T)
    scale = UP_LEG / ((leg * valid).sum(1) / count).clamp(min=1e-3)                     # (B,)
    toe_y = torch.where(valid.bool(), joints[:, :, [10, 11], 1].amin(-1), torch.full_like(leg, float("inf")))
    lift = UP_TOE_HEIGHT - scale * toe_y.amin(1)                                         # (B,)
    zup = torch.stack([joints[..., 0], -joints[..., 2], joints[..., 1]], -1) * scale[:, None, None, None]
    zup = zup + torch.stack([torch.zeros_like(lift), torch.zeros_like(lift), lift], -1)[:, None, None]
    up = zup.new_zeros(b, t, 23, 3)
    up[:, :, list(HML_TO_UP)] = zup
    up[:, :, 4] = 0.5 * (up[:, :, 3] + up[:, :, 5])
    return up


def resample(x: torch.Tensor, factor: int, lengths: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Linear upsampling along dim 1 by an integer factor: T frames -> (T-1)·factor + 1."""
    b, t = x.shape[:2]
    lengths = lengths if lengths is not None else torch.full((b,), t, dtype=torch.long)
    pos = torch.arange((t - 1) * factor + 1, device=x.device, dtype=x.dtype) / factor
    lo = pos.floor().long().clamp(max=t - 1)
    hi = (lo + 1).clamp(max=t - 1)
    w = (pos - lo.to(x.dtype)).view(1, -1, *([1] * (x.dim() - 2)))
    return x[:, lo] * (1 - w) + x[:, hi] * w, (lengths - 1) * factor + 1


class UPAdapter(nn.Module):
    """A V23 that takes HumanML3D joints at 20 fps: retarget, 100 Hz, V23, back to 20 fps."""

    def __init__(self, v23: VGRFNet):
        super().__init__()
        if v23.num_joints != 23:
            raise FootskateError("UPAdapter needs a 23-joint (UnderPressure) vGRF network")
        self.v23 = v23
        self.num_joints = 22
        self.factor = int(UP_FPS / HML_FPS)

    def forward(self, joints: torch.Tensor, lengths: torch.Tensor | None = None) -> torch.Tensor:
        up, up_lengths = resample(to_up_skeleton(joints, lengths), self.factor, lengths)
        forces = self.v23(up, up_lengths if lengths is not None else None)
        return forces[:, :: self.factor]


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
    p = argparse.ArgumentParser(prog="python -m footskate.retarget", description=__doc__.splitlines()[0])
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
        print(f"footskate.retarget: error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
