"""Editing and joint control at sampling time: in-painting in every sampler, joint guidance, specs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from stablemo.control import Inpaint, JointControl
from stablemo.control.guidance import JointGuidance, project_root
from stablemo.diffusion.hooks import StepState
from stablemo.diffusion.inpainting import Inpainting
from stablemo.diffusion.samplers import SAMPLER_TABLE
from stablemo.diffusion.schedule import NoiseSchedule
from stablemo.errors import StableMoError
from stablemo.inference.bundle import save_bundle
from stablemo.inference.pipeline import Pipeline
from stablemo.motion import features_to_joints

DEMO = Path(__file__).resolve().parents[1] / "stablemo" / "assets" / "demo_bundle"
D, J = 263, 22


@pytest.fixture(scope="module")
def demo():
    return Pipeline.from_bundle(DEMO)


@pytest.fixture(scope="module")
def students(tmp_path_factory):
    """LCM and PCM students initialised from the demo teacher (untrained: the contract, not quality)."""
    from stablemo.training.distill_module import ConsistencyDistillation

    out = {}
    for mode in ("lcm", "pcm"):
        module = ConsistencyDistillation(teacher=str(DEMO), mode=mode, ddim_steps=50, phases=4)
        config, state = module.bundle()
        out[mode] = Pipeline.from_bundle(save_bundle(tmp_path_factory.mktemp("s") / mode, config, state))
    return out


def _source(pipe, length=60, seed=7, text="a person jumps forward twice"):
    return pipe.generate([text], length, seed=seed).feature_list()[0]


# ---------------------------------------------------------------------------------- in-painting


def test_inpainting_imposes_the_level_and_the_values():
    values, noise = torch.randn(2, 5, 3), torch.randn(2, 5, 3)
    mask = torch.rand(2, 5, 3) > 0.5
    inp = Inpainting(values, mask, noise)
    x = torch.randn(2, 5, 3)
    noisy = inp.noisy(x, 0.6, 0.8)
    assert torch.equal(noisy[~mask], x[~mask])
    assert torch.allclose(noisy[mask], 0.6 * values[mask] + 0.8 * noise[mask])
    assert torch.equal(inp.clean(x)[mask], values[mask]) and torch.equal(inp.clean(x)[~mask], x[~mask])


@pytest.mark.parametrize("sampler", sorted(SAMPLER_TABLE))
def test_every_sampler_keeps_the_known_part_exactly(sampler):
    """A toy denoiser whose x0 ignores the known values: the sampler still returns them exactly."""
    torch.manual_seed(0)
    schedule = NoiseSchedule()
    values = torch.randn(2, 12, 4)
    mask = torch.zeros(2, 12, 4, dtype=torch.bool)
    mask[0, :4] = True  # a prefix
    mask[1, :, :2] = True  # a channel group
    x_T = torch.randn(2, 12, 4)
    seen = []

    def denoise(x, t):
        seen.append(x.clone())
        return torch.tanh(x) * 0.3  # an x0 guess unrelated to the known values

    out = SAMPLER_TABLE[sampler].run(denoise, x_T, schedule, 5, generator=torch.Generator().manual_seed(0),
                                     inpaint=Inpainting(values, mask, x_T))
    assert (out[mask] - values[mask]).abs().max() <= 1e-6
    # the network saw the known part noised: at the first (noisiest) state the known entries are
    # alpha * values + sigma * x_T with alpha small, so close to x_T and far from the values
    assert (seen[0][mask] - x_T[mask]).abs().max() < 0.3 < (seen[0][mask] - values[mask]).abs().max()
    free = SAMPLER_TABLE[sampler].run(denoise, x_T, schedule, 5, generator=torch.Generator().manual_seed(0))
    assert not torch.allclose(free[mask], values[mask], atol=1e-2)


@pytest.mark.parametrize("sampler", ["ddpm", "ddim", "dpmpp_2m", "dpmpp_2m_sde"])
def test_teacher_prefix_completion_is_exact_in_feature_space(demo, sampler):
    src = _source(demo)
    keep = np.zeros(60, bool)
    keep[:20] = True
    steps = 20 if sampler == "ddpm" else 10
    result = demo.generate(["a person walks forward"], 60, seed=1, sampler=sampler, steps=steps,
                           inpaint=Inpaint(src, keep))
    out = result.raw_features[0].numpy()  # the sampler's output, before the finishing step
    assert np.abs(out[:20] - src[:20]).max() <= 1e-5
    assert np.isfinite(out).all() and np.abs(out[20:] - src[20:]).max() > 1e-2
    # what the user receives: the known frames are the same body in the same place (the finishing
    # step re-derives velocities and contacts at the hand-over row, and the pelvis shape and floor
    # from the whole new motion: positions within 2 cm, most within millimetres)
    src_joints = features_to_joints(torch.from_numpy(src[:20]).double()).numpy()
    diff = np.abs(result.joint_list()[0][:19] - src_joints[:19])
    assert diff.max() < 0.02 and np.median(diff) < 0.002


@pytest.mark.parametrize("mode,steps", [("lcm", 1), ("lcm", 2), ("lcm", 4), ("pcm", 1), ("pcm", 2), ("pcm", 4)])
def test_students_keep_the_known_part_exactly(demo, students, mode, steps):
    src = _source(demo)
    mask = np.zeros((60, D), bool)
    mask[40:] = True  # a suffix
    mask[:, :4] = True  # and the root everywhere
    out = students[mode].generate(["a person walks forward"], 60, seed=3, steps=steps,
                                  inpaint=Inpaint(src, mask)).raw_features[0].numpy()  # before finishing
    assert np.abs(out[mask] - src[mask]).max() <= 1e-5


def test_inpainting_is_batch_invariant_with_different_specs_and_lengths(demo):
    src = _source(demo, 80)
    a = np.zeros(80, bool)
    a[:30] = True
    b = np.zeros((60, D), bool)
    b[:, :4] = True
    texts, lengths = ["a person walks forward", "a person waves", "a person kicks"], [80, 60, 44]
    specs = [Inpaint(src, a), Inpaint(src[:60], b), None]
    batched = demo.generate(texts, lengths, seed=[1, 2, 3], inpaint=specs)
    for i in range(3):
        single = demo.generate([texts[i]], [lengths[i]], seed=[i + 1], inpaint=[specs[i]])
        np.testing.assert_allclose(batched.feature_list()[i], single.feature_list()[0], atol=1e-4)


def test_inpainting_changes_nothing_where_nothing_is_known(demo):
    """A request without in-painting and the same request with `inpaint=None` are identical."""
    a = demo.generate(["a person walks forward"], 40, seed=4)
    b = demo.generate(["a person walks forward"], 40, seed=4, inpaint=[None])
    assert torch.equal(a.features, b.features)


# ---------------------------------------------------------------------------------- joint control


def test_root_projection_passes_through_sparse_targets_in_the_motions_heading():
    torch.manual_seed(0)
    feats = torch.randn(2, 30, D) * 0.05
    feats[..., 0] = 0.05  # turning
    targets = torch.randn(2, 30, 3)
    mask = torch.zeros(2, 30, dtype=torch.bool)
    mask[0, [5, 17, 29]] = True
    mask[1] = True
    mask[1, 0] = False  # frame 0 is the origin anyway
    out = project_root(feats, targets, mask, torch.tensor([30, 30]))
    root = features_to_joints(out)[..., 0, :]
    assert (root[mask] - targets[mask]).abs().max() < 1e-4
    # heading and the pose are untouched
    assert torch.equal(out[..., 0], feats[..., 0]) and torch.equal(out[..., 4:], feats[..., 4:])


@pytest.mark.parametrize("skeleton,wrist,scale", [("humanml3d", 20, 1.0), ("kit", 10, 1000.0)])
def test_guidance_lowers_the_error_on_a_toy_problem(skeleton, wrist, scale):
    """Targets for a wrist on 5 frames of a random motion: one guided x0 edit reaches them (KIT: mm)."""
    from stablemo.motion.skeleton import get_skeleton

    skel = get_skeleton(skeleton)
    torch.manual_seed(1)
    mean, std = torch.zeros(skel.feature_dim), torch.ones(skel.feature_dim) * 0.1 * scale
    x0 = torch.randn(1, 40, skel.feature_dim)
    joints = features_to_joints(x0 * std + mean, skel)
    targets = joints + torch.tensor([0.2, -0.1, 0.3]) * scale
    mask = torch.zeros(1, 40, skel.num_joints, dtype=torch.bool)
    mask[0, ::8, wrist] = True
    hook = JointGuidance(targets, mask, mean, std, skel, final_iters=60)
    state = StepState(9, 10, 0, x0, torch.ones(1, 40, dtype=torch.bool), [40])
    out = features_to_joints(hook(state) * std + mean, skel)
    before = (joints - targets)[mask].norm(dim=-1).mean()
    after = (out - targets)[mask].norm(dim=-1).mean()
    assert after < 0.01 * before


def test_a_far_wrist_target_moves_the_body_within_the_arms_reach():
    """A wrist target 0.9 m in front of a body (the benchmark's targets sit that far from a generated
    body): the pose step moves only the wrist, so the root must come close enough for the rigid arm
    of the finishing step to reach it (guidance.REACH_SHARE of the arm from the shoulder)."""
    from stablemo.control.guidance import REACH_SHARE
    from stablemo.motion.skeleton import get_skeleton

    skel = get_skeleton("humanml3d")
    from stablemo.data.synth import actions
    from stablemo.data.synth.compose import build
    from stablemo.motion import joints_to_features

    params = actions.sample_params("walk", np.random.default_rng(0))
    clip = joints_to_features(build([("walk", params)]).joints, "humanml3d")[:40]
    mean, std = torch.zeros(skel.feature_dim), torch.ones(skel.feature_dim)
    x0 = torch.from_numpy(clip).float()[None]
    joints = features_to_joints(x0, skel)
    targets = joints.clone()
    left = 20  # the left wrist
    targets[0, 20:, left] = joints[0, 20:, 0] + torch.tensor([0.0, 0.1, 0.9])  # 0.9 m ahead of the pelvis
    mask = torch.zeros(1, 40, skel.num_joints, dtype=torch.bool)
    mask[0, 20:, left] = True
    hook = JointGuidance(targets, mask, mean, std, skel, follow=0.5)
    out = features_to_joints(hook(StepState(9, 10, 0, x0, torch.ones(1, 40, dtype=torch.bool), [40])), skel)
    arm = float(skel.bone_lengths[18] + skel.bone_lengths[left])
    reach = (targets[0, 20:, left] - out[0, 20:, 16]).norm(dim=-1)  # from the left shoulder
    before = (targets[0, 20:, left] - joints[0, 20:, 16]).norm(dim=-1)
    assert before.min() > arm  # out of reach as generated
    assert reach.max() < REACH_SHARE * arm + 0.05, reach.max()
    assert (out[0, 20:, left] - targets[0, 20:, left]).norm(dim=-1).max() < 0.02  # and met (the step is smoothed over time)


def _control_from(joints: np.ndarray, frames, joint_ids) -> JointControl:
    mask = np.zeros(joints.shape[:2], bool)
    mask[np.ix_(np.asarray(frames), np.asarray(joint_ids))] = True
    return JointControl(joints, mask)


def test_control_reaches_the_targets_and_is_batch_invariant(demo):
    src = demo.generate(["a person walks in a circle counterclockwise", "a person jumps forward twice"], 80, seed=9)
    j0, j1 = src.joint_list()
    specs = [_control_from(j0, range(80), [0]), _control_from(j1, [0, 30, 60, 79], range(J)), None]
    texts, lengths = ["a person walks forward", "a person walks forward", "a person waves"], [80, 80, 48]
    batched = demo.generate(texts, lengths, seed=[1, 2, 3], control=specs)
    for i, (spec, src_joints) in enumerate(zip(specs[:2], (j0, j1))):
        got = batched.joint_list()[i]
        err = np.linalg.norm(got - src_joints, axis=-1)[np.asarray(spec.mask)]
        assert err.mean() < 0.03, (i, err.mean())
    for i in range(3):
        single = demo.generate([texts[i]], [lengths[i]], seed=[i + 1], control=[specs[i]])
        np.testing.assert_allclose(batched.feature_list()[i], single.feature_list()[0], atol=1e-4)


def test_control_and_footskate_in_one_request(demo):
    from stablemo.inference.hooks import make_hooks

    src = demo.generate(["a person walks in a circle counterclockwise"], 80, seed=9).joint_list()[0]
    spec = _control_from(src, range(80), [0])
    out = demo.generate(["a person walks forward"], 80, seed=1, control=spec, hooks=make_hooks(demo, footskate=True))
    err = np.linalg.norm(out.joint_list()[0][:, 0] - src[:, 0], axis=-1)
    assert err.mean() < 0.03 and np.isfinite(out.features).all()


# ---------------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("case,message", [
    ("late", "frame 60"),
    ("nan", "NaN"),
    ("joints", "21"),
    ("empty", "all False"),
    ("start", "origin"),
])
def test_bad_joint_control_is_one_clear_error(demo, case, message):
    pos = np.zeros((80, J, 3), np.float32)
    mask = np.zeros((80, J), bool)
    mask[10, 20] = True
    if case == "late":
        mask[60, 0] = True
    elif case == "nan":
        pos[10, 20] = np.nan
    elif case == "joints":
        pos, mask = pos[:, :21], mask[:, :21]
    elif case == "empty":
        mask[:] = False
    elif case == "start":
        mask[0, 0] = True
        pos[0, 0] = (0.5, 0.9, 0.0)
    with pytest.raises(StableMoError, match=message):
        demo.generate(["a person walks"], 60, control=JointControl(pos, mask))


def test_bad_inpaint_is_one_clear_error(demo):
    feats = np.zeros((60, D), np.float32)
    with pytest.raises(StableMoError, match="shape"):
        demo.generate(["a person walks"], 60, inpaint=Inpaint(feats[:, :100], np.ones(60, bool)))
    with pytest.raises(StableMoError, match="all False"):
        demo.generate(["a person walks"], 60, inpaint=Inpaint(feats, np.zeros(60, bool)))
    with pytest.raises(StableMoError, match="frame 40"):
        demo.generate(["a person walks"], 40, inpaint=Inpaint(np.zeros((60, D)), np.ones(60, bool)))
    bad = feats.copy()
    bad[3, 5] = np.nan
    with pytest.raises(StableMoError, match="NaN"):
        demo.generate(["a person walks"], 60, inpaint=Inpaint(bad, np.ones(60, bool)))
    with pytest.raises(StableMoError, match="2 entries for 1 prompts"):
        demo.generate(["a person walks"], 60, inpaint=[None, None])


def test_smooth_offsets_are_exact_at_anchors_and_have_no_kink():
    from stablemo.control.guidance import smooth_offsets

    T = 50
    anchors = torch.zeros(1, T, dtype=torch.bool)
    anchors[0, [0, 12, 30, 41]] = True
    delta = torch.zeros(1, T, 2)
    delta[0, [0, 12, 30, 41]] = torch.tensor([[0.0, 0.0], [1.0, -0.5], [0.2, 0.8], [-0.4, 0.1]])
    out = smooth_offsets(delta, anchors)
    assert torch.allclose(out[anchors], delta[anchors], atol=1e-6)
    assert torch.allclose(out[0, 41:], delta[0, 41].expand(T - 41, 2))  # held after the last anchor
    vel = out[0, 1:] - out[0, :-1]
    # C1: the velocity changes gradually; straight lines between the anchors would jump by 0.13 at frame 12
    jumps = (vel[1:] - vel[:-1]).norm(dim=-1)
    assert jumps.max() < 0.04
