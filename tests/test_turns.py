"""A turn said in words is read (stablemo.text.turns) and the body turns by it (stablemo.control.turn):
the reading on phrasings beyond the training captions, the turn on ground-truth motions measured
as the behaviour suite measures it, the checks of a caller's Turn, and the pipeline's wiring."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from stablemo.control.turn import K_MAX, Turn, apply_turns, said_turns, turn_scale
from stablemo.errors import StableMoError
from stablemo.eval.behaviour.measures import heading_change
from stablemo.eval.behaviour.table import Part
from stablemo.eval.behaviour.truth import build_parts
from stablemo.motion import features_to_joints, joints_to_features
from stablemo.text.turns import AskedTurn, asked_turn

FPS = 20.0


@pytest.mark.parametrize("text, degrees, side", [
    # the synthetic captions' own phrasings
    ("a person turns left.", 90, "left"),
    ("a man turns to his right", 90, "right"),
    ("someone makes a quarter turn to the left", 90, "left"),
    ("a woman turns around to the right.", 180, "right"),
    ("the man turns all the way around over his left shoulder", 180, "left"),
    ("a person walks in a clockwise circle.", 360, "right"),
    ("a man circles counterclockwise", 360, "left"),
    # other words for the same turns (written for this test, used by no caption or suite prompt)
    ("the dancer pivots to the right", 90, "right"),
    ("she takes a left turn", 90, "left"),
    ("a person swivels leftward", 90, "left"),
    ("a man does a 180-degree turn", 180, None),
    ("someone rotates one hundred and eighty degrees clockwise", 180, "right"),
    ("the person turns forty-five degrees to the left", 45, "left"),
    ("a woman turns 270 degrees counter-clockwise", 270, "left"),
    ("a soldier does an about-face", 180, None),
    ("the man turns back around", 180, None),
    ("a child turns to face the opposite direction", 180, None),
    ("a person walks half a circle to the left", 180, "left"),
    ("a man makes three-quarters of a turn to the right", 270, "right"),
    ("a skater spins around", 360, None),
    ("a ballerina does a pirouette", 360, None),
    ("a man walks in a small loop anticlockwise", 360, "left"),
    ("a jogger runs a complete circle to the right", 360, "right"),
    ("a person walks forward, turns around and walks back", 180, None),
])
def test_a_turn_said_in_words_is_read(text, degrees, side):
    assert asked_turn(text) == AskedTurn(float(degrees), side)


@pytest.mark.parametrize("text", [
    "a person walks forward",
    "a person waves his right hand",
    "a person turns his head to the left",  # the head, not the body
    "a man looks to the right",
    "a person walks in circles",  # how many?
    "a person turns slightly left",  # no size said
    "someone turns left and then turns right",  # two turns said alike: no one angle
    "a person turns around twice",
    "a person draws a circle in the air",
    "a person walks and curves to the left",
    "a person turns",
    "",
])
def test_no_sizeable_turn_reads_as_none(text):
    assert asked_turn(text) is None


def _turn_features(direction: str, angle: int, seed: int = 0) -> np.ndarray:
    joints = build_parts((Part("turn", {"direction": direction, "angle": angle}),), seed)
    return joints_to_features(joints, "humanml3d").astype(np.float32)


def _turned(features: np.ndarray) -> float:
    joints = features_to_joints(torch.from_numpy(features)[None], "humanml3d")[0].numpy()
    return heading_change(joints, FPS)


@pytest.mark.parametrize("direction, angle, asked, side", [
    ("right", 90, 180, "right"), ("left", 90, 45, None), ("left", 180, 90, "left"), ("right", 180, 270, None)])
def test_a_ground_truth_turn_turns_by_what_is_asked(direction, angle, asked, side):
    feats = _turn_features(direction, angle)
    T = len(feats)
    assert abs(abs(_turned(feats)) - angle) < 5
    out = apply_turns(torch.from_numpy(feats)[None], [T], [Turn(asked, side).resolve(T)], "humanml3d", FPS)[0].numpy()
    sign = 1 if direction == "left" else -1
    assert _turned(out) == pytest.approx(sign * asked, abs=3.0)  # as the behaviour suite measures it (smoothed)
    # only the root's turn changed: the body's pose and its steps in its own frame are as they were
    np.testing.assert_array_equal(out[:, 1:], feats[:, 1:])


def test_a_turn_acts_on_its_frames_only_and_never_reverses_or_invents_one():
    a, b = _turn_features("right", 90, 1), _turn_features("left", 90, 2)
    n = min(len(a), len(b))
    feats = torch.from_numpy(np.concatenate([a[:n], b[:n]]))[None]  # right, then left: 0 in all
    T = feats.shape[1]
    out = apply_turns(feats, [T], [Turn(180, "left", n, T).resolve(T)], "humanml3d", FPS)[0].numpy()
    np.testing.assert_array_equal(out[:n], feats[0, :n].numpy())  # before the span: untouched
    assert _turned(out[n:]) == pytest.approx(180, abs=3.0)
    # asked for the other side: nothing changes (the side check should see the wrong side)
    k = turn_scale(torch.from_numpy(a)[None], [len(a)], [Turn(90, "left").resolve(len(a))], "humanml3d", FPS)
    assert float(k[0]) == 1.0
    # a body that barely turns is not spun round
    still = build_parts((Part("stand", {}),), 0)
    sf = torch.from_numpy(joints_to_features(still, "humanml3d").astype(np.float32))[None]
    assert float(turn_scale(sf, [sf.shape[1]], [Turn(90).resolve(sf.shape[1])], "humanml3d", FPS)[0]) == 1.0
    # a much too small turn is made larger, within the bound
    k = turn_scale(torch.from_numpy(a)[None], [len(a)], [Turn(720, "right").resolve(len(a))], "humanml3d", FPS)
    assert float(k[0]) == pytest.approx(K_MAX)


@pytest.mark.parametrize("turn, message", [
    (Turn(0), "turns.degrees: expected a number in (0, 720]"),
    (Turn(float("nan")), "turns.degrees: expected a number in (0, 720]"),
    (Turn("far"), "turns.degrees: expected a number, got 'far'"),
    (Turn(90, "up"), "turns.side: expected 'left', 'right' or None, got 'up'"),
    (Turn(90, None, 30, 20), "turns: frames [30, 20) do not lie in a motion of 60 frames"),
    (Turn(90, None, 0, 61), "turns: frames [0, 61) do not lie in a motion of 60 frames"),
    (Turn(90, None, 1.5), "turns.start: expected a whole number of frames, got 1.5"),
])
def test_a_bad_turn_is_one_clear_error(turn, message):
    with pytest.raises(StableMoError, match=message.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
        turn.resolve(60)


def test_a_turn_takes_numpy_frame_numbers():
    assert Turn(90, "left", np.int64(2), np.int64(40)).resolve(60) == Turn(90.0, "left", 2, 40)


def test_said_turns_share_a_split_span():
    turns = said_turns(["a man turns left", "a man bows"], [(10, 50), (0, 40)], [0.5, 1.0])
    assert turns == [Turn(45.0, "left", 10, 50), None]
    assert said_turns(["a man bows"], [(0, 40)]) is None


@pytest.fixture(scope="module")
def student():
    from stablemo.inference.bundle import DEMO_STUDENT
    from stablemo.inference.pipeline import Pipeline

    return Pipeline.from_bundle(DEMO_STUDENT)


def test_a_planned_request_turns_as_said_and_a_whole_one_as_the_network_does(student):
    from stablemo.inference.pipeline import Request

    text = "a man turns to the right."  # the demo student turns it 45-85 degrees on its own
    seeds = [0, 1, 2, 3]
    said = student.generate(Request([text] * 4, seed=seeds, plan=True))
    own = student.generate(Request([text] * 4, seed=seeds))
    turned = [heading_change(j, FPS) for j in said.joint_list()]
    assert all(abs(t + 90) < 10 for t in turned), turned
    assert not all(abs(heading_change(j, FPS) + 90) < 10 for j in own.joint_list())
    # a caller's Turn does the same without planning, and the same seed gives the same motion
    given = student.generate(Request([text] * 4, seed=seeds, turns=Turn(90, "right")))
    np.testing.assert_array_equal(given.joints.numpy(), said.joints.numpy())
    with pytest.raises(StableMoError, match=r"turns\[1\]: expected a Turn or None, got int"):
        student.generate(Request([text] * 2, turns=[None, 3]))


def test_a_timeline_window_turns_by_its_share_of_the_angle(student):
    from stablemo.timeline.compose import plan_timeline

    made = plan_timeline(student, [(0, 4, "a person turns left, then walks forward"), (4, 6, "a person bows")], 0)
    assert made.turns[0] == Turn(90.0, "left", *made.windows[0].new_frames)
    assert made.turns[1:] == [None, None]
    assert plan_timeline(student, [(0, 4, "a person turns left")], 0, plan=False).turns is None


def test_generate_says_the_turn_it_read_and_whole_reads_none(tmp_path, capsys):
    from stablemo.cli import main
    from stablemo.inference.bundle import DEMO_STUDENT

    text = "a man makes a quarter turn to the right"
    assert main(["generate", text, "--bundle", str(DEMO_STUDENT), "--out", str(tmp_path / "a"), "--no-render"]) == 0
    assert "; turning 90 degrees to the right)" in capsys.readouterr().out
    assert main(["generate", text, "--bundle", str(DEMO_STUDENT), "--out", str(tmp_path / "b"), "--no-render",
                 "--whole"]) == 0
    assert "turning" not in capsys.readouterr().out


def test_the_hook_leaves_samples_it_does_not_turn_bit_for_bit():
    """A multistep sampler steps first order for any sample whose x0 a hook changed; a sample
    without a turn (or one left alone) must come back exactly as it went in."""
    from stablemo.control.turn import TurnAsAsked
    from stablemo.diffusion.hooks import StepState

    turn = _turn_features("left", 90)
    T = len(turn)
    walk = joints_to_features(build_parts((Part("walk", {"speed_label": "normal"}),), 0, T + 1), "humanml3d")[:T]
    feats = torch.from_numpy(np.stack([turn, walk.astype(np.float32)]))
    mean, std = feats.flatten(0, 1).mean(0), feats.flatten(0, 1).std(0) + 0.1
    x0 = (feats - mean) / std
    hook = TurnAsAsked(mean, std, "humanml3d", [Turn(180, "left").resolve(T), None])
    out = hook(StepState(0, 10, 500, x0.clone(), torch.ones(2, T, dtype=torch.bool), [T, T]))
    assert torch.equal(out[1], x0[1]) and not torch.equal(out[0], x0[0])
    alone = TurnAsAsked(mean, std, "humanml3d", [None, Turn(90, "right").resolve(T)])  # a walk: no turn to scale
    assert alone(StepState(0, 10, 500, x0.clone(), torch.ones(2, T, dtype=torch.bool), [T, T])) is None
