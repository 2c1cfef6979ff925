"""stablemo.retarget: roles found by name in every convention, one-line refusals, the round trip onto
our own rig, the issue's targets on rigs of other sizes, names and rest poses, glTF characters."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from stablemo.bvh import forward_kinematics, motion_to_animation, write_bvh
from stablemo.bvh.names import bvh_names
from stablemo.errors import StableMoError
from stablemo.retarget import retarget, retarget_file
from stablemo.retarget.measure import (
    flipped_joints,
    heading_error,
    reach_error,
    stance_speed,
)
from stablemo.retarget.names import find_roles
from stablemo.retarget.source import SKELETON_ROLES
from stablemo.retarget.variants import CONVENTIONS, rig_bvh, variant_rig

SAMPLE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "humanml3d-sample" / "new_joints" / "012314.npy"


def synth(action: str, seed: int = 0, **params) -> np.ndarray:
    """(T, 22, 3) one synthetic action on one rigid body (stablemo.data.synth)."""
    from stablemo.bench.motions import synth_joints

    return synth_joints(action, seed, **params)


@pytest.fixture(scope="module")
def walk() -> np.ndarray:
    return synth("walk", 3)


def body_of(joints: np.ndarray) -> np.ndarray:
    """(22, 3) the motion's own T-pose body (our BVH writer's rig)."""
    return motion_to_animation(joints).rig.offsets


def test_every_naming_convention_finds_every_role():
    want = SKELETON_ROLES["humanml3d"]
    for convention in CONVENTIONS:
        rig, index = variant_rig(convention, legs=1.25, a_pose_deg=45, units="cm")
        roles = find_roles(rig.names, rig.parents, rig.rest, convention)
        assert roles.hips == index[want.hips], convention
        assert roles.spine == tuple(index[j] for j in want.spine), convention
        assert roles.neck == tuple(index[j] for j in want.neck) and roles.head == index[want.head], convention
        for side in ("Left", "Right"):
            got = {role: rig.names[j] for role, j in roles.sides[side].items()}
            assert got == {role: rig.names[index[j]] for role, j in want.sides[side].items()}, convention


def test_sides_of_unnamed_joints_come_from_the_rest_pose():
    rig, index = variant_rig("unreal")
    # no side words, as a mirrored copy in Blender is named: thigh_l/thigh_r -> thigh/thigh.001; +x is the left
    names = [n.removesuffix("_l").removesuffix("_r") + (".001" if n.endswith("_r") else "") for n in rig.names]
    roles = find_roles(names, rig.parents, rig.rest, "x")
    assert names[roles.sides["Left"]["UpperLeg"]] == "thigh" and rig.rest[roles.sides["Left"]["UpperLeg"], 0] > 0
    assert roles.sides["Right"]["Hand"] == index[21]


def test_a_rig_without_hands_is_one_line_naming_them(tmp_path):
    rig, index = variant_rig("mixamo", extras=False)
    names = list(rig.names)
    for j in (index[20], index[21]):
        names[j] = f"mixamorig:Prop{j}"
    with pytest.raises(StableMoError, match=r"not a humanoid rig.*LeftHand, RightHand; pass --map") as err:
        find_roles(names, rig.parents, rig.rest, "prop.bvh")
    assert "\n" not in str(err.value)


def test_a_yaml_map_names_what_the_names_do_not(tmp_path, walk):
    from dataclasses import replace

    rig, index = variant_rig("mixamo", extras=False)
    names = list(rig.names)
    names[index[20]], names[index[21]] = "grip_a", "grip_b"
    odd = replace(rig, names=tuple(names))
    (tmp_path / "odd.bvh").write_text(rig_bvh(odd))
    (tmp_path / "map.yaml").write_text("LeftHand: grip_a\nRightHand: grip_b\n")
    report = retarget_file(walk, tmp_path / "odd.bvh", tmp_path / "out.bvh", role_map=tmp_path / "map.yaml")
    assert report.roles["grip_a"] == "LeftHand" and (tmp_path / "out.bvh").is_file()
    (tmp_path / "bad.yaml").write_text("LeftPaw: grip_a\n")
    with pytest.raises(StableMoError, match=r"unknown role\(s\) \['LeftPaw'\]"):
        retarget_file(walk, tmp_path / "odd.bvh", tmp_path / "out2.bvh", role_map=tmp_path / "bad.yaml")
    (tmp_path / "missing.yaml").write_text("LeftHand: nowhere\n")
    with pytest.raises(StableMoError, match="no joint named 'nowhere'"):
        retarget_file(walk, tmp_path / "odd.bvh", tmp_path / "out2.bvh", role_map=tmp_path / "missing.yaml")
    assert not (tmp_path / "out2.bvh").exists()


def round_trip_error(joints: np.ndarray, tmp_path) -> np.ndarray:
    """(T, 22) distance of each joint after retargeting onto our own rig (the BVH `stablemo bvh` writes)."""
    write_bvh(tmp_path / "own.bvh", joints)
    solved = retarget(joints, tmp_path / "own.bvh")
    order = [solved.target.names.index(n) for n in bvh_names("humanml3d")]
    return np.linalg.norm(solved.positions[:, order] - joints, axis=-1)


def test_round_trip_onto_our_own_rig_gives_the_joints_back(tmp_path, walk):
    err = round_trip_error(walk, tmp_path)
    assert err.mean() < 0.003 and err.max() < 0.01, (err.mean(), err.max())


@pytest.mark.skipif(not SAMPLE.is_file(), reason="the HumanML3D sample clip is not in ../shared")
def test_round_trip_of_the_real_clip(tmp_path):
    err = round_trip_error(np.load(SAMPLE).astype(np.float64), tmp_path)
    assert err.mean() < 0.003, err.mean()


def check_targets(joints: np.ndarray, rig, uniform: bool) -> dict:
    """The issue's targets on one rig: stance feet no faster than the source's + 2 cm/s, hands and
    feet within 3 % of leg length of the scaled source where no contact holds them and the arm can
    reach (on rigs of our proportions every frame is reachable), no knee or elbow bending the other
    way, heading within 5 degrees."""
    solved = retarget(joints, rig)
    speed = stance_speed(solved)
    assert speed["steps"] > 10 and speed["target_m_s"] <= speed["source_m_s"] + 0.02, speed
    reach = reach_error(solved)
    assert reach["max"] <= 0.03, reach
    if uniform:
        assert reach["unreachable"] == 0.0, reach
    flips = flipped_joints(solved)
    assert flips.pop("bent") > 50 and not any(flips.values()), flips
    assert heading_error(solved) <= 5.0
    anim = solved.anim
    fk = forward_kinematics(anim)
    assert np.abs(fk - solved.positions).max() < 1e-6 * np.abs(solved.positions).max()  # the rotations are the pose
    return {"reach": reach, "speed": speed}


RIGS = [  # (convention, legs, arms, scale, A-pose degrees, units)
    ("mixamo", 1.0, 1.0, 0.8, 45.0, "cm"),
    ("unreal", 1.0, 1.0, 1.25, 45.0, "cm"),
    ("vrm", 1.0, 1.0, 1.25, 30.0, "m"),
    ("smplx", 1.0, 1.0, 0.8, 0.0, "m"),
    ("daz", 1.0, 1.0, 1.25, 45.0, "cm"),  # the hips above a pelvis that holds only the thighs
    ("cc", 1.0, 1.0, 0.8, 45.0, "cm"),
]


@pytest.mark.parametrize("convention, legs, arms, scale, a_pose, units", RIGS)
def test_targets_on_rigs_of_other_sizes_names_and_rest_poses(walk, convention, legs, arms, scale, a_pose, units):
    rig, _ = variant_rig(convention, legs, arms, scale, a_pose, units, body=body_of(walk))
    check_targets(walk, rig, uniform=True)


@pytest.mark.parametrize("legs", [0.8, 1.25])
def test_legs_alone_longer_or_shorter(walk, legs):
    """Only the legs change: with longer legs the arms cannot put the hands everywhere the source's
    scaled hands are (those frames are counted, docs/retarget.md); where they can, the hands are
    there, and feet, knees, elbows and heading still hold."""
    rig, _ = variant_rig("unity", legs=legs, a_pose_deg=40, body=body_of(walk))
    reach = check_targets(walk, rig, uniform=False)["reach"]
    if legs > 1:
        assert reach["unreachable"] > 0.1, reach  # the measure leaves out what no arm of this rig reaches


@pytest.mark.skipif(not SAMPLE.is_file(), reason="the HumanML3D sample clip is not in ../shared")
def test_targets_on_the_real_clip():
    joints = np.load(SAMPLE).astype(np.float64)
    for scale in (0.8, 1.25):
        rig, _ = variant_rig("cmu", scale=scale, a_pose_deg=45, units="cm", body=body_of(joints))
        check_targets(joints, rig, uniform=True)


def test_targets_on_a_demo_model_motion():
    from stablemo.inference.bundle import DEMO_BUNDLE
    from stablemo.inference.pipeline import Pipeline

    out = Pipeline.from_bundle(DEMO_BUNDLE).generate(["a person walks forward"], 120, seed=0, steps=4)
    joints = out.joints[0].double().numpy()
    for scale in (0.8, 1.25):
        rig, _ = variant_rig("biped", scale=scale, a_pose_deg=45, body=body_of(joints))
        check_targets(joints, rig, uniform=True)


def test_a_kit_motion_in_millimetres(walk):
    """KIT-ML joints (21, millimetres, no clavicle, no neck joint), made from the HumanML3D walk by
    joint correspondence: retargeted with the same targets as a HumanML3D motion."""
    kit_from_ours = [0, 3, 6, 9, 15, 17, 19, 21, 16, 18, 20, 2, 5, 8, 11, 11, 1, 4, 7, 10, 10]
    kit = walk[:, kit_from_ours] * 1000.0
    kit[:, [15, 20]] += [0.0, 0.0, 50.0]  # toe tips 5 cm in front of the metatarsals
    rig, _ = variant_rig("unity", scale=1.1, a_pose_deg=45, body=body_of(walk))
    solved = retarget(kit, rig)
    assert solved.scale == pytest.approx(1.1 / 1000, rel=1e-3)
    speed = stance_speed(solved)
    assert speed["target_m_s"] <= speed["source_m_s"] + 0.02
    flips = flipped_joints(solved)
    assert flips.pop("bent") > 50 and not any(flips.values())
    assert heading_error(solved) < 5.0


def test_extra_bones_stay_at_rest_and_the_root_bone_carries_the_travel(walk):
    rig, index = variant_rig("unreal", scale=1.1, body=body_of(walk))  # a root bone on the floor, fingers, twists
    solved = retarget(walk, rig)
    extra = [j for j, n in enumerate(rig.names) if "Index" in n or "twist" in n]
    assert len(extra) == 6
    assert np.allclose(np.abs(solved.anim.rotations[:, extra, 0]), 1.0)  # identity: at rest under their parents
    assert rig.names[0] == "root" and np.allclose(solved.anim.rotations[:, 0], [1, 0, 0, 0])
    hips = index[0]
    assert np.abs(solved.positions[:, hips] - (solved.positions[:, 0] + rig.offsets[hips])).max() < 1e-9


def test_a_ten_second_motion_is_retargeted_fast(walk):
    """The issue's budget is 200 ms for 10 s on this CPU (scripts/retarget/measure.py measures it);
    here a loose bound that a loop over frames would break."""
    joints = np.concatenate([walk] * int(np.ceil(200 / len(walk))))[:200]
    rig, _ = variant_rig("mixamo", scale=1.1, a_pose_deg=45, units="cm", body=body_of(walk))
    retarget(joints, rig)
    start = time.perf_counter()
    retarget(joints, rig)
    assert time.perf_counter() - start < 1.0


def test_a_bvh_motion_retargets_like_its_joints(tmp_path, walk):
    write_bvh(tmp_path / "walk.bvh", walk, units="cm")
    rig, _ = variant_rig("vrm", scale=1.2, a_pose_deg=45, body=body_of(walk))
    a, b = retarget(tmp_path / "walk.bvh", rig), retarget(walk, rig)
    assert a.scale == pytest.approx(b.scale / 100, rel=1e-6)
    assert np.abs(a.positions - b.positions).max() < 1e-4


def test_a_z_up_rig_and_a_z_up_bvh_motion(tmp_path, walk):
    """Blender's own BVH export is z up, the character facing -y: the motion comes out so, and such
    a file read back as a motion is the same motion."""
    from dataclasses import replace

    from stablemo.bvh.text import format_bvh

    y_up, _ = variant_rig("unity", scale=1.1, a_pose_deg=30, body=body_of(walk))
    z_up = replace(y_up, offsets=np.stack([y_up.offsets[:, 0], -y_up.offsets[:, 2], y_up.offsets[:, 1]], -1))
    direct = retarget(walk, y_up)
    turned = retarget(walk, z_up)
    assert np.abs(turned.positions - np.stack([direct.positions[..., 0], -direct.positions[..., 2],
                                               direct.positions[..., 1]], -1)).max() < 1e-9
    assert heading_error(turned) < 1e-6 and turned.positions[..., 2].min() > -0.01  # above a z-up floor
    (tmp_path / "z.bvh").write_text(format_bvh(turned.anim))
    again = retarget(tmp_path / "z.bvh", y_up)
    assert np.abs(again.positions - direct.positions).max() < 1e-4


def test_a_rig_standing_on_its_floor_plants_its_feet_at_their_own_height(walk):
    """A rig modelled standing on the floor (its ankles 10 cm up, toes 35 degrees below them, as
    drawn feet are, not HumanML3D's 5 cm and 20 degrees): where the source's foot is flat, the rig's
    ankle and toe are where they are at rest."""
    from dataclasses import replace

    rig, index = variant_rig("mixamo", scale=1.2, a_pose_deg=45, body=body_of(walk))
    offsets = rig.offsets.copy()
    for ankle, toe in ((index[7], index[10]), (index[8], index[11])):
        offsets[toe] = 0.17 * np.array([0.0, -np.sin(np.radians(35)), np.cos(np.radians(35))])
    standing = replace(rig, offsets=offsets)
    offsets[0, 1] -= standing.rest[:, 1].min()  # the root raised: the toes on y = 0
    standing = replace(rig, offsets=offsets)
    solved = retarget(walk, standing)
    rest = standing.rest
    for s_i, side in enumerate(("Left", "Right")):
        flat = solved.contacts[:, 2 * s_i:2 * s_i + 2].all(-1)
        for role in ("Foot", "Toes"):
            j = solved.roles.sides[side][role]
            assert abs(np.median(solved.positions[flat, j, 1]) - rest[j, 1]) < 0.01, (side, role)
    as_scaled = retarget(walk, rig)  # the same rig hanging from its root at the origin: only scaled
    free = as_scaled.held[:, 0] == 0
    assert free.sum() > 5 and np.abs(as_scaled.positions[free, index[7]] - as_scaled.scaled[free, 7]).max() < 1e-9


def test_a_rig_facing_backwards_at_rest_walks_the_motion_s_way(walk):
    """A y-up rig that faces -z at rest (its left at -x): every bone turns from its own rest, so the
    joints land where they do on the same rig facing +z."""
    from dataclasses import replace

    ahead, _ = variant_rig("mixamo", scale=1.1, a_pose_deg=45, body=body_of(walk))
    behind = replace(ahead, offsets=ahead.offsets * [-1.0, 1.0, -1.0])
    a, b = retarget(walk, ahead), retarget(walk, behind)
    assert np.abs(a.positions - b.positions).max() < 1e-6
    assert not np.allclose(np.abs(a.anim.rotations[:, 0, 0]), np.abs(b.anim.rotations[:, 0, 0]))  # turned about


def test_a_bvh_motion_with_odd_names_takes_a_source_map(tmp_path, walk, capsys):
    from stablemo.cli import main

    write_bvh(tmp_path / "walk.bvh", walk)
    text = (tmp_path / "walk.bvh").read_text()
    (tmp_path / "odd.bvh").write_text(text.replace("LeftHand", "paw_a").replace("RightHand", "paw_b"))
    rig, _ = variant_rig("unreal", scale=1.1, body=body_of(walk))
    (tmp_path / "rig.bvh").write_text(rig_bvh(rig))
    args = ["retarget", str(tmp_path / "odd.bvh"), "--rig", str(tmp_path / "rig.bvh"), "--out", str(tmp_path / "o.bvh")]
    assert main(args) == 2
    assert "no joint found for LeftHand, RightHand; pass --source-map MAP.yaml" in capsys.readouterr().err
    (tmp_path / "map.yaml").write_text("LeftHand: paw_a\nRightHand: paw_b\n")
    assert main(args + ["--source-map", str(tmp_path / "map.yaml")]) == 0
    direct = retarget(walk, tmp_path / "rig.bvh")
    assert np.abs(retarget(tmp_path / "odd.bvh", tmp_path / "rig.bvh", source_map=tmp_path / "map.yaml").positions
                  - direct.positions).max() < 1e-4


def test_a_bvh_motion_turns_the_rig_s_hands_and_head(tmp_path, walk):
    """A BVH file's wrists bend and its head turns (joint positions cannot say so): the rig's hands
    and head turn the same way from their own rest (A-pose arms against the file's T-pose)."""
    from scipy.spatial.transform import Rotation

    from stablemo.bvh.text import format_bvh

    anim = motion_to_animation(walk)
    names = list(anim.rig.names)
    turns = {"LeftHand": [0.0, 0.0, -50.0], "RightHand": [0.0, 40.0, 0.0], "Head": [0.0, 60.0, 0.0]}
    for name, degrees in turns.items():  # a bend of the wrist, a turn of the head, growing over the motion
        ramp = np.linspace(0.0, 1.0, anim.num_frames)[:, None] * np.radians(degrees)
        anim.rotations[:, names.index(name)] = Rotation.from_rotvec(ramp).as_quat()[:, [3, 0, 1, 2]]
    (tmp_path / "turns.bvh").write_text(format_bvh(anim))
    rig, index = variant_rig("unity", scale=1.2, a_pose_deg=45, body=body_of(walk))  # fingers under the hands
    solved = retarget(tmp_path / "turns.bvh", rig)
    file_joints = forward_kinematics(anim)
    ends = {"LeftHand": index[20], "RightHand": index[21]}
    for name, hand in ends.items():
        finger = rig.names.index(rig.names[hand] + "Index1")
        got = solved.positions[:, finger] - solved.positions[:, hand]
        # where the file's hand points: its End Site turned with it
        j = names.index(name)
        world = Rotation.from_quat(anim.rotations[:, j][:, [1, 2, 3, 0]])
        for p in _ancestors(anim.rig.parents, j):  # parent first: R_root ... R_parent R_joint
            world = Rotation.from_quat(anim.rotations[:, p][:, [1, 2, 3, 0]]) * world
        want = world.apply(anim.rig.end_sites[j])
        cos = (got * want).sum(-1) / np.linalg.norm(got, axis=-1) / np.linalg.norm(want, axis=-1)
        assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 1.0, name
        forearm = file_joints[:, j] - file_joints[:, anim.rig.parents[j]]
        bend = (forearm[-1] * want[-1]).sum() / np.linalg.norm(forearm[-1]) / np.linalg.norm(want[-1])
        assert np.degrees(np.arccos(np.clip(bend, -1, 1))) > 30  # the wrist did bend away from the forearm
    # the head: the rig's (same rest direction, up) turns as the file's, 60 degrees by the end
    turned = [_world(anim.rotations, anim.rig.parents, names.index("Head")),
              _world(solved.anim.rotations, rig.parents, index[15])]
    assert (turned[0].inv() * turned[1]).magnitude().max() < np.radians(1.0)
    assert turned[0][-1].magnitude() > np.radians(30)


def _world(rotations: np.ndarray, parents, joint: int):
    """scipy Rotation (T,): a joint's world rotation from local ones (T, J, 4) w-first."""
    from scipy.spatial.transform import Rotation

    world = Rotation.from_quat(rotations[:, joint][:, [1, 2, 3, 0]])
    for p in _ancestors(parents, joint):
        world = Rotation.from_quat(rotations[:, p][:, [1, 2, 3, 0]]) * world
    return world


def _ancestors(parents, joint: int) -> list[int]:
    out = []
    while parents[joint] >= 0:
        joint = parents[joint]
        out.append(joint)
    return out


def glb_character(tmp_path, joints) -> tuple[Path, object]:
    """A GLB character (our mannequin) whose nodes have rest rotations of their own, as an FBX's do."""
    from scipy.spatial.transform import Rotation

    from stablemo.bvh.rig import Rig
    from stablemo.gltf import glb_bytes, mannequin

    rig, _ = variant_rig("vrm", scale=1.1, a_pose_deg=40, body=body_of(joints))
    rest = Rotation.from_rotvec(np.random.default_rng(0).normal(0, 0.5, (rig.num_joints, 3)))
    world = [None] * rig.num_joints
    local = np.zeros_like(rig.offsets)
    for j, p in enumerate(rig.parents):
        world[j] = rest[j] if p < 0 else world[p] * rest[j]
        local[j] = rig.offsets[j] if p < 0 else world[p].inv().apply(rig.offsets[j])
    node_rig = Rig(rig.names, rig.parents, local, {})
    quats = rest.as_quat()[:, [3, 0, 1, 2]]
    colours = {"left": "#d04040", "right": "#4060d0", "center": "#909090"}
    body = mannequin(node_rig, colours, quats, rest_root=rig.offsets[0])
    path = tmp_path / "character.glb"
    path.write_bytes(glb_bytes(node_rig, None, body, rest_rotations=quats, rest_root=rig.offsets[0]))
    return path, rig


def as_matrices(path: Path) -> None:
    """Rewrite a GLB's nodes with `matrix` instead of translation/rotation/scale (both are glTF)."""
    from stablemo.gltf import read_glb
    from stablemo.gltf.writer import pack_glb
    from stablemo.retarget.gltf_rig import node_matrix

    doc, binary = read_glb(path.read_bytes())
    for node in doc["nodes"]:
        m = node_matrix(node)
        for key in ("translation", "rotation", "scale"):
            node.pop(key, None)
        node["matrix"] = m.T.reshape(-1).tolist()  # column-major
    path.write_bytes(pack_glb(doc, binary))


@pytest.mark.parametrize("matrices", [False, True])
def test_a_glb_character_gets_its_own_file_back_with_the_animation(tmp_path, walk, matrices):
    from stablemo.gltf import read_glb
    from stablemo.gltf.writer import accessor_array

    path, rig = glb_character(tmp_path, walk)
    if matrices:
        as_matrices(path)
    report = retarget_file(walk, path, tmp_path / "out.glb")
    solved = retarget(walk, path)
    doc, binary = read_glb((tmp_path / "out.glb").read_bytes())
    before, _ = read_glb(path.read_bytes())
    assert doc["meshes"] == before["meshes"] and doc["skins"][0]["joints"] == before["skins"][0]["joints"]
    assert not any("matrix" in doc["nodes"][n] for n in solved.target.extra["nodes"])  # animated nodes hold TRS
    anim = doc["animations"][-1]
    assert report.fmt == "glb" and len(anim["channels"]) == rig.num_joints + 1
    for frame in (0, len(walk) // 2, len(walk) - 1):  # the file's node transforms at a frame put the joints on the solve
        nodes = [dict(n) for n in doc["nodes"]]
        for ch in anim["channels"]:
            values = accessor_array(doc, binary, anim["samplers"][ch["sampler"]]["output"])
            nodes[ch["target"]["node"]][ch["target"]["path"]] = values[frame].tolist()
        heads = np.array([node_world(nodes, n)[:3, 3] for n in solved.target.extra["nodes"]])
        assert np.abs(heads - solved.positions[frame]).max() < 1e-5


def node_world(nodes: list, node: int) -> np.ndarray:
    """(4, 4) a glTF node's world transform: its ancestors' and its own, from the root down."""
    from stablemo.retarget.gltf_rig import node_matrix

    parent = {c: i for i, n in enumerate(nodes) for c in n.get("children", [])}
    chain = [node]
    while chain[-1] in parent:
        chain.append(parent[chain[-1]])
    out = np.eye(4)
    for n in reversed(chain):
        out = out @ node_matrix(nodes[n])
    return out


def gltf_skeleton(tmp_path, walk):
    """tmp_path/rig.gltf: the GLB character's nodes and skin joints alone, as JSON (no buffers)."""
    import json

    from stablemo.gltf import read_glb

    path, rig = glb_character(tmp_path, walk)
    doc, _ = read_glb(path.read_bytes())
    nodes = [{k: v for k, v in n.items() if k not in ("mesh", "skin")} for n in doc["nodes"]]
    (tmp_path / "rig.gltf").write_text(json.dumps({"asset": doc["asset"], "nodes": nodes,
                                                   "skins": [{"joints": doc["skins"][0]["joints"]}]}))
    return rig


def test_a_gltf_rig_gets_its_skeleton_back_as_a_glb(tmp_path, walk):
    from stablemo.bvh import Animation
    from stablemo.gltf import read_glb
    from stablemo.gltf.writer import accessor_array

    rig = gltf_skeleton(tmp_path, walk)
    retarget_file(walk, tmp_path / "rig.gltf", tmp_path / "skeleton.glb")
    solved = retarget(walk, tmp_path / "rig.gltf")
    out, binary = read_glb((tmp_path / "skeleton.glb").read_bytes())
    assert [n["name"] for n in out["nodes"]] == list(solved.target.names) and "meshes" not in out
    # its channels are the solve's rotations and root: forward kinematics gives the joints
    anim = out["animations"][0]
    rotations = np.zeros((len(walk), rig.num_joints, 4))
    root = None
    for ch in anim["channels"]:
        values = accessor_array(out, binary, anim["samplers"][ch["sampler"]]["output"])
        if ch["target"]["path"] == "rotation":
            rotations[:, ch["target"]["node"]] = values[:, [3, 0, 1, 2]]
        else:
            root = values
    fk = forward_kinematics(Animation(solved.anim.rig, root.astype(float), rotations, solved.anim.fps))
    assert np.abs(fk - solved.positions).max() < 1e-4


def test_every_glb_we_write_passes_the_khronos_validator(tmp_path, walk):
    from stablemo.gltf import validator

    if validator.available() is not None:
        pytest.skip(validator.available())
    path, _ = glb_character(tmp_path, walk)
    as_matrices(path)
    retarget_file(walk, path, tmp_path / "out.glb")  # the character (nodes as matrices) with the animation added
    gltf_skeleton(tmp_path, walk)
    retarget_file(walk, tmp_path / "rig.gltf", tmp_path / "skeleton.glb")  # a skeleton alone
    reports = validator.validate([tmp_path / "out.glb", tmp_path / "skeleton.glb"])
    assert [(r["errors"], r["warnings"]) for r in reports] == [(0, 0), (0, 0)], reports


@pytest.mark.parametrize("doc, message", [
    ({"nodes": [{"name": "a", "children": [1]}, {"name": "b", "children": [0]}], "skins": [{"joints": [0, 1]}]},
     "children form a loop"),
    ({"nodes": [{"name": "a", "children": [5]}], "skins": [{"joints": [0]}]}, "children: 5 is not a node"),
    ({"nodes": [{"name": "a", "rotation": [0, 0, 0]}], "skins": [{"joints": [0]}]}, "node 'a': not a transform"),
    ({"nodes": [{"name": "a", "translation": [0, float("nan"), 0]}], "skins": [{"joints": [0]}]}, "NaN or Inf"),
    ({"nodes": [{"name": "a"}], "skins": [{"joints": [3]}]}, "names a node that does not exist"),
    ({"nodes": [{"name": "a"}]}, "no skin"),
    ({"nodes": [{"name": "a"}, {"name": "b"}], "skins": [{"joints": [0, 1]}]}, "form 2 trees"),
])
def test_a_broken_gltf_rig_is_one_line_naming_the_file(tmp_path, doc, message):
    import json

    from stablemo.retarget.target import read_rig

    path = tmp_path / "rig.gltf"
    path.write_text(json.dumps({"asset": {"version": "2.0"}, **doc}))
    with pytest.raises(StableMoError, match=message) as err:
        read_rig(path)
    assert str(err.value).startswith(str(path)) and "\n" not in str(err.value)


def test_command_line_errors_are_one_line_before_any_work(tmp_path, walk, capsys, monkeypatch):
    from stablemo.cli import main

    np.save(tmp_path / "walk.joints.npy", walk)
    rig, _ = variant_rig("mixamo")
    (tmp_path / "rig.bvh").write_text(rig_bvh(rig))
    motion = str(tmp_path / "walk.joints.npy")
    cases = [
        (["--rig", str(tmp_path / "rig.bvh"), "--out", str(tmp_path / "o.glb")], "a .bvh rig is written as .bvh"),
        (["--rig", str(tmp_path / "nope.bvh"), "--out", str(tmp_path / "o.bvh")], "nope.bvh: file not found"),
        (["--rig", str(tmp_path / "rig.obj"), "--out", str(tmp_path / "o.bvh")], "expected a .bvh, .gltf, .glb or .fbx"),
        (["--rig", str(tmp_path / "rig.bvh"), "--out", str(tmp_path / "o.bvh"), "--fps", "nan"], "--fps"),
    ]
    (tmp_path / "rig.fbx").write_bytes(b"not really")
    monkeypatch.setattr("shutil.which", lambda name: None)
    cases.append((["--rig", str(tmp_path / "rig.fbx"), "--out", str(tmp_path / "o.bvh")], "needs Blender on PATH"))
    for args, message in cases:
        assert main(["retarget", motion, *args]) == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, err
    assert not list(tmp_path.glob("o.*"))
    assert main(["retarget", motion, "--rig", str(tmp_path / "rig.bvh"), "--out", str(tmp_path / "o.bvh"), "--fps", "30"]) == 0
    assert "at 30 fps" in capsys.readouterr().out
