"""Calibrate the gated vGRF contact decision on synthetic validation motions.

    python scripts/footskate/calibrate.py [--weights V22] [--seeds 3000,4000] [--per-type 8] [--json out.json]

The network's contacts are kept where the foot force reaches `gate_force` body weights and the
joint is within `gate_margin` of its own lowest point and slower than `gate_speed`, and also where
the height/speed rule says the joint is down and the force reaches `gate_support`, and where it stays
still near the floor for `gate_rest` seconds (footskate.cleanup
detect_contacts, gate=True). This grid-searches them (the height gate: see MARGINS) on the benchmark's motion types built
from validation seeds (default 3000-3007 and 4000-4007; the benchmark's test seeds are 1000-1999,
its tuning seed 0, the V22's training motions 10000+ and the generator mix), with the benchmark's
injected sliding, and picks the setting whose *smallest* per-type F1 margin over the height rule
is largest (ties: overall F1). The real HumanML3D clip is not looked at. The search is
stablemo.bench.footskate_calibrate.calibrate; this script parses the options, prints and stores.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

from stablemo.bench.footskate_calibrate import MARGINS, RESTS, SUPPORTS, calibrate


def main(argv=None) -> int:
    from stablemo.skating.cleanup import load_vgrf_model
    from stablemo.io import write_text

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--weights", default=None, help="vGRF weights (default: the shipped V22, or V21 for kit)")
    p.add_argument("--seeds", default="3000,4000")
    p.add_argument("--per-type", type=int, default=8)
    p.add_argument("--skeleton", choices=("humanml3d", "kit"), default="humanml3d")
    p.add_argument("--margins", default=",".join(map(str, MARGINS)), help="height gates to search (m, comma-separated)")
    p.add_argument("--supports", default=",".join(map(str, SUPPORTS)), help="support forces to search (BW, comma-separated; 0: off)")
    p.add_argument("--rests", default=",".join(map(str, RESTS)), help="rest durations to search (s, comma-separated; 0: off)")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--json", default=None)
    p.add_argument("--store", default=None,
                   help="write a copy of the weights here with the best force in their metadata ('gate_force', "
                        "which the gated decision then uses for this network)")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    model = load_vgrf_model(args.weights, args.skeleton)
    out = calibrate(model, tuple(int(s) for s in args.seeds.split(",")),
                    args.per_type, args.skeleton, tuple(float(m) for m in args.margins.split(",")),
                    tuple(float(f) for f in args.supports.split(",")), tuple(float(r) for r in args.rests.split(",")))
    fmt = lambda f: " ".join(f"{k} {v:.4f}" for k, v in f.items())
    print("rule  ", fmt(out["rule"]))
    for r in out["grid"][:8]:
        print(f"force {r['gate_force']:.2f} margin {r['gate_margin']:.3f} speed {r['gate_speed']:.1f} "
              f"support {r['gate_support']:.2f} rest {r['gate_rest']:.2f} "
              f"min margin {r['min_margin']:+.4f} | {fmt(r['f1'])}")
    b = out["best"]
    print(f"best: gate_force {b['gate_force']} gate_margin {b['gate_margin']} gate_speed {b['gate_speed']} "
          f"gate_support {b['gate_support']} gate_rest {b['gate_rest']}")
    if args.json:
        write_text(Path(args.json), json.dumps(out, indent=1) + "\n")
    if args.store:
        from footskate.vgrf import save_vgrf

        meta = {**getattr(model, "metadata", {}), "gate_force": b["gate_force"],
                "gate_force_calibration": {"seeds": args.seeds, "per_type": args.per_type, "min_margin": b["min_margin"],
                                           "command": "python scripts/footskate/calibrate.py " + " ".join(argv or [])}}
        save_vgrf(model, args.store, meta)
        print(f"stored gate_force {b['gate_force']} in {args.store}")
    return 0


if __name__ == "__main__":
    from stablemo.errors import run_script

    sys.exit(run_script(main, "/".join(Path(__file__).parts[-2:]), sys.argv[1:]))
