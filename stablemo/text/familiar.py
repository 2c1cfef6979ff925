"""Is a prompt like anything the model was trained on? One warning line instead of silent nonsense.

A text-to-motion model trained on a closed vocabulary (the demo models: the synthetic dataset's
actions) answers any prompt with some motion: "a person plays the guitar" stood still for 6 s and
"asdf qwerty zzz" walked, without a word. A bundle can carry its training captions' sentence
embeddings (the frozen text encoder's token features, mean-pooled and normalised, as sentence
encoders pool them), deduplicated (a caption within DEDUP cosine of one kept is dropped), and the
cosine threshold below which a prompt is unlike all of them.

Measured with the demo models' MiniLM on the synthetic data (seed 0, 4208 unique training captions,
2174 kept at DEDUP 0.9): the validation split's captions (unseen phrasings of the same actions) reach
at least 0.743 to their nearest kept caption, 15 everyday actions outside the vocabulary at most
0.564; the threshold 0.65 lies between, and on the held-out side the test split's 1111 captions
reach at least 0.777, the issue's own prompts 0.948, and 15 other out-of-vocabulary prompts at most
0.549 (scripts/text/familiarity.py).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import torch

from stablemo.errors import StableMoError

FILE = "familiar.safetensors"  # in a bundle: tensor "embeddings" (N, D) fp16; metadata "captions" (JSON list)
DEDUP = 0.9


def sentence_embeddings(encoder, texts: list[str]) -> torch.Tensor:
    """(N, D) float32, unit length: each text's token features (encoder.encode) averaged."""
    with torch.inference_mode():
        pooled = torch.stack([tokens.float().mean(0) for tokens in encoder.encode(list(texts))])
    return torch.nn.functional.normalize(pooled, dim=-1)


def deduplicate(embeddings: torch.Tensor, keep_above: float = DEDUP) -> list[int]:
    """Indices of a subset in which no two rows are closer than `keep_above` cosine, covering every
    row within that cosine (greedy, in order)."""
    kept: list[int] = []
    for i in range(len(embeddings)):
        if not kept or float((embeddings[kept] @ embeddings[i]).max()) < keep_above:
            kept.append(i)
    return kept


@dataclass(frozen=True)
class Unfamiliar:
    text: str
    similarity: float  # cosine to the nearest training caption
    closest: str  # that caption
    threshold: float

    def message(self) -> str:
        return (f"{self.text!r} is unlike this model's training texts (closest: {self.closest!r}, similarity "
                f"{self.similarity:.2f} < {self.threshold:.2f}): the motion may not follow it")


@dataclass(frozen=True)
class Familiarity:
    embeddings: torch.Tensor  # (N, D) float32, unit rows
    captions: tuple[str, ...]
    threshold: float

    @classmethod
    def build(cls, encoder, captions: list[str], threshold: float) -> Familiarity:
        unique = list(dict.fromkeys(c.strip() for c in captions if c.strip()))
        emb = sentence_embeddings(encoder, unique)
        kept = deduplicate(emb)
        return cls(emb[kept], tuple(unique[i] for i in kept), float(threshold))

    def write(self, folder: str | Path) -> dict:
        """Writes FILE into a bundle folder (atomically); returns the config entry."""
        from safetensors.torch import save

        from stablemo.io import write_bytes

        data = save({"embeddings": self.embeddings.half().contiguous()},
                    metadata={"captions": json.dumps(list(self.captions))})
        write_bytes(Path(folder) / FILE, data)
        return {"file": FILE, "threshold": self.threshold, "captions": len(self.captions)}

    @classmethod
    def load(cls, folder: str | Path, entry: dict, source: str = "config.json") -> Familiarity:
        from safetensors import safe_open

        path = Path(folder) / FILE
        if not isinstance(entry, dict) or not isinstance(entry.get("threshold"), (int, float)) \
                or not -1.0 <= float(entry["threshold"]) <= 1.0:
            raise StableMoError(f"{source}: 'familiarity' must be an object with a threshold in [-1, 1]")
        if not path.is_file():
            raise StableMoError(f"{source}: 'familiarity' names {FILE}, which the bundle does not hold")
        with safe_open(str(path), framework="pt") as f:
            emb = f.get_tensor("embeddings").float()
            captions = json.loads((f.metadata() or {}).get("captions", "[]"))
        if emb.ndim != 2 or len(captions) != emb.shape[0] or not torch.isfinite(emb).all():
            raise StableMoError(f"{path}: expected (N, D) finite embeddings and N captions")
        return cls(torch.nn.functional.normalize(emb, dim=-1), tuple(captions), float(entry["threshold"]))

    def check(self, encoder, texts: list[str]) -> list[Unfamiliar]:
        """The texts unlike every training caption, in order (empty when all are familiar)."""
        if not texts:
            return []
        sims = sentence_embeddings(encoder, texts) @ self.embeddings.T  # (B, N)
        best, idx = sims.max(1)
        return [Unfamiliar(t, float(s), self.captions[int(i)], self.threshold)
                for t, s, i in zip(texts, best, idx) if float(s) < self.threshold]


__all__ = ["DEDUP", "FILE", "Familiarity", "Unfamiliar", "deduplicate", "sentence_embeddings"]
