"""A followed path turns the body (issue #41): the facing-vs-travel measure on ground truth, the
steering that keeps the path exactly, the gaits texts name, and the pipeline end to end."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from stablemo.control.heading import gait_from_text, steer_heading
from stablemo.data.synth.actions import sample_params
from stablemo.data.synth.compose import build
from stablemo.eval.heading import heading_measures
from stablemo.eval.paths import FAMILIES, family_path, path_control
from stablemo.motion.features import (
    features_to_joints,
    joints_to_features,
    recover_root,
)


def _clip(action: str, seed: int, **override) -> np.ndarray:
    rng = np.random.default_rng(seed)
    params = sample_params(action, rng)
    params.update(override)
    return build([(action, params)]).joints


@pytest.mark.parametrize("action, low, high", [("walk", 0, 2), ("jog", 0, 2), ("circle", 0, 2),
                                               ("walk_backward", 178, 180), ("walk_sideways", 88, 92)])
def test_facing_against_travel_reads_ground_truth_gaits(action, low, high):
    joints = torch.tensor(np.stack([_clip(action, s)[:60] for s in (11, 12, 13)]))
    m = heading_measures(joints, torch.tensor([60, 60, 60]), "humanml3d")
    assert np.all((m["facing_deg"] >= low) & (m["facing_deg"] <= high)), m["facing_deg"]


def test_standing_has_no_direction_of_travel():
    joints = torch.tensor(_clip("stand", 3)[None])
    m = heading_measures(joints, torch.tensor([joints.shape[1]]), "humanml3d")
    assert np.isnan(m["facing_deg"][0])


def _walk_features() -> torch.Tensor:
    feats = joints_to_features(_clip("walk", 5, duration=4.0), "humanml3d")
    return torch.tensor(feats, dtype=torch.float64)[None]


@pytest.mark.parametrize("gait, expected", [(math.pi / 2, 90.0), (math.pi, 180.0), (-math.pi / 2, 90.0)])
def test_steering_turns_the_body_and_keeps_the_path(gait, expected):
    feats = _walk_features()
    n = torch.tensor([feats.shape[1]])
    turned = steer_heading(feats, n, 20.0, gait=torch.tensor([gait], dtype=feats.dtype))
    _, before = recover_root(feats)
    _, after = recover_root(turned)
    assert torch.allclose(before, after, atol=1e-9)  # the path is the same
    m = heading_measures(features_to_joints(turned, "humanml3d"), n, "humanml3d")
    assert abs(m["facing_deg"][0] - expected) < 3, m
    # and back: the forward gait faces the path again, the path still kept
    back = steer_heading(turned, n, 20.0, gait=torch.zeros(1, dtype=feats.dtype))
    assert torch.allclose(recover_root(back)[1], before, atol=1e-9)
    assert heading_measures(features_to_joints(back, "humanml3d"), n, "humanml3d")["facing_deg"][0] < 3


def test_steering_leaves_unselected_samples_bit_identical():
    feats = _walk_features().repeat(2, 1, 1)
    n = torch.tensor([feats.shape[1]] * 2)
    out = steer_heading(feats, n, 20.0, steer=torch.tensor([False, True]),
                        gait=torch.tensor([math.pi, math.pi], dtype=feats.dtype))
    assert torch.equal(out[0], feats[0]) and not torch.equal(out[1], feats[1])


@pytest.mark.parametrize("text, gait", [
    ("a person side steps to the left", math.pi / 2), ("someone walks sideways to his right", -math.pi / 2),
    ("a man sidesteps to the right", -math.pi / 2), ("the person walks backwards", math.pi),
    ("a person moonwalks", math.pi), ("a person walks forward", None), ("a person walks back and forth", None),
    ("a person turns left", None), ("a person waves the left hand", None)])
def test_the_gait_a_text_names(text, gait):
    assert gait_from_text(text) == gait


@pytest.mark.parametrize("family", FAMILIES)
def test_path_families_are_walked_at_the_asked_speed_from_the_origin(family):
    xz = family_path(family, np.random.default_rng(0), 120, 20.0, 1.0)
    steps = np.linalg.norm(np.diff(xz, axis=0), axis=1) * 20
    assert xz.shape == (120, 2) and np.allclose(xz[0], 0) and np.allclose(steps, 1.0, atol=0.02)


def _on_polyline(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    """(N,) distance of each point to a polyline (M, 2)."""
    a, b = line[:-1], line[1:]
    ab = b - a
    u = np.clip(((points[:, None] - a[None]) * ab[None]).sum(-1) / np.maximum((ab**2).sum(-1), 1e-12), 0, 1)
    return np.linalg.norm(a[None] + u[..., None] * ab[None] - points[:, None], axis=-1).min(1)


def test_a_drawn_path_is_walked_where_the_reference_walks_and_waits_where_it_stands():
    from stablemo.control.pace import timed_path

    fps, T = 20.0, 100
    drawn = family_path("arc", np.random.default_rng(3), 40, fps, 1.0)  # a 2 m arc, as drawn
    # the reference stands 1 s, walks 3 s at 0.8 m/s along +x, stands 1 s
    speed = np.r_[np.zeros(20), np.full(60, 0.8), np.zeros(19)] / fps
    ref = np.stack([np.r_[0, np.cumsum(speed)], np.zeros(T)], -1)
    out = timed_path(drawn, ref, T)
    along = np.r_[0, np.cumsum(np.linalg.norm(np.diff(out, axis=0), axis=1))]
    assert out.shape == (T, 2) and np.allclose(out[0], drawn[0]) and np.allclose(out[-1], drawn[-1])
    assert _on_polyline(out, drawn).max() < 1e-9  # the drawn shape, only re-timed
    assert np.all(np.diff(along) >= 0)
    step = np.linalg.norm(np.diff(out, axis=0), axis=1) * fps  # (T-1,) m/s
    length = along[-1]
    assert step[:16].max() < 1e-9 and step[84:].max() < 1e-9  # waits while the reference stands
    assert np.allclose(step[24:76], length / 3.0, rtol=1e-3)  # at the reference's pace, scaled (chords of the arc: 1e-3)
    # a reference that stands: one constant speed from frame 0; another length: the same shares of time
    still = timed_path(drawn, np.zeros((T, 2)), T)
    assert np.allclose(np.linalg.norm(np.diff(still, axis=0), axis=1) * fps, length / ((T - 1) / fps), rtol=1e-3)
    half = timed_path(drawn, ref, 50)
    assert np.allclose(half, out[::2][:50], atol=0.05)


def test_a_clip_path_is_walked_at_the_reference_pace_and_length():
    """path_on_reference: the clip's shape (its sway smoothed over a gait cycle), scaled to the
    reference's length, from the reference's start, walked at its pace; a clip that stands gives
    the reference itself."""
    from stablemo.control.pace import path_on_reference, progress

    fps, T = 20.0, 100
    t = np.arange(T) / fps
    # the clip: 3 m along a diagonal at a steady pace, swaying 4 cm sideways once a second
    d = np.array([0.6, -0.8])
    clip = (3.0 * t / t[-1])[:, None] * d + 0.04 * np.sin(2 * np.pi * t)[:, None] * np.array([0.8, 0.6])
    # the reference: stands 1 s, then walks 1.5 m along +z from (1, 2)
    walked = np.r_[np.zeros(20), np.linspace(0.0, 1.5, T - 20)]
    ref = np.stack([np.ones(T), 2.0 + walked], -1)
    out = path_on_reference(clip, ref, smooth_frames=20)
    assert out.shape == (T, 2) and np.allclose(out[0], ref[0])
    step = np.linalg.norm(np.diff(out, axis=0), axis=1)
    assert step[:17].max() < 1e-9  # waits while the reference stands
    assert abs(step.sum() - 1.5) < 0.02  # the reference's length
    direction = (out[-1] - out[0]) / np.linalg.norm(out[-1] - out[0])
    assert direction @ d > 0.999  # the clip's direction
    share = np.r_[0, np.cumsum(step)] / step.sum()
    assert np.abs(share - progress(ref, T)).max() < 0.02  # at the reference's pace
    # the sway is smoothed away
    side = np.array([d[1], -d[0]])
    off = out[40:-10] @ side  # inside: a half cycle at either end keeps some (the average meets the edge)
    raw = path_on_reference(clip, ref)[40:-10] @ side  # unsmoothed: the clip's 8 cm swing, halved
    assert np.ptp(off) < 0.004 and np.ptp(raw) > 0.03
    assert np.array_equal(path_on_reference(np.zeros((T, 2)), ref), ref)


@pytest.fixture(scope="module")
def student():
    from stablemo.inference.bundle import DEMO_STUDENT
    from stablemo.inference.pipeline import Pipeline

    return Pipeline.from_bundle(DEMO_STUDENT)


def test_a_path_behind_the_body_is_walked_facing_forward(student):
    """The issue's moonwalk: a straight path 'into the screen' (-z) behind a body that starts facing
    +z. Without steering the student walks it backwards; steered, it turns and walks it forward."""
    from stablemo.inference.pipeline import Request

    T, seeds = 120, [0, 1]
    t = np.arange(T) / 20.0
    xz = np.stack([np.zeros(T), -0.9 * t], -1)
    control = path_control(xz, np.full(T, 0.93), 22)
    result = {}
    for face in (False, True):
        out = student.generate(Request(["a person walks forward"] * 2, T, seed=seeds, control=[control] * 2,
                                       face_travel=face))
        m = heading_measures(out.joints, torch.tensor([T, T]), "humanml3d")
        err = (out.joints[:, :, 0][..., [0, 2]] - torch.tensor(xz, dtype=out.joints.dtype)).norm(dim=-1)
        result[face] = (m["facing_deg"], float(err.max()))
    assert np.all(result[False][0] > 120), result
    assert np.all(result[True][0] < 15), result
    assert result[True][1] < 0.01  # still on the path (guidance projects the root exactly)


def test_a_controlnet_without_guidance_is_steered_by_its_own_hook():
    from stablemo.inference.bundle import DEMO_CONTROLNET
    from stablemo.inference.pipeline import Pipeline, Request

    pipe = Pipeline.from_bundle(DEMO_CONTROLNET)
    T = 100
    xz = family_path("arc", np.random.default_rng(3), T, 20.0, 0.9)
    control = path_control(xz, np.full(T, 0.93), 22)
    facing, paths = {}, {}
    for face in (False, True):
        out = pipe.generate(Request(["a person walks forward"] * 2, T, seed=[0, 1], control=[control] * 2,
                                    control_guidance=False, face_travel=face))
        facing[face] = heading_measures(out.joints, torch.tensor([T, T]), "humanml3d")["facing_deg"]
        paths[face] = out.raw_joints[:, :, 0]
    assert np.all(facing[True] < 10) and np.all(facing[False] > 2 * facing[True]), facing
    # the hook turns the body, not the ControlNet's path
    assert torch.allclose(paths[True][..., [0, 2]], paths[False][..., [0, 2]], atol=1e-4)


def test_facing_error_is_zero_for_the_gait_of_the_reference_and_large_against_another():
    from stablemo.eval.heading import facing_error

    walk = torch.tensor(_clip("walk", 21)[:60])[None]
    back = torch.tensor(_clip("walk_backward", 22)[:60])[None]
    n = torch.tensor([60])
    assert facing_error(walk, walk, n, "humanml3d")[0] < 1 and facing_error(back, back, n, "humanml3d")[0] < 1
    assert facing_error(back, walk, n, "humanml3d")[0] > 170


def test_a_controlnet_with_guidance_walks_a_path_behind_it_forward():
    """A ControlNet's x0 already walks where its hint pulls (backwards, for a path behind the body), so
    its gait is not read from it: the body turns and walks the path forward."""
    from stablemo.inference.bundle import DEMO_CONTROLNET
    from stablemo.inference.pipeline import Pipeline, Request

    pipe = Pipeline.from_bundle(DEMO_CONTROLNET)
    T = 100
    xz = np.stack([np.zeros(T), -0.9 * np.arange(T) / 20.0], -1)
    control = path_control(xz, np.full(T, 0.93), 22)
    out = pipe.generate(Request(["a person walks forward"] * 2, T, seed=[0, 1], control=[control] * 2))
    assert np.all(heading_measures(out.joints, torch.tensor([T, T]), "humanml3d")["facing_deg"] < 15)
