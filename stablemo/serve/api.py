"""The FastAPI app: the page, its static files, and the JSON API beside it.

    GET  /                 the page (static/index.html)
    GET  /api/info         served models: defaults, length range, samplers, skeleton
    POST /api/generate     {"text", "seconds"|"frames", "seed", "model", "sampler", "steps", "cfg",
                            "footskate", "encoding", "features"} -> joints, features, fps, ...
    POST /api/download     the same body + "format": joints.npy | features.npy | bvh | gif -> the file
    POST /api/stream       {"timeline": [{"text", "seconds"}, ...], "chunk_seconds", "seed", ...} ->
                           NDJSON: a header line, one line per chunk as it is made, a last "done" line

Bad input is HTTP 400 with {"error": "<field>: <one line>"}, checked before the job is queued. All
generation runs on one worker thread: a request that arrives while another computes waits its
turn (FIFO) instead of splitting the cores, and past `max_queue` waiting requests the answer is
503 at once. GIFs and BVH files are made on a second thread so a download does not hold up typing.
"""

# no `from __future__ import annotations`: FastAPI reads the route functions' annotations at run time
import asyncio
import contextlib
import io
import json
import logging
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from fastapi import FastAPI, Request
from fastapi.responses import FileResponse, JSONResponse, Response, StreamingResponse
from fastapi.staticfiles import StaticFiles

from stablemo.errors import StableMoError, one_line
from stablemo.generate import slugify
from stablemo.serve.models import ModelSet, Motion, encode_array, motion_json

STATIC_DIR = Path(__file__).resolve().parent / "static"
DOWNLOADS = {"joints.npy": "application/octet-stream", "features.npy": "application/octet-stream",
             "gif": "image/gif", "bvh": "application/octet-stream"}
log = logging.getLogger("stablemo.serve")


class Busy(Exception):
    pass


class Worker:
    """One thread for generation, a bounded count of waiting requests (counted on the event loop)."""

    def __init__(self, max_queue: int, name: str):
        self.executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix=name)
        self.max_queue, self.waiting = max_queue, 0

    async def run(self, fn, *args):
        if self.waiting >= self.max_queue:
            raise Busy(f"server busy: {self.waiting} requests are waiting; try again shortly")
        self.waiting += 1
        try:
            return await asyncio.get_running_loop().run_in_executor(self.executor, fn, *args)
        finally:
            self.waiting -= 1

    def shutdown(self) -> None:
        self.executor.shutdown(wait=False, cancel_futures=True)


def create_app(models: ModelSet, max_queue: int = 32, static_dir: Path = STATIC_DIR):
    generate_worker = Worker(max_queue, "stablemo-generate")
    render_worker = Worker(4, "stablemo-render")
    @contextlib.asynccontextmanager
    async def lifespan(app):
        yield
        generate_worker.shutdown()
        render_worker.shutdown()

    # no /docs page: FastAPI's loads Swagger UI from a CDN, and nothing here may need the network
    app = FastAPI(title="StableMo", lifespan=lifespan, docs_url=None, redoc_url=None, openapi_url="/api/openapi.json")
    app.state.models = models

    def error(status: int, message: str) -> JSONResponse:
        return JSONResponse({"error": one_line(message)}, status_code=status)

    async def parse(request: Request):
        try:
            body = json.loads(await request.body())
        except (json.JSONDecodeError, UnicodeDecodeError) as err:
            raise StableMoError(f"request: the body is not valid JSON ({err})") from None
        return models.parse(body)

    async def run_job(spec) -> tuple[Motion, bool, float]:
        queued = time.perf_counter()
        motion, cached = await generate_worker.run(models.generate, spec)
        return motion, cached, time.perf_counter() - queued

    @app.exception_handler(StableMoError)
    async def _bad_input(request, err: StableMoError):
        return error(400, str(err))

    @app.exception_handler(Busy)
    async def _busy(request, err: Busy):
        return error(503, str(err))

    @app.get("/", include_in_schema=False)
    async def page():
        return FileResponse(static_dir / "index.html")

    @app.get("/api/info")
    async def info():
        return {**models.describe(), "downloads": sorted(DOWNLOADS), "max_queue": max_queue}

    @app.post("/api/generate")
    async def generate(request: Request):
        spec, options = await parse(request)
        motion, cached, total = await run_job(spec)
        out = motion_json(motion, options["encoding"], options["features"])
        # compute: the model's time for this motion (0 when it came from the cache); total: with the queue
        out["timing"] = {"compute_ms": 0.0 if cached else round(motion.seconds * 1000, 2),
                         "total_ms": round(total * 1000, 2), "cached": cached}
        return out

    @app.post("/api/stream")
    async def stream(request: Request):
        try:
            body = json.loads(await request.body())
        except (json.JSONDecodeError, UnicodeDecodeError) as err:
            raise StableMoError(f"request: the body is not valid JSON ({err})") from None
        job = models.parse_stream(body)

        async def lines():
            start = time.perf_counter()
            yield json.dumps({"model": job.model, "fps": job.fps, "frames": job.frames, "chunks": len(job.texts),
                              "texts": job.texts}) + "\n"
            while True:
                try:  # one chunk per turn of the worker: other requests interleave with a long stream
                    chunk = await generate_worker.run(next, job.chunks, None)
                except (StableMoError, Busy) as err:
                    yield json.dumps({"error": one_line(str(err))}) + "\n"
                    return
                if chunk is None:
                    break
                yield json.dumps({"index": chunk.index, "text": chunk.text, "start": chunk.start,
                                  "frames": len(chunk.joints), "joints": encode_array(chunk.joints, job.encoding),
                                  "elapsed_ms": round((time.perf_counter() - start) * 1000, 2)}) + "\n"
            yield json.dumps({"done": True, "elapsed_ms": round((time.perf_counter() - start) * 1000, 2)}) + "\n"

        return StreamingResponse(lines(), media_type="application/x-ndjson")

    @app.post("/api/download")
    async def download(request: Request):
        spec, options = await parse(request)
        fmt = options["format"]
        if fmt not in DOWNLOADS:
            raise StableMoError(f"format: expected one of {', '.join(sorted(DOWNLOADS))}, got {fmt!r}")
        motion, _, _ = await run_job(spec)
        if fmt == "gif":
            data = await render_worker.run(gif_bytes, motion)
        elif fmt == "bvh":
            data = await render_worker.run(bvh_bytes, motion)
        else:
            data = npy_bytes(motion.joints if fmt == "joints.npy" else motion.features)
        name = f"{slugify(spec.text)}-seed{spec.seed}.{fmt}"
        return Response(data, media_type=DOWNLOADS[fmt], headers={"Content-Disposition": f'attachment; filename="{name}"'})

    app.mount("/static", StaticFiles(directory=static_dir), name="static")
    return app


def npy_bytes(arr: np.ndarray) -> bytes:
    """An .npy file's bytes, built in memory (the download is the only copy; nothing on disk)."""
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, np.ascontiguousarray(arr, dtype=np.float32), allow_pickle=False)
    return buffer.getvalue()


def bvh_bytes(motion: Motion) -> bytes:
    """The motion as BVH (stablemo.bvh: a T-pose rig from its bones, rotations at its frame rate, metres)."""
    from stablemo.bvh import bvh_text

    return bvh_text(motion.joints, skeleton=motion.info["skeleton"], source_fps=motion.fps).encode("ascii")


def gif_bytes(motion: Motion) -> bytes:
    """The motion as `stablemo render` draws it. The renderer writes files, so it writes into a
    private temporary folder that is removed with everything in it when the bytes are read."""
    from stablemo.render import render_animation

    with tempfile.TemporaryDirectory(prefix="stablemo-serve-") as tmp:
        path = render_animation(motion.joints, Path(tmp) / "motion.gif", motion.info["skeleton"], fps=motion.fps,
                                title=motion.spec.text)
        return path.read_bytes()
