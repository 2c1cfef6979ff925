"""How far unsharded training drifts from FSDP2's, step by step, and what a data-parallel split alone does.

    .venv/bin/python scripts/bench/fsdp_rounding.py [--net unet] [--steps 10] [--init own|normal]

In this one process (a 1-process gloo group: FSDP2's autograd graph without communication), four
copies of a small network train on the same batches with AdamW (fused, lr 1e-3, weight decay 0.01)
and gradient clipping at 1.0, as the tests' tiny config does:

    sharded    fully_shard'ed as `--trainer.strategy=fsdp` does (stablemo.training.sharding.shard_model)
    plain      unsharded, as training was before group_unit_gradients
    grouped    unsharded with group_unit_gradients (what DDP and 1-process training do now)
    halves     grouped, each batch as two halves whose gradients are averaged (DDP's split of a batch)

Prints, after every step, the largest weight difference of `sharded` against `plain` and `grouped`,
and of `halves` against `grouped`: the rounding a data-parallel split brings by itself, for scale.
`--init own` keeps the network's own initialisation (a zero output layer: step 1 moves the output
layer only, as real training starts); `normal` draws every weight from N(0, 0.05^2) so that every
gradient is non-zero from step 1.
"""

from __future__ import annotations

import argparse
import copy

import torch

NETS = {  # the tests' small networks (tests/test_fsdp.py)
    "unet": {"name": "unet", "input_dim": 263, "base_channels": 16, "channel_mults": [1, 2], "time_dim": 32,
             "num_groups": 4, "num_heads": 2, "dropout": 0.0},
    "dit": {"name": "dit", "input_dim": 263, "latent_dim": 32, "num_layers": 2, "num_heads": 2, "ff_dim": 64,
            "dropout": 0.0},
    "retnet": {"name": "retnet", "input_dim": 263, "latent_dim": 32, "num_layers": 2, "num_heads": 2, "ff_dim": 64,
               "dropout": 0.0},
}
TEXT = {"encoder": "minilm", "latent_dim": 32, "num_layers": 2, "num_heads": 2, "ff_dim": 64, "dropout": 0.0}
TEXTS = ["a person walks forward", "someone jumps", "a man waves", "turn around"]


def loss_of(model, x, t, mask, texts):
    text, text_mask = model.encode_text(texts)
    return (model(x, t, text, text_mask, mask).float() - x).square().mean()


def full(p: torch.Tensor) -> torch.Tensor:
    return (p.full_tensor() if hasattr(p, "full_tensor") else p).detach()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--net", choices=sorted(NETS), default="unet")
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--init", choices=("own", "normal"), default="own")
    args = parser.parse_args()
    torch.set_num_threads(1)

    import torch.distributed as dist
    from torch.distributed.device_mesh import init_device_mesh

    from stablemo.nets.model import MotionDiffusionModel
    from stablemo.training.sharding import group_unit_gradients, shard_model

    dist.init_process_group("gloo", store=dist.HashStore(), rank=0, world_size=1)
    torch.manual_seed(0)
    base = MotionDiffusionModel(denoiser=NETS[args.net], text=TEXT)
    if args.init == "normal":
        for p in base.parameters():
            torch.nn.init.normal_(p, std=0.05)
    arms = {name: copy.deepcopy(base) for name in ("sharded", "plain", "grouped", "halves")}
    shard_model(arms["sharded"], init_device_mesh("cpu", (1,)))
    group_unit_gradients(arms["grouped"])
    group_unit_gradients(arms["halves"])
    optimisers = {k: torch.optim.AdamW(m.parameters(), lr=1e-3, weight_decay=0.01, fused=True)
                  for k, m in arms.items()}
    gen = torch.Generator().manual_seed(0)
    for step in range(1, args.steps + 1):
        x = torch.randn(4, 8, 263, generator=gen)  # (B, T, D)
        t = torch.randint(0, 1000, (4,), generator=gen)
        mask = torch.ones(4, 8, dtype=torch.bool)
        mask[1, 5:] = False
        for name, model in arms.items():
            optimisers[name].zero_grad()
            if name == "halves":
                for lo in (0, 2):
                    half = slice(lo, lo + 2)
                    (0.5 * loss_of(model, x[half], t[half], mask[half], TEXTS[half])).backward()
            else:
                loss_of(model, x, t, mask, TEXTS).backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
            optimisers[name].step()
        weights = {k: [full(p) for p in m.parameters()] for k, m in arms.items()}
        far = {pair: max((p - q).abs().max().item() for p, q in zip(weights[pair[0]], weights[pair[1]]))
               for pair in (("sharded", "plain"), ("sharded", "grouped"), ("halves", "grouped"))}
        print(f"{args.net} ({args.init} init) step {step}: sharded vs plain {far['sharded', 'plain']:.3g}, "
              f"sharded vs grouped {far['sharded', 'grouped']:.3g}, halves vs grouped "
              f"{far['halves', 'grouped']:.3g}", flush=True)
    dist.destroy_process_group()


if __name__ == "__main__":
    main()
