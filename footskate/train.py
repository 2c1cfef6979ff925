"""Train our own V22 vGRF network on a dataset whose contacts are known (the synthetic dataset).

Labels come from kinematics + contact labels (`footskate.forces`), never from UnderPressure.
Loss: masked MSLE, as UnderPressure. Augmentations make the network blind to heading, horizontal
position and ±10% body scale (heights stay floor-relative: this is V22, which sees the floor).

    python -m footskate.train --data DIR --out footskate/weights/v22_synth.safetensors --steps 1500

DIR has `new_joints/<id>.npy` (T, 22, 3) and `contacts/<id>.npy` (T, 4) bool
[L_heel, L_toe, R_heel, R_toe].
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch

from footskate.contacts import contacts_from_forces, contacts_from_heights
from footskate.errors import FootskateError, one_line
from footskate.forces import forces_from_contacts
from footskate.skeletons import topology_for
from footskate.vgrf import VGRFNet, msle, save_vgrf

WIDTHS = {"full": ((128, 128, 256, 256), 256), "half": ((64, 64, 128, 128), 128)}


def load_motions(data_dir: Path, fps: float, label_fn=None):
    """-> ids, joints (T, J, 3), contacts (T, 4) or None, force labels (T, 2, 16).

    Labels come from `label_fn(joints, contacts)` if given (e.g. a teacher network), else from
    kinematics and the contact labels (`footskate.forces`), which are then required.
    """
    joint_dir, contact_dir = data_dir / "new_joints", data_dir / "contacts"
    if not joint_dir.is_dir():
        raise FootskateError(f"{data_dir}: expected a new_joints/ folder")
    if label_fn is None and not contact_dir.is_dir():
        raise FootskateError(f"{data_dir}: expected a contacts/ folder (contact labels) beside new_joints/")
    ids, joints, contacts, forces = [], [], [], []
    for jpath in sorted(joint_dir.glob("*.npy")):
        cpath = contact_dir / jpath.name
        if label_fn is None and not cpath.is_file():
            continue
        j = torch.from_numpy(np.load(jpath, allow_pickle=False).astype(np.float32))
        c = torch.from_numpy(np.load(cpath, allow_pickle=False).astype(bool)) if cpath.is_file() else None
        if j.ndim != 3 or j.shape[-1] != 3 or j.shape[0] < 8 or not torch.isfinite(j).all():
            raise FootskateError(f"{jpath}: expected finite joints (T >= 8, J, 3), got {tuple(j.shape)}")
        if c is not None and c.shape != (j.shape[0], 4):
            raise FootskateError(f"{cpath}: contacts {tuple(c.shape)} do not match joints {tuple(j.shape)}")
        if label_fn is not None:
            f = label_fn(j, c)
        else:
            topo = topology_for(j.shape[1])
            f = forces_from_contacts(j[None], c[None], topo.feet, fps, topo.up_axis)[0]
        ids.append(jpath.stem), joints.append(j), contacts.append(c), forces.append(f)
    if not ids:
        raise FootskateError(f"{data_dir}: no usable motion")
    return ids, joints, contacts, forces


def sample_batch(joints, forces, batch: int, window: int, gen: torch.Generator, augment: bool = True):
    """Random windows (B, W, J, 3) / (B, W, 2, 16) + lengths, heading/position/scale augmented."""
    idx = torch.randint(len(joints), (batch,), generator=gen).tolist()
    j_count = joints[0].shape[1]
    x = torch.zeros(batch, window, j_count, 3)
    y = torch.zeros(batch, window, 2, 16)
    lengths = torch.zeros(batch, dtype=torch.long)
    for b, i in enumerate(idx):  # batch assembly (training data loading), not a hot path
        t = joints[i].shape[0]
        n = min(t, window)
        s = int(torch.randint(t - n + 1, (1,), generator=gen))
        x[b, :n], y[b, :n], lengths[b] = joints[i][s:s + n], forces[i][s:s + n], n
        x[b, n:], y[b, n:] = x[b, n - 1], y[b, n - 1]
    if augment:
        theta = torch.rand(batch, generator=gen) * 2 * math.pi
        cos, sin = torch.cos(theta)[:, None, None], torch.sin(theta)[:, None, None]
        start = x[:, :1, :1, [0, 2]]
        xz = x[..., [0, 2]] - start
        rx = cos * xz[..., 0] - sin * xz[..., 1]
        rz = sin * xz[..., 0] + cos * xz[..., 1]
        shift = (torch.rand(batch, 1, 1, 2, generator=gen) - 0.5) * 6.0
        x = torch.stack([rx, x[..., 1], rz], -1)
        x[..., [0, 2]] += shift
        x = x * (0.9 + 0.2 * torch.rand(batch, 1, 1, 1, generator=gen))
    return x, y, lengths


def masked_msle(pred: torch.Tensor, target: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
    """MSLE over the 2×16 cells plus MSLE of the per-foot totals, on valid frames.

    Single cells carry ~1/16 body weight, where log1p is nearly linear and the cell loss alone
    gives a weak signal; the per-foot totals (what contact detection thresholds) speed training up.
    """
    mask = (torch.arange(pred.shape[1])[None, :] < lengths[:, None]).float()
    per_frame = msle(pred, target).mean((-1, -2)) + msle(pred.sum(-1), target.sum(-1)).mean(-1)
    return (per_frame * mask).sum() / mask.sum()


def f1(pred: torch.Tensor, true: torch.Tensor) -> float:
    tp = (pred & true).sum().item()
    denom = pred.sum().item() + true.sum().item()
    return 2 * tp / denom if denom else 1.0


@torch.no_grad()
def evaluate(model: VGRFNet, joints, contacts, forces, fps: float) -> dict[str, float]:
    """Validation loss and contact F1 (network contacts vs labels; heuristic as a baseline)."""
    model.eval()
    topo = topology_for(joints[0].shape[1])
    lengths = torch.tensor([j.shape[0] for j in joints])
    t = int(lengths.max())
    pad = lambda seq: torch.stack([torch.cat([s, s[-1:].expand(t - s.shape[0], *s.shape[1:])]) for s in seq])
    x, y = pad(joints), pad(forces)
    c = pad(contacts) if contacts[0] is not None else None
    pred = model(x, lengths)
    mask = torch.arange(t)[None, :] < lengths[:, None]
    net_c = contacts_from_forces(pred, fps, lengths)[mask]
    label_c = contacts_from_forces(y, fps, lengths)[mask]
    heur_c = contacts_from_heights(x[:, :, list(topo.feet)], fps, topo.up_axis, lengths)[mask]
    if contacts[0] is None:  # no contact labels (distillation): compare with the teacher's contacts
        return {"val_msle": float(masked_msle(pred, y, lengths)), "contact_f1_vs_teacher": f1(net_c, label_c)}
    true = c[mask]
    return {"val_msle": float(masked_msle(pred, y, lengths)), "contact_f1_net": f1(net_c, true),
            "contact_acc_net": float((net_c == true).float().mean()),
            "contact_acc_heuristic": float((heur_c == true).float().mean()),
            "contact_f1_labels_roundtrip": f1(label_c, true), "contact_f1_heuristic": f1(heur_c, true)}


def fit(model: VGRFNet, joints, forces, steps: int, batch: int, window: int, lr: float, gen: torch.Generator,
        log=print) -> VGRFNet:
    """Train `model` in place on random windows of (joints, forces) (sample_batch, augmented): Adam,
    cosine decay to 5 % of `lr`, MSLE; logs every 250 steps. A non-finite loss is a FootskateError."""
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps, eta_min=lr * 0.05)
    started, running = time.time(), 0.0
    for step in range(1, steps + 1):
        model.train()
        x, y, lengths = sample_batch(joints, forces, batch, window, gen)
        loss = masked_msle(model(x, lengths), y, lengths)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        running += float(loss.detach())
        if not math.isfinite(running):
            raise FootskateError(f"vGRF training: the loss became non-finite at step {step}; lower the learning rate")
        if step % 250 == 0 or step == steps:
            log(f"step {step:5d}  train_msle {running / (250 if step % 250 == 0 else step % 250):.5f}  "
                f"lr {sched.get_last_lr()[0]:.2e}  {time.time() - started:.0f}s")
            running = 0.0
    return model.eval()


def train(data_dir: str, out: str, steps: int = 1500, batch: int = 16, window: int = 48, lr: float = 1.5e-4,
          width: str = "half", fps: float = 20.0, seed: int = 0, val_fraction: float = 0.1,
          log=print, label_fn=None, extra_meta: dict | None = None) -> dict:
    torch.manual_seed(seed)
    gen = torch.Generator().manual_seed(seed)
    ids, joints, contacts, forces = load_motions(Path(data_dir), fps, label_fn)
    order = torch.randperm(len(ids), generator=gen).tolist()
    n_val = max(1, int(round(val_fraction * len(ids)))) if len(ids) > 1 else 0
    val, tr = order[:n_val], order[n_val:] or order
    pick = lambda seq, idx: [seq[i] for i in idx]
    channels, hidden = WIDTHS[width]
    model = VGRFNet(joints[0].shape[1], conv_channels=channels, hidden=hidden)
    log(f"footskate.train: {len(tr)} train / {len(val)} val motions from {data_dir}; "
        f"{sum(p.numel() for p in model.parameters())} parameters ({width}); {steps} steps, batch {batch}, window {window}")
    fit(model, pick(joints, tr), pick(forces, tr), steps, batch, window, lr, gen, log)
    metrics = evaluate(model, pick(joints, val), pick(contacts, val), pick(forces, val), fps) if val else {}
    log("validation: " + "  ".join(f"{k} {v:.4f}" for k, v in metrics.items()))
    meta = {"trained_on": str(data_dir), "steps": steps, "batch": batch, "window": window, "lr": lr,
            "seed": seed, "fps": fps, "up_axis": "y",
            "labels": "footskate.forces (kinematics + contact labels)" if label_fn is None else "teacher",
            "metrics": metrics, **(extra_meta or {})}
    save_vgrf(model, out, meta)
    log(f"saved {out}")
    return metrics


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m footskate.train", description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True, help="dataset folder with new_joints/ and contacts/")
    p.add_argument("--out", required=True, help="output .safetensors")
    p.add_argument("--steps", type=int, default=1500)
    p.add_argument("--batch", type=int, default=16)
    p.add_argument("--window", type=int, default=48, help="frames per training window")
    p.add_argument("--lr", type=float, default=1.5e-4, help="above ~3e-4 the Softplus output can die (all-zero forces)")
    p.add_argument("--width", choices=sorted(WIDTHS), default="half")
    p.add_argument("--fps", type=float, default=20.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: leave default)")
    p.add_argument("--log", default=None, help="also append the log to this file")
    args = p.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    log_file = open(args.log, "a") if args.log else None

    def log(msg: str) -> None:
        print(msg, flush=True)
        if log_file:
            log_file.write(msg + "\n")
            log_file.flush()

    log("$ python -m footskate.train " + " ".join(argv if argv is not None else sys.argv[1:]))
    try:
        train(args.data, args.out, args.steps, args.batch, args.window, args.lr, args.width, args.fps, args.seed, log=log)
    except FootskateError as err:
        print(f"footskate.train: error: {one_line(str(err))}", file=sys.stderr)
        return 2
    finally:
        if log_file:
            log_file.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
