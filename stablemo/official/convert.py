"""A published StableMoFusion checkpoint (`latest.tar`) -> a StableMo inference bundle.

The official training writes `NAME/model/latest.tar` ({"encoder", "model_ema", "opt_encoder",
"total_it"}), `NAME/meta/mean.npy`, `NAME/meta/std.npy` (the model's normalisation: the dataset's
Mean/Std with the Std of the root features and foot contacts divided by --feat_bias) and
`NAME/opt.txt` (its options). The checkpoint is read with `torch.load(weights_only=True)`: tensors
and plain values only, nothing unpickled. Weights are mapped by `stablemo.official.layout`, the
frozen CLIP ViT-B/32 comes from a local `transformers` folder (or hub id) and is checked against
the CLIP weights the checkpoint itself carries.
"""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import torch

from stablemo.errors import StableMoError
from stablemo.inference.bundle import check_bundle_target, save_bundle
from stablemo.inference.config import InferenceConfig
from stablemo.io import load_npy
from stablemo.motion.plausible import check_feature_stats
from stablemo.motion.skeleton import MAX_FRAMES, get_skeleton
from stablemo.official import layout

DEFAULT_CLIP = "openai/clip-vit-base-patch32"
# dataset -> (skeleton, feature width, fps) as the published code sets them (options/get_opt.py)
DATASETS = {name: (name, get_skeleton(name).feature_dim, get_skeleton(name).fps) for name in ("humanml3d", "kit")}
OPT_DATASETS = {"t2m": "humanml3d", "humanml": "humanml3d", "kit": "kit"}
# the CLIP tensors the official checkpoint carries -> their transformers names (text tower)
CLIP_CHECKS = {
    "clip_model.token_embedding.weight": "embeddings.token_embedding.weight",
    "clip_model.positional_embedding": "embeddings.position_embedding.weight",
    "clip_model.ln_final.weight": "final_layer_norm.weight",
    "clip_model.ln_final.bias": "final_layer_norm.bias",
}


def load_checkpoint(path: Path) -> dict:
    if not path.is_file():
        raise StableMoError(f"{path}: checkpoint not found")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError, OSError, ValueError) as err:
        raise StableMoError(f"{path}: not a readable PyTorch checkpoint of tensors and plain values "
                            f"({type(err).__name__}: {' '.join(str(err).split())[:200]})") from None
    if not isinstance(ckpt, dict) or not any(k in ckpt for k in ("encoder", "model_ema")):
        raise StableMoError(f"{path}: not a StableMoFusion checkpoint (expected 'encoder' / 'model_ema' entries)")
    return ckpt


def pick_weights(ckpt: dict, ema: bool, source: str) -> tuple[dict, str]:
    """The EMA weights unless `ema` is False; like the official loader, the raw ones when the
    checkpoint has no EMA (trained without --model-ema)."""
    name = "model_ema" if ema and isinstance(ckpt.get("model_ema"), dict) else "encoder"
    state = ckpt.get(name)
    if not isinstance(state, dict) or not state:
        raise StableMoError(f"{source}: no {name!r} weights in the checkpoint")
    state = layout.strip_wrapper(state)
    bad = [k for k, v in state.items() if not isinstance(v, torch.Tensor)]
    if bad:
        raise StableMoError(f"{source}: {name}[{bad[0]!r}] is not a tensor")
    nonfinite = [k for k, v in state.items() if v.is_floating_point() and not torch.isfinite(v).all()]
    if nonfinite:
        raise StableMoError(f"{source}: {name} weights hold NaN/Inf (e.g. {nonfinite[0]})")
    return state, name


def read_opt(path: Path) -> dict[str, str]:
    """The official `opt.txt` ("key: value" lines) as strings."""
    opt = {}
    for line in path.read_text(errors="replace").splitlines():
        key, sep, value = line.strip().partition(": ")
        if sep and not key.startswith("-"):
            opt[key] = value.strip()
    return opt


def _default_beside(ckpt: Path, *parts: str) -> Path | None:
    """NAME/<parts> for a checkpoint at NAME/model/latest.tar (the published layout), if it exists."""
    candidate = ckpt.resolve().parent.parent.joinpath(*parts)
    return candidate if candidate.exists() else None


def read_stats(mean_path: Path, std_path: Path, width: int) -> tuple[np.ndarray, np.ndarray]:
    values = []
    for path in (mean_path, std_path):
        array = load_npy(path).astype(np.float64)
        if array.shape != (width,):
            raise StableMoError(f"{path}: expected {width} values (the network's feature width), got shape {array.shape}")
        if not np.isfinite(array).all():
            raise StableMoError(f"{path}: holds NaN/Inf")
        check_feature_stats(array, str(path))
        values.append(array)
    if (values[1] <= 0).any():
        raise StableMoError(f"{std_path}: holds values <= 0")
    return values[0], values[1]


def check_clip(frozen, state: dict, clip_dim: int, clip: str) -> str:
    """The CLIP from --clip against the checkpoint's: width, and the tensors it carries (CLIP_CHECKS)."""
    if frozen.dim != clip_dim:
        raise StableMoError(f"--clip: {clip} gives {frozen.dim}-wide token features, the checkpoint's text "
                            f"projection takes {clip_dim} (CLIP ViT-B/32: 512)")
    # transformers < 5 nests the text tower under "text_model."
    theirs = {k.removeprefix("text_model."): v for k, v in frozen.model.named_parameters()}
    checked = 0
    for ours, name in CLIP_CHECKS.items():
        if ours not in state or name not in theirs:
            continue
        a, b = state[ours].float(), theirs[name].detach().float().cpu()
        if a.shape != b.shape or not torch.allclose(a, b, rtol=1e-3, atol=1e-5):
            raise StableMoError(f"--clip: {clip} is not the CLIP the checkpoint was trained with ({name} differs "
                                f"from the checkpoint's {ours})")
        checked += 1
    return f"{checked} CLIP tensors match the checkpoint's" if checked else "the checkpoint carries no CLIP weights to compare"


def import_official(ckpt: str | Path, out: str | Path, clip: str = DEFAULT_CLIP, dataset: str | None = None,
                    ema: bool = True, meta: str | Path | None = None, mean: str | Path | None = None,
                    std: str | Path | None = None, opt: str | Path | None = None, feat_bias: float | None = None,
                    overwrite: bool = False, log=print) -> Path:
    """Convert the checkpoint `ckpt` into a bundle at `out`; see `stablemo import-official --help`."""
    from stablemo.diffusion.schedule import NoiseSchedule, check_prediction_type
    from stablemo.nets.model import MotionDiffusionModel

    ckpt = Path(ckpt)
    check_bundle_target(out, overwrite, flag="--out")
    if not ckpt.is_file():
        raise StableMoError(f"{ckpt}: checkpoint not found")
    if (mean is None) != (std is None):
        raise StableMoError("--mean/--std: give both files or neither")
    if meta is not None and mean is not None:
        raise StableMoError("--meta: give either --meta DIR or --mean FILE --std FILE, not both")
    if feat_bias is not None and not (np.isfinite(feat_bias) and feat_bias > 0):
        raise StableMoError(f"--feat-bias: must be a positive number, got {feat_bias}")
    if feat_bias is not None and mean is None:
        raise StableMoError("--feat-bias: only with --mean/--std of a dataset (meta/std.npy has it applied already)")
    if dataset is not None and dataset not in DATASETS:
        raise StableMoError(f"--dataset: expected one of {sorted(DATASETS)}, got {dataset!r}")
    opt_path = Path(opt) if opt is not None else _default_beside(ckpt, "opt.txt")
    if opt_path is not None and not opt_path.is_file():
        raise StableMoError(f"--opt: {opt_path}: file not found")
    if mean is None:
        meta_dir = Path(meta) if meta is not None else _default_beside(ckpt, "meta")
        if meta_dir is None:
            raise StableMoError(f"{ckpt}: no meta/ folder beside its model/ folder; pass --meta DIR (the "
                                "checkpoint's meta/ with mean.npy and std.npy) or --mean FILE --std FILE")
        mean, std = meta_dir / "mean.npy", meta_dir / "std.npy"

    options = read_opt(opt_path) if opt_path is not None else {}
    if options.get("no_eff") == "True":
        raise StableMoError(f"{opt_path}: trained with --no_eff (softmax cross-attention), which StableMo does not import")
    prediction_type = options.get("prediction_type", "sample")
    check_prediction_type(prediction_type)
    schedule = NoiseSchedule(num_train_timesteps=int(options.get("diffusion_steps", 1000)),
                             beta_schedule=options.get("beta_schedule", "linear"))

    checkpoint = load_checkpoint(ckpt)
    state, weights = pick_weights(checkpoint, ema, str(ckpt))
    denoiser, text = layout.infer_config(state, str(ckpt))
    clip_dim = text.pop("clip_dim")
    width = denoiser["input_dim"]
    if dataset is None:
        dataset = OPT_DATASETS.get(options.get("dataset_name", ""))
        dataset = dataset or next((name for name, (_, w, _) in DATASETS.items() if w == width), None)
        if dataset is None:
            raise StableMoError(f"{ckpt}: {width} features is neither HumanML3D (263) nor KIT-ML (251); pass --dataset")
    skeleton, expected, fps = DATASETS[dataset]
    if width != expected:
        raise StableMoError(f"--dataset: {dataset} motions have {expected} features, the checkpoint's network {width}")
    mean_values, std_values = read_stats(Path(mean), Path(std), width)
    if feat_bias is not None:  # as the official training does to a dataset's Std (datasets/t2m_dataset.py)
        std_values[:4] /= feat_bias  # root rotation velocity, root linear velocity (2), root height
        std_values[-4:] /= feat_bias  # foot contacts

    clip_source = str(Path(clip).expanduser().resolve()) if Path(clip).expanduser().is_dir() else clip
    model = MotionDiffusionModel(denoiser, {"encoder": clip_source, **text})
    clip_note = check_clip(model.text.frozen, state, clip_dim, clip)
    weights_state = layout.to_stablemo(state)
    try:
        model.load_state_dict(weights_state, strict=True)
    except RuntimeError as err:
        raise StableMoError(f"{ckpt}: the weights do not fit the inferred network ({' '.join(str(err).split())[:300]})") from None

    config = {
        "kind": "diffusion",
        "model": {"denoiser": denoiser, "text": {"encoder": clip_source, **text}},
        "schedule": schedule.config(),
        "prediction_type": prediction_type,
        "dataset": dataset,
        "skeleton": skeleton,
        "fps": fps,
        "mean": mean_values.tolist(),
        "std": std_values.tolist(),
        "min_length": 1,
        "max_length": MAX_FRAMES,
        "training": {
            "source": "StableMoFusion official checkpoint (stablemo import-official)",
            "checkpoint": str(ckpt),
            "weights": weights,
            "total_it": int(checkpoint.get("total_it", 0) or 0),
            "mean": str(mean),
            "std": str(std),
            "feat_bias_applied": feat_bias,
            "opt": options,
        },
    }
    config["inference"] = InferenceConfig(max_length=MAX_FRAMES, fps=fps).to_dict()
    path = save_bundle(out, config, model.state_dict(), overwrite=overwrite)
    n_params = sum(v.numel() for v in weights_state.values())
    log(f"imported {weights} weights ({n_params / 1e6:.1f} M parameters, {len(denoiser['channel_mults'])} stages of "
        f"{[denoiser['base_channels'] * m for m in denoiser['channel_mults']]} channels), {dataset}, "
        f"prediction '{prediction_type}'; {clip_note}")
    return path
