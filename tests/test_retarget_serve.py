"""POST /api/retarget: the generated motion on the rig a client sends (BVH text), and one-line 400s
for rigs that are not humanoid, before any motion is made."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("fastapi")
pytest.importorskip("httpx")  # FastAPI's TestClient

from fastapi.testclient import TestClient

from stablemo.retarget.variants import rig_bvh, variant_rig
from stablemo.serve.api import create_app
from stablemo.serve.models import ModelSet

DEMO = Path(__file__).resolve().parents[1] / "stablemo" / "assets" / "demo_bundle"


@pytest.fixture(scope="module")
def client():
    with TestClient(create_app(ModelSet({"teacher": DEMO}), hosts=("testserver",))) as c:
        yield c


def test_the_motion_comes_back_on_the_clients_rig(client, tmp_path):
    from stablemo.bvh import forward_kinematics, read_bvh
    from stablemo.retarget import retarget

    rig, _ = variant_rig("unreal", scale=1.2, a_pose_deg=45, units="cm")
    body = {"text": "a person walks forward", "frames": 60, "seed": 3}
    r = client.post("/api/retarget", json={**body, "rig": rig_bvh(rig)})
    assert r.status_code == 200, r.text
    assert r.headers["content-disposition"].endswith('-retarget.bvh"')
    (tmp_path / "out.bvh").write_bytes(r.content)
    anim = read_bvh(tmp_path / "out.bvh")
    assert anim.rig.names[0] == "root" and "thigh_l" in anim.rig.names and anim.num_frames == 60
    # the same motion retargeted here gives the same file's joints
    joints = np.array(client.post("/api/generate", json={**body, "features": False}).json()["joints"])
    want = retarget(joints, rig).positions
    got = forward_kinematics(anim)
    order = [anim.rig.names.index(n) for n in rig.names]
    assert np.abs(got[:, order] - want).max() < 0.05  # cm: the file's 6 decimals and the float32 joints


def test_bad_rigs_are_one_line_400s_naming_the_field(client):
    rig, _ = variant_rig("mixamo", extras=False)
    no_hands = rig_bvh(rig).replace("mixamorig:LeftHand", "mixamorig:Prop1").replace("mixamorig:RightHand", "mixamorig:Prop2")
    body = {"text": "a person walks forward", "frames": 40}
    cases = [
        ({**body}, "rig: missing"),
        ({**body, "rig": 3}, "rig: expected the text of a BVH file"),
        ({**body, "rig": "HIERARCHY\nROOT x\n"}, "rig: no MOTION section"),
        ({**body, "rig": no_hands}, "rig: not a humanoid rig that can be retargeted: no joint found for LeftHand, RightHand"),
        ({**body, "rig": rig_bvh(rig), "rig_map": {"LeftPaw": "x"}}, "rig_map: unknown role(s) ['LeftPaw']"),
        ({**body, "rig": rig_bvh(rig), "frames": -1}, "frames"),
    ]
    for request, message in cases:
        r = client.post("/api/retarget", json=request)
        assert r.status_code == 400 and r.json()["error"].startswith(message), (message, r.text)
    r = client.post("/api/retarget", json={**body, "rig": no_hands, "rig_map": {"LeftHand": "mixamorig:Prop1",
                                                                                "RightHand": "mixamorig:Prop2"}})
    assert r.status_code == 200, r.text
