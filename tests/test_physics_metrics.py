"""Foot skating, ground and control metrics on constructed motions."""

import numpy as np
import pytest

from stablemo.eval.control import control_errors
from stablemo.skating.metrics import foot_skating_ratio, ground_metrics


def _walker(T, foot_speed, foot_height=0.02):
    """22 joints at rest above the floor; both toes (10, 11) at foot_height moving +x at foot_speed m/s."""
    j = np.zeros((T, 22, 3))
    j[:, :, 1] = 0.5
    t = np.arange(T) / 20.0
    for f, z in ((10, 0.1), (11, -0.1)):
        j[:, f, 0] = foot_speed * t
        j[:, f, 1] = foot_height
        j[:, f, 2] = z
    return j


def test_planted_feet_do_not_skate_and_sliding_feet_do():
    assert foot_skating_ratio(_walker(60, 0.0))[0] == 0.0
    assert foot_skating_ratio(_walker(60, 0.3))[0] == 0.0  # below 0.5 m/s
    ratio = foot_skating_ratio(_walker(60, 1.0))[0]
    assert ratio == pytest.approx(1.0)  # box mean at the ends is 0.6 m/s, still above 0.5
    assert foot_skating_ratio(_walker(60, 1.0, foot_height=0.2))[0] == 0.0  # airborne feet


def test_skating_partial_window_and_or_over_feet():
    j = _walker(41, 0.0)
    j[20:, 10, 0] = 0.1 * np.arange(21)  # left toe slides 0.1 m/frame = 2 m/s from frame 20 on
    ratio = foot_skating_ratio(j)[0]
    # transitions 20..39 slide (20 of 40); box mean at 19 is 0.8 m/s but v_19 = 0 → not counted.
    assert ratio == pytest.approx(20 / 40)
    j[:, 11] = j[:, 10] * [1, 1, -1]  # right foot slides identically: OR, not sum
    assert foot_skating_ratio(j)[0] == pytest.approx(20 / 40)


def test_skating_batched_equals_per_sample_with_padding():
    rng = np.random.default_rng(0)
    motions = [_walker(T, s) + rng.normal(scale=0.01, size=(T, 22, 3)) for T, s in ((50, 0.7), (33, 1.2), (60, 0.0))]
    singles = [foot_skating_ratio(m)[0] for m in motions]
    batch = np.full((3, 60, 22, 3), 7.0)  # garbage in padding must not matter
    for i, m in enumerate(motions):
        batch[i, : len(m)] = m
    batched = foot_skating_ratio(batch, lengths=[50, 33, 60])
    np.testing.assert_allclose(batched, singles, atol=1e-12)
    mask = np.arange(60)[None] < np.array([50, 33, 60])[:, None]
    np.testing.assert_allclose(foot_skating_ratio(batch, mask=mask), singles, atol=1e-12)


def test_ground_metrics_constructed():
    j = _walker(20, 0.0, foot_height=0.0)
    g = ground_metrics(j)
    assert g["penetration"][0] == 0 and g["floating"][0] == 0 and g["sliding"][0] == 0
    sunk = j.copy()
    sunk[..., 1] -= 0.105
    assert ground_metrics(sunk)["penetration"][0] == pytest.approx(0.1)
    hover = j.copy()
    hover[..., 1] += 0.205
    assert ground_metrics(hover)["floating"][0] == pytest.approx(0.2)
    slide = j.copy()
    slide[:, 10, 1] = -0.001  # left toe is the lowest joint and moves 1 cm/frame
    slide[:, 10, 0] = 0.01 * np.arange(20)
    assert ground_metrics(slide)["sliding"][0] == pytest.approx(0.01)
    padded = np.concatenate([slide, np.full((10, 22, 3), -5.0)])
    np.testing.assert_allclose([v[0] for v in ground_metrics(padded[None], lengths=[20]).values()],
                               [v[0] for v in ground_metrics(slide).values()])


def test_control_errors_constructed():
    hints = np.zeros((3, 10, 22, 3))
    joints = hints.copy()
    mask = np.zeros((3, 10, 22), bool)
    mask[:, :, 0] = True  # pelvis controlled in every frame
    joints[0, :, 0, 0] = 0.1  # sample 0: 10 cm off everywhere
    joints[1, 3, 0, 2] = 0.6  # sample 1: one frame 60 cm off
    joints[2, :, 5] = 9.0  # sample 2: perfect on the pelvis; uncontrolled joint far off is ignored
    e = control_errors(joints, hints, mask)
    assert e["avg_err"] == pytest.approx((10 * 0.1 + 0.6) / 30)
    assert e["traj_err"] == pytest.approx(1 / 3)
    assert e["loc_err"] == pytest.approx(1 / 30)
