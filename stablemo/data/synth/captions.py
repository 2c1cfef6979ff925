"""Captions for synthetic motions: paraphrased phrases per action, composites, word/POS tokens.

Every phrase names the action and, where the action has them, its direction, speed, side and
count, so a caption determines what happens. Tokens follow HumanML3D's `word/POS` format
(spaCy's coarse tags, verbs and nouns lemmatised) from a small rule-based tagger.
"""

from __future__ import annotations

import functools
import re
from pathlib import Path

import numpy as np
import yaml

from stablemo.data.synth import path_walks

NUMBER_WORDS = {1: "one", 2: "two", 3: "three", 4: "four", 5: "five"}
TIMES_WORDS = {1: "once", 2: "twice", 3: "three times", 4: "four times", 5: "five times"}
SUBJECTS = (("a person", "their"), ("a man", "his"), ("a woman", "her"), ("someone", "their"),
            ("the person", "their"), ("a figure", "its"), ("the man", "his"), ("a human", "their"))


# The vocabulary of the captions (`stablemo data synth --captions`): the plain generator's phrases, or
# those together with captions_varied.yaml's (more subjects and more phrasings of every action; the
# plain sentences stay writable). A dataset's motions do not depend on it (compose.generate_plan).
CAPTION_MODES = {"plain": "the generator's phrasings (the data the demo models were trained on)",
                 "varied": "the plain phrasings and captions_varied.yaml's other subjects and phrasings"}
DEFAULT_CAPTIONS = "plain"
VARIED_FILE = Path(__file__).with_name("captions_varied.yaml")


@functools.cache
def _varied() -> dict:
    return yaml.safe_load(VARIED_FILE.read_text())


def _check(mode: str) -> None:
    if mode not in CAPTION_MODES:
        raise ValueError(f"captions={mode!r}: one of {', '.join(CAPTION_MODES)}")


@functools.cache
def subjects(mode: str = DEFAULT_CAPTIONS) -> tuple[tuple[str, str], ...]:
    """(subject, possessive) pairs a caption may start with."""
    _check(mode)
    if mode == "plain":
        return SUBJECTS
    return SUBJECTS + tuple((s, pron) for s, pron in _varied()["subjects"])


def _side(d: str) -> str:
    return {"left": "left", "right": "right"}[d]


def phrases(action: str, p: dict, pron: str, mode: str = DEFAULT_CAPTIONS) -> list[str]:
    """Paraphrases (third person, present tense) of one action with its parameters, in the caption
    vocabulary `mode` (CAPTION_MODES)."""
    _check(mode)
    out = _plain_phrases(action, p, pron)
    return out + _varied_phrases(action, p, pron) if mode == "varied" else out


def _varied_phrases(action: str, p: dict, pron: str) -> list[str]:
    """captions_varied.yaml's phrasings of one action (none for a walk that waves or follows a path)."""
    if action == "walk_path" or action == "walk" and p.get("waving"):
        return []
    templates = _varied()["phrases"][action]
    key = _varied_key(action, p)
    if key is not None:
        templates = templates[key]
    n, hand = p.get("count"), p.get("hand")
    fill = dict(pron=pron, side=p.get("direction"), leg=p.get("leg"), hand=hand,
                n=NUMBER_WORDS.get(n), times=TIMES_WORDS.get(n),
                what="both arms" if hand == "both" else f"the {hand} arm",
                what2="both arms" if hand == "both" else f"{pron} {hand} arm")
    return [t.format(**fill) for t in templates]


def _varied_key(action: str, p: dict) -> str | None:
    """Which of captions_varied.yaml's lists an action's parameters pick (None: the action has one list)."""
    many = "once" if p.get("count") == 1 else "many"
    if action in ("walk", "walk_backward"):
        return p["speed_label"]
    if action == "turn":
        return str(p["angle"])
    if action == "circle":
        return p["direction"]
    if action in ("jump", "jump_forward", "squat"):
        return many
    if action == "raise_arms":
        return p["mode"]
    if action == "wave":
        return "both" if p["hand"] == "both" else "hand"
    if action == "punch":
        return ("both" if p["hand"] == "both" else "hand") + "_" + many
    return None


def _plain_phrases(action: str, p: dict, pron: str) -> list[str]:
    if action == "stand":
        return ["stands still", "stands in place", "stands still and waits", "stands without moving",
                "waits standing in place"]
    if action == "walk":
        out = {
            "slow": ["walks forward slowly", "walks slowly forward", "strolls forward slowly",
                     "slowly walks straight ahead", "takes a slow walk forward"],
            "normal": ["walks forward", "walks straight ahead", "walks forward at a normal pace",
                       "walks forward at a steady pace", "takes a few steps forward"],
            "fast": ["walks forward quickly", "walks briskly forward", "walks fast straight ahead",
                     "quickly walks forward", "walks forward at a brisk pace"],
        }[p["speed_label"]]
        if p.get("waving"):
            h = p["waving"]
            hands = "both hands" if h == "both" else f"the {h} hand"
            hands2 = "both hands" if h == "both" else f"{pron} {h} hand"
            out = [f"{w} while waving {hands}" for w in out[:3]] + [f"{out[3]}, waving {hands2}",
                                                                    f"waves {hands2} while walking forward"
                                                                    + (" slowly" if p["speed_label"] == "slow" else "")]
        return out
    if action == "walk_path":
        return path_walks.phrases(p)
    if action == "walk_backward":
        if p["speed_label"] == "slow":
            return ["walks backward slowly", "slowly walks backwards", "steps backward slowly",
                    "carefully walks backwards"]
        return ["walks backward", "walks backwards", "moves backward with a few steps",
                "steps backwards", "walks back"]
    if action == "walk_sideways":
        d = _side(p["direction"])
        return [f"walks sideways to the {d}", f"side steps to the {d}", f"steps sideways to {pron} {d}",
                f"shuffles sideways to the {d}", f"moves sideways towards the {d}"]
    if action == "jog":
        return ["jogs forward", "jogs straight ahead", "jogs forward at a moderate pace", "jogs ahead",
                "does a short jog forward"]
    if action == "run":
        return ["runs forward", "runs forward fast", "sprints straight ahead", "runs quickly forward",
                "runs straight ahead"]
    if action == "turn":
        d = _side(p["direction"])
        if p["angle"] == 90:
            return [f"turns {d}", f"turns to the {d}", f"turns 90 degrees to the {d}",
                    f"makes a quarter turn to the {d}", f"turns to {pron} {d}"]
        return [f"turns around to the {d}", f"turns 180 degrees to the {d}", f"makes a half turn to the {d}",
                f"turns all the way around to the {d}", f"turns around over {pron} {d} shoulder"]
    if action == "circle":
        if p["direction"] == "clockwise":
            return ["walks in a circle clockwise", "walks in a clockwise circle",
                    "walks around in a circle to the right", "walks a full circle clockwise",
                    "circles clockwise"]
        return ["walks in a circle counterclockwise", "walks in a counterclockwise circle",
                "walks around in a circle to the left", "walks a full circle counterclockwise",
                "circles counterclockwise"]
    if action == "jump":
        n = p["count"]
        if n == 1:
            return ["jumps in place", "jumps once", "does a jump on the spot", "jumps up once",
                    "jumps up and lands in place"]
        return [f"jumps {TIMES_WORDS[n]}", f"jumps {TIMES_WORDS[n]} in place",
                f"does {NUMBER_WORDS[n]} jumps on the spot", f"jumps up and down {TIMES_WORDS[n]}",
                f"jumps in place {TIMES_WORDS[n]}"]
    if action == "jump_forward":
        n = p["count"]
        if n == 1:
            return ["jumps forward", "jumps forward once", "leaps forward", "does a jump forward",
                    "jumps ahead with both feet"]
        return [f"jumps forward {TIMES_WORDS[n]}", f"does {NUMBER_WORDS[n]} jumps forward",
                f"leaps forward {TIMES_WORDS[n]}", f"jumps ahead {TIMES_WORDS[n]} with both feet"]
    if action == "hop":
        leg, n = p["leg"], p["count"]
        return [f"hops on the {leg} leg {TIMES_WORDS[n]}", f"hops {TIMES_WORDS[n]} on {pron} {leg} foot",
                f"stands on the {leg} leg and hops {TIMES_WORDS[n]}",
                f"balances on {pron} {leg} foot and hops {TIMES_WORDS[n]}",
                f"does {NUMBER_WORDS[n]} hops on the {leg} leg"]
    if action == "kick":
        leg = p["leg"]
        return [f"kicks with the {leg} leg", f"kicks forward with {pron} {leg} foot",
                f"does a front kick with the {leg} leg", f"kicks the {leg} leg forward",
                f"lifts {pron} {leg} leg and kicks"]
    if action == "squat":
        n = p["count"]
        if n == 1:
            return ["squats down once", "does a squat", "squats down and stands back up",
                    "bends the knees into a squat once"]
        return [f"does {NUMBER_WORDS[n]} squats", f"squats {TIMES_WORDS[n]}",
                f"squats down and up {TIMES_WORDS[n]}", f"does {NUMBER_WORDS[n]} squats in a row"]
    if action == "crouch":
        return ["crouches down and stands back up", "crouches low and then rises",
                "crouches down for a moment", "goes down into a crouch and gets back up",
                "crouches down, holds, and stands up"]
    if action == "bow":
        return ["bows", "bows forward", "takes a bow", "bends forward at the waist in a bow",
                "bows and straightens up"]
    if action == "wave":
        h = p["hand"]
        if h == "both":
            return ["waves with both hands", "waves both hands", "raises both arms and waves",
                    "waves both arms above the head"]
        return [f"waves with the {h} hand", f"waves {pron} {h} hand", f"raises the {h} hand and waves",
                f"waves hello with {pron} {h} hand"]
    if action == "raise_arms":
        h, mode = p["hand"], p["mode"]
        what = "both arms" if h == "both" else f"the {h} arm"
        what2 = "both arms" if h == "both" else f"{pron} {h} arm"
        it = "them" if h == "both" else "it"
        where = {"up": "above the head", "sideways": "out to the sides" if h == "both" else "out to the side",
                 "forward": "out in front"}[mode]
        verb = {"up": "raises", "sideways": "raises", "forward": "stretches"}[mode]
        return [f"{verb} {what} {where}", f"lifts {what2} {where}", f"{verb} {what} {where} and lowers {it}",
                f"holds {what} {where} for a moment", f"puts {what2} {where}"]
    if action == "punch":
        h, n = p["hand"], p["count"]
        if h == "both":
            if n == 1:
                return ["punches forward once", "throws a punch", "punches straight ahead once"]
            return [f"punches {TIMES_WORDS[n]} with alternating hands", f"throws {NUMBER_WORDS[n]} punches, alternating hands",
                    f"punches forward {TIMES_WORDS[n]}, left and right", f"throws {NUMBER_WORDS[n]} punches with both fists"]
        if n == 1:
            return [f"punches forward with the {h} hand", f"throws a punch with {pron} {h} fist",
                    f"punches once with the {h} hand", f"does a {h} punch"]
        return [f"punches forward {TIMES_WORDS[n]} with the {h} hand",
                f"throws {NUMBER_WORDS[n]} punches with {pron} {h} fist",
                f"punches {TIMES_WORDS[n]} with the {h} hand", f"does {NUMBER_WORDS[n]} {h} punches"]
    if action == "clap":
        n = p["count"]
        return [f"claps {TIMES_WORDS[n]}", f"claps {pron} hands {TIMES_WORDS[n]}",
                f"claps hands {TIMES_WORDS[n]}", f"claps {NUMBER_WORDS[n]} times in front of the chest"
                if n > 1 else "claps once in front of the chest"]
    raise KeyError(action)


def join(parts: list[str], rng: np.random.Generator) -> str:
    if len(parts) == 1:
        return parts[0]
    if len(parts) == 2:
        style = rng.integers(4)
        return [f"{parts[0]}, then {parts[1]}", f"{parts[0]} and then {parts[1]}",
                f"first {parts[0]}, then {parts[1]}", f"{parts[0]}, and afterwards {parts[1]}"][style]
    style = rng.integers(3)
    return [f"{parts[0]}, then {parts[1]} and {parts[2]}", f"first {parts[0]}, then {parts[1]}, and finally {parts[2]}",
            f"{parts[0]}, {parts[1]}, and then {parts[2]}"][style]


def captions_for(parts: list[tuple[str, dict]], rng: np.random.Generator, num: int = 3,
                 mode: str = DEFAULT_CAPTIONS) -> list[str]:
    """`num` distinct paraphrases of a composite (different subjects, phrases and joiners)."""
    pool = subjects(mode)
    order = rng.permutation(len(pool))
    out: list[str] = []
    for i in range(num * 4):
        subj, pron = pool[order[i % len(pool)]]
        bits = [rng.choice(phrases(a, p, pron, mode)) for a, p in parts]
        text = f"{subj} {join([str(b) for b in bits], rng)}."
        if text not in out:
            out.append(text)
        if len(out) == num:
            break
    return out


def part_caption(action: str, p: dict, rng: np.random.Generator, mode: str = DEFAULT_CAPTIONS) -> str:
    pool = subjects(mode)
    subj, pron = pool[rng.integers(len(pool))]
    return f"{subj} {rng.choice(phrases(action, p, pron, mode))}."


# --- tokens -------------------------------------------------------------------------------------

_POS = {
    "DET": "a an the both each all",
    "SCONJ": "while",
    "PRON": "someone he she they it them his_ her_ their_ its_ something",
    "ADP": "in on to with at over above of into from towards toward behind across like",
    "CCONJ": "and or but",
    "NUM": "one two three four five 90 180",
    "AUX": "is are",
    "ADV": ("forward backward backwards slowly quickly fast briskly then once twice around sideways "
            "straight ahead still up down back low finally first afterwards again out carefully "
            "clockwise counterclockwise"),
    "ADJ": "left right slow quick normal moderate brisk steady short full half single few front quarter",
    "NOUN": ("person man woman figure human hand hands arm arms leg legs foot feet fist fists circle "
             "spot place head side sides pace time times jump jumps squat squats punch punches kick bow "
             "turn degree degrees shoulder waist step steps knee knees hops moment row chest crouch walk jog "
             "way hello"),
}
_TAGS = {w: tag for tag, words in _POS.items() for w in words.split()}
# the varied captions' own words (a word the plain captions use keeps its plain tag)
for _tag, _words in _varied()["pos"].items():
    for _w in _words:
        _TAGS.setdefault(_w, _tag)
# Possessives are tagged DET (as spaCy 2 did for HumanML3D).
for _w in ("his", "her", "their", "its"):
    _TAGS[_w] = "DET"
_LEMMA = {"feet": "foot", "does": "do", "goes": "go", "gets": "get", "takes": "take", "makes": "make",
          "rises": "rise", "lowers": "lower", "crouches": "crouch", "punches": "punch", "stretches": "stretch",
          "times": "time", "degrees": "degree", "hops": "hop", "squats": "squat", "jumps": "jump",
          "lifts": "lift", "puts": "put", "straightens": "straighten", "balances": "balance",
          "circles": "circle", "strolls": "stroll", "shuffles": "shuffle", "waves": "wave", "moves": "move",
          "raises": "raise", "bows": "bow", "waits": "wait", "leaps": "leap", "throws": "throw",
          "waving": "wave", "walking": "walk"}
_NOUN_CONTEXT = {"a", "the", "his", "her", "their", "its", "both", "two", "three", "four", "five", "one",
                 "few", "quick", "short", "front", "half", "quarter", "full", "single", "slow", "brisk",
                 "steady", "normal", "moderate", "left", "right", "clockwise", "counterclockwise"}


def _lemma(word: str) -> str:
    if word in _LEMMA:
        return _LEMMA[word]
    if re.search(r"(ch|sh|x|ss)es$", word):
        return word[:-2]
    if word.endswith("s") and not word.endswith("ss") and len(word) > 3:
        return word[:-1]
    return word


def tag(text: str) -> str:
    """`word/POS` tokens for a caption (punctuation dropped, verbs and nouns lemmatised)."""
    words = re.findall(r"[a-z0-9]+", text.lower())
    out = []
    for i, w in enumerate(words):
        prev = words[i - 1] if i else ""
        t = _TAGS.get(w)
        if w in ("jump", "jumps", "squat", "squats", "punch", "punches", "kick", "bow", "turn", "hops",
                 "circle", "crouch", "walk", "jog", "steps", "step") and prev in _NOUN_CONTEXT:
            t = "NOUN"
        elif w in ("clockwise", "counterclockwise") and i + 1 < len(words) and words[i + 1] == "circle":
            t = "ADJ"
        elif w == "around" and i + 1 < len(words) and words[i + 1] in ("the",):
            t = "ADP"
        elif w == "back" and prev in ("the",):
            t = "NOUN"
        elif t is None or t == "NOUN" and prev in ("", "person", "man", "woman", "someone", "figure",
                                                   "human", "and", "then", "first", "finally", "afterwards"):
            t = "VERB" if (t is None or w.endswith("s")) else t
        if t in ("VERB", "NOUN"):
            w = _lemma(w)
        out.append(f"{w}/{t}")
    return " ".join(out)


def caption_line(text: str, start: float = 0.0, end: float = 0.0) -> str:
    return f"{text}#{tag(text)}#{start:.2f}#{end:.2f}"
