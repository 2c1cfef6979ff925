"""Honest clients of `stablemo serve` while hostile ones attack it: are the honest answers still
exact, and how much slower are they?

    python scripts/bench/serve_load_hostile.py [--requests 60] [--concurrency 2] [--hostile 3] [--out FILE]

Starts `stablemo serve --threads 1` (the packaged demo models) on a free loopback port, as
scripts/bench/serve_bench.py's load test does (this script does not import it), then runs the same honest load twice in one run: quiet,
then with `--hostile` threads sending, over and over, the hostile mix. Every honest answer
is compared, bit for bit, with offline `Pipeline.generate` for its seed; the script prints p50/p95
latency of both phases and their ratio (the target: hostile p95 within 2x of quiet p95), and the
status codes each hostile kind got (never a 500; the server still up at the end). The clients and
the two phases are stablemo.bench.serve_load's (`run`); this script starts the server and prints.

The hostile mix (each kind, and the answer it should get): stablemo.bench.serve_load's module doc.
"""

from __future__ import annotations

import argparse
import contextlib
import http.client
import json
import socket
import subprocess
import sys
import time
from pathlib import Path

from stablemo.bench.serve_load import run

REPO = Path(__file__).resolve().parents[2]


@contextlib.contextmanager
def server():
    """`stablemo serve --threads 1` (the packaged demo models) on a free loopback port, in its own
    process; yields its base URL, stops it at the end."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen([sys.executable, "-m", "stablemo.cli", "serve", "--port", str(port), "--threads", "1"],
                            cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 300
        while True:
            try:
                conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
                conn.request("GET", "/api/info")
                conn.getresponse().read()
                conn.close()
                break
            except OSError:
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise SystemExit(f"stablemo serve did not start (exit code {proc.poll()})") from None
                time.sleep(0.5)
        yield f"http://127.0.0.1:{port}"
    finally:
        proc.terminate()
        proc.wait(30)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--requests", type=int, default=60, help="honest requests per phase")
    ap.add_argument("--concurrency", type=int, default=2, help="honest requests in flight")
    ap.add_argument("--hostile", type=int, default=3, help="hostile client threads")
    ap.add_argument("--model", default="student")
    ap.add_argument("--seconds", type=float, default=6.0)
    ap.add_argument("--out", default=None, help="also write the results as JSON here")
    args = ap.parse_args(argv)
    import torch

    from stablemo.inference.pipeline import Pipeline
    from stablemo.cli.serve import DEMO_MODELS

    torch.set_num_threads(1)  # as the server's worker (--threads 1)
    pipe = Pipeline.from_bundle(DEMO_MODELS[args.model])
    frames = round(args.seconds * pipe.fps)
    with server() as url:
        host, port = url.removeprefix("http://").rsplit(":", 1)
        result = run(host, int(port), pipe, args.model, args.requests, args.concurrency, args.hostile, frames)
    text = json.dumps(result, indent=1)
    if args.out:
        from stablemo.io import write_text

        write_text(Path(args.out), text + "\n")
    print(text)
    print(f"p95 hostile / quiet = {result['p95_ratio']:.2f} (target <= 2), p50 = {result['p50_ratio']:.2f}; "
          f"answers != offline: {len(result['mismatched']['quiet'])} quiet, {len(result['mismatched']['hostile'])} hostile")
    return 0


if __name__ == "__main__":
    sys.exit(main())
