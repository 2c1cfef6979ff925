"""The imported network against the official one: same weights, same x_t, t and CLIP features.

Needs a checkout of github.com/Linketic/StableMoFusion (not shipped with StableMo) at the path in
$STABLEMO_OFFICIAL_SRC, and einops (the official code imports it). A T2MUnet is built by the official
code at a small config with random weights (the zero-initialised layers too) and saved as its
trainer saves it; `stablemo import-official` converts it; both networks then run on the same inputs.
"""

from __future__ import annotations

import copy
import os

import numpy as np
import pytest
import torch
from test_official import write_tiny_clip

SRC = os.environ.get("STABLEMO_OFFICIAL_SRC")
pytestmark = pytest.mark.skipif(not SRC, reason="set STABLEMO_OFFICIAL_SRC to a checkout of Linketic/StableMoFusion")
RTOL = 1e-5
D = 263


def rel(ours: torch.Tensor, theirs: torch.Tensor) -> float:
    return float((ours - theirs).abs().max() / theirs.abs().max())


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """(official T2MUnet holding the EMA weights, the imported StableMo pipeline)."""
    pytest.importorskip("einops", reason="the official models/unet.py imports einops")
    from stablemo.inference.pipeline import Pipeline
    from stablemo.official import reference
    from stablemo.official.convert import import_official

    root = tmp_path_factory.mktemp("equality")
    clip, tokenizer = write_tiny_clip(root / "clip")
    module = reference.official_unet_module(SRC, reference.clip_stand_in(clip, tokenizer))
    torch.manual_seed(0)
    # widths that differ per stage, so that every residual 1x1 and width-changing up-sampler is exercised
    official = module.T2MUnet(input_feats=D, base_dim=16, dim_mults=(1, 2, 3, 4), time_dim=32, text_latent_dim=16,
                              text_ff_size=32, clip_dim=24, num_text_layers=2, cond_mask_prob=0.1)
    ema = copy.deepcopy(official)
    with torch.no_grad():
        for model, scale in ((official, 0.1), (ema, 0.1)):
            for name, p in model.named_parameters():
                if not name.startswith("clip_model."):
                    p.normal_(0, scale)
    run = root / "t2m_run"
    (run / "model").mkdir(parents=True)
    (run / "meta").mkdir()
    torch.save(reference.official_checkpoint(official, ema, total_it=50), run / "model" / "latest.tar")
    np.save(run / "meta" / "mean.npy", np.zeros(D))
    np.save(run / "meta" / "std.npy", np.ones(D))
    import_official(run / "model" / "latest.tar", root / "bundle", clip=str(root / "clip"), log=lambda *_: None)
    return ema.eval(), Pipeline.from_bundle(root / "bundle", fast=False)


TEXTS = ["a person walks forward", "jump twice then turn left"]


def test_text_path_matches(pair):
    official, pipe = pair
    with torch.no_grad():
        theirs = official.encode_text(TEXTS, "cpu")
        ours, mask = pipe.encode(TEXTS)
    assert ours.shape == theirs.shape == (2, 77, 16) and mask.all()
    print(f"text latents: max relative error {rel(ours, theirs):.2e}")  # shown with pytest -s
    assert rel(ours, theirs) < RTOL


@pytest.mark.parametrize("fast", [False, True], ids=["stock", "stablemo.fast"])
def test_network_and_cfg_match_at_a_length_needing_no_padding(pair, fast):
    from stablemo.diffusion.guidance import CFGDenoiser
    from stablemo.fast import accelerate

    official, pipe = pair
    model = accelerate(copy.deepcopy(pipe.model)) if fast else pipe.model
    gen = torch.Generator().manual_seed(1)
    x, t = torch.randn(2, 48, D, generator=gen), torch.tensor([7, 930])  # 48 = 3 x 16: no padding
    motion_mask = torch.ones(2, 48, dtype=torch.bool)
    with torch.no_grad():
        enc = official.encode_text(TEXTS, "cpu")  # the same CLIP token features -> text latents on both sides
        text, text_mask = pipe.encode(TEXTS)
        null_text, null_mask = pipe.null_condition(2)
        cond_theirs = official(x, t, enc_text=enc)
        cfg_theirs = official.forward_with_cfg(x, t, enc_text=enc, cfg_scale=2.5)
        cond_ours = model(x, t, enc, torch.ones(2, 77, dtype=torch.bool), motion_mask)
        cfg_ours = CFGDenoiser(model, text, text_mask, null_text, null_mask, motion_mask, scale=2.5)(x, t)
    print(f"network ({'fast' if fast else 'stock'} layers): max relative error conditional "
          f"{rel(cond_ours, cond_theirs):.2e}, CFG 2.5 {rel(cfg_ours, cfg_theirs):.2e}")
    assert rel(cond_ours, cond_theirs) < RTOL
    assert rel(cfg_ours, cfg_theirs) < RTOL
    assert rel(cfg_theirs, cond_theirs) > 1e-3  # guidance is not vacuous here


def test_official_output_depends_on_padding_ours_does_not(pair):
    """At 40 frames the official network pads to 48 with zeros and no mask: its valid frames see the
    padding. Ours is exact per frame: the same at any padded length."""
    from stablemo.diffusion.guidance import CFGDenoiser

    official, pipe = pair
    gen = torch.Generator().manual_seed(2)
    x, t = torch.randn(2, 40, D, generator=gen), torch.tensor([7, 930])
    with torch.no_grad():
        enc = official.encode_text(TEXTS, "cpu")
        text, text_mask = pipe.encode(TEXTS)
        null_text, null_mask = pipe.null_condition(2)
        theirs = official.forward_with_cfg(x, t, enc_text=enc, cfg_scale=2.5)
        outs = []
        for total in (48, 64):
            mask = torch.arange(total)[None].expand(2, total) < 40
            padded = torch.nn.functional.pad(x, (0, 0, 0, total - 40))
            outs.append(CFGDenoiser(pipe.model, text, text_mask, null_text, null_mask, mask, scale=2.5)(padded, t)[:, :40])
    print(f"40 frames: ours at 48 vs 64 padded {rel(outs[1], outs[0]):.2e}, official vs ours {rel(outs[0], theirs):.2e}")
    assert rel(outs[1], outs[0]) < RTOL
    assert rel(outs[0], theirs) > 1e-3


def test_compare_tool_reports_equality_padding_and_both_loops(tmp_path):
    """`stablemo bench official` (the numbers of docs/official.md), at a small size."""
    import json

    pytest.importorskip("einops", reason="the official models/unet.py imports einops")
    pytest.importorskip("diffusers", reason="the official sampling loop uses diffusers' scheduler")
    from stablemo.cli.bench import main_official

    out = tmp_path / "compare.json"
    assert main_official(["--official-src", SRC, "--size", "small", "--frames", "40", "--aits", "--repeats", "1",
                         "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert max(v for k, v in result["equality"].items() if k != "frames") < RTOL
    assert result["equality"]["frames"] == 32 and result["padding"]["padded_to"] == 48
    assert result["padding"]["max_rel"] > 1e-3
    assert set(result["aits"]) == {"official loop", "StableMo"}
