"""The served models and one generation job: a checked JSON spec in, arrays out.

Every bundle is loaded once, when the server starts (a broken bundle is one line before the port
opens). A job is plain Python with no web framework in it, so the API, the load test and the
tests share it; `api.py` runs jobs on a single worker thread, so a request beyond the one being
computed waits in the queue instead of sharing the cores with it.
"""

from __future__ import annotations

import base64
import math
import re
import time
from collections import OrderedDict
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from threading import Lock
from typing import Any

import numpy as np

from stablemo.checks import check_finite, check_positive_int, check_seed
from stablemo.errors import StableMoError
from stablemo.inference.pipeline import Pipeline, Request
from stablemo.timeline.spec import canonical_timeline, format_timeline, parse_timeline
from stablemo.timeline.stream import chunk_length
from stablemo.timeline.timeline_stream import stream_timeline, whole_features

AUTO = "auto"  # a seconds or frames field that asks for the text's own length, as leaving it out does
MAX_TEXT_CHARS = 1000  # the text encoders keep far fewer tokens; longer is a pasting accident
ENCODINGS = ("lists", "base64")
MAX_STREAM_SECONDS = 300.0  # a bound on one request's work; a longer show is several requests
# a 300-s timeline of one-second prompts of 100 characters each is ~30 kB
MAX_TIMELINE_CHARS = 100_000


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
    # joint targets ((frame, joint, x, y, z), ...) sorted; empty = free motion (stablemo.control.JointControl)
    control: tuple = ()
    # where `frames` came from: "given" (seconds or frames), "text" (the bundle's length predictor) or
    # "default" (a bundle without one), as the answer says it
    length_from: str = "given"
    # a prompt that says an order is generated part by part, a turn sized by its words (Request.plan);
    # false: the network reads it whole
    plan: bool = True


@dataclass
class Motion:
    """A generated motion: joints (T, J, 3) and features (T, D) float32, plus what made it, and its
    BVH rig (stablemo.bvh.Export: the download's animation and its fit to the joints), made with
    it so that the page can say beside the BVH button whether the file would differ."""

    spec: Spec
    joints: np.ndarray
    features: np.ndarray
    fps: float
    info: dict
    seconds: float = 0.0  # compute time of the job (queue time excluded)
    bvh: Any = None  # stablemo.bvh.Export
    root_path: np.ndarray = field(init=False)

    def __post_init__(self):
        self.root_path = self.joints[:, 0, :]  # (T, 3) pelvis

    def file_name(self, fmt: str) -> str:
        """The download's file name: `<prompt slug>-seed<seed>.<fmt>`."""
        from stablemo.outputs.files import slugify

        return f"{slugify(self.spec.text)}-seed{self.spec.seed}.{fmt}"

    def warnings(self) -> list[str]:
        """One line for a prompt unlike the model's training texts (stablemo.text.familiar), and one
        per download that would be more than 3 cm from the motion (stablemo.bvh.fit)."""
        from stablemo.text.familiar import Unfamiliar

        lines = [Unfamiliar(**u).message() for u in self.info.get("unfamiliar", [])]
        line = self.bvh.fit.warning(self.file_name("bvh"), "the joints .npy download is exact") if self.bvh else None
        return lines + ([line] if line else [])


class ServedModel:
    """A loaded bundle with its name and what the page needs to know of it."""

    def __init__(self, name: str, path: Path, pipeline):
        self.name, self.path, self.pipeline = name, path, pipeline

    def describe(self) -> dict:
        from stablemo.bvh.names import rest_joints
        from stablemo.motion.skeleton import get_skeleton

        pipe = self.pipeline
        skel = get_skeleton(pipe.skeleton)
        inf = pipe.inference
        kind = pipe.config.get("kind", "diffusion")
        return {
            "name": self.name,
            "label": f"{self.name} ({kind}, {inf.steps} step{'s' if inf.steps != 1 else ''})",
            "kind": kind,
            "bundle": self.path.name,  # the folder's name only: the page has no use for this machine's paths
            "fps": pipe.fps,
            "min_frames": pipe.min_length,
            "max_frames": pipe.max_length,
            # the length of a motion with no length and no text to predict one from (a path drawn first)
            "default_frames": pipe.inference.default_frames,
            "samplers": sorted(pipe.samplers),
            "defaults": {"sampler": inf.sampler, "steps": inf.steps, "cfg": inf.cfg},
            "skeleton": {"name": skel.name, "units": skel.units, "joints": list(skel.joint_names),
                         "parents": list(skel.parents), "chains": [list(c) for c in skel.kinematic_chains],
                         "sides": [skel.side_of_chain(i) for i in range(len(skel.kinematic_chains))],
                         # where the figure stands before the first motion: the bundle's body at rest
                         "rest": rest_joints(skel, pipe.finish.bone_lengths).round(4).tolist()},
        }


class ModelSet:
    """Named bundles, loaded once each; the first is the default. `generate` is not re-entrant
    (one worker calls it); the result cache is locked because downloads read it from another."""

    def __init__(self, bundles: dict[str, str | Path], device: str | None = None, cache_size: int = 16):
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

    def _model_of(self, body: Any, known: set[str]) -> tuple[str, Pipeline]:
        """(model name, its pipeline) of a JSON request object whose fields are all in `known`."""
        if not isinstance(body, dict):
            raise StableMoError("request: expected a JSON object")
        unknown = sorted(set(body) - known)
        if unknown:
            raise StableMoError(f"{field_name(unknown[0])}: unknown field (known: {', '.join(sorted(known))})")
        name = body.get("model") or self.default
        if not isinstance(name, str) or name not in self.models:  # (a list is not even hashable)
            raise StableMoError(f"model: unknown {json_short(name)}; served: {', '.join(self.models)}")
        return name, self.models[name].pipeline

    def parse(self, body: Any) -> tuple[Spec, dict]:
        """A JSON request body -> (Spec, transport options). Every error names the field, one line."""
        name, pipe = self._model_of(body, {"text", "seconds", "frames", "seed", "model", "sampler", "steps", "cfg",
                                            "footskate", "control", "encoding", "features", "format", "plan"})
        text = body.get("text")
        if not isinstance(text, str):
            raise StableMoError(f"text: expected a string, got {_json_type(text)}")
        if not text.strip():
            raise StableMoError("text: empty prompt")
        if len(text) > MAX_TEXT_CHARS:
            raise StableMoError(f"text: {len(text)} characters, at most {MAX_TEXT_CHARS}")
        frames, length_from = _frames(body, pipe, text.strip())
        seed = check_seed("seed", body.get("seed", 0))
        sampler = body.get("sampler")
        if sampler is not None and sampler not in pipe.samplers:
            raise StableMoError(f"sampler: unknown {json_short(sampler)}; choose from {sorted(pipe.samplers)}")
        steps = body.get("steps")
        if steps is not None:
            if isinstance(steps, bool) or not isinstance(steps, int):
                raise StableMoError(f"steps: expected a whole number, got {json_short(steps)}")
            check_positive_int("steps", steps)
        cfg = body.get("cfg")
        if cfg is not None:
            cfg = check_finite("cfg", _number("cfg", cfg), low=0.0, high=100.0)
        footskate = body.get("footskate", False)
        if not isinstance(footskate, bool):
            raise StableMoError(f"footskate: expected true or false, got {json_short(footskate)}")
        plan = body.get("plan", True)
        if not isinstance(plan, bool):
            raise StableMoError(f"plan: expected true or false, got {json_short(plan)}")
        control = _control(body.get("control"), frames, pipe.skeleton)
        encoding = body.get("encoding", "lists")
        if encoding not in ENCODINGS:
            raise StableMoError(f"encoding: expected one of {', '.join(ENCODINGS)}, got {json_short(encoding)}")
        features = body.get("features", True)
        if not isinstance(features, bool):
            raise StableMoError(f"features: expected true or false, got {json_short(features)}")
        spec = Spec(name, text.strip(), frames, seed, sampler, steps, cfg, footskate, control, length_from, plan)
        # the pipeline's own checks (steps the sampler can run, targets against the motion, ...)
        # before the job is queued
        try:
            pipe.resolve(self._request(spec, hooks=()))
        except StableMoError as err:  # the pipeline names per-prompt lists; one prompt here
            message = str(err).replace("control[0]", "control", 1).replace("texts[0]", "text", 1)
            raise StableMoError(message) from None
        return spec, {"encoding": encoding, "features": features, "format": body.get("format")}

    def _request(self, spec: Spec, hooks) -> Request:
        control = None
        if spec.control:
            control = [control_from_targets(spec.control, spec.frames, self.models[spec.model].pipeline.skeleton)]
        # a length the text chose is asked for as none, so a prompt in parts takes its parts' lengths
        frames = None if spec.length_from == "text" and not spec.control else spec.frames
        return Request([spec.text], frames, seed=spec.seed, sampler=spec.sampler, steps=spec.steps,
                       cfg=spec.cfg, hooks=hooks, control=control, plan=spec.plan)

    def warm_up(self, name: str) -> None:
        """One generation at the default length, uncached: first-call costs are paid at start-up."""
        pipe = self.models[name].pipeline
        pipe.generate(Request(["a person walks forward"], pipe.inference.default_frames))

    def parse_stream(self, body: Any, download: bool = False) -> StreamJob:
        """A JSON timeline request -> a StreamJob whose chunks are computed when pulled. Every error
        (fields, the timeline, the chunk settings against the model) is raised here, before any chunk.
        download: the body may name a `format` (/api/download of a streamed motion)."""
        known = {"timeline", "chunk_seconds", "seed", "model", "sampler", "steps", "cfg", "encoding"}
        name, pipe = self._model_of(body, known | ({"format"} if download else set()))
        text = body.get("timeline")
        if not isinstance(text, str) or not text.strip():
            raise StableMoError("timeline: expected the timeline's text, lines 'start_s end_s prompt' "
                                "(or the page's '<seconds> <prompt>')")
        if len(text) > MAX_TIMELINE_CHARS:
            raise StableMoError(f"timeline: {len(text)} characters, at most {MAX_TIMELINE_CHARS}")
        # the one timeline parser (the CLI's); the page's shorthand lines are converted, and the
        # canonical text goes back to the page in the stream's first line
        segments = parse_timeline(text, "timeline", shorthand=True)
        for i, seg in enumerate(segments):
            if len(seg.text) > MAX_TEXT_CHARS:
                raise StableMoError(f"timeline: prompt {i + 1}: {len(seg.text)} characters, at most {MAX_TEXT_CHARS}")
        if segments[-1].end_s > MAX_STREAM_SECONDS:
            raise StableMoError(f"timeline: {segments[-1].end_s:g} s in all, at most {MAX_STREAM_SECONDS:g} s")
        chunk = check_finite("chunk_seconds", _number("chunk_seconds", body.get("chunk_seconds", 2.0)), low=0.0, strict=True)
        chunk_length(pipe, chunk)  # a tiny chunk would be billions of them
        seed = check_seed("seed", body.get("seed", 0))
        steps = body.get("steps")
        if steps is not None and (isinstance(steps, bool) or not isinstance(steps, int)):
            raise StableMoError(f"steps: expected a whole number, got {json_short(steps)}")
        cfg = None if body.get("cfg") is None else check_finite("cfg", _number("cfg", body["cfg"]), low=0.0, high=100.0)
        sampler = body.get("sampler")
        encoding = body.get("encoding", "lists")
        if encoding not in ENCODINGS:
            raise StableMoError(f"encoding: expected one of {', '.join(ENCODINGS)}, got {json_short(encoding)}")
        pipe.resolve(Request([segments[0].text], pipe.max_length, seed=seed, sampler=sampler, steps=steps, cfg=cfg))
        stream = stream_timeline(pipe, segments, chunk_seconds=chunk, seed=seed, steps=steps, sampler=sampler, cfg=cfg,
                                 source="timeline")  # checks the seeds of every window too
        spec = StreamSpec(name, format_timeline(segments), chunk, seed, sampler, steps, cfg)
        return StreamJob(spec, canonical_timeline(text), stream, self._recorded(spec, stream, pipe), pipe.fps,
                         encoding, body.get("format"))

    def _recorded(self, spec: StreamSpec, stream, pipe) -> Iterator:
        """The stream's chunks, passed on as they come; once the last one is out, the whole motion
        goes into the cache of recent motions, so a download of it re-uses what the page received."""
        start, joints = time.perf_counter(), []
        for chunk in stream.chunks:
            joints.append(chunk.joints)
            yield chunk
        info = {"skeleton": pipe.skeleton, "segments": [vars(s) for s in stream.plan.segments]}
        joints = np.concatenate(joints)  # (N, J, 3): what the page received
        # the features file recovers to these joints (a chunk's features are its window's)
        self._remember(self._motion(spec, joints, whole_features(pipe, joints), pipe, info, time.perf_counter() - start))

    def stream_motion(self, job: StreamJob) -> tuple[Motion, bool]:
        """(the whole motion of a checked timeline, whether it came from the cache): a stream the page
        received is there; otherwise every chunk is made now (the same arrays: same seeds, same code)."""
        with self._lock:
            if job.spec in self._cache:
                self._cache.move_to_end(job.spec)
                return self._cache[job.spec], True
        for _ in job.chunks:
            pass
        with self._lock:
            return self._cache[job.spec], False

    # ---- generation ----------------------------------------------------------------------------

    def generate(self, spec: Spec) -> tuple[Motion, bool]:
        """(the motion of a checked spec, whether it came from the cache of recent motions): the
        same spec always gives the same arrays, so a download re-uses what the page shows."""
        with self._lock:
            if spec in self._cache:
                self._cache.move_to_end(spec)
                return self._cache[spec], True
        from stablemo.inference.hooks import make_hooks

        pipe = self.models[spec.model].pipeline
        start = time.perf_counter()
        result = pipe.generate(self._request(spec, hooks=make_hooks(pipe, footskate=spec.footskate)))
        joints = result.joint_list()[0].astype(np.float32)  # (T, J, 3)
        info = dict(result.info, skeleton=pipe.skeleton)
        if spec.control:
            info["control"] = control_report(spec.control, joints, pipe)
        motion = self._motion(spec, joints, result.feature_list()[0].astype(np.float32), pipe, info,
                              time.perf_counter() - start)
        self._remember(motion)
        return motion, False

    @staticmethod
    def _motion(spec, joints: np.ndarray, features: np.ndarray, pipe, info: dict, seconds: float) -> Motion:
        from stablemo.bvh import export_motion

        # ~8 ms for the longest motion on the 2-core machine: cheap beside the model, and the page
        # learns with the motion whether its BVH would differ from it
        rig = export_motion(joints, skeleton=pipe.skeleton, source_fps=pipe.fps, bone_lengths=pipe.finish.bone_lengths)
        return Motion(spec, joints, features, pipe.fps, info, seconds=seconds, bvh=rig)

    def _remember(self, motion: Motion) -> None:
        with self._lock:
            self._cache[motion.spec] = motion
            while len(self._cache) > self._cache_size:
                self._cache.popitem(last=False)


@dataclass(frozen=True)
class StreamSpec:
    """What decides a streamed motion (the key of the cache of recent motions, beside Spec):
    timeline: its canonical text (stablemo.timeline.format_timeline)."""

    model: str
    timeline: str
    chunk_seconds: float
    seed: int
    sampler: str | None = None
    steps: int | None = None
    cfg: float | None = None

    @property
    def text(self) -> str:
        """A title for the motion and its file name: the prompts in order."""
        return "timeline " + " | ".join(line.split(None, 2)[2] for line in self.timeline.splitlines())


@dataclass
class StreamJob:
    """A checked timeline: `stream` (stablemo.timeline.TimelineStream: its plan and chunk spans) and
    `chunks`, its lazy iterator of stablemo.timeline.Chunk that caches the whole motion at its end;
    timeline: the request's text with the page's shorthand lines written out."""

    spec: StreamSpec
    timeline: str
    stream: Any
    chunks: Iterator
    fps: float
    encoding: str
    format: Any = None

    @property
    def model(self) -> str:
        return self.spec.model

    @property
    def frames(self) -> int:
        return self.stream.frames

    def header(self) -> dict:
        """The first line of /api/stream: what is coming."""
        plan = self.stream.plan
        return {"model": self.model, "fps": self.fps, "frames": self.frames, "chunks": len(self.stream.spans),
                "timeline": self.timeline, "segments": [vars(s) for s in plan.segments],
                "texts": [plan.segments[s.segment].text for s in self.stream.spans]}


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
        "model": spec.model, "text": spec.text, "seed": spec.seed, "frames": len(motion.joints),
        "length_from": spec.length_from, "fps": motion.fps,
        "sampler": motion.info["sampler"], "steps": motion.info["steps"], "cfg": motion.info["cfg"],
        "footskate": spec.footskate, "joints": encode_array(motion.joints, encoding),
    }
    if "control" in motion.info:
        out["control"] = motion.info["control"]
    # its parts [{text, start, end, rest}] when the prompt was generated part by part, else null
    out["plan"] = (motion.info.get("plans") or [None])[0]
    # the turns its words sized and the body was turned by [{text, degrees, side, start, end}], else null
    out["turns"] = (motion.info.get("turns") or [None])[0]
    out["warnings"] = motion.warnings()
    if features:
        out["features"] = encode_array(motion.features, encoding)
    return out


def _control(value: Any, frames: int, skeleton: str) -> tuple:
    """{"targets": [[frame, joint, x, y, z], ...]} -> sorted tuple of targets (frame, joint ints;
    positions in metres, in the motion's frame: it starts at the origin facing +z)."""
    if value is None:
        return ()
    from stablemo.motion.skeleton import get_skeleton

    if not isinstance(value, dict) or set(value) != {"targets"} or not isinstance(value["targets"], list):
        raise StableMoError('control: expected {"targets": [[frame, joint, x, y, z], ...]}')
    joints = get_skeleton(skeleton).num_joints
    targets = value["targets"]
    if len(targets) > frames * joints:
        raise StableMoError(f"control.targets: {len(targets)} targets, more than the motion's {frames} x {joints} (frame, joint) pairs")
    out = {}
    for i, item in enumerate(targets):
        where = f"control.targets[{i}]"
        if not isinstance(item, list) or len(item) != 5:
            raise StableMoError(f"{where}: expected [frame, joint, x, y, z], got {json_short(item)}")
        frame, joint = item[0], item[1]
        for name, v, high in (("frame", frame, frames - 1), ("joint", joint, joints - 1)):
            if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= high:
                raise StableMoError(f"{where}: {name} must be a whole number in [0, {high}], got {json_short(v)}")
        xyz = tuple(_number(f"{where}: position", v) for v in item[2:])
        if (frame, joint) in out:
            raise StableMoError(f"{where}: frame {frame}, joint {joint} is given twice")
        out[frame, joint] = xyz
    return tuple((f, j, *xyz) for (f, j), xyz in sorted(out.items()))


# a target the motion misses by more than this is said to be missed, not reached (the BVH's
# tolerance, stablemo.bvh.fit: what a viewer would notice)
REACHED_M = 0.03


def control_report(control: tuple, joints: np.ndarray, pipe) -> dict:
    """How close the motion came to its targets (metres), the pace they ask of the body and, when
    the page should not say "reached", one line saying why (`note`): targets faster than a body
    follows (it slides along them: stablemo.motion.plausible.FOLLOW_SPEED_M_S), or missed."""
    from stablemo.motion.plausible import FOLLOW_SPEED_M_S, target_pace

    t = np.array(control, dtype=np.float64)  # (N, 5): frame, joint, x, y, z
    frames, which = t[:, 0].astype(int), t[:, 1].astype(int)
    err = np.linalg.norm(joints[frames, which] - t[:, 2:], axis=-1)
    pace = target_pace(frames, which, t[:, 2:], pipe.skeleton, pipe.finish.bone_lengths)
    note = None
    if pace > FOLLOW_SPEED_M_S:
        note = (f"too fast to follow: the targets ask for {pace:.1f} m/s, more than a body keeps up "
                f"({FOLLOW_SPEED_M_S:g} m/s, a jog), so it slides along them; draw a shorter path or make the "
                "motion longer")
    elif err.max() > REACHED_M:
        note = f"targets missed by up to {100 * err.max():.1f} cm (on average {100 * err.mean():.1f} cm)"
    return {"targets": len(t), "mean_error_m": float(err.mean()), "max_error_m": float(err.max()),
            "pace_m_s": round(pace, 3), "limit_m_s": FOLLOW_SPEED_M_S, "note": note}


def control_from_targets(targets: tuple, frames: int, skeleton: str):
    """The JointControl of a Spec's targets: positions (T, J, 3), mask (T, J)."""
    from stablemo.control import JointControl
    from stablemo.motion.skeleton import get_skeleton

    positions = np.zeros((frames, get_skeleton(skeleton).num_joints, 3), np.float32)
    mask = np.zeros(positions.shape[:2], bool)
    for f, j, x, y, z in targets:
        positions[f, j] = (x, y, z)
        mask[f, j] = True
    return JointControl(positions, mask)


def field_name(name: str) -> str:
    """A field's name as an error message starts with it: as is when it looks like one, else quoted
    and cut short (a key may be any JSON string: spaces, newlines, a megabyte)."""
    return name if re.fullmatch(r"[A-Za-z0-9_.-]{1,40}", name) else json_short(name)


def json_short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _frames(body: dict, pipe, text: str) -> tuple[int, str]:
    """(the motion's length in frames, where it came from: "given", "text" or "default"). No length,
    null or "auto" (either field): the text's own (Pipeline.text_lengths)."""
    given = {k: body.get(k) for k in ("seconds", "frames") if body.get(k) not in (None, AUTO)}
    if len(given) == 2:
        raise StableMoError("seconds: give seconds or frames, not both")
    if not given:
        return pipe.text_lengths([text])[0], "text" if pipe.length_predictor is not None else "default"
    if body.get("frames") not in (None, AUTO):
        frames = body["frames"]
        if isinstance(frames, bool) or not isinstance(frames, int):
            raise StableMoError(f"frames: expected a whole number, got {json_short(frames)}")
        flag = ("frames",)
    else:
        seconds = check_finite("seconds", _number("seconds", body["seconds"]), low=0.0, strict=True)
        frames = round(seconds * pipe.fps)
        flag = ("seconds", f"{seconds:g} s is {frames} frames,")
    return pipe.inference.check_length(frames, *flag), "given"


def _number(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise StableMoError(f"{name}: expected a number, got {json_short(value)}")
    if isinstance(value, float) and not math.isfinite(value):
        raise StableMoError(f"{name}: must be a finite number, got {value}")
    return float(value)


def _json_type(value: Any) -> str:
    return {type(None): "null", bool: "a boolean", int: "a number", float: "a number", list: "an array",
            dict: "an object"}.get(type(value), type(value).__name__)
