"""Vertical ground reaction force (vGRF) networks: UnderPressure's layout generalised to J joints.

One `nn.Sequential` whose module indices match UnderPressure's checkpoint keys (its `models.py`), so
a user's own `pretrained.tar` loads into `VGRFNet(23)` with `weights_only=True`. The same stack
with 3·J input channels is V22 (HumanML3D, y-up, 20 fps) or V21 (KIT).

Input (N, F, J, 3) global joint positions in metres; output (N, F, 2, 16): foot (0 left, 1 right)
× 16 insole cells, in body-weight units (Softplus, so never negative).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING

import torch
from torch import nn

from footskate.errors import FootskateError

if TYPE_CHECKING:
    from footskate.skeletons import Topology

ATTRIBUTION = (
    "UnderPressure is an InterDigital product. Its weights are used under InterDigital's "
    "limited evaluation licence (research only, no commercial use). Please cite: L. Mourot, "
    "L. Hoyet, F. Le Clerc, P. Hellier, \"UnderPressure: Deep Learning for Foot Contact "
    "Detection, Ground Reaction Force Estimation and Footskate Cleanup\", Computer Graphics "
    "Forum 41(8), 2022."
)

NUM_FEET = 2
NUM_CELLS = 16
DEFAULT_WEIGHTS = Path(__file__).with_name("weights") / "v22_synth.safetensors"
# the shipped network per skeleton (V21: KIT-ML, issue #22); a skeleton without one gets the rule
SHIPPED = {"humanml3d": DEFAULT_WEIGHTS, "kit": Path(__file__).with_name("weights") / "v21_synth.safetensors"}


class Transpose(nn.Module):
    """Swap two dims; parameter-free, so it keeps the Sequential's indices aligned with UP's keys."""

    def __init__(self, dim0: int, dim1: int):
        super().__init__()
        self.dim0, self.dim1 = dim0, dim1

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x.transpose(self.dim0, self.dim1)


def _fill_padding(x: torch.Tensor, lengths: torch.Tensor, dim: int) -> torch.Tensor:
    """Replace frames >= length by the last valid frame (replicate padding at each sample's own end)."""
    frames = x.shape[dim]
    idx = torch.arange(frames, device=x.device)
    idx = torch.minimum(idx[None, :], (lengths.to(x.device) - 1).clamp(min=0)[:, None])  # (N, F)
    shape = [1] * x.dim()
    shape[0], shape[dim] = idx.shape[0], frames
    idx = idx.view(shape).expand_as(x)
    return torch.gather(x, dim, idx)


class VGRFNet(nn.Module):
    """UnderPressure-style vGRF regressor for J joints (keys `net.<idx>.*`; see `state_dict_up`)."""

    def __init__(self, num_joints: int = 22, conv_channels=(128, 128, 256, 256), hidden: int = 256,
                 kernel_size: int = 7, dropout: float = 0.2):
        super().__init__()
        self.num_joints = int(num_joints)
        self.config = {"num_joints": self.num_joints, "conv_channels": list(conv_channels),
                       "hidden": int(hidden), "kernel_size": int(kernel_size), "dropout": float(dropout)}
        layers: list[nn.Module] = [nn.Flatten(-2), Transpose(-2, -1)]          # 0, 1: (N, 3J, F)
        c_in = 3 * self.num_joints
        for c_out in conv_channels:                                           # 2..13
            layers += [nn.Dropout(0.0),
                       nn.Conv1d(c_in, c_out, kernel_size, padding=kernel_size // 2, padding_mode="replicate"),
                       nn.ELU()]
            c_in = c_out
        layers.append(Transpose(-2, -1))                                      # 14: (N, F, C)
        for _ in range(2):                                                    # 15..20
            layers += [nn.Dropout(dropout), nn.Linear(c_in, hidden), nn.ELU()]
            c_in = hidden
        layers += [nn.Dropout(dropout), nn.Linear(c_in, NUM_FEET * NUM_CELLS, bias=False),  # 21, 22
                   nn.Unflatten(-1, (NUM_FEET, NUM_CELLS)), nn.Softplus()]    # 23, 24
        self.net = nn.Sequential(*layers)

    @property
    def receptive_field(self) -> int:
        k = self.config["kernel_size"]
        return 1 + (k - 1) * len(self.config["conv_channels"])

    def forward(self, positions: torch.Tensor, lengths: torch.Tensor | None = None) -> torch.Tensor:
        """positions (N, F, J, 3) -> forces (N, F, 2, 16).

        With `lengths`, frames past each sample's length are replaced by its last valid frame
        before every convolution, so each sample's valid output equals what it would be alone
        (the convolutions' replicate padding then happens at the sample's own end).
        """
        if positions.shape[-2:] != (self.num_joints, 3):
            raise FootskateError(f"vGRF network expects (..., F, {self.num_joints}, 3) positions, "
                                 f"got {tuple(positions.shape)}")
        lead = positions.shape[:-3]
        x = positions.reshape(-1, *positions.shape[-3:])
        if lengths is not None:
            lengths = lengths.reshape(-1)
            x = _fill_padding(x, lengths, dim=1)
        for module in self.net:
            x = module(x)
            if lengths is not None and isinstance(module, nn.ELU) and x.dim() == 3 and x.shape[-1] == positions.shape[-3]:
                x = _fill_padding(x, lengths, dim=2)  # conv activations are (N, C, F)
        return x.reshape(*lead, *x.shape[-3:])

    def state_dict_up(self) -> dict[str, torch.Tensor]:
        """State dict with UnderPressure's key names (`3.weight`, ... without the `net.` prefix)."""
        return {k.removeprefix("net."): v for k, v in self.net.state_dict().items()}


def msle(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Mean squared logarithmic error, elementwise (no reduction): (log1p(a) - log1p(b))²."""
    return (torch.log1p(a) - torch.log1p(b)).square()


def load_underpressure(path: str | os.PathLike, map_location: str = "cpu", quiet: bool = False) -> VGRFNet:
    """Load a user-supplied UnderPressure checkpoint (`pretrained.tar`) as V23, weights only.

    StableMo never ships UnderPressure's code or weights; the user points to their own copy.
    """
    path = Path(path)
    if not path.is_file():
        raise FootskateError(f"{path}: UnderPressure checkpoint not found")
    try:
        obj = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as err:  # pickles with code objects, truncated zips, ...
        raise FootskateError(f"{path}: not a weights-only torch checkpoint ({err})") from None
    state = obj.get("model", obj) if isinstance(obj, dict) else None
    if not isinstance(state, dict) or "3.weight" not in state:
        raise FootskateError(f"{path}: expected {{'model': state_dict}} with UnderPressure keys ('3.weight', ...)")
    in_channels = state["3.weight"].shape[1]
    if in_channels % 3:
        raise FootskateError(f"{path}: first convolution has {in_channels} input channels, not 3·J")
    model = VGRFNet(in_channels // 3)
    _load_up_keys(model, state, path)
    if not quiet:
        print(ATTRIBUTION)
    return model.eval()


def _load_up_keys(model: VGRFNet, state: dict, path) -> None:
    expected = model.state_dict_up()
    missing = sorted(set(expected) - set(state))
    unexpected = sorted(set(state) - set(expected))
    if missing or unexpected:
        raise FootskateError(f"{path}: state dict keys differ (missing {missing}, unexpected {unexpected})")
    for key, ref in expected.items():
        if tuple(state[key].shape) != tuple(ref.shape):
            raise FootskateError(f"{path}: {key} has shape {tuple(state[key].shape)}, expected {tuple(ref.shape)}")
    model.net.load_state_dict({k: v.float() for k, v in state.items()})


def save_vgrf(model: VGRFNet, path: str | os.PathLike, metadata: dict | None = None) -> None:
    """Write weights as safetensors (UP key names) with the architecture config in the header; atomic."""
    from safetensors.torch import save as safetensors_bytes

    from footskate.atomicio import write_bytes

    meta = {"config": json.dumps(model.config), **{k: json.dumps(v) for k, v in (metadata or {}).items()}}
    tensors = {k: v.detach().float().contiguous().cpu() for k, v in model.state_dict_up().items()}
    write_bytes(path, safetensors_bytes(tensors, metadata=meta))


def load_vgrf(path: str | os.PathLike | None = None, map_location: str = "cpu", quiet: bool = False) -> VGRFNet:
    """Load a vGRF network: our safetensors (default: the shipped synthetic V22) or a UP `.tar`."""
    path = Path(path) if path is not None else DEFAULT_WEIGHTS
    if path.suffix != ".safetensors":
        return load_underpressure(path, map_location, quiet=quiet)
    if not path.is_file():
        raise FootskateError(f"{path}: vGRF weights not found")
    from safetensors import safe_open

    try:
        with safe_open(str(path), framework="pt", device=map_location) as f:
            meta = f.metadata() or {}
            state = {k: f.get_tensor(k) for k in f.keys()}
        config = json.loads(meta["config"])
        model = VGRFNet(**config)
    except Exception as err:
        raise FootskateError(f"{path}: not a footskate vGRF safetensors file ({err})") from None
    _load_up_keys(model, state, path)
    model.metadata = {k: json.loads(v) for k, v in meta.items() if k != "config"}
    return model.eval()


def resolve_vgrf(weights: str | None, topo: "Topology") -> VGRFNet | torch.nn.Module | None:
    """The vGRF model for `topo`: user weights (ours, or a UnderPressure V23 behind the retargeting
    adapter for HumanML3D), else the shipped V22 for HumanML3D / V21 for KIT-ML, else None."""
    if weights is None:
        shipped = SHIPPED.get(topo.name)
        if shipped is None or not shipped.is_file():
            return None
        return load_vgrf(shipped)
    model = load_vgrf(weights)
    if model.num_joints == 23 and topo.num_joints == 22:
        from footskate.retarget import UPAdapter
        return UPAdapter(model).eval()
    if model.num_joints != topo.num_joints:
        raise FootskateError(f"{weights}: vGRF network for {model.num_joints} joints, motion has {topo.num_joints}")
    return model
