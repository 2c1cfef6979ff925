"""Long motion: timeline parsing, windows joined by in-painting in one global frame, streaming."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from stablemo.errors import StableMoError
from stablemo.inference.finish import ANCHOR_REACH_M
from stablemo.inference.pipeline import Pipeline
from stablemo.motion import features_to_joints
from stablemo.motion.skeleton import HUMANML3D
from stablemo.timeline import (
           canonical_timeline,
           format_timeline,
           parse_timeline,
           plan_windows,
           segment_frames,
           stream_timeline,
)
from stablemo.text.plan import plan_words
from stablemo.timeline.planned import share
from stablemo.timeline.seams import seam_report
from stablemo.timeline.windows import RootFrame, crossfade

DEMO = Path(__file__).resolve().parents[1] / "stablemo" / "assets" / "demo_bundle"
FAST = {"steps": 2}  # contract tests: the sampler settings do not change what is checked


@pytest.fixture(scope="module")
def demo():
    return Pipeline.from_bundle(DEMO)


def _global_joints(features: np.ndarray) -> np.ndarray:
    return features_to_joints(torch.from_numpy(features.astype(np.float64))).numpy()


def _assert_finished_from(joints: np.ndarray, raw_features: np.ndarray) -> None:
    """Streamed joints (N, J, 3) are the raw rows, concatenated and recovered in one global frame, then
    finished: the root's path exactly, every joint within the finishing step's few centimetres, every
    bone at one length."""
    raw = _global_joints(raw_features)
    np.testing.assert_allclose(joints[:, 0, [0, 2]], raw[:, 0, [0, 2]], atol=1e-4)
    # the most moved is a wrist the rigid arm cannot reach (0.33 m in the 2-step samples of the teacher
    # shipped 2026-12-07, mid-jump; 0.23 m at its 10 steps; 0.15 m for the teacher before it)
    assert np.abs(joints - raw).max() < 0.4 and np.median(np.abs(joints - raw)) < 0.03
    bones = np.linalg.norm(joints[:, 1:] - joints[:, list(HUMANML3D.parents[1:])], axis=-1)  # (N, J-1)
    assert np.ptp(bones, axis=0).max() < 1e-3


# ---------------------------------------------------------------------------------- the timeline file


def test_timeline_lines_parse_with_comments_and_exact_frames():
    segs = parse_timeline("# a walk\n0 3.33 a person walks forward\n\n3.33 6.67  a person jumps  # high\n"
                          "6.67 10 a person turns left\n")
    assert [s.text for s in segs] == ["a person walks forward", "a person jumps", "a person turns left"]
    frames = segment_frames(segs, 20.0)
    assert frames == [(0, 67), (67, 133), (133, 200)]  # rounded from absolute times: exactly 10 s


@pytest.mark.parametrize("text, message", [
    ("0 3 a\n2 6 b\n", "t.txt:2: starts at 2 s, overlapping"),
    ("0 3 a\n\n4 6 b\n", "t.txt:3: starts at 4 s, leaving a gap"),
    ("0 3 a\n3 x b\n", "t.txt:2: end time 'x' is not a number"),
    ("0 3 a\n3 nan b\n", "t.txt:2: end time 'nan' is not a number"),
    ("1 3 a\n", "t.txt:1: starts at 1 s; the first segment must start at 0"),
    ("0 3 a\n3 3 b\n", "t.txt:2: ends at 3 s, not after its start"),
    ("0 3\n", "t.txt:1: expected 'start_s end_s text'"),
    ("# nothing\n", "t.txt: no segments"),
])
def test_bad_timelines_name_the_line(text, message):
    with pytest.raises(StableMoError, match=message.replace("(", r"\(")):
        parse_timeline(text, "t.txt")


def test_windows_cover_the_motion_once_within_the_model_lengths():
    frames = [(0, 30), (30, 450), (450, 460)]  # short, longer than a window, shorter than the minimum
    windows = plan_windows(frames, ["a", "b", "c"], 40, 196, 20, 5)
    assert windows[0].prefix == 0 and windows[0].new_start == 0
    assert [w.new_start for w in windows[1:]] == [w.new_end for w in windows[:-1]]
    assert windows[-1].new_end == 460
    for w in windows:
        assert 40 <= w.length <= 196 and w.prefix + (w.new_end - w.new_start) <= w.length
        assert w.start == w.new_start - w.prefix and w.blend == min(5, w.prefix)
    middle = [w.new_end - w.new_start for w in windows if w.text == "b"]
    assert len(middle) == 3 and max(middle) - min(middle) <= 1  # split evenly, no sliver window


def test_crossfade_goes_from_old_to_new_in_equal_steps():
    old, new = np.zeros((3, 2), np.float32), np.full((3, 2), 4.0, np.float32)
    np.testing.assert_allclose(crossfade(old, new)[:, 0], [1.0, 2.0, 3.0])


# ---------------------------------------------------------------------------------- one motion


def test_timeline_is_one_motion_of_exact_length_continuing_each_window(demo):
    segs = [(0, 2.5, "a person walks forward"), (2.5, 4.05, "a person jumps in place"), (4.05, 6, "a person turns left")]
    motion = demo.generate_timeline(segs, seed=3, overlap=1.0, settle_s=0.5, **FAST)
    assert motion.features.shape == (120, 263) and motion.joints.shape == (120, 22, 3)
    assert motion.frames == [(0, 50), (50, 81), (81, 120)] and motion.boundaries == [50, 81]
    np.testing.assert_allclose(motion.joints, _global_joints(motion.features), atol=1e-4)
    # the root moves continuously across the joins: no step there larger than the largest inside
    steps = np.linalg.norm(np.diff(motion.joints[:, 0], axis=0), axis=-1)  # (N-1,)
    near = np.zeros(len(steps), bool)
    for b in motion.joins:
        near[b - 2:b + 1] = True
    assert steps[near].max() <= steps[~near].max()
    # each window after the first was conditioned on the previous one: a different first text changes them
    other = demo.generate_timeline([(0, 2.5, "a person runs forward")] + segs[1:], seed=3, overlap=1.0, **FAST)
    assert np.abs(other.features[50:] - motion.features[50:]).max() > 1e-3
    again = demo.generate_timeline(segs, seed=3, overlap=1.0, settle_s=0.5, **FAST)
    assert np.array_equal(again.features, motion.features)


def test_blended_windows_keep_the_hard_prefix_and_fade_the_rest(demo):
    segs = [(0, 2, "a person walks forward"), (2, 4, "a person jumps in place")]
    hard = demo.generate_timeline(segs, seed=1, overlap=1.0, blend=0.0, **FAST)
    soft = demo.generate_timeline(segs, seed=1, overlap=1.0, blend=0.5, **FAST)
    # the windows are joined raw (finishing looks ahead, so compare before it)
    assert np.array_equal(hard.raw_features[:30], soft.raw_features[:30])  # before the faded rows: the first window
    assert np.abs(hard.raw_features[30:40] - soft.raw_features[30:40]).max() > 1e-4  # the faded rows changed
    assert soft.windows[1].blend == 10


@pytest.mark.parametrize("kwargs, message", [
    ({"overlap": 0.5, "blend": 1.0}, "blend: 1 s is longer than the overlap"),
    ({"overlap": 20.0}, "overlap: 20 s"),
    ({"overlap": float("nan")}, "overlap: must be a finite number"),
    ({"seed": -1}, "seed"),
])
def test_bad_timeline_options_are_one_clear_error(demo, kwargs, message):
    with pytest.raises(StableMoError, match=message):
        demo.generate_timeline([(0, 3, "a person walks forward")], **kwargs)


# ---------------------------------------------------------------------------------- streaming


def test_stream_chunks_continue_one_motion_in_one_global_frame(demo):
    texts = ["a person walks forward"] * 3 + ["a person turns left"] * 2
    chunks = list(demo.stream(texts, chunk_seconds=1.5, context_seconds=0.5, seed=2, **FAST))
    assert [c.index for c in chunks] == list(range(5)) and [c.start for c in chunks] == [0, 30, 60, 90, 120]
    assert [c.text for c in chunks] == texts and all(c.features.shape == (30, 263) for c in chunks)
    joints = np.concatenate([c.joints for c in chunks])
    _assert_finished_from(joints, np.concatenate([c.raw_features for c in chunks]))  # heading and position carried
    assert np.abs(joints[-1, 0, [0, 2]]).max() > 0.3  # it went somewhere, and the chunks followed it


def test_stream_asks_the_callback_and_stops_when_it_says_so(demo):
    seen = []

    def texts(index, previous):
        seen.append((index, None if previous is None else previous.index))
        return None if index == 3 else ("a person walks forward" if index < 2 else "a person jumps in place")

    chunks = list(demo.stream(texts, chunk_seconds=1.0, **FAST))
    assert len(chunks) == 3 and seen == [(0, None), (1, 0), (2, 1), (3, 2)]
    assert chunks[2].text == "a person jumps in place"


def test_stream_is_conditioned_on_what_it_produced(demo):
    a = list(demo.stream(["a person walks forward", "a person jumps in place"], chunk_seconds=1.0, seed=5, **FAST))
    b = list(demo.stream(["a person runs forward", "a person jumps in place"], chunk_seconds=1.0, seed=5, **FAST))
    assert np.abs(a[1].features - b[1].features).max() > 1e-3
    free = list(demo.stream(["a person walks forward", "a person jumps in place"], chunk_seconds=1.0, seed=5,
                            context_seconds=0, **FAST))
    assert np.abs(a[1].features - free[1].features).max() > 1e-3
    # without context the root still continues: the next chunk starts where the last row's velocity leads
    _assert_finished_from(np.concatenate([c.joints for c in free]), np.concatenate([c.raw_features for c in free]))


@pytest.mark.parametrize("kwargs, message", [
    ({"chunk_seconds": 0.0}, "chunk_seconds: 0 s is 0 frames"),
    ({"chunk_seconds": 9.0, "context_seconds": 1.0}, "exceed this model's maximum window of 196 frames"),
    ({"chunk_seconds": float("inf")}, "chunk_seconds: must be a finite number"),
    ({"max_chunks": 0}, "max_chunks: must be a positive integer"),
])
def test_bad_stream_options_fail_before_any_chunk(demo, kwargs, message):
    with pytest.raises(StableMoError, match=message):
        demo.stream("a person walks forward", **kwargs)


def test_stream_rejects_an_empty_text_from_the_callback(demo):
    with pytest.raises(StableMoError, match="chunk 1: expected a non-empty prompt"):
        list(demo.stream(lambda i, prev: "a person walks" if i == 0 else " ", **FAST))


def test_root_frame_places_a_window_where_its_first_frame_stands():
    rng = np.random.default_rng(0)
    feats = (rng.standard_normal((50, 263)) * 0.05).astype(np.float32)
    whole = _global_joints(feats)
    frame = RootFrame("humanml3d")
    first = frame.joints(feats[:30])
    frame.advance(feats[:30], first, 20)
    np.testing.assert_allclose(frame.joints(feats[20:]), whole[20:], atol=1e-6)


# ---------------------------------------------------------------------------------- seams, CLI, bench


def test_seam_report_finds_a_jump_and_only_there():
    t = np.arange(100) / 20.0
    joints = np.zeros((100, 22, 3))
    joints[:, :, 2] = (1.2 * t)[:, None]  # walking at 1.2 m/s: no acceleration
    joints[:, :, 1] = 0.9 + 0.02 * np.sin(2 * np.pi * t)[:, None]
    joints[60:, :, 1] += 0.1  # a 10 cm jump of the whole body at frame 60
    rep = seam_report(joints, [30, 60], 20.0)
    smooth, jump = rep["joins"]
    assert jump["frame"] == 60 and jump["root"] > 30 and jump["foot"] > 30  # 0.1 m * 20^2 = 40 m/s^2
    assert smooth["root"] < 1.0 and rep["inside_p99"]["root"] < 1.0
    spans = seam_report(joints, [(52, 57)], 20.0)  # a span before the jump misses it
    assert spans["joins"][0]["root"] < 1.0


def test_generate_timeline_cli_writes_one_motion_of_the_whole_length(tmp_path, capsys):
    from stablemo.cli.generate import main

    file = tmp_path / "walk jump.txt"
    file.write_text("0 2.5 a person walks forward\n2.5 4.5 a person jumps in place\n")
    assert main(["--timeline", str(file), "--out", str(tmp_path / "out"), "--no-render", "--steps", "2"]) == 0
    feats = np.load(tmp_path / "out" / "walk-jump.features.npy")
    joints = np.load(tmp_path / "out" / "walk-jump.joints.npy")
    assert feats.shape == (90, 263) and joints.shape == (90, 22, 3)
    info = json.loads((tmp_path / "out" / "walk-jump.timeline.json").read_text())
    assert [s["frames"] for s in info["segments"]] == [[0, 50], [50, 90]] and len(info["windows"]) == 2
    assert [j["frame"] for j in info["seams"]["joins"]] == [50] and info["seams"]["inside_p99"]["root"] > 0


@pytest.mark.parametrize("text, extra, message", [
    ("0 2 a\n1 3 b\n", [], "t.txt:2: starts at 1 s, overlapping"),
    ("0 2 a person walks\n", ["a prompt"], "--timeline: prompt cannot be combined"),
    ("0 2 a person walks\n", ["--seconds", "3"], "--timeline: --seconds cannot be combined"),
])
def test_generate_timeline_cli_bad_input_is_one_line_before_loading(tmp_path, capsys, monkeypatch, text, extra,
                                                                    message):
    from stablemo import cli

    def refuse(*args, **kwargs):
        raise AssertionError("the model was loaded before the input was checked")

    monkeypatch.setattr(Pipeline, "from_bundle", refuse)
    file = tmp_path / "t.txt"
    file.write_text(text)
    rc = cli.main(["generate", "--timeline", str(file), "--out", str(tmp_path / "out"), *extra])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and message in err and len(err.splitlines()) == 1
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_bench_stream_times_teacher_and_student_side_by_side(capsys):
    from stablemo.cli.bench import main

    assert main(["stream", "--chunks", "1", "--chunk-seconds", "1"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith(("| teacher", "| student"))]
    assert len(rows) == 2 and all(float(row.split("|")[2]) > 0 for row in rows)


def test_stream_applies_hooks_and_joint_control_per_chunk(demo):
    from stablemo.control import JointControl

    calls = []

    class Count:
        def active(self, step, steps):
            return True

        def __call__(self, state):
            calls.append(state.x0.shape[1])

    target = np.array([1.0, 0.95, 1.0], np.float32)

    def control(index, length, context):  # the pelvis at the window's last frame, in the window's frame
        pos, mask = np.zeros((length, 22, 3), np.float32), np.zeros((length, 22), bool)
        pos[-1, 0], mask[-1, 0] = target, True
        return JointControl(pos, mask)

    runs = {}
    for name, ctl in (("free", None), ("control", control)):
        chunks = list(demo.stream("a person walks forward", 2.0, max_chunks=2, seed=1, control=ctl, hooks=[Count()],
                                  **FAST))
        window = np.concatenate([chunks[0].raw_features[-10:], chunks[1].raw_features])  # chunk 1's window (10 rows of context)
        runs[name] = (chunks[0].joints[-1, 0], _global_joints(window)[-1, 0])
    assert len(calls) == 2 * 2 * 2  # two runs x two chunks x two steps
    np.testing.assert_allclose(runs["control"][0], target, atol=1e-3)  # chunk 0: the window is the global frame
    free, ctl = (np.linalg.norm(runs[k][1] - target) for k in ("free", "control"))
    assert ctl < 0.5 * free  # chunk 1 is pulled to its target too (its prefix is fixed, so not exactly)


# ---------------------------------------------------------------------------------- one format


def test_the_pages_shorthand_converts_to_the_one_format_and_two_times_are_never_a_prompt():
    text = "# warm up\n4 a person walks  # slowly\n\n4 10 a person jumps\n2.5 a person turns left\n"
    assert canonical_timeline(text) == ("# warm up\n0 4 a person walks  # slowly\n\n4 10 a person jumps\n"
                                        "10 12.5 a person turns left\n")
    segs = parse_timeline(text, shorthand=True)
    assert segs == parse_timeline(canonical_timeline(text)) == parse_timeline(format_timeline(segs))
    assert [(s.start_s, s.end_s, s.text) for s in segs] == [(0, 4, "a person walks"), (4, 10, "a person jumps"),
                                                            (10, 12.5, "a person turns left")]
    # the CLI reads only the one format, and says what the shorthand is
    with pytest.raises(StableMoError, match="t.txt:1: end time 'a' is not a number of seconds .*page's shorthand"):
        parse_timeline("4 a person walks\n", "t.txt")
    example = (Path(__file__).resolve().parents[1] / "docs" / "data" / "long_motion" / "example.txt").read_text()
    assert canonical_timeline(example) == example
    assert parse_timeline(example, shorthand=True) == parse_timeline(example)


# ---------------------------------------------------------------------------------- streamed by whole prompts


def test_a_streamed_timeline_is_the_composers_motion_cut_into_chunks_within_prompts(demo):
    segs = [(0, 2.5, "a person walks forward"), (2.5, 3.1, "a person jumps"), (3.1, 14, "a person turns left, then walks")]
    stream = stream_timeline(demo, segs, chunk_seconds=2.0, seed=3, **FAST)
    chunks = list(stream.chunks)
    composed = demo.generate_timeline(segs, seed=3, **FAST)
    # every prompt's span is generated whole (its windows, as composed): the raw rows to the bit
    raw = np.concatenate([c.raw_features for c in chunks])
    assert np.array_equal(raw, composed.raw_features)
    # the last prompt says an order: its two parts in order, sharing its 10.9 s (218 frames) in proportion
    # to their predicted lengths (stablemo.timeline.planned; a timeline adds no standing rest)
    modes, _ = demo.text_length_range(["a person turns left", "a person walks"], plan_words().rest_quantile)
    turn, walk = share(218, modes)
    assert turn > 1 and walk > 1
    assert [(w.text, w.new_start, w.new_end) for w in composed.windows] == [
        ("a person walks forward", 0, 50), ("a person jumps", 50, 62), ("a person turns left", 62, 62 + turn),
        ("a person walks", 62 + turn, 280)]
    # chunks of at most 2 s, each inside one prompt (the last prompt's two parts are one prompt), in order,
    # covering the motion once
    spans = [(0, 50, "a person walks"), (50, 62, "a person jumps"), (62, 280, "a person turns")]
    assert [(c.start, len(c.joints), c.text[:14]) for c in chunks] == [
        (s, min(40, end - s), text) for start, end, text in spans for s in range(start, end, 40)]
    joints = np.concatenate([c.joints for c in chunks])
    _assert_finished_from(joints, raw)
    # finished window by window instead of once: within a few centimetres of the composed motion (a stance
    # cut by a window's edge gets its planted foot's anchor from the frames that window sees, each at most
    # ANCHOR_REACH_M from the generated place); the median joint well under a centimetre
    assert np.abs(joints - composed.joints).max() < 2 * ANCHOR_REACH_M + 0.01
    assert np.median(np.abs(joints - composed.joints)) < 0.005
    with pytest.raises(StableMoError, match="chunk_seconds: 0.1 s is 2 frames"):
        stream_timeline(demo, segs, chunk_seconds=0.1)


def test_without_context_a_chunk_does_not_carry_the_streams_heading_in_its_first_row(demo):
    # a chunk finished alone read its first row's turn against facing +z: the stream's whole heading
    # (-0.93 against the network's -0.013 for chunk 1 of a left turn, before the fix)
    chunks = list(demo.stream("a person turns left", chunk_seconds=1.0, context_seconds=0, max_chunks=3, seed=1, **FAST))
    for c in chunks[1:]:
        assert abs(c.features[0, 0] - c.raw_features[0, 0]) < 0.05
    segs = [(0, 2.5, "a person turns left"), (2.5, 5, "a person walks forward")]
    chunks = list(stream_timeline(demo, segs, seed=1, overlap=0.0, **FAST).chunks)
    later = [c for c in chunks if c.start == 50]
    assert len(later) == 1 and abs(later[0].features[0, 0] - later[0].raw_features[0, 0]) < 0.05


def test_a_streamed_timelines_whole_features_recover_to_its_joints(demo):
    from stablemo.timeline.timeline_stream import whole_features

    segs = [(0, 2.5, "a person turns left"), (2.5, 5, "a person walks forward")]
    joints = np.concatenate([c.joints for c in stream_timeline(demo, segs, seed=1, **FAST).chunks])
    back = _global_joints(whole_features(demo, joints))
    assert np.abs(back - joints).max() < 1e-3
