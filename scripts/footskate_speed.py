"""Wall time of the batched cleanup, contact sources side by side in one process (issue #22).

    python scripts/footskate_speed.py [--num 32] [--frames 196] [--repeats 3] [--threads 1]

The batch is the foot-skate benchmark's held-out sliding motions (stablemo.footskate_bench, seed
1000), cycled to `--num` motions and padded to `--frames`. Each repeat runs every configuration
once, in turn, so machine load hits them alike; the fastest of the repeats is reported with the
median. Timings are of `footskate.cleanup` on joints (features in/out adds the re-extraction,
~30 ms for this batch).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import torch

CONFIGS = {
    "heuristic contacts + vGRF term": {"detect": "heuristic"},
    "gated contacts + vGRF term (default)": {"detect": "auto"},
    "gated contacts + vGRF term refreshed every 10": {"detect": "auto", "vgrf_every": 10},
    "gated contacts, no vGRF term": {"detect": "auto", "w_vgrf": 0.0},
}


def main(argv=None) -> int:
    from footskate import HUMANML3D, CleanupConfig, cleanup
    from stablemo.footskate_bench import FEET, build_set
    from stablemo.footskate_guidance import load_vgrf_model

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--num", type=int, default=32)
    p.add_argument("--frames", type=int, default=196)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    data = build_set(1000, 4)
    idx = [i % len(data["kinds"]) for i in range(args.num)]
    x = data["sliding"][idx]
    t = x.shape[1]
    x = torch.cat([x, x[:, -1:].expand(-1, max(args.frames - t, 0), -1, -1)], 1)[:, : args.frames]
    lengths = data["lengths"][idx].clamp(max=args.frames)
    vgrf = load_vgrf_model(None)
    times: dict[str, list[float]] = {k: [] for k in CONFIGS}
    cleanup(x[:2], list(HUMANML3D.parents), FEET, lengths=lengths[:2], vgrf=vgrf, config=CleanupConfig(iters=5))
    for _ in range(args.repeats):
        for name, kw in CONFIGS.items():
            started = time.perf_counter()
            cleanup(x, list(HUMANML3D.parents), FEET, lengths=lengths, vgrf=vgrf, config=CleanupConfig(**kw))
            times[name].append(time.perf_counter() - started)
    print(f"{args.num} x {args.frames} frames, {args.threads} thread(s), {args.repeats} repeats")
    for name, ts in times.items():
        print(f"  {name:45s} fastest {min(ts):.2f} s   median {statistics.median(ts):.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
