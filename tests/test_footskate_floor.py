"""The foot-skate cleanup stands planted feet on the floor (issue #39): a motion lifted off it by
the dataset's placement (its floor set at one frame that dips through it) comes back down on every
motion type, and jumps still leave the floor."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from footskate import HUMANML3D
from footskate.cleanup import CleanupConfig, cleanup
from stablemo.bench.footskate import TYPES, build_motion

FEET = list(HUMANML3D.feet)   # [L_ankle, L_toe, R_ankle, R_toe]
PARENTS = list(HUMANML3D.parents)
DIP = 0.04                    # m: how far one touch-down frame sinks through the floor


def standing(seconds: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """A synthetic person standing still: joints (T, 22, 3), contacts (T, 4) (all down)."""
    from stablemo.data.synth import actions
    from stablemo.data.synth.timeline import Timeline

    tl = Timeline()
    actions.build_stand(tl, {"duration": seconds, "phase": 0.0})
    built = tl.build(round(seconds * 20))
    return built.joints.astype(np.float32), built.contacts.astype(bool)


def lifted(joints: np.ndarray, contacts: np.ndarray, seed: int) -> np.ndarray:
    """joints (T, 22, 3) with their planted feet on y = 0 -> the same motion as a generated one
    reaches the cleanup: 5 mm jitter on every joint, the right foot sinking DIP through the floor
    on one touch-down frame (a landing), and the floor then put at the lowest joint of any frame
    (the dataset's placement), which lifts every other stance by about DIP."""
    rng = np.random.default_rng(seed)
    x = joints + rng.normal(0.0, 0.005, joints.shape).astype(np.float32)
    toe = contacts[:, 3]
    touchdowns = np.flatnonzero(toe[1:] & ~toe[:-1]) + 1
    frame = int(touchdowns[0]) if len(touchdowns) else int(np.flatnonzero(toe)[len(np.flatnonzero(toe)) // 2])
    x[frame, [8, 11], 1] -= DIP
    x[..., 1] -= x[..., 1].min()
    return x


def lowest_foot(joints: torch.Tensor) -> torch.Tensor:
    """joints (T, 22, 3) -> (T, 2): the lower of ankle and toe of each foot."""
    y = joints[:, FEET, 1]
    return torch.minimum(y[:, 0::2], y[:, 1::2])


@pytest.mark.parametrize("kind", list(TYPES) + ["stand"])
def test_planted_feet_come_down_to_the_floor(kind):
    joints, contacts = standing() if kind == "stand" else build_motion(kind, 1000)
    x = torch.from_numpy(lifted(joints, contacts, seed=len(kind)))[None]        # (1, T, 22, 3)
    c = torch.from_numpy(contacts)[None]                                        # (1, T, 4)
    before = lowest_foot(x[0])
    res = cleanup(x, PARENTS, FEET, contacts=c, config=CleanupConfig())
    after = lowest_foot(res.joints[0])                                          # (T, 2)
    w = res.weights[0]
    flat = (w[:, 0::2] >= 1) & (w[:, 1::2] >= 1)                               # both joints fully anchored
    assert flat.sum() >= 5
    assert before[flat].median() > 0.02                                        # the input's stances float
    assert after[flat].abs().max() < 0.01, after[flat]                          # every one is back down
    assert res.joints[0][:, FEET, 1].min() > -0.01                              # nothing sinks through
    assert 0.02 < res.info["floor_offset"][0] < DIP + 0.02                      # the motion was placed
    if kind in ("jump", "hop"):
        airborne = ~c[0].any(-1)                                                # no foot joint down
        # the flight keeps its height above the stances (within the jitter and the dip)
        assert after.amin(-1)[airborne].max() > 0.10
        rise = before.amin(-1)[airborne].max() - before[flat].median()
        assert abs(after.amin(-1)[airborne].max() - rise) < 0.02


def test_a_generated_jump_lands_on_the_floor():
    """The demo model's "a person jumps forward twice" (seed 3), through the features path the
    hook and `stablemo footskate` use: the dataset's placement (its floor at the lowest point of the
    clip, a landing frame) lifts its stances, by 1.5 cm on average with the shipped teacher (3-6 cm
    with the network before its input head); after the cleanup they stand on the floor and the
    jumps still leave it."""
    from footskate.cleanup import detect_contacts
    from stablemo.inference.bundle import DEMO_BUNDLE
    from stablemo.inference.pipeline import Pipeline
    from stablemo.motion import features_to_joints
    from stablemo.skating.cleanup import clean_features, load_vgrf_model, standard_joints

    if not (DEMO_BUNDLE / "model.safetensors").is_file():
        pytest.skip("the demo bundle is not present")
    pipe = Pipeline.from_bundle(DEMO_BUNDLE, device="cpu")
    # the network's own output: the finishing step (stablemo.inference.finish) would place it on the floor first
    feats = pipe.generate(["a person jumps forward twice"], [100], seed=[3], finish=False).features
    n = torch.tensor([100])
    vgrf = load_vgrf_model(None)
    placed = standard_joints(features_to_joints(feats), n)                    # what the cleanup starts from
    contacts = detect_contacts(placed, n, FEET, 20.0, 1, vgrf, gate=True)[0][0]  # (T, 4), as the cleanup finds them
    flat = contacts[:, 0::2] & contacts[:, 1::2]                                # (T, 2) ankle and toe down
    assert flat.sum() > 40
    assert lowest_foot(placed[0])[flat].mean() > 0.01                          # lifted before

    cleaned, _, _ = clean_features(feats, n, "humanml3d", vgrf)
    out = features_to_joints(cleaned)[0]                                        # what the user's file holds
    low = lowest_foot(out)
    assert low[flat].abs().mean() < 0.01 and low[flat].median().abs() < 0.005
    assert (low[flat].abs() < 0.01).float().mean() > 0.8
    assert out[:, FEET, 1].min() > -0.01
    # every flight (no foot down for 5 frames or more) still rises above 10 cm
    airborne = ~contacts.any(-1)
    edges = torch.diff(torch.cat([torch.tensor([0]), airborne.int(), torch.tensor([0])]))
    flights = [(s, e) for s, e in zip(torch.nonzero(edges == 1).flatten().tolist(),
                                       torch.nonzero(edges == -1).flatten().tolist()) if e - s >= 5]
    assert len(flights) >= 2
    for s, e in flights:
        if s > 0:  # the clip's first frames, before the motion starts, are not a jump
            assert low.amin(-1)[s:e].max() > 0.10, (s, e)


def test_without_the_placement_the_legs_alone_bring_the_feet_down():
    """place_on_floor=False: no vertical shift of the whole motion; the anchors still put every
    stance on the floor, the legs bending for it while the upper body moves at most max_root_shift."""
    joints, contacts = build_motion("walk", 1000)
    x = torch.from_numpy(lifted(joints, contacts, seed=4))[None]
    c = torch.from_numpy(contacts)[None]
    upper = [j for j in range(len(PARENTS)) if j not in (1, 2, 4, 5, 7, 8, 10, 11)]   # all but the legs
    for place in (True, False):
        res = cleanup(x, PARENTS, FEET, contacts=c, config=CleanupConfig(place_on_floor=place))
        w = res.weights[0]
        flat = (w[:, 0::2] >= 1) & (w[:, 1::2] >= 1)
        assert lowest_foot(res.joints[0])[flat].abs().max() < 0.01
        moved = (res.joints[0] - x[0])[:, upper].norm(dim=-1)                   # (T, J')
        if place:   # the whole body came down with its feet
            assert res.info["floor_offset"][0] > 0.03 and moved.min() > res.info["floor_offset"][0] - 0.026
        else:
            assert res.info["floor_offset"] == [0.0] and moved.max() <= CleanupConfig().max_root_shift + 1e-6
