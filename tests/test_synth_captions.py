"""The varied caption vocabulary (`stablemo data synth --captions varied`): the same motions with
other words, every caption-relevant parameter still said, and the sentences held apart from training
(the behaviour suite's held-out prompts, the unseen composites, the turn report's phrasings) still
unseen."""

from __future__ import annotations

import ast
import json
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from stablemo.data.synth import ACTIONS, compose, write_dataset
from stablemo.data.synth import captions as synth_captions
from stablemo.data.synth.actions import sample_params
from stablemo.data.synth.writer import motion_rng
from stablemo.errors import StableMoError
from stablemo.eval.behaviour.table import load_prompts
from test_behaviour import _producible, _training_words

REPO = Path(__file__).resolve().parents[1]
WORD = re.compile(r"[a-z0-9]+")


def _held_apart_sentences() -> list[str]:
    texts = [p.text for p in load_prompts() if p.split == "held_out"]
    unseen = yaml.safe_load((REPO / "docs/data/results/plan_composites_unseen.yaml").read_text())["prompts"]
    texts += [p["text"] for p in unseen]
    tree = ast.parse((REPO / "scripts/results/turn_report.py").read_text())
    turns = next(node.value for node in tree.body if isinstance(node, ast.Assign)
                 and any(getattr(t, "id", None) == "PROMPTS" for t in node.targets))
    texts += ast.literal_eval(turns)
    return texts


def test_the_motions_are_the_same_and_only_the_captions_differ():
    changed = 0
    for i in range(12):
        plain = compose.generate_motion(motion_rng(5, i))
        assert compose.generate_motion(motion_rng(5, i), caption_mode="plain").captions == plain.captions
        varied = compose.generate_motion(motion_rng(5, i), caption_mode="varied")
        assert np.array_equal(plain.joints, varied.joints) and np.array_equal(plain.contacts, varied.contacts)
        assert [(a, b) for _, a, b in plain.sub_captions] == [(a, b) for _, a, b in varied.sub_captions]
        assert len(varied.captions) == 3 and len(set(varied.captions)) == 3
        changed += plain.captions != varied.captions
        again = compose.generate_motion(motion_rng(5, i), caption_mode="varied")
        assert (again.captions, again.sub_captions) == (varied.captions, varied.sub_captions)
    assert changed >= 10
    path = compose.generate_path_walk(motion_rng(5, 0), caption_mode="varied")
    assert np.array_equal(path.joints, compose.generate_path_walk(motion_rng(5, 0)).joints)


SLOW = r"slow|unhurried|gentle|amble|wander|saunter|inch|eas"
FAST = r"quick|brisk|fast|\bhurr|rush|rapid|strid"
COUNT_WORDS = r"\b(once|twice|one|two|three|four|five|times)\b"


def _says(action: str, p: dict, text: str) -> None:
    """Assert that a varied phrase says each caption-relevant parameter of `p`, and no other value."""
    for key in ("direction", "leg", "hand"):
        if p.get(key) in ("left", "right"):
            other = {"left": "right", "right": "left"}[p[key]]
            assert re.search(rf"\b{p[key]}\b", text) and not re.search(rf"\b{other}\b", text), text
        elif p.get(key) == "both":  # both hands; a punch's: alternating (a single one: either hand, unsaid)
            assert not re.search(r"\b(left|right)\b", text), text
            assert re.search(r"both|alternat|switching", text) or action == "punch" and p["count"] == 1, text
    if "count" in p:
        n = p["count"]
        said = set(re.findall(COUNT_WORDS, text))
        if n == 1:
            assert said <= {"once"}, text
        else:
            assert {synth_captions.TIMES_WORDS[n], synth_captions.NUMBER_WORDS[n]} & said or \
                f"{synth_captions.NUMBER_WORDS[n]} times" in text, text
            assert not said - set(synth_captions.TIMES_WORDS[n].split()) - {synth_captions.NUMBER_WORDS[n]}, text
    if action == "walk":
        slow, fast = bool(re.search(SLOW, text)), bool(re.search(FAST, text))
        assert (slow, fast) == {"slow": (True, False), "normal": (False, False), "fast": (False, True)}[p["speed_label"]], text
    if action == "walk_backward":
        assert re.search(r"back|reverse|retreat", text), text
        assert bool(re.search(SLOW, text)) == (p["speed_label"] == "slow"), text
    if action == "walk_sideways":
        assert re.search(r"side|lateral", text), text
    if action == "turn":
        assert bool(re.search(r"around|half|180", text)) == (p["angle"] == 180), text
    if action == "circle":
        assert re.search(r"\bcircle|ring|lap\b", text), text
        assert ("counterclockwise" in text) == (p["direction"] == "counterclockwise") and "clockwise" in text, text
    if action == "raise_arms":
        assert re.search({"up": r"overhead|above|\bup\b", "sideways": r"side", "forward": r"forward|front"}[p["mode"]], text)


def test_every_varied_phrase_says_what_the_motion_does():
    rng = np.random.default_rng(1)
    seen = 0
    for action in ACTIONS:
        for _ in range(60):
            p = sample_params(action, rng)
            plain = synth_captions.phrases(action, p, "his")
            varied = synth_captions.phrases(action, p, "his", "varied")
            assert varied[:len(plain)] == plain  # every plain sentence can still be written
            for text in varied[len(plain):]:
                assert "{" not in text and "then" not in text.split()  # filled; one part (no order word)
                _says(action, p, text)
                seen += 1
    assert seen > 1000
    assert len(synth_captions.subjects("varied")) == len(synth_captions.SUBJECTS) + 8


def test_held_apart_sentences_stay_unseen():
    plain = _training_words()
    varied = _training_words("varied")
    assert len(varied - plain) > 80
    for text in _held_apart_sentences():
        unseen = set(WORD.findall(text.lower())) - plain
        assert not unseen & varied, f"{text}: the varied captions use {sorted(unseen & varied)}"
    for prompt in load_prompts():
        if prompt.split == "held_out":
            assert not _producible(prompt, "varied"), prompt.text


def test_varied_words_are_tagged_without_changing_plain_tags():
    tags = yaml.safe_load(synth_captions.VARIED_FILE.read_text())["pos"]
    tagged = {w for words in tags.values() for w in words}
    assert not tagged & _training_words()  # the plain captions' words keep the plain tagger's reading
    line = synth_captions.caption_line("a teenager moves laterally to the left, then springs up twice.")
    assert line.split("#")[1].split() == ["a/DET", "teenager/NOUN", "move/VERB", "laterally/ADV", "to/ADP", "the/DET",
                                          "left/ADJ", "then/ADV", "spring/VERB", "up/ADV", "twice/ADV"]


def test_caption_vocabulary_is_checked_and_recorded(tmp_path):
    with pytest.raises(ValueError, match="caption_mode='rich'"):
        compose.generate_motion(np.random.default_rng(0), caption_mode="rich")
    with pytest.raises(StableMoError, match="^captions='rich': must be one of plain, varied"):
        write_dataset(tmp_path / "bad", num=3, captions="rich")
    assert not (tmp_path / "bad").exists()
    from stablemo.cli import main

    assert main(["data", "synth", "--out", str(tmp_path / "v"), "--num", "3", "--captions", "varied"]) == 0
    write_dataset(tmp_path / "p", num=3, workers=1)
    assert json.loads((tmp_path / "v" / "synth.json").read_text())["captions"] == "varied"
    assert "captions" not in json.loads((tmp_path / "p" / "synth.json").read_text())  # as written before the option
    for sub in ("new_joint_vecs", "new_joints", "contacts"):
        for i in range(3):
            assert (tmp_path / "v" / sub / f"00000{i}.npy").read_bytes() == (tmp_path / "p" / sub / f"00000{i}.npy").read_bytes()
    assert (tmp_path / "v" / "Mean.npy").read_bytes() == (tmp_path / "p" / "Mean.npy").read_bytes()
    assert (tmp_path / "v" / "texts" / "000000.txt").read_text() != (tmp_path / "p" / "texts" / "000000.txt").read_text()
