"""Our contrastive evaluator: masking invariance, loss, training to good retrieval on a tiny dataset, loading."""

import numpy as np
import pytest
import torch

from stablemo.errors import StableMoError
from stablemo.eval.evaluator import (
    EvaluatorModule,
    MotionEncoder,
    export_evaluator,
    info_nce,
    load_evaluator,
)

CLASSES = ["a person walks forward", "a person jumps up and down", "someone waves with the right hand",
           "a man sits down on a chair"]


def make_tiny_dataset(root, per_class=(24, 8, 10), seed=0, dim=263):
    """HumanML3D layout with 4 caption classes whose motions carry a class-specific temporal pattern."""
    rng = np.random.default_rng(seed)
    (root / "new_joint_vecs").mkdir(parents=True)
    (root / "texts").mkdir()
    splits, all_feats, n = {"train": [], "val": [], "test": []}, [], 0
    for split, count in zip(splits, per_class):
        for i in range(count * len(CLASSES)):
            cls = i % len(CLASSES)
            T = int(rng.integers(40, 100))
            t = np.arange(T)[:, None]
            x = rng.normal(scale=1.0, size=(T, dim))
            x[:, 4 + 20 * cls : 24 + 20 * cls] += 2.0 * np.sin(t / (3 + cls) + rng.uniform(0, 6))
            cid = f"{n:06d}"
            np.save(root / "new_joint_vecs" / f"{cid}.npy", x.astype(np.float32))
            text = CLASSES[cls]
            tokens = " ".join(f"{w}/OTHER" for w in text.split())
            (root / "texts" / f"{cid}.txt").write_text(f"{text}#{tokens}#0.0#0.0\n")
            splits[split].append(cid)
            all_feats.append(x)
            n += 1
    for split, ids in splits.items():
        (root / f"{split}.txt").write_text("\n".join(ids) + "\n")
    cat = np.concatenate(all_feats)
    np.save(root / "Mean.npy", cat.mean(0).astype(np.float32))
    np.save(root / "Std.npy", cat.std(0).astype(np.float32))
    return root


def test_motion_encoder_ignores_padding():
    torch.manual_seed(0)
    enc = MotionEncoder(259, hidden=32, embed_dim=16, num_blocks=3).eval()
    x = torch.randn(2, 64, 259)
    mask = torch.arange(64)[None] < torch.tensor([64, 37])[:, None]
    ref = enc(x * mask[..., None], mask)
    x2 = x.clone()
    x2[1, 37:] = 100.0
    torch.testing.assert_close(enc(x2 * mask[..., None], mask), ref)
    torch.testing.assert_close(enc(x[1:, :37], mask[1:, :37]), ref[1:], atol=1e-6, rtol=1e-5)
    torch.testing.assert_close(ref.norm(dim=-1), torch.ones(2))


def test_info_nce_duplicate_captions_are_not_negatives():
    e = torch.nn.functional.normalize(torch.randn(4, 8), dim=-1)
    scale = torch.tensor(10.0)
    perfect = info_nce(e, e, scale)
    assert perfect < info_nce(e, e.roll(1, 0), scale)
    # With all four captions equal, every off-diagonal logit is masked: loss is exactly 0.
    assert info_nce(e, e.roll(1, 0), scale, ["x"] * 4) == pytest.approx(0.0, abs=1e-6)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A small evaluator trained for 40 steps on the tiny 4-class dataset (~10 s on one core)."""
    import lightning as L

    from stablemo.data import MotionDataModule

    torch.set_num_threads(1)
    tmp = tmp_path_factory.mktemp("evaluator")
    root = make_tiny_dataset(tmp / "data")
    L.seed_everything(0, verbose=False)
    dm = MotionDataModule(str(root), batch_size=32, pad_multiple=4, cache=False)
    model = EvaluatorModule(motion_hidden=48, motion_blocks=2, text_hidden=64, embed_dim=32, lr=3e-3)
    trainer = L.Trainer(max_steps=40, accelerator="cpu", logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False, num_sanity_val_steps=0,
                        default_root_dir=str(tmp))
    trainer.fit(model, datamodule=dm)
    ckpt = tmp / "eval.ckpt"
    trainer.save_checkpoint(ckpt)
    return {"root": root, "dm": dm, "model": model.eval(), "trainer": trainer, "ckpt": ckpt, "tmp": tmp}


def test_trains_to_good_retrieval_and_reloads(trained):
    model, dm, root, tmp = trained["model"], trained["dm"], trained["root"], trained["tmp"]
    np.testing.assert_allclose(model.mean.numpy(), dm.mean)  # statistics adopted from the data
    res = trained["trainer"].test(model, datamodule=dm, verbose=False)[0]
    # Each batch of 32 holds 8 motions per caption class, all equally true for the caption: the best
    # possible R@k is k/8 (chance k/32).
    assert res["test/r3"] >= 0.3, res
    with torch.no_grad():
        batch = next(iter(dm.test_dataloader()))
        motion = model.embed_normalised(batch["motion"], batch["mask"])
        text = model.embed_text(CLASSES)
    predicted = (motion @ text.T).argmax(1)
    truth = torch.tensor([CLASSES.index(t) for t in batch["text"]])
    assert (predicted == truth).float().mean() >= 0.9

    loaded = load_evaluator(trained["ckpt"])
    out = export_evaluator(trained["ckpt"], tmp / "evaluator")
    from_dir = load_evaluator(out)
    feats = torch.from_numpy(np.load(root / "new_joint_vecs" / "000000.npy"))[None]
    with torch.no_grad():
        ref = model.embed_motion(feats, torch.tensor([feats.shape[1]]))
        torch.testing.assert_close(loaded.embed_motion(feats, torch.tensor([feats.shape[1]])), ref)
        torch.testing.assert_close(from_dir.embed_text(["a person walks forward"]),
                                   model.embed_text(["a person walks forward"]))
    with pytest.raises(StableMoError):
        load_evaluator(tmp / "missing.ckpt")


def test_benchmark_protocol_with_constructed_generators(trained):
    from stablemo.data import MotionDataset
    from stablemo.eval.evaluate import REAL_ROW, OurEvaluator, evaluate, format_table

    data = MotionDataset.from_folder(trained["root"], "train", crop="eval", cache=False, progress=False)
    evaluator = OurEvaluator(trained["ckpt"])
    whole = MotionDataset.from_folder(trained["root"], "train", crop="none", cache=False, progress=False)
    by_text = {}
    for i in range(len(whole)):
        it = whole[i]
        by_text.setdefault(it["text"], []).append(it["motion"] * torch.from_numpy(data.std) + torch.from_numpy(data.mean))

    def oracle(texts, lengths, seeds):  # a real motion of the right class, cropped to the length
        out = torch.zeros(len(texts), max(lengths), data.spec.feature_dim)
        for i, (t, n, s) in enumerate(zip(texts, lengths, seeds)):
            pool = [m for m in by_text[t] if len(m) >= n]
            out[i, :n] = pool[s % len(pool)][:n]
        return out, None

    def noise(texts, lengths, seeds):
        g = torch.Generator().manual_seed(seeds[0])
        return torch.randn(len(texts), max(lengths), data.spec.feature_dim, generator=g) * 3, None

    res_oracle = evaluate(data, evaluator, oracle, replications=3, seed=0, progress=False, row_name="oracle",
                          multimodality=True, mm_captions=4, mm_generations=10)
    res_noise = evaluate(data, evaluator, noise, replications=3, seed=0, progress=False, row_name="noise")
    real, good, bad = res_oracle["rows"][REAL_ROW], res_oracle["rows"]["oracle"], res_noise["rows"]["noise"]
    assert real["fid"]["mean"] < 0.2 * bad["fid"]["mean"]
    assert good["fid"]["mean"] < 0.2 * bad["fid"]["mean"]
    assert good["r3"]["mean"] > 2 * bad["r3"]["mean"]
    assert len(real["r1"]["values"]) == 3 and real["r1"]["conf95"] >= 0
    assert good["multimodality"]["mean"] > 0
    # Same seed, same numbers.
    again = evaluate(data, evaluator, noise, replications=3, seed=0, progress=False, row_name="noise")
    assert again["rows"]["noise"]["fid"]["values"] == bad["fid"]["values"]
    table = format_table(res_oracle, aits=0.123)
    assert "R@1" in table and "oracle" in table and "0.123" in table


def test_raw_and_final_rows_carry_the_kinematic_measures(trained):
    """A generator returning the network's raw output beside the final one: both rows, raw after final,
    with FID and the kinematic measures; a raw output sunk 5 cm reads 5 cm lower at the floor."""
    from stablemo.eval.evaluate import RAW_SUFFIX, REAL_ROW, OurEvaluator, evaluate, format_csv, format_table
    from stablemo.motion import features_to_joints

    data = eval_dataset(trained["root"])
    evaluator = OurEvaluator(trained["ckpt"])

    def finished(texts, lengths, seeds):
        g = torch.Generator().manual_seed(seeds[0])
        feats = torch.randn(len(texts), max(lengths), data.spec.feature_dim, generator=g) * torch.from_numpy(data.std)
        feats = feats + torch.from_numpy(data.mean)
        joints = features_to_joints(feats, "humanml3d")
        return feats, joints, feats, joints - torch.tensor([0.0, 0.05, 0.0])

    res = evaluate(data, evaluator, finished, replications=2, seed=0, progress=False, row_name="model")
    raw, final = res["rows"]["model" + RAW_SUFFIX], res["rows"]["model"]
    assert list(res["rows"]) == [REAL_ROW, "model", "model" + RAW_SUFFIX]
    assert {"fid", "r3", "bone_change", "floor_p1", "below_floor", "foot_acc", "airborne"} <= set(raw) & set(final)
    assert raw["floor_p1"]["mean"] == pytest.approx(final["floor_p1"]["mean"] - 5.0, abs=1e-3)  # float32 joints
    assert raw["bone_change"]["mean"] == pytest.approx(final["bone_change"]["mean"], abs=1e-6)
    assert raw["fid"]["values"] == final["fid"]["values"]            # the same features: the same embeddings
    assert "bone_change" in res["rows"][REAL_ROW]
    table = format_table(res)
    assert "Bone Δ cm" in table and "Floor p1 cm" in table and "model [raw]" in table
    lines = format_csv(res).splitlines()
    assert lines[0] == "method,metric,mean,conf95,replications"
    assert any(line.startswith("model [raw],floor_p1,") and line.endswith(",2") for line in lines)
    plain = evaluate(data, evaluator, lambda t, n, s: finished(t, n, s)[:2], replications=1, seed=0, progress=False,
                     row_name="model", kinematic_measures=False)
    assert list(plain["rows"]) == [REAL_ROW, "model"] and "floor_p1" not in plain["rows"]["model"]
    with pytest.raises(StableMoError, match="generate: expected"):
        evaluate(data, evaluator, lambda t, n, s: finished(t, n, s)[:3], replications=1, progress=False)


def eval_dataset(root):
    from stablemo.data import MotionDataset

    return MotionDataset.from_folder(root, "train", crop="eval", cache=False, progress=False)


def test_evaluate_command_real_motion_only(trained, capsys):
    import json

    from stablemo.cli.evaluate import main

    out = trained["tmp"] / "results.json"
    assert main(["--data", str(trained["root"]), "--evaluator", str(trained["ckpt"]), "--split", "train",
                 "--replications", "2", "--out", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "Real motion" in printed and "FID" in printed
    result = json.loads(out.read_text())
    assert result["rows"]["Real motion"]["fid"]["mean"] < 0.1
    assert result["settings"]["replications"] == 2
    with pytest.raises(StableMoError):
        main(["--data", str(trained["root"]), "--evaluator", str(trained["tmp"] / "nope.ckpt"), "--no-progress"])


def test_evaluate_command_with_a_bundle(trained, capsys):
    """End to end through Pipeline.from_bundle with a tiny untrained model: table, footskate, AITS, JSON."""
    import json

    from stablemo.cli.evaluate import main
    from stablemo.inference.bundle import save_bundle
    from stablemo.nets.model import MotionDiffusionModel

    torch.manual_seed(0)
    model_cfg = {"denoiser": {"name": "unet", "input_dim": 263, "base_channels": 16, "channel_mults": [1, 2],
                              "time_dim": 32, "num_groups": 4, "num_heads": 2},
                 "text": {"latent_dim": 32, "num_layers": 1, "num_heads": 2, "ff_dim": 64}}
    net = MotionDiffusionModel(**model_cfg)
    dm = trained["dm"]
    bundle = save_bundle(trained["tmp"] / "bundle", {
        "model": model_cfg, "schedule": {}, "prediction_type": "sample", "dataset": "humanml3d",
        "skeleton": "humanml3d", "fps": 20.0, "mean": dm.mean.tolist(), "std": dm.std.tolist(),
        "min_length": 40, "max_length": 196, "kind": "diffusion"}, net.state_dict())
    out, out_csv = trained["tmp"] / "bundle_results.json", trained["tmp"] / "bundle_results.csv"
    argv = ["--bundle", str(bundle), "--data", str(trained["root"]), "--evaluator", str(trained["ckpt"]),
            "--split", "train", "--replications", "1", "--steps", "2", "--sampler", "ddim", "--footskate",
            "--aits", "2", "--max-items", "40", "--out", str(out), "--csv", str(out_csv), "--no-progress"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "bundle (ddim, 2 steps, cfg 2.5) + footskate" in printed and "Skate" in printed and "AITS" in printed
    result = json.loads(out.read_text())
    row = result["rows"]["bundle (ddim, 2 steps, cfg 2.5) + footskate"]
    assert set(row) >= {"r1", "r2", "r3", "fid", "mm_dist", "diversity", "skate_ratio"}
    assert 0.0 <= row["skate_ratio"]["mean"] <= 1.0
    # An untrained model is far from the data; the real motions are not.
    assert row["fid"]["mean"] > 5 * result["rows"]["Real motion"]["fid"]["mean"]
    assert result["aits"] > 0 and result["settings"]["items"] == 40
    # the network's raw output is scored beside what the user receives, kinematic measures included
    raw = result["rows"]["bundle (ddim, 2 steps, cfg 2.5) + footskate [raw]"]
    assert set(raw) >= {"fid", "r3", "bone_change", "floor_p1", "below_floor", "foot_acc", "airborne"}
    assert "Bone Δ cm" in printed and "[raw]" in printed
    csv_lines = out_csv.read_text().splitlines()
    assert csv_lines[0] == "method,metric,mean,conf95,replications" and len(csv_lines) > 3 * 10
    assert any(line.startswith('"bundle (ddim, 2 steps, cfg 2.5) + footskate [raw]",bone_change,') for line in csv_lines)


def test_test_stage_restores_statistics_from_checkpoint(trained):
    import lightning as L

    kwargs = dict(motion_hidden=48, motion_blocks=2, text_hidden=64, embed_dim=32)
    trainer = L.Trainer(accelerator="cpu", logger=False, enable_progress_bar=False, enable_model_summary=False,
                        default_root_dir=str(trained["tmp"]))
    res = trainer.test(EvaluatorModule(**kwargs), datamodule=trained["dm"], ckpt_path=str(trained["ckpt"]),
                       verbose=False)[0]
    assert res["test/r3"] >= 0.3
    with pytest.raises(StableMoError, match="statistics"):
        trainer.test(EvaluatorModule(**kwargs), datamodule=trained["dm"], verbose=False)


def test_embed_motions_keeps_input_order(trained):
    from stablemo.eval.evaluate import OurEvaluator, embed_motions

    evaluator = OurEvaluator(trained["ckpt"])
    g = torch.Generator().manual_seed(0)
    feats = [torch.randn(n, 263, generator=g) for n in (80, 41, 120, 60, 44)]
    batched = embed_motions(evaluator, feats, batch_size=2)
    single = np.concatenate([evaluator.embed_motion(f[None], torch.tensor([len(f)])) for f in feats])
    np.testing.assert_allclose(batched, single, atol=1e-5)
