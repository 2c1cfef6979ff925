"""The FastAPI app: the page, its static files, and the JSON API beside it.

    GET  /                 the page (static/index.html)
    GET  /api/info         served models: defaults, length range, samplers, skeleton, downloads
    GET  /api/rest.glb     ?model=NAME: the model's body standing at ease (GLB), the page's figure
                           before its first motion; the glb download is the same body in motion
    POST /api/generate     {"text", "seconds"|"frames", "seed", "model", "sampler", "steps", "cfg",
                            "footskate", "plan", "encoding", "features"} -> joints, features, fps, plan, ...,
                           warnings (plan: a prompt that says an order is made part by part; the parts)
                           (no seconds or frames, or "auto": the text's own length, "length_from": "text")
                           (one line per download that would be more than 3 cm from the motion)
    POST /api/download     the same body + "format": joints.npy | features.npy | bvh | gif | glb | fbx -> the file;
                           with /api/stream's body + "format", the streamed motion's file
    POST /api/retarget     the /api/generate body + "rig": a humanoid rig's BVH text (+ "rig_map": {Role: joint
                           name} for joints its names do not tell) -> the motion on that rig, as BVH
                           (stablemo.retarget); a rig that is not humanoid is a 400 before the motion is made
    POST /api/stream       {"timeline": "0 4 a person walks forward\n4 6 a person jumps\n", "chunk_seconds",
                           "seed", ...} (the CLI's timeline text, stablemo.timeline.spec) -> NDJSON: a header
                           line (the canonical timeline, segments, chunks), one line per chunk as it is
                           made (each prompt's span is generated whole and sent out in chunks), a last
                           "done" line

Bad input is HTTP 400 with {"error": "<field>: <one line>"}, checked before the job is queued;
requests from another Host or Origin, non-JSON POSTs and oversized or slow bodies are refused
before any route runs (stablemo.serve.guard). All generation runs on one worker thread: a request
that arrives while another computes waits its turn (FIFO) instead of splitting the cores, and
past `max_queue` waiting requests the answer is 503 at once. GIFs and BVH files are made on a
second thread so a download does not hold up typing; a download whose file is not made within
`render_budget_s` (queue wait included) is a 503, so one costly download cannot hold others for long.
Both threads are daemons: stopping the server never waits for a job to finish.
"""

# no `from __future__ import annotations`: FastAPI reads the route functions' annotations at run time
import asyncio
import contextlib
import io
import json
import logging
import queue
import tempfile
import threading
import time
from concurrent.futures import Future
from pathlib import Path

import numpy as np
from fastapi import FastAPI, Request
from fastapi.responses import FileResponse, JSONResponse, Response, StreamingResponse
from fastapi.staticfiles import StaticFiles

from stablemo.errors import StableMoError, one_line
from stablemo.serve.guard import LOOPBACK_HOSTS, Guard, read_json
from stablemo.serve.models import (
    ModelSet,
    Motion,
    encode_array,
    json_short,
    motion_json,
)

STATIC_DIR = Path(__file__).resolve().parent / "static"
# glb: our skinned mannequin (stablemo.gltf); fbx: the same through Blender, listed by /api/info
# only when Blender is on PATH (without it the download is a one-line 400)
DOWNLOADS = {"joints.npy": "application/octet-stream", "features.npy": "application/octet-stream",
             "glb": "model/gltf-binary", "fbx": "application/octet-stream",
             "gif": "image/gif", "bvh": "application/octet-stream"}
log = logging.getLogger("stablemo.serve")
# An honest GIF of the longest demo motion (196 frames) took 3-6 s on the 2-core machine at load 3
# (docs/serve.md): 60 s is a 10x margin. A download waits at most this long, its wait in the render
# queue included.
RENDER_BUDGET_S = 60.0


class Busy(Exception):
    pass


class Worker:
    """One daemon thread running jobs in arrival order, and a bounded count of requests waiting for
    it (counted on the event loop, the one being computed included). A daemon, not a
    ThreadPoolExecutor: the interpreter joins an executor's threads at exit, so a long job would
    hold a stopping server; a job whose request went away before it started is skipped."""

    def __init__(self, max_queue: int, name: str):
        self.max_queue, self.waiting, self.name = max_queue, 0, name
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        while (job := self._jobs.get()) is not None:
            future, fn, args = job
            if not future.set_running_or_notify_cancel():
                continue  # cancelled while it waited (the client disconnected, the server stops)
            try:
                future.set_result(fn(*args))
            except BaseException as err:  # handed to the awaiting request, which reports it
                future.set_exception(err)

    async def run(self, fn, *args, budget_s: float | None = None):
        """fn(*args) on the worker thread. budget_s: raise Busy if the result (queue wait included)
        takes longer; the job then finishes on its own, unread (a thread cannot be stopped)."""
        if self.waiting >= self.max_queue:
            raise Busy(f"server busy: {self.waiting} requests are waiting; try again shortly")
        self.waiting += 1
        try:
            future: Future = Future()
            self._jobs.put((future, fn, args))
            result = asyncio.wrap_future(future)  # cancelling this request cancels a job not yet started
            try:
                return await (result if budget_s is None else asyncio.wait_for(result, budget_s))
            except TimeoutError:
                raise Busy(f"server busy: the job took over {budget_s:g} s and was abandoned; "
                           "try again shortly") from None
            except asyncio.CancelledError:
                # the server is stopping (uvicorn cancels what is still running after its short grace
                # time): a one-line 503 for the client instead of a traceback in the log
                raise Busy("server busy: the request was cancelled because the server is stopping") from None
        finally:
            self.waiting -= 1

    def shutdown(self) -> None:
        """Cancel what waits and let the thread end after the job it is on (without waiting for it)."""
        while True:
            try:
                job = self._jobs.get_nowait()
            except queue.Empty:
                break
            if job is not None:
                job[0].cancel()
        self._jobs.put(None)


def create_app(models: ModelSet, max_queue: int = 32, static_dir: Path = STATIC_DIR, hosts=LOOPBACK_HOSTS,
               render_budget_s: float = RENDER_BUDGET_S, **guard):
    """The app. hosts: the names the server answers to in Host (tests add FastAPI's 'testserver');
    guard: Guard's max_body / body_timeout."""
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
    app.add_middleware(Guard, hosts=hosts, **guard)

    def error(status: int, message: str) -> JSONResponse:
        return JSONResponse({"error": short_line(message)}, status_code=status)

    async def parse(request: Request):
        return models.parse(await read_json(request))

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
        from stablemo.gltf.fbx import blender_path

        offered = [f for f in sorted(DOWNLOADS) if f != "fbx" or blender_path()]
        return {**models.describe(), "downloads": offered, "max_queue": max_queue}

    rest_bodies: dict[str, bytes] = {}

    @app.get("/api/rest.glb")
    async def rest_glb(model: str | None = None):
        name = models.default if model is None else model
        if name not in models.models:
            raise StableMoError(f"model: unknown model {json_short(name)}; served: {', '.join(models.models)}")
        if name not in rest_bodies:
            rest_bodies[name] = standing_bytes(models.models[name].pipeline)
        return Response(rest_bodies[name], media_type=DOWNLOADS["glb"])

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
        job = models.parse_stream(await read_json(request))

        async def lines():
            start = time.perf_counter()
            yield json.dumps(job.header()) + "\n"
            while True:
                try:  # one chunk per turn of the worker: other requests interleave with a long stream
                    chunk = await generate_worker.run(next, job.chunks, None)
                except (StableMoError, Busy) as err:
                    yield json.dumps({"error": short_line(str(err))}) + "\n"
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
        body = await read_json(request)
        if isinstance(body, dict) and "timeline" in body:  # a streamed motion: the /api/stream body + format
            job = models.parse_stream(body, download=True)
            fmt = check_format(job.format)
            motion, _ = await generate_worker.run(models.stream_motion, job)
        else:
            spec, options = models.parse(body)
            fmt = check_format(options["format"])
            motion, _, _ = await run_job(spec)
        if fmt == "gif":
            data = await render_worker.run(gif_bytes, motion, budget_s=render_budget_s)
        elif fmt in ("glb", "fbx"):
            data = await render_worker.run(body_bytes, motion, fmt, budget_s=render_budget_s)
        elif fmt == "bvh":
            data = await render_worker.run(bvh_bytes, motion, budget_s=render_budget_s)
        else:
            data = npy_bytes(motion.joints if fmt == "joints.npy" else motion.features)
        return Response(data, media_type=DOWNLOADS[fmt],
                        headers={"Content-Disposition": f'attachment; filename="{motion.file_name(fmt)}"'})

    @app.post("/api/retarget")
    async def retarget(request: Request):
        from stablemo.retarget.api import retarget_bvh_text, rig_from_text

        body = await read_json(request)
        if not isinstance(body, dict) or "rig" not in body:
            raise StableMoError("rig: missing (the text of a humanoid rig's BVH file)")
        body = dict(body)
        rig_text, role_map = body.pop("rig"), body.pop("rig_map", None)
        spec, _ = models.parse(body)
        rig, role_map = await render_worker.run(rig_from_text, rig_text, role_map, budget_s=render_budget_s)
        motion, _, _ = await run_job(spec)
        text = await render_worker.run(retarget_bvh_text, motion.joints, rig, role_map, motion.fps,
                                       budget_s=render_budget_s)
        name = motion.file_name("bvh").removesuffix(".bvh") + "-retarget.bvh"
        return Response(text.encode("utf-8"), media_type=DOWNLOADS["bvh"],
                        headers={"Content-Disposition": f'attachment; filename="{name}"'})

    app.mount("/static", StaticFiles(directory=static_dir), name="static")
    return app


def check_format(fmt) -> str:
    if fmt not in DOWNLOADS:
        raise StableMoError(f"format: expected one of {', '.join(sorted(DOWNLOADS))}, got {json_short(fmt)}")
    if fmt == "fbx":  # before the motion is made: FBX needs Blender on this machine
        from stablemo.gltf.fbx import check_blender

        check_blender("format")
    return fmt


MAX_ERROR_CHARS = 500


def short_line(message: str) -> str:
    """An error as one line of at most MAX_ERROR_CHARS: a message quoting what a client sent (a
    value, a field name) never echoes a megabyte back."""
    line = one_line(message)
    return line if len(line) <= MAX_ERROR_CHARS else line[:MAX_ERROR_CHARS - 3] + "..."


def npy_bytes(arr: np.ndarray) -> bytes:
    """An .npy file's bytes, built in memory (the download is the only copy; nothing on disk)."""
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, np.ascontiguousarray(arr, dtype=np.float32), allow_pickle=False)
    return buffer.getvalue()


def bvh_bytes(motion: Motion) -> bytes:
    """The motion as BVH (stablemo.bvh: a T-pose rig of the bundle's body, rotations at the motion's
    frame rate, metres), the rig made with the motion; /api/generate's `warnings` say how close it is."""
    return motion.bvh.bvh().encode("ascii")


def body_bytes(motion: Motion, fmt: str) -> bytes:
    """The motion on our skinned mannequin (stablemo.gltf), the rig of its BVH download: GLB, or FBX
    through Blender (made in a private temporary folder, removed once read)."""
    from stablemo.gltf import export_glb
    from stablemo.outputs.render import COLOURS

    glb = export_glb(motion.bvh, COLOURS, name=motion.file_name(fmt).rsplit(".", 1)[0])
    if fmt == "glb":
        return glb
    from stablemo.gltf.fbx import glb_to_fbx

    with tempfile.TemporaryDirectory(prefix="stablemo-serve-") as tmp:
        return glb_to_fbx(glb, Path(tmp) / "motion.fbx", motion.fps).read_bytes()


def standing_bytes(pipe) -> bytes:
    """A model's body standing at ease, on the floor (stablemo.gltf.standing_glb), as a GLB."""
    from stablemo.gltf import standing_glb
    from stablemo.outputs.render import COLOURS

    return standing_glb(pipe.skeleton, pipe.finish.bone_lengths, COLOURS)


def gif_bytes(motion: Motion) -> bytes:
    """The motion as `stablemo render` draws it. The renderer writes files, so it writes into a
    private temporary folder that is removed with everything in it when the bytes are read."""
    from stablemo.outputs.render import render_animation

    with tempfile.TemporaryDirectory(prefix="stablemo-serve-") as tmp:
        path = render_animation(motion.joints, Path(tmp) / "motion.gif", motion.info["skeleton"], fps=motion.fps,
                                title=motion.spec.text)
        return path.read_bytes()
