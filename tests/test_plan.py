"""Prompts read as a sequence of parts (stablemo.text.plan) and generated part by part
(stablemo.timeline.planned): the splitting, the lengths, and what the motions do."""

from __future__ import annotations

import numpy as np
import pytest

from stablemo.inference.bundle import DEMO_STUDENT
from stablemo.inference.pipeline import Pipeline, Request
from stablemo.text.plan import plan_words, split_parts
from stablemo.timeline.planned import plan_prompt, share


@pytest.mark.parametrize("text, parts", [
    ("a person walks forward, then waves their right hand",
     ["a person walks forward", "a person waves their right hand"]),
    ("a man walks forward, then turns left and squats twice", ["a man walks forward", "a man turns left", "a man squats twice"]),
    ("someone jumps once, claps twice, and then walks backward.",
     ["someone jumps once", "someone claps twice", "someone walks backward"]),
    ("a woman first squats down once, then walks forward, and finally waves with the right hand.",
     ["a woman squats down once", "a woman walks forward", "a woman waves with the right hand"]),
    ("an athlete squats two times and after that jumps up once.", ["an athlete squats two times", "an athlete jumps up once"]),
    ("a dancer walks ahead, after that she jumps once.", ["a dancer walks ahead", "she jumps once"]),
    ("a person side steps to the right, and afterwards jumps once.", ["a person side steps to the right", "a person jumps once"]),
    ("a boy waves with the right hand before walking forward.", ["a boy waves with the right hand", "a boy walking forward"]),
    ("The man jumps after walking forward", ["The man walking forward", "The man jumps"]),  # "Y after X": X first
    ("a person walks forward. Then he sits down", ["a person walks forward", "he sits down"]),
    ("a person walked forward and then turned around", ["a person walked forward", "a person turned around"]),
    ("the kid turns to his left, followed by a walk forward.", ["the kid turns to his left", "a walk forward"]),
    ("a person walks forward and then finally sits down", ["a person walks forward", "a person sits down"]),
])
def test_an_order_in_words_splits_the_prompt_into_its_parts(text, parts):
    assert split_parts(text) == parts


@pytest.mark.parametrize("text", [
    "a person jumps in place twice",
    "a person crouches down and stands back up",  # one action, said in two verbs
    "a woman jumps up and down twice",
    "a person walks forward and waves",  # no order said: may be meant at once
    "a person walks in a circle counterclockwise",
    "someone walks while waving",
    "the man kicks with his left leg, then his right",  # no action of its own after "then": one action
    "a person walks forward then back",
    "he jumps after 2 seconds",
    "a person then jumps",  # an order word, but one action
    "a man finally sits down",
    "",
])
def test_a_prompt_that_says_no_order_stays_whole(text):
    assert split_parts(text) == [text.strip()]


def test_shares_fill_the_length_in_proportion():
    for total, weights in [(196, [80, 64]), (7, [40, 40, 40]), (100, [1, 1, 98]), (3, [50, 50, 50])]:
        out = share(total, weights)
        assert sum(out) == total and min(out) >= 1
    assert share(120, [80, 40]) == [80, 40]


def test_a_long_length_keeps_the_parts_and_ends_standing():
    words = plan_words()
    # two parts asking 64 and 80 frames, at most 72 and 100 as a rule
    plan = plan_prompt(["a jumps twice", "a walks"], [64, 80], [72, 100], 196, 20.0, words)
    assert plan.texts == ("a jumps twice", "a walks", words.rest_text) and plan.frames == (64, 80, 52) and plan.rest
    assert plan.spans == [(0, 64), (64, 144), (144, 196)]
    # within what such texts take (or too little left over for a rest): the parts share the length
    assert plan_prompt(["a", "b"], [64, 80], [72, 100], 160, 20.0, words).frames == (71, 89)
    assert plan_prompt(["a", "b"], [64, 80], [72, 100], 100, 20.0, words).frames == (44, 56)
    assert plan_prompt(["a", "b"], [64, 80], [72, 100], None, 20.0, words).frames == (64, 80)
    # one part: a plan only when a rest follows it
    assert plan_prompt(["a"], [64], [72], 70, 20.0, words) is None
    assert plan_prompt(["a"], [64], [72], None, 20.0, words) is None
    assert plan_prompt(["a"], [64], [72], 120, 20.0, words).frames == (64, 56)


@pytest.fixture(scope="module")
def student():
    return Pipeline.from_bundle(DEMO_STUDENT)


def test_a_planned_motion_is_its_parts_in_order_one_window_each(student):
    text = "a person jumps once, then walks forward"
    out = student.generate(Request([text], seed=3, plan=True, finish=False))
    plan = out.info["plans"][0]
    assert [p["text"] for p in plan] == ["a person jumps once", "a person walks forward"]
    first, second = plan
    assert out.lengths == [second["end"]] and first["end"] == second["start"]
    # the first part is the same motion as that text alone (window 0 takes the prompt's seed)
    alone = student.generate(Request([first["text"]], first["end"], seed=3, finish=False))
    np.testing.assert_allclose(out.raw_features[0, :first["end"]], alone.raw_features[0, :first["end"]], atol=2e-5)
    # the jump happens in the first part, the walk in the second
    joints = out.raw_joints[0, :out.lengths[0]].numpy()
    pelvis = joints[:, 0]
    jump, walk = slice(0, first["end"]), slice(second["start"] + 10, second["end"])
    rise = pelvis[jump, 1].max() - np.median(pelvis[:, 1])
    travel = lambda sl: np.linalg.norm(pelvis[sl.stop - 1, [0, 2]] - pelvis[sl.start, [0, 2]])  # noqa: E731
    assert rise > 0.15 and travel(walk) > 1.0 and travel(jump) < 0.5


def test_a_count_in_a_long_motion_is_done_once_and_the_rest_stands(student):
    out = student.generate(Request(["a person jumps in place twice"], 196, seed=0, plan=True))
    plan = out.info["plans"][0]
    assert plan[-1]["rest"] and plan[-1]["text"] == plan_words().rest_text and plan[-1]["end"] == 196
    pelvis = out.joints[0, :, 0].numpy()
    rest = slice(plan[-1]["start"] + 20, 196)  # after the hand-over settles (1 s)
    speed = np.linalg.norm(np.diff(pelvis[rest], axis=0), axis=-1) * student.fps
    assert pelvis[rest, 1].max() - pelvis[rest, 1].min() < 0.05 and np.median(speed) < 0.1
    assert out.lengths == [196]


def test_planning_is_seeded_batch_blind_and_off_by_default(student):
    texts = ["a person walks forward, then turns left", "a person bows"]
    a = student.generate(Request(texts, seed=5, plan=True))
    b = student.generate(Request(texts, seed=5, plan=True))
    assert np.array_equal(a.joints.numpy(), b.joints.numpy())
    alone = student.generate(Request(texts[:1], seed=5, plan=True))
    n = alone.lengths[0]
    assert a.lengths[0] == n
    np.testing.assert_allclose(a.joints[0, :n], alone.joints[0, :n], atol=1e-4)
    # off by default, and for a prompt that says no order at a length it fills: the network reads it whole
    whole = student.generate(Request(texts, seed=5))
    assert whole.info["plans"] == [None, None] and whole.lengths[0] != n
    own = student.text_lengths(texts[1:])[0]
    single = [student.generate(Request(texts[1:], own, seed=1, plan=p)).joints for p in (True, False)]
    assert np.array_equal(single[0].numpy(), single[1].numpy())


def test_generate_says_the_parts_and_whole_turns_planning_off(tmp_path, capsys):
    from stablemo.cli import main

    text = "a person walks forward, then waves their right hand"
    assert main(["generate", text, "--bundle", str(DEMO_STUDENT), "--out", str(tmp_path / "a"), "--no-render"]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert "in parts: 'a person walks forward'" in line and "'a person waves their right hand'" in line
    assert main(["generate", text, "--bundle", str(DEMO_STUDENT), "--out", str(tmp_path / "b"), "--no-render",
                 "--whole"]) == 0
    assert "in parts" not in capsys.readouterr().out


def test_every_behaviour_prompt_splits_into_as_many_parts_as_it_names_actions():
    """The suite's 111 prompts (30 held out: paraphrases and subjects no caption uses): single
    actions stay whole, composites of 2 and 3 split into 2 and 3."""
    from stablemo.eval.behaviour.table import load_prompts

    prompts = load_prompts()
    assert len(prompts) >= 100 and sum(len(p.parts) > 1 for p in prompts) >= 20
    for p in prompts:
        assert len(split_parts(p.text)) == len(p.parts), p.text


def test_a_timeline_plans_each_segment_as_generate_plans_a_prompt(student):
    from stablemo.timeline.compose import plan_timeline

    segs = [(0, 4, "a person turns left, then walks forward"), (4, 6, "a person bows")]
    made = plan_timeline(student, segs, 0)
    assert made.frames == [(0, 80), (80, 120)]  # the segments stay as given
    texts = [w.text for w in made.windows]
    assert texts == ["a person turns left", "a person walks forward", "a person bows"]
    turn, walk = made.windows[:2]
    assert turn.new_start == 0 and turn.new_end == walk.new_start and walk.new_end == 80
    whole = plan_timeline(student, segs, 0, plan=False)
    assert [w.text for w in whole.windows] == [s[2] for s in segs]
    # the stream and the composer agree on it (one plan)
    from stablemo.timeline import stream_timeline

    assert [w.text for w in stream_timeline(student, segs).plan.windows] == texts


def test_without_rest_a_long_length_is_shared_over_the_parts():
    words = plan_words()
    assert plan_prompt(["a", "b"], [64, 80], [72, 100], 196, 20.0, words, rest=False).frames == (87, 109)
    assert plan_prompt(["a"], [64], [72], 196, 20.0, words, rest=False) is None
    assert plan_prompt(["a"], [64], [72], 196, 20.0, words).rest  # (rest on by default)
