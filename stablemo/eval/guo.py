"""The published text–motion matching evaluator of Guo et al. (CVPR 2022), weight-compatible.

Module and parameter names follow the state-dict layout of `t2m/text_mot_match/model/finest.tar`
(Guo et al.'s `networks/modules.py`), so a user's checkpoint loads with `torch.load(weights_only=True)` and
`load_state_dict(strict=True)`. Inputs to `encode_motion` are features normalised with the
*evaluator's* statistics (not the model's), contact dims included (they are dropped here).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn
from torch.nn.utils.rnn import pack_padded_sequence

from stablemo.errors import StableMoError
from stablemo.io import load_npy

UNIT_LENGTH = 4  # the movement encoder downsamples time by 4


class MovementConvEncoder(nn.Module):
    """Two strided convolutions (4× temporal downsampling) and a per-step linear layer."""

    def __init__(self, input_size: int, hidden_size: int = 512, output_size: int = 512):
        super().__init__()
        self.main = nn.Sequential(
            nn.Conv1d(input_size, hidden_size, 4, 2, 1),
            nn.Dropout(0.2),
            nn.LeakyReLU(0.2),
            nn.Conv1d(hidden_size, output_size, 4, 2, 1),
            nn.Dropout(0.2),
            nn.LeakyReLU(0.2),
        )
        self.out_net = nn.Linear(output_size, output_size)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # x: (B, T, D-4) -> (B, T/4, 512)
        return self.out_net(self.main(x.transpose(1, 2)).transpose(1, 2))


class _BiGRUCo(nn.Module):
    """Shared body: input projection, bidirectional GRU from a learned state, MLP on the last states."""

    def __init__(self, input_size: int, hidden_size: int, output_size: int):
        super().__init__()
        self.input_emb = nn.Linear(input_size, hidden_size)
        self.gru = nn.GRU(hidden_size, hidden_size, batch_first=True, bidirectional=True)
        self.output_net = nn.Sequential(
            nn.Linear(hidden_size * 2, hidden_size),
            nn.LayerNorm(hidden_size),
            nn.LeakyReLU(0.2),
            nn.Linear(hidden_size, output_size),
        )
        self.hidden = nn.Parameter(torch.randn(2, 1, hidden_size))

    def _encode(self, x: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
        lengths = torch.as_tensor(lengths).cpu().long()
        if (lengths < 1).any() or (lengths > x.shape[1]).any():
            raise StableMoError(f"evaluator: sequence lengths must be in 1..{x.shape[1]}, got {lengths.tolist()}")
        packed = pack_padded_sequence(self.input_emb(x), lengths, batch_first=True, enforce_sorted=False)
        _, last = self.gru(packed, self.hidden.expand(-1, x.shape[0], -1).contiguous())  # last: (2, B, H)
        return self.output_net(torch.cat([last[0], last[1]], dim=-1))


class TextEncoderBiGRUCo(_BiGRUCo):
    """Word vectors + POS embedding → BiGRU → co-embedding."""

    def __init__(self, word_size: int = 300, pos_size: int = 15, hidden_size: int = 512, output_size: int = 512):
        super().__init__(word_size, hidden_size, output_size)
        self.pos_emb = nn.Linear(pos_size, word_size)

    def forward(self, word_emb: torch.Tensor, pos_onehot: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
        # word_emb: (B, L, 300), pos_onehot: (B, L, 15), lengths: (B,) -> (B, 512)
        return self._encode(word_emb + self.pos_emb(pos_onehot), lengths)


class MotionEncoderBiGRUCo(_BiGRUCo):
    """Movement codes (B, T/4, 512) with lengths in units of 4 frames → co-embedding."""

    def __init__(self, input_size: int = 512, hidden_size: int = 1024, output_size: int = 512):
        super().__init__(input_size, hidden_size, output_size)

    def forward(self, movements: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
        return self._encode(movements, lengths)


# Key order inside `output_net`: 0 Linear, 1 LayerNorm, 2 LeakyReLU, 3 Linear (text-to-motion `networks/modules.py`).
DATASET_DIMS = {"humanml3d": 263, "kit": 251}
# Subfolders of the published evaluator archive (checkpoints root), per dataset.
_ARCHIVE = {
    "humanml3d": ("t2m", ("Comp_v6_KLD01", "Comp_v6_KLD005")),
    "kit": ("kit", ("Comp_v6_KLD005", "Comp_v6_KLD01")),
}


class GuoEvaluator(nn.Module):
    """The three published networks plus the evaluator's own normalisation statistics."""

    def __init__(self, feature_dim: int = 263):
        super().__init__()
        self.feature_dim = feature_dim
        self.movement_encoder = MovementConvEncoder(feature_dim - 4, 512, 512)
        self.text_encoder = TextEncoderBiGRUCo(300, 15, 512, 512)
        self.motion_encoder = MotionEncoderBiGRUCo(512, 1024, 512)
        self.register_buffer("mean", torch.zeros(feature_dim))
        self.register_buffer("std", torch.ones(feature_dim))

    def load_checkpoint(self, path: str | Path) -> "GuoEvaluator":
        path = Path(path)
        if not path.is_file():
            raise StableMoError(f"{path}: evaluator checkpoint not found")
        try:
            ckpt = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as err:
            raise StableMoError(f"{path}: cannot load evaluator checkpoint with weights_only=True ({err})") from None
        for name in ("movement_encoder", "text_encoder", "motion_encoder"):
            if name not in ckpt:
                raise StableMoError(f"{path}: missing '{name}' (keys: {sorted(ckpt)[:8]})")
            try:
                getattr(self, name).load_state_dict(ckpt[name], strict=True)
            except RuntimeError as err:
                raise StableMoError(f"{path}: '{name}' does not match the published layout ({err})") from None
        return self

    def set_statistics(self, mean: np.ndarray, std: np.ndarray) -> None:
        mean, std = np.asarray(mean, np.float32), np.asarray(std, np.float32)
        if mean.shape != (self.feature_dim,) or std.shape != (self.feature_dim,):
            raise StableMoError(f"evaluator statistics: expected ({self.feature_dim},), got {mean.shape}/{std.shape}")
        self.mean.copy_(torch.from_numpy(mean))
        self.std.copy_(torch.from_numpy(std))

    @torch.no_grad()
    def encode_motion(self, features: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
        """features: (B, T, D) *raw* (de-normalised) features, zero-padded; lengths (B,) -> (B, 512)."""
        x = (features - self.mean) / self.std
        valid = torch.arange(x.shape[1], device=x.device)[None, :] < torch.as_tensor(lengths, device=x.device)[:, None]
        x = x * valid[..., None]  # padding is zero in evaluator-normalised space
        movements = self.movement_encoder(x[..., :-4])
        return self.motion_encoder(movements, torch.as_tensor(lengths).cpu() // UNIT_LENGTH)

    @torch.no_grad()
    def encode_text(self, word_emb: torch.Tensor, pos_onehot: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
        return self.text_encoder(word_emb, pos_onehot, lengths)


@dataclass
class GuoAssets:
    checkpoint: Path
    mean: Path
    std: Path
    glove_dir: Path


def find_guo_assets(root: str | Path, dataset: str = "humanml3d", glove_dir: str | Path | None = None) -> GuoAssets:
    """Locate finest.tar, the evaluator Mean/Std and the GloVe folder inside the published archive.

    Accepts the checkpoints root (holding `t2m/` or `kit/`), the dataset folder itself, or a folder
    prepared by hand with `finest.tar`, `mean.npy`, `std.npy` and `glove/`.
    """
    root = Path(root)
    if dataset not in _ARCHIVE:
        raise StableMoError(f"--dataset: unknown dataset {dataset!r}")
    sub, comps = _ARCHIVE[dataset]
    bases = [root / sub, root]
    ckpt = next((p for b in bases for p in (b / "text_mot_match/model/finest.tar", b / "finest.tar") if p.is_file()), None)
    if ckpt is None:
        raise StableMoError(f"{root}: no text_mot_match/model/finest.tar (nor finest.tar) for {dataset}")
    stats = [b / c / "meta" for b in bases for c in comps] + [b / "meta" for b in bases] + bases
    meta = next((d for d in stats if (d / "mean.npy").is_file() and (d / "std.npy").is_file()), None)
    if meta is None:
        raise StableMoError(f"{root}: evaluator statistics not found (expected {sub}/{comps[0]}/meta/mean.npy, std.npy)")
    glove_candidates = [Path(glove_dir)] if glove_dir else [root / "glove", root.parent / "glove", root / sub / "glove"]
    glove = next((g for g in glove_candidates if (g / "our_vab_data.npy").is_file()), None)
    if glove is None:
        raise StableMoError(f"{glove_candidates[0]}: GloVe files (our_vab_data.npy, our_vab_words.pkl) not found")
    return GuoAssets(checkpoint=ckpt, mean=meta / "mean.npy", std=meta / "std.npy", glove_dir=glove)


def load_guo_evaluator(assets: GuoAssets, dataset: str = "humanml3d") -> GuoEvaluator:
    model = GuoEvaluator(DATASET_DIMS[dataset]).load_checkpoint(assets.checkpoint)
    model.set_statistics(load_npy(assets.mean), load_npy(assets.std))
    return model.eval()
