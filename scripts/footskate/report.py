"""Measure foot-skate removal on a model's generations: plain vs post-process vs inside denoising.

    python scripts/footskate/report.py [--bundle stablemo/assets/demo_bundle] [--num 32] [--frames 196]
        [--steps 10 --cfg 2.5 --seed 0] [--threads 1] [--json outputs/footskate_report.json]

One batch of prompts is generated once; the same motions are then cleaned by the stand-alone
post-process (`stablemo footskate`, features in -> consistent features out) and generated again
with the correction inside the last denoising steps (`stablemo generate --footskate`). Skating
ratio (GMD definition), PhysDiff ground sliding and floating, the feet's mean acceleration
(jitter) and the height of the lowest foot joint on contact frames (contacts as the cleanup finds
them on its input) are read from the joints recovered from each row's *features*. Every row is the
network's own output (`finish=False`): the finishing step that puts each generation on the
bundle's body and the floor (stablemo.inference.finish) is not applied. For the post-process the
script also reports anchor drift inside contact ranges, the vertical placement on the floor
(`floor_offset`), movement of the non-foot joints (with and without that placement),
bone-length change and the cleanup's wall time for the whole batch.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from footskate.cleanup import detect_contacts
from stablemo.errors import run_script
from stablemo.skating.metrics import foot_skating_ratio, ground_metrics
from stablemo.inference.hooks import make_hooks
from stablemo.skating.cleanup import (topology, clean_features, load_vgrf_model,
                                         standard_joints)
from stablemo.io import write_text
from stablemo.motion import canonicalize_joints, features_to_joints
from stablemo.inference.pipeline import Pipeline
from stablemo.inference.config import PAPER_CFG, PAPER_STEPS

PROMPTS = [
    "a person walks forward", "a person walks forward slowly", "a person jogs forward",
    "a person walks forward and turns left", "a person walks forward and turns right",
    "a person walks in a circle", "a person walks backwards", "a person side steps to the left",
    "a person runs forward", "a person walks forward and waves", "a person walks forward then stops",
    "a person jumps forward", "a person walks and kicks", "a person crouches and walks forward",
    "a person jumps in place twice", "a person stands and claps",
]


def bone_lengths(joints: torch.Tensor, parents) -> torch.Tensor:
    """joints (B, T, J, 3) -> (B, T, J-1)"""
    return (joints[..., 1:, :] - joints[..., list(parents[1:]), :]).norm(dim=-1)


def foot_acceleration(joints: torch.Tensor, lengths: torch.Tensor, topo) -> float:
    """Mean |second difference| of the foot joints' positions (ankles and toes), m/s², over valid
    frames: a correction that plants feet by making them jitter shows up here."""
    feet = joints[:, :, list(topo.feet)]                                     # (B, T, 4, 3)
    fps = topo.fps
    acc = (feet[:, 2:] - 2 * feet[:, 1:-1] + feet[:, :-2]).abs() * fps * fps  # (B, T-2, 4, 3)
    valid = torch.arange(joints.shape[1] - 2)[None] < (lengths - 2)[:, None]
    return float(acc[valid].mean())


def row(joints: torch.Tensor, lengths: torch.Tensor, topo, contacts: torch.Tensor) -> dict:
    """joints (B, T, J, 3); contacts (B, T, 4) of the feet (padding False)."""
    ratio = foot_skating_ratio(joints, lengths=lengths)
    ground = ground_metrics(joints, lengths=lengths)
    y = joints[:, :, list(topo.feet), 1].float()
    lowest = torch.minimum(y[..., 0::2], y[..., 1::2])                      # (B, T, 2) per foot
    planted = lowest[contacts[..., 0::2] | contacts[..., 1::2]]
    return {"skating_ratio": float(ratio.mean()), "sliding_m": float(np.mean(ground["sliding"])),
            "floating_m": float(np.mean(ground["floating"])),
            "foot_acceleration": foot_acceleration(joints.float(), lengths, topo),
            "planted_height_mean_m": float(planted.mean()), "planted_height_median_m": float(planted.median()),
            "planted_height_p95_m": float(planted.quantile(0.95))}


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bundle", default="stablemo/assets/demo_bundle")
    p.add_argument("--num", type=int, default=32)
    p.add_argument("--frames", type=int, default=196)
    p.add_argument("--steps", type=int, default=PAPER_STEPS)
    p.add_argument("--cfg", type=float, default=PAPER_CFG)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--json", default=None, help="also write the numbers here")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)

    pipe = Pipeline.from_bundle(args.bundle)
    texts = [PROMPTS[i % len(PROMPTS)] for i in range(args.num)]
    frames = min(max(args.frames, pipe.min_length), pipe.max_length)
    lengths = torch.full((args.num,), frames)
    seeds = [args.seed + i for i in range(args.num)]
    gen = dict(steps=args.steps, cfg=args.cfg, seed=seeds)

    # the network's own output (finish=False): the finishing step that puts every generation on the
    # bundle's body and the floor (stablemo.inference.finish) would be measured along with the cleanup
    plain = pipe.generate(texts, lengths.tolist(), finish=False, **gen)
    joints_plain = features_to_joints(plain.features)                      # (B, T, J, 3)

    topo = topology(pipe.skeleton)
    vgrf = load_vgrf_model(None, pipe.skeleton)
    clean_features(plain.features[:2], [frames] * 2, pipe.skeleton, vgrf)  # warm-up (first-call allocations)
    started = time.perf_counter()
    feats_post, joints_post, info = clean_features(plain.features, lengths.tolist(), pipe.skeleton, vgrf)
    post_seconds = time.perf_counter() - started
    recovered_post = features_to_joints(feats_post)  # tensors in, tensors out (batched torch path)

    started = time.perf_counter()
    hooks = make_hooks(pipe, footskate=True)  # [FootskateHook]; it records each call's info
    inside = pipe.generate(texts, lengths.tolist(), hooks=hooks, finish=False, **gen)
    inside_seconds = time.perf_counter() - started
    joints_inside = features_to_joints(inside.features)

    # the cleanup starts from the motion on the standard skeleton and floor (clean_features'
    # standardize step); movement, bone lengths and contacts are measured on that input
    standard = standard_joints(joints_plain, lengths, pipe.skeleton)
    contacts = detect_contacts(standard, lengths, list(topo.feet), topo.fps, 1, vgrf, gate=True)[0]  # (B, T, 4)
    feet = set(topo.feet) | {j for j in range(topo.num_joints) if j in _leg_chain(topo)}
    others = [j for j in range(topo.num_joints) if j not in feet]
    moved = (joints_post - standard)[:, :, others].norm(dim=-1)         # (B, T, J')
    lift = torch.tensor(info["floor_offset"])                            # (B,) metres moved down
    posed = joints_post.clone()
    posed[..., 1] += lift[:, None, None]
    moved_posed = (posed - standard)[:, :, others].norm(dim=-1)         # beyond the vertical placement
    bones = (bone_lengths(joints_post, topo.parents) - bone_lengths(standard, topo.parents)).abs()
    placed = torch.from_numpy(canonicalize_joints(joints_post.numpy(), pipe.skeleton, refit=False)).float()
    feature_error = (recovered_post - placed).norm(dim=-1)                # the extraction's rigid placement
    drift = info["anchor_drift"]
    report = {
        "bundle": args.bundle, "num": args.num, "frames": frames, "steps": args.steps, "cfg": args.cfg,
        "seed": args.seed, "threads": args.threads,
        "plain": row(joints_plain, lengths, topo, contacts),
        "plain_on_standard_skeleton": row(standard, lengths, topo, contacts),
        "post_process": {**row(recovered_post, lengths, topo, contacts),
                         "on_corrected_joints": row(joints_post, lengths, topo, contacts),
                         "anchored_ranges": info["anchored_ranges"], "ranges": info["ranges"],
                         "anchor_drift_mean_m": drift["mean"], "anchor_drift_p95_m": drift["p95"],
                         "floor_offset_mean_m": float(lift.mean()), "floor_offset_max_m": float(lift.max()),
                         "non_foot_moved_mean_m": float(moved.mean()),
                         "non_foot_moved_beyond_placement_mean_m": float(moved_posed.mean()),
                         "non_foot_moved_beyond_placement_max_m": float(moved_posed.max()),
                         "bone_length_change_max_m": float(bones.max()),
                         "features_vs_corrected_joints_max_m": float(feature_error.max()),
                         "seconds_wall": post_seconds},
        "inside_denoising": {**row(joints_inside, lengths, topo, contacts), "seconds_wall_generation": inside_seconds,
                             "hook_seconds": [c["seconds"] for c in hooks[0].calls]},
    }
    base = report["plain"]["skating_ratio"]
    base_std = report["plain_on_standard_skeleton"]["skating_ratio"]  # the re-extracted baseline
    for key in ("post_process", "inside_denoising"):
        report[key]["reduction"] = 1.0 - report[key]["skating_ratio"] / base if base > 0 else 0.0
        report[key]["reduction_vs_re_extracted"] = 1.0 - report[key]["skating_ratio"] / base_std if base_std > 0 else 0.0
    print(json.dumps(report, indent=2))
    if args.json:
        write_text(Path(args.json), json.dumps(report, indent=2) + "\n")
    return report


def _leg_chain(topo) -> set[int]:
    """The feet and their ancestors below the hips: the joints the cleanup is allowed to bend."""
    from footskate.cleanup import leg_joints

    legs = set(leg_joints(list(topo.parents), list(topo.feet)))
    return legs | {topo.parents[j] for j in legs if topo.parents[j] > 0}


if __name__ == "__main__":
    sys.exit(run_script(main, "/".join(Path(__file__).parts[-2:]), sys.argv[1:]))
