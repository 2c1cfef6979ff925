"""Generation: text -> motion features and joints, with the paper's inference tricks (§4.3).

- text is encoded once per request (the frozen encoder also caches by string across requests),
- classifier-free guidance runs its conditional and unconditional halves as one batched forward,
- the network alone runs in low precision (fp16 on CUDA, bf16 on CPU if asked); the solver,
  x0 conversion and noise stay float32,
- prompts of different lengths share a batch: each sample is padded to the network's length
  multiple with a mask, and draws its start noise and per-step noise from its own generator at its
  own length, so a sample's result does not depend on what else is in the batch (the denoisers are
  exactly padding invariant),
- a guidance hook may rewrite the predicted x0 at chosen steps (used by foot-skate cleanup).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np
import torch
from torch import nn

from stablemo.diffusion.accelerate import accelerate
from stablemo.diffusion.guidance import CFGDenoiser
from stablemo.diffusion.samplers import SAMPLERS
from stablemo.diffusion.schedule import NoiseSchedule, check_prediction_type
from stablemo.errors import StableMoError

# bundle "kind" -> its sampler table; a consistency student's table depends on its own config
# (mode, grid, phase edges) and is built in from_bundle
SAMPLER_TABLES: dict[str, dict[str, Callable[..., torch.Tensor]]] = {"diffusion": SAMPLERS, "consistency": {}}
DEFAULT_SAMPLER: dict[str, str] = {"diffusion": "dpmpp_2m_sde"}

DTYPES = {"fp32": torch.float32, "float32": torch.float32, "bf16": torch.bfloat16, "bfloat16": torch.bfloat16,
          "fp16": torch.float16, "float16": torch.float16}

# hook(step_index, t, x0 (B,T,D) normalised float32, motion_mask (B,T) bool) -> new x0 or None
X0Hook = Callable[[int, int, torch.Tensor, torch.Tensor], "torch.Tensor | None"]


def resolve_dtype(dtype, device: torch.device) -> torch.dtype:
    """Network precision: default fp16 on CUDA, fp32 on CPU; fp16 is refused on CPU (slow, inexact)."""
    if dtype is None:
        return torch.float16 if device.type == "cuda" else torch.float32
    if isinstance(dtype, str):
        if dtype not in DTYPES:
            raise StableMoError(f"dtype: expected one of {sorted(DTYPES)}, got {dtype!r}")
        dtype = DTYPES[dtype]
    if dtype not in (torch.float32, torch.bfloat16, torch.float16):
        raise StableMoError(f"dtype: expected float32, bfloat16 or float16, got {dtype}")
    if dtype == torch.float16 and device.type == "cpu":
        raise StableMoError("dtype: float16 is for CUDA; use bf16 or fp32 on the CPU")
    return dtype


@dataclass
class Generation:
    """A batch of generated motions; padded tensors with a mask, plus per-sample views.

    features: (B, T, D) de-normalised, zero on padding; joints: (B, T, J, 3), zero on padding;
    normalized: (B, T, D) the sampler's output in model space; mask: (B, T) bool.
    """

    texts: list[str]
    lengths: list[int]
    seeds: list[int]
    features: torch.Tensor
    joints: torch.Tensor
    normalized: torch.Tensor
    mask: torch.Tensor
    info: dict = field(default_factory=dict)

    def feature_list(self) -> list[np.ndarray]:
        return [self.features[i, :n].numpy() for i, n in enumerate(self.lengths)]

    def joint_list(self) -> list[np.ndarray]:
        return [self.joints[i, :n].numpy() for i, n in enumerate(self.lengths)]


class _PerSampleNoise:
    """N(0, I) draws where sample i comes from its own generator at its own length (T_i, D)."""

    def __init__(self, generators: list[torch.Generator], lengths: list[int]):
        self.generators, self.lengths = generators, lengths

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        z = torch.zeros(x.shape, dtype=torch.float32)
        for i, (gen, n) in enumerate(zip(self.generators, self.lengths)):
            z[i, :n] = torch.randn((n,) + tuple(x.shape[2:]), generator=gen, dtype=torch.float32)
        return z.to(x.device, x.dtype)


class Pipeline:
    """A trained MotionDiffusionModel plus what generation needs around it (schedule, stats, skeleton)."""

    def __init__(
        self,
        model: nn.Module,
        schedule: NoiseSchedule,
        mean: Sequence[float] | np.ndarray,
        std: Sequence[float] | np.ndarray,
        prediction_type: str = "sample",
        skeleton: str = "humanml3d",
        fps: float = 20.0,
        min_length: int = 1,
        max_length: int = 196,
        kind: str = "diffusion",
        device: str | torch.device | None = None,
        dtype=None,
        config: dict | None = None,
        fast: bool = True,
    ) -> None:
        check_prediction_type(prediction_type)
        if kind not in SAMPLER_TABLES:
            raise StableMoError(f"kind: no samplers for bundle kind {kind!r}; known: {sorted(SAMPLER_TABLES)}")
        self.device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
        self.dtype = resolve_dtype(dtype, self.device)
        self.model = model.eval().requires_grad_(False).to(self.device)
        if fast:  # GEMM convolutions, cached low-precision weights (stablemo.diffusion.accelerate)
            accelerate(self.model)
        self.schedule, self.prediction_type, self.kind = schedule, prediction_type, kind
        self.mean = torch.as_tensor(np.asarray(mean, dtype=np.float32))
        self.std = torch.as_tensor(np.asarray(std, dtype=np.float32))
        if self.mean.shape != self.std.shape or self.mean.dim() != 1:
            raise StableMoError(f"mean/std: expected two (D,) vectors, got {tuple(self.mean.shape)} and {tuple(self.std.shape)}")
        self.skeleton, self.fps = skeleton, float(fps)
        self.min_length, self.max_length = int(min_length), int(max_length)
        self.config = config or {}
        self._null: tuple[torch.Tensor, torch.Tensor] | None = None
        # frozen text encoders wherever the model holds a text conditioner (a student wraps its teacher's)
        frozen = (getattr(m, "frozen", None) for m in self.model.modules())
        self._frozen_encoders = list({id(f): f for f in frozen if hasattr(f, "clear_cache")}.values())
        self.samplers = SAMPLER_TABLES[kind]
        if kind == "consistency":
            from stablemo.distill.sampling import consistency_samplers

            self.samplers = consistency_samplers(self.config["consistency"], schedule)

    # ---- construction -----------------------------------------------------------------------

    @classmethod
    def from_bundle(cls, path: str | Path, device=None, dtype=None, fast: bool = True,
                    random_weights: bool = False) -> "Pipeline":
        """Load a bundle; `random_weights` keeps the network's fresh initialisation (benchmarks)."""
        from stablemo.bundle import load_bundle

        bundle = load_bundle(path)
        config = bundle.config
        cfg_file = Path(path) / "config.json"
        for key in ("model", "mean", "std"):
            if key not in config:
                raise StableMoError(f"{cfg_file}: missing key {key!r}")
        kind = config.get("kind", "diffusion")
        if kind not in SAMPLER_TABLES:
            raise StableMoError(f"{cfg_file}: bundle kind {kind!r} is not supported by this pipeline "
                                f"(known: {sorted(SAMPLER_TABLES)})")
        if kind == "consistency":
            from stablemo.distill.student import ConsistencyStudent

            if "consistency" not in config:
                raise StableMoError(f"{cfg_file}: a consistency bundle needs a 'consistency' section")
            model = ConsistencyStudent(config["model"], w_dim=config["consistency"].get("w_dim", 256))
        else:
            from stablemo.model import MotionDiffusionModel

            model = MotionDiffusionModel(**config["model"])
        if not random_weights:
            try:
                model.load_state_dict(bundle.state_dict, strict=True)
            except RuntimeError as err:
                raise StableMoError(f"{Path(path) / 'model.safetensors'}: weights do not fit the config ({err})") from None
        return cls(
            model,
            NoiseSchedule(**config.get("schedule", {})),
            config["mean"],
            config["std"],
            prediction_type=config.get("prediction_type", "sample"),
            skeleton=config.get("skeleton") or config.get("dataset", "humanml3d"),
            fps=config.get("fps", 20.0),
            min_length=config.get("min_length", 1),
            max_length=config.get("max_length", 196),
            kind=kind,
            device=device,
            dtype=dtype,
            config=config,
            fast=fast,
        )

    # ---- helpers ----------------------------------------------------------------------------

    @property
    def length_multiple(self) -> int:
        return int(getattr(self.model, "length_multiple", 1))

    def normalize(self, features: torch.Tensor) -> torch.Tensor:
        return (features - self.mean.to(features.device)) / self.std.to(features.device)

    def denormalize(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.std.to(x.device) + self.mean.to(x.device)

    def encode(self, texts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        """(text (B,L,C), text_mask (B,L)) on the pipeline's device, one conditioner pass."""
        with torch.no_grad():
            text, mask = self.model.encode_text(list(texts))
        return text.to(self.device, torch.float32), mask.to(self.device)

    def null_condition(self, batch: int) -> tuple[torch.Tensor, torch.Tensor]:
        """The empty-prompt encoding, computed once per pipeline and expanded to the batch."""
        if self._null is None:
            self._null = self.encode([""])
        text, mask = self._null
        return text.expand(batch, -1, -1), mask.expand(batch, -1)

    def clear_text_caches(self, keep_null: bool = False) -> None:
        """Forget cached text encodings (every frozen encoder's string cache, and the null prompt's
        unless `keep_null`: it is a constant of the model, which AITS counts as loading).

        The frozen encoders are shared across the process, so this also clears what other pipelines
        cached in the same encoder.
        """
        if not keep_null:
            self._null = None
        for frozen in self._frozen_encoders:
            frozen.clear_cache()

    def _check_request(self, texts, lengths) -> tuple[list[str], list[int]]:
        if isinstance(texts, str):
            texts = [texts]
        texts = list(texts)
        if not texts:
            raise StableMoError("texts: no prompts given")
        for i, text in enumerate(texts):
            if not isinstance(text, str) or not text.strip():
                raise StableMoError(f"texts[{i}]: empty prompt")
        if isinstance(lengths, (int, np.integer)):
            lengths = [int(lengths)] * len(texts)
        lengths = [int(n) for n in lengths]
        if len(lengths) != len(texts):
            raise StableMoError(f"lengths: {len(lengths)} lengths for {len(texts)} prompts")
        for i, n in enumerate(lengths):
            if not self.min_length <= n <= self.max_length:
                raise StableMoError(f"lengths[{i}]: {n} frames is outside this model's range "
                                    f"[{self.min_length}, {self.max_length}] ({self.fps:g} fps)")
        return texts, lengths

    # ---- generation -------------------------------------------------------------------------

    def generate(
        self,
        texts: str | Sequence[str],
        lengths: int | Sequence[int],
        steps: int = 10,
        cfg: float = 2.5,
        sampler: str | None = None,
        seed: int | Sequence[int] = 0,
        dtype=None,
        x0_hook: X0Hook | None = None,
        hook_steps: Iterable[int] | None = None,
        batch_size: int | None = None,
        parallel_cfg: bool = True,
        text_cache: bool = True,
        progress: bool = False,
    ) -> Generation:
        """Sample one motion per prompt.

        seed: an int (sample i uses seed + i) or one seed per prompt. hook_steps: step indices at
        which x0_hook runs (negative counts from the end, indices outside the run are ignored; None =
        every step). batch_size: split large requests into chunks (results do not depend on it).
        parallel_cfg=False and text_cache=False (re-encode the prompts at every network call,
        bypassing every cache) exist to measure the paper's baselines; they change no result.
        """
        texts, lengths = self._check_request(texts, lengths)
        table = self.samplers
        sampler = sampler or DEFAULT_SAMPLER.get(self.kind) or next(iter(table))
        if sampler not in table:
            raise StableMoError(f"sampler: unknown {sampler!r}; choose from {sorted(table)}")
        if isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + i for i in range(len(texts))]
        else:
            seeds = [int(s) for s in seed]
            if len(seeds) != len(texts):
                raise StableMoError(f"seed: {len(seeds)} seeds for {len(texts)} prompts")
        net_dtype = resolve_dtype(dtype, self.device) if dtype is not None else self.dtype
        hook_at = None
        if hook_steps is not None:
            hook_at = {s + steps if s < 0 else s for s in hook_steps} & set(range(steps))  # -k: k-th from the end
        chunk = batch_size or len(texts)
        parts = []
        for start in range(0, len(texts), chunk):
            sl = slice(start, start + chunk)
            parts.append(self._generate_batch(texts[sl], lengths[sl], seeds[sl], steps, float(cfg), table[sampler],
                                              net_dtype, x0_hook, hook_at, parallel_cfg, text_cache, progress))
        T = max(p.shape[1] for p in parts)
        normalized = torch.cat([torch.nn.functional.pad(p, (0, 0, 0, T - p.shape[1])) for p in parts])
        mask = torch.arange(T)[None, :] < torch.tensor(lengths)[:, None]
        features = torch.where(mask[..., None], self.denormalize(normalized), torch.zeros(()))
        joints = self.to_joints(features, mask)
        info = {"steps": steps, "cfg": float(cfg), "sampler": sampler, "dtype": str(net_dtype).replace("torch.", "")}
        return Generation(texts, lengths, seeds, features, joints, normalized, mask, info)

    def to_joints(self, features: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """De-normalised features (B,T,D) -> joints (B,T,J,3), zero on padding (root integration is causal)."""
        from stablemo.motion import features_to_joints

        joints = features_to_joints(features, self.skeleton)
        return torch.where(mask[:, :, None, None], joints, torch.zeros((), dtype=joints.dtype))

    def _generate_batch(self, texts, lengths, seeds, steps, cfg, sampler_fn, net_dtype, x0_hook, hook_at,
                        parallel_cfg, text_cache, progress) -> torch.Tensor:
        B, D = len(texts), self.mean.shape[0]
        mult = self.length_multiple
        T = int(math.ceil(max(lengths) / mult) * mult)
        mask = (torch.arange(T)[None, :] < torch.tensor(lengths)[:, None]).to(self.device)
        generators = [torch.Generator().manual_seed(s) for s in seeds]
        noise = _PerSampleNoise(generators, lengths)
        x_T = noise(torch.empty(B, T, D)).to(self.device)

        def guided_denoiser():
            text, text_mask = self.encode(texts)
            if self.kind == "consistency":  # guidance is embedded in the student: w = cfg - 1
                from stablemo.distill.student import StudentDenoiser

                return StudentDenoiser(self.model, text, text_mask, mask, w=cfg - 1.0, dtype=net_dtype)
            null_text, null_mask = self.null_condition(B)
            return CFGDenoiser(self.model, text, text_mask, null_text, null_mask, mask, scale=cfg,
                               batched=parallel_cfg, dtype=net_dtype)

        if text_cache:
            denoise = guided_denoiser()  # text encoded once per request
        else:
            def denoise(x, t):
                self.clear_text_caches()
                return guided_denoiser()(x, t)

        callback = None
        if x0_hook is not None:
            def callback(i, t, x0):
                if hook_at is None or i in hook_at:
                    with torch.enable_grad():  # hooks may optimise (e.g. foot-skate cleanup)
                        return x0_hook(i, t, x0.clone(), mask)
                return None

        # inference_mode is the fastest context, but its tensors cannot enter autograd: with a hook
        # the loop runs under no_grad so the hook may differentiate through its own computations
        with torch.no_grad() if x0_hook is not None else torch.inference_mode():
            x0 = sampler_fn(denoise, x_T, self.schedule, steps, noise=noise, callback=callback,
                            prediction_type=self.prediction_type, progress=progress)
        x0 = torch.where(mask[..., None], x0.float(), torch.zeros((), device=x0.device))
        return x0.cpu()
