"""The behaviour suite's prompt table: prompts.yaml (shipped in this package), read and checked.

A prompt names the synthetic actions it asks for (`parts`, in order, with the caption parameters
its text fixes), the attributes it is scored on (`tests`) and its split. The expected value of each
attribute is derived from the parts (count=2, side=right, direction=backward, angle=90,
order=[walk, wave], ...), so the table says each fact once.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
import yaml

from stablemo.data.synth.actions import ACTIONS, sample_params
from stablemo.errors import StableMoError

PACKAGED = "prompts.yaml"
ATTRIBUTES = ("action", "count", "side", "direction", "angle", "speed", "body_part", "order")
SPLITS = ("suite", "held_out")
# the body part a prompt of the action names ("kicks with the left leg", "claps his hands")
BODY_PARTS = {"hop": "foot", "kick": "leg", "wave": "hand", "raise_arms": "arm", "punch": "fist",
              "clap": "hands", "bow": "waist"}
SIDE_PARAM = {"hop": "leg", "kick": "leg", "wave": "hand", "raise_arms": "hand", "punch": "hand", "walk": "waving"}
FORWARD_GAITS = ("walk", "jog", "run", "jump_forward")


@dataclass(frozen=True)
class Part:
    action: str
    params: dict  # caption parameters the text fixes; a ground-truth motion draws the rest


@dataclass(frozen=True)
class Prompt:
    text: str
    parts: tuple[Part, ...]
    tests: dict  # attribute -> expected value, in ATTRIBUTES order
    split: str

    @property
    def actions(self) -> list[str]:
        return [p.action for p in self.parts]

    def describe(self) -> str:
        """`count=2, side=right` (the attributes and what they expect)."""
        return ", ".join(f"{k}={'>'.join(v) if isinstance(v, list) else v}" for k, v in self.tests.items())


def expected(attribute: str, parts: tuple[Part, ...]):
    """The value `attribute` must take for these parts; KeyError where the text fixes none."""
    if attribute == "order":
        if len(parts) < 2:
            raise KeyError("order needs two or three parts")
        return [p.action for p in parts]
    if len(parts) != 1:
        raise KeyError(f"{attribute} is scored on single-action prompts (composites test their order)")
    action, p = parts[0].action, parts[0].params
    if attribute == "action":
        return action
    if attribute == "count":
        return int(p["count"])
    if attribute == "side":
        return str(p[SIDE_PARAM[action]])
    if attribute == "direction":
        if action in FORWARD_GAITS:
            return "forward"
        if action == "walk_backward":
            return "backward"
        return str(p["mode" if action == "raise_arms" else "direction"])
    if attribute == "angle":
        return 360 if action == "circle" else int(p["angle"])
    if attribute == "speed":
        return action if action in ("jog", "run") else str(p["speed_label"])
    if attribute == "body_part":
        return BODY_PARTS[action]
    raise KeyError(attribute)


def _param_keys(action: str) -> set[str]:
    return set(sample_params(action, np.random.default_rng(0)))


def _entry(raw, where: str) -> Prompt:
    if not isinstance(raw, dict) or not {"text", "parts", "tests", "split"} <= set(raw):
        raise StableMoError(f"{where}: expected a mapping with text, parts, tests and split")
    text = raw["text"]
    if not isinstance(text, str) or not text.strip():
        raise StableMoError(f"{where}: text must be a non-empty string")
    where = f"{where} ({text!r})"
    if raw["split"] not in SPLITS:
        raise StableMoError(f"{where}: split must be one of {', '.join(SPLITS)}, got {raw['split']!r}")
    if not isinstance(raw["parts"], list) or not 1 <= len(raw["parts"]) <= 3:
        raise StableMoError(f"{where}: parts must list one to three actions")
    parts = []
    for part in raw["parts"]:
        if not isinstance(part, dict) or part.get("action") not in ACTIONS:
            raise StableMoError(f"{where}: each part needs an action of {', '.join(ACTIONS)}, got {part!r}")
        params = {k: v for k, v in part.items() if k != "action"}
        unknown = set(params) - _param_keys(part["action"])
        if unknown:
            raise StableMoError(f"{where}: {part['action']} has no parameter {min(unknown)!r}")
        parts.append(Part(part["action"], params))
    parts = tuple(parts)
    tests = raw["tests"]
    if not isinstance(tests, list) or not tests or any(t not in ATTRIBUTES for t in tests):
        raise StableMoError(f"{where}: tests must list attributes of {', '.join(ATTRIBUTES)}, got {tests!r}")
    values = {}
    for attribute in sorted(set(tests), key=ATTRIBUTES.index):
        try:
            values[attribute] = expected(attribute, parts)
        except KeyError as err:
            raise StableMoError(f"{where}: cannot test {attribute} ({err.args[0]})") from None
    return Prompt(text.strip(), parts, values, raw["split"])


def load_prompts(path: str | Path | None = None) -> list[Prompt]:
    """The prompt table: the packaged prompts.yaml, or a file of the same layout."""
    if path is None:
        name, text = f"stablemo/eval/behaviour/{PACKAGED}", resources.files(__package__).joinpath(PACKAGED).read_text()
    else:
        name = str(path)
        try:
            text = Path(path).read_text(encoding="utf-8")
        except OSError as err:
            raise StableMoError(f"{name}: cannot read the prompt table ({err.strerror or err})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise StableMoError(f"{name}: not valid YAML ({str(err).splitlines()[0]})") from None
    if not isinstance(data, dict) or not isinstance(data.get("prompts"), list) or not data["prompts"]:
        raise StableMoError(f"{name}: expected a mapping with a non-empty 'prompts' list")
    prompts = [_entry(raw, f"{name}: prompt {i + 1}") for i, raw in enumerate(data["prompts"])]
    seen = set()
    for i, p in enumerate(prompts):
        if p.text in seen:
            raise StableMoError(f"{name}: prompt {i + 1} ({p.text!r}) appears twice")
        seen.add(p.text)
    return prompts


__all__ = ["ATTRIBUTES", "BODY_PARTS", "SPLITS", "Part", "Prompt", "expected", "load_prompts"]
