"""One motion of every action on a contact sheet (docs/data/synth/synth_contact_sheet.png).

    stablemo data preview docs/data/synth/synth_contact_sheet.png [--seed 0] [--frames 8]
"""

from __future__ import annotations

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


def write_contact_sheet(out: Path, seed: int = 0, frames_per_row: int = 8, only: list[str] | None = None) -> Path:
    """A PNG contact sheet of one motion per action (`only`: these actions)."""
    from stablemo.outputs.render import render_contact_sheet

    gallery = action_gallery(seed)
    if only:
        keep = [i for i, a in enumerate(actions.ACTIONS) if a in only]
        gallery = [gallery[i] for i in keep]
    return render_contact_sheet([j for _, j in gallery], [t for t, _ in gallery], Path(out), "humanml3d",
                                frames_per_row=frames_per_row)
