"""Score one training checkpoint of the demo teacher as the shipped teacher is scored: the rows of
docs/training.md "Behaviour against size and training time".

    .venv/bin/python scripts/train/score_checkpoint.py runs/demo/checkpoints/epoch=57-step=6000.ckpt \
        --out runs/scores/base32_6000

1. `stablemo export CKPT --out OUT/bundle --cfg 1.5` (the shipped teacher's guidance);
2. the bundle gets the shipped length predictor and training captions (`--like`, default the packaged
   teacher): both depend on the data and the frozen text encoder only (scripts/train/ship_demo.sh),
   so a checkpoint scored without them would be scored at lengths the shipped model never uses;
3. `stablemo behaviour --seeds 4 --lengths default natural 6 9.8` -> OUT/behaviour.json;
4. `stablemo evaluate --data data/synth_tight --max-items 128 --replications 3` -> OUT/benchmark.json.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
TEXT_MODELS = ("length_predictor", "familiarity")  # what generation reads beside the network


def text_models_of(like: Path) -> dict | None:
    """`like`'s config entries of the length predictor and captions; None when it lacks one."""
    try:
        source = json.loads((like / "config.json").read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(source, dict) or any(not isinstance(source.get(key), dict) for key in TEXT_MODELS):
        return None
    return source


def attach_text_models(bundle: Path, like: Path) -> None:
    """Give `bundle` the length predictor and familiarity captions of `like` (files and config keys)."""
    from stablemo.io import write_bytes, write_text

    config = json.loads((bundle / "config.json").read_text())
    source = text_models_of(like)
    for key in TEXT_MODELS:
        config[key] = source[key]
        write_bytes(bundle / source[key]["file"], (like / source[key]["file"]).read_bytes())
    write_text(bundle / "config.json", json.dumps(config, indent=2) + "\n")


def _run(cmd: list[str]) -> int:
    print("$", " ".join(cmd), flush=True)
    return subprocess.run(cmd).returncode


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint", type=Path)
    ap.add_argument("--out", type=Path, required=True, help="folder for the bundle and the two reports")
    ap.add_argument("--cfg", type=float, default=1.5, help="guidance scale exported with the bundle")
    ap.add_argument("--like", type=Path, default=REPO / "stablemo/assets/demo_bundle",
                    help="bundle whose length predictor and captions the scored one gets")
    ap.add_argument("--data", type=Path, default=REPO / "data/synth_tight", help="benchmark data")
    ap.add_argument("--seeds", type=int, default=4)
    args = ap.parse_args(argv)
    if not args.checkpoint.is_file():
        print(f"score_checkpoint.py: checkpoint {args.checkpoint} not found", file=sys.stderr)
        return 2
    if text_models_of(args.like) is None:
        print(f"score_checkpoint.py: --like {args.like} is not a bundle with a length predictor and captions "
              f"({' and '.join(TEXT_MODELS)} in its config.json)", file=sys.stderr)
        return 2
    if not (args.data / "Mean.npy").is_file():
        print(f"score_checkpoint.py: --data {args.data} is not a dataset folder (no Mean.npy); make it with "
              f"`stablemo data synth --out {args.data} --num 2000 --seed 0 --rest tight`", file=sys.stderr)
        return 2
    stablemo = str(Path(sys.executable).with_name("stablemo"))
    bundle = args.out / "bundle"
    args.out.mkdir(parents=True, exist_ok=True)
    export = [stablemo, "export", str(args.checkpoint), "--out", str(bundle), "--overwrite", "--cfg", str(args.cfg)]
    scores = [
        [stablemo, "behaviour", "--bundle", str(bundle), "--seeds", str(args.seeds), "--lengths", "default",
         "natural", "6", "9.8", "--out", str(args.out / "behaviour.json"), "--no-progress"],
        [stablemo, "evaluate", "--bundle", str(bundle), "--data", str(args.data), "--max-items", "128",
         "--replications", "3", "--out", str(args.out / "benchmark.json"), "--no-progress"],
    ]
    rc = _run(export)
    if rc:
        return rc
    attach_text_models(bundle, args.like)
    for cmd in scores:
        rc = _run(cmd)
        if rc:
            return rc
    return 0


if __name__ == "__main__":
    sys.exit(main())
