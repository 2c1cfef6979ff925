"""Behaviour suite (issue #40): the prompt table, the checks on the synthetic generator's own motions
(they pass) and on motions wrong in one attribute (they fail), the pass-rate summary and the command."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from stablemo.data.synth import ACTIONS
from stablemo.data.synth import captions as synth_captions
from stablemo.data.synth.actions import sample_params
from stablemo.errors import StableMoError
from stablemo.eval.behaviour import measures, truth
from stablemo.eval.behaviour.checks import score
from stablemo.eval.behaviour.runner import parse_lengths, run_suite, truth_generator
from stablemo.eval.behaviour.summary import format_table, summarize, wilson
from stablemo.eval.behaviour.table import ATTRIBUTES, load_prompts

FPS = 20.0


@pytest.fixture(scope="module")
def prompts():
    return load_prompts()


def _representatives(prompts):
    """One prompt per (attribute, action, expected value kind): every check once, in seconds."""
    seen, out = set(), []
    for p in prompts:
        for attribute, value in p.tests.items():
            key = (attribute, len(p.parts)) if attribute == "order" else (attribute, p.parts[0].action, value == "both")
            if key not in seen:
                seen.add(key)
                if p not in out:
                    out.append(p)
    return out


# --------------------------------------------------------------------------- the table


def test_table_covers_every_action_attribute_and_split(prompts):
    assert len(prompts) >= 80
    assert {a for p in prompts for a in p.actions} == set(ACTIONS)
    assert {t for p in prompts for t in p.tests} == set(ATTRIBUTES)
    assert {p.split for p in prompts} == {"suite", "held_out"}
    assert {len(p.parts) for p in prompts if "order" in p.tests} == {2, 3}
    held_out = [p for p in prompts if p.split == "held_out"]
    assert len(held_out) >= 20 and {t for p in held_out for t in p.tests} == set(ATTRIBUTES)
    hop = next(p for p in prompts if p.text == "a man hops three times on his right foot.")
    assert hop.tests == {"count": 3, "side": "right", "body_part": "foot"}
    assert next(p for p in prompts if p.text.startswith("someone walks forward, then waves")).tests == \
        {"order": ["walk", "wave"]}


def _templates(n: int) -> set[str]:
    """Every way captions.join writes n phrases (its style is drawn by the rng), with <i> for phrase i."""
    return {synth_captions.join([f"<{i}>" for i in range(n)], np.random.default_rng(seed)) for seed in range(64)}


def _producible(prompt, mode: str = "plain") -> bool:
    """Whether the synthetic captions (vocabulary `mode`) can write this very sentence for the prompt's parts."""
    for subject, pron in synth_captions.subjects(mode):
        options = [synth_captions.phrases(part.action, {"waving": None, **part.params}, pron, mode)
                   for part in prompt.parts]
        for template in _templates(len(options)):
            pattern = re.escape(f"{subject} {template}.")
            for i, phrases in enumerate(options):
                pattern = pattern.replace(re.escape(f"<{i}>"), "(" + "|".join(map(re.escape, phrases)) + ")")
            if re.fullmatch(pattern, prompt.text):
                return True
    return False


def _training_words(mode: str = "plain") -> set[str]:
    """Every word the synthetic captions (vocabulary `mode`) can write."""
    words = set()
    rng = np.random.default_rng(0)
    for action in ACTIONS:
        for _ in range(200):  # every discrete parameter value of the generator, many times over
            params = sample_params(action, rng)
            for subject, pron in synth_captions.subjects(mode):
                for text in synth_captions.phrases(action, params, pron, mode):
                    words.update(re.findall(r"[a-z0-9]+", f"{subject} {text}"))
    words.update(re.findall(r"[a-z]+", " ".join(_templates(2) | _templates(3))))
    return words


def test_suite_prompts_are_training_phrasings_and_held_out_ones_are_not(prompts):
    vocabulary = _training_words()
    for p in prompts:
        if p.split == "suite":
            assert _producible(p), p.text
        else:
            assert not _producible(p), p.text
            assert set(re.findall(r"[a-z0-9]+", p.text)) - vocabulary, f"{p.text}: every word is a training word"


def test_held_out_prompts_are_not_among_the_bundles_captions(prompts):
    from safetensors import safe_open

    from stablemo.inference.bundle import DEMO_BUNDLE

    with safe_open(str(DEMO_BUNDLE / "familiar.safetensors"), framework="pt") as f:
        captions = {c.strip().lower() for c in json.loads(f.metadata()["captions"])}
    assert len(captions) > 1000
    assert not {p.text.lower() for p in prompts if p.split == "held_out"} & captions


@pytest.mark.parametrize("entry, message", [
    ({"text": "x", "parts": [{"action": "fly"}], "tests": ["action"], "split": "suite"}, "each part needs an action"),
    ({"text": "x", "parts": [{"action": "walk", "speed_label": "slow"}], "tests": ["count"], "split": "suite"},
     "cannot test count"),
    ({"text": "x", "parts": [{"action": "jump", "count": 1}], "tests": ["count"], "split": "test"}, "split must be"),
    ({"text": "x", "parts": [{"action": "jump", "height": 1}], "tests": ["count"], "split": "suite"},
     "no parameter 'height'"),
    ({"text": "x", "parts": [{"action": "jump", "count": 1}, {"action": "walk"}], "tests": ["count"],
      "split": "suite"}, "composites test their order"),
])
def test_bad_table_entries_are_one_line_naming_the_file(tmp_path, entry, message):
    path = tmp_path / "table.yaml"
    path.write_text(json.dumps({"prompts": [entry]}))
    with pytest.raises(StableMoError, match=re.escape(message)) as err:
        load_prompts(path)
    assert str(err.value).startswith(f"{path}: prompt 1 ") and "\n" not in str(err.value)


# --------------------------------------------------------------------------- checks on ground truth


def test_checks_pass_on_the_generators_motions_and_fail_on_wrong_ones(prompts):
    reps = _representatives(prompts)
    assert len(reps) >= 25
    for p in reps:
        for frames in (None, 196):
            for attribute, verdict in score(p, truth.truth_joints(p, 0, frames), FPS).items():
                assert verdict.passed, (p.text, frames, attribute, verdict.measured)
        for attribute in p.tests:
            wrong = score(p, truth.wrong_joints(p, attribute, 0), FPS)[attribute]
            assert not wrong.passed, (p.text, attribute, truth.wrong_parts(p, attribute), wrong.measured)


def test_the_count_check_fails_on_three_jumps_for_twice_and_the_side_check_on_the_mirror(prompts):
    twice = next(p for p in prompts if p.text == "a man jumps twice in place.")
    three = truth.build_parts((truth.Part("jump", {"count": 3}),), 0)
    assert score(twice, three, FPS)["count"].measured == "3" and not score(twice, three, FPS)["count"].passed
    left = next(p for p in prompts if p.text == "a person waves with the left hand.")
    j = truth.truth_joints(left, 0)
    assert score(left, j, FPS)["side"].passed and not score(left, truth.mirrored(j), FPS)["side"].passed
    assert np.array_equal(truth.mirrored(truth.mirrored(j)), j)
    turn = next(p for p in prompts if p.text == "a person turns 90 degrees to the left.")
    k = truth.truth_joints(turn, 1)
    assert measures.heading_change(truth.mirrored(k), FPS) == pytest.approx(-measures.heading_change(k, FPS), abs=1e-6)


def test_ground_truth_lengths_pad_with_standing(prompts):
    p = next(p for p in prompts if p.text == "a person jumps once.")
    natural = truth.natural_frames(p)
    assert 40 <= natural < 120
    assert len(truth.truth_joints(p, 0, 150)) == 150
    # the same motion, standing longer: only the last frames' smoothing into the stand differs (< 5 mm)
    padded, own = truth.truth_joints(p, 0, 150)[:natural], truth.truth_joints(p, 0)
    assert np.abs(padded - own).max() < 0.005 and np.abs(padded[: natural - 10] - own[: natural - 10]).max() < 1e-5
    assert len(truth.truth_joints(p, 0, 10)) == natural  # the actions are never cut


def test_spans_hysteresis_and_minimum_length():
    x = np.array([0, 5, 5, 3, 5, 0, 0, 5, 0, 5, 5, 5], float)
    assert measures.spans(x > 4, x < 1) == [(1, 5), (7, 8), (9, 12)]
    assert measures.spans(x > 4, x < 1, min_frames=2) == [(1, 5), (9, 12)]


# --------------------------------------------------------------------------- summary and runner


def test_wilson_interval():
    assert wilson(0, 10) == pytest.approx((0.0, 0.2775), abs=1e-4)  # z^2 / (n + z^2)
    assert wilson(10, 10) == pytest.approx((0.7225, 1.0), abs=1e-4)
    assert wilson(5, 10) == pytest.approx((0.2366, 0.7634), abs=1e-4)
    assert all(np.isnan(wilson(0, 0)))


def test_run_suite_on_ground_truth_is_deterministic_and_summarised(prompts):
    picked = [next(p for p in prompts if p.text == t) for t in
              ("a man squats twice.", "a dancer side steps to the right.", "a man jumps twice and then walks forward.")]
    generate = truth_generator(120)
    result = run_suite(generate, picked, ["default", "natural", "8"], [0, 1], FPS, 40, 196)
    rows = result["rows"]
    assert len(rows) == 3 * 3 * 2 and all(r["passed"] for r in rows)
    assert [r["frames"] for r in rows[:6:2]] == [120, truth.natural_frames(picked[0]), 160]
    s = result["summary"]
    assert s["overall"]["total"] == 18 and s["overall"]["rate"] == 1.0
    assert s["splits"]["held_out"]["attributes"]["direction"]["total"] == 6
    assert set(s["lengths"]) == {"default", "natural", "8"}
    again = run_suite(generate, picked, ["default", "natural", "8"], [0, 1], FPS, 40, 196)["rows"]
    assert again == rows
    table = format_table(s)
    assert re.search(r"^count\s+6\s+100\.0 \[", table, re.MULTILINE) and "held_out" in table and "length 8" in table


def test_summary_counts_a_motion_as_passed_only_when_every_check_passes():
    rows = [{"split": "suite", "length": "default", "passed": False,
             "attributes": {"count": {"passed": True, "measured": "2"}, "side": {"passed": False, "measured": "left"}}},
            {"split": "suite", "length": "default", "passed": True,
             "attributes": {"count": {"passed": True, "measured": "2"}}}]
    s = summarize(rows)
    assert (s["overall"]["passed"], s["overall"]["total"]) == (1, 2)
    assert (s["checks"]["passed"], s["checks"]["total"]) == (2, 3)
    assert s["attributes"]["side"]["rate"] == 0.0 and s["attributes"]["count"]["rate"] == 1.0


def test_parse_lengths():
    assert parse_lengths(["default", "natural", "9.80"]) == ["default", "natural", "9.8"]
    for bad, message in ((["fast"], "not 'default'"), (["-1"], "positive"), (["nan"], "positive"),
                         (["natural", "natural"], "twice"), ([], "at least one")):
        with pytest.raises(StableMoError, match=message):
            parse_lengths(bad)


# --------------------------------------------------------------------------- the command


def test_cli_ground_truth_writes_json_and_prints_the_table(tmp_path, capsys):
    from stablemo.cli import main

    table = tmp_path / "t.yaml"
    table.write_text("prompts:\n  - {text: 'a person claps twice.', parts: [{action: clap, count: 2}], tests: [count], split: suite}\n"
                     "  - {text: 'a kid jogs ahead.', parts: [{action: jog}], tests: [speed], split: held_out}\n")
    out = tmp_path / "r.json"
    assert main(["behaviour", "--ground-truth", "--prompts", str(table), "--seeds", "2", "--lengths", "natural",
                 "--out", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "2 prompts x 1 lengths x 2 seeds = 4 motions" in printed and re.search(r"^speed\s+2\s+100\.0", printed, re.MULTILINE)
    data = json.loads(out.read_text())
    assert data["summary"]["overall"]["passed"] == 4 and len(data["rows"]) == 4
    assert data["rows"][0]["attributes"]["count"] == {"passed": True, "measured": "2"}
    assert data["prompts"][1] == {"text": "a kid jogs ahead.", "split": "held_out", "actions": ["jog"],
                                  "tests": {"speed": "jog"}}
    from stablemo.eval.behaviour.report import load

    assert load(out) == data


def test_cli_with_a_bundle_is_deterministic(tmp_path, capsys):
    from conftest import make_tiny_bundle

    from stablemo.cli import main

    bundle = tmp_path / "bundle"
    make_tiny_bundle(bundle)
    table = tmp_path / "t.yaml"
    table.write_text("prompts:\n  - {text: 'a man jumps twice in place.', parts: [{action: jump, count: 2}], "
                     "tests: [count], split: suite}\n")
    outs = []
    for name in ("a.json", "b.json"):
        assert main(["evaluate", "--behaviour", "--bundle", str(bundle), "--prompts", str(table), "--seeds", "2",
                     "--lengths", "default", "1.5", "--out", str(tmp_path / name), "--no-progress"]) == 0
        outs.append(json.loads((tmp_path / name).read_text()))
    assert outs[0]["rows"] == outs[1]["rows"] and len(outs[0]["rows"]) == 4
    assert [r["frames"] for r in outs[0]["rows"]] == [40, 40, 30, 30]  # the tiny model's default is its maximum
    assert outs[0]["settings"]["seeds"] == [0, 1]
    # the printed header says how the model sampled, as the JSON does (a score is quoted with its steps)
    s = outs[0]["settings"]
    header = f"behaviour: {bundle} ({s['sampler']}, {s['steps']} steps, cfg {s['cfg']:g}); 1 prompts x 2 lengths"
    assert header in capsys.readouterr().out
    assert main(["evaluate", "--behaviour", "--bundle", str(bundle), "--prompts", str(table), "--seeds", "1",
                 "--lengths", "1.5", "--steps", "1", "--no-retrieval", "--no-progress"]) == 0
    assert f"({s['sampler']}, 1 step, cfg {s['cfg']:g})" in capsys.readouterr().out


@pytest.mark.parametrize("argv, message", [
    (["--ground-truth", "--lengths", "fast"], "--lengths: 'fast' is not 'default', 'natural' or a length in seconds"),
    (["--ground-truth", "--lengths", "20"], "--lengths: 20 s is 400 frames, outside the model's range"),
    (["--ground-truth", "--seeds", "0"], "--seeds: must be >= 1"),
    (["--ground-truth", "--bundle", "x"], "--bundle: --ground-truth scores the synthetic motions, not a model"),
    (["--bundle", "/nope"], "--bundle: /nope: bundle folder not found"),
    (["--ground-truth", "--prompts", "/nope.yaml"], "/nope.yaml: cannot read the prompt table"),
    (["--ground-truth", "--out", "{tmp}/file.txt/r.json"], "--out: "),
])
def test_bad_input_is_one_line(argv, message, tmp_path, capsys):
    from stablemo.cli import main

    (tmp_path / "file.txt").write_text("a file, not a folder")
    assert main(["behaviour", *[a.replace("{tmp}", str(tmp_path)) for a in argv]]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"stablemo behaviour: error: {message}") and "\n" not in err


# --------------------------------------------------------------------------- retrieval and the report


def test_retrieval_blocks_score_each_item_once():
    from stablemo.eval.behaviour.retrieval import blocks

    out = blocks(list(range(100, 170)), np.random.default_rng(0))
    assert [len(b) for b, _ in out] == [32, 32, 32] and [len(s) for _, s in out] == [32, 32, 6]
    scored = [i for _, s in out for i in s]
    assert sorted(scored) == list(range(100, 170))
    assert all(set(s) <= set(b) for b, s in out)
    assert blocks(list(range(31)), np.random.default_rng(0)) == []


def test_ground_truth_motions_are_retrieved(prompts):
    from stablemo.eval.behaviour.retrieval import top3_hits
    from stablemo.eval.evaluate import SYNTH_EVALUATOR
    from stablemo.eval.text_motion import load_text_motion_evaluator

    picked = prompts[::3][:36]
    joints = [truth.truth_joints(p, 0) for p in picked]
    hits = top3_hits(load_text_motion_evaluator(SYNTH_EVALUATOR), [p.text for p in picked], joints,
                     [list(range(len(picked)))])
    assert None not in hits and sum(hits) >= 32  # the real motions' R@3 is 0.99 on the test split


def test_summary_of_retrieval_counts_the_motions_that_fail_a_check():
    rows = [{"split": "suite", "length": "6", "passed": p, "r3": hit, "attributes": {"count": {"passed": p, "measured": ""}}}
            for p, hit in ((True, True), (False, True), (False, False), (False, True), (True, None))]
    s = summarize(rows)
    assert (s["r3"]["passed"], s["r3"]["total"]) == (3, 4)
    assert (s["r3_failed"]["passed"], s["r3_failed"]["total"]) == (2, 3)
    assert re.search(r"^R@3 of those failing a check\s+3\s+66\.7 \[", format_table(s), re.MULTILINE)
    assert "r3" not in summarize([{**r, "r3": None} for r in rows])


def test_report_section_chart_and_its_place_in_the_results(tmp_path, prompts):
    from stablemo.eval.behaviour.report import TITLE, chart, section, write_section

    picked = [p for p in prompts if p.split == "held_out"][:4]
    result = run_suite(truth_generator(120), picked, ["natural", "9.8"], [0], FPS, 40, 196)
    settings = {"model": "ground truth (stablemo.data.synth)", "prompts": 4, "lengths": ["natural", "9.8"],
                "seeds": [0], "seconds": {"total": 1.0}, "started": "now"}
    runs = {"ground truth": {"settings": settings, **result},
            "teacher": {"settings": {**settings, "model": "m", "sampler": "ddim", "steps": 1, "cfg": 2.5}, **result}}
    text = section(runs, "data/results/behaviour.png")
    assert text.lstrip().startswith(TITLE) and "| attribute | checks | ground truth | teacher |" in text
    assert "| motions (every check) | 8 | 100.0 [67.6, 100.0] | 100.0 [67.6, 100.0] |" in text
    doc = tmp_path / "results.md"
    doc.write_text("# Results\n\n## Kinematic measures\n\ntext\n\n## Joint control by guidance\n\nmore\n")
    write_section(doc, text)
    write_section(doc, text)  # replaced, not added twice
    body = doc.read_text()
    assert body.count(TITLE) == 1 and body.index("## Kinematic") < body.index(TITLE) < body.index("## Joint control")
    chart(runs, tmp_path / "b.png")
    assert (tmp_path / "b.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_report_names_the_demo_bundle_relative_to_the_checkout(tmp_path):
    from stablemo.cli.behaviour import shown_path
    from stablemo.inference.bundle import DEMO_BUNDLE

    assert shown_path(DEMO_BUNDLE) == "stablemo/assets/demo_bundle"  # not the machine's own folder
    assert shown_path(tmp_path / "b") == str(tmp_path / "b")
