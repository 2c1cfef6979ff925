"""`stablemo behaviour`: does each motion do what its prompt says?

    stablemo behaviour [--bundle DIR] [--seeds 4] [--lengths default natural 9.8] [--out results.json]
    stablemo behaviour --ground-truth            # the checks on the synthetic generator's own motions
    stablemo evaluate --behaviour ...            # the same command

Generates every prompt of the suite (stablemo/eval/behaviour/prompts.yaml, or --prompts FILE) at every
length with seeds --seed .. --seed + --seeds - 1, measures the joints (counts, sides, directions,
angles, speeds, body parts, order of composites) and prints the pass rate per attribute, per split
(suite: phrasings of the training captions; held_out: paraphrases and subjects none uses) and per
length, with Wilson 95 % intervals. docs/evaluation.md ("Behaviour") says what each check measures.
"""

from __future__ import annotations

import argparse
import sys
from datetime import datetime, timezone

from stablemo.checks import check_finite, check_positive_int, check_seed
from stablemo.errors import StableMoError


def shown_path(path) -> str:
    """A path as a report names it: relative to the checkout when it lies inside it (the demo's
    bundles, wherever the repository was cloned), else as given."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]  # the checkout: stablemo/cli/behaviour.py's grandparent
    try:
        return Path(path).resolve().relative_to(root).as_posix()
    except ValueError:
        return str(path)


def _parser() -> argparse.ArgumentParser:
    from stablemo.eval.behaviour.runner import DEFAULT_LENGTHS, DEFAULT_SEEDS

    p = argparse.ArgumentParser(prog="stablemo behaviour", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--bundle", help="inference bundle to score (default: the packaged demo teacher)")
    p.add_argument("--ground-truth", action="store_true",
                   help="score the synthetic generator's own motions of each prompt instead of a model's")
    p.add_argument("--prompts", help="prompt table (YAML, the layout of the packaged one)")
    p.add_argument("--split", choices=["suite", "held_out"], help="only this split's prompts")
    p.add_argument("--lengths", nargs="+", default=list(DEFAULT_LENGTHS),
                   help="'default' (no length given: the bundle's length predictor, else its default length; "
                        "--ground-truth: 6 s), 'natural' (the action's own length) or seconds "
                        f"(default: {' '.join(DEFAULT_LENGTHS)})")
    p.add_argument("--seeds", type=int, default=DEFAULT_SEEDS, help="motions per prompt and length")
    p.add_argument("--seed", type=int, default=0, help="first seed")
    p.add_argument("--steps", type=int, default=None, help="default: the bundle's inference config")
    p.add_argument("--sampler", default=None, help="default: the bundle's inference config")
    p.add_argument("--cfg", type=float, default=None, help="default: the bundle's inference config")
    p.add_argument("--evaluator", help="text-motion evaluator for the R@3 of the same motions "
                                        "(default: the packaged synthetic one, stablemo/assets/evaluator_synth)")
    p.add_argument("--no-retrieval", dest="retrieval", action="store_false",
                   help="leave out R@3 (which shows what retrieval misses: motions failing a check that it ranks top 3)")
    p.add_argument("--whole", action="store_true",
                   help="give the network each prompt whole at each length (default: as `stablemo generate` does, "
                        "prompts that say an order in parts, lengths longer than the text asks for ending standing, "
                        "and turns sized by their words)")
    p.add_argument("--batch-size", type=int, default=64, help="motions per network batch")
    p.add_argument("--device", default=None)
    p.add_argument("--dtype", choices=["fp32", "bf16", "fp16"], default=None)
    p.add_argument("--out", help="write the results (settings, summary, every motion's verdicts) as JSON here")
    p.add_argument("--no-progress", action="store_true")
    return p


def _check(args) -> None:
    """Every option, before anything is loaded or generated."""
    check_positive_int("--seeds", args.seeds)
    check_seed("--seed", args.seed, args.seeds)
    check_positive_int("--batch-size", args.batch_size)
    if args.steps is not None:
        check_positive_int("--steps", args.steps)
    if args.cfg is not None:
        check_finite("--cfg", args.cfg, low=0.0, high=100.0)
    if args.evaluator and not args.retrieval:
        raise StableMoError("--evaluator: serves the R@3 column, which --no-retrieval leaves out")
    if args.ground_truth:
        given = [f for f, v in (("--bundle", args.bundle), ("--steps", args.steps), ("--sampler", args.sampler),
                                ("--cfg", args.cfg), ("--dtype", args.dtype), ("--device", args.device)) if v is not None]
        if given:
            raise StableMoError(f"{given[0]}: --ground-truth scores the synthetic motions, not a model")


def main(argv: list[str]) -> int:
    args = _parser().parse_args(argv)
    _check(args)
    from stablemo.eval.behaviour.runner import parse_lengths

    lengths = parse_lengths(args.lengths)
    if args.out:
        from stablemo.io import check_output_file

        check_output_file(args.out, "--out")
    from stablemo.eval.behaviour.table import load_prompts

    prompts = load_prompts(args.prompts)
    if args.split:
        prompts = [p for p in prompts if p.split == args.split]
        if not prompts:
            raise StableMoError(f"--split: no prompt of the table is in split {args.split!r}")
    seeds = list(range(args.seed, args.seed + args.seeds))
    from stablemo.eval.behaviour import runner
    from stablemo.eval.behaviour.summary import format_table
    from stablemo.inference.config import InferenceConfig

    settings = {"prompts": len(prompts), "prompt_table": args.prompts or "packaged", "split": args.split or "all",
                "lengths": lengths, "seeds": seeds,
                "started": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")}
    if args.ground_truth:
        config = InferenceConfig()
        generate = runner.truth_generator(config.default_frames)
        fps, low, high = config.fps, config.min_length, config.max_length
        settings.update(model="ground truth (stablemo.data.synth)", default_length=f"{config.default_frames} frames")
    else:
        from stablemo.inference.bundle import bundle_or_demo
        from stablemo.inference.pipeline import Pipeline

        bundle = bundle_or_demo(args.bundle)
        pipe = Pipeline.from_bundle(bundle, device=args.device, dtype=args.dtype)
        if pipe.skeleton != "humanml3d":
            raise StableMoError(f"--bundle: {bundle}: the behaviour checks read HumanML3D joints, this model makes "
                                f"{pipe.skeleton}")
        request = {k: v for k, v in (("steps", args.steps), ("sampler", args.sampler), ("cfg", args.cfg)) if v is not None}
        generate = runner.pipeline_generator(pipe, args.batch_size, plan=not args.whole, **request)
        fps, low, high = pipe.fps, pipe.min_length, pipe.max_length
        inference = pipe.inference
        settings.update(model=shown_path(bundle), sampler=args.sampler or inference.sampler,
                        steps=args.steps or inference.steps, cfg=inference.cfg if args.cfg is None else args.cfg,
                        planned=not args.whole,
                        device=str(pipe.device),
                        default_length="the bundle's length predictor" if pipe.length_predictor is not None
                        else f"{inference.default_frames} frames",
                        length_predictor=pipe.config.get("length_predictor"),  # which one chose 'default
                        unfamiliar=[u.text for u in pipe.unfamiliar([p.text for p in prompts])])
    for token in lengths:  # explicit lengths outside the model's range: one line before any generation
        runner.frames_for(token, prompts[0], fps, low, high)
    evaluator = None
    from stablemo.eval.metrics import R_PRECISION_BATCH

    if args.retrieval and len(prompts) >= R_PRECISION_BATCH:  # fewer prompts than a batch: no R@3 to take
        from stablemo.eval.evaluate import SYNTH_EVALUATOR
        from stablemo.eval.text_motion import load_text_motion_evaluator

        evaluator = load_text_motion_evaluator(args.evaluator or SYNTH_EVALUATOR)
        settings["evaluator"] = evaluator.name
    log = None if args.no_progress else (lambda line: print(line, file=sys.stderr, flush=True))
    result = runner.run_suite(generate, prompts, lengths, seeds, fps, low, high, progress=log, evaluator=evaluator)
    settings["seconds"] = {k: round(v, 1) for k, v in result["seconds"].items()}
    # the sampling beside the model: a student's bundle may default to any number of steps, and a score
    # read without it has been quoted for the wrong one
    sampling = (f" ({settings['sampler']}, {settings['steps']} step{'s' if settings['steps'] != 1 else ''}, "
                f"cfg {settings['cfg']:g})" if "steps" in settings else "")
    print(f"behaviour: {settings['model']}{sampling}; {len(prompts)} prompts x {len(lengths)} lengths x "
          f"{len(seeds)} seeds = {len(result['rows'])} motions; pass rate [Wilson 95 % interval]")
    print(format_table(result["summary"]))
    if args.out:
        from stablemo.eval.behaviour.report import dumps
        from stablemo.io import write_text

        write_text(args.out, dumps(settings, result))
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
