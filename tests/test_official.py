"""`stablemo import-official`: published StableMoFusion checkpoints -> StableMo bundles.

These tests need no official code: they write checkpoints in the published layout themselves
(`official_key` below spells that layout independently of stablemo.official.layout). The equality
with the official network itself is tests/test_official_equality.py (needs a checkout).
"""

from __future__ import annotations

import copy
import re

import numpy as np
import pytest
import torch

from stablemo.cli import main as cli_main
from stablemo.errors import StableMoError
from stablemo.nets.model import MotionDiffusionModel
from stablemo.official import layout
from stablemo.text import NULL_TEXT, TextConditioner

D = 263  # HumanML3D features: the importer recognises the dataset by the width
TEXT = dict(latent_dim=16, num_layers=2, num_heads=4, ff_dim=32, dropout=0.1, variant="official")
DENOISER = dict(name="unet", input_dim=D, text_dim=16, base_channels=8, channel_mults=[1, 2, 3, 4], time_dim=16,
                kernel_size=5, num_groups=8, num_heads=8, dropout=0.1, cross_attention=True, norm="frame",
                variant="official")


def write_tiny_clip(path, seed: int = 0, hidden: int = 24):
    """A random, tiny transformers CLIPTextModel saved with save_pretrained, standing in for CLIP
    ViT-B/32, which loads the same way from a user's folder."""
    from stablemo.official.reference import write_random_clip

    return write_random_clip(path, hidden=hidden, layers=2, seed=seed)


_INNER = [("conv1.", "conv1d.blocks.0.block."), ("norm1.", "conv1d.blocks.0.group_norm."),
          ("conv2.", "conv1d.blocks.1.block."), ("norm2.", "conv1d.blocks.1.norm."),
          ("emb.1.", "conv1d.time_mlp.1."), ("skip.", "conv1d.residual_conv.")]


def official_key(key: str) -> str:
    """Our MotionDiffusionModel key -> the published T2MUnet's (models/unet.py of the official code)."""
    for ours, theirs in [("text.proj.", "embed_text."), ("text.transformer.", "textTransEncoder."),
                         ("text.norm.", "text_ln."), ("denoiser.time_embed.mlp.0.", "unet.time_mlp.1."),
                         ("denoiser.time_embed.mlp.2.", "unet.time_mlp.3."), ("denoiser.out.", "unet.final_conv.")]:
        if key.startswith(ours):
            return theirs + key[len(ours):]
    m = re.match(r"denoiser\.(downsample|upsample)\.(\d+)\.(.*)", key)
    if m:
        return f"unet.{'downs' if m[1] == 'downsample' else 'ups'}.{m[2]}.{2 if m[1] == 'downsample' else 0}.conv.{m[3]}"
    m = re.match(r"denoiser\.(down|mid|up)\.(?:(\d+)\.)?(blocks|attns)\.(\d)\.(.*)", key)
    stage, index, part, b, rest = m.groups()
    b = int(b)
    prefix = {"down": f"unet.downs.{index}.{b}.", "mid": f"unet.mid_block{b + 1}.", "up": f"unet.ups.{index}.{b + 1}."}[stage]
    if part == "attns":
        return prefix + "cross_attention.".join(["cross_attn.", rest.removeprefix("attn.")])
    for ours, theirs in _INNER:
        if rest.startswith(ours):
            return prefix + theirs + rest[len(ours):]
    raise AssertionError(key)


def tiny_model(clip_dir, seed: int = 0) -> MotionDiffusionModel:
    torch.manual_seed(seed)
    model = MotionDiffusionModel(DENOISER, {"encoder": str(clip_dir), **TEXT}).eval()
    with torch.no_grad():
        for p in model.parameters():  # the zero-initialised layers too: else the output is 0
            p.normal_(0, 0.1)
    return model


def official_state(model: MotionDiffusionModel, clip) -> dict[str, torch.Tensor]:
    """The model's weights as the published T2MUnet's state dict, with the CLIP tensors it carries."""
    state = {official_key(k): v.clone() for k, v in model.state_dict().items()}
    state["clip_model.token_embedding.weight"] = clip.embeddings.token_embedding.weight.detach().clone()
    state["clip_model.positional_embedding"] = clip.embeddings.position_embedding.weight.detach().clone()
    state["clip_model.ln_final.weight"] = clip.final_layer_norm.weight.detach().clone()
    state["clip_model.ln_final.bias"] = clip.final_layer_norm.bias.detach().clone()
    state["unet.time_mlp.0.pe"] = torch.zeros(5000, 16)
    return state


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """An official run folder NAME/{model/latest.tar, meta/, opt.txt}: raw and EMA weights differ;
    the EMA state is in the older AveragedModel form ('module.' keys, n_averaged)."""
    root = tmp_path_factory.mktemp("official")
    clip, _ = write_tiny_clip(root / "clip")
    raw, ema = tiny_model(root / "clip", 0), tiny_model(root / "clip", 1)
    ema_state = {"module." + k: v for k, v in official_state(ema, clip).items()} | {"n_averaged": torch.tensor(9)}
    (root / "run" / "model").mkdir(parents=True)
    (root / "run" / "meta").mkdir()
    torch.save({"encoder": official_state(raw, clip), "model_ema": ema_state, "total_it": 1234,
                "opt_encoder": torch.optim.AdamW(raw.parameters()).state_dict()}, root / "run" / "model" / "latest.tar")
    gen = np.random.default_rng(0)
    np.save(root / "run" / "meta" / "mean.npy", gen.normal(size=D))
    np.save(root / "run" / "meta" / "std.npy", gen.uniform(0.5, 2.0, size=D))
    (root / "run" / "opt.txt").write_text("------------ Options -------------\ndataset_name: t2m\nprediction_type: sample\n"
                                          "diffusion_steps: 1000\nbeta_schedule: linear\nno_eff: False\n"
                                          "-------------- End ----------------\n")
    return dict(root=root, clip=clip, raw=raw, ema=ema, ckpt=root / "run" / "model" / "latest.tar")


@pytest.fixture(scope="module")
def bundle(run):
    out = run["root"] / "bundle"
    assert cli_main(["import-official", str(run["ckpt"]), "--out", str(out), "--clip", str(run["root"] / "clip")]) == 0
    return out


def test_layout_maps_every_key_both_ways_and_recovers_the_network(run):
    model = run["raw"]
    for key in model.state_dict():
        assert layout.stablemo_key(official_key(key)) == key
    state = official_state(model, run["clip"])
    denoiser, text = layout.infer_config(state, "ckpt")
    assert denoiser == DENOISER
    assert text == {"clip_dim": 24, **TEXT}
    with pytest.raises(StableMoError, match="unexpected key 'unet.extra.weight'"):
        layout.stablemo_key("unet.extra.weight")


def test_import_writes_the_ema_weights_stats_and_official_variants(run, bundle):
    from stablemo.inference.bundle import load_bundle

    loaded = load_bundle(bundle)
    assert loaded.state_dict.keys() == run["ema"].state_dict().keys()
    for key, value in run["ema"].state_dict().items():
        assert torch.equal(loaded.state_dict[key], value), key
    config = loaded.config
    assert config["model"]["denoiser"]["variant"] == config["model"]["text"]["variant"] == "official"
    assert config["model"]["text"]["encoder"] == str((run["root"] / "clip").resolve())
    np.testing.assert_allclose(config["std"], np.load(run["root"] / "run" / "meta" / "std.npy"))
    assert (config["dataset"], config["skeleton"], config["fps"]) == ("humanml3d", "humanml3d", 20.0)
    assert config["training"]["weights"] == "model_ema" and config["training"]["total_it"] == 1234


def test_no_ema_imports_the_raw_weights(run):
    from stablemo.inference.bundle import load_bundle

    out = run["root"] / "raw_bundle"
    assert cli_main(["import-official", str(run["ckpt"]), "--out", str(out), "--clip", str(run["root"] / "clip"),
                     "--no-ema"]) == 0
    state = load_bundle(out).state_dict
    assert all(torch.equal(state[k], v) for k, v in run["raw"].state_dict().items())


def test_dataset_stats_get_the_official_feat_bias(run):
    from stablemo.inference.bundle import load_bundle

    meta, out = run["root"] / "run" / "meta", run["root"] / "feat_bias_bundle"
    assert cli_main(["import-official", str(run["ckpt"]), "--out", str(out), "--clip", str(run["root"] / "clip"),
                     "--mean", str(meta / "mean.npy"), "--std", str(meta / "std.npy"), "--feat-bias", "5"]) == 0
    std, given = np.asarray(load_bundle(out).config["std"]), np.load(meta / "std.npy")
    np.testing.assert_allclose(std[4:-4], given[4:-4])
    np.testing.assert_allclose(std[:4], given[:4] / 5)
    np.testing.assert_allclose(std[-4:], given[-4:] / 5)


def test_official_text_path_keeps_77_positions_and_the_null_text_has_none(run):
    from transformers import CLIPTokenizer

    clip = run["clip"]
    cond = TextConditioner(str(run["root"] / "clip"), **TEXT).eval()
    feats, mask = cond.frozen_features(["walk", NULL_TEXT, "run fast"])
    assert feats.shape == (3, 77, 24)
    assert mask[0].all() and mask[2].all() and not mask[1].any() and (feats[1] == 0).all()
    # the frozen features are CLIP's on ids padded with 0 to 77 (OpenAI's clip.tokenize), no attention mask

    tokenizer = CLIPTokenizer.from_pretrained(run["root"] / "clip")
    ids = torch.zeros(1, 77, dtype=torch.long)
    tokens = tokenizer("walk")["input_ids"]
    ids[0, : len(tokens)] = torch.tensor(tokens)
    with torch.no_grad():
        torch.testing.assert_close(feats[0], clip(input_ids=ids).last_hidden_state[0], rtol=0, atol=0)
        text, text_mask = cond(["walk", NULL_TEXT])
    assert torch.isfinite(text).all() and (text[1] == 0).all() and not text_mask[1].any()


def test_unconditional_pass_is_the_network_without_cross_attention(bundle):
    """The published CFG's unconditional half skips cross-attention: the null condition adds exactly 0."""
    from stablemo.inference.pipeline import Pipeline

    pipe = Pipeline.from_bundle(bundle, fast=False)
    null_text, null_mask = pipe.null_condition(2)
    gen = torch.Generator().manual_seed(0)
    x, t = torch.randn(2, 32, D, generator=gen), torch.tensor([3, 700])
    mask = torch.ones(2, 32, dtype=torch.bool)
    with torch.no_grad():
        out = pipe.model(x, t, null_text, null_mask, mask)
        bare = copy.deepcopy(pipe.model)
        for stage in bare.denoiser.stages():
            stage.attns = torch.nn.ModuleList()
        torch.testing.assert_close(out, bare(x, t, null_text, null_mask, mask), rtol=0, atol=0)
        text, text_mask = pipe.encode(["walk", "jump"])
        assert (pipe.model(x, t, text, text_mask, mask) - out).abs().max() > 1e-3  # the text does act


def test_imported_bundle_generates_with_footskate_cleanup(bundle, tmp_path):
    out = tmp_path / "gen"
    assert cli_main(["generate", "walk forward", "jump", "--bundle", str(bundle), "--frames", "37", "--steps", "2",
                     "--footskate", "--out", str(out), "--no-render"]) == 0
    files = sorted(p.name for p in out.iterdir())
    joints = [np.load(out / name) for name in files if name.endswith(".joints.npy")]
    assert len(joints) == 2 and all(j.shape == (37, 22, 3) and np.isfinite(j).all() for j in joints)


def test_bench_aits_runs_on_an_imported_bundle(bundle, capsys, monkeypatch):
    from stablemo.bench import aits as bench
    from stablemo.cli import bench as bench_cli

    # the 2048^3 matmul reference (sampled ~7 times) is most of the run's time; a small one here
    measure = bench.matmul_gflops
    monkeypatch.setattr(bench, "matmul_gflops", lambda dtype=torch.float32: measure(dtype, n=256, repeats=1))
    assert bench_cli.main(["aits", "--bundle", str(bundle), "--frames", "32", "--repeats", "1", "--steps", "2",
                       "--skip-ddpm", "--threads", "1"]) == 0
    report = capsys.readouterr().out
    assert "+ parallel CFG" in report and "1-step LCM student" in report


def test_imported_bundle_distils(bundle, tmp_path):
    from stablemo.inference.bundle import save_bundle
    from stablemo.inference.pipeline import Pipeline
    from stablemo.training.distill_module import ConsistencyDistillation

    module = ConsistencyDistillation(teacher=str(bundle), mode="lcm", ddim_steps=10)
    gen = torch.Generator().manual_seed(0)
    batch = {"motion": torch.randn(2, 16, D, generator=gen), "mask": torch.ones(2, 16, dtype=torch.bool),
             "text": ["walk", "jump"]}
    loss = module.distillation_loss(batch, torch.Generator().manual_seed(1))["loss"]
    loss.backward()
    assert torch.isfinite(loss) and module.student.model.denoiser.out.weight.grad.abs().sum() > 0
    config, state = module.bundle()
    pipe = Pipeline.from_bundle(save_bundle(tmp_path / "student", config, state))
    assert torch.isfinite(pipe.generate(["walk"], [20], steps=1, seed=0).features).all()


def _error(capsys, argv) -> str:
    capsys.readouterr()  # what the test itself printed (transformers' save progress)
    assert cli_main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


def test_bad_input_is_one_line_naming_the_argument(run, tmp_path, capsys):
    ckpt, clip = str(run["ckpt"]), str(run["root"] / "clip")
    other = tmp_path / "other_clip"
    write_tiny_clip(other, seed=7)
    assert "not the CLIP the checkpoint was trained with" in _error(
        capsys, ["import-official", ckpt, "--out", str(tmp_path / "a"), "--clip", str(other)])
    wide = tmp_path / "wide_clip"
    write_tiny_clip(wide, hidden=32)
    assert "--clip" in _error(capsys, ["import-official", ckpt, "--out", str(tmp_path / "a"), "--clip", str(wide)])
    # a pickled object is refused, never unpickled
    evil = tmp_path / "evil.tar"
    torch.save({"encoder": {"x": object()}}, evil)
    meta = ["--meta", str(run["root"] / "run" / "meta")]
    assert "not a readable PyTorch checkpoint" in _error(
        capsys, ["import-official", str(evil), "--out", str(tmp_path / "a"), *meta])
    assert "checkpoint not found" in _error(capsys, ["import-official", str(tmp_path / "no.tar"), "--out", str(tmp_path / "a")])
    # no meta/ beside a lone checkpoint
    lone = tmp_path / "lone" / "latest.tar"
    lone.parent.mkdir()
    lone.write_bytes(run["ckpt"].read_bytes())
    assert "--meta" in _error(capsys, ["import-official", str(lone), "--out", str(tmp_path / "a"), "--clip", clip])
    short = tmp_path / "short.npy"
    np.save(short, np.ones(12))
    assert "expected 263 values" in _error(capsys, ["import-official", str(lone), "--out", str(tmp_path / "a"),
                                                    "--clip", clip, "--mean", str(short), "--std", str(short)])
    # an --out that is not a bundle folder: refused before anything is read
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "notes.txt").write_text("mine")
    assert "--out" in _error(capsys, ["import-official", "missing.tar", "--out", str(tmp_path / "full")])
    assert (tmp_path / "full" / "notes.txt").read_text() == "mine" and not (tmp_path / "a").exists()


def test_unsupported_official_options_are_named(run, tmp_path, capsys):
    state = official_state(run["raw"], run["clip"])
    state["unet.downs.0.0.conv1d.time_mlp.1.weight"] = state["unet.downs.0.0.conv1d.time_mlp.1.weight"][:8]
    (tmp_path / "model").mkdir()
    torch.save({"encoder": state}, tmp_path / "model" / "latest.tar")
    (tmp_path / "meta").mkdir()
    np.save(tmp_path / "meta" / "mean.npy", np.zeros(D))
    np.save(tmp_path / "meta" / "std.npy", np.ones(D))
    argv = ["import-official", str(tmp_path / "model" / "latest.tar"), "--out", str(tmp_path / "b"),
            "--clip", str(run["root"] / "clip")]
    assert "--no_adagn" in _error(capsys, argv)
    (tmp_path / "opt.txt").write_text("no_eff: True\n")
    assert "--no_eff" in _error(capsys, argv)
