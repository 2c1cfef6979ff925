"""`stablemo export CKPT --out DIR`: a Lightning training checkpoint -> an inference bundle.

The bundle (stablemo.inference.bundle) holds the EMA weights by default, the network/schedule/prediction
configuration from the checkpoint's hyperparameters and the dataset facts (Mean/Std, skeleton,
fps, lengths) the DiffusionModule stored at save time — no dataset is needed to export.

`--overwrite` replaces a bundle (config.json and model.safetensors, nothing else) in one atomic
exchange (footskate.atomicio.replace_dir): --out names the old bundle or the new one at every
instant, and leftovers of a killed export beside it are removed by the next one.
"""

from __future__ import annotations

from dataclasses import replace

import inspect
from pathlib import Path

import torch

from stablemo.errors import StableMoError
from stablemo.inference.bundle import check_bundle_target, save_bundle
from stablemo.inference.config import InferenceConfig, student_inference
from stablemo.training.checkpoint_io import load_checkpoint_file
from stablemo.training.module import CHECKPOINT_KEY

WEIGHTS = ("ema", "raw")


def bundle_from_checkpoint(checkpoint: dict, source: str = "", weights: str = "ema") -> tuple[dict, dict[str, torch.Tensor]]:
    """(bundle config, state_dict of MotionDiffusionModel) from a loaded DiffusionModule checkpoint."""
    if weights not in WEIGHTS:
        raise StableMoError(f"--weights: expected one of {WEIGHTS}, got {weights!r}")
    hp = checkpoint.get("hyper_parameters")
    extra = checkpoint.get(CHECKPOINT_KEY)
    if isinstance(extra, dict) and "bundle" in extra:
        return _precomputed_bundle(checkpoint, extra, source)
    if not isinstance(hp, dict) or "model" not in hp or not isinstance(extra, dict):
        raise StableMoError(f"{source}: not a DiffusionModule checkpoint (no model hyperparameters / EMA section)")
    data = extra.get("data")
    if not data:
        raise StableMoError(f"{source}: the checkpoint holds no dataset statistics (trained without a data module?)")

    if weights == "ema":
        state = dict(extra["ema"]["shadow"])
    else:
        prefix = "model."
        state = {k[len(prefix):]: v for k, v in checkpoint["state_dict"].items() if k.startswith(prefix)}
    if not state:
        raise StableMoError(f"{source}: no {weights} weights in the checkpoint")
    _check_finite(state, source, weights)

    from stablemo.diffusion.schedule import NoiseSchedule
    from stablemo.text import TextConditioner

    model = {"denoiser": dict(hp["model"]["denoiser"]), "text": dict(hp["model"].get("text") or {})}
    # Make the text encoder id explicit even when the training config relied on the default.
    default_encoder = inspect.signature(TextConditioner.__init__).parameters["encoder"].default
    model["text"].setdefault("encoder", default_encoder)
    config = {
        "kind": "diffusion",
        "model": model,
        "schedule": NoiseSchedule(**(hp.get("schedule") or {})).config(),
        "prediction_type": hp.get("prediction_type", "sample"),
        "dataset": data["dataset"],
        "skeleton": data["skeleton"],
        "fps": data["fps"],
        "mean": list(data["mean"]),
        "std": list(data["std"]),
        "min_length": data["min_length"],
        "max_length": data["max_length"],
        **({"body": data["body"]} if "body" in data else {}),  # the bone lengths generation keeps
        "training": {
            "checkpoint": source,
            "global_step": int(checkpoint.get("global_step", 0)),
            "epoch": int(checkpoint.get("epoch", 0)),
            "weights": weights,
            "ema_decay": extra["ema"]["decay"],
            "ema_updates": int(extra["ema"]["num_updates"]),
            "cond_drop_prob": hp.get("cond_drop_prob"),
            "lr": hp.get("lr"),
            "data": {k: v for k, v in (checkpoint.get("datamodule_hyper_parameters") or {}).items()
                     if not k.startswith("_")},
            "lightning_version": checkpoint.get("pytorch-lightning_version"),
        },
    }
    return config, state


def _check_finite(state: dict[str, torch.Tensor], source: str, label: str) -> None:
    bad = [k for k, v in state.items() if v.is_floating_point() and not torch.isfinite(v).all()]
    if bad:
        raise StableMoError(f"{source}: {label} weights contain NaN/Inf (e.g. {bad[0]}); export an earlier checkpoint")


def _precomputed_bundle(checkpoint: dict, extra: dict, source: str) -> tuple[dict, dict[str, torch.Tensor]]:
    """Modules other than DiffusionModule (e.g. ConsistencyDistillation) store their bundle config at
    save time and name the state-dict prefix of the weights to export (the student's EMA target)."""
    prefix = extra["weights_prefix"]
    state = {k[len(prefix):]: v for k, v in checkpoint["state_dict"].items() if k.startswith(prefix)}
    if not state:
        raise StableMoError(f"{source}: no weights under {prefix!r} in the checkpoint")
    ema = extra.get("ema")
    if ema is not None:  # a trained part's averaged weights over its raw ones (a ControlNet on a frozen base)
        state.update({extra["ema_prefix"] + k: v for k, v in ema["shadow"].items()})
    _check_finite(state, source, "exported")
    config = dict(extra["bundle"])
    config["training"] = {**config.get("training", {}), "checkpoint": source,
                          "global_step": int(checkpoint.get("global_step", 0))}
    return config, state


def export(ckpt: str | Path, out: str | Path, weights: str = "ema", overwrite: bool = False,
           cfg: float | None = None, steps: int | None = None) -> Path:
    """Write the bundle of checkpoint `ckpt` to folder `out`; an existing bundle there is replaced
    only with `overwrite`, anything else at `out` is refused (checked before the checkpoint loads).
    cfg: the bundle's default guidance scale, steps: its sampler's default number of steps (None:
    the inference config's own; e.g. a PCM student trained for 4 phases shipped to sample in 1)."""
    check_bundle_target(out, overwrite)
    checkpoint = load_checkpoint_file(ckpt)
    config, state = bundle_from_checkpoint(checkpoint, source=str(ckpt), weights=weights)
    # the one inference config (sampler, steps, cfg, length range, fps), stated in every bundle
    config.setdefault("inference", InferenceConfig.from_bundle(config, str(ckpt)).to_dict())
    if config.get("kind") == "consistency":  # its own sampler (older checkpoints carry the teacher's)
        config["inference"] = student_inference(config, str(ckpt)).to_dict()
    if cfg is not None:
        config["inference"] = replace(InferenceConfig(**config["inference"]), cfg=float(cfg)).to_dict()
    if steps is not None:
        config["inference"] = replace(InferenceConfig(**config["inference"]), steps=int(steps)).to_dict()
    return save_bundle(out, config, state, overwrite=overwrite)


