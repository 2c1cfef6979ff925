"""How much a synthetic clip's length says about its action's count, per rest mode.

    .venv/bin/python scripts/synth/length_vs_count.py [--num 2000] [--seed 0] [--data DIR ...]

For the actions with a count (jump, jump_forward, hop, squat, punch, clap), over the
single-action clips of `--num` motions drawn with `--seed` in each rest mode (idle.REST_MODES;
both modes draw the same plans and captions, so the rows compare the same clips): Spearman's
rho of count vs length (feature frames), and the lengths per count (min-median-max). The last
rows pool every clip with one counted part (composites too). Prints a Markdown table
(docs/synth.md, "Length and count").

--data: folders written by `stablemo data synth` with the same --num/--seed; each one's clip
lengths are checked against the regenerated ones of the rest mode its synth.json names, so the
numbers describe those folders.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

from stablemo.data.synth.compose import generate_motion
from stablemo.data.synth.idle import REST_MODES
from stablemo.data.synth.writer import MARKER, clip_id, motion_rng
from stablemo.errors import StableMoError, run_script
from stablemo.io import load_npy

COUNTED = ("jump", "jump_forward", "hop", "squat", "punch", "clap")


def lengths_and_counts(num: int, seed: int, rest: str) -> tuple[list[int], list[tuple[str, int, int, bool]]]:
    """Every clip's feature frames, and (action, count, frames, single-action?) per counted part."""
    lengths, rows = [], []
    for i in range(num):
        m = generate_motion(motion_rng(seed, i), rest)
        frames = len(m.joints) - 1
        lengths.append(frames)
        counted = [p for p in m.parts if p.action in COUNTED]
        if len(counted) == 1:
            rows.append((counted[0].action, int(counted[0].params["count"]), frames, len(m.parts) == 1))
    return lengths, rows


def folder_rest(folder: Path, num: int, seed: int) -> str:
    """The rest mode of a `data synth` folder written with `num` and `seed` (checked before any compute)."""
    meta_path = folder / MARKER
    if not meta_path.is_file():
        raise StableMoError(f"--data {folder}: no {MARKER} (not written by `stablemo data synth`)")
    meta = json.loads(meta_path.read_text())
    rest = meta.get("rest", "tight")  # folders from before the option are tight
    if (meta.get("num"), meta.get("seed")) != (num, seed) or rest not in REST_MODES:
        raise StableMoError(f"--data {folder}: written with num={meta.get('num')} seed={meta.get('seed')} "
                            f"rest={rest}, measured num={num} seed={seed}")
    return rest


def check_lengths(folder: Path, lengths: list[int]) -> None:
    """Every clip of `folder` has the regenerated length."""
    on_disk = [len(load_npy(folder / "new_joint_vecs" / f"{clip_id(i)}.npy", mmap=True)) for i in range(len(lengths))]
    if on_disk != lengths:
        bad = next(i for i, (a, b) in enumerate(zip(on_disk, lengths)) if a != b)
        raise StableMoError(f"--data {folder}: clip {clip_id(bad)} has {on_disk[bad]} frames, the generator "
                            f"makes {lengths[bad]} (another StableMo version?)")


def _rho(counts: list[int], frames: list[int]) -> str:
    return f"{spearmanr(counts, frames)[0]:+.2f}" if len(set(counts)) > 1 else "-"


def _spread(values: list[int]) -> str:
    return f"{min(values)}-{int(np.median(values))}-{max(values)}" if values else "-"


def table(rows: dict[str, list[tuple[str, int, int, bool]]]) -> str:
    modes = list(rows)
    head = ("| action | clips | " + " | ".join(f"rho ({m})" for m in modes) + " | count | "
            + " | ".join(f"frames ({m}) min-median-max" for m in modes) + " |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]

    def block(name: str, keep) -> None:
        sel = {m: [r for r in rows[m] if keep(r)] for m in modes}
        rhos = " | ".join(_rho([r[1] for r in sel[m]], [r[2] for r in sel[m]]) for m in modes)
        for k, count in enumerate(sorted({r[1] for r in sel[modes[0]]})):
            spreads = " | ".join(_spread([r[2] for r in sel[m] if r[1] == count]) for m in modes)
            first = f"| {name} | {len(sel[modes[0]])} | {rhos}" if k == 0 else "| | | " + " | ".join("" for _ in modes)
            lines.append(f"{first} | {count} | {spreads} |")

    for action in COUNTED:
        block(action, lambda r, a=action: r[0] == a and r[3])
    block("all counted, single-action", lambda r: r[3])
    block("all counted, in composites too", lambda r: True)
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--num", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--data", nargs="*", default=[], help="`data synth` folders of the same --num/--seed to check")
    args = ap.parse_args(argv)
    if args.num < 1 or args.seed < 0:
        raise StableMoError(f"--num {args.num} / --seed {args.seed}: need num >= 1 and seed >= 0")
    modes = sorted(REST_MODES, key=lambda m: m != "tight")  # before (version-1 data), then after
    folders = {Path(folder): folder_rest(Path(folder), args.num, args.seed) for folder in args.data}
    lengths, rows = {}, {}
    for rest in modes:
        lengths[rest], rows[rest] = lengths_and_counts(args.num, args.seed, rest)
        frames = np.array(lengths[rest])
        print(f"{rest}: {args.num} clips, frames min {frames.min()} mean {frames.mean():.1f} max {frames.max()}",
              file=sys.stderr)
    for folder, rest in folders.items():
        check_lengths(folder, lengths[rest])
        print(f"{folder}: clip lengths are the {rest} ones", file=sys.stderr)
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main, "/".join(Path(__file__).parts[-2:]), sys.argv[1:]))
