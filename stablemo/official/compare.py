"""Official T2MUnet vs its StableMo import, side by side in one run (numbers for docs/official.md).

    stablemo bench official --official-src DIR [--clip PATH] [--size paper|small]
        [--frames 196] [--aits] [--repeats 3] [--threads 1] [--seed 0] [--json FILE]

1. Builds the official network with the official code (a checkout at DIR, see reference.py), its
   zero-initialised layers given PyTorch's default initialisation (reference.randomize), saves it
   as the official trainer does (EMA = the same weights), imports it with `import_official`.
2. Equality at the longest length <= --frames that needs no padding (a multiple of 16): the
   conditional output and CFG 2.5 (`forward_with_cfg`), official vs StableMo (stock and fast layers).
3. Padding at --frames: the official forward pads to a multiple of 16 with zeros and no mask, so its
   valid frames see the padding; StableMo's import is exact per frame. Reported: the difference on
   the valid frames, and from which frame on it exceeds 1e-5 of the output's scale.
4. With --aits: seconds per sentence (batch 1, --frames frames, 10 steps of SDE-DPM-Solver++ 2M
   with Karras sigmas, CFG 2.5, fp32) of the official sampling loop (its DiffusePipeline.generate_batch:
   text encoded once, forward_with_cfg, diffusers' DPMSolverMultistepScheduler) and of StableMo's
   pipeline (its bundle defaults), on the same weights, timed round-robin.

Without --clip a random CLIP text model of ViT-B/32's width (512) stands in (reference.write_random_clip);
the networks' weights are random either way: the numbers measure the code, not a trained model.
"""

from __future__ import annotations

import copy
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from stablemo.errors import StableMoError
from stablemo.official import reference

D = 263
PROMPTS = ["a person walks forward and waves with the right hand", "a man jumps up and down twice",
           "someone turns to the left and sits down"]
SIZES = {  # T2MUnet keyword arguments: the published HumanML3D model, and a small one for quick runs
    "paper": dict(base_dim=512, dim_mults=(2, 2, 2, 2), time_dim=512, text_latent_dim=256, text_ff_size=2048),
    "small": dict(base_dim=64, dim_mults=(1, 2, 2, 2), time_dim=128, text_latent_dim=64, text_ff_size=256),
}


def _rel(ours: torch.Tensor, theirs: torch.Tensor) -> float:
    return float((ours - theirs).abs().max() / theirs.abs().max())


def build(src: str, clip: str | None, size: str, seed: int, work: Path):
    """(official T2MUnet in eval mode, StableMo Pipeline of its import, the CLIP folder used)."""
    from stablemo.inference.pipeline import Pipeline
    from stablemo.io import atomic_open, save_npy
    from stablemo.official.convert import import_official

    if clip is None:
        clip_dir = work / "clip"
        hf, tokenizer = reference.write_random_clip(clip_dir, hidden=512, layers=2, seed=seed)
    else:
        from transformers import AutoTokenizer, CLIPTextModel

        clip_dir = Path(clip)
        hf = CLIPTextModel.from_pretrained(clip_dir, weights_only=True).eval()
        tokenizer = AutoTokenizer.from_pretrained(clip_dir)
    module = reference.official_unet_module(src, reference.clip_stand_in(hf, tokenizer))
    torch.manual_seed(seed)
    official = reference.randomize(module.T2MUnet(input_feats=D, clip_dim=hf.config.hidden_size, cond_mask_prob=0.1,
                                                  **SIZES[size])).eval()
    run = work / "run"
    with atomic_open(run / "model" / "latest.tar") as f:
        torch.save(reference.official_checkpoint(official, official, total_it=0), f)
    save_npy(run / "meta" / "mean.npy", np.zeros(D, dtype=np.float32))
    save_npy(run / "meta" / "std.npy", np.ones(D, dtype=np.float32))
    import_official(run / "model" / "latest.tar", work / "bundle", clip=str(clip_dir), log=lambda *_: None)
    return official, Pipeline.from_bundle(work / "bundle", fast=True), Pipeline.from_bundle(work / "bundle", fast=False)


def equality(official, pipes, frames: int, seed: int) -> dict:
    """Max relative errors at the longest unpadded length <= frames (batch 2, two timesteps)."""
    from stablemo.diffusion.guidance import CFGDenoiser

    T = frames // 16 * 16
    gen = torch.Generator().manual_seed(seed)
    x, t = torch.randn(2, T, D, generator=gen), torch.tensor([50, 900])
    mask = torch.ones(2, T, dtype=torch.bool)
    texts = PROMPTS[:2]
    result = {"frames": T}
    with torch.no_grad():
        enc = official.encode_text(texts, "cpu")
        cond_theirs = official(x, t, enc_text=enc)
        cfg_theirs = official.forward_with_cfg(x, t, enc_text=enc, cfg_scale=2.5)
        for name, pipe in pipes.items():
            text, text_mask = pipe.encode(texts)
            null_text, null_mask = pipe.null_condition(2)
            result[f"text_{name}"] = _rel(text, enc)
            result[f"cond_{name}"] = _rel(pipe.model(x, t, enc, torch.ones_like(text_mask), mask), cond_theirs)
            cfg = CFGDenoiser(pipe.model, text, text_mask, null_text, null_mask, mask, scale=2.5)(x, t)
            result[f"cfg_{name}"] = _rel(cfg, cfg_theirs)
    return result


def padding_effect(official, pipe, frames: int, seed: int) -> dict:
    """Official (zero padding to a multiple of 16, no mask) vs StableMo (exact per frame) at `frames`."""
    from stablemo.diffusion.guidance import CFGDenoiser

    gen = torch.Generator().manual_seed(seed + 1)
    x, t = torch.randn(1, frames, D, generator=gen), torch.tensor([500])
    padded_len = -(-frames // 16) * 16
    texts = PROMPTS[:1]
    with torch.no_grad():
        enc = official.encode_text(texts, "cpu")
        theirs = official.forward_with_cfg(x, t, enc_text=enc, cfg_scale=2.5)[0]
        text, text_mask = pipe.encode(texts)
        null_text, null_mask = pipe.null_condition(1)
        mask = torch.arange(padded_len)[None] < frames
        padded = torch.nn.functional.pad(x, (0, 0, 0, padded_len - frames))
        ours = CFGDenoiser(pipe.model, text, text_mask, null_text, null_mask, mask, scale=2.5)(padded, t)[0, :frames]
    scale = float(theirs.abs().max())
    per_frame = (ours - theirs).abs().amax(dim=1) / scale  # (frames,)
    above = (per_frame > 1e-5).nonzero()
    edges = sorted({0, frames // 4, frames // 2, 3 * frames // 4, max(frames - 16, 0), frames})
    return {"frames": frames, "padded_to": padded_len, "t": 500, "max_rel": float(per_frame.max()),
            "mean_abs_rel": float((ours - theirs).abs().mean() / theirs.abs().mean()),
            "max_rel_by_frames": {f"{a}-{b - 1}": float(per_frame[a:b].max()) for a, b in zip(edges, edges[1:])},
            "first_frame_above_1e-5": int(above[0]) if len(above) else None}


def official_loop(official, text: str, frames: int, seed: int, steps: int = 10) -> torch.Tensor:
    """The published DiffusePipeline.generate_batch for one sentence, fp32 (its fp16 is CUDA only)."""
    from diffusers import DPMSolverMultistepScheduler

    scheduler = DPMSolverMultistepScheduler(num_train_timesteps=1000, beta_schedule="linear", prediction_type="sample",
                                            algorithm_type="sde-dpmsolver++", use_karras_sigmas=True)
    torch.manual_seed(seed)
    sample = torch.randn(1, frames, D)
    scheduler.set_timesteps(steps, "cpu")
    with torch.no_grad():
        enc = official.encode_text([text], "cpu")
        for t in scheduler.timesteps:
            predict = official.forward_with_cfg(sample, torch.tensor([int(t)]), enc_text=enc)
            sample = scheduler.step(predict, t, sample).prev_sample
    return sample


def aits(official, pipe, frames: int, repeats: int, seed: int) -> dict:
    """Seconds per sentence, official loop vs StableMo pipeline, round-robin after one warm-up each."""
    runs = {
        "official loop": lambda i: official_loop(official, PROMPTS[i % len(PROMPTS)], frames, seed + i),
        "StableMo": lambda i: pipe.generate([PROMPTS[i % len(PROMPTS)]], [frames], seed=seed + i, steps=10, cfg=2.5,
                                            sampler="dpmpp_2m_sde", dtype="fp32"),
    }
    times = {name: [] for name in runs}
    cpu = {name: [] for name in runs}
    for name, run in runs.items():
        run(repeats)  # warm-up: a sentence not timed below
    for i in range(repeats):
        for name, run in runs.items():
            pipe.clear_text_caches(keep_null=True)  # every sentence encodes its text, as the official loop does
            start, start_cpu = time.perf_counter(), time.process_time()
            run(i)
            times[name].append(time.perf_counter() - start)
            cpu[name].append(time.process_time() - start_cpu)
    # CPU seconds stay meaningful when other processes share the cores (wall time then measures the queue)
    return {name: {"mean_s": statistics.mean(v), "best_s": min(v), "samples": v, "best_cpu_s": min(cpu[name]),
                   "cpu_samples": cpu[name]} for name, v in times.items()}


def run_compare(args) -> dict:
    """`stablemo bench official` (args: its options): equality, padding effect and, with args.aits,
    the paired timing; prints them, writes args.json if given, returns the result."""
    if not 16 <= args.frames <= 10_000:
        raise StableMoError(f"--frames: must be in [16, 10000], got {args.frames}")
    if args.json:
        from stablemo.io import check_output_file

        check_output_file(args.json, "--json")
    if args.threads:
        torch.set_num_threads(args.threads)
    with tempfile.TemporaryDirectory() as tmp:
        official, fast, stock = build(args.official_src, args.clip, args.size, args.seed, Path(tmp))
        result = {"size": args.size, "threads": torch.get_num_threads(),
                  "parameters_M": sum(p.numel() for p in stock.model.parameters()) / 1e6,
                  "equality": equality(official, {"stock": stock, "fast": fast}, args.frames, args.seed),
                  "padding": padding_effect(official, copy.deepcopy(stock), args.frames, args.seed)}
        print(json.dumps(result, indent=2))
        if args.aits:
            result["aits"] = aits(official, fast, args.frames, args.repeats, args.seed)
            print(json.dumps(result["aits"], indent=2))
    if args.json:
        from stablemo.io import write_text

        write_text(args.json, json.dumps(result, indent=2) + "\n")
    return result

