"""A prompt read as a sequence of parts: "a person walks forward, then waves their right hand" ->
["a person walks forward", "a person waves their right hand"].

A denoiser reads a whole prompt at once, and a small one does its parts at the same time: the demo
models waved while they walked, or walked after the wave, in about 70 % of "X, then Y" motions
(docs/results.md, "order"). Said in words, the order is plain English: the words of plan.yaml
("then", "afterwards", "followed by", "before", "Y after X") end one part and start the next. A
split prompt is generated part by part, each window continuing the motion so far
(stablemo.timeline.planned), so the order holds by construction and each part is one action the
network knows.

Inside a split prompt, pieces joined by "and" or a comma are parts too when the piece after the
joint starts with a verb in the third person ("..., then turns left and squats twice"); a prompt
without any of the order words is never split ("crouches down and stands back up" is one action,
and "walks and waves" may be meant at once). A later part that starts with a verb gets the first
part's subject ("a man"), so each part reads as a whole sentence.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources

import yaml

from stablemo.text.phrases import alternatives

PACKAGED = "plan.yaml"


@dataclass(frozen=True)
class PlanWords:
    """The words of plan.yaml, and the settings of how long parts are."""

    then: tuple[str, ...]
    after: tuple[str, ...]
    noun_after: tuple[str, ...]
    first: tuple[str, ...]
    not_verbs: frozenset[str]
    before_verb: frozenset[str]
    pronouns: tuple[str, ...]
    max_subject_words: int
    rest_text: str
    rest_quantile: float
    min_rest_s: float


@lru_cache(maxsize=1)
def plan_words() -> PlanWords:
    """plan.yaml, shipped with the package."""
    raw = yaml.safe_load(resources.files("stablemo.text").joinpath(PACKAGED).read_text(encoding="utf-8"))
    return PlanWords(tuple(raw["then"]), tuple(raw["after"]), tuple(raw["noun_after"]), tuple(raw["first"]),
                     frozenset(raw["not_verbs"]), frozenset(raw["before_verb"]), tuple(raw["pronouns"]),
                     int(raw["max_subject_words"]), str(raw["rest_text"]), float(raw["rest_quantile"]),
                     float(raw["min_rest_s"]))


def _is_verb(word: str, words: PlanWords) -> bool:
    """A third-person verb, as far as a word alone tells: lower case, ending in 's', not a known other."""
    w = word.lower().strip(",.;!")
    return len(w) >= 3 and w.endswith("s") and not w.endswith("ss") and w.isalpha() and w not in words.not_verbs


def _gerund(word: str) -> bool:
    w = word.lower().strip(",.;!")
    return len(w) >= 5 and w.endswith("ing") and w.isalpha()


def _clean(piece: str) -> str:
    return re.sub(r"\s+", " ", piece).strip(" ,;.")


def _verbish(word: str, words: PlanWords) -> bool:
    """A third-person verb, a gerund or a past tense, as far as a word alone tells."""
    w = word.lower().strip(",.;!")
    return _is_verb(w, words) or _gerund(w) or (len(w) > 4 and w.endswith("ed") and w.isalpha())


def _has_verb(piece: str, words: PlanWords) -> bool:
    """Whether a piece says an action of its own."""
    return any(_verbish(w, words) for w in piece.split())


def split_parts(text: str, words: PlanWords | None = None) -> list[str]:
    """The parts of `text` in the order they happen (one part, the text itself, when it says no order).
    Every part after an order word must say an action of its own (a verb), except after words like
    "followed by" that take a noun ("followed by a walk"); else the prompt stays whole ("kicks with the
    left leg, then the right" is one action)."""
    words = words or plan_words()
    then = re.compile(rf"((?:,\s*|\s+)(?:and\s+)?\b(?:{alternatives(words.then)})\b\s*,?)", re.IGNORECASE)
    after = re.compile(rf"(?:,\s*|\s+)\b(?:{alternatives(words.after)})\b\s+", re.IGNORECASE)
    noun_after = re.compile(rf"\b(?:{alternatives(words.noun_after)})\b", re.IGNORECASE)
    leading = re.compile(rf"^\s*(?:(?:and\s+)?\b(?:{alternatives(words.then)})\b\s*,?\s*)+", re.IGNORECASE)
    whole = [_clean(text)] if _clean(text) else [text]
    split = then.split(text)  # [piece, separator, piece, ...]
    # "..., and then finally sits down": an order word left at a piece's start goes with the separator
    pieces, separators = [split[0]] + [leading.sub("", p) for p in split[2::2]], split[1::2]
    if len(pieces) > 1 and not _has_verb(pieces[0], words):  # "a person then jumps": one action
        return whole
    if len(pieces) == 1:  # "Y after X": X first; only where no other order word is said
        pieces = [p for p in after.split(text) if _clean(p)]
        if len(pieces) != 2 or not all(_has_verb(p, words) for p in pieces):
            return whole
        pieces = pieces[::-1]
    else:
        kept = [pieces[0]]
        for sep, piece in zip(separators, pieces[1:]):
            if not _clean(piece):
                continue
            if not (_has_verb(piece, words) or noun_after.search(sep)):
                return whole
            kept.append(piece)
        pieces = [p for p in kept if _clean(p)]
    if len(pieces) == 1:
        return whole
    parts: list[str] = []
    for piece in pieces:  # "jumps once, claps twice" / "turns left and squats twice"
        parts.extend(_split_joined(piece, words))
    subject = _subject(text, words)  # the sentence's own subject, whichever part comes first
    out = []
    for part in [_with_subject(_drop_first(p, words) if i == 0 else p, subject, words) for i, p in enumerate(parts)]:
        part = _clean(part)
        if part:
            out.append(part)
    return out if len(out) > 1 else whole


def _split_joined(piece: str, words: PlanWords) -> list[str]:
    """A piece of a split prompt cut where ", " or " and " is followed by a third-person verb."""
    out, start = [], 0
    for m in re.finditer(r"(?:,\s*(?:and\s+)?|\s+and\s+)(?=(\S+))", piece):
        if _is_verb(m.group(1), words):
            out.append(piece[start:m.start()])
            start = m.end()
    out.append(piece[start:])
    return [p for p in out if _clean(p)]


def _subject(part: str, words: PlanWords) -> str:
    """The words before the first part's verb ("a man"), if they are few; else ""."""
    tokens = _clean(part).split()
    for i, token in enumerate(tokens):
        lower = token.lower()
        if i and (_verbish(token, words) or lower in words.before_verb or lower in words.first):
            subject = tokens[:i]
            return " ".join(subject) if 0 < len(subject) <= words.max_subject_words else ""
    return ""


def _drop_first(part: str, words: PlanWords) -> str:
    return re.sub(rf"\b(?:{alternatives(words.first)})\b\s*,?", "", part, count=1, flags=re.IGNORECASE)


def _with_subject(part: str, subject: str, words: PlanWords) -> str:
    """A later part that starts with a verb ("squats twice", "walking forward") gets the subject."""
    part = _clean(part)
    if not subject or not part:
        return part
    head = part.split()[0]
    lower = part.lower()
    if any(lower == p or lower.startswith(p + " ") for p in words.pronouns):
        return part
    if _verbish(head, words):
        return f"{subject} {part}"
    return part


__all__ = ["PlanWords", "plan_words", "split_parts"]
