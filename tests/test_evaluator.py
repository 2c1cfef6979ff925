"""Our contrastive evaluator: masking invariance, loss, training to good retrieval on a tiny dataset, loading."""

import numpy as np
import pytest
import torch

from stablemo.errors import StableMoError
from stablemo.eval.evaluator import EvaluatorModule, MotionEncoder, export_evaluator, info_nce, load_evaluator

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


def test_trains_to_good_retrieval_and_reloads(tmp_path):
    import lightning as L

    from stablemo.data import MotionDataModule

    torch.set_num_threads(1)
    root = make_tiny_dataset(tmp_path / "data")
    L.seed_everything(0, verbose=False)
    dm = MotionDataModule(str(root), batch_size=32, pad_multiple=4, cache=False)
    model = EvaluatorModule(motion_hidden=48, motion_blocks=2, text_hidden=64, embed_dim=32, lr=3e-3)
    trainer = L.Trainer(max_steps=40, accelerator="cpu", logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False, num_sanity_val_steps=0,
                        default_root_dir=str(tmp_path))
    trainer.fit(model, datamodule=dm)
    np.testing.assert_allclose(model.mean.numpy(), dm.mean)  # statistics adopted from the data
    res = trainer.test(model, datamodule=dm, verbose=False)[0]
    # Each batch of 32 holds 8 motions per caption class, all equally true for the caption: the best
    # possible R@k is k/8 (chance k/32).
    assert res["test/r3"] >= 0.3, res
    model.eval()
    with torch.no_grad():
        batch = next(iter(dm.test_dataloader()))
        motion = model.embed_normalised(batch["motion"], batch["mask"])
        text = model.embed_text(CLASSES)
    predicted = (motion @ text.T).argmax(1)
    truth = torch.tensor([CLASSES.index(t) for t in batch["text"]])
    assert (predicted == truth).float().mean() >= 0.9

    ckpt = tmp_path / "eval.ckpt"
    trainer.save_checkpoint(ckpt)
    loaded = load_evaluator(ckpt)
    out = export_evaluator(ckpt, tmp_path / "evaluator")
    from_dir = load_evaluator(out)
    feats = torch.from_numpy(np.load(root / "new_joint_vecs" / "000000.npy"))[None]
    ref = model.eval().embed_motion(feats, torch.tensor([feats.shape[1]]))
    torch.testing.assert_close(loaded.embed_motion(feats, torch.tensor([feats.shape[1]])), ref)
    torch.testing.assert_close(from_dir.embed_text(["a person walks forward"]), model.embed_text(["a person walks forward"]))
    with pytest.raises(StableMoError):
        load_evaluator(tmp_path / "missing.ckpt")
