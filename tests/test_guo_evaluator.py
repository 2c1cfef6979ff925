"""Published-evaluator compatibility: module layout, checkpoint loading, GloVe files read without unpickling."""

import os
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch

from stablemo.errors import StableMoError
from stablemo.eval import guo
from stablemo.eval.word_vectorizer import (
    POS_INDEX,
    WordVectorizer,
    read_pickled_strings,
)

# Shapes of every tensor in the published HumanML3D finest.tar (text-to-motion `networks/modules.py`).
EXPECTED = {
    "movement_encoder": {
        "main.0.weight": (512, 259, 4), "main.0.bias": (512,), "main.3.weight": (512, 512, 4),
        "main.3.bias": (512,), "out_net.weight": (512, 512), "out_net.bias": (512,),
    },
    "text_encoder": {
        "pos_emb.weight": (300, 15), "pos_emb.bias": (300,), "input_emb.weight": (512, 300),
        "input_emb.bias": (512,), "gru.weight_ih_l0": (1536, 512), "gru.weight_hh_l0": (1536, 512),
        "gru.bias_ih_l0": (1536,), "gru.bias_hh_l0": (1536,), "gru.weight_ih_l0_reverse": (1536, 512),
        "gru.weight_hh_l0_reverse": (1536, 512), "gru.bias_ih_l0_reverse": (1536,),
        "gru.bias_hh_l0_reverse": (1536,), "output_net.0.weight": (512, 1024), "output_net.0.bias": (512,),
        "output_net.1.weight": (512,), "output_net.1.bias": (512,), "output_net.3.weight": (512, 512),
        "output_net.3.bias": (512,), "hidden": (2, 1, 512),
    },
    "motion_encoder": {
        "input_emb.weight": (1024, 512), "input_emb.bias": (1024,), "gru.weight_ih_l0": (3072, 1024),
        "gru.weight_hh_l0": (3072, 1024), "gru.bias_ih_l0": (3072,), "gru.bias_hh_l0": (3072,),
        "gru.weight_ih_l0_reverse": (3072, 1024), "gru.weight_hh_l0_reverse": (3072, 1024),
        "gru.bias_ih_l0_reverse": (3072,), "gru.bias_hh_l0_reverse": (3072,),
        "output_net.0.weight": (1024, 2048), "output_net.0.bias": (1024,), "output_net.1.weight": (1024,),
        "output_net.1.bias": (1024,), "output_net.3.weight": (512, 1024), "output_net.3.bias": (512,),
        "hidden": (2, 1, 1024),
    },
}


def test_state_dict_layout_matches_published():
    model = guo.GuoEvaluator(263)
    for name, shapes in EXPECTED.items():
        got = {k: tuple(v.shape) for k, v in getattr(model, name).state_dict().items()}
        assert got == shapes, name
    assert guo.GuoEvaluator(251).movement_encoder.main[0].weight.shape == (512, 247, 4)


def _fake_archive(tmp_path, seed=0):
    torch.manual_seed(seed)
    src = guo.GuoEvaluator(263)
    ckpt = {name: getattr(src, name).state_dict() for name in EXPECTED}
    ckpt.update(epoch=12, iter=3400, opt_text_encoder={"state": {}, "param_groups": [{"lr": 1e-4, "params": [0]}]})
    root = tmp_path / "checkpoints"
    (root / "t2m/text_mot_match/model").mkdir(parents=True)
    torch.save(ckpt, root / "t2m/text_mot_match/model/finest.tar")
    meta = root / "t2m/Comp_v6_KLD01/meta"
    meta.mkdir(parents=True)
    np.save(meta / "mean.npy", np.random.default_rng(0).normal(size=263).astype(np.float32))
    np.save(meta / "std.npy", np.full(263, 0.5, np.float32))
    glove = root / "glove"
    glove.mkdir()
    words = ["sos", "eos", "unk", "a", "person", "walk", "forward", "slowly"]
    np.save(glove / "our_vab_data.npy", np.random.default_rng(1).normal(size=(len(words), 300)).astype(np.float32))
    with open(glove / "our_vab_words.pkl", "wb") as f:
        pickle.dump(words, f)
    with open(glove / "our_vab_idx.pkl", "wb") as f:
        pickle.dump({w: i for i, w in enumerate(words)}, f)
    return src, root


def test_checkpoint_roundtrip_and_encoders(tmp_path):
    src, root = _fake_archive(tmp_path)
    assets = guo.find_guo_assets(root, "humanml3d")
    model = guo.load_guo_evaluator(assets)
    for name in EXPECTED:
        for k, v in getattr(src, name).state_dict().items():
            torch.testing.assert_close(getattr(model, name).state_dict()[k], v)
    np.testing.assert_allclose(model.std.numpy(), 0.5)
    # Motion path: raw features + lengths. Padding values must not matter (they are zeroed in
    # evaluator-normalised space, as the reference loader pads), nor the other batch members.
    torch.manual_seed(0)
    feats = torch.randn(3, 64, 263)
    lengths = torch.tensor([64, 40, 52])
    emb = model.encode_motion(feats, lengths)
    assert emb.shape == (3, 512)
    garbage = feats.clone()
    garbage[1, 40:] = 1e3
    torch.testing.assert_close(model.encode_motion(garbage, lengths), emb, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(model.encode_motion(feats[1:2], lengths[1:2]), emb[1:2], atol=1e-5, rtol=1e-5)
    assert not torch.allclose(model.encode_motion(feats, torch.tensor([64, 44, 52]))[1], emb[1], atol=1e-3)
    # Text path.
    wv = WordVectorizer(assets.glove_dir)
    w, p, n = wv.encode_tokens("a/DET person/NOUN walk/VERB forward/ADV slowly/ADV xyzzy/NOUN".split())
    assert w.shape == (22, 300) and p.shape == (22, 15) and n == 8
    text = model.encode_text(torch.from_numpy(w)[None], torch.from_numpy(p)[None], torch.tensor([n]))
    assert text.shape == (1, 512) and torch.isfinite(text).all()


def test_wrong_layout_is_a_clear_error(tmp_path):
    _, root = _fake_archive(tmp_path)
    with pytest.raises(StableMoError, match="published layout"):
        guo.GuoEvaluator(251).load_checkpoint(root / "t2m/text_mot_match/model/finest.tar")
    with pytest.raises(StableMoError, match="finest.tar"):
        guo.find_guo_assets(tmp_path / "nothing")


def test_word_vectorizer_pos_and_vip(tmp_path):
    _, root = _fake_archive(tmp_path)
    wv = WordVectorizer(root / "glove")
    vec, pos = wv["walk/VERB"]
    assert pos.argmax() == POS_INDEX["Act_VIP"]  # VIP list overrides the tag
    assert wv["person/NOUN"][1].argmax() == POS_INDEX["NOUN"]
    assert wv["slowly/ADV"][1].argmax() == POS_INDEX["Desc_VIP"]
    assert wv["a/DET"][1].argmax() == POS_INDEX["DET"]
    vec_unk, pos_unk = wv["zebra/NOUN"]  # out of vocabulary: unk vector, OTHER
    np.testing.assert_array_equal(vec_unk, wv.vectors[2])
    assert pos_unk.argmax() == POS_INDEX["OTHER"]
    w, p, n = wv.encode_tokens(["a/DET"] * 30)  # long sentence: cropped to 20 + sos + eos
    assert n == 22 and p[0].argmax() == POS_INDEX["OTHER"]


@pytest.mark.parametrize("protocol", [0, 2, 3, 4, 5])
def test_safe_pickle_reader_all_protocols(tmp_path, protocol):
    words = ["sos", "eos", "unk"] + [f"w{i}" for i in range(300)] + ["sos"]
    idx = {w: i for i, w in enumerate(words)}
    (tmp_path / "w.pkl").write_bytes(pickle.dumps(words, protocol=protocol))
    (tmp_path / "i.pkl").write_bytes(pickle.dumps(idx, protocol=protocol))
    assert read_pickled_strings(tmp_path / "w.pkl") == words
    assert read_pickled_strings(tmp_path / "i.pkl") == idx


class _Evil:
    def __reduce__(self):
        return (os.system, ("echo pwned > /dev/null",))


def test_safe_pickle_reader_refuses_code(tmp_path):
    (tmp_path / "evil.pkl").write_bytes(pickle.dumps(["a", _Evil()]))
    with pytest.raises(StableMoError, match="refusing pickle opcode"):
        read_pickled_strings(tmp_path / "evil.pkl")
    (tmp_path / "arr.pkl").write_bytes(pickle.dumps([1.5, "a"]))
    with pytest.raises(StableMoError):
        read_pickled_strings(tmp_path / "arr.pkl")


def test_text_conversion_matches_pickle(tmp_path, capsys):
    from stablemo.cli import main as cli

    _, root = _fake_archive(tmp_path)
    glove = root / "glove"
    from_pkl = WordVectorizer(glove)
    assert cli(["data", "glove-words", str(tmp_path / "nowhere")]) == 2  # one line naming the file
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nowhere" in err
    assert cli(["data", "glove-words", str(glove)]) == 0
    out = glove / "our_vab_words.txt"
    assert out.read_text().split("\n")[:3] == ["sos", "eos", "unk"]
    (glove / "our_vab_words.pkl").unlink()
    (glove / "our_vab_idx.pkl").unlink()
    from_txt = WordVectorizer(glove)
    for token in ("person/NOUN", "walk/VERB", "nothing/NOUN"):
        np.testing.assert_array_equal(from_pkl[token][0], from_txt[token][0])


REAL = os.environ.get("STABLEMO_GUO_EVALUATOR")


@pytest.mark.skipif(not REAL or not Path(REAL).exists(), reason="set STABLEMO_GUO_EVALUATOR to the published checkpoints root")
def test_real_published_checkpoint_loads():
    assets = guo.find_guo_assets(REAL, "humanml3d")
    model = guo.load_guo_evaluator(assets)
    feats = model.mean.expand(2, 64, -1).clone()
    assert model.encode_motion(feats, torch.tensor([64, 48])).shape == (2, 512)
    assert len(WordVectorizer(assets.glove_dir)) > 1000


def test_command_adapter_for_the_published_evaluator(tmp_path):
    from stablemo.eval.evaluate import (
        GuoTextMotionEvaluator,
        embed_motions,
        load_text_motion_evaluator,
    )

    _, root = _fake_archive(tmp_path)
    adapter = load_text_motion_evaluator(root / "t2m/text_mot_match/model/finest.tar", "humanml3d", root / "glove")
    assert isinstance(adapter, GuoTextMotionEvaluator) and adapter.feature_dim == 263
    text = adapter.embed_text(["a person walks", "jump"], [["a/DET", "person/NOUN", "walk/VERB"], []])
    assert text.shape == (2, 512)
    torch.manual_seed(1)
    feats = [torch.randn(n, 263) for n in (64, 40, 196)]
    emb = embed_motions(adapter, feats, batch_size=2)
    # Every motion is padded to 196 frames, as the reference loader does: batching does not matter.
    single = np.concatenate([adapter.embed_motion(f[None], torch.tensor([len(f)])) for f in feats])
    np.testing.assert_allclose(emb, single, atol=1e-5)
