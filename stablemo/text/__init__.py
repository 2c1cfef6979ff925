"""Text conditioning: frozen pretrained token encoders (cached) and the trainable conditioner."""

from stablemo.text.conditioner import NULL_TEXT, TextConditioner
from stablemo.text.encoders import MINILM, FrozenTextEncoder, get_encoder, minilm_path

__all__ = ["MINILM", "NULL_TEXT", "FrozenTextEncoder", "TextConditioner", "get_encoder", "minilm_path"]
