"""One motion of every action on a contact sheet (docs/data/synth/synth_contact_sheet.png).

    python -m stablemo.data.synth.preview docs/data/synth/synth_contact_sheet.png [--seed 0] [--frames 8]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from stablemo.data.synth import actions, captions, compose


def action_gallery(seed: int = 0) -> list[tuple[str, np.ndarray]]:
    """(caption, joints) for one single-action motion of every action."""
    out = []
    for i, name in enumerate(actions.ACTIONS):
        rng = np.random.default_rng([seed, i])
        params = actions.sample_params(name, rng)
        built = compose.build([(name, params)])
        text = captions.captions_for([(name, params)], rng, num=1)[0]
        out.append((text, built.joints))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", help="PNG path")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--frames", type=int, default=8, help="frames per row")
    parser.add_argument("--only", nargs="*", help="restrict to these actions")
    args = parser.parse_args(argv)
    from stablemo.outputs.render import render_contact_sheet

    gallery = action_gallery(args.seed)
    if args.only:
        keep = [i for i, a in enumerate(actions.ACTIONS) if a in args.only]
        gallery = [gallery[i] for i in keep]
    render_contact_sheet([j for _, j in gallery], [t for t, _ in gallery], Path(args.out), "humanml3d",
                         frames_per_row=args.frames)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
