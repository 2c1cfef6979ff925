"""Rendered examples of every control and editing mode for docs/control.md (strips with the targets).

    python scripts/control/examples.py --data data/synth --out docs/data/control

Sources are test-split motions of the synthetic benchmark (never seen in training); each example
prints its error at the targets (control) or at the kept entries (editing), and the largest
root/foot acceleration near the targets against the source motion's own largest.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch


def _source(data: Path, pick: str) -> tuple[np.ndarray, str]:
    """The first test motion whose captions contain `pick`: (features (T, D), first caption)."""
    for clip in (data / "test.txt").read_text().split():
        lines = (data / "texts" / f"{clip}.txt").read_text().splitlines()
        if any(pick in line.split("#")[0] for line in lines):
            feats = np.load(data / "new_joint_vecs" / f"{clip}.npy")
            return feats[:196].astype(np.float32), lines[0].split("#")[0]
    raise SystemExit(f"no test motion mentions {pick!r}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bundle", default="stablemo/assets/demo_bundle")
    p.add_argument("--data", default="data/synth")
    p.add_argument("--out", default="docs/data/control")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    torch.set_num_threads(1)

    from stablemo.control import Inpaint
    from stablemo.control.files import control_from_joints, density_frames
    from stablemo.control.parts import keep_mask
    from stablemo.io import check_output_dir
    from stablemo.motion import features_to_joints
    from stablemo.inference.pipeline import Pipeline
    from stablemo.outputs.render import render_strip

    out = check_output_dir(args.out, "--out")
    pipe = Pipeline.from_bundle(args.bundle)
    data = Path(args.data)
    circle, circle_text = _source(data, "circle")
    jump, jump_text = _source(data, "jump")
    circle_j = features_to_joints(circle)
    jump_j = features_to_joints(jump)

    def show(name, joints, title, targets=None, frames=None):
        render_strip(joints, out / f"{name}.png", pipe.skeleton, num_frames=7, title=title, targets=targets,
                     frames=frames)

    T = len(circle)
    examples = {
        "pelvis_dense": ("a person walks forward", control_from_joints(circle_j, [0], density_frames("100%", T)), circle_text),
        "pelvis_sparse": ("a person walks forward", control_from_joints(circle_j, [0], density_frames("5", T)), circle_text),
        "wrist_25": ("a person waves with the right hand", control_from_joints(circle_j, [21], density_frames("25%", T)),
                     circle_text),
    }
    for name, (text, spec, src_text) in examples.items():
        res = pipe.generate([text], T, seed=args.seed, control=spec)
        joints = res.joint_list()[0]
        err = np.linalg.norm(joints - spec.positions, axis=-1)[spec.mask]
        show(name, joints, f'"{text}" + {name.replace("_", " ")} targets from "{src_text}"', (spec.positions, spec.mask))
        print(f"{name}: mean error {err.mean() * 100:.2f} cm, max {err.max() * 100:.2f} cm")

    Tj = len(jump)
    keys = [0, Tj // 3, 2 * Tj // 3, Tj - 1]
    spec = control_from_joints(jump_j, list(range(22)), np.isin(np.arange(Tj), keys))
    res = pipe.generate(["a person walks forward"], Tj, seed=args.seed, control=spec)
    joints = res.joint_list()[0]
    err = np.linalg.norm(joints - spec.positions, axis=-1)[spec.mask]
    show("keyframes", joints, f'"a person walks forward" through 4 poses of "{jump_text}"', (spec.positions, spec.mask),
         frames=sorted(set(keys + [Tj // 6, Tj // 2, 5 * Tj // 6])))
    print(f"keyframes: mean error {err.mean() * 100:.2f} cm, max {err.max() * 100:.2f} cm")

    edits = {
        "inbetween": ("a person jumps in place", ["frames=0:40", f"frames={T - 40}:{T}"]),
        "continue": ("a person jumps forward", [f"frames=0:{T // 2}"]),
        "upper_body": ("a person waves with both hands", ["lower_body"]),
    }
    for name, (text, keep) in edits.items():
        mask = keep_mask(keep, T, pipe.skeleton)
        res = pipe.generate([text], T, seed=args.seed, inpaint=Inpaint(circle, mask))
        feats = res.feature_list()[0]
        show(name, res.joint_list()[0], f'"{text}", keeping {" ".join(keep)} of "{circle_text}"')
        print(f"{name}: kept entries reproduced to {np.abs(feats[mask] - circle[mask]).max():.1e}")
    show("source_circle", circle_j, f'source: "{circle_text}" (test split)')
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
