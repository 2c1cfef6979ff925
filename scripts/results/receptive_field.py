"""How far apart can two frames of a motion influence each other? The effective receptive field of a
bundle's denoiser: the gradient of its output at the middle frame of a T-frame motion with respect
to every frame of its input x_t (summed over 8 random texts and inputs), and the window around the middle that holds 50 / 90 / 99 % of it,
at a few timesteps (random text tokens and input; the network as shipped, stock layers).

    python scripts/results/receptive_field.py --bundle stablemo/assets/demo_bundle

A network whose window is short against the motion cannot make distant frames agree (how many jumps,
how far a turn has gone): docs/training.md, "Counting needs the whole motion".
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
import torch

from stablemo.inference.pipeline import Pipeline


def windows(net, frames: int, timesteps, draws: int = 8, seed: int = 0,
            shares=(0.5, 0.9, 0.99)) -> dict[int, list[int]]:
    """{timestep: [half-width in frames holding each share of the gradient]}, the gradient's mass
    summed over `draws` random texts and inputs."""
    gen = torch.Generator().manual_seed(seed)
    centre, out = frames // 2, {}
    for t in timesteps:
        g = np.zeros(frames)  # gradient mass per input frame
        for _ in range(draws):
            text = torch.randn(1, 8, net.text_dim, generator=gen)
            ctx = net.prepare(text, torch.ones(1, 8, dtype=torch.bool), torch.ones(1, frames, dtype=torch.bool))
            x = torch.randn(1, frames, net.input_dim, generator=gen).requires_grad_(True)
            net(x, torch.tensor([t]), ctx)[0, centre].pow(2).sum().backward()
            g += x.grad[0].abs().sum(-1).numpy()
        cum = [g[max(0, centre - k): centre + k + 1].sum() for k in range(frames)]
        out[t] = [int(np.argmax(np.array(cum) >= q * g.sum())) for q in shares]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bundle", default="stablemo/assets/demo_bundle")
    ap.add_argument("--frames", type=int, default=196)
    ap.add_argument("--timesteps", default="50,500,900")
    args = ap.parse_args(argv)
    torch.manual_seed(0)
    net = Pipeline.from_bundle(args.bundle, fast=False).model.denoiser
    fps = 20.0
    print(f"{args.bundle}: output frame {args.frames // 2} of {args.frames}; half-width of the window holding "
          "50 / 90 / 99 % of the input gradient")
    for t, ks in windows(net, args.frames, [int(s) for s in args.timesteps.split(",")]).items():
        print(f"  t = {t:3d}: " + " / ".join(f"±{k} frames ({k / fps:.1f} s)" for k in ks))
    return 0


if __name__ == "__main__":
    sys.exit(main())
