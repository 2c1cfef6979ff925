"""`stablemo serve`: the JSON API against offline generation, its errors, its queue, downloads,
the page's assets (nothing from the network) and the vendoring of three.js."""

from __future__ import annotations

import asyncio
import base64
import io
import json
import re
import tarfile
import threading
import urllib.request
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("fastapi")
pytest.importorskip("httpx")  # FastAPI's TestClient

from fastapi.testclient import TestClient

from stablemo.cli import main as cli_main
from stablemo.errors import StableMoError
from stablemo.inference.pipeline import Request
from stablemo.serve import vendor as vendor_mod
from stablemo.serve.api import STATIC_DIR, Busy, Worker, create_app
from stablemo.serve.local import serving
from stablemo.serve.models import ModelSet
from stablemo.timeline import stream_timeline

DEMO = Path(__file__).resolve().parents[1] / "stablemo" / "assets" / "demo_bundle"
TEST_HOSTS = ("testserver",)  # FastAPI's TestClient sends Host: testserver; the server itself never allows it


@pytest.fixture(scope="module")
def models():
    return ModelSet({"teacher": DEMO})


@pytest.fixture(scope="module")
def client(models):
    with TestClient(create_app(models, hosts=TEST_HOSTS)) as c:
        yield c


def offline(models, text, frames, seed, plan=True, **kw):
    """What the server answers: the pipeline with the server's default of planning prompts in parts."""
    pipe = models.models["teacher"].pipeline
    g = pipe.generate(Request([text], frames, seed=seed, plan=plan, **kw))
    return g.joint_list()[0], g.feature_list()[0]


def decode(arr):
    return np.frombuffer(base64.b64decode(arr["base64"]), dtype="<f4").reshape(arr["shape"])


def test_generate_equals_offline_generation(client, models):
    body = {"text": "a person jumps, then turns left", "frames": 44, "seed": 7, "steps": 2}
    res = client.post("/api/generate", json=body)
    assert res.status_code == 200, res.text
    data = res.json()
    joints, feats = offline(models, body["text"], 44, 7, steps=2)
    assert (data["frames"], data["fps"], data["seed"], data["steps"], data["cfg"]) == (44, 20.0, 7, 2, 1.5)
    assert np.array_equal(np.asarray(data["joints"], dtype=np.float32), joints)  # lists: every float32 exact
    assert np.array_equal(np.asarray(data["features"], dtype=np.float32), feats)
    res = client.post("/api/generate", json={**body, "encoding": "base64", "features": False})
    data = res.json()
    assert "features" not in data and data["timing"]["cached"] is True
    assert np.array_equal(decode(data["joints"]), joints)
    # another seed is another motion; seconds are converted at the model's frame rate
    other = client.post("/api/generate", json={**body, "seed": 8, "frames": None, "seconds": 2.2}).json()
    assert other["frames"] == 44 and not np.array_equal(np.asarray(other["joints"], dtype=np.float32), joints)


@pytest.mark.parametrize("body, message", [
    ({"text": "   "}, "text: empty prompt"),
    ({"seconds": 3}, "text: expected a string, got null"),
    ({"text": "walk", "seconds": 30}, "seconds: 30 s is 600 frames, outside this model's range [40, 196] frames"),
    ({"text": "walk", "frames": 12.5}, "frames: expected a whole number"),
    ({"text": "walk", "seconds": 3, "frames": 60}, "seconds: give seconds or frames, not both"),
    ({"text": "walk", "seed": -1}, "seed: must be in [0,"),
    ({"text": "walk", "seed": "1"}, "seed: expected a whole number"),
    ({"text": "walk", "steps": 0}, "steps: must be >= 1"),
    ({"text": "walk", "steps": 5000}, "steps: must be an integer in [1, 1000]"),
    ({"text": "walk", "cfg": -1}, "cfg: must be >= 0"),
    ({"text": "walk", "sampler": "euler"}, "sampler: unknown 'euler'"),
    ({"text": "walk", "model": "other"}, "model: unknown 'other'; served: teacher"),
    ({"text": "walk", "stpes": 3}, "stpes: unknown field"),
    ({"text": "walk", "footskate": "yes"}, "footskate: expected true or false"),
    ({"text": "walk", "encoding": "msgpack"}, "encoding: expected one of lists, base64"),
    ({"text": "x" * 1001}, "text: 1001 characters, at most 1000"),
    ([1, 2], "request: expected a JSON object"),
])
def test_bad_input_is_400_with_one_line(client, body, message):
    res = client.post("/api/generate", json=body)
    assert res.status_code == 400
    error = res.json()["error"]
    assert error.startswith(message) and "\n" not in error


def test_bad_json_and_bad_download_format(client):
    res = client.post("/api/generate", content=b'{"text": "walk",', headers={"Content-Type": "application/json"})
    assert res.status_code == 400 and res.json()["error"].startswith("request: the body is not valid JSON")
    res = client.post("/api/download", json={"text": "walk", "format": "mp3"})
    assert res.status_code == 400 and res.json()["error"].startswith("format: expected one of")


def test_downloads_are_the_shown_motion(client, models, tmp_path):
    body = {"text": "a person waves", "frames": 40, "seed": 2, "steps": 1}
    joints, feats = offline(models, body["text"], 40, 2, steps=1)
    res = client.post("/api/download", json={**body, "format": "joints.npy"})
    assert res.status_code == 200
    assert res.headers["content-disposition"] == 'attachment; filename="a-person-waves-seed2.joints.npy"'
    assert np.array_equal(np.load(io.BytesIO(res.content), allow_pickle=False), joints)
    res = client.post("/api/download", json={**body, "format": "features.npy"})
    assert np.array_equal(np.load(io.BytesIO(res.content), allow_pickle=False), feats)
    res = client.post("/api/download", json={**body, "format": "bvh"})
    assert res.headers["content-disposition"] == 'attachment; filename="a-person-waves-seed2.bvh"'
    (tmp_path / "m.bvh").write_bytes(res.content)
    from stablemo.bvh import forward_kinematics, motion_to_animation, read_bvh
    from stablemo.bvh.names import bvh_names

    anim = read_bvh(tmp_path / "m.bvh")
    fk = forward_kinematics(anim)[:, [anim.rig.names.index(n) for n in bvh_names("humanml3d")]]  # (T, 22, 3)
    lengths = models.models["teacher"].pipeline.finish.bone_lengths  # the bundle's body
    rigid = forward_kinematics(motion_to_animation(joints, skeleton="humanml3d", bone_lengths=lengths))
    assert anim.fps == 20.0 and np.abs(fk - rigid).max() < 1e-5
    # the motion is one rigid body: the file is within the 3 mm mean / 1 cm max of it, so the
    # page is not told otherwise
    err = np.linalg.norm(fk - joints, axis=-1)  # metres
    assert err.mean() < 0.003 and err.max() < 0.01, (err.mean(), err.max())
    assert client.post("/api/generate", json=body).json()["warnings"] == []
    res = client.post("/api/download", json={**body, "format": "gif"})
    assert res.status_code == 200 and res.content[:6] == b"GIF89a"
    from PIL import Image

    assert Image.open(io.BytesIO(res.content)).n_frames == 40


def test_the_glb_download_and_the_standing_body(client, models, monkeypatch):
    """The page's body: the GLB download is the shown motion on our mannequin (stablemo.gltf), the
    rest body stands on the floor; FBX is offered only with Blender and refused in one line without."""
    import shutil

    from test_gltf import pose_file

    body = {"text": "a person waves", "frames": 40, "seed": 2, "steps": 1}
    joints, _ = offline(models, body["text"], 40, 2, steps=1)
    res = client.post("/api/download", json={**body, "format": "glb"})
    assert res.status_code == 200 and res.headers["content-type"] == "model/gltf-binary"
    assert res.headers["content-disposition"] == 'attachment; filename="a-person-waves-seed2.glb"'
    doc, world, times = pose_file(res.content)
    assert len(times) == 40 and len(doc["meshes"][0]["primitives"]) == 3
    assert np.linalg.norm(world[..., :3, 3] - joints, axis=-1).max() < 1e-4
    rest = client.get("/api/rest.glb")
    assert rest.status_code == 200 and rest.content[:4] == b"glTF"
    assert client.get("/api/rest.glb", params={"model": "teacher"}).content == rest.content
    bad = client.get("/api/rest.glb", params={"model": "nope"})
    assert bad.status_code == 400 and bad.json() == {"error": "model: unknown model 'nope'; served: teacher"}
    offered = client.get("/api/info").json()["downloads"]
    assert "glb" in offered and ("fbx" in offered) == (shutil.which("blender") is not None)
    monkeypatch.setattr("stablemo.gltf.fbx.blender_path", lambda: None)
    assert "fbx" not in client.get("/api/info").json()["downloads"]
    res = client.post("/api/download", json={**body, "format": "fbx"})
    assert res.status_code == 400 and res.json()["error"].startswith(
        "format: FBX is written through Blender, which is not on PATH")


def test_generate_says_when_the_bvh_download_would_miss_the_motion(client, monkeypatch, tmp_path):
    import torch

    from stablemo.bvh import forward_kinematics, read_bvh
    from stablemo.bvh.names import bvh_names
    from stablemo.inference.pipeline import Pipeline

    original = Pipeline.generate

    def stretching(self, request):  # bones that grow by 30% over the motion, as the raw network output's
        result = original(self, request)
        grow = 1 + 0.3 * torch.linspace(0, 1, result.joints.shape[1])[None, :, None, None]
        result.joints = result.joints[:, :, :1] + (result.joints - result.joints[:, :, :1]) * grow
        return result

    monkeypatch.setattr(Pipeline, "generate", stretching)
    body = {"text": "a person stretches", "frames": 40, "seed": 91, "steps": 1}
    data = client.post("/api/generate", json=body).json()
    (line,) = data["warnings"]
    assert line.startswith("warning: a-person-stretches-seed91.bvh is up to ") and "the joints .npy download is exact" in line
    # the number in the warning is how far the downloaded file really is from the motion shown
    res = client.post("/api/download", json={**body, "format": "bvh"})
    (tmp_path / "m.bvh").write_bytes(res.content)
    anim = read_bvh(tmp_path / "m.bvh")
    fk = forward_kinematics(anim)[:, [anim.rig.names.index(n) for n in bvh_names("humanml3d")]]
    worst = np.linalg.norm(fk - np.array(data["joints"]), axis=-1).max() * 100
    assert f"is up to {worst:.1f} cm" in line and worst > 3.0


def test_no_page_of_the_server_needs_the_network(client):
    assert client.get("/docs").status_code == 404  # FastAPI's Swagger page loads from a CDN
    assert client.get("/api/openapi.json").status_code == 200
    page = client.get("/").text
    assert "/static/app.js" in page and "importmap" in page


def test_the_demo_student_is_served_by_default_and_equals_offline(tmp_path):
    from stablemo.cli.serve import DEMO_MODELS, bundles_from_args

    assert bundles_from_args(None) == DEMO_MODELS and list(DEMO_MODELS) == ["student", "teacher"]
    student = ModelSet({"student": DEMO_MODELS["student"]})
    with TestClient(create_app(student, hosts=TEST_HOSTS)) as c:
        data = c.post("/api/generate", json={"text": "a person jumps, then turns left", "seed": 11}).json()
        info = c.get("/api/info").json()["models"][0]
    pipe = student.models["student"].pipeline
    # no length asked: the text's own, here its two parts' (tests/test_plan.py)
    frames = sum(pipe.text_lengths(["a person jumps", "a person turns left"]))
    assert (data["steps"], data["sampler"], data["frames"], data["length_from"]) == (1, "lcm", frames, "text")
    assert [p["text"] for p in data["plan"]] == ["a person jumps", "a person turns left"]
    # the turn its words size, over the frames of its part (docs/inference.md, "Turns as said")
    turn = data["plan"][1]
    assert data["turns"] == [{"text": "a person turns left", "degrees": 90.0, "side": "left",
                              "start": turn["start"], "end": turn["end"]}]
    assert info["kind"] == "consistency" and info["label"] == "student (consistency, 1 step)"
    ref = pipe.generate(Request(["a person jumps, then turns left"], seed=11, plan=True)).joint_list()[0]
    assert np.array_equal(np.asarray(data["joints"], dtype=np.float32), ref)


def test_plan_false_gives_the_network_the_prompt_whole(client, models):
    body = {"text": "a person jumps, then turns left", "frames": 60, "seed": 3, "steps": 2, "plan": False}
    data = client.post("/api/generate", json=body).json()
    joints, _ = offline(models, body["text"], 60, 3, plan=False, steps=2)
    assert data["plan"] is None and data["turns"] is None and data["frames"] == 60
    assert np.array_equal(np.asarray(data["joints"], dtype=np.float32), joints)
    planned = client.post("/api/generate", json={**body, "plan": True}).json()
    assert [p["text"] for p in planned["plan"]] == ["a person jumps", "a person turns left"]
    assert planned["frames"] == 60 and planned["plan"][-1]["end"] == 60
    res = client.post("/api/generate", json={**body, "plan": "yes"})
    assert res.status_code == 400 and res.json()["error"] == "plan: expected true or false, got 'yes'"



def test_info_describes_the_model(client):
    info = client.get("/api/info").json()
    assert info["default"] == "teacher"
    (model,) = info["models"]
    assert model["defaults"] == {"sampler": "dpmpp_2m_sde", "steps": 10, "cfg": 1.5}
    assert (model["min_frames"], model["max_frames"], model["fps"]) == (40, 196, 20.0)
    assert len(model["skeleton"]["parents"]) == 22 and model["skeleton"]["sides"].count("center") == 1


def test_concurrent_requests_queue_and_none_is_mixed_up(models):
    """8 requests, 4 at a time, through a real socket: each answer is its own seed's motion."""
    with serving(create_app(models)) as url:
        def post(seed):
            body = json.dumps({"text": "a person runs in a circle", "frames": 40, "seed": seed, "steps": 1,
                               "encoding": "base64"}).encode()
            req = urllib.request.Request(f"{url}/api/generate", body, {"Content-Type": "application/json"})
            with urllib.request.urlopen(req, timeout=60) as res:
                return json.loads(res.read())

        with ThreadPoolExecutor(4) as pool:
            answers = list(pool.map(post, range(100, 108)))
    for seed, data in zip(range(100, 108), answers):
        assert data["seed"] == seed
        assert np.array_equal(decode(data["joints"]), offline(models, "a person runs in a circle", 40, seed, steps=1)[0])


def test_worker_runs_one_job_at_a_time_and_refuses_past_its_queue():
    worker = Worker(max_queue=2, name="test")
    gate, running, peak = threading.Event(), [], []

    def job(i):
        running.append(i)
        peak.append(len(running))
        gate.wait(10)
        running.remove(i)
        return i

    async def scenario():
        first = asyncio.ensure_future(worker.run(job, 1))
        second = asyncio.ensure_future(worker.run(job, 2))
        await asyncio.sleep(0.05)
        with pytest.raises(Busy, match="2 requests are waiting"):
            await worker.run(job, 3)
        gate.set()
        return await asyncio.gather(first, second)

    assert asyncio.run(scenario()) == [1, 2]
    assert max(peak) == 1  # never two generations at once
    worker.shutdown()


def test_page_loads_nothing_from_the_network():
    html = (STATIC_DIR / "index.html").read_text()
    # our own modules: app.js and what it imports by a relative path (body.js)
    modules = {"app.js": (STATIC_DIR / "app.js").read_text()}
    for spec in re.findall(r"from '\./([^']+)'", modules["app.js"]):
        assert (STATIC_DIR / spec).is_file(), spec
        modules[spec] = (STATIC_DIR / spec).read_text()
    assert "body.js" in modules
    for text in (html, *modules.values(), (STATIC_DIR / "style.css").read_text()):
        assert not re.search(r"(https?:)?//[a-z0-9.-]+\.[a-z]{2,}/", text), "an absolute URL in the page"
    imports = json.loads(re.search(r'<script type="importmap">(.*?)</script>', html, re.DOTALL).group(1))["imports"]
    assert all(v.startswith("/static/vendor/") for v in imports.values())
    for js in modules.values():
        for spec in re.findall(r"from '([^'.][^']*)'", js):  # bare names: through the import map
            target = imports.get(spec) or next(v + spec[len(k):] for k, v in imports.items()
                                              if k.endswith("/") and spec.startswith(k))
            rel = target[len("/static/"):]
            assert rel.split("/")[1] == "three"
            assert rel[len("vendor/"):] in vendor_mod.FILES.values()  # vendored by stablemo.serve.vendor


def test_serve_command_says_how_to_get_three_js(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(vendor_mod, "VENDOR_DIR", tmp_path / "vendor")
    assert cli_main(["serve"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "stablemo vendor three" in err and "npm" in err
    import socket

    taken = socket.socket()
    taken.bind(("127.0.0.1", 0))
    taken.listen()
    port = taken.getsockname()[1]
    monkeypatch.setattr(vendor_mod, "missing", lambda *a: None)  # past the vendor check
    for argv, message in ((["serve", "--port", "0"], "--port: must be in [1, 65535]"),
                          (["serve", "--port", str(port)], f"--port: cannot listen on 127.0.0.1:{port}"),
                          (["serve", "--bundle", str(tmp_path / "nope")], "bundle folder not found")):
        assert cli_main(argv) == 2
        assert message in capsys.readouterr().err
    taken.close()


def _fake_npm(tmp_path: Path, payload: bytes) -> Path:
    """An `npm` that 'packs' a tarball with our file names and the given content."""
    tgz = tmp_path / "three.tgz"
    with tarfile.open(tgz, "w:gz") as tar:
        for member in vendor_mod.FILES:
            info = tarfile.TarInfo(member)
            info.size = len(payload)
            tar.addfile(info, io.BytesIO(payload))
    npm = tmp_path / "npm"
    npm.write_text(f'#!/bin/sh\n# args: pack three@VERSION --silent --pack-destination DIR\ncp {tgz} "$5/three-{vendor_mod.THREE_VERSION}.tgz"\n')
    npm.chmod(0o755)
    return npm


def test_vendor_refuses_a_tarball_that_is_not_the_pinned_release(tmp_path):
    npm = _fake_npm(tmp_path, b"export const tampered = 1;\n")
    with pytest.raises(StableMoError, match="integrity sha512-.* is not the pinned"):
        vendor_mod.vendor(tmp_path / "vendor", npm=str(npm))
    assert not (tmp_path / "vendor").exists()  # nothing half-vendored
    assert "not vendored" in vendor_mod.missing(tmp_path / "vendor")


def test_vendor_copies_the_pinned_files(tmp_path, monkeypatch):
    payload = b"// stand-in\n"
    npm = _fake_npm(tmp_path, payload)
    tgz = (tmp_path / "three.tgz").read_bytes()
    import hashlib

    monkeypatch.setattr(vendor_mod, "THREE_INTEGRITY", "sha512-" + base64.b64encode(hashlib.sha512(tgz).digest()).decode())
    out = vendor_mod.vendor(tmp_path / "vendor", npm=str(npm))
    assert vendor_mod.missing(out) is None
    assert all((out / dest).read_bytes() == payload for dest in vendor_mod.FILES.values())


def test_joint_control_reaches_the_targets_and_equals_offline(client, models):
    """A pelvis path (every frame) and one right-wrist keyframe, as the page sends them."""
    from stablemo.control import JointControl

    frames = 60
    path = [[f, 0, 0.02 * f, 0.95, 0.0] for f in range(frames)]  # walk 1.2 m along +x (sideways to the start)
    wrist = [30, 21, 0.9, 1.6, 0.3]
    body = {"text": "a person walks forward", "frames": frames, "seed": 4, "control": {"targets": path + [wrist]}}
    data = client.post("/api/generate", json=body).json()
    joints = np.asarray(data["joints"], dtype=np.float32)
    free = np.asarray(client.post("/api/generate", json={**body, "control": None}).json()["joints"], dtype=np.float32)
    target = np.array([p[2:] for p in path])
    assert np.linalg.norm(joints[:, 0] - target, axis=-1).mean() < 0.05  # the pelvis follows the path
    assert np.linalg.norm(free[:, 0] - target, axis=-1).mean() > 0.2  # and would not without it
    assert data["control"]["targets"] == frames + 1
    assert data["control"]["mean_error_m"] == pytest.approx(
        np.linalg.norm(np.concatenate([joints[:, 0] - target, joints[30, 21][None] - wrist[2:]]), axis=-1).mean(), abs=1e-5)
    positions, mask = np.zeros((frames, 22, 3), np.float32), np.zeros((frames, 22), bool)
    for f, j, *xyz in path + [wrist]:
        positions[f, j], mask[f, j] = xyz, True
    ref, _ = offline(models, body["text"], frames, 4, control=[JointControl(positions, mask)])
    assert np.array_equal(joints, ref)


def test_a_path_faster_than_a_body_follows_gets_a_note_instead_of_reached(client):
    def path(speed):  # a straight pelvis path along +x at `speed` m/s over 40 frames
        return [[f, 0, speed * f / 20, 0.95, 0.0] for f in range(40)]

    slow = client.post("/api/generate", json={"text": "a person walks forward", "frames": 40, "steps": 2,
                                              "control": {"targets": path(1.0)}}).json()["control"]
    assert slow["pace_m_s"] == pytest.approx(1.0) and slow["limit_m_s"] == 3.0
    assert slow["note"] is None and slow["max_error_m"] < 0.03
    fast = client.post("/api/generate", json={"text": "a person walks forward", "frames": 40, "steps": 2,
                                              "control": {"targets": path(5.0)}}).json()["control"]
    assert fast["pace_m_s"] == pytest.approx(5.0)
    assert fast["note"].startswith("too fast to follow: the targets ask for 5.0 m/s, more than a body keeps up (3 m/s")
    # a keyframe far from where the body can get in time: the right wrist 4 m away half a second in
    key = client.post("/api/generate", json={"text": "a person waves", "frames": 40, "steps": 2,
                                             "control": {"targets": [[10, 21, 4.0, 1.2, 0.0]]}}).json()["control"]
    assert key["pace_m_s"] > 3.0 and key["note"].startswith("too fast to follow")


@pytest.mark.parametrize("control, message", [
    ({"points": []}, 'control: expected {"targets"'),
    ({"targets": [[0, 0, 1.0, 2.0]]}, "control.targets[0]: expected [frame, joint, x, y, z]"),
    ({"targets": [[60, 0, 0, 1, 0]]}, "control.targets[0]: frame must be a whole number in [0, 59], got 60"),
    ({"targets": [[1, 22, 0, 1, 0]]}, "control.targets[0]: joint must be a whole number in [0, 21], got 22"),
    ({"targets": [[1, 3, 0, "a", 0]]}, "control.targets[0]: position: expected a number"),
    ({"targets": [[1, 3, 0, 1, 0], [1, 3, 0, 1, 1]]}, "control.targets[1]: frame 1, joint 3 is given twice"),
    ({"targets": [[0, 0, 1.0, 0.9, 0.0]]}, "control.positions: the root at frame 0 is at x=1.000"),
])
def test_bad_control_is_400_with_one_line(client, control, message):
    res = client.post("/api/generate", json={"text": "walk", "frames": 60, "control": control})
    assert res.status_code == 400 and res.json()["error"].startswith(message), res.json()


def test_timeline_streams_whole_prompts_in_chunks_and_downloads_what_it_streamed(client, models):
    # the page's shorthand, converted: 3 s of walking, then 2.5 s of jumping
    body = {"timeline": "# a walk, then a jump\n3 a person walks forward\n2.5 a person jumps  # high\n",
            "chunk_seconds": 2, "seed": 5, "steps": 2, "encoding": "base64"}
    with client.stream("POST", "/api/stream", json=body) as res:
        assert res.status_code == 200 and res.headers["content-type"].startswith("application/x-ndjson")
        lines = [json.loads(line) for line in res.iter_lines() if line]
    head, chunks, last = lines[0], lines[1:-1], lines[-1]
    assert head["timeline"] == "# a walk, then a jump\n0 3 a person walks forward\n3 5.5 a person jumps  # high\n"
    assert head["segments"] == [{"start_s": 0.0, "end_s": 3.0, "text": "a person walks forward"},
                                {"start_s": 3.0, "end_s": 5.5, "text": "a person jumps"}]
    # chunks never straddle two prompts: 3 s = 2 + 1, 2.5 s = 2 + 0.5
    assert head["texts"] == ["a person walks forward"] * 2 + ["a person jumps"] * 2
    assert [(c["start"], c["frames"]) for c in chunks] == [(0, 40), (40, 20), (60, 40), (100, 10)]
    assert (head["chunks"], head["frames"], last["done"]) == (4, 110, True)
    pipe = models.models["teacher"].pipeline
    offline = stream_timeline(pipe, [(0, 3, "a person walks forward"), (3, 5.5, "a person jumps")], chunk_seconds=2,
                              seed=5, steps=2)
    for line, ref in zip(chunks, offline.chunks, strict=True):
        assert (line["index"], line["start"], line["text"]) == (ref.index, ref.start, ref.text)
        assert np.array_equal(decode(line["joints"]), ref.joints)
    streamed = np.concatenate([decode(c["joints"]) for c in chunks])  # (110, 22, 3)

    # the streamed motion downloads as it was received (from the cache of recent motions) ...
    res = client.post("/api/download", json={**body, "format": "joints.npy"})
    assert res.status_code == 200, res.text
    assert 'filename="timeline-a-person-walks-forward-a-person-jumps-seed5.joints.npy"' in res.headers["content-disposition"]
    assert np.array_equal(np.load(io.BytesIO(res.content)), streamed)
    bvh = client.post("/api/download", json={**body, "format": "bvh"})
    assert bvh.status_code == 200 and bvh.content.startswith(b"HIERARCHY") and "\nFrames: 110\n" in bvh.text
    # its features file recovers to the joints received (one global frame, from the origin)
    feats = np.load(io.BytesIO(client.post("/api/download", json={**body, "format": "features.npy"}).content))
    from stablemo.motion import features_to_joints

    back = features_to_joints(torch.from_numpy(feats.astype(np.float64))).numpy()
    assert feats.shape == (110, 263) and np.abs(back - streamed).max() < 1e-3
    # ... and gives the same arrays when it was never streamed (another server: an empty cache)
    with TestClient(create_app(ModelSet({"teacher": DEMO}), hosts=TEST_HOSTS)) as other:
        again = other.post("/api/download", json={**body, "format": "joints.npy"})
    assert again.status_code == 200 and np.array_equal(np.load(io.BytesIO(again.content)), streamed)


def test_a_timeline_line_with_two_times_is_never_a_prompt(models):
    job = models.parse_stream({"timeline": "0 5 a person walks\n5 10 a person jumps\n"})
    assert [(s["start_s"], s["end_s"], s["text"]) for s in job.header()["segments"]] == \
        [(0.0, 5.0, "a person walks"), (5.0, 10.0, "a person jumps")]
    # the docs' example file is a timeline the API reads as it is
    example = (Path(__file__).resolve().parents[1] / "docs" / "data" / "long_motion" / "example.txt").read_text()
    job = models.parse_stream({"timeline": example})
    assert job.timeline == example and job.frames == 600 and len(job.header()["segments"]) == 6


@pytest.mark.parametrize("body, message", [
    ({"timeline": []}, "timeline: expected the timeline's text"),
    ({"timeline": [{"text": "walk", "seconds": 2}]}, "timeline: expected the timeline's text"),
    ({"timeline": "  \n"}, "timeline: expected the timeline's text"),
    ({"timeline": "0 2 walk\n3 4 jump"}, "timeline:2: starts at 3 s, leaving a gap"),
    ({"timeline": "2 walk\n0 3 jump"}, "timeline:2: starts at 0 s, overlapping"),
    ({"timeline": "walk"}, "timeline:1: expected 'start_s end_s text'"),
    ({"timeline": "-2 walk"}, "timeline:1: a line '<seconds> <prompt>' needs seconds > 0"),
    ({"timeline": "0 400 walk"}, "timeline: 400 s in all, at most 300 s"),
    ({"timeline": "4 walk", "chunk_seconds": 0.1}, "chunk_seconds: 0.1 s is 2 frames"),
    ({"timeline": "4 walk", "steps": 0}, "steps: must be >= 1"),
    ({"timeline": "4 walk", "format": "bvh"}, "format: unknown field"),
])
def test_bad_timeline_is_400_before_any_chunk(client, body, message):
    res = client.post("/api/stream", json=body)
    assert res.status_code == 400 and res.json()["error"].startswith(message), res.json()


def test_a_streamed_download_checks_its_format_first(client):
    res = client.post("/api/download", json={"timeline": "0 300 walk", "format": "mp4"})
    assert res.status_code == 400 and res.json()["error"].startswith("format: expected one of")
