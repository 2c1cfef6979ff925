"""Generation: text -> motion features and joints, with the paper's inference tricks (§4.3).

- text is encoded once per request (the frozen encoder also caches by string across requests),
- classifier-free guidance runs its conditional and unconditional halves as one batched forward,
- the network alone runs in low precision (fp16 on CUDA, bf16 on CPU if asked); the solver,
  x0 conversion and noise stay float32,
- prompts of different lengths share a batch: each sample is padded to the network's length
  multiple with a mask, and draws its start noise and per-step noise from its own generator at its
  own length, so a sample's result does not depend on what else is in the batch (the denoisers are
  exactly padding invariant),
- sample hooks (stablemo.diffusion.hooks) may rewrite the predicted x0 at chosen steps (foot-skate
  cleanup, and in the same interface any other editing of a sample while it is denoised).

A request is a `Request` (texts, lengths, seeds, sampler, steps, guidance, hooks); what a bundle's
kind contributes (network, samplers, denoiser) comes from stablemo.inference.kinds, and the defaults from the
bundle's inference config (stablemo.inference.config).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
from torch import nn

from stablemo.checks import (
    check_finite,
    check_positive_int,
    check_seed,
    resolve_device,
    resolve_dtype,
)
from stablemo.control.spec import ControlTargets, Inpaint, JointControl
from stablemo.control.turn import Turn
from stablemo.diffusion.hooks import SampleHook, StepState, apply_hooks
from stablemo.diffusion.schedule import NoiseSchedule, check_prediction_type
from stablemo.errors import StableMoError
from stablemo.fast import accelerate
from stablemo.inference.config import InferenceConfig
from stablemo.inference.finish import Finish, body_lengths
from stablemo.inference.kinds import Denoise, DenoiserInputs, ModelKind, model_kind
from stablemo.motion.plausible import check_feature_stats

# (pipeline, texts, motion_mask (B, T), cfg, network dtype, planned timesteps) -> denoise(x_t, t).
# The default encodes the texts once and asks the bundle's kind; the benchmarks pass their
# baselines (no text cache, serial CFG) this way.
DenoiserFactory = Callable[["Pipeline", list, torch.Tensor, float, "torch.dtype | None", list], Denoise]


@dataclass
class Request:
    """One generation request. lengths: frames, one for all texts or one per text; None (for all, or
    in the list for one text) = the length the bundle's length predictor gives the text
    (`Pipeline.text_lengths`); seed: an int (sample i uses seed + i) or one per text; sampler,
    steps, cfg: None = the bundle's inference config; dtype: network precision (None = the
    pipeline's); hooks: sample hooks, applied in this order; batch_size: split large requests into
    chunks (results do not depend on it); inpaint: known features per prompt (`stablemo.control.
    Inpaint`, or None for a free prompt), imposed inside the sampler; control: joint targets per
    prompt (`stablemo.control.JointControl` or None): a ControlNet bundle reads them as its hint,
    and with control_guidance (default) the joint-guidance hook refines x0 towards them after the
    other hooks at every step (a 1-step student: one refinement after its step); face_travel: a body
    following a pelvis path faces its direction of travel (stablemo.control.heading: in the
    guidance hook, or its own hook for a ControlNet without guidance), the gait the text asks for
    (backwards, side steps) kept; finish: put the
    result on the bundle's rigid body and the floor (stablemo.inference.finish; False: features and
    joints are the network's raw output, for code that post-processes it itself); plan: read each
    prompt as a sequence of parts ("X, then Y", stablemo.text.plan) and generate it part by part, and
    a length longer than the text asks for as its parts then a body standing
    (stablemo.timeline.planned), each part (or the whole prompt) turning by the angle its text says
    (stablemo.text.turns) when `turns` is not given. Off here, so the network reads each prompt
    whole at the length given (benchmarks, evaluation); `stablemo generate`, the server and the
    behaviour suite turn it on. Prompts with in-painting, joint control or given turns are never planned.
    turns: per prompt a `stablemo.control.Turn` or None: the body turns that many degrees over
    those frames (stablemo.control.turn, at every sampler step)."""

    texts: Sequence[str]
    lengths: int | Sequence[int | None] | None = None
    seed: int | Sequence[int] = 0
    sampler: str | None = None
    steps: int | None = None
    cfg: float | None = None
    dtype: str | torch.dtype | None = None
    hooks: Sequence[SampleHook] = ()
    batch_size: int | None = None
    progress: bool = False
    inpaint: Inpaint | Sequence[Inpaint | None] | None = None
    control: JointControl | Sequence[JointControl | None] | None = None
    control_guidance: bool = True
    face_travel: bool = True
    finish: bool = True
    plan: bool = False
    turns: Turn | Sequence[Turn | None] | None = None


@dataclass
class Generation:
    """A batch of generated motions; padded tensors with a mask, plus per-sample views.

    features: (B, T, D) de-normalised, zero on padding; joints: (B, T, J, 3), zero on padding: what
    the user receives (the rigid body on the floor, unless the request said finish=False);
    normalized: (B, T, D) the sampler's output in model space; mask: (B, T) bool;
    raw_features, raw_joints: the network's output before the finishing step (evaluation reads both).
    """

    texts: list[str]
    lengths: list[int]
    seeds: list[int]
    features: torch.Tensor
    joints: torch.Tensor
    normalized: torch.Tensor
    mask: torch.Tensor
    info: dict = field(default_factory=dict)
    raw_features: torch.Tensor | None = None
    raw_joints: torch.Tensor | None = None

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
    """A trained model plus what generation needs around it (schedule, stats, skeleton, inference config)."""

    def __init__(
        self,
        model: nn.Module,
        schedule: NoiseSchedule,
        mean: Sequence[float] | np.ndarray,
        std: Sequence[float] | np.ndarray,
        prediction_type: str = "sample",
        skeleton: str = "humanml3d",
        kind: str = "diffusion",
        device: str | torch.device | None = None,
        dtype=None,
        config: dict | None = None,
        inference: InferenceConfig | None = None,
        fast: bool = True,
    ) -> None:
        check_prediction_type(prediction_type)
        self.config = config or {}
        self.kind: ModelKind = model_kind(kind)
        self.device = resolve_device(device)
        self.dtype = resolve_dtype(dtype, self.device)
        self.model = model.eval().requires_grad_(False).to(self.device)
        if fast:  # GEMM convolutions, fused blocks, cached low-precision weights (stablemo.fast)
            self.model = accelerate(self.model)
        self.schedule, self.prediction_type = schedule, prediction_type
        self.mean = torch.as_tensor(np.asarray(mean, dtype=np.float32))
        self.std = torch.as_tensor(np.asarray(std, dtype=np.float32))
        if self.mean.shape != self.std.shape or self.mean.dim() != 1:
            raise StableMoError(f"mean/std: expected two (D,) vectors, got {tuple(self.mean.shape)} and {tuple(self.std.shape)}")
        self.skeleton = skeleton
        self.inference = inference or InferenceConfig.from_bundle(self.config)
        self.finish = Finish.from_config(self.config, skeleton, self.inference.fps)
        self._null: tuple[torch.Tensor, torch.Tensor] | None = None
        # frozen text encoders wherever the model holds a text conditioner (a student wraps its teacher's)
        frozen = (getattr(m, "frozen", None) for m in self.model.modules())
        self._frozen_encoders = list({id(f): f for f in frozen if hasattr(f, "clear_cache")}.values())
        # the bundle's training captions (stablemo.text.familiar), to say when a prompt is unlike them
        self.familiarity = None
        # the bundle's length predictor (stablemo.text.length): a prompt's length when none is asked for
        self.length_predictor = None
        self.samplers = self.kind.samplers(self.config, schedule)
        if self.inference.sampler not in self.samplers:
            raise StableMoError(f"inference.sampler: {self.inference.sampler!r} is not a sampler of this model "
                                f"(choose from {sorted(self.samplers)})")

    # ---- construction -----------------------------------------------------------------------

    @classmethod
    def from_bundle(cls, path: str | Path, device=None, dtype=None, fast: bool = True) -> Pipeline:
        """Load a bundle: its network with its weights, statistics, schedule and inference defaults."""
        from stablemo.inference.bundle import load_bundle, skeleton_name

        device = resolve_device(device)  # a wrong device is reported before any loading
        bundle = load_bundle(path)
        config = bundle.config
        cfg_file = str(Path(path) / "config.json")
        for key in ("model", "mean", "std"):
            if key not in config:
                raise StableMoError(f"{cfg_file}: missing key {key!r}")
        kind_name = config.get("kind", "diffusion")
        kind = model_kind(kind_name, cfg_file)
        try:
            model = kind.build_model(config, cfg_file)
        except TypeError as err:
            raise StableMoError(f"{cfg_file}: 'model' does not describe a network ({err})") from None
        _check_stats(config, cfg_file)
        body_lengths(config, skeleton_name(config), cfg_file)  # named here
        weights_file = Path(path) / "model.safetensors"
        bad = [k for k, v in bundle.state_dict.items() if v.is_floating_point() and not torch.isfinite(v).all()]
        if bad:
            raise StableMoError(f"{weights_file}: {len(bad)} weight tensor(s) hold NaN/Inf (e.g. {bad[0]}); "
                                "the bundle is broken, export it again from a good checkpoint")
        try:
            model.load_state_dict(bundle.state_dict, strict=True)
        except RuntimeError as err:
            raise StableMoError(f"{weights_file}: weights do not fit the config ({err})") from None
        familiarity = None
        if config.get("familiarity") is not None:
            from stablemo.text.familiar import Familiarity

            familiarity = Familiarity.load(path, config["familiarity"], cfg_file)
        length_predictor = None
        if config.get("length_predictor") is not None:
            from stablemo.text.length import LengthPredictor

            length_predictor = LengthPredictor.load(path, config["length_predictor"], cfg_file)
        pipe = cls(
            model,
            NoiseSchedule(**config.get("schedule", {})),
            config["mean"],
            config["std"],
            prediction_type=config.get("prediction_type", "sample"),
            skeleton=skeleton_name(config),
            kind=kind_name,
            device=device,
            dtype=dtype,
            config=config,
            inference=InferenceConfig.from_bundle(config, cfg_file),
            fast=fast,
        )
        pipe.familiarity = familiarity
        if length_predictor is not None:
            pipe.use_length_predictor(length_predictor, cfg_file)
        return pipe

    # ---- helpers ----------------------------------------------------------------------------

    @property
    def fps(self) -> float:
        return self.inference.fps

    @property
    def min_length(self) -> int:
        return self.inference.min_length

    @property
    def max_length(self) -> int:
        return self.inference.max_length

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

    def make_denoiser(self, texts: list[str], motion_mask: torch.Tensor, cfg: float, dtype, timesteps,
                      control: ControlTargets | None = None) -> Denoise:
        """The default DenoiserFactory: texts encoded once, the bundle kind's denoiser (which may read
        the batch's joint targets, `control`)."""
        text, text_mask = self.encode(texts)
        return self.kind.make_denoiser(DenoiserInputs(self.model, self.config, text, text_mask, motion_mask, cfg, dtype,
                                                      timesteps, self.null_condition, control))

    def use_length_predictor(self, predictor, source: str = "config.json") -> None:
        """Give prompts without a length the `predictor`'s (stablemo.text.length), refused (one line
        naming `source`) when it reads another text encoder than the model's."""
        encoder = self._frozen_encoders[0] if self._frozen_encoders else None
        if encoder is None or (predictor.encoder, predictor.dim) != (encoder.name, encoder.dim):
            have = "no frozen text encoder" if encoder is None else f"{encoder.name!r} ({encoder.dim} features)"
            raise StableMoError(f"{source}: length_predictor reads text encoder {predictor.encoder!r} "
                                f"({predictor.dim} features); the model has {have}")
        self.length_predictor = predictor

    def text_lengths(self, texts: Sequence[str]) -> list[int]:
        """The length in frames of a motion of each text when none is asked for: the bundle's length
        predictor's (its most likely length) within the model's range at the network's length
        multiple; without a predictor the inference config's default (DEFAULT_SECONDS)."""
        if self.length_predictor is None:
            return [self.inference.default_frames] * len(texts)
        return self._mode_lengths(self._sentence_embeddings(texts))

    def text_length_range(self, texts: Sequence[str], quantile: float) -> tuple[list[int], list[int]]:
        """Per text, the length in frames it asks for (`text_lengths`) and the `quantile` of the
        predictor's lengths for it (how long such motions are at most, as a rule, in the training
        data); without a predictor both are the default length."""
        if self.length_predictor is None:
            default = self.text_lengths(texts)
            return default, list(default)
        emb = self._sentence_embeddings(texts)
        return self._mode_lengths(emb), [int(n) for n in self.length_predictor.quantile_frames(emb, quantile)]

    def _sentence_embeddings(self, texts: Sequence[str]) -> torch.Tensor:
        from stablemo.text.familiar import sentence_embeddings

        return sentence_embeddings(self._frozen_encoders[0], list(texts))

    def _mode_lengths(self, embeddings: torch.Tensor) -> list[int]:
        """(N, D) sentence embeddings -> the predictor's mode of each, within the model's range at the
        network's length multiple."""
        frames = self.length_predictor.mode_frames(embeddings)
        return [self.inference.nearest_length(int(n), self.length_multiple) for n in frames]

    def resolve(self, request: Request) -> Request:
        """The request with every default filled in from the inference config, checked: one clear
        error naming the field for anything a sampler could not run or would turn into NaN."""
        texts = [request.texts] if isinstance(request.texts, str) else list(request.texts)
        if not texts:
            raise StableMoError("texts: no prompts given")
        for i, text in enumerate(texts):
            if not isinstance(text, str) or not text.strip():
                raise StableMoError(f"texts[{i}]: empty prompt")
        lengths = request.lengths
        if lengths is None or isinstance(lengths, (int, np.integer)):
            lengths = [lengths] * len(texts)
        lengths = list(lengths)
        if len(lengths) != len(texts):
            raise StableMoError(f"lengths: {len(lengths)} lengths for {len(texts)} prompts")
        unset = [i for i, n in enumerate(lengths) if n is None]
        for i, n in zip(unset, self.text_lengths([texts[i] for i in unset]) if unset else []):
            lengths[i] = n
        lengths = [check_positive_int(f"lengths[{i}]", n) for i, n in enumerate(lengths)]
        for i, n in enumerate(lengths):
            self.inference.check_length(n, f"lengths[{i}]")
        if isinstance(request.seed, (int, np.integer)):
            seeds = [check_seed("seed", request.seed, len(texts)) + i for i in range(len(texts))]
        else:
            seeds = [check_seed(f"seed[{i}]", s) for i, s in enumerate(request.seed)]
            if len(seeds) != len(texts):
                raise StableMoError(f"seed: {len(seeds)} seeds for {len(texts)} prompts")
        sampler = request.sampler or self.inference.sampler
        if sampler not in self.samplers:
            raise StableMoError(f"sampler: unknown {sampler!r}; choose from {sorted(self.samplers)}")
        steps = check_positive_int("steps", self.inference.steps if request.steps is None else request.steps)
        cfg = check_finite("cfg", self.inference.cfg if request.cfg is None else request.cfg, low=0.0, high=100.0)
        self.samplers[sampler].timesteps(self.schedule, steps)  # the sampler's own check of steps
        if request.batch_size is not None:
            check_positive_int("batch_size", request.batch_size)
        for i, hook in enumerate(request.hooks):
            if not (callable(hook) and callable(getattr(hook, "active", None))):
                raise StableMoError(f"hooks[{i}]: {type(hook).__name__} is not a sample hook "
                                    "(it needs active(step, steps) and __call__(state); see stablemo.diffusion.hooks)")
        for name in ("control_guidance", "face_travel", "finish", "plan"):
            if not isinstance(getattr(request, name), bool):
                raise StableMoError(f"{name}: expected True or False, got {getattr(request, name)!r}")
        dtype = self.dtype if request.dtype is None else resolve_dtype(request.dtype, self.device)
        inpaint = self._per_prompt(request.inpaint, Inpaint, "inpaint", lengths,
                                   lambda spec, n, what: spec.resolve(n, self.mean.shape[0], what))
        control = self._per_prompt(request.control, JointControl, "control", lengths,
                                   lambda spec, n, what: spec.resolve(n, self.skeleton, what))
        turns = self._per_prompt(request.turns, Turn, "turns", lengths, lambda spec, n, what: spec.resolve(n, what))
        return replace(request, texts=texts, lengths=lengths, seed=seeds, sampler=sampler, steps=steps, cfg=cfg,
                       dtype=dtype, hooks=list(request.hooks), inpaint=inpaint, control=control, turns=turns)

    @staticmethod
    def _per_prompt(value, cls, name: str, lengths: list[int], resolve) -> list | None:
        """One checked spec (arrays) or None per prompt; None when no prompt has one."""
        if value is None:
            return None
        items = [value] * len(lengths) if isinstance(value, cls) else list(value)
        if len(items) != len(lengths):
            raise StableMoError(f"{name}: {len(items)} entries for {len(lengths)} prompts")
        out = []
        for i, (item, n) in enumerate(zip(items, lengths)):
            if item is None:
                out.append(None)
            elif isinstance(item, cls):
                out.append(resolve(item, n, f"{name}[{i}]"))
            else:
                raise StableMoError(f"{name}[{i}]: expected a {cls.__name__} or None, got {type(item).__name__}")
        return out if any(item is not None for item in out) else None

    # ---- generation -------------------------------------------------------------------------

    def generate(self, request: Request | str | Sequence[str], lengths: int | Sequence[int] | None = None,
                 denoiser: DenoiserFactory | None = None, **fields) -> Generation:
        """Sample one motion per prompt: `generate(Request(...))` or `generate(texts, lengths, steps=...)`
        with the fields of `Request` (lengths None: each text's own, `text_lengths`). denoiser: a
        DenoiserFactory replacing the kind's (benchmarks).

        A result that is not finite everywhere (diverged weights, a hook gone wrong) is an error
        naming the prompt, never a returned motion.
        """
        if not isinstance(request, Request):
            try:
                request = Request(request, lengths, **fields)
            except TypeError as err:
                raise StableMoError(f"generate: {err}") from None
        elif lengths is not None or fields:
            raise StableMoError("generate: pass either a Request or texts, lengths and options, not both")
        req = self.resolve(request)
        asked = request.lengths if isinstance(request.lengths, Sequence) else [request.lengths] * len(req.texts)
        predicted = "text" if self.length_predictor is not None else "default"
        lengths_from = [predicted if n is None else "given" for n in asked]
        factory = denoiser or Pipeline.make_denoiser
        plans = None
        reads_turns = req.plan and req.inpaint is None and req.control is None and req.turns is None
        if reads_turns:
            from stablemo.timeline.planned import generate_planned, plan_prompts

            plans = plan_prompts(self, req.texts, asked, req.lengths)
            if all(p is None for p in plans):
                plans = None
                from stablemo.control.turn import said_turns

                # each prompt whole: the turn its text says, over all of it
                req = replace(req, turns=said_turns(req.texts, [(0, n) for n in req.lengths]))
        if plans is None:
            chunk = req.batch_size or len(req.texts)
            parts = []
            for start in range(0, len(req.texts), chunk):
                sl = slice(start, start + chunk)
                parts.append(self._generate_batch(req.texts[sl], req.lengths[sl], req.seed[sl], req, factory,
                                                  req.inpaint[sl] if req.inpaint else None,
                                                  req.control[sl] if req.control else None,
                                                  req.turns[sl] if req.turns else None))
            T = max(p.shape[1] for p in parts)
            normalized = torch.cat([torch.nn.functional.pad(p, (0, 0, 0, T - p.shape[1])) for p in parts])
        else:  # part by part; a planned prompt's length is its plan's
            req = replace(req, lengths=[n if p is None else p.total for n, p in zip(req.lengths, plans)])
            motions = generate_planned(self, req, plans, req.lengths, denoiser)
            T = -(-max(req.lengths) // self.length_multiple) * self.length_multiple
            normalized = torch.zeros(len(motions), T, self.mean.shape[0])
            for i, m in enumerate(motions):
                normalized[i, :len(m)] = self.normalize(torch.from_numpy(m))
        mask = torch.arange(T)[None, :] < torch.tensor(req.lengths)[:, None]
        raw_features = torch.where(mask[..., None], self.denormalize(normalized), torch.zeros(()))
        raw_joints = self.to_joints(raw_features, mask)
        for i, text in enumerate(req.texts):
            if not (torch.isfinite(raw_features[i]).all() and torch.isfinite(raw_joints[i]).all()):
                raise StableMoError(f"prompt {i + 1} ({text!r}): the model produced non-finite values "
                                    f"(check the bundle's weights and the sampler settings); nothing was written")
        features, joints = raw_features, raw_joints
        if req.finish:
            targets = None if req.control is None else self._control_targets(req.control, T)
            if targets is not None:
                targets = ControlTargets(targets.targets.cpu(), targets.mask.cpu())
            features, joints = self.finish(raw_features, req.lengths, targets, raw_joints,
                                           self._given_feet(req.inpaint, T))
        info = {"steps": req.steps, "cfg": req.cfg, "sampler": req.sampler,
                "dtype": str(req.dtype).replace("torch.", ""), "finished": req.finish,
                "lengths_from": lengths_from,  # per prompt: "given", "text" (the predictor) or "default"
                # per prompt: its parts [{text, start, end, rest}] when it was generated part by part, else None
                "plans": [None if p is None else p.to_dict() for p in plans] if plans else [None] * len(req.texts),
                # per prompt: the turns imposed [{text, degrees, side, start, end}] (text None: the caller's), else None
                "turns": _turns_info(req, plans, reads_turns),
                "unfamiliar": [asdict(u) for u in self.unfamiliar(req.texts)]}
        return Generation(req.texts, req.lengths, req.seed, features, joints, normalized, mask, info,
                          raw_features, raw_joints)

    def generate_timeline(self, segments, seed: int = 0, **options):
        """A timeline [(start_s, end_s, text), ...] (or `stablemo.timeline.Segment`s) -> one motion of
        exactly its length (`stablemo.timeline.TimelineMotion`); options: overlap, blend (seconds),
        steps, sampler, cfg, dtype, hooks. docs/long_motion.md."""
        from stablemo.timeline import generate_timeline

        return generate_timeline(self, segments, seed=seed, **options)

    def stream(self, texts_or_callback, chunk_seconds: float = 2.0, **options):
        """An iterator of `stablemo.timeline.Chunk`s of one continuing motion, each conditioned on the
        frames already produced; the text may change between chunks (a list, or a callable
        (index, previous chunk) -> text or None). Options: seed, context_seconds, max_chunks, steps,
        sampler, cfg, dtype, hooks, control. docs/long_motion.md."""
        from stablemo.timeline import stream

        return stream(self, texts_or_callback, chunk_seconds=chunk_seconds, **options)

    def to_joints(self, features: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """De-normalised features (B,T,D) -> joints (B,T,J,3), zero on padding (root integration is causal)."""
        from stablemo.motion import features_to_joints

        joints = features_to_joints(features, self.skeleton)
        return torch.where(mask[:, :, None, None], joints, torch.zeros((), dtype=joints.dtype))

    def _generate_batch(self, texts, lengths, seeds, req: Request, factory: DenoiserFactory,
                        inpaint: list | None = None, control: list | None = None,
                        turns: list | None = None) -> torch.Tensor:
        B, D = len(texts), self.mean.shape[0]
        mult = self.length_multiple
        T = int(math.ceil(max(lengths) / mult) * mult)
        mask = (torch.arange(T)[None, :] < torch.tensor(lengths)[:, None]).to(self.device)
        generators = [torch.Generator().manual_seed(s) for s in seeds]
        noise = _PerSampleNoise(generators, lengths)
        x_T = noise(torch.empty(B, T, D)).to(self.device)
        sampler = self.samplers[req.sampler]
        timesteps = sampler.timesteps(self.schedule, req.steps)
        targets = None if control is None else self._control_targets(control, T)
        # a factory that ignores control (a benchmark baseline) is only asked for it when there is some
        extra_args = {} if targets is None else {"control": targets}
        denoise = factory(self, list(texts), mask, req.cfg, req.dtype, timesteps, **extra_args)

        hooks = list(req.hooks)
        if turns is not None and any(t is not None for t in turns):
            from stablemo.control.turn import TurnAsAsked

            hooks.append(TurnAsAsked(self.mean, self.std, self.skeleton, list(turns)))
        if targets is not None and req.control_guidance:  # last: after the other hooks (e.g. foot skating) moved the body
            from stablemo.control.guidance import JointGuidance
            from stablemo.control.heading import named_gaits

            hooks.append(JointGuidance(targets.targets, targets.mask, self.mean, self.std, self.skeleton,
                                       face_travel=req.face_travel, named_gaits=named_gaits(texts),
                                       own_gait=not getattr(self.kind, "reads_control", False)))
        elif targets is not None and req.face_travel:
            from stablemo.control.guidance import steers_heading
            from stablemo.control.heading import FaceTravel, named_gaits

            steer = steers_heading(targets.mask, self.skeleton)
            if steer.any():
                hooks.append(FaceTravel(self.mean, self.std, self.skeleton, steer, named_gaits(texts)))
        extra = {}
        if inpaint is not None:
            extra["inpaint"] = self._inpainting(inpaint, x_T)
        callback = None
        if hooks:
            def callback(i, t, x0):
                return apply_hooks(hooks, StepState(i, req.steps, int(t), x0, mask, list(lengths)))

        # inference_mode is the fastest context, but its tensors cannot enter autograd: with hooks
        # the loop runs under no_grad so a hook may differentiate through its own computations
        with torch.no_grad() if hooks else torch.inference_mode():
            x0 = sampler.run(denoise, x_T, self.schedule, req.steps, noise=noise, callback=callback,
                             prediction_type=self.prediction_type, progress=req.progress, **extra)
        x0 = torch.where(mask[..., None], x0.float(), torch.zeros((), device=x0.device))
        return x0.cpu()


    def _inpainting(self, specs: list, x_T: torch.Tensor):
        """The batch's Inpainting: known values normalised, padded to x_T's (B, T, D)."""
        from stablemo.diffusion.inpainting import Inpainting

        values, known = torch.zeros_like(x_T), torch.zeros(x_T.shape, dtype=torch.bool, device=x_T.device)
        for i, spec in enumerate(specs):
            if spec is not None:
                feats, keep = (torch.from_numpy(a).to(x_T.device) for a in spec)
                n = feats.shape[0]
                values[i, :n] = torch.where(keep, self.normalize(feats), torch.zeros(()))
                known[i, :n] = keep
        return Inpainting(values, known, x_T)

    def unfamiliar(self, texts) -> list:
        """The prompts unlike every training caption of the bundle (`stablemo.text.familiar.Unfamiliar`,
        with .message()), [] when all are familiar or the bundle carries no captions. A generation's
        info["unfamiliar"] holds them as dicts."""
        if self.familiarity is None or not self._frozen_encoders:
            return []
        return self.familiarity.check(self._frozen_encoders[0], list(dict.fromkeys(texts)))

    def _given_feet(self, specs: list | None, T: int) -> torch.Tensor | None:
        """(B, T) bool: the frames whose ankles an in-painting request keeps (their root-relative
        positions are known), or None without in-painting."""
        if not specs or all(spec is None for spec in specs):
            return None
        from stablemo.motion.features import feature_slices
        from stablemo.motion.skeleton import get_skeleton

        skel = get_skeleton(self.skeleton)
        ric = feature_slices(skel).get("ric")
        cols = [ric.start + 3 * (ankle - 1) for _, _, ankle in skel.legs.values()]
        given = torch.zeros(len(specs), T, dtype=torch.bool)
        for i, spec in enumerate(specs):
            if spec is not None:
                keep = torch.from_numpy(np.asarray(spec[1]))  # (L, D) bool
                given[i, :keep.shape[0]] = keep[:, cols].any(-1)
        return given

    def _control_targets(self, specs: list, T: int) -> ControlTargets:
        """The batch's joint targets: targets (B, T, J, 3) and mask (B, T, J), padded, on the device."""
        from stablemo.motion.skeleton import get_skeleton

        J = get_skeleton(self.skeleton).num_joints
        targets, mask = torch.zeros(len(specs), T, J, 3), torch.zeros(len(specs), T, J, dtype=torch.bool)
        for i, spec in enumerate(specs):
            if spec is not None:
                pos, keep = spec
                targets[i, :pos.shape[0]] = torch.from_numpy(pos)
                mask[i, :keep.shape[0]] = torch.from_numpy(keep)
        return ControlTargets(targets.to(self.device), mask.to(self.device))


def _turns_info(req: Request, plans, read: bool) -> list[list[dict] | None]:
    """Per prompt the turns a generation imposed (stablemo.control.turn): read from each part's
    words when `read`, else the caller's `req.turns`; None for a prompt without one."""
    from stablemo.text.turns import asked_turn

    out = []
    for i, (text, n) in enumerate(zip(req.texts, req.lengths)):
        if read:
            parts = plans[i].to_dict() if plans and plans[i] is not None else [{"text": text, "start": 0, "end": n}]
            said = [(p, asked_turn(p["text"])) for p in parts]
            turns = [{"text": p["text"], "degrees": a.degrees, "side": a.side, "start": p["start"], "end": p["end"]}
                     for p, a in said if a is not None]
        else:
            given = req.turns[i] if req.turns else None
            turns = [] if given is None else [{"text": None, "degrees": given.degrees, "side": given.side,
                                                "start": given.start, "end": given.end}]
        out.append(turns or None)
    return out


def _check_stats(config: dict, source: str) -> None:
    """Mean/Std: finite vectors of the network's feature width, Std > 0 (it divides). Called after
    the kind built the network, so config["model"]["denoiser"] is known to be complete."""
    width = int(config["model"]["denoiser"]["input_dim"])
    values = {}
    for key in ("mean", "std"):
        try:
            values[key] = np.asarray(config[key], dtype=np.float64) if isinstance(config[key], list) else None
        except (TypeError, ValueError):
            values[key] = None
        if values[key] is None or values[key].ndim != 1:
            raise StableMoError(f"{source}: {key!r} must be a list of numbers")
        if len(values[key]) != width:
            raise StableMoError(f"{source}: {key!r} has {len(values[key])} values, the network's features have {width}")
        if not np.isfinite(values[key]).all():
            raise StableMoError(f"{source}: {key!r} holds NaN/Inf")
    if (values["std"] <= 0).any():
        raise StableMoError(f"{source}: 'std' holds values <= 0")
    for key in ("mean", "std"):
        check_feature_stats(values[key], f"{source}: {key!r}")
