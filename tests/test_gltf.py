"""GLB out (stablemo.gltf): the file poses our joints, its mannequin is bound and follows them,
Khronos' validator finds nothing wrong with any file we write, `generate --format glb` writes one,
and FBX is a one-line error without Blender. (The Blender and browser readings of the same files
are in tests/test_bvh_blender.py and tests/test_serve_browser.py.)"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from stablemo.bench.motions import flip, heading, synth_joints
from stablemo.bvh import Animation, Rig, forward_kinematics, motion_to_animation
from stablemo.bvh.names import bvh_names
from stablemo.errors import StableMoError
from stablemo.gltf import (
    glb_bytes,
    mannequin,
    motion_glb,
    read_glb,
    standing_glb,
    write_glb,
)
from stablemo.gltf.mannequin import SOLE
from stablemo.gltf.validator import available, validate
from stablemo.gltf.writer import accessor_array
from stablemo.outputs.render import COLOURS


def quat_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) glTF (x, y, z, w) -> (..., 3, 3), written out independently of the writer's."""
    x, y, z, w = np.moveaxis(q / np.linalg.norm(q, axis=-1, keepdims=True), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


def pose_file(data: bytes) -> tuple[dict, np.ndarray, np.ndarray]:
    """Read a GLB as a viewer does: (document, joint world matrices (T, J, 4, 4) at every key,
    key times (T,)), from the node tree and the animation's channels alone."""
    doc, binary = read_glb(data)
    (skin,) = doc["skins"]
    joints = skin["joints"]
    nodes = doc["nodes"]
    anim = doc["animations"][0]
    times = accessor_array(doc, binary, anim["samplers"][0]["input"])
    t = len(times)
    trs = {j: {"translation": np.tile(nodes[j].get("translation", [0, 0, 0]), (t, 1)),
               "rotation": np.tile(nodes[j].get("rotation", [0, 0, 0, 1]), (t, 1))} for j in joints}
    for ch in anim["channels"]:
        sampler = anim["samplers"][ch["sampler"]]
        assert sampler["interpolation"] == "LINEAR"
        assert np.array_equal(accessor_array(doc, binary, sampler["input"]), times)
        trs[ch["target"]["node"]][ch["target"]["path"]] = accessor_array(doc, binary, sampler["output"])
    parent = {c: j for j in joints for c in nodes[j].get("children", [])}
    world = np.zeros((t, len(joints), 4, 4))
    for k, j in enumerate(joints):  # parents come first
        local = np.zeros((t, 4, 4))
        local[:, :3, :3] = quat_matrix(trs[j]["rotation"])
        local[:, :3, 3] = trs[j]["translation"]
        local[:, 3, 3] = 1
        world[:, k] = local if j not in parent else world[:, joints.index(parent[j])] @ local
    return doc, world, times


def skinned_vertices(data: bytes, world: np.ndarray) -> list[np.ndarray]:
    """Each primitive's vertices (T, V, 3) by linear blend skinning with the file's inverse bind matrices."""
    doc, binary = read_glb(data)
    ibm = accessor_array(doc, binary, doc["skins"][0]["inverseBindMatrices"]).reshape(-1, 4, 4).transpose(0, 2, 1)
    out = []
    for prim in doc["meshes"][0]["primitives"]:
        a = prim["attributes"]
        pos = accessor_array(doc, binary, a["POSITION"]).astype(np.float64)
        jnt, wts = accessor_array(doc, binary, a["JOINTS_0"]), accessor_array(doc, binary, a["WEIGHTS_0"])
        skin = world @ ibm  # (T, J, 4, 4)
        moved = np.einsum("tvkij,vj->tvki", skin[:, jnt][..., :3, :3], pos) + skin[:, jnt][..., :3, 3]
        out.append(np.einsum("tvki,vk->tvi", moved, wts))
    return out


@pytest.fixture(scope="module")
def walk():
    """(T, 22, 3) a walk turned to 60 degrees, on one rigid body, and its GLB's bytes."""
    joints = forward_kinematics(motion_to_animation(heading(synth_joints("walk", 41), 60)))
    data, fit = motion_glb(joints, colours=COLOURS)
    assert fit.max_m < 1e-9
    return joints, data


def test_the_file_poses_the_motion_at_its_frame_rate(walk):
    joints, data = walk
    doc, world, times = pose_file(data)
    assert data[:4] == b"glTF" and doc["asset"]["version"] == "2.0"
    assert [doc["nodes"][j]["name"] for j in doc["skins"][0]["joints"]] == list(bvh_names("humanml3d"))
    assert np.allclose(times, np.arange(len(joints)) / 20.0, atol=1e-6)  # one key per frame, 20 fps
    err = np.linalg.norm(world[..., :3, 3] - joints, axis=-1)
    assert err.max() < 1e-5  # float32 in the file


def test_the_mannequin_is_bound_at_rest_and_follows_its_bones_rigidly(walk):
    joints, data = walk
    doc, world, _ = pose_file(data)
    binary = read_glb(data)[1]
    prims = doc["meshes"][0]["primitives"]
    assert [doc["materials"][p["material"]]["name"] for p in prims] == ["left", "right", "center"]
    moved = skinned_vertices(data, world)
    for prim, verts in zip(prims, moved):
        jnt = accessor_array(doc, binary, prim["attributes"]["JOINTS_0"])[:, 0]
        # every vertex keeps its distance to its joint: rigid parts, nothing stretched or torn off
        dist = np.linalg.norm(verts - world[:, jnt][..., :3, 3], axis=-1)  # (T, V)
        assert np.ptp(dist, axis=0).max() < 1e-4
        assert dist.max() < 0.55  # nothing floats away: a thigh (0.4 m) and its cap at most
    every = np.concatenate(moved, axis=1)  # (T, V, 3)
    # the body surrounds the skeleton: the pelvis is inside it, the head's top 20-35 cm above the neck
    assert every[..., 1].max(1).min() > joints[:, 12, 1].max() + 0.1
    # the soles stand on the floor: on frames where both feet are flat (ankle < 7 cm above the toe
    # joint, which is on y = 0) the lowest point is within 1.5 cm of it; at a toe-off the synthetic
    # walk stands its foot 75 degrees steep on the toe joint, and a foot without toes then dips in
    flat = (joints[:, [7, 8], 1] - joints[:, [10, 11], 1]).max(1) < 0.07
    assert flat.sum() > 10 and np.abs(every[flat][..., 1].min(1)).max() < 0.015
    assert every[..., 1].min() > -0.07


def test_colours_and_a_skeleton_without_mesh():
    rig = Rig(("root", "tip"), (-1, 0), np.array([[0.0, 0, 0], [0, 1, 0]]), {})
    anim = Animation(rig, np.zeros((3, 3)), np.tile([1.0, 0, 0, 0], (3, 2, 1)), 30.0)
    doc, _ = read_glb(glb_bytes(rig, anim))
    assert "meshes" not in doc and "skins" not in doc and len(doc["animations"][0]["channels"]) == 3
    body = mannequin(rig, {"left": "#ff0000", "right": "#00ff00", "center": "#808080"})
    (center,) = body  # no Left/Right names: one grey primitive
    assert center.colour[:3] == pytest.approx((0.2158605, 0.2158605, 0.2158605))  # sRGB 0x80 in linear
    with pytest.raises(StableMoError, match="rotations"):
        glb_bytes(rig, Animation(rig, np.zeros((3, 3)), np.zeros((3, 3, 4)), 30.0))
    with pytest.raises(StableMoError, match="NaN"):
        glb_bytes(rig, Animation(rig, np.full((3, 3), np.nan), np.tile([1.0, 0, 0, 0], (3, 2, 1)), 30.0))


def test_any_rig_with_rest_rotations_is_bound_where_it_stands(tmp_path):
    """A rig whose bones are turned at rest (a character from another tool): posed at its rest, the
    skinned mesh is exactly where it was bound; posed otherwise, the joints follow the rotations."""
    rig = Rig(("Hips", "LeftUpLeg", "LeftLeg"), (-1, 0, 1), np.array([[0.0, 0, 0], [0.1, -0.05, 0], [0, 0.4, 0]]), {})
    half = np.sqrt(0.5)
    rest = np.array([[1.0, 0, 0, 0], [0, 0, 0, 1.0], [half, half, 0, 0]])  # w-first: a half turn about z, 90 deg about x
    still = Animation(rig, np.tile([0.0, 0.9, 0], (2, 1)), np.stack([rest, rest]), 10.0)
    body = mannequin(rig, {"left": "#1f6fd1", "right": "#d62f2f", "center": "#444444"}, rest, (0.0, 0.9, 0.0))
    data = glb_bytes(rig, still, body, rest_rotations=rest, rest_root=(0.0, 0.9, 0.0))
    doc, world, _ = pose_file(data)
    binary = read_glb(data)[1]
    for prim, verts in zip(doc["meshes"][0]["primitives"], skinned_vertices(data, world)):
        bound = accessor_array(doc, binary, prim["attributes"]["POSITION"])
        assert np.abs(verts - bound).max() < 1e-5
    # the knee (LeftLeg): the hip joint at (0.1, 0.85, 0), turned half round z, puts the knee's 0.4 m
    # +y offset below it
    assert np.allclose(world[0, 2, :3, 3], [0.1, 0.85 - 0.4, 0.0], atol=1e-6)
    if available() is None:
        (tmp_path / "rig.glb").write_bytes(data)
        (report,) = validate([tmp_path / "rig.glb"])
        assert (report["errors"], report["warnings"]) == (0, 0), report["messages"][:5]


def test_the_standing_body_stands_on_the_floor():
    data = standing_glb("humanml3d", colours=COLOURS)
    _, world, times = pose_file(data)
    assert len(times) == 1
    verts = np.concatenate(skinned_vertices(data, world), axis=1)[0]
    assert abs(verts[:, 1].min()) < 0.005  # soles on y = 0
    assert 1.5 < verts[:, 1].max() < 1.9  # a person's height
    from stablemo.bvh.names import rest_joints

    # the rig's rest pose (the page's stick figure before a motion), raised by the sole's thickness
    assert np.abs(world[0, :, :3, 3] - rest_joints("humanml3d") - [0, SOLE, 0]).max() < 1e-5


def test_write_glb_is_fast_and_atomic(tmp_path, walk):
    joints, _ = walk
    long = np.concatenate([joints] * 5)[:196]  # the longest HumanML3D motion, 9.8 s
    start = time.perf_counter()
    write_glb(tmp_path / "w.glb", long, colours=COLOURS)
    took = time.perf_counter() - start
    assert took < 0.5, took  # beside seconds of generation: 50-62 ms measured on the 2 cores at load ~10
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w.glb"]
    with pytest.raises(StableMoError, match="NaN"):
        write_glb(tmp_path / "bad.glb", np.full_like(joints, np.nan))
    assert not (tmp_path / "bad.glb").exists()


@pytest.mark.skipif(available() is not None, reason=str(available()))
def test_the_khronos_validator_finds_nothing_in_any_file_we_write(tmp_path, walk):
    _, data = walk
    files = {"walk.glb": data, "rest.glb": standing_glb("humanml3d", colours=COLOURS), "kit.glb": standing_glb("kit")}
    somersault = heading(flip(2), 200)
    files["flip.glb"] = motion_glb(somersault)[0]
    rig = Rig(("root", "tip"), (-1, 0), np.array([[0.0, 0, 0], [0, 1, 0]]), {})
    files["bones.glb"] = glb_bytes(rig, Animation(rig, np.zeros((2, 3)), np.tile([1.0, 0, 0, 0], (2, 2, 1)), 30.0))
    for name, blob in files.items():
        (tmp_path / name).write_bytes(blob)
    reports = validate(sorted(tmp_path.iterdir()))
    assert len(reports) == len(files)
    for report in reports:
        assert (report["errors"], report["warnings"]) == (0, 0), (report["file"], report["messages"][:5])
    walk_report = next(r for r in reports if r["file"].endswith("walk.glb"))
    assert walk_report["info"]["animationCount"] == 1 and walk_report["info"]["hasSkins"]


@pytest.mark.skipif(available() is not None, reason=str(available()))
def test_the_validator_does_report_a_broken_file(tmp_path, walk):
    _, data = walk
    broken = bytearray(data)
    broken[8:12] = (len(data) + 4).to_bytes(4, "little")  # the header's length is wrong
    (tmp_path / "broken.glb").write_bytes(bytes(broken))
    (report,) = validate([tmp_path / "broken.glb"])
    assert report["errors"] > 0


def test_generate_writes_a_glb_and_fbx_needs_blender(tmp_path, monkeypatch, capsys):
    from stablemo.cli import main

    out = tmp_path / "out"
    student = Path(__file__).resolve().parents[1] / "stablemo" / "assets" / "demo_student"  # 1 step: quick
    assert main(["generate", "a person waves", "--format", "glb", "--frames", "40", "--out", str(out),
                 "--bundle", str(student)]) == 0
    joints = np.load(out / "a-person-waves.joints.npy")
    data = (out / "a-person-waves.glb").read_bytes()
    _, world, times = pose_file(data)
    assert len(times) == len(joints)
    assert np.linalg.norm(world[..., :3, 3] - joints, axis=-1).max() < 1e-4
    if available() is None:  # a generated motion's file is valid too
        (report,) = validate([out / "a-person-waves.glb"])
        assert (report["errors"], report["warnings"]) == (0, 0), report["messages"][:5]
    capsys.readouterr()
    monkeypatch.setattr(shutil, "which", lambda name, *a, **k: None)  # no Blender on PATH
    assert main(["generate", "a person waves", "--format", "fbx", "--out", str(tmp_path / "none")]) != 0
    err = capsys.readouterr().err
    assert err == ("stablemo generate: error: --format fbx: FBX is written through Blender, which is not on PATH "
                   "(Debian/Ubuntu: apt-get install blender); GLB needs nothing\n")
    assert not (tmp_path / "none").exists()  # refused before anything was loaded or written
    feats = str(out / "a-person-waves.features.npy")
    assert main(["edit", feats, "--keep", "lower_body", "--text", "a person waves", "--format", "fbx",
                 "--out", str(tmp_path / "none")]) != 0
    assert capsys.readouterr().err.startswith("stablemo edit: error: --format fbx: FBX is written through Blender")
    assert not (tmp_path / "none").exists()
