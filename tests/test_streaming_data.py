"""MotionDataModule(shards=...): the folder reader's items, seeded epochs, rank shares, bounded memory, exact resume."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from test_training import _fit, tiny_config, write_random_dataset

from stablemo.data import MotionDataModule
from stablemo.data.shards import write_shards
from stablemo.data.streaming import ShardSampler
from stablemo.errors import StableMoError
from stablemo.training.checkpoint_io import load_checkpoint_file


@pytest.fixture(scope="module")
def synth(tmp_path_factory) -> tuple[Path, Path]:
    """A synthetic folder (sub-captioned clips, so items != clips) and its shards, 9 clips a shard."""
    from stablemo.data.synth.writer import write_dataset

    base = tmp_path_factory.mktemp("synth")
    folder = write_dataset(base / "folder", num=40, seed=2, workers=1)
    write_shards([str(folder)], str(base / "shards"), clips_per_shard=9, progress=False)
    return folder, base / "shards"


def both(synth, **kwargs) -> tuple[MotionDataModule, MotionDataModule]:
    folder, shards = synth
    kwargs = {"batch_size": 4, "max_length": 64, "pad_multiple": 4, "seed": 5, **kwargs}
    a, b = MotionDataModule(str(folder), **kwargs), MotionDataModule(shards=str(shards), **kwargs)
    a.setup("fit"), b.setup("fit")
    return a, b


def test_items_stats_and_body_are_the_folder_readers(synth):
    a, b = both(synth)
    for role in ("train", "val"):
        da, db = a.datasets[role], b.datasets[role]
        assert len(da) == len(db) and len(db) > 0
        for epoch in (0, 3):
            for i in range(len(da)):
                x, y = da[(i, epoch)], db[(i, epoch)]  # same caption and crop: seeded by (seed, epoch, item)
                assert (x["id"], x["text"], x["length"]) == (y["id"], y["text"], y["length"])
                assert torch.equal(x["motion"], y["motion"])
    assert len(a.datasets["train"]) > 30  # sub-caption windows counted like the folder reader's
    assert np.array_equal(a.mean, b.mean) and np.array_equal(a.std, b.std)
    np.testing.assert_allclose(a.body, b.body, rtol=1e-6)


def _ids(loader, epoch: int) -> list[str]:
    loader.sampler.set_epoch(epoch)
    return [i for batch in loader for i in batch["id"]]


def test_epochs_are_seeded_shuffles_of_every_item_and_batches_pad_the_same(synth):
    _, b = both(synth)
    loader = b.train_dataloader()
    first = _ids(loader, 0)
    assert sorted(first) == sorted(b.datasets["train"][(i, 0)]["id"] for i in range(len(b.datasets["train"])))
    assert _ids(loader, 0) == first and _ids(loader, 1) != first  # replayed exactly; a new order each epoch
    _, other = both(synth, seed=6)
    assert _ids(other.train_dataloader(), 0) != first
    _, workers = both(synth, num_workers=2)
    assert _ids(workers.train_dataloader(), 0) == first  # loader processes do not change the data
    for batch in loader:  # the folder reader's collate: zero padding to a multiple of pad_multiple, a frame mask
        assert batch["motion"].shape[1] % 4 == 0 and batch["motion"].shape[1] == -(-int(batch["length"].max()) // 4) * 4
        assert torch.equal(batch["mask"], torch.arange(batch["motion"].shape[1])[None] < batch["length"][:, None])
        assert not batch["motion"][~batch["mask"]].any()


def test_ranks_get_disjoint_equal_shares_and_resume_anywhere():
    counts = np.array([9, 7, 9, 4, 9, 8])  # items per shard
    total = int(counts.sum())
    for world in (1, 2, 3, 4):
        shares = [ShardSampler(counts, seed=1, rank=r, world_size=world) for r in range(world)]
        for s in shares:
            s.set_epoch(2)
        orders = [s.order() for s in shares]
        assert {len(o) for o in orders} == {total // world}  # same number of batches on every rank
        flat = np.concatenate(orders)
        assert len(set(flat.tolist())) == len(flat) == world * (total // world)  # disjoint, nothing twice
        assert [list(iter(s)) for s in shares] == [[(int(i), 2) for i in o] for o in orders]
        shares[0].start_at(5)  # a mid-epoch resume: the same order from position 5
        assert [i for i, _ in shares[0]] == orders[0][5:].tolist()
        assert [i for i, _ in shares[0]] == orders[0].tolist()  # once only
    plain = ShardSampler(counts, shuffle=False)
    assert plain.order().tolist() == list(range(total))
    a, b = ShardSampler(counts, seed=1), ShardSampler(counts, seed=1)
    b.set_epoch(1)
    assert a.order().tolist() != b.order().tolist()
    # a rank reads only its part of the shards: with 3 ranks, rank 0 touches at most 3 of 6 shards
    first = np.concatenate([[0], np.cumsum(counts)])
    touched = set(np.searchsorted(first, ShardSampler(counts, seed=4, rank=0, world_size=3).order(), side="right") - 1)
    assert len(touched) <= 3


def test_datamodule_gives_each_rank_its_share(synth):
    class FakeTrainer:
        def __init__(self, rank, world):
            self.global_rank, self.world_size = rank, world

    ids = []
    for rank in range(2):
        _, b = both(synth)
        b.trainer = FakeTrainer(rank, 2)
        ids.append(_ids(b.train_dataloader(), 0))
    n = len(b.datasets["train"])
    assert len(ids[0]) == len(ids[1]) == n // 2 and not set(ids[0]) & set(ids[1])


def test_memory_is_bounded_by_the_shuffle_window(synth):
    _, b = both(synth)
    ds = b.datasets["train"]
    decoded, real = [], type(ds).shard

    def counting(self, s):
        if s not in self._decoded:
            decoded.append(s)
        out = real(self, s)
        assert len(self._decoded) <= self.cache_shards
        return out

    type(ds).shard = counting
    try:
        loader = b.train_dataloader()
        loader.sampler.set_epoch(0)
        list(loader)
    finally:
        type(ds).shard = real
    shards = len(ds.shards)
    assert shards >= 4 and len(decoded) == shards  # every shard decoded once per epoch, never re-read


def test_resume_mid_epoch_from_shards_is_exact(tmp_path):
    """6 steps straight == 3 steps, then resume for 3 (4 batches an epoch), training from shards."""
    data = write_random_dataset(tmp_path / "tiny")
    write_shards([str(data)], str(tmp_path / "shards"), clips_per_shard=3, progress=False)
    over = {"data.data_dir": None, "data.shards": str(tmp_path / "shards")}
    straight, split = tmp_path / "straight", tmp_path / "split"
    _fit(tiny_config(straight, data, **over))
    cfg = tiny_config(split, data, **over)
    _fit(cfg, "--trainer.max_steps=3")
    _fit(cfg, "--ckpt_path=last")
    a = load_checkpoint_file(straight / "checkpoints" / "last.ckpt")
    b = load_checkpoint_file(split / "checkpoints" / "last.ckpt")
    assert a["global_step"] == b["global_step"] == 6
    for key in a["state_dict"]:
        assert torch.equal(a["state_dict"][key], b["state_dict"][key]), key
    for key in a["stablemo"]["ema"]["shadow"]:
        assert torch.equal(a["stablemo"]["ema"]["shadow"][key], b["stablemo"]["ema"]["shadow"][key]), key
    loops = b["loops"]["fit_loop"]["state_dict"]["combined_loader"]
    assert loops == [{"epoch": 1, "batches": 2}]  # stopped mid-epoch 1 of 4-batch epochs, as intended


def test_shard_settings_are_checked(synth, tmp_path):
    folder, shards = synth
    with pytest.raises(StableMoError, match="both data_dir .* and shards .* add --data.data_dir=null"):
        MotionDataModule(str(folder), shards=str(shards))
    with pytest.raises(StableMoError, match="give data_dir .* or shards"):
        MotionDataModule()
    with pytest.raises(StableMoError, match="holds humanml3d clips, but dataset='kit'"):
        MotionDataModule(shards=str(shards), dataset="kit").mean
    with pytest.raises(StableMoError, match="missing: shard folder not found"):
        MotionDataModule(shards=str(tmp_path / "missing")).prepare_data()
    with pytest.raises(StableMoError, match=r"manifest.json: not found \(not a shard folder\)"):
        MotionDataModule(shards=str(folder)).prepare_data()


@pytest.mark.skipif(__import__("shutil").which("curl") is None, reason="WebDataset opens http:// URLs with curl")
def test_shards_stream_from_an_http_url(synth):
    import functools
    import http.server
    import threading

    folder, shards = synth
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(shards))
    handler.log_message = lambda *a: None
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        url = f"http://127.0.0.1:{server.server_address[1]}"
        local = MotionDataModule(shards=str(shards), batch_size=4, seed=5)
        remote = MotionDataModule(shards=url, batch_size=4, seed=5)
        local.setup("fit"), remote.setup("fit")
        assert np.array_equal(local.mean, remote.mean)
        a, b = local.datasets["train"], remote.datasets["train"]
        for i in range(0, len(a), 3):
            assert a[(i, 1)]["id"] == b[(i, 1)]["id"] and torch.equal(a[(i, 1)]["motion"], b[(i, 1)]["motion"])
        with pytest.raises(StableMoError, match=r"/nothing/manifest.json: cannot open"):
            MotionDataModule(shards=url + "/nothing").prepare_data()
    finally:
        server.shutdown()


DDP_SCRIPT = '''
import json, sys
import lightning as L
import torch
from stablemo.data import MotionDataModule

class Recorder(L.LightningModule):
    def __init__(self):
        super().__init__()
        self.w = torch.nn.Parameter(torch.zeros(1))
        self.seen = []

    def training_step(self, batch, i):
        self.seen.append(list(batch["id"]))
        return self.w.sum() * batch["motion"].mean()

    def configure_optimizers(self):
        return torch.optim.SGD(self.parameters(), lr=0.0)

    def on_train_end(self):
        with open(f"{sys.argv[2]}/rank{self.global_rank}.json", "w") as f:
            json.dump({"seen": self.seen, "sampler": type(self.trainer.train_dataloader.sampler).__name__}, f)

if __name__ == "__main__":
    trainer = L.Trainer(accelerator="cpu", devices=2, strategy="ddp", max_epochs=1, logger=False,
                        enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False,
                        limit_val_batches=0)
    trainer.fit(Recorder(), datamodule=MotionDataModule(shards=sys.argv[1], batch_size=4, seed=1))
'''


@pytest.mark.slow  # two processes under Lightning's DDP (gloo)
def test_lightning_ddp_keeps_the_shard_sampler_and_ranks_share_the_epoch(synth, tmp_path):
    import json
    import subprocess
    import sys

    _, shards = synth
    script = tmp_path / "ddp_ids.py"
    script.write_text(DDP_SCRIPT)
    subprocess.run([sys.executable, str(script), str(shards), str(tmp_path)], check=True, capture_output=True,
                   timeout=600)
    ranks = [json.loads((tmp_path / f"rank{r}.json").read_text()) for r in range(2)]
    assert [r["sampler"] for r in ranks] == ["ShardSampler", "ShardSampler"]  # not wrapped by Lightning
    ids = [[i for batch in r["seen"] for i in batch] for r in ranks]
    _, b = both(synth)
    total = len(b.datasets["train"])
    assert len(ranks[0]["seen"]) == len(ranks[1]["seen"])  # same number of steps on both ranks
    assert len(ids[0]) == len(ids[1]) == total // 2 and not set(ids[0]) & set(ids[1])
