"""Honest and hostile clients of `stablemo serve`, side by side (the library side of
scripts/bench/serve_load_hostile.py, which starts the server, parses the options and prints; and of
tests/test_serve_hostile.py, which runs `run` against an in-process server).

`run` sends the same honest load twice: quiet, then with hostile threads sending, over and over,
the hostile mix below. Every honest answer is compared, bit for bit, with offline
`Pipeline.generate` for its seed; it reports p50/p95 latency of both phases and their ratio, and the
status codes each hostile kind got.

The hostile mix (each one request, sent as raw HTTP on its own socket):
  huge_body     Content-Length of 600 MB, then as much body as the server takes   -> 413 at once
  chunked_body  a chunked body with no length, 64 KiB chunks without end          -> 413 past 1 MiB
  slow_body     a body trickled a byte at a time                                  -> 408 (body timeout)
  bad_json      a truncated JSON object                                           -> 400
  deep_json     100 000 nested arrays                                             -> 400 naming the field
  huge_int      a seed of 5000 digits                                             -> 400 naming the field
  far_target    a GIF download whose pelvis target is 10 000 km away              -> 400 before any work
  tiny_chunks   a 300 s stream of 1e-9 s chunks                                   -> 400 before any work
  wrong_host    Host: attacker.example (DNS rebinding)                            -> 400
  wrong_origin  Origin: http://attacker.example (another web page)                -> 403
  text_plain    Content-Type: text/plain (a browser's "simple request")           -> 415
"""

from __future__ import annotations

import base64
import http.client
import itertools
import json
import os
import socket
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

HONEST_TEXT = "a person jumps, then turns left"


# ---- the hostile mix ----------------------------------------------------------------------------

def _raw(host: str, port: int, head: bytes, body=(), pause: float = 0.0, timeout: float = 30.0) -> int | str:
    """Send request head + body pieces on a fresh socket; the status code of the answer, or the
    name of the error that ended the exchange (the server closing on a refused body is fine)."""
    try:
        with socket.create_connection((host, port), timeout=timeout) as sock:
            sock.sendall(head)
            try:
                for piece in body:
                    sock.sendall(piece)
                    if pause:
                        time.sleep(pause)
            except OSError:
                pass  # the server answered and closed while we were still sending
            data = b""
            while b"\r\n" not in data:
                chunk = sock.recv(4096)
                if not chunk:
                    break
                data += chunk
            line = data.split(b"\r\n", 1)[0].split()
            return int(line[1]) if len(line) >= 2 else "closed"
    except OSError as err:
        return type(err).__name__


def _head(method: str, path: str, host: str, extra: dict[str, str]) -> bytes:
    lines = [f"{method} {path} HTTP/1.1", f"Host: {host}"] + [f"{k}: {v}" for k, v in extra.items()]
    return ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1")


def _json_head(path: str, host: str, body: bytes, **extra) -> bytes:
    return _head("POST", path, host, {"Content-Type": "application/json", "Content-Length": str(len(body)), **extra})


def hostile_request(kind: str, host: str, port: int, slow_seconds: float = 20.0) -> int | str:
    """One hostile request of `kind` (the module docstring) against host:port."""
    me = f"{host}:{port}"
    if kind == "huge_body":
        head = _head("POST", "/api/generate", me, {"Content-Type": "application/json", "Content-Length": str(600 << 20)})
        return _raw(host, port, head, itertools.repeat(b"[" * 65536, 32))
    if kind == "chunked_body":
        head = _head("POST", "/api/generate", me, {"Content-Type": "application/json", "Transfer-Encoding": "chunked"})
        piece = b"10000\r\n" + b" " * 65536 + b"\r\n"
        return _raw(host, port, head, itertools.repeat(piece, 64))
    if kind == "slow_body":
        body = json.dumps({"text": "a person walks", "seed": 1}).encode()
        return _raw(host, port, _json_head("/api/generate", me, body + b" " * 1000), (body[i:i + 1] for i in range(len(body))),
                    pause=slow_seconds / len(body))
    bodies = {
        "bad_json": b'{"text": "a person walks", "seed":',
        "deep_json": b'{"text": "walk", "control": ' + b"[" * 100_000 + b"]" * 100_000 + b"}",
        "huge_int": b'{"text": "a person walks", "seed": 1' + b"0" * 5000 + b"}",
        "far_target": json.dumps({"text": "a person walks", "frames": 40, "format": "gif",
                                  "control": {"targets": [[20, 0, 1e7, 0.9, 0.0]]}}).encode(),
        "tiny_chunks": json.dumps({"timeline": "0 300 a person walks",
                                   "chunk_seconds": 1e-9}).encode(),
    }
    path = "/api/download" if kind == "far_target" else "/api/stream" if kind == "tiny_chunks" else "/api/generate"
    if kind in bodies:
        return _raw(host, port, _json_head(path, me, bodies[kind]) + bodies[kind])
    body = json.dumps({"text": "a person walks", "frames": 40, "seed": 1}).encode()
    if kind == "wrong_host":
        return _raw(host, port, _json_head(path, f"attacker.example:{port}", body) + body)
    if kind == "wrong_origin":
        return _raw(host, port, _json_head(path, me, body, Origin="http://attacker.example") + body)
    if kind == "text_plain":
        head = _head("POST", path, me, {"Content-Type": "text/plain", "Content-Length": str(len(body))})
        return _raw(host, port, head + body)
    raise ValueError(kind)


HOSTILE_KINDS = ("huge_body", "chunked_body", "slow_body", "bad_json", "deep_json", "huge_int", "far_target",
                 "tiny_chunks", "wrong_host", "wrong_origin", "text_plain")
EXPECTED = {"huge_body": 413, "chunked_body": 413, "slow_body": 408, "bad_json": 400, "deep_json": 400,
            "huge_int": 400, "far_target": 400, "tiny_chunks": 400, "wrong_host": 400, "wrong_origin": 403,
            "text_plain": 415}


def hostile_clients(host: str, port: int, threads: int, stop: threading.Event, slow_seconds: float = 20.0):
    """Start `threads` threads cycling through HOSTILE_KINDS until `stop` (each thread sends every
    kind at least once); returns (threads, results: kind -> list of statuses). Thread i starts at
    kind 4 i, so different kinds run side by side."""
    results: dict[str, list] = {k: [] for k in HOSTILE_KINDS}

    def loop(offset: int):
        for i in itertools.count(offset):
            if stop.is_set() and i - offset >= len(HOSTILE_KINDS):
                return
            kind = HOSTILE_KINDS[i % len(HOSTILE_KINDS)]
            results[kind].append(hostile_request(kind, host, port, slow_seconds))

    pool = [threading.Thread(target=loop, args=(i * 4,), daemon=True) for i in range(threads)]
    for t in pool:
        t.start()
    return pool, results


# ---- honest clients -----------------------------------------------------------------------------

def honest_request(host: str, port: int, body: dict, timeout: float = 300.0) -> tuple[int, dict, float]:
    """(status, answer, seconds) of one POST /api/generate, as the page sends it."""
    start = time.perf_counter()
    conn = http.client.HTTPConnection(host, port, timeout=timeout)
    try:
        data = json.dumps(body).encode()
        conn.request("POST", "/api/generate", data, {"Content-Type": "application/json",
                                                     "Origin": f"http://{host}:{port}"})
        res = conn.getresponse()
        answer = json.loads(res.read() or b"{}")
        return res.status, answer, time.perf_counter() - start
    finally:
        conn.close()


def honest_load(host: str, port: int, seeds: list[int], concurrency: int, model: str, frames: int) -> list[dict]:
    def one(seed: int) -> dict:
        body = {"text": HONEST_TEXT, "frames": frames, "seed": seed, "model": model, "encoding": "base64"}
        status, data, seconds = honest_request(host, port, body)
        return {"seed": seed, "status": status, "data": data, "seconds": seconds}

    with ThreadPoolExecutor(concurrency) as pool:
        return list(pool.map(one, seeds))


def decode(arr: dict) -> np.ndarray:
    return np.frombuffer(base64.b64decode(arr["base64"]), dtype="<f4").reshape(arr["shape"])


def mismatched(answers: list[dict], pipe, frames: int) -> list[int]:
    """Seeds whose answer is not offline generation's motion, bit for bit (or is not a 200)."""
    from stablemo.inference.pipeline import Request

    bad = []
    for a in answers:
        if a["status"] != 200:
            bad.append(a["seed"])
            continue
        ref = pipe.generate(Request([HONEST_TEXT], frames, seed=a["seed"], plan=True))  # as the server does
        same = (a["data"]["seed"] == a["seed"] and np.array_equal(decode(a["data"]["joints"]), ref.joint_list()[0])
                and np.array_equal(decode(a["data"]["features"]), ref.feature_list()[0]))
        if not same:
            bad.append(a["seed"])
    return bad


def p(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values) * 1000, q))


def run(host: str, port: int, pipe, model: str, requests: int, concurrency: int, hostile: int, frames: int,
        slow_seconds: float = 20.0) -> dict:
    """The quiet phase, then the hostile phase (other seeds: no cached answers), in one run."""
    quiet = honest_load(host, port, list(range(5000, 5000 + requests)), concurrency, model, frames)
    stop = threading.Event()
    pool, statuses = hostile_clients(host, port, hostile, stop, slow_seconds)
    time.sleep(0.5)  # the attack is under way before the first honest request
    try:
        loud = honest_load(host, port, list(range(6000, 6000 + requests)), concurrency, model, frames)
    finally:
        stop.set()
        for t in pool:
            t.join(slow_seconds + 60)
    lat_q, lat_h = [a["seconds"] for a in quiet], [a["seconds"] for a in loud]
    out = {"model": model, "frames": frames, "requests": requests, "concurrency": concurrency, "hostile_threads": hostile,
           "quiet": {"p50_ms": p(lat_q, 50), "p95_ms": p(lat_q, 95), "max_ms": p(lat_q, 100)},
           "hostile": {"p50_ms": p(lat_h, 50), "p95_ms": p(lat_h, 95), "max_ms": p(lat_h, 100)},
           "mismatched": {"quiet": mismatched(quiet, pipe, frames), "hostile": mismatched(loud, pipe, frames)},
           "hostile_statuses": {k: sorted(set(map(str, v))) for k, v in statuses.items()},
           "hostile_counts": {k: len(v) for k, v in statuses.items()},
           "unexpected": {k: [s for s in v if s != EXPECTED[k] and s not in ("ConnectionResetError", "BrokenPipeError")]
                          for k, v in statuses.items()},
           "load_average": os.getloadavg()}
    out["p95_ratio"] = out["hostile"]["p95_ms"] / out["quiet"]["p95_ms"]
    out["p50_ratio"] = out["hostile"]["p50_ms"] / out["quiet"]["p50_ms"]
    return out
