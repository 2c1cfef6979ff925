"""Reading a network description from YAML: a denoiser-only file (`configs/nets/*.yaml`: `name` and
its keyword arguments) or any config holding `denoiser` (and `text`) at some depth, e.g. a
LightningCLI training config (`model.model.denoiser`). One reader for `nets summary` and `bench`.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from stablemo.errors import StableMoError, yaml_error_line


def read_yaml(path: str | Path, flag: str | None = None):
    path = Path(path)
    if not path.is_file():
        raise StableMoError(f"{flag + ': ' if flag else ''}{path}: file not found")
    try:
        return yaml.safe_load(path.read_text())
    except yaml.YAMLError as err:
        raise StableMoError(yaml_error_line(path, err)) from None


def find_model(node) -> dict | None:
    """The first mapping (any nesting, dicts and lists) whose `denoiser` is a mapping: {denoiser, text}."""
    if isinstance(node, dict):
        if isinstance(node.get("denoiser"), dict):
            return {"denoiser": dict(node["denoiser"]), "text": dict(node.get("text") or {})}
        children = node.values()
    elif isinstance(node, list):
        children = node
    else:
        return None
    for child in children:
        found = find_model(child)
        if found is not None:
            return found
    return None


def load_model_config(path: str | Path, flag: str | None = None, text_defaults: dict | None = None) -> dict:
    """{"denoiser": {...}, "text": {...}} from `path`. A denoiser-only file gets `text_defaults`
    (with `latent_dim` = its `text_dim`) for the text conditioner. The text width is made explicit
    on both sides (the conditioner's `latent_dim` is the denoiser's `text_dim`)."""
    data = read_yaml(path, flag)
    found = find_model(data)
    if found is None and isinstance(data, dict) and isinstance(data.get("name"), str):  # denoiser-only
        found = {"denoiser": dict(data), "text": dict(text_defaults or {})}
        if "text_dim" in data:
            found["text"]["latent_dim"] = data["text_dim"]
    if found is None:
        raise StableMoError(f"{path}: no model description found (expected a 'denoiser' mapping, "
                            "optionally with 'text', at any level, or a denoiser-only file with 'name')")
    if not isinstance(found["denoiser"].get("name"), str):
        raise StableMoError(f"{path}: denoiser needs a 'name' (unet, dit, retnet)")
    text = found["text"]
    if "latent_dim" in text:
        found["denoiser"].setdefault("text_dim", text["latent_dim"])
    elif "text_dim" in found["denoiser"]:
        text["latent_dim"] = found["denoiser"]["text_dim"]
    return found


def load_denoiser_config(path: str | Path) -> dict:
    """Denoiser dict {"name": ..., **kwargs} from a nets YAML or a training YAML."""
    return load_model_config(path)["denoiser"]
