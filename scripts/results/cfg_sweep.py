"""Choose a bundle's default guidance scale on the val split: FID and R@3 at each scale.

    python scripts/results/cfg_sweep.py --bundle stablemo/assets/demo_bundle --data data/synth \
        --cfg 1.0 1.5 2.0 2.5 --out docs/data/training/cfg_sweep_val.json

Runs `stablemo evaluate --split val` once per scale (same items, captions and seeds for every scale),
prints a table and writes the rows as JSON. The scale with the lowest FID (R@3 breaking a tie within
the intervals) is the one to export with (`stablemo export ... --cfg X`); the test split is left for
reporting.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from stablemo.cli import main as stablemo
from stablemo.io import write_text


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bundle", required=True)
    p.add_argument("--data", required=True)
    p.add_argument("--cfg", type=float, nargs="+", required=True)
    p.add_argument("--split", default="val")
    p.add_argument("--replications", type=int, default=5)
    p.add_argument("--max-items", type=int, default=128)
    p.add_argument("--out", help="write the rows here (JSON)")
    args = p.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for cfg in args.cfg:
            out = Path(tmp) / f"cfg{cfg:g}.json"
            code = stablemo(["evaluate", "--bundle", args.bundle, "--data", args.data, "--split", args.split,
                             "--replications", str(args.replications), "--max-items", str(args.max_items),
                             "--cfg", f"{cfg:g}", "--no-kinematics", "--no-progress", "--out", str(out)])
            if code:
                return code
            result = json.loads(out.read_text())
            (name,) = [k for k in result["rows"] if k.endswith(f"cfg {cfg:g})")]  # what the user receives
            row = result["rows"][name]
            rows.append({"cfg": cfg, **{k: {"mean": row[k]["mean"], "conf95": row[k]["conf95"]}
                                        for k in ("fid", "r3", "mm_dist", "diversity")}})
    print("| cfg | FID | R@3 | MM-Dist | Diversity |\n|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['cfg']:g} | " + " | ".join(f"{r[k]['mean']:.3f} ± {r[k]['conf95']:.3f}"
                                               for k in ("fid", "r3", "mm_dist", "diversity")) + " |")
    if args.out:
        write_text(args.out, json.dumps({"bundle": args.bundle, "data": args.data, "split": args.split,
                                         "replications": args.replications, "max_items": args.max_items,
                                         "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
