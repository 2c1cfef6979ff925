"""Text conditioning: offline MiniLM, frozen encoder kept out of weights and gradients, LRU cache."""

from __future__ import annotations

import copy
import json
import os

import pytest
import torch

from stablemo.errors import StableMoError
from stablemo.nets.model import MotionDiffusionModel
from stablemo.text import NULL_TEXT, FrozenTextEncoder, TextConditioner, get_encoder

SMALL = dict(latent_dim=32, num_layers=2, num_heads=4, ff_dim=64, dropout=0.0)


@pytest.fixture(scope="module")
def conditioner():
    torch.manual_seed(0)
    return TextConditioner("minilm", **SMALL).eval()


def test_minilm_offline_shapes_and_null_condition(conditioner, monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    text, mask = conditioner(["a person walks forward and waves", NULL_TEXT])
    assert text.shape[0] == 2 and text.shape[2] == 32 and mask.dtype == torch.bool
    # [CLS] a person walks forward and waves [SEP] = 8 tokens; "" = [CLS] [SEP]
    assert mask.sum(dim=1).tolist() == [8, 2]
    assert (text[~mask] == 0).all()
    assert torch.isfinite(text).all()
    assert conditioner.frozen.dim == 384


def test_frozen_encoder_not_in_state_dict_and_gets_no_gradients(conditioner):
    keys = set(conditioner.state_dict())
    assert keys == {name for name, _ in conditioner.named_parameters()} | {
        name for name, _ in conditioner.named_buffers()}
    assert not any("embeddings" in k or "encoder.layer" in k for k in keys)
    n_trainable = sum(p.numel() for p in conditioner.parameters())
    assert n_trainable < 1_000_000  # the 22.7M-parameter MiniLM is not counted
    conditioner.train()
    text, mask = conditioner(["jump twice"])
    text.sum().backward()
    conditioner.eval()
    assert all(p.grad is not None for p in conditioner.parameters())
    assert all(not p.requires_grad and p.grad is None for p in conditioner.frozen.model.parameters())
    conditioner.zero_grad()


def test_encoding_is_deterministic_and_batch_independent(conditioner):
    with torch.no_grad():
        alone, m1 = conditioner(["walk"])
        batch, m2 = conditioner(["a man runs in a circle then sits down", "walk"])
    n = int(m1[0].sum())
    torch.testing.assert_close(batch[1, :n], alone[0, :n], rtol=1e-5, atol=1e-5)
    assert not m2[1, n:].any()


def test_lru_cache_is_bounded_and_returns_same_features():
    enc = get_encoder("minilm", cache_size=2)
    enc.clear_cache()
    a = enc.encode(["one", "two"])
    assert enc.cache_info()["size"] == 2
    enc.encode(["one"])  # "one" becomes most recent
    enc.encode(["three"])  # evicts "two"
    assert list(enc._cache) == ["one", "three"]
    again = enc.encode(["one", "two"])
    torch.testing.assert_close(again[0], a[0])
    torch.testing.assert_close(again[1], a[1], rtol=1e-5, atol=1e-5)  # recomputed
    assert enc.cache_info()["size"] == 2
    with pytest.raises(StableMoError, match="texts"):
        enc.encode("not a list")


def test_model_state_dict_roundtrip_and_deepcopy_shares_encoder():
    torch.manual_seed(0)
    den = {"name": "unet", "input_dim": 12, "base_channels": 16, "channel_mults": [1, 2], "time_dim": 16,
           "num_groups": 2, "num_heads": 2}
    model = MotionDiffusionModel(den, SMALL).eval()
    assert model.length_multiple == 2
    other = MotionDiffusionModel(den, SMALL).eval()
    other.load_state_dict(model.state_dict())  # strict: only trainable weights on both sides
    ema = copy.deepcopy(model)
    assert ema.text.frozen is model.text.frozen
    text, tm = model.encode_text(["walk forward", ""])
    x = torch.randn(2, 8, 12)
    mm = torch.ones(2, 8, dtype=torch.bool)
    out = model(x, torch.tensor([5, 500]), text, tm, mm)
    assert out.shape == (2, 8, 12)
    with pytest.raises(StableMoError, match="text_dim"):
        MotionDiffusionModel({**den, "text_dim": 7}, SMALL)
    with pytest.raises(StableMoError, match="name"):
        MotionDiffusionModel({"input_dim": 12}, SMALL)


def test_unknown_encoder_raises(tmp_path):
    with pytest.raises(StableMoError, match="cannot load"):
        FrozenTextEncoder(str(tmp_path))  # an empty local directory


def _write_tiny_clip(path):
    """A randomly initialised, tiny CLIP checkpoint with a character-level BPE vocabulary."""
    from transformers import CLIPConfig, CLIPModel, CLIPTokenizer

    letters = "abcdefghijklmnopqrstuvwxyz"
    vocab = {"<|startoftext|>": 0, "<|endoftext|>": 1}
    for ch in letters:
        vocab[ch] = len(vocab)
        vocab[ch + "</w>"] = len(vocab)
    path.mkdir()
    (path / "vocab.json").write_text(json.dumps(vocab))
    (path / "merges.txt").write_text("#version: 0.2\n")
    tok = CLIPTokenizer(str(path / "vocab.json"), str(path / "merges.txt"), pad_token="<|endoftext|>")
    tok.save_pretrained(path)
    config = CLIPConfig(
        text_config=dict(vocab_size=len(vocab), hidden_size=24, intermediate_size=48, num_hidden_layers=1,
                         num_attention_heads=2, max_position_embeddings=77, bos_token_id=0, eos_token_id=1,
                         pad_token_id=1),
        vision_config=dict(hidden_size=16, intermediate_size=32, num_hidden_layers=1, num_attention_heads=2,
                           image_size=32, patch_size=16),
        projection_dim=8,
    )
    torch.manual_seed(0)
    CLIPModel(config).save_pretrained(path)


def test_clip_text_tower_from_local_directory(tmp_path):
    path = tmp_path / "tiny-clip"
    _write_tiny_clip(path)
    cond = TextConditioner(str(path), **SMALL).eval()
    assert cond.frozen.dim == 24
    assert type(cond.frozen.model).__name__ == "CLIPTextModel"
    text, mask = cond(["walk", "run fast", NULL_TEXT])
    assert mask.sum(dim=1).tolist() == [6, 9, 2]  # BOS + characters + EOS
    assert torch.isfinite(text).all()


@pytest.mark.skipif(not os.environ.get("STABLEMO_CLIP"), reason="set STABLEMO_CLIP to a local CLIP ViT-B/32 directory")
def test_real_clip_if_available():
    cond = TextConditioner(os.environ["STABLEMO_CLIP"], **SMALL).eval()
    assert cond.frozen.dim == 512
    text, mask = cond(["a person walks forward", NULL_TEXT])
    assert text.shape[-1] == 32 and mask[1].sum() == 2


def test_feature_noise_only_in_training_and_drawn_from_the_seeded_generator():
    """feature_noise blurs the frozen token features in training mode only; the global generator
    (which the training step seeds per step) decides the draw, so the same seed gives the same
    features; a negative or non-finite value is one clear error."""
    torch.manual_seed(0)
    noisy = TextConditioner(latent_dim=32, num_layers=1, ff_dim=64, dropout=0.0, feature_noise=0.5)
    quiet = TextConditioner(latent_dim=32, num_layers=1, ff_dim=64, dropout=0.0)
    quiet.load_state_dict(noisy.state_dict())
    texts = ["a person walks forward.", "a man jumps twice."]
    noisy.eval(), quiet.eval()
    assert torch.equal(noisy(texts)[0], quiet(texts)[0])  # eval: no noise
    noisy.train(), quiet.train()
    torch.manual_seed(1)
    a = noisy(texts)[0]
    torch.manual_seed(1)
    b = noisy(texts)[0]
    torch.manual_seed(2)
    c = noisy(texts)[0]
    assert torch.equal(a, b) and not torch.equal(a, c)
    assert not torch.allclose(a, quiet(texts)[0], atol=1e-3)
    for bad in (-0.1, float("nan"), float("inf"), "0.5", True):
        with pytest.raises(StableMoError, match="feature_noise"):
            TextConditioner(latent_dim=32, num_layers=1, ff_dim=64, feature_noise=bad)
