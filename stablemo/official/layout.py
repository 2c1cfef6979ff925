"""The published StableMoFusion checkpoint layout (`T2MUnet` state dict) and its StableMo names.

What the published `T2MUnet` holds, and where each piece goes in a `MotionDiffusionModel` with
`TextConditioner(variant="official")` and `CondUNet1D(variant="official")`:

    embed_text                       -> text.proj           (CLIP width -> text latent)
    textTransEncoder.layers.{k}      -> text.transformer.layers.{k}   (same PyTorch layer)
    text_ln                          -> text.norm
    clip_model.*                     -> not imported: the frozen CLIP loads from --clip
    unet.time_mlp.{1,3}              -> denoiser.time_embed.mlp.{0,2}  (.0.pe: a constant table)
    unet.downs.{i}.{0,1}             -> denoiser.down.{i}, block/attention 0 or 1
    unet.downs.{i}.2.conv            -> denoiser.downsample.{i}
    unet.mid_block{1,2}              -> denoiser.mid, block/attention 0 or 1
    unet.ups.{j}.0.conv              -> denoiser.upsample.{j}
    unet.ups.{j}.{1,2}               -> denoiser.up.{j}, block/attention 0 or 1
    unet.final_conv                  -> denoiser.out

and inside each `CondConv1DBlock` (block/attention b of a stage):

    conv1d.blocks.0.block / .group_norm   -> blocks.{b}.conv1 / .norm1   (AdaGN conv)
    conv1d.blocks.1.block / .norm         -> blocks.{b}.conv2 / .norm2
    conv1d.time_mlp.1                     -> blocks.{b}.emb.1             ([scale | shift])
    conv1d.residual_conv                  -> blocks.{b}.skip
    cross_attn.cross_attention.*          -> attns.{b}.attn.*             (norm, text_norm, query, key, value)

The network's hyperparameters are read from the tensors' shapes (`infer_config`); the published
code fixes the rest (8 norm groups, 8 attention heads, 4 text heads, kernel 5 by default).
"""

from __future__ import annotations

import math
import re
from functools import reduce

import torch

from stablemo.errors import StableMoError

# fixed in the published code (not options of its build_models)
NUM_GROUPS, NUM_HEADS, TEXT_HEADS, DROPOUT = 8, 8, 4, 0.1

_BLOCK = [
    (r"conv1d\.blocks\.0\.block\.", "blocks.{b}.conv1."),
    (r"conv1d\.blocks\.0\.group_norm\.", "blocks.{b}.norm1."),
    (r"conv1d\.blocks\.1\.block\.", "blocks.{b}.conv2."),
    (r"conv1d\.blocks\.1\.norm\.", "blocks.{b}.norm2."),
    (r"conv1d\.time_mlp\.1\.", "blocks.{b}.emb.1."),
    (r"conv1d\.residual_conv\.", "blocks.{b}.skip."),
    (r"cross_attn\.cross_attention\.", "attns.{b}.attn."),
]
# (pattern on the official key, StableMo prefix, block index group or None, stage offset)
_TOP = [
    (r"embed_text\.", "text.proj."),
    (r"textTransEncoder\.", "text.transformer."),
    (r"text_ln\.", "text.norm."),
    (r"unet\.time_mlp\.1\.", "denoiser.time_embed.mlp.0."),
    (r"unet\.time_mlp\.3\.", "denoiser.time_embed.mlp.2."),
    (r"unet\.final_conv\.", "denoiser.out."),
    (r"unet\.downs\.(\d+)\.2\.conv\.", "denoiser.downsample.{0}."),
    (r"unet\.ups\.(\d+)\.0\.conv\.", "denoiser.upsample.{0}."),
]
_STAGES = [  # a CondConv1DBlock: (pattern, StableMo stage, how its index picks block 0 or 1)
    (r"unet\.downs\.(\d+)\.([01])\.", "denoiser.down.{0}.", lambda g: int(g)),
    (r"unet\.mid_block([12])\.", "denoiser.mid.", lambda g: int(g) - 1),
    (r"unet\.ups\.(\d+)\.([12])\.", "denoiser.up.{0}.", lambda g: int(g) - 1),
]
# not network weights: the frozen CLIP (loaded from --clip), the time table (a constant), the
# EMA wrapper's counter
DROPPED = (r"clip_model\.", r"unet\.time_mlp\.0\.pe$", r"n_averaged$")


def strip_wrapper(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Keys without the `module.` prefix an EMA wrapper (torch AveragedModel) or DataParallel adds."""
    if state and all(k.startswith("module.") or k == "n_averaged" for k in state):
        return {k.removeprefix("module."): v for k, v in state.items()}
    return dict(state)


def stablemo_key(key: str) -> str | None:
    """The StableMo name of an official key; None for what is not imported; error for the unknown."""
    if any(re.match(p, key) for p in DROPPED):
        return None
    for pattern, prefix in _TOP:
        m = re.match(pattern, key)
        if m:
            return prefix.format(*m.groups()) + key[m.end():]
    for pattern, stage, block_of in _STAGES:
        m = re.match(pattern, key)
        if not m:
            continue
        groups = m.groups()
        b = block_of(groups[-1])
        rest = key[m.end():]
        for inner, target in _BLOCK:
            n = re.match(inner, rest)
            if n:
                return stage.format(*groups[:-1]) + target.format(b=b) + rest[n.end():]
    raise StableMoError(f"unexpected key {key!r}: not part of the published T2MUnet")


def to_stablemo(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """An official T2MUnet state dict -> a MotionDiffusionModel state dict (float32 copies)."""
    out = {}
    for key, value in state.items():
        name = stablemo_key(key)
        if name is not None:
            out[name] = value.detach().to(torch.float32).clone()
    return out


def _shape(state, key: str, source: str) -> tuple[int, ...]:
    if key not in state:
        raise StableMoError(f"{source}: no {key!r}: not a T2MUnet checkpoint (StableMoFusion)")
    return tuple(state[key].shape)


def infer_config(state: dict[str, torch.Tensor], source: str) -> tuple[dict, dict]:
    """(denoiser kwargs, text conditioner kwargs without the encoder) from the tensors' shapes."""
    stages = sorted({int(m.group(1)) for k in state if (m := re.match(r"unet\.downs\.(\d+)\.", k))})
    if not stages or stages != list(range(len(stages))):
        raise StableMoError(f"{source}: no UNet stages (unet.downs.*): not a T2MUnet checkpoint (StableMoFusion)")
    widths, kernel = [], None
    for i in stages:
        out_ch, _, k = _shape(state, f"unet.downs.{i}.0.conv1d.blocks.0.block.weight", source)
        widths.append(out_ch)
        kernel = k
        emb = _shape(state, f"unet.downs.{i}.0.conv1d.time_mlp.1.weight", source)
        if emb[0] != 2 * out_ch:
            raise StableMoError(f"{source}: trained with --no_adagn (blocks without AdaGN), which StableMo does not import")
    base = reduce(math.gcd, widths)
    input_dim = _shape(state, "unet.final_conv.weight", source)[0]
    time_dim = _shape(state, "unet.time_mlp.1.weight", source)[1]
    text_dim, clip_dim = _shape(state, "embed_text.weight", source)
    layers = sorted({int(m.group(1)) for k in state if (m := re.match(r"textTransEncoder\.layers\.(\d+)\.", k))})
    if not layers:
        raise StableMoError(f"{source}: no text transformer (textTransEncoder.layers.*)")
    ff_dim = _shape(state, "textTransEncoder.layers.0.linear1.weight", source)[0]
    denoiser = dict(name="unet", input_dim=input_dim, text_dim=text_dim, base_channels=base,
                    channel_mults=[w // base for w in widths], time_dim=time_dim, kernel_size=kernel,
                    num_groups=NUM_GROUPS, num_heads=NUM_HEADS, dropout=DROPOUT, cross_attention=True,
                    norm="frame", variant="official")
    text = dict(latent_dim=text_dim, num_layers=len(layers), num_heads=TEXT_HEADS, ff_dim=ff_dim,
                dropout=DROPOUT, variant="official")
    return denoiser, {"clip_dim": clip_dim, **text}
