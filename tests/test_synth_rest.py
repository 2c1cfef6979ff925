"""Synthetic data: the idle rest around each action: length does not imply count."""

from __future__ import annotations

import json

import numpy as np
import pytest

from stablemo.data.synth import compose, idle, write_dataset
from stablemo.data.synth import captions as synth_captions
from stablemo.data.synth.writer import motion_rng
from stablemo.errors import StableMoError
from test_synth import _measure

N_SAMPLE = 40
FEET = [7, 8, 10, 11]  # ankles and toes
# the action's first steps begin peeling a heel off up to 2 frames before its part starts
PRE_ACTION = 3


@pytest.fixture(scope="module")
def pairs():
    """The first motions of seed 0 in both rest modes (the same generator draws)."""
    return [(compose.generate_motion(motion_rng(0, i), "tight"), compose.generate_motion(motion_rng(0, i), "varied"))
            for i in range(N_SAMPLE)]


def _rest_frames(m) -> list[slice]:
    """The lead-in (up to the action's preparation) and the lead-out, as frame slices."""
    return [slice(0, max(m.parts[0].start - PRE_ACTION, 0)), slice(m.parts[-1].end, len(m.joints))]


def test_same_plans_and_captions_longer_rest(pairs):
    for tight, varied in pairs:
        assert tight.actions == varied.actions and tight.captions == varied.captions
        assert [p.params for p in tight.parts] == [p.params for p in varied.parts]
        # the actions themselves are unchanged: only the rest around them differs
        assert [p.end - p.start for p in tight.parts] == [p.end - p.start for p in varied.parts]
        assert [s[0] for s in tight.sub_captions] == [s[0] for s in varied.sub_captions]
        assert 40 <= len(varied.joints) - 1 <= 196
        # tight: 0.1-0.4 s before, 0.2-0.5 s after (more after only to reach 40 frames)
        assert tight.parts[0].start <= 8
        assert len(tight.joints) - 1 - tight.parts[-1].end <= 10 or len(tight.joints) - 1 <= 50
    lead_in = np.array([v.parts[0].start for _, v in pairs])
    lead_out = np.array([len(v.joints) - 1 - v.parts[-1].end for _, v in pairs])
    assert np.median(lead_in + lead_out) > 30 and (lead_in + lead_out).max() > 100
    assert np.ptp(lead_in) > 40 and np.ptp(lead_out) > 40  # both ends vary


def test_rest_varies_with_the_seed():
    first = [compose.generate_motion(motion_rng(seed, 0), "varied") for seed in range(6)]
    leads = {(m.parts[0].start, len(m.joints) - 1 - m.parts[-1].end) for m in first}
    assert len(leads) == 6
    assert max(sum(lead) for lead in leads) - min(sum(lead) for lead in leads) > 20  # frames


def test_rest_is_still_and_on_the_floor(pairs):
    checked = 0
    for _, m in pairs:
        j = m.joints.astype(np.float64)
        for sl in _rest_frames(m):
            rest = j[sl]
            if len(rest) < 2:
                continue
            feet = rest[:, FEET]
            assert np.linalg.norm(np.diff(feet, axis=0), axis=-1).max() < 1e-4  # m per frame: planted
            assert rest[:, FEET, 1].min(1).max() < 0.005  # a foot joint on the floor in every frame
            assert m.contacts[sl].all()
            root = rest[:, 0]
            assert np.linalg.norm(np.diff(root, axis=0), axis=-1).max() * 20 < 0.2  # m/s: idling, not moving
            assert np.linalg.norm(root[:, [0, 2]] - root[0, [0, 2]], axis=-1).max() < 0.06  # sways, stays put
            checked += len(rest)
    assert checked > 1000


def test_rest_moves_a_little():
    """Idle, not frozen: the pelvis sways and the chest breathes in a long lead-in."""
    rng = np.random.default_rng(5)
    built = compose.build_rested([("clap", dict(count=2))], 80, 10, (idle.sample_style(rng), idle.sample_style(rng)))
    j = built.joints[:70].astype(np.float64)
    assert np.ptp(j[:, 0, 0]) > 0.002  # m: sideways sway
    chest_lean = j[:, 9, [0, 2]] - j[:, 0, [0, 2]]
    assert np.linalg.norm(chest_lean - chest_lean[0], axis=-1).max() > 0.001


@pytest.mark.parametrize("name,params", [
    ("jump", dict(count=2, flight=0.42)), ("jump_forward", dict(count=2, distance=0.7, flight=0.44)),
    ("hop", dict(leg="left", count=3)), ("squat", dict(count=3, depth=0.35, period=1.7)),
    ("punch", dict(hand="right", count=2)), ("clap", dict(count=4)),
])
def test_count_is_the_same_whatever_the_length(name, params):
    """The captioned count is what the joints do at the shortest, a middle and the longest length."""
    rng = np.random.default_rng(len(name))
    plan = [(name, params)]
    core = len(compose.build_rested(plan, 0, 0, (idle.sample_style(rng), idle.sample_style(rng))).joints) - 1
    texts = synth_captions.captions_for(plan, rng)
    for total in (max(core, 40), (core + 196) // 2, 196):
        before = int(rng.integers(0, total - core + 1))
        built = compose.build_rested(plan, before, total - core - before, (idle.sample_style(rng), idle.sample_style(rng)))
        assert len(built.joints) - 1 == total
        for text in texts:
            _measure(name, built.joints, text)


def test_length_spans_the_range_whatever_the_count():
    """Drawn lengths of a 1-jump and a 3-jump plan overlap over most of 40..196 frames."""
    spans = {}
    for count in (1, 3):
        plan = [("jump", dict(count=count, flight=0.42))]
        shortest = len(compose.build(plan, 0.2, 0.3).joints) - 1
        totals = [len(compose.draw_rest(plan, shortest, 4, 6, np.random.default_rng([count, k])).joints) - 1
                  for k in range(16)]
        spans[count] = (min(totals), max(totals))
    assert spans[1][0] < 70 and spans[1][1] > 180 and spans[3][1] > 180
    assert spans[3][0] < 120  # the three-jump clips are not all long either


def test_determinism_varied():
    a = compose.generate_motion(motion_rng(7, 3), "varied")
    b = compose.generate_motion(motion_rng(7, 3), "varied")
    assert np.array_equal(a.joints, b.joints) and np.array_equal(a.contacts, b.contacts)
    assert compose.text_file(a) == compose.text_file(b)


def test_rest_mode_is_checked_and_recorded(tmp_path):
    with pytest.raises(ValueError, match="rest='idle'"):
        compose.generate_motion(np.random.default_rng(0), "idle")
    with pytest.raises(StableMoError, match="^rest='idle': must be one of varied, tight"):
        write_dataset(tmp_path / "bad", num=3, rest="idle")
    assert not (tmp_path / "bad").exists()
    from stablemo.cli import main

    assert main(["data", "synth", "--out", str(tmp_path / "t"), "--num", "3", "--rest", "tight"]) == 0
    assert json.loads((tmp_path / "t" / "synth.json").read_text())["rest"] == "tight"
    write_dataset(tmp_path / "v", num=3, workers=1)
    assert json.loads((tmp_path / "v" / "synth.json").read_text())["rest"] == idle.DEFAULT_REST == "varied"
    lengths = {mode: [len(np.load(tmp_path / d / "new_joint_vecs" / f"00000{i}.npy")) for i in range(3)]
               for mode, d in (("tight", "t"), ("varied", "v"))}
    for i in range(3):
        m = compose.generate_motion(motion_rng(0, i), "varied")
        assert lengths["varied"][i] == len(m.joints) - 1
    assert lengths["tight"] != lengths["varied"]



def test_length_vs_count_script(tmp_path):
    """scripts/synth/length_vs_count.py, run as a user runs it: the table of docs/synth.md, and
    folders checked against it."""
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    cmd = [sys.executable, str(repo / "scripts" / "synth" / "length_vs_count.py"), "--num", "30"]
    write_dataset(tmp_path / "v", num=30, seed=2, workers=1)
    done = subprocess.run([*cmd, "--seed", "2", "--data", str(tmp_path / "v")], capture_output=True, text=True,
                          cwd=repo, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.startswith("| action | clips | rho (tight) | rho (varied) |")
    assert "| all counted, single-action |" in done.stdout
    assert f"{tmp_path / 'v'}: clip lengths are the varied ones" in done.stderr
    other = subprocess.run([*cmd, "--seed", "3", "--data", str(tmp_path / "v")], capture_output=True, text=True,
                           cwd=repo, check=False)
    assert other.returncode == 2 and other.stdout == ""
    assert other.stderr.strip().splitlines()[-1].endswith(
        "written with num=30 seed=2 rest=varied, measured num=30 seed=3")
