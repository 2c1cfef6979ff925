"""StableMo's own text–motion evaluator: a contrastive dual encoder for any dataset in the layout.

Motion path: features normalised with the evaluator's statistics, contact dims dropped, masked
dilated 1D convolutions (padding never leaks: masks after every convolution), masked mean + max
pooling, MLP. Text path: the frozen pretrained token features of `stablemo.text` (MiniLM by
default), one small transformer layer with a padding mask, masked mean pooling, MLP. Both
embeddings are L2-normalised, so distances (FID, R-precision, MM-Dist, Diversity) live on the unit
sphere. Training objective: symmetric InfoNCE with a learnable temperature; duplicated captions in
a batch are not used as each other's negatives.

Train: `stablemo fit --config configs/evaluator_synth.yaml`; the checkpoint (or a folder written by
`export_evaluator`) is what `stablemo evaluate --evaluator` takes.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from lightning.pytorch import LightningModule
from torch import nn

from stablemo.errors import StableMoError
from stablemo.eval.metrics import r_precision

CONFIG_NAME = "config.json"
WEIGHTS_NAME = "model.safetensors"
EVALUATOR_FORMAT = "stablemo-evaluator"


class _MaskedConvBlock(nn.Module):
    """Pre-norm residual block: LayerNorm → dilated Conv1d → GELU → Conv1d(k1), masked."""

    def __init__(self, dim: int, kernel: int, dilation: int, dropout: float):
        super().__init__()
        self.norm = nn.LayerNorm(dim)
        self.conv = nn.Conv1d(dim, dim, kernel, padding=dilation * (kernel // 2), dilation=dilation)
        self.proj = nn.Linear(dim, dim)
        self.drop = nn.Dropout(dropout)

    def forward(self, h: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:  # h: (B, T, C), mask (B, T, 1)
        y = self.conv((self.norm(h) * mask).transpose(1, 2)).transpose(1, 2)
        return (h + self.drop(self.proj(F.gelu(y)))) * mask


class MotionEncoder(nn.Module):
    def __init__(self, input_dim: int, hidden: int = 192, embed_dim: int = 256, num_blocks: int = 4,
                 kernel: int = 5, dropout: float = 0.1):
        super().__init__()
        self.input = nn.Linear(input_dim, hidden)
        self.blocks = nn.ModuleList(_MaskedConvBlock(hidden, kernel, 2**i, dropout) for i in range(num_blocks))
        self.norm = nn.LayerNorm(hidden)
        self.head = nn.Sequential(nn.Linear(2 * hidden, hidden), nn.GELU(), nn.Linear(hidden, embed_dim))

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        # x: (B, T, D-4) normalised, mask: (B, T) bool -> (B, E) unit norm
        m = mask[..., None].to(x.dtype)
        h = self.input(x) * m
        for block in self.blocks:
            h = block(h, m)
        h = self.norm(h)
        mean = (h * m).sum(1) / m.sum(1).clamp(min=1)
        peak = h.masked_fill(~mask[..., None], float("-inf")).amax(1)
        return F.normalize(self.head(torch.cat([mean, peak], -1)), dim=-1)


class TextEncoder(nn.Module):
    def __init__(self, token_dim: int = 384, hidden: int = 256, embed_dim: int = 256, num_heads: int = 4,
                 num_layers: int = 1, dropout: float = 0.1):
        super().__init__()
        self.input = nn.Linear(token_dim, hidden)
        layer = nn.TransformerEncoderLayer(hidden, num_heads, 2 * hidden, dropout, batch_first=True, norm_first=True)
        self.transformer = nn.TransformerEncoder(layer, num_layers, enable_nested_tensor=False)
        self.norm = nn.LayerNorm(hidden)
        self.head = nn.Sequential(nn.Linear(hidden, hidden), nn.GELU(), nn.Linear(hidden, embed_dim))

    def forward(self, tokens: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        # tokens: (B, L, token_dim), mask: (B, L) bool (True = real token) -> (B, E) unit norm
        h = self.norm(self.transformer(self.input(tokens), src_key_padding_mask=~mask))
        m = mask[..., None].to(h.dtype)
        return F.normalize(self.head((h * m).sum(1) / m.sum(1).clamp(min=1)), dim=-1)


def info_nce(text: torch.Tensor, motion: torch.Tensor, logit_scale: torch.Tensor,
             captions: list[str] | None = None) -> torch.Tensor:
    """Symmetric InfoNCE over a batch of matched pairs; identical captions are not negatives."""
    logits = logit_scale * text @ motion.T  # (B, B)
    if captions is not None:
        ids = {c: i for i, c in enumerate(dict.fromkeys(captions))}
        key = torch.tensor([ids[c] for c in captions], device=logits.device)
        same = (key[:, None] == key[None, :]) & ~torch.eye(len(captions), dtype=torch.bool, device=logits.device)
        logits = logits.masked_fill(same, float("-inf"))
    target = torch.arange(len(text), device=text.device)
    return 0.5 * (F.cross_entropy(logits, target) + F.cross_entropy(logits.T, target))


class EvaluatorModule(LightningModule):
    """Contrastive text–motion evaluator (LightningModule).

    Args:
        feature_dim: motion feature width (263 HumanML3D, 251 KIT); the 4 contact dims are dropped.
        text_encoder: frozen token encoder id of `stablemo.text` ("minilm" or a CLIP path / hub id).
        token_dim: width of that encoder's token features (384 for MiniLM, 512 for CLIP ViT-B).
        embed_dim, motion_hidden, motion_blocks, text_hidden, text_layers, dropout: network sizes.
        lr, weight_decay: AdamW; the learning rate follows a cosine decay to 10% over max_steps.
        temperature: initial softmax temperature (learnable, clamped at 0.01).
        seed: kept for the record (the Trainer's seed_everything drives the randomness).
    """

    def __init__(self, feature_dim: int = 263, text_encoder: str = "minilm", token_dim: int = 384,
                 embed_dim: int = 256, motion_hidden: int = 192, motion_blocks: int = 4, text_hidden: int = 256,
                 text_layers: int = 1, dropout: float = 0.1, lr: float = 1e-3, weight_decay: float = 0.01,
                 temperature: float = 0.07, seed: int = 0):
        super().__init__()
        if feature_dim < 8:
            raise StableMoError(f"feature_dim: expected the motion feature width (263 or 251), got {feature_dim}")
        self.save_hyperparameters()
        self.motion_encoder = MotionEncoder(feature_dim - 4, motion_hidden, embed_dim, motion_blocks, dropout=dropout)
        self.text_encoder = TextEncoder(token_dim, text_hidden, embed_dim, dropout=dropout, num_layers=text_layers)
        self.logit_scale_log = nn.Parameter(torch.tensor(math.log(1.0 / temperature)))
        # The evaluator's own normalisation statistics (raw-feature space), saved with the weights.
        self.register_buffer("mean", torch.zeros(feature_dim))
        self.register_buffer("std", torch.ones(feature_dim))
        self._frozen = None
        self._val: list[tuple[torch.Tensor, torch.Tensor]] = []

    # ------------------------------------------------------------------ encoders

    @property
    def frozen_text(self):
        if self._frozen is None:
            from stablemo.text import get_encoder

            self._frozen = get_encoder(self.hparams.text_encoder)
            if self._frozen.dim != self.hparams.token_dim:
                raise StableMoError(f"token_dim: {self.hparams.token_dim} but text encoder "
                                    f"{self.hparams.text_encoder!r} gives {self._frozen.dim}")
        return self._frozen

    def _text_tokens(self, texts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        feats = self.frozen_text.encode(list(texts))  # [(l_i, C)]
        lengths = torch.tensor([len(f) for f in feats])
        tokens = torch.zeros(len(feats), int(lengths.max()), feats[0].shape[-1])
        for i, f in enumerate(feats):
            tokens[i, : len(f)] = f
        mask = torch.arange(tokens.shape[1])[None] < lengths[:, None]
        return tokens.to(self.device), mask.to(self.device)

    def embed_text(self, texts: list[str]) -> torch.Tensor:
        """Captions -> (B, E) unit-norm embeddings."""
        if not texts or any(not isinstance(t, str) for t in texts):
            raise StableMoError("texts: expected a non-empty list of strings")
        return self.text_encoder(*self._text_tokens(texts))

    def embed_normalised(self, motion: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """motion: (B, T, D) normalised with the evaluator statistics, mask (B, T) -> (B, E)."""
        return self.motion_encoder(motion[..., :-4] * mask[..., None], mask)

    def embed_motion(self, features: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
        """features: (B, T, D) raw (de-normalised) features, lengths (B,) -> (B, E)."""
        features = features.to(self.device, torch.float32)
        mask = torch.arange(features.shape[1], device=self.device)[None] < torch.as_tensor(lengths, device=self.device)[:, None]
        return self.embed_normalised((features - self.mean) / self.std, mask)

    @property
    def logit_scale(self) -> torch.Tensor:
        return self.logit_scale_log.clamp(max=math.log(100.0)).exp()

    # ------------------------------------------------------------------ Lightning

    def setup(self, stage: str) -> None:
        dm = getattr(self.trainer, "datamodule", None) if self._trainer is not None else None
        if dm is None or getattr(dm, "mean", None) is None:
            return
        if int(dm.feature_dim) != self.hparams.feature_dim:
            raise StableMoError(f"model.feature_dim: {self.hparams.feature_dim} but the dataset has {dm.feature_dim}")
        if stage == "fit":
            # Batches arrive normalised with the data module's statistics: adopt them as ours.
            self.mean.copy_(torch.as_tensor(np.asarray(dm.mean), dtype=torch.float32))
            self.std.copy_(torch.as_tensor(np.asarray(dm.std), dtype=torch.float32))

    def _check_data_statistics(self) -> None:
        # Runs after a checkpoint is restored (setup() runs before): validate/test batches must be
        # normalised the way this evaluator was trained.
        dm = getattr(self.trainer, "datamodule", None)
        if dm is None or getattr(dm, "mean", None) is None:
            return
        if not (np.allclose(self.mean.cpu().numpy(), dm.mean, atol=1e-5)
                and np.allclose(self.std.cpu().numpy(), dm.std, atol=1e-5)):
            raise StableMoError("data: its statistics (Mean/Std with feat_bias) differ from the evaluator's "
                                "(untrained evaluator? pass --ckpt_path)")

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        text = self.embed_text(batch["text"])
        motion = self.embed_normalised(batch["motion"], batch["mask"])
        loss = info_nce(text, motion, self.logit_scale, batch["text"])
        self.log("train/loss", loss, prog_bar=True, batch_size=len(text))
        self.log("train/logit_scale", self.logit_scale, batch_size=len(text))
        return loss

    def _eval_step(self, batch: dict) -> None:
        text = self.embed_text(batch["text"])
        motion = self.embed_normalised(batch["motion"], batch["mask"])
        self._val.append((text.detach().cpu(), motion.detach().cpu()))

    def _eval_end(self, split: str) -> None:
        if not self._val:
            return
        text = torch.cat([t for t, _ in self._val]).double().numpy()
        motion = torch.cat([m for _, m in self._val]).double().numpy()
        self._val.clear()
        if len(text) < 32:
            return
        res = r_precision(text, motion)
        for k in range(3):
            self.log(f"{split}/r{k + 1}", float(res.r_precision[k]), prog_bar=k != 1)
        self.log(f"{split}/mm_dist", res.mm_dist)

    def on_validation_start(self) -> None:
        self._check_data_statistics()

    def on_test_start(self) -> None:
        self._check_data_statistics()

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        self._eval_step(batch)

    def on_validation_epoch_end(self) -> None:
        self._eval_end("val")

    def test_step(self, batch: dict, batch_idx: int) -> None:
        self._eval_step(batch)

    def on_test_epoch_end(self) -> None:
        self._eval_end("test")

    def configure_optimizers(self):
        decay = [p for n, p in self.named_parameters() if p.ndim >= 2]
        other = [p for n, p in self.named_parameters() if p.ndim < 2]
        opt = torch.optim.AdamW([{"params": decay, "weight_decay": self.hparams.weight_decay},
                                 {"params": other, "weight_decay": 0.0}], lr=self.hparams.lr)
        total = self.trainer.max_steps if self.trainer and self.trainer.max_steps and self.trainer.max_steps > 0 else None
        if total is None:
            return opt
        warmup = max(1, total // 20)

        def factor(step: int) -> float:
            if step < warmup:
                return (step + 1) / warmup
            return 0.1 + 0.45 * (1 + math.cos(math.pi * min(1.0, (step - warmup) / max(1, total - warmup))))

        sched = torch.optim.lr_scheduler.LambdaLR(opt, factor)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}


# ---------------------------------------------------------------------- loading and export


def _module_kwargs(hparams: dict) -> dict:
    import inspect

    allowed = set(inspect.signature(EvaluatorModule.__init__).parameters) - {"self"}
    return {k: v for k, v in hparams.items() if k in allowed}


def load_evaluator(path: str | Path) -> EvaluatorModule:
    """Our evaluator from a Lightning checkpoint (.ckpt) or an exported folder; eval mode, CPU."""
    path = Path(path)
    if path.is_dir():
        from safetensors.torch import load_file

        cfg_path, weights = path / CONFIG_NAME, path / WEIGHTS_NAME
        if not cfg_path.is_file() or not weights.is_file():
            raise StableMoError(f"{path}: evaluator folder needs {CONFIG_NAME} and {WEIGHTS_NAME}")
        try:
            config = json.loads(cfg_path.read_text())
        except json.JSONDecodeError as err:
            raise StableMoError(f"{cfg_path}: not valid JSON ({err})") from None
        if config.get("format") != EVALUATOR_FORMAT:
            raise StableMoError(f"{cfg_path}: not a StableMo evaluator (format={config.get('format')!r})")
        hparams, state = config.get("hparams", {}), load_file(str(weights))
    elif path.is_file():
        from stablemo.training.checkpoint_io import load_checkpoint_file

        ckpt = load_checkpoint_file(path)
        if "state_dict" not in ckpt or "hyper_parameters" not in ckpt:
            raise StableMoError(f"{path}: not a Lightning checkpoint of EvaluatorModule")
        hparams, state = dict(ckpt["hyper_parameters"]), ckpt["state_dict"]
    else:
        raise StableMoError(f"{path}: evaluator checkpoint or folder not found")
    model = EvaluatorModule(**_module_kwargs(hparams))
    try:
        model.load_state_dict(state, strict=True)
    except RuntimeError as err:
        raise StableMoError(f"{path}: weights do not match the evaluator ({err})") from None
    return model.eval()


def export_evaluator(checkpoint: str | Path, out_dir: str | Path) -> Path:
    """Write an evaluator folder (config.json + model.safetensors) from a training checkpoint, atomically."""
    from stablemo.inference.bundle import write_weights_folder

    out_dir = _check_evaluator_target(Path(out_dir))  # before the checkpoint loads
    model = load_evaluator(checkpoint)
    config = {"format": EVALUATOR_FORMAT, "version": 1, "hparams": dict(_module_kwargs(dict(model.hparams)))}
    tensors = {k: v.contiguous() for k, v in model.state_dict().items()}
    return write_weights_folder(out_dir, config, tensors, _is_evaluator_folder, "evaluator")


def _is_evaluator_folder(path: Path) -> bool:
    """An evaluator folder we wrote: its config says so and it holds nothing else (safe to replace)."""
    try:
        config = json.loads((path / CONFIG_NAME).read_text())
    except (OSError, ValueError):
        return False
    extra = {p.name for p in path.iterdir()} - {CONFIG_NAME, WEIGHTS_NAME}
    return isinstance(config, dict) and config.get("format") == EVALUATOR_FORMAT and not extra


def _check_evaluator_target(out_dir: Path) -> Path:
    """Replace only a previous evaluator folder: never a file or a folder of anything else."""
    from stablemo.io import output_dir_problem

    if out_dir.is_symlink() or (out_dir.exists() and not out_dir.is_dir()):
        raise StableMoError(f"{out_dir}: exists and is not a folder; nothing was written")
    if out_dir.is_dir() and any(out_dir.iterdir()) and not _is_evaluator_folder(out_dir):
        raise StableMoError(f"{out_dir}: folder is not empty and is not an evaluator folder; nothing was written")
    problem = output_dir_problem(out_dir.parent)
    if problem:
        raise StableMoError(f"{out_dir}: cannot write beside it ({problem})")
    return out_dir
