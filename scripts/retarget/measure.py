"""Retargeting report (docs/retarget.md): the issue's targets on rigs of other sizes, names and rest
poses, the round trip onto our own rig, the time for a 10-s motion, and the figure.

Motions: a synthetic walk and jump (stablemo.data.synth), the demo model's walk, and the real
HumanML3D clip 012314 (when ../shared has it). Rigs: our body (each motion's own, as `stablemo bvh`
writes it) scaled 0.8x and 1.25x with other names and A-pose arms; the same with only the legs
scaled; the Rigify human metarig made by Blender (when installed).

    OMP_NUM_THREADS=1 .venv/bin/python scripts/retarget/measure.py [--no-blender]
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT.parent / "shared" / "data" / "humanml3d-sample" / "new_joints" / "012314.npy"
OUT = ROOT / "docs" / "data" / "retarget"

RIGS = [  # label, convention, legs, arms, scale, A-pose degrees, units
    ("0.8x Mixamo A-pose (cm)", "mixamo", 1.0, 1.0, 0.8, 45.0, "cm"),
    ("1.25x Unreal A-pose (cm)", "unreal", 1.0, 1.0, 1.25, 45.0, "cm"),
    ("legs 0.8x, VRM A-pose", "vrm", 0.8, 1.0, 1.0, 40.0, "m"),
    ("legs 1.25x, SMPL-X A-pose", "smplx", 1.25, 1.0, 1.0, 40.0, "m"),
]


def motions() -> dict[str, np.ndarray]:
    from stablemo.bench.motions import synth_joints
    from stablemo.inference.bundle import DEMO_BUNDLE
    from stablemo.inference.pipeline import Pipeline

    out = {"synth walk": synth_joints("walk", 3), "synth jump": synth_joints("jump", 3)}
    gen = Pipeline.from_bundle(DEMO_BUNDLE).generate(["a person walks forward"], 196, seed=0, steps=4)
    out["demo model walk"] = gen.joints[0].double().numpy()
    if SAMPLE.is_file():
        out["HumanML3D 012314"] = np.load(SAMPLE).astype(np.float64)
    return out


def rigify(tmp: Path):
    from stablemo.bench.blender import MAKE_RIGS, blender, custom_spec
    from stablemo.bench.motions import synth_joints
    from stablemo.io import write_text

    write_text(tmp / "spec.json", json.dumps(custom_spec(synth_joints("walk", 3))))
    blender(MAKE_RIGS, tmp, str(tmp), str(tmp / "spec.json"))
    return tmp / "metarig.bvh" if (tmp / "metarig.bvh").is_file() else None  # None: a Blender without Rigify


def row(solved) -> dict:
    from stablemo.retarget.measure import report

    r = report(solved)
    return {"stance_target_cm_s": round(100 * r["stance"]["target_m_s"], 2),
            "stance_source_cm_s": round(100 * r["stance"]["source_m_s"], 2),
            "reach_mean_pct": round(100 * r["reach"]["mean"], 3), "reach_max_pct": round(100 * r["reach"]["max"], 2),
            "hands_unreachable_pct": round(100 * r["reach"]["unreachable"], 2),
            "flipped_frames": sum(v for k, v in r["flipped"].items() if k != "bent"), "bent_frames": r["flipped"]["bent"],
            "heading_max_deg": round(r["heading_deg"], 4), "scale": round(r["scale"], 4)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--no-blender", action="store_true")
    args = p.parse_args(argv)
    from stablemo.bvh import motion_to_animation, write_bvh
    from stablemo.bvh.names import bvh_names
    from stablemo.retarget import retarget
    from stablemo.retarget.variants import variant_rig

    results: dict = {"targets": {}, "round_trip_mm": {}, "speed": {}}
    scratch = tempfile.TemporaryDirectory(prefix="stablemo-retarget-")  # removed when the script ends
    tmp = Path(scratch.name)
    metarig = rigify(tmp) if not args.no_blender and shutil.which("blender") else None
    found = motions()
    for label, joints in found.items():
        body = motion_to_animation(joints).rig.offsets
        rows = {}
        for name, convention, legs, arms, scale, a_pose, units in RIGS:
            rig, _ = variant_rig(convention, legs, arms, scale, a_pose, units, body=body)
            rows[name] = row(retarget(joints, rig))
        if metarig is not None:
            rows["Rigify metarig (Blender, z up)"] = row(retarget(joints, metarig))
        results["targets"][label] = rows
        write_bvh(tmp / "own.bvh", joints)
        solved = retarget(joints, tmp / "own.bvh")
        order = [solved.target.names.index(n) for n in bvh_names("humanml3d")]
        err = np.linalg.norm(solved.positions[:, order] - joints, axis=-1)
        results["round_trip_mm"][label] = {"mean": round(1000 * float(err.mean()), 4), "max": round(1000 * float(err.max()), 3)}
        print(label, json.dumps(rows), results["round_trip_mm"][label], flush=True)
    # a 10-s motion (200 frames at 20 fps) onto a 0.8x Mixamo rig with fingers and twist bones
    walk = found["synth walk"]
    ten = np.concatenate([walk] * int(np.ceil(200 / len(walk))))[:200]
    rig, _ = variant_rig("mixamo", scale=0.8, a_pose_deg=45, units="cm", body=motion_to_animation(walk).rig.offsets)
    retarget(ten, rig)
    times = []
    for _ in range(20):
        start = time.perf_counter()
        retarget(ten, rig)
        times.append(time.perf_counter() - start)
    results["speed"] = {"frames": 200, "joints": rig.num_joints, "median_ms": round(1000 * float(np.median(times)), 1),
                        "min_ms": round(1000 * float(np.min(times)), 1)}
    print("10-s motion:", results["speed"])
    OUT.mkdir(parents=True, exist_ok=True)
    from stablemo.io import write_text

    write_text(OUT / "measure.json", json.dumps(results, indent=1) + "\n")
    figure(found["synth walk"][:41], metarig, OUT / "retarget.png")  # its first 2 s
    return 0


def figure(joints: np.ndarray, metarig, path: Path) -> None:
    """Side views (z forward, y up, one scale) of the source and of retargeted rigs at three moments."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stablemo.bvh import motion_to_animation
    from stablemo.motion.skeleton import HUMANML3D
    from stablemo.retarget import retarget
    from stablemo.retarget.variants import variant_rig

    body = motion_to_animation(joints).rig.offsets
    panels = [("source (HumanML3D joints)", None)]
    for name, convention, legs, arms, scale, a_pose, units in (RIGS[0], RIGS[1], RIGS[3]):
        panels.append((name, variant_rig(convention, legs, arms, scale, a_pose, units, body=body)[0]))
    if metarig is not None:
        panels.append(("Rigify metarig (Blender)", metarig))
    frames = np.linspace(0, len(joints) - 1, 3).astype(int)
    fig, axes = plt.subplots(1, len(panels), figsize=(2.9 * len(panels), 3.2), sharey=True)
    for ax, (name, rig) in zip(axes, panels):
        if rig is None:
            pos, parents, per_metre = joints, HUMANML3D.parents, 1.0
            feet, hips = [7, 8, 10, 11], 0
        else:
            solved = retarget(joints, rig)
            pos = solved.positions @ solved.axes  # y up for the drawing
            parents = solved.target.parents
            per_metre = 100.0 if "cm" in name else 1.0
            feet = [solved.roles.sides[s][r] for s in ("Left", "Right") for r in ("Foot", "Toes")]
            hips = solved.roles.hips
        pos = pos / per_metre
        for f, shade in zip(frames, (0.35, 0.65, 1.0)):
            for j, p in enumerate(parents):
                if p >= 0:
                    ax.plot(pos[f, [p, j], 2], pos[f, [p, j], 1], color=(0.1, 0.2, 0.6, shade), lw=1.2)
        for k in feet:
            ax.plot(pos[:, k, 2], pos[:, k, 1], color="tab:orange", lw=0.6)
        ax.plot(pos[:, hips, 2], pos[:, hips, 1], color="tab:green", lw=0.8)
        ax.set_title(name, fontsize=8)
        ax.set_xlim(-0.3, 3.6)  # one scale for every panel: the bodies' sizes compare
        ax.set_ylim(-0.05, 2.0)
        ax.set_aspect("equal")
        ax.axhline(0.0, color="grey", lw=0.5)
        ax.tick_params(labelsize=6)
        ax.set_xlabel("forward (m)", fontsize=7)
    axes[0].set_ylabel("up (m)", fontsize=7)
    fig.suptitle("2 s of a synthetic walk retargeted (3 moments, darker later; orange: ankles and toes, green: hips)",
                 fontsize=9)
    fig.tight_layout()
    from stablemo.outputs.render import save_png

    save_png(fig, path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
