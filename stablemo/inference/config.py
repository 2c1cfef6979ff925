"""The one inference configuration: sampler, steps, guidance, length range and frame rate.

Every bundle carries it (`config.json` -> "inference"), written at export; generation, evaluation
and the benchmarks read it from here, so the paper's defaults (10 SDE-DPM-Solver++ steps, CFG 2.5,
motions of up to 196 frames at 20 fps) are stated once. Bundles written before it existed get it
derived from their other keys (a consistency student's own steps and absorbed guidance).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

from stablemo.checks import check_finite, check_positive_int
from stablemo.errors import StableMoError
from stablemo.motion.skeleton import FPS, MAX_FRAMES

# StableMoFusion §4.3: SDE variant of DPM-Solver++(2M) with Karras sigmas, 10 steps, CFG 2.5;
# the length range and frame rate default to HumanML3D's (stablemo.motion.skeleton).
PAPER_SAMPLER, PAPER_STEPS, PAPER_CFG = "dpmpp_2m_sde", 10, 2.5
DEFAULT_SECONDS = 6.0  # a motion's length when none is asked for (capped at the model's maximum)


@dataclass(frozen=True)
class InferenceConfig:
    sampler: str = PAPER_SAMPLER
    steps: int = PAPER_STEPS
    cfg: float = PAPER_CFG
    min_length: int = 1
    max_length: int = MAX_FRAMES
    fps: float = FPS

    def __post_init__(self):
        check_positive_int("steps", self.steps)
        check_finite("cfg", self.cfg, low=0.0)
        check_positive_int("min_length", self.min_length)
        check_positive_int("max_length", self.max_length)
        if self.min_length > self.max_length:
            raise StableMoError(f"min_length: {self.min_length} exceeds max_length {self.max_length}")
        check_finite("fps", self.fps, low=0.0, strict=True)

    def to_dict(self) -> dict:
        return asdict(self)

    @property
    def default_frames(self) -> int:
        """The length of a motion when none is asked for: DEFAULT_SECONDS, within the model's range."""
        return min(max(round(DEFAULT_SECONDS * self.fps), self.min_length), self.max_length)

    def nearest_length(self, frames: int, multiple: int = 1) -> int:
        """The length nearest `frames` within [min_length, max_length] that is a multiple of
        `multiple` (the network's), or merely within the range when no multiple lies in it."""
        lo, hi = -(-self.min_length // multiple) * multiple, self.max_length // multiple * multiple
        if lo > hi:
            return min(max(int(frames), self.min_length), self.max_length)
        return min(max((int(frames) + multiple // 2) // multiple * multiple, lo), hi)  # halves round up

    def check_length(self, frames: int, what: str, said: str | None = None) -> int:
        """`frames` within [min_length, max_length], else one error naming `what` (the flag or field;
        `said`: how the caller's value reads, e.g. "30 s is 600 frames,"). The one range check of the
        CLI, the Python API and the server."""
        if not self.min_length <= frames <= self.max_length:
            lo, hi = self.min_length, self.max_length
            raise StableMoError(f"{what}: {said or f'{frames} frames is'} outside this model's range [{lo}, {hi}] "
                                f"frames ({lo / self.fps:g}-{hi / self.fps:g} s at {self.fps:g} fps)")
        return frames

    @classmethod
    def from_bundle(cls, config: dict, source: str = "config.json") -> "InferenceConfig":
        """The bundle's "inference" section, or one derived from its older keys."""
        section = config.get("inference")
        if section is not None:
            if not isinstance(section, dict) or set(section) - set(cls.__dataclass_fields__):
                raise StableMoError(f"{source}: 'inference' must be an object with keys "
                                    f"{sorted(cls.__dataclass_fields__)}")
            try:
                return cls(**section)
            except (TypeError, StableMoError) as err:
                raise StableMoError(f"{source}: inference: {err}") from None
        base = cls(min_length=int(config.get("min_length", 1)), max_length=int(config.get("max_length", MAX_FRAMES)),
                   fps=float(config.get("fps", FPS)))
        student = config.get("consistency")
        if config.get("kind") == "consistency" and isinstance(student, dict):
            return replace(base, sampler=student["mode"], steps=int(student.get("steps", 1)),
                           cfg=1.0 + float(student.get("w", 0.0)))
        return base


def student_inference(config: dict, source: str = "config.json") -> InferenceConfig:
    """A consistency student's inference config: its own sampler, steps and absorbed guidance (from
    its 'consistency' section) with the length range and fps it inherited from its teacher.

    A student's config starts as a copy of its teacher's, whose inference section names the
    teacher's sampler; students exported before this was fixed carry it, and export corrects them.
    """
    own = InferenceConfig.from_bundle({k: v for k, v in config.items() if k != "inference"}, source)
    inherited = InferenceConfig.from_bundle(config, source)
    return replace(own, min_length=inherited.min_length, max_length=inherited.max_length, fps=inherited.fps)


