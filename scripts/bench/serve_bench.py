"""Measure `stablemo serve` on this machine: prompt -> first frame in the browser, and a load test.

    python scripts/bench/serve_bench.py latency [--prompts 12] [--out /tmp/serve_latency.json]
    python scripts/bench/serve_bench.py load [--requests 200] [--concurrency 4] [--model student] [--out ...]

Both start `stablemo serve` (the packaged demo models, --threads 1) as a separate process on a free
loopback port and stop it at the end; nothing is sent anywhere but 127.0.0.1.

latency: headless Chromium (Debian's chromium + chromium-driver) opens the page; for each model
and each prompt the prompt is put in the box as one edit (an `input` event, as typing's last
keystroke), and the page's own clock (performance.now) gives: send -> first frame drawn (the
request, the model, the transfer, decoding and the first render; "drawn" is the next animation
frame after the render call, when the frame has gone to the screen), and keystroke -> drawn (plus
the page's 300 ms pause before sending). Every prompt is new to the server (no cached answers).

load: `--requests` POST /api/generate, `--concurrency` at a time, each with its own seed; reports
throughput and p50/p95 latency, counts errors, and checks that every answer equals its seed's
offline generation (the same bundle loaded in this process, one motion at a time), bit for bit.
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import socket
import statistics
import subprocess
import sys
import time
import urllib.error
import urllib.request
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
STABLEMO = [sys.executable, "-m", "stablemo.cli"]
PROMPTS = [
    "a person jumps, then turns left", "a person walks forward, then waves their right hand",
    "a person runs in a circle clockwise", "a person kicks with their left leg", "a person squats twice",
    "a person walks backward", "a person turns right, then walks forward", "a person jumps in place twice",
    "a person waves with both hands", "a person walks in a circle counterclockwise", "a person runs forward",
    "a person kicks with their right leg, then jumps", "a person walks to the left", "a person squats, then jumps",
    "a person turns around", "a person runs, then stops",
]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def server(threads: int = 1):
    port = free_port()
    proc = subprocess.Popen([*STABLEMO, "serve", "--port", str(port), "--threads", str(threads)], cwd=REPO,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 300
        while True:
            try:
                info = get_json(url + "/api/info")
                break
            except OSError:
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise SystemExit(f"stablemo serve did not start (exit code {proc.poll()})") from None
                time.sleep(0.5)
        yield url, info
    finally:
        proc.terminate()
        proc.wait(30)


def get_json(url: str) -> dict:
    with urllib.request.urlopen(url, timeout=10) as res:
        return json.loads(res.read())


def post_json(url: str, body: dict, timeout: float = 300) -> tuple[int, dict]:
    req = urllib.request.Request(url, json.dumps(body).encode(), {"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(req, timeout=timeout) as res:
            return res.status, json.loads(res.read())
    except urllib.error.HTTPError as err:
        return err.code, json.loads(err.read() or b"{}")


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q))


# ---- latency in the browser ---------------------------------------------------------------------

def latency(args) -> dict:
    from selenium import webdriver

    opts = webdriver.ChromeOptions()
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1280,800",
                "--enable-unsafe-swiftshader"):
        opts.add_argument(arg)
    results = {}
    with server() as (url, info):
        driver = webdriver.Chrome(options=opts, service=webdriver.ChromeService(executable_path="/usr/bin/chromedriver"))
        try:
            driver.get(url + "/")
            wait(driver, "return window.stablemo && window.stablemo.ready")
            renderer = driver.execute_script(
                "const gl = document.createElement('canvas').getContext('webgl2');"
                "const e = gl.getExtension('WEBGL_debug_renderer_info');"
                "return e ? gl.getParameter(e.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER)")
            default_hold = driver.execute_script("return window.stablemo.holdWhileComputing")
            for model in info["models"]:
                name = model["name"]
                driver.execute_script("const m = document.getElementById('model'); m.value = arguments[0];"
                                      "m.dispatchEvent(new Event('change'));", name)
                time.sleep(3)  # the model switch regenerates the box's prompt; let it settle
                rows = []
                for i in range(args.prompts + 1):
                    text = f"{PROMPTS[i % len(PROMPTS)]} ({name} {i})"  # new to the server's cache
                    # A/B in one run: even prompts with the page's default, odd ones with the figure
                    # animating while the request is computed (the default under software WebGL holds it)
                    hold = default_hold if i % 2 == 0 else False
                    driver.execute_script("window.stablemo.holdWhileComputing = arguments[0];", hold)
                    driver.execute_script("const p = document.getElementById('prompt'); p.value = arguments[0];"
                                          "p.dispatchEvent(new Event('input'));", text)
                    rec = wait(driver, "return window.stablemo.timings.find(t => t.text === arguments[0] && t.drawn)", text)
                    if i == 0:
                        continue  # the first request after a model switch is not counted
                    rows.append({"hold": hold, "send_to_drawn_ms": rec["drawn"] - rec["send"],
                                 "input_to_drawn_ms": rec["drawn"] - rec["input"],
                                 "send_to_response_ms": rec["response"] - rec["send"],
                                 "response_to_drawn_ms": rec["drawn"] - rec["response"],
                                 "model_ms": rec["server"]["compute_ms"]})
                    time.sleep(0.3)
                keys = [k for k in rows[0] if k.endswith("_ms")]
                out = {"steps": model["defaults"]["steps"], "label": model["label"], "rows": rows}
                for label, sel in (("default", [r for r in rows if r["hold"] == default_hold]),
                                   ("animating", [r for r in rows if not r["hold"]])):
                    if sel and (label == "default" or default_hold):
                        out[label] = {"n": len(sel), **{f"median_{k}": statistics.median(r[k] for r in sel) for k in keys},
                                      **{f"max_{k}": max(r[k] for r in sel) for k in keys}}
                results[name] = out
        finally:
            driver.quit()
    return {"renderer": renderer, "hold_by_default": default_hold, "load_average": os.getloadavg(), "models": results}


def wait(driver, script: str, *args, timeout: float = 120.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = driver.execute_script(script, *args)
        if value:
            return value
        time.sleep(0.01)
    raise SystemExit(f"timed out waiting for: {script}")


# ---- load test ------------------------------------------------------------------------------------

def load(args) -> dict:
    import torch

    torch.set_num_threads(1)  # as the server's worker (--threads 1)
    text = "a person jumps, then turns left"
    seeds = [args.seed + i for i in range(args.requests)]
    with server() as (url, info):
        model = args.model or info["default"]
        # /api/info names bundles, not their paths: the server runs the packaged demo models
        from stablemo.cli.serve import DEMO_MODELS

        bundle = DEMO_MODELS[model]

        def one(seed: int) -> dict:
            start = time.perf_counter()
            status, data = post_json(url + "/api/generate", {"text": text, "seconds": args.seconds, "seed": seed,
                                                             "model": model, "encoding": "base64", "features": True})
            return {"seed": seed, "status": status, "data": data, "seconds": time.perf_counter() - start}

        start = time.perf_counter()
        with ThreadPoolExecutor(args.concurrency) as pool:
            answers = list(pool.map(one, seeds))
        wall = time.perf_counter() - start
    from stablemo.inference.pipeline import Pipeline, Request

    pipe = Pipeline.from_bundle(bundle)
    frames = round(args.seconds * pipe.fps)
    errors = [a for a in answers if a["status"] != 200]
    mismatched = []
    for a in answers:
        if a["status"] != 200:
            continue
        ref = pipe.generate(Request([text], frames, seed=a["seed"], plan=True))  # as the server does
        joints, feats = (decode(a["data"][k]) for k in ("joints", "features"))
        if a["data"]["seed"] != a["seed"] or not (np.array_equal(joints, ref.joint_list()[0])
                                                  and np.array_equal(feats, ref.feature_list()[0])):
            mismatched.append(a["seed"])
    lat = [a["seconds"] * 1000 for a in answers]
    compute = [a["data"]["timing"]["compute_ms"] for a in answers if a["status"] == 200]
    return {"model": model, "bundle": str(bundle), "requests": args.requests, "concurrency": args.concurrency,
            "frames": frames, "wall_s": wall, "throughput_rps": args.requests / wall,
            "p50_ms": percentile(lat, 50), "p95_ms": percentile(lat, 95), "max_ms": max(lat),
            "model_p50_ms": percentile(compute, 50) if compute else None, "errors": len(errors),
            "error_messages": sorted({a["data"].get("error", "") for a in errors}), "mismatched": mismatched,
            "load_average": os.getloadavg()}


def decode(arr: dict) -> np.ndarray:
    return np.frombuffer(base64.b64decode(arr["base64"]), dtype="<f4").reshape(arr["shape"])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="what", required=True)
    lat = sub.add_parser("latency", help="prompt -> first frame drawn, in headless Chromium")
    lat.add_argument("--prompts", type=int, default=12)
    ld = sub.add_parser("load", help="bounded localhost load test")
    ld.add_argument("--requests", type=int, default=200)
    ld.add_argument("--concurrency", type=int, default=4)
    ld.add_argument("--model", default=None, help="served model name (default: the server's default)")
    ld.add_argument("--seconds", type=float, default=6.0)
    ld.add_argument("--seed", type=int, default=1000)
    for s in (lat, ld):
        s.add_argument("--out", default=None, help="also write the results as JSON here")
    args = p.parse_args(argv)
    result = latency(args) if args.what == "latency" else load(args)
    text = json.dumps(result, indent=1)
    if args.out:
        from stablemo.io import write_text

        write_text(Path(args.out), text + "\n")
    summary = {k: v for k, v in result.items() if k != "models"}
    if args.what == "latency":
        for name, r in result["models"].items():
            summary[name] = {label: {k: round(v, 1) for k, v in r[label].items()}
                             for label in ("default", "animating") if label in r}
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
