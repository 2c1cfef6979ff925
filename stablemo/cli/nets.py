"""`stablemo nets summary --config FILE [--length 196]`: parameters and FLOPs per module (stablemo.nets.summary)."""

from __future__ import annotations

import argparse

import torch

from stablemo.errors import StableMoError, one_line
from stablemo.motion.skeleton import MAX_FRAMES
from stablemo.nets import build_denoiser
from stablemo.nets.config import load_denoiser_config
from stablemo.nets.summary import check_options, count_parameters, human, summarize


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="stablemo nets", description="denoiser tools")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("summary", help="parameters and FLOPs per module")
    p.add_argument("--config", required=True, help="denoiser YAML (name + kwargs) or training YAML")
    p.add_argument("--length", type=int, default=MAX_FRAMES, help=f"motion frames (padded up to the length multiple; default {MAX_FRAMES})")
    p.add_argument("--text-length", type=int, default=20, help="text tokens")
    p.add_argument("--input-dim", type=int, default=None, help="feature width if the config has none (263)")
    p.add_argument("--text-dim", type=int, default=None, help="text latent width if the config has none (256)")
    p.add_argument("--depth", type=int, default=1, help="module nesting depth to list")
    p.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    check_options(args)

    config = load_denoiser_config(args.config)
    name = config.pop("name")
    if args.input_dim is not None:
        config["input_dim"] = args.input_dim
    if args.text_dim is not None:
        config["text_dim"] = args.text_dim
    config.setdefault("input_dim", 263)
    config.setdefault("text_dim", 256)
    torch.manual_seed(args.seed)
    try:
        model = build_denoiser(name, **config)
        rows, total_flops, total_len = summarize(model, args.length, args.text_length, depth=args.depth, seed=args.seed)
    except StableMoError as err:
        raise StableMoError(f"{args.config}: {err}") from None
    except (RuntimeError, ValueError, TypeError) as err:
        # the options built a network that cannot run a forward pass (e.g. input_dim: 0 in the file)
        raise StableMoError(f"{args.config}: denoiser {name!r} with {config} fails on a {args.length}-frame input "
                            f"({type(err).__name__}: {one_line(str(err))})") from None

    width = max([len("module")] + [len(r[0]) for r in rows])
    print(f"denoiser {name}: {', '.join(f'{k}={v}' for k, v in config.items())}")
    print(f"{'module':<{width}}  {'params':>14}  {'GFLOPs':>10}")
    for mod, n, f in rows:
        print(f"{mod:<{width}}  {n:>14,}  {f / 1e9:>10.3f}")
    n_total = count_parameters(model)
    print(f"{'total':<{width}}  {n_total:>14,}  {total_flops / 1e9:>10.3f}")
    print(f"parameters: {human(n_total)}; FLOPs per forward (batch 1, {args.length} frames padded to {total_len}, "
          f"{args.text_length} text tokens): {human(total_flops)}")
    return 0
