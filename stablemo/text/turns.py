"""How far a text says the body turns: "a person turns 90 degrees to the left" -> 90 degrees, left.

The demo models turn by what their small networks make of the words, not by the angle said: the
teacher's quarter turns turned 22-69 degrees, its half turns 200-290 and its circles 430-580
(docs/results.md, "Behaviour"). The angle is plain English, as an order is (stablemo.text.plan),
so StableMo reads it there and the body is turned by it (stablemo.control.turn). The words are
data (turns.yaml); the rules, from the most explicit to the least:

1. a number of degrees ("turns 90 degrees", "rotates ninety degrees", "a 180-degree turn");
2. a fraction of a turn ("a quarter turn", "half a circle", "a three-quarter rotation");
3. ending up facing the other way ("spins around to face the other way", "an about-face"): 180;
4. a whole turn ("a full circle", "walks in a circle", "circles clockwise", "a complete rotation"): 360;
5. a spin named without an angle ("spins around", "twirls"): 360;
6. turning around ("turns around", "turns all the way around"): 180;
7. turning to a side ("turns left", "turns to his right", "makes a right turn"): 90.

A text that says two turns of the rule that read it, or a turn of no stated size ("slightly",
"in circles", "turns his head", "twice"; turns.yaml `vague`), or names no turn, reads as None: the
network's own turn is kept. The side ("left"/"right"; counterclockwise is left) is read where the
text names exactly one.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources

import yaml

from stablemo.text.phrases import alternatives

PACKAGED = "turns.yaml"
HYPHEN_OR_SPACE = r"[\s-]+"  # between number and fraction words: "forty-five" = "forty five"


@dataclass(frozen=True)
class AskedTurn:
    """The turn a text asks for: degrees > 0 and the side ("left", "right" or None: not said)."""

    degrees: float
    side: str | None


def _bounded(pattern: str) -> re.Pattern:
    return re.compile(rf"(?<![\w-])(?:{pattern})(?![\w-])", re.IGNORECASE)


@dataclass(frozen=True)
class _Rules:
    rules: tuple[tuple[re.Pattern, object], ...]  # (pattern, degrees or None: the number it holds)
    vague: re.Pattern
    left: re.Pattern
    right: re.Pattern


@lru_cache(maxsize=1)
def _rules() -> _Rules:
    raw = yaml.safe_load(resources.files("stablemo.text").joinpath(PACKAGED).read_text(encoding="utf-8"))
    verb, noun, side = (alternatives(words) for words in (raw["verbs"], raw["nouns"], raw["left"] + raw["right"]))
    fill = rf"(?:\s+(?:{alternatives(raw['fillers'])}))*"
    numbers = {_key(k): int(v) for k, v in raw["numbers"].items()}
    number = rf"\d+(?:\.\d+)?|{alternatives(numbers, HYPHEN_OR_SPACE)}"
    fractions = {_key(k): int(v) for k, v in raw["fractions"].items()}
    rules = [
        # 1. degrees: "90 degrees", "ninety-degree", "180°"
        (_bounded(rf"(?P<n>{number})(?:\s*-\s*|\s+)?(?:degrees?|deg|°)"), numbers),
        # 2. fractions: "a quarter turn", "half a turn", "half of a circle", "three-quarter rotation"
        (_bounded(rf"(?P<f>{alternatives(fractions, HYPHEN_OR_SPACE)})(?:\s*-\s*|\s+)(?:(?:a|of\s+a|an)\s+)?(?:{noun})s?"), fractions),
        (_bounded(alternatives(raw["opposite"])), 180),
        (_bounded(rf"(?:{alternatives(raw['whole'])})\s+(?:{noun})|an?\s+(?:(?:{side}|{alternatives(raw['circle_adjectives'])})\s+)?"
                  rf"(?:{alternatives(raw['circle_nouns'])})|{alternatives(raw['circle_verbs'])}"), 360),
        (_bounded(alternatives(raw["spin"])), 360),
        (_bounded(rf"(?:{verb}){fill}\s+(?:around|round)"), 180),
        (_bounded(rf"(?:{verb}){fill}\s+(?:{side})|(?:makes?|takes?|making|taking|does|doing)\s+an?\s+(?:{side})\s+turn"), 90),
    ]
    vague, left, right = (_bounded(alternatives(raw[key])) for key in ("vague", "left", "right"))
    return _Rules(tuple(rules), vague, left, right)


def asked_turn(text: str) -> AskedTurn | None:
    """The turn `text` asks for (see the module docstring), or None when it says none it can size."""
    rules = _rules()
    if rules.vague.search(text):
        return None
    for pattern, value in rules.rules:
        found = list(pattern.finditer(text))
        if not found:
            continue
        if len(found) > 1:
            return None  # two turns said the same way: their total is not one turn's angle
        match = found[0]
        if isinstance(value, dict):
            said = _key(next(v for v in match.groupdict().values() if v is not None))
            degrees = float(said) if said[0].isdigit() else float(value[said])
        else:
            degrees = float(value)
        if not 0 < degrees <= 720:
            return None
        # "counterclockwise" holds "clockwise": the right side is read once the left words are gone
        left, right = bool(rules.left.search(text)), bool(rules.right.search(rules.left.sub(" ", text)))
        return AskedTurn(degrees, "left" if left and not right else "right" if right and not left else None)
    return None


def _key(words: str) -> str:
    """Number and fraction words compared without case or hyphens ("Forty-Five" = "forty five")."""
    return " ".join(words.lower().replace("-", " ").split())


__all__ = ["AskedTurn", "asked_turn"]
