"""footskate: vGRF network layout and loaders, contacts, force labels, batched cleanup."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import torch

from footskate import HUMANML3D, CleanupConfig, FootskateError, VGRFNet, anchor_drift
from footskate.cleanup import cleanup, contact_ranges, detect_contacts, leg_joints
from footskate.contacts import (
    contacts_from_forces,
    contacts_from_heights,
    majority_filter,
)
from footskate.forces import forces_from_contacts
from footskate.vgrf import ATTRIBUTION, load_underpressure, load_vgrf, save_vgrf

SAMPLE = Path(__file__).parents[2] / "shared/data/humanml3d-sample"
PARENTS, FEET = list(HUMANML3D.parents), list(HUMANML3D.feet)
# HumanML3D target bone lengths (parent -> k) and a standing pose built from them.
BONES = [0, .1031, .1099, .1316, .3936, .3902, .1432, .4324, .4256, .0574, .1434, .1494, .2194, .1375,
         .1434, .1030, .1316, .1230, .2568, .2631, .2660, .2699]
DIRS = {1: (1, 0, 0), 13: (1, 0, 0), 2: (-1, 0, 0), 14: (-1, 0, 0), 3: (0, 1, 0), 6: (0, 1, 0), 9: (0, 1, 0),
        12: (0, 1, 0), 10: (0, -.05, 1), 11: (0, -.05, 1), 15: (0, 0, 1), 4: (0, -1, .3), 5: (0, -1, .3),
        7: (0, -1, -.3), 8: (0, -1, -.3)}


def standing_pose() -> torch.Tensor:
    p = torch.zeros(22, 3)
    for j in range(1, 22):
        d = torch.tensor(DIRS.get(j, (0, -1, 0)), dtype=torch.float32)
        p[j] = p[PARENTS[j]] + BONES[j] * d / d.norm()
    p[:, 1] -= p[[10, 11], 1].min()  # toes on the floor (y = 0: where the training data plants them)
    return p


def bone_lengths(x: torch.Tensor) -> torch.Tensor:
    return (x[..., 1:, :] - x[..., PARENTS[1:], :]).norm(dim=-1)


def drifting_planted_foot(frames: int = 41) -> tuple[torch.Tensor, torch.Tensor]:
    """Body translating 1 cm/frame while the left foot is labelled planted the whole time."""
    x = standing_pose().expand(frames, 22, 3).clone()
    x[:, :, 2] += 0.01 * torch.arange(frames)[:, None]
    contacts = torch.zeros(frames, 4, dtype=torch.bool)
    contacts[:, :2] = True
    return x, contacts


def gmd_skating_ratio(joints: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
    try:
        from stablemo.skating.metrics import foot_skating_ratio
        return torch.as_tensor(foot_skating_ratio(joints, lengths=lengths))
    except ImportError:  # GMD's definition (Karunratanakul et al. 2023), for a checkout without the eval package
        feet = joints[:, :, [10, 11]].double()
        v = 20 * (feet[:, 1:, :, [0, 2]] - feet[:, :-1, :, [0, 2]]).norm(dim=-1)
        valid = (torch.arange(joints.shape[1] - 1)[None] < (lengths - 1)[:, None])
        v = v * valid[..., None]
        vbar = torch.nn.functional.conv1d(v.transpose(1, 2).reshape(-1, 1, v.shape[1]),
                                          torch.full((1, 1, 5), 0.2, dtype=v.dtype), padding=2)
        vbar = vbar.reshape(v.shape[0], 2, -1).transpose(1, 2)
        h = feet[..., 1]
        skate = ((h[:, :-1] < 0.05) & (h[:, 1:] < 0.05) & (v > 0.5) & (vbar > 0.5)).any(-1) & valid
        return skate.sum(1) / valid.sum(1)


# --- vGRF network ---------------------------------------------------------------------------

def test_v23_layout_matches_underpressure_keys():
    model = VGRFNet(23)
    state = model.state_dict_up()
    shapes = {k: tuple(v.shape) for k, v in state.items()}
    assert shapes == {
        "3.weight": (128, 69, 7), "3.bias": (128,), "6.weight": (128, 128, 7), "6.bias": (128,),
        "9.weight": (256, 128, 7), "9.bias": (256,), "12.weight": (256, 256, 7), "12.bias": (256,),
        "16.weight": (256, 256), "16.bias": (256,), "19.weight": (256, 256), "19.bias": (256,),
        "22.weight": (32, 256)}
    assert sum(v.numel() for v in state.values()) == 1_005_184
    assert model.receptive_field == 25
    out = model.eval()(torch.randn(2, 30, 23, 3))
    assert out.shape == (2, 30, 2, 16) and (out >= 0).all()
    assert VGRFNet(22).state_dict_up()["3.weight"].shape == (128, 66, 7)
    assert VGRFNet(21).state_dict_up()["3.weight"].shape == (128, 63, 7)


def test_underpressure_style_checkpoint_loads_weights_only(tmp_path, capsys):
    torch.manual_seed(0)
    ref = VGRFNet(23).eval()
    path = tmp_path / "pretrained.tar"
    torch.save({"model": ref.state_dict_up()}, path)
    model = load_underpressure(path)
    assert "UnderPressure is an InterDigital product" in capsys.readouterr().out
    x = torch.randn(1, 40, 23, 3)
    torch.testing.assert_close(model(x), ref(x))
    bad = tmp_path / "bad.tar"
    torch.save({"model": {"3.weight": torch.zeros(128, 70, 7)}}, bad)
    with pytest.raises(FootskateError, match="bad.tar"):
        load_underpressure(bad)
    with pytest.raises(FootskateError, match="not found"):
        load_underpressure(tmp_path / "missing.tar")


@pytest.mark.skipif(not os.environ.get("UNDERPRESSURE_WEIGHTS"), reason="set UNDERPRESSURE_WEIGHTS=/path/pretrained.tar")
def test_user_supplied_underpressure_weights(capsys):
    model = load_underpressure(os.environ["UNDERPRESSURE_WEIGHTS"])
    assert ATTRIBUTION in capsys.readouterr().out
    assert model.num_joints == 23
    standing = torch.zeros(1, 100, 23, 3)
    standing[..., 2] = torch.linspace(1.5, 0.0, 23)  # z-up column of joints: feet on the floor
    forces = model(standing)
    assert torch.isfinite(forces).all()


def test_safetensors_roundtrip_and_padding_invariance(tmp_path):
    torch.manual_seed(1)
    model = VGRFNet(22, conv_channels=(16, 16, 32, 32), hidden=32).eval()
    save_vgrf(model, tmp_path / "v.safetensors", {"steps": 3})
    loaded = load_vgrf(tmp_path / "v.safetensors")
    assert loaded.metadata["steps"] == 3
    x = torch.randn(3, 50, 22, 3)
    lengths = torch.tensor([50, 31, 12])
    batched = loaded(x, lengths)
    for b, n in enumerate(lengths.tolist()):
        alone = model(x[b:b + 1, :n])
        torch.testing.assert_close(batched[b:b + 1, :n], alone, rtol=1e-5, atol=1e-6)


def test_shipped_weights_load():
    path = Path(__file__).parents[1] / "footskate/weights/v22_synth.safetensors"
    if not path.is_file():
        pytest.skip("shipped V22 weights not built yet")
    model = load_vgrf(path)
    assert model.num_joints == 22 and "metrics" in model.metadata


# --- contacts ---------------------------------------------------------------------------------

def _forces(front: torch.Tensor, back: torch.Tensor) -> torch.Tensor:
    """front/back (F, 2) body weights -> (F, 2, 16) spread over the front and back cells."""
    f = torch.zeros(front.shape[0], 2, 16)
    f[..., 8:16] = (front / 8)[..., None]
    f[..., 0:4] = (back / 4)[..., None]
    return f


def test_contacts_from_constructed_force_curves():
    frames = 300  # 3 s at 100 Hz
    front, back = torch.zeros(frames, 2), torch.zeros(frames, 2)
    back[50:150, 0] = 0.6                    # left heel loaded for 1 s
    front[100:200, 0] = 0.6                  # then the left ball
    front[120, 1] = 0.8                      # a 10 ms blip on the right foot: filtered out
    front[250:300, 1] = 0.04                 # right foot below the 0.10 foot threshold
    c = contacts_from_forces(_forces(front, back), fps=100)   # (F, 4) [L_heel, L_toe, R_heel, R_toe]
    heel, toe = c[:, 0], c[:, 1]
    assert heel[60:140].all() and not heel[:45].any() and not heel[155:].any()
    assert toe[105:195].all() and not toe[:95].any() and not toe[205:].any()
    assert not c[:, 2:].any()
    # Parts are rescaled by total/(front+back): mid-foot cells (4-7) load the part that carries weight.
    f = torch.zeros(frames, 2, 16)
    f[:, 0, 4:8] = 0.5 / 4
    f[:, 0, 8:16] = 0.1 / 8
    c = contacts_from_forces(f, fps=100)
    assert c[:, 1].all() and not c[:, 0].any()


def test_contact_windows_rescale_with_frame_rate():
    # The same 0.6 s load sampled at 100 Hz and at 20 Hz gives the same contact interval.
    t100, t20 = torch.arange(300) / 100, torch.arange(60) / 20
    load = lambda t: torch.where((t >= 1.0) & (t < 1.6), 0.7, 0.0)[:, None].expand(-1, 2).clone()
    c100 = contacts_from_forces(_forces(load(t100), load(t100)), fps=100)[:, 1]
    c20 = contacts_from_forces(_forces(load(t20), load(t20)), fps=20)[:, 1]
    assert abs(c100.float().sum() / 100 - c20.float().sum() / 20) < 0.1
    assert abs(t100[c100].mean() - t20[c20].mean()) < 0.06


def test_majority_filter_batched_equals_per_sample():
    g = torch.Generator().manual_seed(0)
    c = torch.rand(4, 60, 3, generator=g) > 0.5
    lengths = torch.tensor([60, 45, 20, 7])
    batched = majority_filter(c, 5, lengths)
    for b, n in enumerate(lengths.tolist()):
        assert torch.equal(batched[b, :n], majority_filter(c[b:b + 1, :n], 5)[0])


def test_height_speed_heuristic():
    x, _ = drifting_planted_foot()
    feet = x[None, :, FEET]
    c = contacts_from_heights(feet, fps=20)[0]     # moving at 0.2 m/s, low: contact
    assert c.all()
    fast = x.clone()
    fast[:, :, 2] *= 10                              # 2 m/s: not a contact
    assert not contacts_from_heights(fast[None, :, FEET], fps=20).any()


def test_force_labels_give_back_their_contacts():
    x, _ = drifting_planted_foot(60)
    contacts = torch.zeros(60, 4, dtype=torch.bool)
    contacts[:40, 0:2] = True                        # left foot flat, then lifts
    contacts[20:, 2:4] = True                        # right foot lands at 1 s
    forces = forces_from_contacts(x[None], contacts[None], FEET, fps=20)[0]
    assert torch.allclose(forces.sum((-1, -2)), torch.ones(60), atol=1e-4)  # static body: weight 1
    assert (forces[40:, 0] == 0).all() and (forces[:20, 1] == 0).all()
    recovered = contacts_from_forces(forces, fps=20)
    assert (recovered == contacts).float().mean() > 0.95


# --- cleanup ----------------------------------------------------------------------------------

def test_contact_ranges_match_python_reference():
    g = torch.Generator().manual_seed(3)
    c = torch.rand(3, 40, 4, generator=g) > 0.4
    pos = torch.randn(3, 40, 4, 3, generator=g)
    _, w_strict, strict = contact_ranges(c, pos, up_axis=1, ramp_frames=1, min_range=3, max_offset=0.25)
    assert strict["rejected_ranges"] > 0           # joints wandering ~1 m are not planted feet
    targets, weights, info = contact_ranges(c, pos, up_axis=1, ramp_frames=1, min_range=3, max_offset=float("inf"))
    count = 0
    for b in range(3):
        for k in range(4):
            t = 0
            while t < 40:
                if not c[b, t, k]:
                    t += 1
                    continue
                s = t
                while t < 40 and c[b, t, k]:
                    t += 1
                count += 1
                mid = s + (t - s - 1) // 2
                exp = pos[b, mid, k].clone()
                # the height that stands the foot on the floor (its lowest joint at y = 0): the
                # joint's mean height above its foot's lowest joint on the range's flat frames
                # (the same side's ankle and toe both down), else its lowest height moved with
                # the foot's lowest joint over the range
                y, other = pos[b, s:t, k, 1], pos[b, s:t, k ^ 1, 1]
                sole = torch.minimum(y, other)
                flat = c[b, s:t, k ^ 1]
                exp[1] = (y - sole)[flat].mean() if flat.any() else y.min() - sole.min()
                torch.testing.assert_close(targets[b, s:t, k], exp.expand(t - s, 3))
                if t - s < 3:
                    assert (weights[b, s:t, k] == 0).all()
                else:
                    assert weights[b, s, k] == 0.5 and weights[b, t - 1, k] == 0.5
                    assert (weights[b, s + 1:t - 1, k] == 1).all()
    assert info["ranges"] == count
    assert strict["anchored_ranges"] + strict["rejected_ranges"] == info["anchored_ranges"]
    assert ((w_strict == 0) | (w_strict == weights)).all() and (w_strict > 0).sum() < (weights > 0).sum()
    assert torch.isnan(targets[~c]).all() and (weights[~c] == 0).all()


def test_planted_foot_drifting_is_anchored():
    x, contacts = drifting_planted_foot()
    res = cleanup(x[None], PARENTS, FEET, contacts=contacts[None])
    out = res.joints[0]
    drift = anchor_drift(res.joints, res, FEET)[0, :, :2]
    assert drift.max() < 0.005                                  # was up to 20 cm
    before = anchor_drift(x[None], res, FEET)[0, :, :2]
    assert before.max() > 0.19
    torch.testing.assert_close(bone_lengths(out), bone_lengths(x), atol=1e-5, rtol=0)
    root_vel, root_vel0 = out[1:, 0] - out[:-1, 0], x[1:, 0] - x[:-1, 0]
    # the pelvis may dip a little to reach (4.1 mm/frame at most; 3.9 before the floor held the
    # stretched leg's toe at y >= 0 instead of letting it sink)
    assert (root_vel - root_vel0).norm(dim=-1).max() < 0.0045
    assert (root_vel - root_vel0)[:, [0, 2]].norm(dim=-1).max() < 0.0015  # heading speed kept (1 cm/frame)
    others = [j for j in range(22) if j not in leg_joints(PARENTS, FEET)]
    assert (out[:, others] - x[:, others]).norm(dim=-1).mean() < 0.02
    # every frame: the root and the upper body move by at most max_root_shift (2.5 cm), the legs take up the rest
    assert (out[:, others] - x[:, others]).norm(dim=-1).max() < 0.0251


def test_clean_motion_is_left_alone_and_cleanup_is_idempotent():
    x = standing_pose()
    x[[2, 5, 8, 11], 1] -= x[11, 1]  # both feet on the floor (the fixture's right leg is 1 cm shorter)
    x = x.expand(30, 22, 3).clone()
    contacts = torch.ones(30, 4, dtype=torch.bool)
    res = cleanup(x[None], PARENTS, FEET, contacts=contacts[None])
    torch.testing.assert_close(res.joints[0], x, atol=1e-6, rtol=0)
    moving, contacts = drifting_planted_foot()
    once = cleanup(moving[None], PARENTS, FEET, contacts=contacts[None]).joints
    twice = cleanup(once, PARENTS, FEET, contacts=contacts[None]).joints
    change = (twice - once).norm(dim=-1)
    # a second pass only polishes the residual: mean 1.3 mm, max 10.2 mm (the knee at the last
    # frame). The foot here is held for 41 frames while the body travels 40 cm, more than the legs
    # can take up; each pass may move the root by at most max_root_shift (2.5 cm) from its own
    # input, so the second pass takes up a little more (unbounded root: 1.3 / 4.1 mm)
    assert change.mean() < 0.002 and change.max() < 0.012
    root_moved = (once[0, :, 0] - moving[:, 0]).norm(dim=-1)
    assert root_moved.max() <= CleanupConfig().max_root_shift + 1e-6


def test_batched_equals_per_sample_with_different_lengths():
    g = torch.Generator().manual_seed(0)
    base, _ = drifting_planted_foot(48)
    lengths = torch.tensor([48, 33, 20])
    batch = base.expand(3, 48, 22, 3).clone()
    batch[..., [0, 2]] += 0.02 * torch.randn(3, 48, 1, 2, generator=g).cumsum(1)
    batch[1, 33:] = 123.0                                        # garbage in padding must not leak
    model = VGRFNet(22, conv_channels=(16, 16, 32, 32), hidden=32).eval()
    cfg = CleanupConfig(iters=30)
    res = cleanup(batch, PARENTS, FEET, lengths=lengths, vgrf=model, config=cfg)
    for b, n in enumerate(lengths.tolist()):
        alone = cleanup(batch[b:b + 1, :n], PARENTS, FEET, vgrf=model, config=cfg)
        assert torch.equal(alone.contacts[0], res.contacts[b, :n])
        torch.testing.assert_close(res.joints[b, :n], alone.joints[0], atol=2e-5, rtol=0)
    assert torch.equal(res.joints[1, 33:], batch[1, 33:])


@pytest.mark.parametrize("kind", ["none", "all"])
def test_no_nan_without_or_with_only_contacts(kind):
    x, _ = drifting_planted_foot(25)
    contacts = torch.full((1, 25, 4), kind == "all")
    res = cleanup(x[None], PARENTS, FEET, contacts=contacts, vgrf=VGRFNet(22).eval(), config=CleanupConfig(iters=10))
    assert torch.isfinite(res.joints).all()
    if kind == "none":
        assert torch.equal(res.joints[0], x)


def test_bad_input_is_named():
    x, contacts = drifting_planted_foot(10)
    with pytest.raises(FootskateError, match="joints"):
        cleanup(x, PARENTS, FEET)
    bad = x.clone()
    bad[3, 4, 0] = float("nan")
    with pytest.raises(FootskateError, match="NaN"):
        cleanup(bad[None], PARENTS, FEET)
    with pytest.raises(FootskateError, match="lengths"):
        cleanup(x[None], PARENTS, FEET, lengths=torch.tensor([11]))


def _injected_sliding(clean: torch.Tensor, contacts: torch.Tensor, gen: torch.Generator, speed: float) -> torch.Tensor:
    """Feet slide under the body: during each contact the leg drifts (speed m/frame), relaxing in swing."""
    b_count, frames = clean.shape[:2]
    out = clean.clone()
    for side, (knee, ankle, toe) in enumerate(((4, 7, 10), (5, 8, 11))):
        planted = contacts[..., 2 * side:2 * side + 2].any(-1)
        angle = torch.rand(b_count, generator=gen) * 2 * torch.pi
        direction = torch.stack([torch.cos(angle), torch.sin(angle)], -1)
        offset = torch.zeros(b_count)
        for t in range(frames):  # test-data construction only
            offset = torch.where(planted[:, t], offset + speed, offset * 0.6)
            for joint, w in ((knee, 0.5), (ankle, 1.0), (toe, 1.0)):
                out[:, t, joint, [0, 2]] += w * offset[:, None] * direction
    return out


@pytest.mark.skipif(not (SAMPLE / "new_joints/012314.npy").is_file(), reason="HumanML3D sample not present")
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_skating_ratio_never_increases(seed):
    clip = torch.from_numpy(np.load(SAMPLE / "new_joints/012314.npy")).float()
    g = torch.Generator().manual_seed(seed)
    frames = clip.shape[0]
    lengths = torch.randint(80, frames + 1, (4,), generator=g)
    clean = clip.expand(4, frames, 22, 3).clone()
    contacts, _ = detect_contacts(clean, lengths, FEET, 20.0, 1)
    sliding = _injected_sliding(clean, contacts, g, speed=0.015)
    res = cleanup(sliding, PARENTS, FEET, lengths=lengths)
    # The cleanup also stands the motion on the floor (one vertical shift: this clip's planted toes
    # are ~1 cm up). GMD's 5 cm height gate counts more swing frames of a lower motion, so skating
    # is compared on the same floor, the input's.
    lift = torch.tensor(res.info["floor_offset"])                               # (4,) metres
    assert ((0.005 < lift) & (lift < 0.025)).all()
    unplaced = res.joints + lift[:, None, None, None] * torch.tensor([0.0, 1.0, 0.0])
    before, after = gmd_skating_ratio(sliding, lengths), gmd_skating_ratio(unplaced, lengths)
    assert (after <= before + 1e-9).all(), (before, after)
    assert after.mean() < 0.8 * before.mean()
    mask = torch.arange(frames)[None] < lengths[:, None]
    torch.testing.assert_close(bone_lengths(res.joints)[mask], bone_lengths(sliding)[mask], atol=1e-5, rtol=0)


# --- retargeting, distillation, command, StableMo glue -----------------------------------------

def test_retarget_to_underpressure_skeleton():
    from footskate.retarget import HML_TO_UP, UPAdapter, resample, to_up_skeleton

    x = standing_pose().expand(2, 12, 22, 3).clone()
    up = to_up_skeleton(x)
    assert up.shape == (2, 12, 23, 3)
    assert sorted(HML_TO_UP) == [i for i in range(23) if i != 4]
    assert torch.allclose(up[..., 4, :], 0.5 * (up[..., 3, :] + up[..., 5, :]))
    assert abs(up[0, 0, [18, 22], 2].min() - 0.015) < 1e-6          # z-up, lowest toe at UP's toe height
    assert 0.75 < up[0, 0, 0, 2] < 1.0                              # pelvis near UP's 0.93 m (knees bent)
    assert up[0, 0, 6, 2] > up[0, 0, 0, 2] > up[0, 0, 21, 2]        # head above pelvis above ankle
    # facing +z in HumanML3D (toes ahead of ankles) becomes -y in UP's frame
    assert (up[0, 0, 22, 1] - up[0, 0, 21, 1]) < -0.1
    fine, n = resample(x, 5)
    assert fine.shape[1] == 56 and int(n[0]) == 56
    torch.manual_seed(0)
    adapter = UPAdapter(VGRFNet(23).eval())
    walk = x.clone()
    walk[..., 2] += 0.02 * torch.arange(12)[:, None]
    lengths = torch.tensor([12, 7])
    forces = adapter(walk, lengths)
    assert forces.shape == (2, 12, 2, 16)
    torch.testing.assert_close(forces[1, :7], adapter(walk[1:, :7])[0], rtol=1e-4, atol=1e-6)


def test_distillation_command_with_a_stand_in_v23(tmp_path, capsys):
    from footskate.distill import main as retarget_main

    torch.manual_seed(0)
    v23 = tmp_path / "pretrained.tar"
    torch.save({"model": VGRFNet(23).state_dict_up()}, v23)   # random stand-in: UP's weights are never shipped
    data = tmp_path / "hml" / "new_joints"
    data.mkdir(parents=True)
    for i in range(3):
        x, _ = drifting_planted_foot(30 + 5 * i)
        np.save(data / f"{i:06d}.npy", x.numpy())
    out = tmp_path / "v22.safetensors"
    assert retarget_main(["distill", "--v23", str(v23), "--data", str(data.parent), "--out", str(out),
                          "--steps", "2", "--width", "half"]) == 0
    assert "InterDigital" in capsys.readouterr().out
    model = load_vgrf(out)
    assert model.num_joints == 22 and model.metadata["labels"] == "teacher"
    conv = tmp_path / "up.npy"
    assert retarget_main(["convert", str(data / "000000.npy"), "--out", str(conv)]) == 0
    assert np.load(conv).shape == ((30 - 1) * 5 + 1, 23, 3)


def test_footskate_command_on_joints(tmp_path):
    from footskate.command import main

    x, _ = drifting_planted_foot(40)
    x[:, :, 2] *= 0.3                                   # 3 mm/frame: a slow slide the heuristic calls contact
    src, dst = tmp_path / "in.npy", tmp_path / "out.npy"
    np.save(src, x.numpy())
    assert main([str(src), "--out", str(dst), "--contacts", "heuristic"]) == 0
    out = torch.from_numpy(np.load(dst))
    assert out.shape == x.shape
    speed = lambda j: (j[1:, FEET] - j[:-1, FEET])[..., [0, 2]].norm(dim=-1).mean()
    assert speed(out) < 0.3 * speed(x)
    with pytest.raises(FootskateError, match="needs StableMo"):
        np.save(src, np.zeros((10, 263), dtype=np.float32) + 1)
        main([str(src), "--out", str(dst), "--contacts", "heuristic"])


@pytest.mark.skipif(not (SAMPLE / "new_joint_vecs/012314.npy").is_file(), reason="HumanML3D sample not present")
def test_stablemo_footskate_features_are_consistent(tmp_path):
    from stablemo.cli import main
    from stablemo.motion import canonicalize_joints, features_to_joints

    feats = np.load(SAMPLE / "new_joint_vecs/012314.npy")
    out, joints_out = tmp_path / "clean.npy", tmp_path / "joints.npy"
    assert main(["footskate", str(SAMPLE / "new_joint_vecs/012314.npy"), "--out", str(out),
                 "--joints-out", str(joints_out), "--contacts", "heuristic", "--iters", "60"]) == 0
    cleaned = np.load(out)
    assert cleaned.shape == feats.shape and np.isfinite(cleaned).all()
    # every feature group comes from the corrected positions: recovering joints gives them back
    # exactly, up to the extraction's rigid placement of frame 0
    recovered = features_to_joints(cleaned)
    placed = canonicalize_joints(np.load(joints_out), "humanml3d", refit=False)
    assert np.abs(recovered - placed).max() < 1e-4
    lengths = torch.tensor([feats.shape[0]])
    # skating compared on the same floor, the input's: the cleanup also stands the clip on the
    # floor its planted feet define (one vertical shift; GMD's 5 cm height gate counts more swing
    # frames of a lower motion)
    joints_in = torch.from_numpy(features_to_joints(feats))[None]
    lift = cleanup(joints_in, PARENTS, FEET, config=CleanupConfig(iters=1, detect="heuristic")).info["floor_offset"][0]
    assert 0.005 < lift < 0.02  # this clip's planted toes stand ~1 cm up
    before = gmd_skating_ratio(joints_in, lengths)
    after = gmd_skating_ratio(torch.from_numpy(recovered)[None] + lift * torch.tensor([0.0, 1.0, 0.0]), lengths)
    assert after < before
    assert main(["footskate", str(tmp_path / "missing.npy"), "--out", str(out)]) == 2


def test_clean_features_reproduce_the_cleaned_joints():
    """Features out of clean_features give back exactly the joints it returns (no refit moves the
    anchored feet), on the standard skeleton, with less skating than the input."""
    from stablemo.motion import canonicalize_joints, features_to_joints
    from stablemo.skating.cleanup import clean_features, joints_to_consistent_features

    x = standing_pose().expand(60, 22, 3).clone()              # (60, 22, 3)
    x[:, :, 2] += 0.1 * torch.sin(torch.arange(60) * torch.pi / 10)[:, None]  # body and feet sway ±10 cm, up to 0.6 m/s
    batch = torch.stack([x, torch.cat([x[:45], torch.zeros(15, 22, 3)])])       # lengths 60 and 45
    feats = torch.from_numpy(joints_to_consistent_features(batch.numpy(), [60, 45], refit=True))
    cleaned, joints, info = clean_features(feats, [60, 45], vgrf=None)   # tensors in, tensors out
    assert torch.is_tensor(cleaned) and torch.is_tensor(joints)
    cleaned, joints = cleaned.numpy(), joints.numpy()
    np.testing.assert_array_equal(clean_features(feats.numpy(), [60, 45], vgrf=None)[0], cleaned)  # numpy in, out
    assert cleaned.shape == feats.shape and info["anchored_ranges"] > 0
    assert np.all(cleaned[1, 45:] == 0) and np.all(joints[1, 45:] == 0)
    for b, n in enumerate((60, 45)):
        rec = features_to_joints(cleaned[b, :n])
        assert np.abs(rec - canonicalize_joints(joints[b, :n], "humanml3d", refit=False)).max() < 1e-4
        lengths = np.linalg.norm(joints[b, :n, 1:] - joints[b, :n][:, PARENTS[1:]], axis=-1)
        assert np.abs(lengths - np.array(BONES[1:])[None]).max() < 2e-3   # the standard skeleton
    lengths_t = torch.tensor([60, 45])
    before = gmd_skating_ratio(torch.from_numpy(features_to_joints(feats.numpy())), lengths_t)
    after = gmd_skating_ratio(torch.from_numpy(features_to_joints(cleaned)), lengths_t)
    assert (after < 0.5 * before).all(), (before, after)


@pytest.mark.skipif(not (SAMPLE / "new_joints/012314.npy").is_file(), reason="HumanML3D sample not present")
def test_guidance_hook_cleans_x0_inside_denoising():
    from stablemo.diffusion.schedule import NoiseSchedule
    from stablemo.inference.config import InferenceConfig
    from stablemo.inference.pipeline import Pipeline
    from stablemo.motion import features_to_joints
    from stablemo.skating.cleanup import joints_to_consistent_features
    from stablemo.skating.hook import FootskateHook

    clip = torch.from_numpy(np.load(SAMPLE / "new_joints/012314.npy")).float()[:64]
    contacts, _ = detect_contacts(clip[None], None, FEET, 20.0, 1)
    sliding = _injected_sliding(clip[None], contacts, torch.Generator().manual_seed(0), 0.015)
    target = torch.from_numpy(joints_to_consistent_features(sliding.numpy(), [64]))  # (1, 64, 263)
    mean, std = np.zeros(263, np.float32), np.ones(263, np.float32)

    class Fixed(torch.nn.Module):  # an "x0 predictor" that always proposes the sliding motion
        length_multiple = 1

        def encode_text(self, texts):
            return torch.zeros(len(texts), 1, 4), torch.ones(len(texts), 1, dtype=torch.bool)

        def prepare(self, text, text_mask, motion_mask, time_cond=None, timesteps=()):
            return None

        def denoise(self, x, t, ctx):
            return target.expand(x.shape[0], -1, -1)[:, : x.shape[1]].to(x.dtype)

    pipe = Pipeline(Fixed(), NoiseSchedule(), mean, std, inference=InferenceConfig(min_length=8, max_length=64),
                    device="cpu", fast=False)
    hook = FootskateHook(pipe, vgrf=None, iters=60, steps=[-1])
    plain = pipe.generate(["walk"], [64], steps=3, seed=0)
    guided = pipe.generate(["walk"], [64], steps=3, seed=0, hooks=[hook])
    assert [c["step"] for c in hook.calls] == [2]
    lengths = torch.tensor([64])
    # the hook's work is the sampler's output (before the finishing step, whose floor placement moves
    # feet across the GMD ratio's absolute 5 cm height rule)
    j_plain = features_to_joints(plain.raw_features)
    j_guided = features_to_joints(guided.raw_features)
    assert gmd_skating_ratio(j_guided, lengths) < 0.8 * gmd_skating_ratio(j_plain, lengths)
    # and what the user receives keeps it: the stance feet slide less than without the hook
    from stablemo.eval.kinematics import measure

    speed = [measure(g.joints.double(), [64], "humanml3d")["stance_speed"][0] for g in (plain, guided)]
    assert speed[1] < 0.8 * speed[0]


def test_long_travelling_contacts_can_be_split():
    c = torch.ones(1, 40, 4, dtype=torch.bool)
    pos = torch.zeros(1, 40, 4, 3)
    pos[..., 0] = 0.01 * torch.arange(40)[None, :, None]                 # a shuffling foot: 1 cm/frame
    _, _, whole = contact_ranges(c, pos, up_axis=1, ramp_frames=1, min_range=3)
    targets, _, split = contact_ranges(c, pos, up_axis=1, ramp_frames=1, min_range=3, split_travel=0.1)
    assert whole["ranges"] == 4 and split["ranges"] == 16                 # 39 cm of path in 10 cm pieces
    assert (targets[0, :, 0, 0] - pos[0, :, 0, 0]).abs().max() <= 0.05 + 1e-6


def test_vgrf_fit_learns_repeats_and_refuses_a_non_finite_loss():
    """footskate.train.fit (the loop of `python -m footskate.train` and scripts/footskate/train_vgrf.py):
    the loss falls on a fixed toy set, the same generator gives the same weights, and a loss that
    turns non-finite is one FootskateError."""
    from footskate.train import fit, masked_msle, sample_batch

    g = torch.Generator().manual_seed(0)
    joints = [torch.randn(40, 22, 3, generator=g) * 0.3 for _ in range(4)]
    forces = [torch.rand(40, 2, 16, generator=g) for _ in range(4)]

    def trained(steps: int, lr: float = 1e-3) -> VGRFNet:
        torch.manual_seed(0)
        model = VGRFNet(22, conv_channels=(8, 8, 8, 8), hidden=16)
        return fit(model, joints, forces, steps, 4, 32, lr, torch.Generator().manual_seed(1), log=lambda _: None)

    def loss(model: VGRFNet) -> float:
        x, y, n = sample_batch(joints, forces, 8, 32, torch.Generator().manual_seed(2), augment=False)
        with torch.no_grad():
            return float(masked_msle(model(x, n), y, n))

    a, b = trained(60), trained(60)
    assert not a.training
    for (name, p), q in zip(a.state_dict().items(), b.state_dict().values()):
        assert torch.equal(p, q), name
    assert loss(a) < 0.8 * loss(trained(0))
    with pytest.raises(FootskateError, match="became non-finite at step"):
        trained(3, lr=float("inf"))
