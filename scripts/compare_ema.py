"""Measure whether stablemo.lit.ema.EMA can be replaced by Lightning's WeightAveraging (issue #19 item 6).

    .venv/bin/python scripts/compare_ema.py            # all sections, ~1 min on 2 CPU cores
    .venv/bin/python scripts/compare_ema.py --no-ddp   # skip the 2-process gloo DDP run

Sections (each prints its numbers):
  1. equality   -- AveragedModel with an avg_fn reproducing beta_n = min(decay, (1+n)/(warmup+n)) vs our EMA,
                   same weight sequence, max |diff| after N steps (float32; also bf16 weights).
  2. resume     -- Lightning: N straight steps vs k steps + checkpoint + resume to N; are WeightAveraging's
                   averaged weights (and our EMA's shadow) bit-identical? Also WA vs our EMA in the same run.
  3. cost       -- what WeightAveraging copies (deepcopy of the whole LightningModule) on the tiny
                   DiffusionModule of tests/test_training.py: bytes, the frozen text encoder, the nested EMA.
  4. ddp        -- 2 processes, gloo, strategy="ddp": averaged weights identical across ranks? What DDP
                   broadcasts / all-reduces, and whether any averaged-model tensor is among it.
"""

from __future__ import annotations

import argparse
import itertools
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch
from lightning.pytorch import LightningModule, Trainer
from lightning.pytorch.callbacks import Callback, ModelCheckpoint, WeightAveraging
from torch import nn
from torch.optim.swa_utils import AveragedModel
from torch.utils.data import DataLoader, TensorDataset

from stablemo.io import atomic_open, write_text
from stablemo.lit.ema import EMA

DECAY, WARMUP = 0.999, 10.0


# ---------------------------------------------------------------------------------------------- averaging functions

def beta(n: int, decay: float = DECAY, warmup: float = WARMUP) -> float:
    return decay if warmup <= 1.0 else min(decay, (1.0 + n) / (warmup + n))


def avg_fn_naive(avg, cur, num_averaged):
    """Our beta_n with AveragedModel's own counter; AveragedModel *copies* at its first update (n_averaged == 0),
    so the initial weights are dropped where ours keeps 1/warmup of them."""
    b = beta(int(num_averaged))
    return b * avg + (1.0 - b) * cur


def avg_fn_offset(avg, cur, num_averaged):
    """For use with n_averaged pre-set to 1 (the weights at construction count as the first 'average'):
    beta index = n_averaged - 1, and the same lerp as ours."""
    return avg.lerp(cur.to(avg.dtype), 1.0 - beta(int(num_averaged) - 1))


class OffsetWeightAveraging(WeightAveraging):
    """WeightAveraging whose average starts from the weights at fit start, as our EMA does."""

    def setup(self, trainer, pl_module, stage):
        super().setup(trainer, pl_module, stage)
        if stage == "fit":
            self._average_model.n_averaged.fill_(1)


def tiny_net() -> nn.Module:
    torch.manual_seed(0)
    net = nn.Sequential(nn.Linear(16, 64), nn.GroupNorm(4, 64), nn.SiLU(), nn.Linear(64, 16))
    net.register_buffer("scale", torch.ones(16))  # a float buffer, averaged by both
    return net


def max_diff(a: dict, b: dict) -> float:
    return max((a[k].float() - b[k].float()).abs().max().item() for k in a)


def bit_equal(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


# ---------------------------------------------------------------------------------------------- 1. equality

def section_equality(steps: int = 300) -> None:
    print(f"== 1. equality: {steps} SGD steps on random gradients, decay={DECAY}, warmup={WARMUP}")
    for dtype in (torch.float32, torch.bfloat16):
        net = tiny_net().to(dtype)
        ours = EMA(net, decay=DECAY, warmup=WARMUP)
        naive = AveragedModel(net, avg_fn=avg_fn_naive, use_buffers=True)
        offset = AveragedModel(net, avg_fn=avg_fn_offset, use_buffers=True)
        offset.n_averaged.fill_(1)
        ref64 = {k: v.double().clone() for k, v in net.state_dict().items()}  # float64 reference average
        gen = torch.Generator().manual_seed(1)
        for n in range(steps):
            with torch.no_grad():
                for p in net.parameters():
                    p.add_(torch.randn(p.shape, generator=gen).to(dtype), alpha=-1e-2)
            ours.update(net)
            naive.update_parameters(net)
            offset.update_parameters(net)
            b = beta(n)
            for k, v in net.state_dict().items():
                ref64[k] = b * ref64[k] + (1 - b) * v.double()
        ours_sd = ours.shadow
        naive_sd = {k[len("module."):]: v for k, v in naive.state_dict().items() if k.startswith("module.")}
        off_sd = {k[len("module."):]: v for k, v in offset.state_dict().items() if k.startswith("module.")}
        name = str(dtype).replace("torch.", "")
        print(f"  weights {name}: |ours - float64 ref| {max_diff(ours_sd, ref64):.3e}")
        print(f"  weights {name}: |AveragedModel(naive avg_fn, first update copies) - ours| {max_diff(naive_sd, ours_sd):.3e}")
        print(f"  weights {name}: |AveragedModel(n_averaged preset 1, lerp avg_fn) - ours| {max_diff(off_sd, ours_sd):.3e}"
              f"  bit-identical={bit_equal({k: v.float() for k, v in off_sd.items()}, ours_sd)}"
              f"  |AveragedModel - float64 ref| {max_diff(off_sd, ref64):.3e}  (avg dtype {next(iter(off_sd.values())).dtype})")


# ---------------------------------------------------------------------------------------------- Lightning tiny runs

class LitTiny(LightningModule):
    """A small module that also carries our EMA exactly as DiffusionModule does (update in optimizer_step,
    saved in on_save_checkpoint)."""

    def __init__(self):
        super().__init__()
        self.net = tiny_net()
        self.ema = EMA(self.net, decay=DECAY, warmup=WARMUP)

    def training_step(self, batch, batch_idx):
        x, y = batch
        return nn.functional.mse_loss(self.net(x), y)

    def optimizer_step(self, *args, **kwargs):
        super().optimizer_step(*args, **kwargs)
        self.ema.update(self.net)

    def configure_optimizers(self):
        return torch.optim.AdamW(self.parameters(), lr=1e-2)

    def on_save_checkpoint(self, checkpoint):
        checkpoint["ours_ema"] = self.ema.state_dict()

    def on_load_checkpoint(self, checkpoint):
        self.ema.load_state_dict(checkpoint["ours_ema"])


def loader(num_batches: int = 4, batch: int = 8) -> DataLoader:
    """Every batch holds the same samples: a plain DataLoader restarts its epoch on a mid-epoch resume, and
    identical batches keep that from changing the live weights (the repo's data module resumes exactly)."""
    gen = torch.Generator().manual_seed(2)
    x = torch.randn(batch, 16, generator=gen).repeat(num_batches, 1)
    return DataLoader(TensorDataset(x, x.flip(-1) * 0.5), batch_size=batch, shuffle=False)


class Capture(Callback):
    """Placed before WeightAveraging: records live weights, WA's average and our shadow at on_train_end,
    before WeightAveraging.on_train_end overwrites the live weights with the average."""

    def __init__(self, wa: WeightAveraging):
        self.wa, self.out = wa, {}

    def on_train_end(self, trainer, pl_module):
        avg = self.wa._average_model.module
        self.out = {
            "live": {k: v.clone() for k, v in pl_module.net.state_dict().items()},
            "wa": {k: v.clone() for k, v in avg.net.state_dict().items()},
            "ours": {k: v.clone() for k, v in pl_module.ema.shadow.items()},
            "n_averaged": int(self.wa._average_model.n_averaged),
            "ours_updates": pl_module.ema.num_updates,
        }


def fit(max_steps: int, root: Path, ckpt_path=None, every=None, wa_cls=OffsetWeightAveraging) -> dict:
    wa = wa_cls(avg_fn=avg_fn_offset if wa_cls is OffsetWeightAveraging else avg_fn_naive)
    cap = Capture(wa)
    callbacks = [cap, wa]
    if every:
        callbacks.append(ModelCheckpoint(dirpath=root, every_n_train_steps=every, save_top_k=-1,
                                         filename="{step}"))
    trainer = Trainer(max_steps=max_steps, accelerator="cpu", devices=1, logger=False, callbacks=callbacks,
                      enable_checkpointing=bool(every), enable_progress_bar=False, enable_model_summary=False,
                      default_root_dir=root, num_sanity_val_steps=0, deterministic=True)
    torch.manual_seed(0)
    trainer.fit(LitTiny(), loader(), ckpt_path=ckpt_path)
    return cap.out


def section_resume(tmp: Path, n: int = 10) -> None:
    print(f"== 2. exact resume (Lightning, {n} steps, 4 batches/epoch, AdamW lr 1e-2)")
    for wa_cls in (OffsetWeightAveraging, WeightAveraging):
        label = "WA(n_averaged preset 1, lerp avg_fn)" if wa_cls is OffsetWeightAveraging else "WA(naive avg_fn)"
        root = tmp / wa_cls.__name__
        straight = fit(n, root / "straight", every=3, wa_cls=wa_cls)  # also writes step=3,6,9 checkpoints
        print(f"  {label}: straight run vs our EMA in the same run: |WA - ours| {max_diff(straight['wa'], straight['ours']):.3e}"
              f" bit-identical={bit_equal(straight['wa'], straight['ours'])}"
              f" (n_averaged={straight['n_averaged']}, our updates={straight['ours_updates']})")
        for k in (3, 4):  # 3: mid-epoch, 4: epoch boundary
            ck = root / "straight" / f"step={k}.ckpt"
            if not ck.exists():
                # 4 is not a multiple of 3: write it with a separate k-step run
                fit(k, root / f"k{k}", every=k, wa_cls=wa_cls)
                ck = root / f"k{k}" / f"step={k}.ckpt"
            resumed = fit(n, root / f"resume{k}", ckpt_path=str(ck), wa_cls=wa_cls)
            print(f"    resume from step {k}: live bit-identical={bit_equal(straight['live'], resumed['live'])}"
                  f"  WA average bit-identical={bit_equal(straight['wa'], resumed['wa'])}"
                  f" (|diff| {max_diff(straight['wa'], resumed['wa']):.1e})"
                  f"  our EMA bit-identical={bit_equal(straight['ours'], resumed['ours'])}")
    ck = torch.load(tmp / "OffsetWeightAveraging" / "straight" / "step=3.ckpt", weights_only=False)
    print(f"  WA checkpoint layout: state_dict = AVERAGED weights, live weights under 'current_model_state',"
          f" keys {sorted(k for k in ck if k in ('state_dict', 'current_model_state', 'averaging_state'))},"
          f" averaging_state={ {k: v.tolist() for k, v in ck['averaging_state'].items()} }")


# ---------------------------------------------------------------------------------------------- 3. cost

def nbytes(tensors) -> int:
    return sum(t.numel() * t.element_size() for t in tensors)


def section_cost() -> None:
    print("== 3. what WeightAveraging copies: AveragedModel(DiffusionModule(tests' TINY_MODEL))")
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from test_training import TINY_MODEL

    from stablemo.lit.module import DiffusionModule

    module = DiffusionModule(model=TINY_MODEL)
    enc = module.model.text._frozen
    t0 = time.perf_counter()
    avg = AveragedModel(module, use_buffers=True)  # what WeightAveraging.setup does
    dt = time.perf_counter() - t0
    copied = avg.module
    live_pb = nbytes(itertools.chain(module.parameters(), module.buffers()))
    avg_pb = nbytes(itertools.chain(copied.parameters(), copied.buffers()))
    shadow = nbytes(module.ema.shadow.values())
    nested = nbytes(copied.ema.shadow.values())
    shared_nested = any(a.data_ptr() == b.data_ptr() for a, b in zip(copied.ema.shadow.values(), module.ema.shadow.values()))
    print(f"  deepcopy time {dt * 1e3:.1f} ms; module params+buffers {live_pb / 1e6:.3f} MB; our EMA shadow {shadow / 1e6:.3f} MB")
    print(f"  AveragedModel params+buffers {avg_pb / 1e6:.3f} MB (same tensors as the shadow: "
          f"{len(list(copied.parameters())) + len(list(copied.buffers()))} vs {len(module.ema.shadow)})")
    print(f"  plus a deep copy of the module's own EMA shadow: {nested / 1e6:.3f} MB (shared with original: {shared_nested})"
          f" -- i.e. 2x the shadow while both exist")
    print(f"  frozen text encoder: shared, not copied = {copied.model.text._frozen is enc}"
          f" ({nbytes(enc.model.parameters()) / 1e6:.1f} MB of MiniLM weights, outside parameters()/state_dict)")
    print(f"  AveragedModel also keeps n_averaged (int64 buffer); other deep-copied attributes: NoiseSchedule tables "
          f"{nbytes([copied.schedule.betas, copied.schedule.alphas_cumprod, copied.schedule.sigmas]) / 1e3:.1f} kB, hparams")
    wa_avg = AveragedModel(module, avg_fn=avg_fn_offset, use_buffers=True)
    wa_avg.n_averaged.fill_(1)
    timings = {}
    for name, update in (("ours EMA.update", lambda: module.ema.update(module.model)),
                         ("AveragedModel.update_parameters", lambda: wa_avg.update_parameters(module))):
        update()
        t0 = time.perf_counter()
        for _ in range(50):
            update()
        timings[name] = (time.perf_counter() - t0) / 50 * 1e3
    print("  per-update time (260 tensors, 1 thread): " + ", ".join(f"{k} {v:.2f} ms" for k, v in timings.items()))


# ---------------------------------------------------------------------------------------------- 4. ddp

def ddp_worker(out: Path) -> None:
    """Runs in each of the 2 ranks (Lightning re-executes this script for rank 1)."""
    import torch.distributed as dist
    from lightning.pytorch.strategies import DDPStrategy
    from torch.distributed.algorithms.ddp_comm_hooks import default_hooks

    log = {"broadcast": [], "allreduce_bytes": 0, "allreduce_calls": 0}
    orig = dist._broadcast_coalesced

    def counting_broadcast(group, tensors, *args, **kwargs):
        tensors = list(tensors)
        log["broadcast"].append([t.data_ptr() for t in tensors] + [nbytes(tensors)])
        return orig(group, tensors, *args, **kwargs)

    dist._broadcast_coalesced = counting_broadcast

    def counting_hook(state, bucket):
        log["allreduce_calls"] += 1
        log["allreduce_bytes"] += bucket.buffer().numel() * bucket.buffer().element_size()
        return default_hooks.allreduce_hook(state, bucket)

    class RegisterHook(Callback):  # Lightning registers DDPStrategy(ddp_comm_hook=...) on CUDA only
        def on_train_start(self, trainer, pl_module):
            trainer.strategy.model.register_comm_hook(state=None, hook=counting_hook)

    wa = OffsetWeightAveraging(avg_fn=avg_fn_offset)
    cap = Capture(wa)
    trainer = Trainer(max_steps=6, accelerator="cpu", devices=2, strategy=DDPStrategy(process_group_backend="gloo"),
                      logger=False, callbacks=[RegisterHook(), cap, wa], enable_checkpointing=False,
                      enable_progress_bar=False, enable_model_summary=False, default_root_dir=out)
    torch.manual_seed(0)
    module = LitTiny()
    trainer.fit(module, loader(num_batches=8))
    avg = wa._average_model
    avg_ptrs = {t.data_ptr() for t in itertools.chain(avg.parameters(), avg.buffers())}
    bcast_ptrs = {p for call in log["broadcast"] for p in call[:-1]}
    rank = trainer.global_rank
    with atomic_open(out / f"rank{rank}.pt") as f:
        torch.save(cap.out, f)
    info = {
        "broadcast_calls": len(log["broadcast"]),
        "broadcast_bytes_per_call": [call[-1] for call in log["broadcast"]],
        "allreduce_calls": log["allreduce_calls"],
        "allreduce_bytes": log["allreduce_bytes"],
        "averaged_tensors_broadcast": len(avg_ptrs & bcast_ptrs),
        "avg_in_ddp_module": any(t is p for t in avg.parameters() for p in trainer.strategy.model.parameters()),
        "ddp_param_bytes": nbytes(trainer.strategy.model.parameters()),
        "ddp_buffer_bytes": nbytes(trainer.strategy.model.buffers()),
        "avg_bytes": nbytes(itertools.chain(avg.parameters(), avg.buffers())),
        "optimizer_steps": trainer.global_step,
    }
    write_text(out / f"rank{rank}.json", json.dumps(info))


def section_ddp(tmp: Path) -> None:
    print("== 4. DDP: 2 processes, gloo, strategy='ddp', 6 steps")
    out = tmp / "ddp"
    out.mkdir()
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, __file__, "--ddp-worker", str(out)], capture_output=True, text=True, check=False,
                          timeout=120)
    if proc.returncode:
        print(proc.stdout[-2000:], proc.stderr[-4000:])
        raise SystemExit("ddp run failed")
    r0, r1 = (torch.load(out / f"rank{r}.pt", weights_only=False) for r in (0, 1))
    i0, i1 = (json.loads((out / f"rank{r}.json").read_text()) for r in (0, 1))
    print(f"  ran in {time.perf_counter() - t0:.1f} s; live weights identical across ranks: {bit_equal(r0['live'], r1['live'])}")
    print(f"  WA average identical across ranks: {bit_equal(r0['wa'], r1['wa'])}; our EMA identical across ranks: "
          f"{bit_equal(r0['ours'], r1['ours'])}; WA vs ours on rank 0 bit-identical: {bit_equal(r0['wa'], r0['ours'])}")
    for r, i in ((0, i0), (1, i1)):
        print(f"  rank {r}: {json.dumps(i)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-ddp", action="store_true")
    parser.add_argument("--ddp-worker", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.ddp_worker:
        ddp_worker(args.ddp_worker)
        return
    torch.set_num_threads(1)
    import logging
    import warnings

    logging.getLogger("lightning.pytorch").setLevel(logging.ERROR)
    warnings.filterwarnings("ignore")
    with tempfile.TemporaryDirectory() as tmp:
        section_equality()
        section_resume(Path(tmp))
        section_cost()
        if not args.no_ddp:
            section_ddp(Path(tmp))


if __name__ == "__main__":
    main()
