"""`stablemo bench`: inference timing (AITS, paper Table 5) and, via the training package, training speed.

    stablemo bench aits [--config FILE | --bundle DIR] [--random-weights] [--frames 196] [--repeats N]
    stablemo bench stream [--chunks N] [--chunk-seconds 2]   (stablemo.bench.timeline)
    stablemo bench train ...   (stablemo.bench.train)

AITS = average inference time per sentence: batch 1, text in -> de-normalised features and joints
out, model loading and warm-up (one untimed 2-step generation per row) excluded. The progressive
tricks of Table 5 are measured side by side in one run, each row adding one trick to the previous
one:

    DDPM 1000 steps (text re-encoded at every call, CFG as two forwards, fp32)
    + 10-step SDE-DPM-Solver++ 2M (Karras)
    + text cache (prompt encoded once per request)
    + parallel CFG (conditional and unconditional halves in one forward)
    + low precision (bf16 on CPU, fp16 on CUDA; network only)

and, for the distillation speed-up, a 1-step LCM consistency student of the same network (its
guidance embedded: one forward of batch 1 per sentence, fp32), as `stablemo distill` exports it
before training (the student starts as a copy of the teacher, so the timing is the trained one's).
`--bundle` with a student bundle times its own row; with a controlled bundle (kind `controlnet`),
its frozen base beside it following a dense pelvis path, without and with one guidance
refinement, all at the bundle's own sampler, steps and CFG.

The denoiser's FLOPs per step come from torch.utils.flop_counter; achieved GFLOP/s of a row are
steps x FLOPs/step / AITS, and its efficiency is that over this machine's fp32 matmul throughput,
measured in the same run (a 2048^3 matmul, best of 5, sampled before every row and at the end; the
median sample is the reference). Both are also reported per CPU-second, which stays meaningful
when other processes compete for the cores (wall-clock figures then mostly measure the queue).
On a shared machine run with `--threads 1`, or with OMP_WAIT_POLICY=PASSIVE in the environment,
so that OpenMP threads waiting for a descheduled sibling do not spin and inflate the CPU time.
"""

from __future__ import annotations

import json
import statistics
import sys
from dataclasses import dataclass, replace

import torch

from stablemo.bench.measure import (  # noqa: F401 (re-exported: tests and scripts use stablemo.bench.aits.*)
    _fastest,
    baseline_denoiser,
    denoiser_flops,
    matmul_gflops,
    time_generation,
)
from stablemo.errors import StableMoError
from stablemo.fast import gemm
from stablemo.inference.bundle import ASSETS, DEMO_CONTROLNET
from stablemo.inference.config import (
    MAX_FRAMES,
    InferenceConfig,
)
from stablemo.inference.kinds import model_kind
from stablemo.nets.config import load_model_config

# StableMoFusion's network as the HumanML3D training config describes it (paper §4.1.1, §5.1):
# Conv1D UNet, base 512, multipliers [2, 2, 2, 2], time embedding 512, text latent 256 with 4
# transformer layers. The paper's frozen encoder is CLIP ViT-B/32; the packaged MiniLM stands in
# for it here unless --text-encoder says otherwise (it runs once per request, not per step).
PAPER_NETWORK = ASSETS / "paper_network.yaml"  # shipped in the package; configs/humanml3d.yaml trains it
STAND_IN_ENCODER = "minilm"

PROMPTS = [
    "a person walks forward and waves with the right hand",
    "a man jumps up and down twice",
    "someone turns to the left and sits down",
    "a person runs in a circle",
    "the person kicks with the left leg then steps back",
    "a figure raises both arms above the head",
    "a person walks backwards slowly",
    "a man crouches and then stands up",
]


# The longest motion timed for a network given by --config (no bundle states its range); a
# bundle's own [min_length, max_length] applies to --bundle.
CONFIG_MAX_FRAMES = 10_000

STUDENT_ROW = "1-step LCM student (fp32)"
CONTROLNET_ROW = "1-step + ControlNet (fp32)"  # dense pelvis targets
CONTROLNET_GUIDED_ROW = "1-step + ControlNet + guidance (fp32)"  # and one guidance refinement
TEACHER_ROW = "+ parallel CFG"
# A test set's spread of motion lengths (HumanML3D keeps 40-196 frames): AITS is defined over a
# test set, where every sentence may bring a length (a row count) the kernels have not seen yet.
VARIED_LENGTHS = (40, 64, 88, 120, 152, MAX_FRAMES)


@dataclass
class Row:
    name: str
    sampler: str
    steps: int
    text_cache: bool
    parallel_cfg: bool
    dtype: str
    seconds: list[float]
    cpu_seconds: list[float]
    measured_steps: int
    flops_per_step: float

    @property
    def aits(self) -> float:
        """Seconds per sentence for the full number of steps (extrapolated if fewer were run)."""
        return statistics.mean(self.seconds) * self.steps / self.measured_steps

    @property
    def best(self) -> float:
        return min(self.seconds) * self.steps / self.measured_steps

    @property
    def cpu(self) -> float:
        """CPU seconds (all threads) per sentence, best repeat, full number of steps."""
        return min(self.cpu_seconds) * self.steps / self.measured_steps


# ---- model --------------------------------------------------------------------------------------


def model_kwargs(config_path: str | None) -> tuple[dict, str]:
    """MotionDiffusionModel kwargs from YAML (stablemo.nets.config): by default the paper network of
    stablemo/assets/paper_network.yaml with the packaged text encoder; a denoiser-only file gets that
    network's text conditioner."""
    paper = load_model_config(PAPER_NETWORK)
    paper["text"]["encoder"] = STAND_IN_ENCODER
    if config_path is None:
        layout = paper["denoiser"].get("variant", "stablemo")
        return paper, f"paper UNet ({PAPER_NETWORK.name}: the {layout} layout, {STAND_IN_ENCODER} text encoder)"
    kwargs = load_model_config(config_path, "--config", text_defaults=paper["text"])
    kwargs["denoiser"].setdefault("input_dim", 263)
    kwargs["text"].setdefault("latent_dim", kwargs["denoiser"].get("text_dim", 256))
    return kwargs, str(config_path)


def _build_pipeline(args, fast: bool):
    from stablemo.diffusion.schedule import NoiseSchedule
    from stablemo.inference.pipeline import Pipeline
    from stablemo.nets.model import MotionDiffusionModel

    if args.bundle:
        pipe = Pipeline.from_bundle(args.bundle, device=args.device, fast=fast and not args.random_weights)
        if not args.random_weights:
            return pipe, f"bundle {args.bundle}"
        # the bundle's network as it is built before training (seeded): its speed, not its weights
        kind = pipe.config.get("kind", "diffusion")
        torch.manual_seed(args.seed)
        model = model_kind(kind, args.bundle).build_model(pipe.config, args.bundle)
        return (_sibling_pipeline(pipe, model, kind, pipe.config, pipe.inference, fast),
                f"bundle {args.bundle} (random weights)")
    kwargs, source = model_kwargs(args.config)
    if args.text_encoder:
        kwargs["text"]["encoder"] = args.text_encoder
    torch.manual_seed(args.seed)
    model = MotionDiffusionModel(**kwargs)
    dim = int(kwargs["denoiser"]["input_dim"])
    pipe = Pipeline(model, NoiseSchedule(), mean=[0.0] * dim, std=[1.0] * dim, prediction_type="sample",
                    skeleton="humanml3d" if dim == 263 else "kit", device=args.device, fast=fast, config={"model": kwargs},
                    inference=InferenceConfig(max_length=CONFIG_MAX_FRAMES))
    return pipe, f"{source}, random weights"


def _sibling_pipeline(pipe, model, kind: str, config: dict, inference, fast: bool):
    """A pipeline for `model` with `pipe`'s schedule, statistics, prediction type, skeleton and device."""
    from stablemo.inference.pipeline import Pipeline

    return Pipeline(model, pipe.schedule, mean=pipe.mean.numpy(), std=pipe.std.numpy(),
                    prediction_type=pipe.prediction_type, skeleton=pipe.skeleton, kind=kind, device=pipe.device,
                    config=config, inference=inference, fast=fast)


def student_pipeline(pipe, fast: bool):
    """A 1-step LCM student of `pipe`'s network (stablemo.distill's defaults), with the teacher's weights."""
    from stablemo.distill.student import ConsistencyStudent

    student = ConsistencyStudent(pipe.config["model"])
    student.model.load_state_dict(pipe.model.state_dict())
    config = {"consistency": {"mode": "lcm", "ddim_steps": 50, "sigma_data": 0.5, "timestep_scale": 10.0}}
    inference = replace(pipe.inference, sampler="lcm", steps=1, cfg=1.0)
    return _sibling_pipeline(pipe, student, "consistency", config, inference, fast)


CONTROLNET_ASSET = DEMO_CONTROLNET


def _shipped_control_form() -> dict:
    """The shipped pelvis ControlNet's form (hint encoder, path channels, output injection), read
    from its config.json, so the benchmark times the ControlNet users get."""
    path = CONTROLNET_ASSET / "config.json"
    if not path.is_file():
        raise StableMoError(f"{path}: the shipped ControlNet is missing (a source checkout has it); pass --skip-controlnet")
    return dict(json.loads(path.read_text())["controlnet"]["control"])


def _controlled_pipeline(pipe, student, fast: bool):
    """`student` (a 1-step LCM pipeline of `pipe`'s network) with a ControlNet on its network
    (stablemo.control.controlnet; its injections start at zero, so the timing is a trained one's)."""
    from stablemo.control.controlnet import ControlledModel
    from stablemo.distill.student import ConsistencyStudent
    from stablemo.motion.skeleton import get_skeleton

    J = get_skeleton(student.skeleton).num_joints
    base = ConsistencyStudent(pipe.config["model"])  # stock modules: the ControlNet copies them (fast ones hold packed weights)
    base.model.load_state_dict(pipe.model.state_dict())
    control = _shipped_control_form()
    model = ControlledModel(base, "consistency", J, control)
    config = {**student.config, "controlnet": {"base_kind": "consistency", "joints": J, "hint_scale": 1.0,
                                               "control": control}}
    return _sibling_pipeline(student, model, "controlnet", config, student.inference, fast)


def _pelvis_path(frames: int, skeleton):
    """Dense pelvis targets: 1 m/s forward at hip height, from the origin (MotionLCM's test setting)."""
    import numpy as np

    from stablemo.control.spec import JointControl
    from stablemo.motion.skeleton import get_skeleton

    J = get_skeleton(skeleton).num_joints
    pos = np.zeros((frames, J, 3), np.float32)
    pos[:, 0, 1] = 0.9
    pos[:, 0, 2] = np.arange(frames) / 20.0
    mask = np.zeros((frames, J), bool)
    mask[:, 0] = True
    return JointControl(pos, mask)


def time_sentences(pipe, args, sampler: str, steps: int, text_cache: bool, parallel_cfg: bool, dtype,
                   max_steps: int | None = None, cfg: float | None = None, **control) -> tuple[list[float], list[float], int]:
    """`args.repeats` timed sentences (wall s, CPU s each) and how many sampler steps each ran, at
    guidance `cfg` (default `args.cfg`); control: `control=` and `control_guidance=` of every request."""
    seconds, cpu_seconds, measured = [], [], steps
    for r in range(args.repeats):
        elapsed, cpu, measured = time_generation(pipe, PROMPTS[r % len(PROMPTS)], args.frames, sampler, steps,
                                                 args.cfg if cfg is None else cfg, text_cache, parallel_cfg, dtype, args.seed + r, max_steps,
                                                 **control)
        seconds.append(elapsed)
        cpu_seconds.append(cpu)
    return seconds, cpu_seconds, measured


def run_aits(args) -> dict:
    threads = torch.get_num_threads()
    if args.threads:
        torch.set_num_threads(args.threads)
    try:
        return _run_aits(args)
    finally:
        torch.set_num_threads(threads)


def _base_pipeline(pipe, fast: bool):
    """The frozen base of a controlled bundle's pipeline as a pipeline of its own kind (the same
    modules: the base's weights are shared, not copied)."""
    kind = pipe.model.base_kind
    config = {k: v for k, v in pipe.config.items() if k != "controlnet"} | {"kind": kind}
    return _sibling_pipeline(pipe, pipe.model.base, kind, config, pipe.inference, fast)


def _bundle_rows(pipe, args, fast: bool) -> tuple[list[Row], float, str | None]:
    """Rows for a bundle that is not a plain diffusion model, at its own sampler, steps and CFG: a
    consistency student's one row; a controlled bundle's base beside the bundle following a dense
    pelvis path, without and with one guidance refinement. Returns the rows, the base network's
    FLOPs per denoiser call, and the name of the row the controlled ones are compared with."""
    inf = pipe.inference
    cfg = inf.cfg
    kind = pipe.config.get("kind", "diffusion")
    base = _base_pipeline(pipe, fast) if kind == "controlnet" else pipe
    # a teacher-based ControlNet runs CFG as one batch of 2; a student embeds its guidance
    batch = 2 if kind == "controlnet" and pipe.model.base_kind == "diffusion" else 1
    student = base.config.get("kind") == "consistency"
    base_name = STUDENT_ROW if student and inf.steps == 1 else f"base, {inf.steps} {inf.sampler} steps (fp32)"
    flops = denoiser_flops(base, args.frames, batch)
    time_generation(base, "warm up", args.frames, inf.sampler, 2, cfg, True, True, "fp32", 0)  # 2 calls: packs
    seconds, cpu_seconds, _ = time_sentences(base, args, inf.sampler, inf.steps, True, True, "fp32", cfg=cfg)
    rows = [Row(base_name, inf.sampler, inf.steps, True, not student, "fp32", seconds, cpu_seconds, inf.steps, flops)]
    if kind != "controlnet" or args.skip_controlnet:
        return rows, flops, None
    spec = _pelvis_path(args.frames, pipe.skeleton)
    flops_control = denoiser_flops(pipe, args.frames, batch)
    time_generation(pipe, "warm up", args.frames, inf.sampler, 2, cfg, True, True, "fp32", 0, control=spec)
    names = (CONTROLNET_ROW, CONTROLNET_GUIDED_ROW) if base_name == STUDENT_ROW else \
        (f"+ ControlNet, {inf.steps} steps (fp32)", f"+ ControlNet + guidance, {inf.steps} steps (fp32)")
    for name, refine in zip(names, (False, True)):
        seconds, cpu_seconds, _ = time_sentences(pipe, args, inf.sampler, inf.steps, True, True, "fp32", cfg=cfg,
                                                 control=spec, control_guidance=refine)
        rows.append(Row(name, inf.sampler, inf.steps, True, not student, "fp32", seconds, cpu_seconds, inf.steps,
                        flops_control))
    return rows, flops, base_name


def _run_aits(args) -> dict:
    pipe, source = _build_pipeline(args, fast=not args.stock)
    check_frames(args.frames, pipe)
    low = "fp16" if pipe.device.type == "cuda" else "bf16"
    B = 1
    if pipe.config.get("kind", "diffusion") != "diffusion":
        peaks = [matmul_gflops()]
        rows, flops, base_name = _bundle_rows(pipe, args, fast=not args.stock)
        peaks.append(matmul_gflops())
        return _result(args, pipe, source, low, flops, rows, peaks, None, base_name, cfg=pipe.inference.cfg)
    flops_cfg = denoiser_flops(pipe, args.frames, 2 * B)  # one step of CFG = 2 sequences
    peaks = [matmul_gflops()]

    rows_spec = [
        ("DDPM 1000 (baseline)", "ddpm", 1000, False, False, "fp32"),
        (f"+ SDE-DPM-Solver++ 2M, {args.steps} steps", "dpmpp_2m_sde", args.steps, False, False, "fp32"),
        ("+ text cache", "dpmpp_2m_sde", args.steps, True, False, "fp32"),
        (TEACHER_ROW, "dpmpp_2m_sde", args.steps, True, True, "fp32"),
        (f"+ low precision ({low})", "dpmpp_2m_sde", args.steps, True, True, low),
    ]
    if args.skip_ddpm:
        rows_spec = rows_spec[1:]
    rows, varied = [], None
    for name, sampler, steps, cache, parallel, dtype in rows_spec:
        # warm-up (part of loading) with this row's own settings: kernels, low-precision weight copies,
        # and accelerate's packed weights, which are laid out for one row count (batch x frames) at a
        # time and made at its second call: a row switching between CFG as one batch and as two
        # passes would otherwise pay the re-packing of every weight inside its first timed sentence
        time_generation(pipe, "warm up", args.frames, sampler, 2, args.cfg, cache, parallel, dtype, 0)
        peaks.append(matmul_gflops())  # the reference is sampled between rows: clocks and neighbours drift
        limit = args.ddpm_steps if sampler == "ddpm" else None
        seconds, cpu_seconds, measured = time_sentences(pipe, args, sampler, steps, cache, parallel, dtype, limit)
        rows.append(Row(name, sampler, steps, cache, parallel, dtype, seconds, cpu_seconds, measured, flops_cfg))
        print(f"  measured {name}: {statistics.mean(seconds):.2f} s over {measured} step(s)", file=sys.stderr)
    if not args.skip_student:
        student = student_pipeline(pipe, fast=not args.stock)
        flops_one = denoiser_flops(pipe, args.frames, B)  # the same network, batch 1 (no CFG pass)
        time_generation(student, "warm up", args.frames, "lcm", 2, args.cfg, True, True, "fp32", 0)  # 2 calls: packs
        seconds, cpu_seconds, _ = time_sentences(student, args, "lcm", 1, True, True, "fp32")
        rows.append(Row(STUDENT_ROW, "lcm", 1, True, False, "fp32", seconds, cpu_seconds, 1, flops_one))
        if not args.skip_controlnet:
            controlled = _controlled_pipeline(pipe, student, fast=not args.stock)
            spec = _pelvis_path(args.frames, pipe.skeleton)
            flops_control = denoiser_flops(controlled, args.frames, B)
            time_generation(controlled, "warm up", args.frames, "lcm", 2, args.cfg, True, True, "fp32", 0, control=spec)
            for name, refine in ((CONTROLNET_ROW, False), (CONTROLNET_GUIDED_ROW, True)):
                seconds, cpu_seconds, _ = time_sentences(controlled, args, "lcm", 1, True, True, "fp32",
                                                         control=spec, control_guidance=refine)
                rows.append(Row(name, "lcm", 1, True, False, "fp32", seconds, cpu_seconds, 1, flops_control))
        varied = varied_length_aits(pipe, student, args)
        print(f"  measured varied lengths: teacher {varied['teacher']:.2f} s, student {varied['student']:.2f} s",
              file=sys.stderr)
    peaks.append(matmul_gflops())
    return _result(args, pipe, source, low, flops_cfg, rows, peaks, varied, STUDENT_ROW, cfg=args.cfg)


def check_frames(frames: int, pipe) -> None:
    """--frames within the model's range, checked once the model is loaded and before anything
    runs: the FLOP count and the warm-ups would otherwise start on it (a million frames ran out
    of memory, or for minutes, instead of the generation's own refusal)."""
    if not pipe.min_length <= frames <= pipe.max_length:
        raise StableMoError(f"--frames: {frames} frames is outside this model's range "
                            f"[{pipe.min_length}, {pipe.max_length}]")


def _result(args, pipe, source: str, low: str, flops: float, rows: list[Row], peaks: list, varied,
            control_base: str | None, cfg: float) -> dict:
    """The run's numbers: rows, the matmul references sampled between them, the environment."""
    low_dtype = torch.bfloat16 if low == "bf16" else torch.float16
    peak_low = _fastest(matmul_gflops(low_dtype))[0] if pipe.device.type == "cpu" else None
    references = [_fastest(p) for p in peaks]
    return {
        "varied_lengths": varied,
        "model": source,
        "parameters_M": sum(p.numel() for p in pipe.model.parameters()) / 1e6,
        "frames": args.frames,
        "cfg": cfg,
        "control_base_row": control_base,
        "threads": torch.get_num_threads(),
        "device": str(pipe.device),
        "kernels": "stock PyTorch" if args.stock else
                   f"stablemo.fast (GEMM convolutions, {gemm.gemm_backend()} packed GEMM)",
        "flops_per_step": flops,
        "matmul_fp32_gflops": statistics.median(w for w, _ in references),
        "matmul_fp32_gflops_per_cpu_s": statistics.median(c for _, c in references),
        "matmul_fp32_samples": references,
        "matmul_fp32_by_product": {name: statistics.median(p[name][0] for p in peaks) for name in peaks[0]},
        "matmul_low_gflops": peak_low,
        "low_precision": low,
        "rows": rows,
    }


def varied_length_aits(pipe, student, args) -> dict:
    """Teacher ('+ parallel CFG' settings) and 1-step student AITS over sentences of VARIED_LENGTHS,
    timed side by side (round-robin, cold text caches), as a test set's AITS would see them."""
    from stablemo.eval import metrics

    lengths = [min(max(n, pipe.min_length), pipe.max_length) for n in VARIED_LENGTHS]  # as reported
    texts = [PROMPTS[i % len(PROMPTS)] for i in range(len(lengths))]
    methods = {TEACHER_ROW: metrics.pipeline_method(pipe, args.steps, args.cfg, "dpmpp_2m_sde", args.seed),
               STUDENT_ROW: metrics.pipeline_method(student, 1, args.cfg, "lcm", args.seed)}
    times = metrics.average_inference_times(methods, texts, lengths, warmup=0)  # warm already, not at these lengths
    return {"lengths": lengths, "teacher": times[TEACHER_ROW], "student": times[STUDENT_ROW]}


def _span(samples: list[tuple[float, float]]) -> str:
    wall = [w for w, _ in samples]
    cpu = [c for _, c in samples]
    return f"{min(wall):.0f}-{max(wall):.0f} wall, {min(cpu):.0f}-{max(cpu):.0f} per CPU-s"


def format_report(result: dict) -> str:
    peak, peak_cpu = result["matmul_fp32_gflops"], result["matmul_fp32_gflops_per_cpu_s"]
    lines = [
        f"AITS benchmark: {result['model']} ({result['parameters_M']:.1f} M parameters)",
        f"batch 1, {result['frames']} frames, CFG {result['cfg']:g}, device {result['device']}, "
        f"{result['threads']} thread(s), kernels: {result['kernels']}",
        f"denoiser FLOPs per step (conditional + unconditional): {result['flops_per_step'] / 1e9:.1f} GFLOP",
        f"measured fp32 matmul (2048^3, best of 5, sampled before every row and at the end; median of the fastest "
        f"product): {peak:.1f} GFLOP/s ({peak_cpu:.1f} per CPU-second; samples {_span(result['matmul_fp32_samples'])}; "
        + ", ".join(f"{name} {value:.1f}" for name, value in result.get("matmul_fp32_by_product", {}).items()) + ")"
        + (f"; {result['low_precision']}: {result['matmul_low_gflops']:.1f} GFLOP/s" if result["matmul_low_gflops"] else ""),
        "",
        f"{'method':<38} {'steps':>5} {'AITS s':>9} {'best s':>8} {'GFLOP/s':>8} {'of matmul':>9} {'CPU s':>8} {'per CPU-s':>9}",
    ]
    notes = []
    for row in result["rows"]:
        gflops = row.flops_per_step * row.steps / row.aits / 1e9
        cpu_eff = row.flops_per_step * row.steps / row.cpu / 1e9 / peak_cpu
        mark = ""
        if row.measured_steps < row.steps:
            mark = " *"
            notes.append(f"* extrapolated: {row.measured_steps} of {row.steps} steps run, time per step x {row.steps}")
        lines.append(f"{row.name + mark:<38} {row.steps:>5} {row.aits:>9.3f} {row.best:>8.3f} {gflops:>8.1f} "
                     f"{gflops / peak:>9.0%} {row.cpu:>8.2f} {cpu_eff:>9.0%}")
    by_name = {row.name: row for row in result["rows"]}
    if STUDENT_ROW in by_name and TEACHER_ROW in by_name:
        notes.append(f"1-step student AITS / teacher's {by_name[TEACHER_ROW].steps}-step AITS ('{TEACHER_ROW}' row): "
                     f"{by_name[STUDENT_ROW].aits / by_name[TEACHER_ROW].aits:.3f}")
    base = result.get("control_base_row", STUDENT_ROW)
    for name in by_name:
        if "ControlNet" in name and base in by_name:
            notes.append(f"'{name}' AITS / '{base}' AITS: {by_name[name].aits / by_name[base].aits:.2f} "
                         "(dense pelvis path)")
    varied = result.get("varied_lengths")
    if varied:
        notes.append(f"the same two over {len(varied['lengths'])} sentences of varied lengths "
                     f"({', '.join(map(str, varied['lengths']))} frames), side by side: teacher {varied['teacher']:.3f} s, "
                     f"student {varied['student']:.3f} s, ratio {varied['student'] / varied['teacher']:.3f}")
    lines += [""] + notes + [
        "AITS = mean wall time per sentence (text in -> features and joints out). GFLOP/s counts the denoiser only;",
        "'of matmul' = achieved / measured fp32 matmul throughput (wall clock); 'per CPU-s' = the same ratio with",
        "both measured per CPU-second (all threads), which stays meaningful when other processes share the cores.",
    ]
    return "\n".join(lines)


