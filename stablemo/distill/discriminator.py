"""Adversarial head for phased consistency (MotionPCM): frozen teacher features + small trainable heads.

The teacher's block outputs are read through forward hooks (the teacher stays frozen and in eval
mode, but gradients flow through its activations to the student's samples). Each head is a small
Conv1d stack over one block output, pooled over valid frames only; the discriminator's score is the
sum over heads. Hinge losses as in PCM: L_D = E relu(1 + D(fake)) + E relu(1 - D(real)),
L_G = E relu(1 - D(fake)).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from stablemo.errors import StableMoError


def default_feature_layers(network: nn.Module) -> list[str]:
    """Block outputs worth reading: UNet down stages + middle; transformer-style `blocks` otherwise."""
    names = dict(network.named_modules())
    if "denoiser.down" in names:
        layers = [f"denoiser.down.{i}" for i in range(len(names["denoiser.down"]))]
        return layers + (["denoiser.mid"] if "denoiser.mid" in names else [])
    if "denoiser.blocks" in names:
        return [f"denoiser.blocks.{i}" for i in range(len(names["denoiser.blocks"]))]
    raise StableMoError("discriminator: cannot find block outputs in the teacher; set disc_layers explicitly")


def _frame_mask(mask: torch.Tensor, frames: int) -> torch.Tensor:
    """Mask (B, T) resampled to a block with `frames` frames (stride-2 down-sampling keeps frame 2j)."""
    stride = max(mask.shape[1] // frames, 1)
    return mask[:, ::stride][:, :frames]


class TeacherFeatureDiscriminator(nn.Module):
    """D(x_t, t, text) -> (B,) scores from the frozen `teacher` network's block outputs.

    teacher: a MotionDiffusionModel (frozen); call as D(x, t, text, text_mask, motion_mask).
    """

    def __init__(self, teacher: nn.Module, layers: list[str] | None = None, hidden: int = 64) -> None:
        super().__init__()
        # kept out of this module's parameters: the teacher is not trained here
        self.__dict__["teacher"] = teacher
        self.layers = list(layers or default_feature_layers(teacher))
        modules = dict(teacher.named_modules())
        missing = [name for name in self.layers if name not in modules]
        if missing:
            raise StableMoError(f"disc_layers: no such teacher module(s): {missing}")
        self._features: dict[str, torch.Tensor] = {}
        for name in self.layers:
            modules[name].register_forward_hook(self._keeper(name))
        self.heads = nn.ModuleDict()
        self.hidden = hidden

    def _keeper(self, name: str):
        def hook(_module, _inputs, output):
            if self._capturing:
                self._features[name] = output
        return hook

    _capturing = False

    def _capture(self, x, t, text, text_mask, motion_mask) -> dict[str, torch.Tensor]:
        self._features = {}
        self._capturing = True
        try:
            self.teacher(x, t, text, text_mask, motion_mask)
        finally:
            self._capturing = False
        return self._features

    def build(self, x, t, text, text_mask, motion_mask) -> None:
        """Create the heads once the teacher's feature widths are known (one dry forward)."""
        with torch.no_grad():
            feats = self._capture(x, t, text, text_mask, motion_mask)
        for name in self.layers:
            channels = feats[name].shape[1]
            self.heads[name.replace(".", "_")] = nn.Sequential(
                nn.Conv1d(channels, self.hidden, 3, padding=1), nn.SiLU(), nn.Conv1d(self.hidden, 1, 1))

    def forward(self, x, t, text, text_mask, motion_mask) -> torch.Tensor:
        if not len(self.heads):
            raise StableMoError("discriminator: call build() before use")
        feats = self._capture(x, t, text, text_mask, motion_mask)
        score = x.new_zeros(x.shape[0], dtype=torch.float32)
        for name in self.layers:
            h = feats[name].float()  # (B, C, T_l)
            logits = self.heads[name.replace(".", "_")](h)[:, 0]  # (B, T_l)
            valid = _frame_mask(motion_mask, logits.shape[1]).float()
            score = score + (logits * valid).sum(1) / valid.sum(1).clamp(min=1.0)
        return score


def hinge_d_loss(real: torch.Tensor, fake: torch.Tensor) -> torch.Tensor:
    return F.relu(1 + fake).mean() + F.relu(1 - real).mean()


def hinge_g_loss(fake: torch.Tensor) -> torch.Tensor:
    return F.relu(1 - fake).mean()
