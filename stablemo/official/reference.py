"""The published network code, loaded from a user's checkout, for side-by-side comparisons.

StableMo does not ship the official StableMoFusion code. Tests and `python -m
stablemo.official.compare` load `models/unet.py` from a checkout of
github.com/Linketic/StableMoFusion (a path, usually $STABLEMO_OFFICIAL_SRC). That file imports
OpenAI's `clip` package and loads ViT-B/32 weights in its constructor; neither is needed to compare
networks, so `official_unet_module` gives it a stand-in `clip` module whose `load` returns a
`transformers` CLIPTextModel dressed in OpenAI CLIP's attribute names (`OpenAIStyleCLIP`) and
whose `tokenize` pads with token id 0 to 77 positions, as OpenAI's does. The official `encode_text`
then runs its own code (token + positional embedding, transformer, ln_final, projection, text
transformer, layer norm) on the same CLIP weights StableMo loads. The official file needs `einops`.
"""

from __future__ import annotations

import importlib.util
import sys
import types
from pathlib import Path

import torch
from torch import nn

from stablemo.errors import StableMoError

CONTEXT = 77


class OpenAIStyleCLIP(nn.Module):
    """A transformers CLIPTextModel with OpenAI CLIP's interface as the official encode_text uses it:
    token_embedding, positional_embedding, transformer (on (L, N, D)), ln_final, dtype."""

    def __init__(self, hf_model: nn.Module):
        super().__init__()
        tower = getattr(hf_model, "text_model", hf_model)  # transformers < 5 nests the text tower
        self.token_embedding = tower.embeddings.token_embedding
        self.positional_embedding = tower.embeddings.position_embedding.weight
        self.ln_final = tower.final_layer_norm
        self.transformer = _CausalEncoder(tower)
        self.dtype = torch.float32


class _CausalEncoder(nn.Module):
    def __init__(self, tower: nn.Module):
        super().__init__()
        self.encoder = tower.encoder
        object.__setattr__(self, "_config", tower.config)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (L, N, D) -> (L, N, D), causal as CLIP's
        from transformers.models.clip.modeling_clip import create_causal_mask

        h = x.permute(1, 0, 2)
        mask = create_causal_mask(config=self._config, inputs_embeds=h, attention_mask=None, cache=None)
        return self.encoder(inputs_embeds=h, attention_mask=mask, is_causal=True).last_hidden_state.permute(1, 0, 2)


def write_random_clip(path: Path, hidden: int = 512, layers: int = 1, seed: int = 0):
    """A random transformers CLIPTextModel (with a character-level tokenizer) saved with
    save_pretrained to `path`: it loads exactly as a real CLIP folder does, for comparisons and
    tests on machines without CLIP weights. -> (model, tokenizer)."""
    import json

    from transformers import CLIPTextConfig, CLIPTextModel, CLIPTokenizer

    from stablemo.io import atomic_dir, write_text

    vocab = {"<|startoftext|>": 0, "<|endoftext|>": 1}
    for ch in "abcdefghijklmnopqrstuvwxyz":
        vocab[ch] = len(vocab)
        vocab[ch + "</w>"] = len(vocab)
    torch.manual_seed(seed)
    heads = 8 if hidden % 8 == 0 else 2
    config = CLIPTextConfig(vocab_size=len(vocab), hidden_size=hidden, intermediate_size=2 * hidden,
                            num_hidden_layers=layers, num_attention_heads=heads, max_position_embeddings=CONTEXT,
                            bos_token_id=0, eos_token_id=1, pad_token_id=1)
    model = CLIPTextModel(config).eval()
    with atomic_dir(path) as tmp:
        write_text(tmp / "vocab.json", json.dumps(vocab))
        write_text(tmp / "merges.txt", "#version: 0.2\n")
        tokenizer = CLIPTokenizer(str(tmp / "vocab.json"), str(tmp / "merges.txt"), pad_token="<|endoftext|>")
        tokenizer.save_pretrained(tmp)
        model.save_pretrained(tmp)
    return model, tokenizer


def clip_stand_in(hf_model: nn.Module, tokenizer) -> types.ModuleType:
    """A `clip` module: load() -> OpenAIStyleCLIP(hf_model); tokenize() -> (B, 77) ids padded with 0,
    truncated keeping the end-of-text token last (OpenAI's truncate=True)."""
    module = types.ModuleType("clip")

    def tokenize(texts, context_length=CONTEXT, truncate=False):
        texts = [texts] if isinstance(texts, str) else list(texts)
        out = torch.zeros(len(texts), context_length, dtype=torch.long)
        for i, text in enumerate(texts):
            ids = tokenizer(text)["input_ids"]
            if len(ids) > context_length:
                ids = ids[:context_length]
                ids[-1] = tokenizer.eos_token_id
            out[i, : len(ids)] = torch.tensor(ids)
        return out

    module.tokenize = tokenize
    module.load = lambda name, device="cpu", jit=False: (OpenAIStyleCLIP(hf_model).to(device).eval(), None)
    return module


def official_unet_module(src: str | Path, clip_module: types.ModuleType) -> types.ModuleType:
    """Import `models/unet.py` of the checkout `src` with `clip_module` standing in for OpenAI's clip."""
    path = Path(src) / "models" / "unet.py"
    if not path.is_file():
        raise StableMoError(f"{src}: not a StableMoFusion checkout (no models/unet.py)")
    before = sys.modules.get("clip")
    sys.modules["clip"] = clip_module
    try:
        spec = importlib.util.spec_from_file_location("stablemofusion_official_unet", path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    except ImportError as err:  # the official code's own dependencies (einops, ...) are not ours
        raise StableMoError(f"{path}: importing it failed ({err}); install what the official code needs, "
                            "e.g. pip install einops") from None
    finally:
        if before is None:
            sys.modules.pop("clip", None)
        else:
            sys.modules["clip"] = before
    return module  # its `import clip` bound the stand-in


def randomize(model: nn.Module) -> nn.Module:
    """Give the layers the official code zero-initialises (output convolution, each block's second
    convolution and AdaGN projection) PyTorch's default initialisation, like every other layer:
    otherwise the network's output is exactly zero and a comparison says nothing. CLIP untouched."""
    for name, module in model.named_modules():
        if name.startswith("clip_model") or not isinstance(module, (nn.Conv1d, nn.Linear)):
            continue
        if not module.weight.any():
            module.reset_parameters()
    return model


def official_checkpoint(model: nn.Module, ema_model: nn.Module, total_it: int = 0) -> dict:
    """The dict the official DDPMTrainer.save writes: raw weights, EMA weights (its
    AveragedModel's .module), optimizer state, iteration count."""
    optimizer = torch.optim.AdamW(model.parameters(), lr=2e-4, weight_decay=1e-2)
    return {"opt_encoder": optimizer.state_dict(), "total_it": total_it,
            "encoder": model.state_dict(), "model_ema": ema_model.state_dict()}
