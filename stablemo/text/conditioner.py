"""TextConditioner: frozen token encoder + the paper's small trainable transformer (latent 256).

texts (list[str]) -> (text (B, L, latent_dim), text_mask (B, L) bool). The frozen encoder is kept
outside the module tree, so it is neither in ``state_dict()`` nor in ``parameters()`` and never
receives gradients; bundles hold only the trainable part. The classifier-free-guidance null
condition is the empty string ``NULL_TEXT = ""`` (encoded like any caption: its special tokens).

``variant="official"`` is the published StableMoFusion T2MUnet's text path (stablemo.official):
the frozen encoder (CLIP) gives all 77 positions of each caption, padding (token id 0) included,
and the transformer runs with no padding mask, as the published code does; the null condition
has no token at all (mask all False), so the denoiser's cross-attention adds nothing for it, which
is the published classifier-free guidance's unconditional pass (cross-attention skipped).
"""

from __future__ import annotations

import torch
from torch import nn

from stablemo.checks import check_weight
from stablemo.errors import StableMoError
from stablemo.text.encoders import MINILM, FrozenTextEncoder, get_encoder

NULL_TEXT = ""
OFFICIAL_CONTEXT = 77  # CLIP's context length: the published text path keeps all of its positions


def frozen_encoder(encoder: str = MINILM, variant: str = "stablemo", cache_size: int = 4096) -> FrozenTextEncoder:
    """The shared frozen encoder a model's text config (`encoder`, `variant`) reads its prompts with:
    the one a TextConditioner holds, for code that needs the encoder without the model (e.g.
    scripts/text/length_predictor.py)."""
    if variant not in ("stablemo", "official"):
        raise StableMoError(f"text variant: expected 'stablemo' or 'official' (the published T2MUnet's "
                            f"text path), got {variant!r}")
    return get_encoder(encoder, cache_size, OFFICIAL_CONTEXT if variant == "official" else None)


class TextConditioner(nn.Module):
    def __init__(self, encoder: str = MINILM, latent_dim: int = 256, num_layers: int = 4, num_heads: int = 4,
                 ff_dim: int = 2048, dropout: float = 0.1, cache_size: int = 4096, variant: str = "stablemo",
                 feature_noise: float = 0.0):
        """feature_noise: in training only, each frozen token feature gets Gaussian noise of this many
        times its own standard deviation over the feature axis (0: none), so that the layers above
        learn a neighbourhood of each caption's features, not the caption's exact ones (an experiment
        for sentences unlike the training captions: docs/training.md, "Noise on the text features")."""
        super().__init__()
        self.feature_noise = check_weight("text feature_noise", feature_noise)
        frozen = frozen_encoder(encoder, variant, cache_size)
        self.encoder_name, self.latent_dim, self.variant = encoder, latent_dim, variant
        # stored in __dict__ (not a submodule): no state_dict entry, no parameters, no .to() moves
        object.__setattr__(self, "_frozen", frozen)
        self.proj = nn.Linear(self.frozen.dim, latent_dim)
        layer = nn.TransformerEncoderLayer(latent_dim, num_heads, ff_dim, dropout, activation="gelu", batch_first=True)
        self.transformer = nn.TransformerEncoder(layer, num_layers, enable_nested_tensor=False)
        self.norm = nn.LayerNorm(latent_dim)

    @property
    def frozen(self) -> FrozenTextEncoder:
        return self._frozen

    def frozen_features(self, texts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        """Padded frozen token features (B, L, dim) float32 and mask (B, L) bool, on CPU."""
        if isinstance(texts, str) or not isinstance(texts, (list, tuple)) or not texts:
            raise StableMoError("texts: expected a non-empty list of strings")
        if self.variant == "official":
            return self._official_features(list(texts))
        feats = self.frozen.encode(list(texts))
        L = max(f.shape[0] for f in feats)
        out = torch.zeros(len(feats), L, self.frozen.dim)
        mask = torch.zeros(len(feats), L, dtype=torch.bool)
        for i, f in enumerate(feats):
            out[i, : f.shape[0]] = f
            mask[i, : f.shape[0]] = True
        return out, mask

    def _official_features(self, texts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, 77, dim) features and mask: all True for a caption, all False (zeros) for NULL_TEXT."""
        real = [t for t in texts if t != NULL_TEXT]
        found = dict(zip(real, self.frozen.encode(real))) if real else {}
        out = torch.zeros(len(texts), OFFICIAL_CONTEXT, self.frozen.dim)
        mask = torch.zeros(len(texts), OFFICIAL_CONTEXT, dtype=torch.bool)
        for i, text in enumerate(texts):
            if text != NULL_TEXT:
                out[i], mask[i] = found[text], True
        return out, mask

    def forward(self, texts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        weight = self.proj.weight
        if self.frozen.device != weight.device:
            self.frozen.to(weight.device)
        feats, mask = self.frozen_features(texts)
        feats, mask = feats.to(weight.device, weight.dtype), mask.to(weight.device)  # (B, L, dim), (B, L)
        if self.training and self.feature_noise > 0:
            # drawn from the global generator, which the training step seeds per step (as the dropout
            # layers' draws), so a resumed run draws the same noise
            scale = feats.std(dim=-1, keepdim=True)  # (B, L, 1)
            feats = feats + self.feature_noise * scale * torch.randn_like(feats)
        # the official path has no padding mask (a null row, all masked, would give NaN with one)
        padding = None if self.variant == "official" else ~mask
        x = self.transformer(self.proj(feats), src_key_padding_mask=padding)
        x = self.norm(x)
        return torch.where(mask[:, :, None], x, torch.zeros((), dtype=x.dtype, device=x.device)), mask
