"""`stablemo bench stream`: the cost of one streamed chunk, teacher and 1-step student side by side.

    stablemo bench stream [--bundle DIR] [--student DIR] [--chunks 20] [--chunk-seconds 2] [--threads 1]

Two streams of the same prompts run interleaved (teacher chunk, student chunk, teacher chunk, ...),
so both rows see the same machine load; each row times `next(stream)`: the text encoding (cached
after the first chunk of a prompt), the in-painted sampling of the window (context + chunk), the
joints and their placement in the global frame. The first chunk of each stream is warm-up (kernel
packing, text encoder) and not counted. Without --student the packaged demo student is used when
present, else a 1-step LCM student holding the teacher's weights (stablemo.bench.aits's, as distillation
starts it: its timing is a trained student's, its motion is not).
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path

import torch

from stablemo.errors import StableMoError
from stablemo.inference.bundle import DEMO_STUDENT

STUDENT_ASSET = DEMO_STUDENT
PROMPTS = ["a person walks forward", "a person turns left", "a person jumps in place", "a person runs forward"]


def _student(pipe, path: str | None):
    from stablemo.inference.pipeline import Pipeline

    if path is not None:
        if not Path(path).is_dir():
            raise StableMoError(f"--student: {path}: bundle folder not found")
        return Pipeline.from_bundle(path), path
    if (STUDENT_ASSET / "config.json").is_file():
        return Pipeline.from_bundle(STUDENT_ASSET), str(STUDENT_ASSET)
    from stablemo.bench.aits import student_pipeline

    return student_pipeline(pipe, fast=True), "1-step LCM student with the teacher's weights (timing only)"


def run_stream_bench(args) -> dict:
    from stablemo.inference.bundle import bundle_or_demo
    from stablemo.inference.pipeline import Pipeline

    pipe = Pipeline.from_bundle(bundle_or_demo(args.bundle))
    student, student_name = _student(pipe, args.student)
    texts = lambda i, prev: PROMPTS[(i // 3) % len(PROMPTS)]  # the text changes every 3 chunks
    rows = {
        f"teacher ({pipe.inference.sampler}, {pipe.inference.steps} steps, cfg {pipe.inference.cfg:g})":
            pipe.stream(texts, args.chunk_seconds, seed=args.seed, context_seconds=args.context_seconds),
        f"student ({student.inference.sampler}, {student.inference.steps} step)":
            student.stream(texts, args.chunk_seconds, seed=args.seed, context_seconds=args.context_seconds),
    }
    times: dict[str, list[tuple[float, float]]] = {name: [] for name in rows}
    for i in range(args.chunks + 1):
        for name, chunks in rows.items():
            wall, cpu = time.perf_counter(), time.process_time()
            next(chunks)
            if i:  # chunk 0 is warm-up
                times[name].append((time.perf_counter() - wall, time.process_time() - cpu))
    return {"student": student_name, "chunk_seconds": args.chunk_seconds, "context_seconds": args.context_seconds,
            "frames": round(args.chunk_seconds * pipe.fps), "threads": torch.get_num_threads(), "times": times}


def format_report(result: dict) -> str:
    lines = [(f"Streaming: {result['chunk_seconds']:g} s chunks ({result['frames']} frames) after "
              f"{result['context_seconds']:g} s of context, {result['threads']} thread(s); student: {result['student']}"),
             "", "| row | ms per chunk (median) | mean | min | CPU ms (median) | x real time |", "|---|---|---|---|---|---|"]
    for name, samples in result["times"].items():
        wall = [w * 1e3 for w, _ in samples]
        cpu = [c * 1e3 for _, c in samples]
        med = statistics.median(wall)
        lines.append(f"| {name} | {med:.1f} | {statistics.mean(wall):.1f} | {min(wall):.1f} | "
                     f"{statistics.median(cpu):.1f} | {result['chunk_seconds'] * 1e3 / med:.0f} |")
    return "\n".join(lines)


__all__ = ["format_report", "run_stream_bench"]
