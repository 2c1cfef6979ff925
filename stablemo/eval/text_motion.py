"""Text-motion evaluators behind one interface for `stablemo evaluate`: StableMo's own (a training
checkpoint or an exported folder) and the published Guo et al. archive.

Both give `embed_text(texts, tokens) -> (N, E)`, `embed_motion(features (B, T, D), lengths (B,)) -> (B, E)`
and `feature_dim`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from stablemo.errors import StableMoError


class OurEvaluator:
    """Adapter over stablemo.eval.evaluator.EvaluatorModule (captions as strings)."""

    def __init__(self, path: str | Path):
        from stablemo.eval.evaluator import load_evaluator

        self.model = load_evaluator(path)
        self.name = f"stablemo evaluator ({Path(path).name})"
        self.feature_dim = int(self.model.hparams.feature_dim)

    @torch.no_grad()
    def embed_text(self, texts: list[str], tokens: list[list[str]]) -> np.ndarray:
        return self.model.embed_text(texts).double().cpu().numpy()

    @torch.no_grad()
    def embed_motion(self, features: torch.Tensor, lengths: torch.Tensor) -> np.ndarray:
        return self.model.embed_motion(features, lengths).double().cpu().numpy()


class GuoTextMotionEvaluator:
    """Adapter over the published Guo et al. evaluator (word/POS tokens + GloVe)."""

    PAD_TO = 196

    def __init__(self, root: str | Path, dataset: str, glove: str | Path | None = None):
        from stablemo.eval.guo import find_guo_assets, load_guo_evaluator
        from stablemo.eval.word_vectorizer import WordVectorizer

        assets = find_guo_assets(root, dataset, glove)
        self.model = load_guo_evaluator(assets, dataset)
        self.words = WordVectorizer(assets.glove_dir)
        self.name = f"Guo et al. evaluator ({assets.checkpoint})"
        self.feature_dim = self.model.feature_dim

    @torch.no_grad()
    def embed_text(self, texts: list[str], tokens: list[list[str]]) -> np.ndarray:
        from stablemo.eval.word_vectorizer import tokens_from_caption

        encoded = [self.words.encode_tokens(list(tok) or tokens_from_caption(txt)) for txt, tok in zip(texts, tokens)]
        words = torch.from_numpy(np.stack([e[0] for e in encoded]))
        pos = torch.from_numpy(np.stack([e[1] for e in encoded]))
        lengths = torch.tensor([e[2] for e in encoded])
        return self.model.encode_text(words, pos, lengths).double().numpy()

    @torch.no_grad()
    def embed_motion(self, features: torch.Tensor, lengths: torch.Tensor) -> np.ndarray:
        # The reference loader pads every motion to 196 frames, and the movement encoder's
        # convolutions see a few padded frames past the end: pad the same way for identical embeddings.
        if features.shape[1] < self.PAD_TO:
            features = torch.nn.functional.pad(features, (0, 0, 0, self.PAD_TO - features.shape[1]))
        return self.model.encode_motion(features.float(), lengths).double().numpy()


def load_text_motion_evaluator(path: str | Path, dataset: str = "humanml3d", glove: str | Path | None = None):
    """Our evaluator (.ckpt or exported folder) or the published one (archive folder or finest.tar)."""
    path = Path(path)
    if not path.exists():
        raise StableMoError(f"--evaluator {path}: not found")
    if path.is_dir() and (path / "config.json").is_file():
        return OurEvaluator(path)
    if path.is_file() and path.suffix == ".ckpt":
        return OurEvaluator(path)
    if path.is_file() and path.name.endswith(".tar"):
        # …/<dataset>/text_mot_match/model/finest.tar -> the dataset folder of the archive
        root = path.parents[2] if len(path.parents) > 2 and path.parent.name == "model" else path.parent
        return GuoTextMotionEvaluator(root, dataset, glove)
    if path.is_dir():
        return GuoTextMotionEvaluator(path, dataset, glove)
    raise StableMoError(f"--evaluator {path}: expected a .ckpt, an evaluator folder or the published archive")
