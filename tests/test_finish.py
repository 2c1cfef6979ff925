"""The finishing step (stablemo.inference.finish): generated joints -> one rigid body on the floor."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from stablemo.errors import StableMoError
from stablemo.eval import kinematics as K
from stablemo.inference.finish import Finish, body_lengths
from stablemo.motion.features import feature_slices, features_to_joints, joints_to_features
from stablemo.motion.floor import place_on_floor
from stablemo.motion.rigid import bone_lengths_of, rigid_joints
from stablemo.motion.skeleton import HUMANML3D, KIT

REAL_CLIP = Path(__file__).resolve().parents[2] / "shared" / "data" / "humanml3d-sample" / "new_joints" / "012314.npy"
KINDS = ("walk", "jump", "run", "squat", "turn", "wave")
FEET = list(HUMANML3D.contact_joints)


def synth(action: str, seed: int = 0) -> np.ndarray:
    from stablemo.data.synth import actions
    from stablemo.data.synth.compose import build

    rng = np.random.default_rng([seed, KINDS.index(action)])
    return build([(action, actions.sample_params(action, rng))]).joints.astype(np.float64)


def stretch(joints: np.ndarray, seed: int = 0, amount: float = 0.12) -> np.ndarray:
    """Every joint moved by its own smooth wobble of up to `amount` metres: rubber limbs, as a
    denoiser makes them (each joint predicted on its own)."""
    rng = np.random.default_rng(seed)
    t = np.arange(len(joints))[:, None, None]
    phase, freq = rng.uniform(0, 6.3, (1, 22, 3)), rng.uniform(0.05, 0.2, (1, 22, 3))
    wobble = amount * np.sin(freq * t + phase) * rng.uniform(0.2, 1.0, (1, 22, 3))
    wobble[:, 0] = 0.0  # the root path is what it is
    return joints + wobble


def spread(j: np.ndarray) -> float:
    """Largest change of any bone's length within the motion (metres)."""
    lengths = bone_lengths_of(torch.from_numpy(j), HUMANML3D).numpy()[:, 1:]
    return float(np.ptp(lengths, axis=0).max())


def test_a_rigid_motion_is_left_as_it_is():
    for action in KINDS:
        clip = synth(action)
        out = rigid_joints(torch.from_numpy(clip), HUMANML3D).numpy()
        # the synthetic body is the standard one to < 1 mm, but its generator bends spine1 against the
        # hips (up to ~7° in squats and jumps), which a rigid pelvis (SMPL's, a BVH's) does not; the
        # real clip's pelvis is rigid and comes back exactly (next test)
        assert np.abs(out - clip).max() < 0.02, action
        assert np.median(np.abs(out - clip)) < 1e-3, action


@pytest.mark.skipif(not REAL_CLIP.is_file(), reason="HumanML3D sample clip absent")
def test_a_real_clip_keeps_its_pose_and_gets_the_body():
    clip = np.load(REAL_CLIP).astype(np.float64)
    out = rigid_joints(torch.from_numpy(clip), HUMANML3D).numpy()
    assert spread(out) < 1e-6 and np.abs(out - clip).max() < 1e-4  # the real data already has this body


def test_the_pelvis_and_chest_keep_one_shape():
    rubber = stretch(synth("turn"), seed=3)
    out = rigid_joints(torch.from_numpy(rubber), HUMANML3D).numpy()
    for a, b in ((1, 2), (1, 3), (13, 14), (12, 13)):  # hip to hip, hip to spine, collar to collar, neck to collar
        assert np.ptp(np.linalg.norm(rubber[:, a] - rubber[:, b], axis=-1)) > 0.02
        assert np.ptp(np.linalg.norm(out[:, a] - out[:, b], axis=-1)) < 1e-6, (a, b)


def test_rubber_limbs_become_rigid_with_hands_and_feet_kept():
    clip = synth("walk")
    rubber = stretch(clip)
    assert spread(rubber) > 0.1
    out = rigid_joints(torch.from_numpy(rubber), HUMANML3D).numpy()
    assert spread(out) < 1e-6
    lengths = bone_lengths_of(torch.from_numpy(out[:1]), HUMANML3D).numpy()[0]
    np.testing.assert_allclose(lengths[1:], HUMANML3D.bone_lengths[1:], atol=1e-9)
    np.testing.assert_array_equal(out[:, 0, [0, 2]], rubber[:, 0, [0, 2]])  # the root's path (its height may move)
    # feet stay where they were generated wherever the rigid leg reaches them
    for upper, mid, end in HUMANML3D.ik_limbs[:2]:
        reach = HUMANML3D.bone_lengths[mid] + HUMANML3D.bone_lengths[end]
        ok = np.linalg.norm(rubber[:, end] - out[:, upper], axis=-1) < reach - 1e-3
        assert ok.mean() > 0.3
        assert np.abs(out[ok, end] - rubber[ok, end]).max() < 1e-6
    # each knee bends to the side of the hip-ankle line that the generated knee is on: never flipped
    forward = np.cross([0, 1, 0], rubber[:, 1] - rubber[:, 2])
    for hip, knee, ankle in HUMANML3D.ik_limbs[:2]:
        line = rubber[:, ankle] - out[:, hip]
        line /= np.linalg.norm(line, axis=-1, keepdims=True)

        def side(k, hip=hip, line=line):
            rel = k - out[:, hip]
            across = rel - np.einsum("ti,ti->t", rel, line)[:, None] * line
            return np.einsum("ti,ti->t", across, forward)
        reach = HUMANML3D.bone_lengths[knee] + HUMANML3D.bone_lengths[ankle]
        straight = np.linalg.norm(rubber[:, ankle] - out[:, hip], axis=-1) > reach - 1e-3  # no bend to keep
        thigh = rubber[:, knee] - rubber[:, hip]
        generated = out[:, hip] + HUMANML3D.bone_lengths[knee] * thigh / np.linalg.norm(thigh, axis=-1, keepdims=True)
        bent = (np.abs(side(generated)) > 0.01) & ~straight
        assert bent.mean() > 0.15 and np.all(np.sign(side(out[:, knee])[bent]) == np.sign(side(generated)[bent]))


def test_hands_keep_their_angles_unless_held_and_an_unreachable_one_is_reached_for():
    clip = synth("wave")
    rubber = stretch(clip, seed=5)
    out = rigid_joints(torch.from_numpy(rubber), HUMANML3D).numpy()
    for shoulder, elbow, wrist in HUMANML3D.ik_limbs[2:]:  # by default: the generated elbow angle
        def cos(j):
            a, b = j[:, elbow] - j[:, shoulder], j[:, wrist] - j[:, elbow]
            return np.einsum("ti,ti->t", a, b) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
        np.testing.assert_allclose(cos(out), cos(rubber), atol=1e-6)
    far = clip.copy()
    far[:, 21] += (far[:, 21] - far[:, 17]) * 1.0  # the wrist twice as far from the shoulder
    hold = np.zeros(far.shape[:2])  # (T, J)
    hold[..., [7, 8, 10, 11, 21]] = 1.0  # the feet and the right hand keep their generated places
    out = rigid_joints(torch.from_numpy(far), HUMANML3D, hold=torch.from_numpy(hold)).numpy()
    aim = far[:, 21] - out[:, 17]
    got = out[:, 21] - out[:, 17]
    cos = np.einsum("ti,ti->t", aim, got) / np.linalg.norm(aim, axis=-1) / np.linalg.norm(got, axis=-1)
    assert cos.min() > 0.999  # straight arm pointing at it
    np.testing.assert_allclose(np.linalg.norm(got, axis=-1), HUMANML3D.bone_lengths[19] + HUMANML3D.bone_lengths[21],
                               rtol=1e-6)


def test_kit_bodies_in_millimetres():
    rng = np.random.default_rng(0)
    base = KIT.target_offsets  # a T-ish rest pose from the skeleton's own offsets
    pose = np.zeros((21, 3))
    for chain in KIT.kinematic_chains:
        for p, c in zip(chain[:-1], chain[1:]):
            pose[c] = pose[p] + base[c]
    pose[:, 1] += 1000.0
    frames = pose[None] + rng.normal(0, 20.0, (30, 21, 3))
    out = rigid_joints(torch.from_numpy(frames), KIT).numpy()
    lengths = bone_lengths_of(torch.from_numpy(out), KIT).numpy()
    np.testing.assert_allclose(lengths[:, 1:], np.broadcast_to(KIT.bone_lengths[1:], lengths[:, 1:].shape), rtol=1e-9)


def lowest_foot(j: np.ndarray) -> np.ndarray:
    return j[:, FEET, 1].min(-1)


def test_sunk_and_drifting_feet_are_put_on_the_floor_and_jumps_still_leave_it():
    for action in ("walk", "jump", "run", "squat"):
        clip = synth(action)
        drift = np.linspace(-0.06, -0.02, len(clip))[:, None]  # the ground sinks then rises under the body
        sunk = clip.copy()
        sunk[..., 1] += drift
        out = place_on_floor(torch.from_numpy(sunk)[None], [len(clip)], HUMANML3D)[0].numpy()
        np.testing.assert_array_equal(out[..., [0, 2]], sunk[..., [0, 2]])  # heights only
        assert out[..., 1].min() > -1e-9
        m = K.measure(out[None], [len(out)], "humanml3d")
        gt = K.measure(clip[None], [len(clip)], "humanml3d")
        assert m["floor_p1"][0] > -1.0 and abs(m["stance_height"][0] - gt["stance_height"][0]) < 1.0, action
        assert abs(m["airborne"][0] - gt["airborne"][0]) < 0.05, action  # jumps and flight phases kept
        assert np.abs(out - clip).max() < 0.02, action  # the drift is undone, the motion otherwise as it was


def test_a_lifted_body_is_lowered_but_a_jump_keeps_its_height():
    clip = synth("jump")
    lifted = clip.copy()
    lifted[..., 1] += 0.04
    out = place_on_floor(torch.from_numpy(lifted)[None], [len(clip)], HUMANML3D)[0].numpy()
    assert np.abs(lowest_foot(out).max() - lowest_foot(clip).max()) < 0.01  # the apex as generated
    assert np.abs(out - clip).max() < 0.01


def make_features(clips: list[np.ndarray]) -> tuple[torch.Tensor, list[int]]:
    feats = [joints_to_features(c, "humanml3d", refit=False) for c in clips]  # rubber kept
    lengths = [len(f) for f in feats]
    out = torch.zeros(len(feats), max(lengths), feats[0].shape[1])
    for i, f in enumerate(feats):
        out[i, : len(f)] = torch.from_numpy(f)
    return out, lengths


def test_finish_gives_features_that_recover_its_rigid_joints_batch_or_alone():
    finish = Finish.from_config({}, "humanml3d", 20.0)
    clips = [stretch(synth(a), seed=i) for i, a in enumerate(("walk", "jump", "turn"))]
    clips = [c[: 60 + 20 * i] for i, c in enumerate(clips)]
    feats, lengths = make_features(clips)
    raw = features_to_joints(feats)
    out_f, out_j = finish(feats, lengths)
    for i, n in enumerate(lengths):
        j = out_j[i, :n].double().numpy()
        assert spread(j) < 1e-3  # written joints: one body (float32 features)
        assert lowest_foot(j).min() > -0.01
        np.testing.assert_allclose(j[:, 0, [0, 2]], raw[i, :n, 0, [0, 2]].numpy(), atol=1e-4)  # the path
        assert torch.equal(features_to_joints(out_f[i, :n]), out_j[i, :n])  # the features' recovery, to the bit
        assert (out_f[i, n:] == 0).all() and (out_j[i, n:] == 0).all()
        alone_f, _ = finish(feats[i:i + 1, :n], [n])
        torch.testing.assert_close(alone_f[0], out_f[i, :n], rtol=0, atol=1e-5)
    # the raw joints were far from rigid
    assert max(spread(raw[i, :n].double().numpy()) for i, n in enumerate(lengths)) > 0.05


def test_finish_in_float32_is_its_float64_result_to_rounding():
    """The step runs in the features' dtype (the pipeline's float32); its many small steps (IK near
    straight limbs, 6D rotations of short bones) must not amplify float32 rounding beyond noise."""
    finish = Finish.from_config({}, "humanml3d", 20.0)
    clips = [stretch(synth(a), seed=i)[:70] for i, a in enumerate(("walk", "run", "squat"))]
    feats, lengths = make_features(clips)
    f32, j32 = finish(feats, lengths)
    f64, j64 = finish(feats.double(), lengths)
    assert f32.dtype == torch.float32 and f64.dtype == torch.float64
    assert (j32.double() - j64).abs().max() < 1e-5  # metres
    assert (f32.double() - f64).abs().max() < 1e-4
    assert (j32.double() - j64).abs().max() > 0  # truly two precisions


def test_joint_targets_keep_their_height():
    from stablemo.control.spec import ControlTargets

    finish = Finish.from_config({}, "humanml3d", 20.0)
    feats, lengths = make_features([synth("walk")[:60]])
    raw = features_to_joints(feats)
    targets, mask = torch.zeros(1, 59, 22, 3), torch.zeros(1, 59, 22, dtype=torch.bool)
    targets[0, 30, 0] = raw[0, 30, 0] + torch.tensor([0.0, 0.1, 0.0])  # the pelvis 10 cm higher at frame 30
    mask[0, 30, 0] = True
    _, joints = finish(feats, lengths, ControlTargets(targets, mask))
    assert abs(float(joints[0, 30, 0, 1] - targets[0, 30, 0, 1])) < 1e-4
    np.testing.assert_allclose(joints[0, 30, 0, [0, 2]].numpy(), targets[0, 30, 0, [0, 2]].numpy(), atol=1e-4)


def test_a_hand_target_is_reached_with_the_feet_on_the_floor():
    """A wrist target (a limb end) is reached by the arm after the body is put on the floor; it does
    not pin the frame's height (a generated body 4 cm in the floor stayed there, and a wrist the rigid
    arm could not reach shifted the whole body down to it: feet 36 cm under the floor)."""
    from stablemo.control.spec import ControlTargets

    finish = Finish.from_config({}, "humanml3d", 20.0)
    clip = synth("wave")[:60]
    clip[..., 1] -= 0.04  # sunk into the floor, as generated bodies are
    feats, lengths = make_features([clip])
    raw = features_to_joints(feats)
    targets, mask = torch.zeros(1, 59, 22, 3), torch.zeros(1, 59, 22, dtype=torch.bool)
    targets[0, 25:35, 21] = raw[0, 25:35, 21] + torch.tensor([0.0, -0.04, 0.03])  # the right wrist, 5 cm off, within reach
    mask[0, 25:35, 21] = True
    _, joints = finish(feats, lengths, ControlTargets(targets, mask))
    j = joints[0].double().numpy()
    assert (np.linalg.norm(j[25:35, 21] - targets[0, 25:35, 21].numpy(), axis=-1) < 0.005).all()
    assert lowest_foot(j).min() > -0.005  # the whole motion on the floor, the targeted frames too
    assert spread(j) < 1e-3


def test_a_pinned_pelvis_lifts_sunk_feet_out_of_the_floor():
    """A pelvis target lower than the generated legs stand (a path's heights from another motion)
    keeps the pelvis there, and the legs bend so that the feet stay out of the floor."""
    from stablemo.control.spec import ControlTargets

    finish = Finish.from_config({}, "humanml3d", 20.0)
    feats, lengths = make_features([synth("walk")[:60]])
    raw = features_to_joints(feats)
    targets, mask = torch.zeros(1, 59, 22, 3), torch.zeros(1, 59, 22, dtype=torch.bool)
    targets[0, :, 0] = raw[0, :59, 0] - torch.tensor([0.0, 0.08, 0.0])  # the pelvis 8 cm lower all along
    mask[0, :, 0] = True
    _, joints = finish(feats, lengths, ControlTargets(targets, mask))
    j = joints[0].double().numpy()
    np.testing.assert_allclose(j[:, 0], targets[0, :, 0].numpy(), atol=1e-4)
    assert lowest_foot(j).min() > -0.005, lowest_foot(j).min()
    assert spread(j) < 1e-3


def test_the_bundle_body_is_read_and_checked(tmp_path):
    np.testing.assert_array_equal(body_lengths({}, "humanml3d"), HUMANML3D.bone_lengths)
    custom = (HUMANML3D.bone_lengths * 1.1).tolist()
    np.testing.assert_allclose(body_lengths({"body": {"bone_lengths": custom}}, "humanml3d"), custom)
    for bad in ([1.0] * 5, [0.0] * 22, ["x"] * 22, None, [float("nan")] * 22):
        with pytest.raises(StableMoError, match=r"bundle/config.json: 'body.bone_lengths' must be 22"):
            body_lengths({"body": {"bone_lengths": bad}}, "humanml3d", "bundle/config.json")
    # a bundle whose body is broken is refused at load, naming its config file
    import shutil

    from stablemo.inference.bundle import DEMO_STUDENT as _STUDENT
    from stablemo.inference.pipeline import Pipeline as _Pipeline

    broken = tmp_path / "broken"
    shutil.copytree(_STUDENT, broken)
    cfg = json.loads((broken / "config.json").read_text())
    cfg["body"] = {"bone_lengths": [1.0, 2.0]}
    (broken / "config.json").write_text(json.dumps(cfg))
    with pytest.raises(StableMoError, match=r"broken/config.json: 'body.bone_lengths' must be 22"):
        _Pipeline.from_bundle(broken)
    # a bundle with another body generates on that body
    from stablemo.inference.bundle import DEMO_STUDENT
    from stablemo.inference.pipeline import Pipeline

    config = json.loads((DEMO_STUDENT / "config.json").read_text())
    assert np.allclose(config["body"]["bone_lengths"], HUMANML3D.bone_lengths, atol=1e-6)  # measured on its data
    pipe = Pipeline.from_bundle(DEMO_STUDENT)
    object.__setattr__(pipe, "finish", Finish.from_config({"body": {"bone_lengths": custom}}, "humanml3d", 20.0))
    out = pipe.generate(["a person walks forward"], 60, seed=0)
    got = bone_lengths_of(out.joints[0].double(), HUMANML3D).numpy()
    np.testing.assert_allclose(got[:, 1:], np.broadcast_to(custom[1:], got[:, 1:].shape), atol=1e-3)


def test_generation_is_finished_unless_asked_not_to():
    from stablemo.inference.bundle import DEMO_BUNDLE
    from stablemo.inference.pipeline import Pipeline

    pipe = Pipeline.from_bundle(DEMO_BUNDLE)
    prompts = ["a person walks forward, then waves their right hand", "a person jumps forward twice"]
    out = pipe.generate(prompts, 120, seed=0, steps=4)
    raw = pipe.generate(prompts, 120, seed=0, steps=4, finish=False)
    torch.testing.assert_close(out.raw_features, raw.features)
    for i in range(2):
        assert spread(raw.joints[i].double().numpy()) > 0.05  # the network's rubber limbs
        assert spread(out.joints[i].double().numpy()) < 1e-3
        assert lowest_foot(out.joints[i].numpy()).min() > -0.01
    with pytest.raises(StableMoError, match="finish: expected True or False"):
        pipe.generate(prompts, 120, finish="yes")


def test_kit_legs_are_legs():
    """KIT's contact joints hang below the ankle: its legs are still found (hip, knee, ankle), so a
    planted KIT foot stays where it was generated and stretched legs lower the pelvis, as on HumanML3D."""
    assert HUMANML3D.legs == {"left": (1, 4, 7), "right": (2, 5, 8)}
    assert KIT.legs == {"left": (16, 17, 18), "right": (11, 12, 13)}
    pose = np.zeros((21, 3))
    for chain in KIT.kinematic_chains:
        for p, c in zip(chain[:-1], chain[1:]):
            pose[c] = pose[p] + KIT.target_offsets[c]
    pose[:, 1] -= pose[:, 1].min()
    frames = np.repeat(pose[None], 20, axis=0)
    # the trunk and hips 8 cm higher on the same knees and feet: legs stretched as a denoiser does
    frames[:, list(range(11)) + [11, 16]] += np.array([0.0, 80.0, 0.0])
    out = rigid_joints(torch.from_numpy(frames), KIT).numpy()
    for _, _, ankle in KIT.legs.values():
        np.testing.assert_allclose(out[:, ankle], frames[:, ankle], atol=1e-6)  # the planted ankle kept
    assert out[:, 0, 1].max() < frames[:, 0, 1].min() - 40.0  # the pelvis came down to reach it


def test_a_giant_stride_does_not_drop_the_body_into_a_lunge():
    """Legs generated 40 % too long in a wide stride: a leg of the body's length cannot keep both
    the planted foot and the knee angle without lowering the pelvis by tens of centimetres (the
    README's prompt did so by 37 cm); the root moves by at most MAX_ROOT_MOVE_M."""
    from stablemo.motion.rigid import MAX_ROOT_MOVE_M

    clip = synth("walk")
    long = clip.copy()
    for hip, knee, ankle in HUMANML3D.legs.values():
        for j in (knee, ankle, 10 if ankle == 7 else 11):
            long[:, j] = clip[:, hip] + 1.4 * (clip[:, j] - clip[:, hip])
    out = rigid_joints(torch.from_numpy(long), HUMANML3D).numpy()
    move = out[:, 0, 1] - long[:, 0, 1]
    assert np.abs(move).max() <= MAX_ROOT_MOVE_M + 1e-9
    assert np.abs(move).max() > 0.05  # it still moves where the legs ask for it


def test_planted_feet_stay_where_they_land():
    """The demo student's walks drag their stance feet (~24 cm/s over the kinematic prompts); the
    finishing step anchors each planted ankle over its stance, so what the user receives keeps
    its feet still while the raw output slides, and no ankle moves further than ANCHOR_REACH_M."""
    from stablemo.eval.kinematics import stance_speed
    from stablemo.inference.bundle import DEMO_STUDENT
    from stablemo.inference.finish import ANCHOR_REACH_M
    from stablemo.inference.pipeline import Pipeline, Request

    pipe = Pipeline.from_bundle(DEMO_STUDENT)
    out = pipe.generate(Request(["a person walks forward", "a person walks slowly in a circle"] * 2, 120,
                                seed=[0, 1, 2, 3]))
    n = torch.tensor(out.lengths)
    raw, final = stance_speed(out.raw_joints, n, "humanml3d"), stance_speed(out.joints, n, "humanml3d")
    assert final.mean() < 0.6 * raw.mean() and np.all(final < 0.8 * raw), (raw, final)
    ankles = [7, 8]
    moved = (out.joints[:, :, ankles][..., [0, 2]] - out.raw_joints[:, :, ankles][..., [0, 2]]).norm(dim=-1)
    assert moved.max() < ANCHOR_REACH_M + 0.02  # the anchor's reach, plus the rigid legs' own few centimetres


def test_a_planted_foot_that_turns_keeps_its_toe_on_its_anchor():
    """A foot generated turning about its planted ankle (the toe sweeping 40 degrees over the floor
    in a second, as the demo teacher's feet do along a turning path) keeps its toe where it was put
    down once finished: the toe turns about the vertical towards its stance's anchor, with the
    foot's pitch and the bone's length as placed; a swinging foot (contacts off) keeps its turn."""
    clip = synth("squat")  # both feet planted throughout
    t = len(clip)
    raw = clip.copy()
    ankle, toe = HUMANML3D.feet_left
    yaw = np.radians(np.linspace(0.0, 40.0, t))  # the left toe swept about the ankle
    rel = clip[:, toe] - clip[:, ankle]
    c, s = np.cos(yaw), np.sin(yaw)
    raw[:, toe, 0] = clip[:, ankle, 0] + c * rel[:, 0] + s * rel[:, 2]
    raw[:, toe, 2] = clip[:, ankle, 2] - s * rel[:, 0] + c * rel[:, 2]
    finish = Finish.from_config({}, HUMANML3D, 20.0)
    joints = torch.from_numpy(raw)[None]

    def toe_speed(j, contacts):
        out = finish.joints(j, [t], contacts=contacts)[0].numpy()
        xz = out[:, toe][:, [0, 2]]
        return np.linalg.norm(np.diff(xz, axis=0), axis=-1).sum(), out

    raw_sweep = np.linalg.norm(np.diff(raw[:, toe][:, [0, 2]], axis=0), axis=-1).sum()
    planted, out = toe_speed(joints, torch.ones(1, t, 4, dtype=joints.dtype))
    swinging, _ = toe_speed(joints, torch.zeros(1, t, 4, dtype=joints.dtype))
    assert raw_sweep > 0.08 and planted < 0.25 * raw_sweep and swinging > 0.8 * raw_sweep, (raw_sweep, planted, swinging)
    np.testing.assert_allclose(np.linalg.norm(out[:, toe] - out[:, ankle], axis=-1), HUMANML3D.bone_lengths[toe], rtol=1e-9)


def test_a_kit_foot_turns_as_one_piece_about_its_ankle():
    """KIT's foot is two bones past the ankle (ankle -> foot -> toe, the contact joints): a planted
    foot generated turning keeps its toe near its anchor, and both foot bones keep the body's length."""
    pose = np.zeros((21, 3))
    for chain in KIT.kinematic_chains:
        for p, c in zip(chain[:-1], chain[1:]):
            pose[c] = pose[p] + KIT.target_offsets[c]
    pose[:, 1] -= pose[:, 1].min()
    t = 40
    raw = np.repeat(pose[None], t, axis=0)
    ankle, (foot, toe) = KIT.legs["left"][2], KIT.feet_left
    yaw = np.radians(np.linspace(0.0, 40.0, t))
    for j in (foot, toe):  # the left foot swept about its ankle
        rel = pose[j] - pose[ankle]
        raw[:, j, 0] = pose[ankle, 0] + np.cos(yaw) * rel[0] + np.sin(yaw) * rel[2]
        raw[:, j, 2] = pose[ankle, 2] - np.sin(yaw) * rel[0] + np.cos(yaw) * rel[2]
    out = Finish.from_config({}, KIT, 12.5).joints(torch.from_numpy(raw)[None], [t],
                                                    contacts=torch.ones(1, t, 4, dtype=torch.float64))[0].numpy()
    sweep = lambda j: np.linalg.norm(np.diff(j[:, toe][:, [0, 2]], axis=0), axis=-1).sum()  # noqa: E731
    assert sweep(raw) > 50.0 and sweep(out) < 0.25 * sweep(raw), (sweep(raw), sweep(out))
    lengths = bone_lengths_of(torch.from_numpy(out), KIT).numpy()
    np.testing.assert_allclose(lengths[:, 1:], np.broadcast_to(KIT.bone_lengths[1:], lengths[:, 1:].shape), rtol=1e-9)


def test_a_wave_on_short_arms_keeps_its_swing():
    """A denoiser's arms come out short (the demo student's forearms ~4 cm short) and its wrists
    swing less than the arm's angles carry them. The finishing step keeps each untargeted arm's
    generated angles at the body's lengths, so a wave keeps its side-to-side swing, scaled up with
    the arm, instead of being pulled in towards the short arm's wrist (which a half-way hold on the
    generated wrist did: the student's waves fell below the behaviour suite's 3-cm swing)."""
    from stablemo.eval.behaviour import measures

    clip = synth("wave")
    t = len(clip)
    short = clip.copy()
    for shoulder, elbow, wrist in HUMANML3D.ik_limbs[2:]:
        short[:, elbow] = clip[:, shoulder] + 0.8 * (clip[:, elbow] - clip[:, shoulder])
        short[:, wrist] = short[:, elbow] + 0.8 * (clip[:, wrist] - clip[:, elbow])
    out = Finish.from_config({}, HUMANML3D, 20.0).joints(torch.from_numpy(short)[None], [t])[0].numpy()
    for shoulder, elbow, wrist in HUMANML3D.ik_limbs[2:]:
        for a, b in ((shoulder, elbow), (elbow, wrist)):  # each arm bone along its generated direction
            got, want = out[:, b] - out[:, a], short[:, b] - short[:, a]
            cos = np.einsum("ti,ti->t", got, want) / np.linalg.norm(got, axis=-1) / np.linalg.norm(want, axis=-1)
            assert cos.min() > 1 - 1e-9
    waves = {side: (measures.wave_spans(clip, side, 20.0), measures.wave_spans(out, side, 20.0)) for side in measures.SIDES}
    assert any(spans for spans, _ in waves.values())  # the clip waves
    for side, (truth, finished) in waves.items():
        assert len(finished) == len(truth), (side, waves)


def test_rows_of_a_motion_own_joints_give_its_features_back():
    """Finish.rows (the step's second half, which scripts/results/finish_fid_parts.py calls alone):
    handed a motion's own joints it gives its features back, every column, and the same joints; on
    rubber joints the root's columns stay the network's and the rest follow the joints."""
    finish = Finish.from_config({}, "humanml3d", 20.0)
    clips = [synth(a)[:41] for a in ("walk", "turn")]  # 40 feature rows each
    assert all(len(c) == 41 for c in clips)
    feats, lengths = make_features(clips)
    joints = features_to_joints(feats)
    out_f, out_j = finish.rows(feats, joints.permute(2, 3, 0, 1).contiguous(), lengths)
    # the last row's velocities and contacts look one frame ahead, past the motion: the step moves
    # the last pose on by the last root step there
    torch.testing.assert_close(out_f[:, :-1], feats[:, :-1], rtol=0, atol=1e-4)
    ahead = feature_slices("humanml3d")["local_vel"].start
    torch.testing.assert_close(out_f[:, -1, :ahead], feats[:, -1, :ahead], rtol=0, atol=1e-4)
    torch.testing.assert_close(out_j, joints, rtol=0, atol=1e-4)
    rubber = torch.from_numpy(np.stack([stretch(c)[:40] for c in clips])).float()
    moved_f, moved_j = finish.rows(feats, rubber.permute(2, 3, 0, 1).contiguous(), lengths)
    assert torch.equal(moved_f[..., :3], feats[..., :3])  # the network's root rotation and path
    assert (moved_f[..., 3:] - feats[..., 3:]).abs().max() > 0.05
    torch.testing.assert_close(moved_j[:, :, 1:] - moved_j[:, :, :1], rubber[:, :, 1:] - rubber[:, :, :1],
                               rtol=0, atol=1e-4)  # the body as handed over, about the root
