"""Kinematic measures (stablemo.eval.kinematics) on ground-truth motions and on planted defects."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from stablemo.errors import StableMoError
from stablemo.eval import kinematics as K

REAL_CLIP = Path(__file__).resolve().parents[2] / "shared" / "data" / "humanml3d-sample" / "new_joints" / "012314.npy"
KINDS = ("stand", "walk", "run", "jump", "kick", "squat", "walk_sideways", "turn", "wave")


def synth_clip(action: str, seed: int = 0) -> np.ndarray:
    """One synthetic ground-truth motion (T, 22, 3), metres, floor at y = 0."""
    from stablemo.data.synth import actions
    from stablemo.data.synth.compose import build

    rng = np.random.default_rng([seed, KINDS.index(action)])
    return build([(action, actions.sample_params(action, rng))]).joints.astype(np.float64)


def pad(clips: list[np.ndarray]) -> tuple[np.ndarray, list[int]]:
    lengths = [len(c) for c in clips]
    out = np.zeros((len(clips), max(lengths)) + clips[0].shape[1:])
    for i, c in enumerate(clips):
        out[i, : len(c)] = c
    return out, lengths


@pytest.fixture(scope="module")
def gt():
    clips = {k: synth_clip(k) for k in KINDS}
    joints, lengths = pad(list(clips.values()))
    return clips, K.measure(joints, lengths, "humanml3d")


def test_ground_truth_is_a_rigid_body_standing_on_the_floor(gt):
    clips, m = gt
    row = {k: i for i, k in enumerate(clips)}
    assert np.all(m["bone_change"] < 1e-3)                       # cm: synthetic bodies are exact FK
    assert np.all(m["floor_p1"] > -0.01) and np.all(m["below_floor"] == 0)
    assert np.all(np.abs(m["stance_height"]) < 0.1)              # the synthetic toe rests at y = 0
    assert np.all(m["stance_speed"] < 2.0)                       # cm/s: planted feet do not slide
    assert m["airborne"][row["jump"]] > 0.1 and m["airborne"][row["run"]] > 0.02
    for still in ("walk", "stand", "squat", "kick", "turn", "wave", "walk_sideways"):
        assert m["airborne"][row[still]] == 0, still
    assert m["foot_acc"][row["stand"]] < 1e-9 and m["foot_acc"][row["run"]] > m["foot_acc"][row["walk"]] > 0


def test_a_batch_scores_each_motion_as_if_alone(gt):
    clips, m = gt
    for i, clip in enumerate(clips.values()):
        alone = K.measure(clip[None], [len(clip)], "humanml3d")
        for key in K.MEASURES:
            np.testing.assert_allclose(m[key][i], alone[key][0], rtol=1e-9, atol=1e-9, err_msg=key)


def test_planted_defects_are_seen():
    walk = synth_clip("walk")
    n = [len(walk)]
    # a forearm 10 cm longer on the second half: the wrist moves along the forearm
    stretched = walk.copy()
    forearm = stretched[:, 20] - stretched[:, 18]
    stretched[len(walk) // 2:, 20] += 0.10 * (forearm / np.linalg.norm(forearm, axis=-1, keepdims=True))[len(walk) // 2:]
    assert K.bone_change(stretched[None], n, "humanml3d")[0] == pytest.approx(10.0, abs=0.01)
    sunk = walk - np.array([0, 0.05, 0])
    pen = K.floor_penetration(sunk[None], n, "humanml3d")
    assert pen["floor_p1"][0] == pytest.approx(-5.0, abs=0.01) and pen["below_floor"][0] == 1.0
    assert K.stance_height(sunk[None], n, "humanml3d")[0] == pytest.approx(-5.0, abs=0.01)
    lifted = walk + np.array([0, 0.05, 0])
    assert K.stance_height(lifted[None], n, "humanml3d")[0] == pytest.approx(5.0, abs=0.01)
    assert K.airborne_share(lifted[None], n, "humanml3d")[0] == 0      # a floating body is not a jump
    # skating: a standing body drifting at 0.3 m/s keeps both feet "in contact" (slow and low)
    stand = synth_clip("stand")
    drift = stand + np.arange(len(stand))[:, None, None] * np.array([0.3 / 20.0, 0, 0])
    assert K.stance_speed(drift[None], [len(stand)], "humanml3d")[0] == pytest.approx(30.0, abs=0.01)
    # a jump glued to the floor no longer leaves it
    jump = synth_clip("jump")
    lowest = jump[:, [7, 8, 10, 11], 1].min(1)                    # every frame's feet put back on the floor
    glued = jump - np.stack([np.zeros_like(lowest), lowest, np.zeros_like(lowest)], -1)[:, None]
    assert K.airborne_share(jump[None], [len(jump)], "humanml3d")[0] > 0.1
    assert K.airborne_share(glued[None], [len(jump)], "humanml3d")[0] == 0



def test_standing_foot_speed_sees_a_drag_that_the_stance_measure_drops():
    """Ground truth stands on still feet; a body dragged at 0.5 m/s slides its standing foot at 0.5;
    dragged at 1.5 m/s (past footskate's 0.93 m/s contact bound) the stance measure stops counting
    those feet, the standing foot's speed does not; a jump's flight is not a slide."""
    for action in ("walk", "stand", "run", "squat", "turn", "walk_sideways", "jump"):
        clip = synth_clip(action)
        assert K.standing_foot_speed(clip[None], [len(clip)], "humanml3d")[0] < 3.0, action  # cm/s
    walk = synth_clip("walk")
    n = [len(walk)]
    t = np.arange(len(walk))[:, None, None] / 20.0
    slow = walk + t * np.array([0.0, 0, 0.5])
    fast = walk + t * np.array([0.0, 0, 1.5])
    assert K.standing_foot_speed(slow[None], n, "humanml3d")[0] == pytest.approx(50.0, abs=6.0)
    assert K.standing_foot_speed(fast[None], n, "humanml3d")[0] == pytest.approx(150.0, abs=10.0)
    assert K.stance_speed(slow[None], n, "humanml3d")[0] == pytest.approx(50.0, abs=6.0)
    assert np.isnan(K.stance_speed(fast[None], n, "humanml3d")[0])  # no foot under 0.93 m/s: no contact
    # a batch scores each motion as if alone, padding ignored
    joints, lengths = pad([walk, slow[:60]])
    both = K.standing_foot_speed(joints, lengths, "humanml3d")
    assert both[1] == pytest.approx(K.standing_foot_speed(slow[None, :60], [60], "humanml3d")[0], rel=1e-9)

def test_floating_between_jumps_is_floating_not_flight():
    """A jump lifted 6 cm except for two frames on the floor (what putting a motion's lowest dip on the
    floor does) floats in stance: stance height 6 cm, its flights as before; a 2-frame dip of 6 cm
    under the floor moves neither."""
    jump = synth_clip("jump")
    n = [len(jump)]
    base = K.measure(jump[None], n, "humanml3d")
    lifted = jump + np.array([0, 0.06, 0])
    lifted[:2] = jump[:2]
    m = K.measure(lifted[None], n, "humanml3d")
    assert m["floor_p1"][0] == pytest.approx(0.0, abs=1e-6) and m["stance_height"][0] == pytest.approx(6.0, abs=0.01)
    assert m["airborne"][0] == pytest.approx(base["airborne"][0], abs=0.02)
    dipped = jump.copy()
    dipped[3:5] -= np.array([0, 0.06, 0])                        # standing still before the jump
    d = K.measure(dipped[None], n, "humanml3d")
    assert d["airborne"][0] == base["airborne"][0] and d["stance_height"][0] == pytest.approx(0.0, abs=1e-6)
    assert d["floor_p1"][0] < -1.0                                # the dip itself is seen where it belongs


def test_kit_millimetres_give_the_same_centimetres():
    from stablemo.bench.footskate import to_kit

    for action in ("walk", "jump"):
        clip = synth_clip(action)
        kit, _ = to_kit(clip.astype(np.float32), np.zeros((len(clip), 4), bool))
        mm = kit.astype(np.float64)[None] * 1000
        m = K.measure(mm, [len(kit)], "kit")
        assert abs(m["floor_p1"][0]) < 0.1 and abs(m["stance_height"][0]) < 0.5, m
        assert m["stance_speed"][0] < 5.0, m                        # 12.5 fps: coarser contact edges (2.5 cm/s)
        sunk = K.floor_penetration(mm - np.array([0, 50.0, 0]), [len(kit)], "kit")
        assert sunk["floor_p1"][0] == pytest.approx(m["floor_p1"][0] - 5.0, abs=0.01)
        assert (m["airborne"][0] > 0.1) == (action == "jump")


@pytest.mark.skipif(not REAL_CLIP.is_file(), reason="the HumanML3D sample clip is absent (../shared/data)")
def test_real_clip_values():
    """HumanML3D 012314: a rigid body on the floor, its toes resting ~1 cm above it in stance."""
    clip = np.load(REAL_CLIP).astype(np.float64)
    m = {k: float(v[0]) for k, v in K.measure(clip[None], [len(clip)], "humanml3d").items()}
    assert m["bone_change"] < 0.01
    assert 0 <= m["floor_p1"] < 0.5 and m["below_floor"] == 0
    assert 0.5 < m["stance_height"] < 1.5                         # measured 0.95 cm
    assert m["stance_speed"] < 10.0                               # measured 8.7 cm/s (contact edges)
    assert m["airborne"] < 0.05


def test_displacement_and_end_effectors():
    assert K.end_effectors("humanml3d") == [10, 11, 15, 20, 21]
    assert K.end_effectors("kit") == [4, 7, 10, 15, 20]
    assert K.end_effector_groups("humanml3d") == {"feet": [10, 11], "hands": [20, 21], "head": [15]}
    assert K.end_effector_groups("kit") == {"feet": [15, 20], "hands": [7, 10], "head": [4]}
    walk = synth_clip("walk")
    joints, lengths = pad([walk, walk[:50]])
    moved = joints + np.array([0.03, 0.0, 0.04])                 # 5 cm, padding included (ignored)
    np.testing.assert_allclose(K.displacement(joints, moved, lengths, "humanml3d"), [5.0, 5.0])
    hands = K.displacement(joints, moved, lengths, "humanml3d", joint_ids=[20, 21])
    np.testing.assert_allclose(hands, [5.0, 5.0])


def test_undefined_and_bad_input():
    walk = synth_clip("walk")
    air = walk + np.arange(len(walk))[:, None, None] * np.array([0, 0, 0.2])  # 4 m/s: no contact
    assert np.isnan(K.stance_height(air[None], [len(walk)], "humanml3d")[0])
    assert K.summarise({"stance_height": np.array([np.nan, 2.0]), "x": np.array([np.nan])}) == {"stance_height": 2.0}
    with pytest.raises(StableMoError, match="joints: expected"):
        K.measure(walk[None, :, :21], [len(walk)], "humanml3d")
    with pytest.raises(StableMoError, match="lengths"):
        K.measure(walk[None], [len(walk) + 1], "humanml3d")
    bad = walk.copy()
    bad[3, 4, 1] = np.nan
    with pytest.raises(StableMoError, match="NaN"):
        K.measure(bad[None], [len(walk)], "humanml3d")
    bad_padding = np.concatenate([walk, np.full((5, 22, 3), np.nan)])[None]  # NaN on padding is ignored
    assert np.isfinite(K.bone_change(bad_padding, [len(walk)], "humanml3d")).all()
