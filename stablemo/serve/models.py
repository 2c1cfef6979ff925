"""The served models and one generation job: a checked JSON spec in, arrays out.

Every bundle is loaded once, when the server starts (a broken bundle is one line before the port
opens). A job is plain Python with no web framework in it, so the API, the load test and the
tests share it; `api.py` runs jobs on a single worker thread, so a request beyond the one being
computed waits in the queue instead of sharing the cores with it.
"""

from __future__ import annotations

import base64
import math
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from threading import Lock
from typing import Any

import numpy as np

from stablemo.errors import StableMoError
from stablemo.inference_config import check_finite, check_positive_int, check_seed

DEFAULT_SECONDS = 6.0
MAX_TEXT_CHARS = 1000  # the text encoders keep far fewer tokens; longer is a pasting accident
ENCODINGS = ("lists", "base64")


@dataclass(frozen=True)
class Spec:
    """One checked request: everything that decides the motion, nothing about its transport."""

    model: str
    text: str
    frames: int
    seed: int
    sampler: str | None = None
    steps: int | None = None
    cfg: float | None = None
    footskate: bool = False
    control: Any = None  # reserved for joint control (stablemo.control), compared by identity of content


@dataclass
class Motion:
    """A generated motion: joints (T, J, 3) and features (T, D) float32, plus what made it."""

    spec: Spec
    joints: np.ndarray
    features: np.ndarray
    fps: float
    info: dict
    seconds: float = 0.0  # compute time of the job (queue time excluded)
    root_path: np.ndarray = field(init=False)

    def __post_init__(self):
        self.root_path = self.joints[:, 0, :]  # (T, 3) pelvis


class ServedModel:
    """A loaded bundle with its name and what the page needs to know of it."""

    def __init__(self, name: str, path: Path, pipeline):
        self.name, self.path, self.pipeline = name, path, pipeline

    def describe(self) -> dict:
        from stablemo.motion.skeleton import get_skeleton

        pipe = self.pipeline
        skel = get_skeleton(pipe.skeleton)
        inf = pipe.inference
        kind = pipe.config.get("kind", "diffusion")
        return {
            "name": self.name,
            "label": f"{self.name} ({kind}, {inf.steps} step{'s' if inf.steps != 1 else ''})",
            "kind": kind,
            "bundle": str(self.path),
            "fps": pipe.fps,
            "min_frames": pipe.min_length,
            "max_frames": pipe.max_length,
            "samplers": sorted(pipe.samplers),
            "defaults": {"sampler": inf.sampler, "steps": inf.steps, "cfg": inf.cfg},
            "skeleton": {"name": skel.name, "units": skel.units, "joints": list(skel.joint_names),
                         "parents": list(skel.parents), "chains": [list(c) for c in skel.kinematic_chains],
                         "sides": [skel.side_of_chain(i) for i in range(len(skel.kinematic_chains))]},
        }


class ModelSet:
    """Named bundles, loaded once each; the first is the default. `generate` is not re-entrant
    (one worker calls it); the result cache is locked because downloads read it from another."""

    def __init__(self, bundles: dict[str, str | Path], device: str | None = None, cache_size: int = 16):
        from stablemo.pipeline import Pipeline

        if not bundles:
            raise StableMoError("--bundle: no model to serve")
        self.models: dict[str, ServedModel] = {}
        for name, path in bundles.items():
            self.models[name] = ServedModel(name, Path(path), Pipeline.from_bundle(path, device=device))
        self.default = next(iter(self.models))
        self._cache: OrderedDict[Spec, Motion] = OrderedDict()
        self._cache_size, self._lock = cache_size, Lock()

    def describe(self) -> dict:
        return {"default": self.default, "models": [m.describe() for m in self.models.values()]}

    # ---- request checking --------------------------------------------------------------------

    def parse(self, body: Any) -> tuple[Spec, dict]:
        """A JSON request body -> (Spec, transport options). Every error names the field, one line."""
        if not isinstance(body, dict):
            raise StableMoError("request: expected a JSON object")
        known = {"text", "seconds", "frames", "seed", "model", "sampler", "steps", "cfg", "footskate", "control",
                 "encoding", "features", "format"}
        unknown = sorted(set(body) - known)
        if unknown:
            raise StableMoError(f"{unknown[0]}: unknown field (known: {', '.join(sorted(known))})")
        name = body.get("model") or self.default
        if name not in self.models:
            raise StableMoError(f"model: unknown {name!r}; served: {', '.join(self.models)}")
        pipe = self.models[name].pipeline
        text = body.get("text")
        if not isinstance(text, str):
            raise StableMoError(f"text: expected a string, got {_json_type(text)}")
        if not text.strip():
            raise StableMoError("text: empty prompt")
        if len(text) > MAX_TEXT_CHARS:
            raise StableMoError(f"text: {len(text)} characters, at most {MAX_TEXT_CHARS}")
        frames = _frames(body, pipe)
        seed = check_seed("seed", body.get("seed", 0))
        sampler = body.get("sampler")
        if sampler is not None and sampler not in pipe.samplers:
            raise StableMoError(f"sampler: unknown {sampler!r}; choose from {sorted(pipe.samplers)}")
        steps = body.get("steps")
        if steps is not None:
            if isinstance(steps, bool) or not isinstance(steps, int):
                raise StableMoError(f"steps: expected a whole number, got {steps!r}")
            check_positive_int("steps", steps)
        cfg = body.get("cfg")
        if cfg is not None:
            cfg = check_finite("cfg", _number("cfg", cfg), low=0.0, high=100.0)
        footskate = body.get("footskate", False)
        if not isinstance(footskate, bool):
            raise StableMoError(f"footskate: expected true or false, got {footskate!r}")
        if body.get("control") is not None:
            raise StableMoError("control: joint control is not available in this server yet")
        encoding = body.get("encoding", "lists")
        if encoding not in ENCODINGS:
            raise StableMoError(f"encoding: expected one of {', '.join(ENCODINGS)}, got {encoding!r}")
        features = body.get("features", True)
        if not isinstance(features, bool):
            raise StableMoError(f"features: expected true or false, got {features!r}")
        spec = Spec(name, text.strip(), frames, seed, sampler, steps, cfg, footskate)
        # the sampler's own checks (steps it can run, ...) before the job is queued
        from stablemo.pipeline import Request

        pipe.resolve(Request([spec.text], spec.frames, seed=seed, sampler=sampler, steps=steps, cfg=cfg))
        return spec, {"encoding": encoding, "features": features, "format": body.get("format")}

    def warm_up(self, name: str) -> None:
        """One generation at the default length, uncached: first-call costs are paid at start-up."""
        from stablemo.pipeline import Request

        pipe = self.models[name].pipeline
        pipe.generate(Request(["a person walks forward"], min(round(DEFAULT_SECONDS * pipe.fps), pipe.max_length)))

    # ---- generation ----------------------------------------------------------------------------

    def generate(self, spec: Spec) -> tuple[Motion, bool]:
        """(the motion of a checked spec, whether it came from the cache of recent motions): the
        same spec always gives the same arrays, so a download re-uses what the page shows."""
        with self._lock:
            if spec in self._cache:
                self._cache.move_to_end(spec)
                return self._cache[spec], True
        from stablemo.hooks import make_hooks
        from stablemo.pipeline import Request

        pipe = self.models[spec.model].pipeline
        start = time.perf_counter()
        hooks = make_hooks(pipe, footskate=spec.footskate)
        result = pipe.generate(Request([spec.text], spec.frames, seed=spec.seed, sampler=spec.sampler,
                                       steps=spec.steps, cfg=spec.cfg, hooks=hooks))
        motion = Motion(spec, result.joint_list()[0].astype(np.float32), result.feature_list()[0].astype(np.float32),
                        pipe.fps, dict(result.info, skeleton=pipe.skeleton), seconds=time.perf_counter() - start)
        with self._lock:
            self._cache[spec] = motion
            while len(self._cache) > self._cache_size:
                self._cache.popitem(last=False)
        return motion, False


def encode_array(arr: np.ndarray, encoding: str) -> Any:
    """Nested lists of numbers, or {"dtype", "shape", "base64"} of its little-endian float32 bytes
    (the page's choice: smaller and faster to parse). The lists hold each float32 value exactly
    (as float64, whose decimal repr reads back to the same float32)."""
    arr = np.ascontiguousarray(arr, dtype="<f4")
    if encoding == "base64":
        return {"dtype": "float32", "shape": list(arr.shape), "base64": base64.b64encode(arr.tobytes()).decode("ascii")}
    return arr.astype(np.float64).tolist()


def motion_json(motion: Motion, encoding: str, features: bool) -> dict:
    spec = motion.spec
    out = {
        "model": spec.model, "text": spec.text, "seed": spec.seed, "frames": spec.frames, "fps": motion.fps,
        "sampler": motion.info["sampler"], "steps": motion.info["steps"], "cfg": motion.info["cfg"],
        "footskate": spec.footskate, "joints": encode_array(motion.joints, encoding),
    }
    if features:
        out["features"] = encode_array(motion.features, encoding)
    return out


def _frames(body: dict, pipe) -> int:
    if body.get("seconds") is not None and body.get("frames") is not None:
        raise StableMoError("seconds: give seconds or frames, not both")
    if body.get("frames") is not None:
        frames = body["frames"]
        if isinstance(frames, bool) or not isinstance(frames, int):
            raise StableMoError(f"frames: expected a whole number, got {frames!r}")
        flag = f"frames: {frames}"
    elif body.get("seconds") is not None:
        seconds = check_finite("seconds", _number("seconds", body["seconds"]), low=0.0, strict=True)
        frames, flag = round(seconds * pipe.fps), f"seconds: {seconds:g} s is {round(seconds * pipe.fps)} frames,"
    else:
        return min(round(DEFAULT_SECONDS * pipe.fps), pipe.max_length)
    if not pipe.min_length <= frames <= pipe.max_length:
        raise StableMoError(f"{flag} outside this model's range [{pipe.min_length}, {pipe.max_length}] frames "
                            f"({pipe.min_length / pipe.fps:g}-{pipe.max_length / pipe.fps:g} s at {pipe.fps:g} fps)")
    return frames


def _number(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise StableMoError(f"{name}: expected a number, got {value!r}")
    if isinstance(value, float) and not math.isfinite(value):
        raise StableMoError(f"{name}: must be a finite number, got {value}")
    return float(value)


def _json_type(value: Any) -> str:
    return {type(None): "null", bool: "a boolean", int: "a number", float: "a number", list: "an array",
            dict: "an object"}.get(type(value), type(value).__name__)
