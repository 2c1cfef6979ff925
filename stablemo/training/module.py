"""DiffusionModule: the paper's training recipe (§4.2, §5.2) as a LightningModule.

What to compute lives here; devices, precision, gradient clipping, checkpointing and DDP are the
Trainer's job (see configs/*.yaml).

Randomness is derived from (seed, step, batch index, rank) at every step instead of being drawn
from a global stream, so a run resumed from a checkpoint draws exactly the numbers the
uninterrupted run would have drawn.
"""

from __future__ import annotations

import hashlib
import zlib
from typing import Any, Sequence

import torch
from lightning.pytorch import LightningModule

from stablemo.data.stats import same_statistics
from stablemo.diffusion.schedule import PREDICTION_TYPES
from stablemo.errors import StableMoError
from stablemo.motion.skeleton import MAX_FRAMES
from stablemo.training.ema import EMA
from stablemo.training.geometry import GEOMETRY_TERMS, GeometricLoss, geometry_weights

# What the MSE is taken on: the prediction type's own target, or the clean-motion estimate x̂0.
LOSS_ON = ("target", "x0")
# Minimum clip length per dataset (frames), used when the data module does not say.
MIN_LENGTH = {"humanml3d": 40, "kit": 24}
# Validation noise is drawn per sample with this many frames and cropped, so the noise a clip
# sees does not depend on how much padding its batch has.
VAL_NOISE_FRAMES = 256
CHECKPOINT_KEY = "stablemo"


def derive_seed(*parts: Any) -> int:
    """A 63-bit seed from any printable parts; stable across processes and Python versions."""
    digest = hashlib.blake2b(":".join(map(str, parts)).encode(), digest_size=8).digest()
    return int.from_bytes(digest, "little") & ((1 << 63) - 1)


def masked_mse(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean squared error over valid frames. pred/target: (B, T, D), mask: (B, T) bool -> (B,)."""
    sq = (pred.float() - target.float()).square().mean(dim=-1)  # (B, T)
    valid = mask.float()
    return (sq * valid).sum(dim=1) / valid.sum(dim=1).clamp(min=1.0)


class DiffusionModule(LightningModule):
    """DDPM training of a MotionDiffusionModel.

    Args:
        model: MotionDiffusionModel kwargs: {"denoiser": {"name": ..., "input_dim": D, ...}, "text": {...}}.
        schedule: NoiseSchedule kwargs (T = 1000, linear β 1e-4 → 0.02 by default).
        prediction_type: "sample" (x0, the paper's choice), "epsilon" or "v_prediction" (v = sqrt(abar) eps -
            sqrt(1 - abar) x0: the x0 estimate alpha x_t - sigma v keeps x_t's detail at low noise).
        cond_drop_prob: fraction of captions replaced by the null condition "" (CFG training).
        ema_decay, ema_warmup: EMA of the weights, see stablemo.training.ema.EMA.
        lr, weight_decay: AdamW.
        lr_step, lr_gamma: the learning rate is multiplied by lr_gamma every lr_step optimiser steps.
        val_timesteps: validation loss is measured at these timesteps with per-clip fixed noise,
            so it is comparable between runs, architectures and world sizes.
        seed: seeds timesteps, noise, caption dropout and dropout layers at every step.
        fast_training: train through stablemo.fast.train's layers (GEMM convolutions and a vectorised
            Mish backward, gradients equal to stock PyTorch's to float rounding; same parameters and
            state_dict) and a fused AdamW; False: stock layers and AdamW (docs/training.md).
        gemm_conv: with fast_training, the GEMM convolutions (the faster ones on the Xeon measured);
            False keeps oneDNN's (the faster ones on the AMD EPYC measured; `stablemo bench train
            --paired --rows stablemo,stablemo-onednn` compares them on yours). Same gradients either way.
        geometry: weights of MDM's geometric losses on the joints of the clean-motion estimate
            ({positions, velocities, foot_contact, bone_lengths}: see stablemo.training.geometry),
            added to the per-sample loss; absent or all zero: none is computed.
        loss_on: "target" (the MSE on the prediction type's own target: x0, the noise or v) or "x0"
            (the MSE of the clean-motion estimate x̂0 whatever the output: the paper's x0 objective,
            with, under v_prediction, x̂0 = sqrt(abar) x_t - sqrt(1 - abar) v̂ carrying x_t's detail
            at low noise; for "sample" both are the same loss).
        geometry_max_t: the geometric terms count only on samples whose timestep is below this (None:
            on all). x̂0 at high noise is a mean over the motions the input may become, which no
            geometric term holds for (docs/training.md, "The rotation term").
        init_from: a diffusion bundle whose weights the network (and its EMA) start from, to train
            a shipped model further (on more data, say); its `model` config must equal `model` and
            its feature statistics the dataset's. A resumed run takes its weights from the checkpoint.
            One difference is allowed: a UNet may grow temporal self-attention (`mid_attention` from 0,
            `up_attention` entries from 0), whose blocks start as the identity, so the grown network
            starts as the bundle's network exactly (`grown_attention`).
    """

    def __init__(
        self,
        model: dict[str, Any],
        schedule: dict[str, Any] | None = None,
        prediction_type: str = "sample",
        cond_drop_prob: float = 0.1,
        ema_decay: float = 0.9999,
        ema_warmup: float = 10.0,
        lr: float = 2e-4,
        weight_decay: float = 0.01,
        lr_step: int = 5000,
        lr_gamma: float = 0.9,
        val_timesteps: Sequence[int] = (50, 250, 500, 750, 950),
        seed: int = 0,
        fast_training: bool = True,
        gemm_conv: bool = True,
        geometry: dict[str, float] | None = None,
        loss_on: str = "target",
        init_from: str | None = None,
        geometry_max_t: int | None = None,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        if prediction_type not in PREDICTION_TYPES:
            raise StableMoError(f"prediction_type: expected one of {PREDICTION_TYPES}, got {prediction_type!r}")
        if loss_on not in LOSS_ON:
            raise StableMoError(f"loss_on: expected one of {LOSS_ON}, got {loss_on!r}")
        if not 0.0 <= cond_drop_prob <= 1.0:
            raise StableMoError(f"cond_drop_prob: must be in [0, 1], got {cond_drop_prob}")
        if lr_step < 1:
            raise StableMoError(f"lr_step: must be >= 1, got {lr_step}")
        self.geometry_weights = geometry_weights(geometry)  # {} = off
        # (the data_info it was built for, held so that identity means the same dataset; the loss)
        self._geometric_loss: tuple[dict, GeometricLoss] | None = None
        from stablemo.diffusion.schedule import NoiseSchedule
        from stablemo.nets.model import MotionDiffusionModel

        self.model = MotionDiffusionModel(**model)
        if fast_training:
            from stablemo.fast.train import accelerate_training

            accelerate_training(self.model, gemm_conv=gemm_conv)
        self.schedule = NoiseSchedule(**(schedule or {}))
        num_t = self.schedule.num_train_timesteps
        bad = [t for t in val_timesteps if not 0 <= int(t) < num_t]
        if bad or not val_timesteps:
            raise StableMoError(f"val_timesteps: need values in [0, {num_t}), got {list(val_timesteps)}")
        if geometry_max_t is not None and (isinstance(geometry_max_t, bool) or not isinstance(geometry_max_t, int)
                                           or not 1 <= geometry_max_t <= num_t):
            raise StableMoError(f"geometry_max_t: a timestep in [1, {num_t}] or null, got {geometry_max_t!r}")
        self.ema = EMA(self.model, decay=ema_decay, warmup=ema_warmup)
        # Filled from the data module in setup() or from a checkpoint; exported into bundles.
        self.data_info: dict | None = None
        self.last_train_loss: torch.Tensor | None = None

    # ------------------------------------------------------------------ setup / checkpoints

    def setup(self, stage: str) -> None:
        datamodule = getattr(self.trainer, "datamodule", None) if self._trainer is not None else None
        if datamodule is None or getattr(datamodule, "mean", None) is None:
            if stage == "fit" and self.hparams.init_from is not None:
                raise StableMoError("model.init_from: needs a data module with feature statistics (checked "
                                    "against the bundle's)")
            return
        self.data_info = data_info_from(datamodule)
        want = self.hparams.model.get("denoiser", {}).get("input_dim")
        if want is not None and int(want) != self.data_info["feature_dim"]:
            raise StableMoError(
                f"model.denoiser.input_dim: {want} does not match the dataset's feature width "
                f"{self.data_info['feature_dim']} ({self.data_info['dataset']})"
            )
        if stage == "fit" and self.hparams.init_from is not None:
            # here, not in __init__: a checkpoint of this run loads (export, resume) without the
            # bundle, and a resumed run's checkpoint is restored after setup, over these weights
            _init_weights(self.model, self.hparams.model, self.hparams.init_from, self.data_info)
            self.ema = EMA(self.model, decay=self.hparams.ema_decay, warmup=self.hparams.ema_warmup)
        if self.geometry_weights:
            self.geometric_loss()  # checks the dataset's facts against the terms before the first step

    def configure_model(self) -> None:
        """Under `--trainer.strategy=fsdp` the network is sharded here, once the processes are up
        (stablemo.training.sharding); under any other strategy nothing happens."""
        from stablemo.training.sharding import configure_sharding

        configure_sharding(self)

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        checkpoint[CHECKPOINT_KEY] = {"ema": self.ema.state_dict(), "data": self.data_info}

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        extra = checkpoint.get(CHECKPOINT_KEY)
        if extra is None:
            raise StableMoError("checkpoint: no StableMo section (EMA weights); was it written by DiffusionModule?")
        self.ema.load_state_dict(extra["ema"])
        if extra.get("data") is not None:
            self.data_info = extra["data"]

    # ------------------------------------------------------------------ training

    def _step_generator(self, batch_idx: int) -> torch.Generator:
        seed = derive_seed("train", self.hparams.seed, self.global_step, batch_idx, self.global_rank)
        return torch.Generator().manual_seed(seed)

    def _check_length(self, x: torch.Tensor) -> None:
        multiple = getattr(self.model, "length_multiple", 1)
        if x.shape[1] % multiple:
            raise StableMoError(
                f"data.pad_multiple: batches have {x.shape[1]} frames but the denoiser needs a multiple of {multiple}"
            )

    def training_inputs(self, batch: dict, batch_idx: int):
        """The step's random draws: captions after CFG dropout, drop mask (B,), timesteps (B,), noise (B,T,D)."""
        x0 = batch["motion"]
        gen = self._step_generator(batch_idx)
        bsz = x0.shape[0]
        drop = torch.rand(bsz, generator=gen) < self.hparams.cond_drop_prob
        texts = ["" if d else caption for d, caption in zip(drop.tolist(), batch["text"])]
        t = torch.randint(0, self.schedule.num_train_timesteps, (bsz,), generator=gen).to(x0.device)
        noise = torch.randn(x0.shape, generator=gen).to(device=x0.device, dtype=x0.dtype)
        return texts, drop, t, noise

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        x0, mask = batch["motion"], batch["mask"]  # (B, T, D), (B, T)
        self._check_length(x0)
        texts, drop, t, noise = self.training_inputs(batch, batch_idx)
        # Dropout layers draw from the global RNG: give them a per-step stream too.
        devices = [x0.device] if x0.device.type == "cuda" else []
        with torch.random.fork_rng(devices=devices):
            torch.manual_seed(derive_seed("dropout", self.hparams.seed, self.global_step, batch_idx, self.global_rank))
            terms = self.loss_terms(x0, mask, texts, t, noise)
        # frame-weighted mean over the batch: every valid frame counts the same
        frames = mask.float().sum(dim=1)
        loss = self._batch_mean(self.objective(terms), frames)
        self.last_train_loss = loss.detach()
        bsz = x0.shape[0]
        self.log("train/loss", loss, prog_bar=True, batch_size=bsz)
        self.log("train/cond_dropped", drop.float().mean(), batch_size=bsz)
        if self.geometry_weights:
            self.log("train/loss_simple", self._batch_mean(terms["simple"], frames).detach(), batch_size=bsz)
            for name in self.geometry_weights:
                self.log(f"train/{GEOMETRY_TERMS[name]}", self._batch_mean(terms[name], frames).detach(), batch_size=bsz)
        return loss

    @staticmethod
    def _batch_mean(per_sample: torch.Tensor, frames: torch.Tensor) -> torch.Tensor:
        """Frame-weighted mean of per-sample values (B,) with valid frame counts (B,)."""
        return (per_sample * frames).sum() / frames.sum().clamp(min=1.0)

    def objective(self, terms: dict[str, torch.Tensor]) -> torch.Tensor:
        """The per-sample objective (B,): the simple loss plus the weighted geometric terms."""
        total = terms["simple"]
        for name, weight in self.geometry_weights.items():
            total = total + weight * terms[name]
        return total

    def loss_terms(self, x0, mask, texts, t, noise) -> dict[str, torch.Tensor]:
        """Per-sample unweighted terms {name: (B,)}: "simple", the masked MSE between the network
        output and its target, and each configured geometric term on the clean-motion estimate x̂0
        (the output itself for "sample", (x_t - sqrt(1 - abar) eps) / sqrt(abar) for "epsilon",
        sqrt(abar) x_t - sqrt(1 - abar) v for "v_prediction")."""
        x_t = self.schedule.q_sample(x0, t, noise)
        text, text_mask = self.model.encode_text(texts)
        pred = self.model(x_t, t, text, text_mask, mask)
        kind = self.hparams.prediction_type
        pred_x0 = None
        if self.geometry_weights or self.hparams.loss_on == "x0":
            pred_x0 = self.schedule.predict_x0(pred, x_t, t, kind)
        if self.hparams.loss_on == "x0":
            terms = {"simple": masked_mse(pred_x0, x0, mask)}
        else:
            terms = {"simple": masked_mse(pred, self.schedule.target(x0, noise, t, kind), mask)}
        if self.geometry_weights:
            geometric = self.geometric_loss().terms(pred_x0, x0, mask)
            if self.hparams.geometry_max_t is not None:  # where (t < max_t), not a product: an Inf stays out
                low = t < self.hparams.geometry_max_t
                geometric = {k: torch.where(low, v, torch.zeros_like(v)) for k, v in geometric.items()}
            terms.update(geometric)
        return terms

    def geometric_loss(self) -> GeometricLoss:
        """The configured geometric terms for the dataset in data_info (set in setup() or from a checkpoint)."""
        if self.data_info is None:
            raise StableMoError("model.geometry: the geometric losses need the dataset's Mean/Std and skeleton, "
                                "which come from the data module (train through `stablemo fit` or a Trainer with one)")
        info = self.data_info
        if self._geometric_loss is None or self._geometric_loss[0] is not info:
            self._geometric_loss = (info, GeometricLoss(self.geometry_weights, info["skeleton"], info["mean"], info["std"]))
        return self._geometric_loss[1]

    def optimizer_step(self, *args, **kwargs) -> None:
        super().optimizer_step(*args, **kwargs)
        # Here rather than in on_train_batch_end: ModelCheckpoint saves in its own
        # on_train_batch_end, which runs before the module's, and must see this step's average.
        self.ema.update(self.model)

    def on_train_start(self) -> None:
        """A resumed run trains at the learning rate (and decay, weight decay) it was given, not the
        checkpoint's: Lightning restores the optimiser and scheduler states after configure_optimizers,
        which would keep the old run's values while the hyper-parameters record the new ones (and
        the divergence error's advice, "resume with a lower --model.lr", would do nothing)."""
        hp = self.hparams
        optimizer = self.trainer.optimizers[0]
        scheduler = self.trainer.lr_scheduler_configs[0].scheduler if self.trainer.lr_scheduler_configs else None
        follow_configured_lrs(optimizer, scheduler, [float(hp.lr)] * len(optimizer.param_groups))
        for group in optimizer.param_groups:
            group["weight_decay"] = hp.weight_decay
        if isinstance(scheduler, torch.optim.lr_scheduler.StepLR):
            scheduler.step_size, scheduler.gamma = hp.lr_step, hp.lr_gamma

    def configure_optimizers(self):
        params = [p for p in self.model.parameters() if p.requires_grad]
        # the fused kernel: one pass over the weights instead of ~7 (5x faster on the CPU for the paper
        # UNet); not with fp16 loss scaling, where the optimiser would unscale gradients Lightning clips
        precision = str(self.trainer.precision) if self._trainer is not None else ""
        fused = self.hparams.get("fast_training", True) and precision not in ("16-mixed", "16")
        optimizer = torch.optim.AdamW(params, lr=self.hparams.lr, weight_decay=self.hparams.weight_decay,
                                      **({"fused": True} if fused else {}))
        if fused and precision in ("bf16-mixed", "bf16"):
            # bf16 has no loss scaler, so nothing is unscaled in the step; the flag only tells a
            # GradScaler (absent here) that the fused step could unscale, and makes Lightning refuse
            # to clip this optimiser's gradients
            optimizer._step_supports_amp_scaling = False
        scheduler = torch.optim.lr_scheduler.StepLR(optimizer, step_size=self.hparams.lr_step, gamma=self.hparams.lr_gamma)
        return {"optimizer": optimizer, "lr_scheduler": {"scheduler": scheduler, "interval": "step", "frequency": 1}}

    # ------------------------------------------------------------------ evaluation

    @torch.no_grad()
    def fixed_noise_losses(self, batch: dict) -> torch.Tensor:
        """Per-sample, per-timestep loss with noise fixed by clip id. -> (B, K) for K val_timesteps.

        Deterministic and independent of batch composition, padding, order and world size.
        """
        return self.fixed_noise_errors(batch)[0]

    @torch.no_grad()
    def fixed_noise_errors(self, batch: dict) -> tuple[torch.Tensor, torch.Tensor]:
        """(loss on the parameterisation's target, MSE of the clean-motion estimate x̂0), each
        (B, K): the second compares runs trained with different prediction types."""
        x0, mask = batch["motion"], batch["mask"]
        self._check_length(x0)
        bsz, frames, dim = x0.shape
        text, text_mask = self.model.encode_text(list(batch["text"]))
        columns, x0_columns = [], []
        kind = self.hparams.prediction_type
        for step in self.hparams.val_timesteps:
            noise = torch.stack([
                torch.randn(max(frames, VAL_NOISE_FRAMES), dim, generator=torch.Generator().manual_seed(
                    derive_seed("val", zlib.crc32(str(clip).encode()), step)))[:frames]
                for clip in batch["id"]
            ]).to(device=x0.device, dtype=x0.dtype)
            t = torch.full((bsz,), int(step), device=x0.device, dtype=torch.long)
            x_t = self.schedule.q_sample(x0, t, noise)
            pred = self.model(x_t, t, text, text_mask, mask)
            columns.append(masked_mse(pred, self.schedule.target(x0, noise, t, kind), mask))
            x0_columns.append(masked_mse(self.schedule.predict_x0(pred, x_t, t, kind), x0, mask))
        return torch.stack(columns, dim=1), torch.stack(x0_columns, dim=1)

    def _evaluate(self, batch: dict, split: str) -> torch.Tensor:
        with self.ema.swapped_into(self.model):
            losses, x0_errors = self.fixed_noise_errors(batch)  # (B, K) each
        bsz = losses.shape[0]
        for step, column in zip(self.hparams.val_timesteps, losses.unbind(1)):
            self.log(f"{split}/loss_t{int(step)}", column.mean(), sync_dist=True, batch_size=bsz)
        if self.hparams.prediction_type != "sample":  # for "sample" it is val/loss itself
            self.log(f"{split}/loss_x0", x0_errors.mean(), sync_dist=True, batch_size=bsz)
        loss = losses.mean()
        self.log(f"{split}/loss", loss, prog_bar=True, sync_dist=True, batch_size=bsz)
        return loss

    def validation_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        return self._evaluate(batch, "val")

    def test_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        return self._evaluate(batch, "test")


def follow_configured_lrs(optimizer, scheduler, base_lrs: list[float]) -> None:
    """Make `base_lrs` (one per param group, as configure_optimizers sets them) the optimiser's
    base learning rates after a resume restored another run's: each group's current lr is scaled
    by new / old base, so a decayed (or warming-up) schedule continues from the same point of its
    curve at the new level. Nothing is touched when they are unchanged (an exact resume stays
    bit-identical)."""
    groups = optimizer.param_groups
    old = list(scheduler.base_lrs) if scheduler is not None else [g.get("initial_lr", g["lr"]) for g in groups]
    if [float(v) for v in old] == [float(v) for v in base_lrs]:
        return
    for group, before, after in zip(groups, old, base_lrs):
        group["lr"] = group["lr"] * (after / before) if before else after
        if "initial_lr" in group:
            group["initial_lr"] = after
    if scheduler is not None:
        scheduler.base_lrs = list(base_lrs)
        scheduler._last_lr = [group["lr"] for group in groups]  # what get_last_lr() and the LR monitor report


def _init_weights(model: torch.nn.Module, config: dict, bundle_path: str, data_info: dict) -> None:
    """Load a diffusion bundle's weights into `model` (built from `config`), after checking that the
    bundle holds this network and that the dataset (`data_info`) normalises its features with the
    statistics the bundle's network was trained with."""
    from stablemo.inference.bundle import load_bundle

    where = f"model.init_from: {bundle_path}"
    try:
        bundle = load_bundle(bundle_path)
    except StableMoError as err:
        raise StableMoError(f"model.init_from: {err}") from None
    if bundle.config.get("kind", "diffusion") != "diffusion":
        raise StableMoError(f"{where}: not a diffusion bundle (kind {bundle.config.get('kind')!r})")
    new = grown_attention(bundle.config.get("model"), config)
    if new is None:
        raise StableMoError(f"{where}: its network config differs from this run's model config "
                            "(train further only the network the bundle holds, or that network with "
                            "temporal self-attention added: mid_attention, up_attention)")
    for key in ("mean", "std"):
        if not same_statistics(bundle.config.get(key), data_info.get(key)):
            raise StableMoError(f"{where}: the dataset's feature {key} differs from the bundle's; normalise with the "
                                f"statistics the bundle was trained with (--data.stats_dir: the folder it was trained on)")
    missing, unexpected = model.load_state_dict(bundle.state_dict, strict=False)
    missing = [k for k in missing if not k.startswith(new)]  # the grown blocks keep their identity start
    if missing or unexpected:
        raise StableMoError(f"{where}: weights do not fit the network ({len(missing)} missing, "
                            f"{len(unexpected)} unexpected, e.g. {(missing + unexpected)[0]!r})")


def grown_attention(before: dict | None, after: dict) -> tuple[str, ...] | None:
    """The state-dict prefixes of the temporal self-attention blocks that network config `after` adds
    to `before` (() when the two are equal), or None when they differ in anything else.

    TemporalSelfAttention1D's output projection starts at zero, so a block added to a trained
    network leaves its function unchanged until training moves it: a shipped network can grow one
    and train on, as a new layer of a residual network starts as the identity."""
    if before == after:
        return ()
    if not isinstance(before, dict) or set(before) != set(after):
        return None
    old, new = before.get("denoiser"), after.get("denoiser")
    if any(before[k] != after[k] for k in before if k != "denoiser") or not isinstance(old, dict) \
            or not isinstance(new, dict) or new.get("name") != "unet" or old.get("name") != "unet":
        return None
    keys = ("mid_attention", "up_attention")
    if {k: v for k, v in old.items() if k not in keys} != {k: v for k, v in new.items() if k not in keys}:
        return None
    prefixes = []
    mid_old, mid_new = old.get("mid_attention", 0), new.get("mid_attention", 0)
    if mid_old != mid_new:
        if mid_old:
            return None
        prefixes.append("denoiser.mid.self_attn.")
    up_old, up_new = list(old.get("up_attention", [])), list(new.get("up_attention", []))
    for k in range(max(len(up_old), len(up_new))):
        a = up_old[k] if k < len(up_old) else 0
        b = up_new[k] if k < len(up_new) else 0
        if a != b:
            if a:
                return None
            prefixes.append(f"denoiser.up.{k}.self_attn.")
    return tuple(prefixes)


def data_info_from(datamodule) -> dict:
    """The dataset facts a bundle needs (plain JSON types), read from a set-up MotionDataModule."""
    skeleton = datamodule.skeleton
    dataset = getattr(datamodule, "dataset", None)
    if not isinstance(dataset, str):
        dataset = datamodule.hparams.get("dataset", getattr(skeleton, "name", "humanml3d"))
    mean = [float(v) for v in datamodule.mean]
    std = [float(v) for v in datamodule.std]
    return {
        "dataset": dataset,
        "skeleton": getattr(skeleton, "name", dataset),
        "fps": float(skeleton.fps),
        "feature_dim": int(datamodule.feature_dim),
        "mean": mean,
        "std": std,
        "min_length": int(getattr(datamodule, "min_length", MIN_LENGTH.get(dataset, 1))),
        "max_length": int(getattr(datamodule, "max_length", datamodule.hparams.get("max_length", MAX_FRAMES))),
        **({"body": {"bone_lengths": [float(v) for v in datamodule.body]}} if hasattr(datamodule, "body") else {}),
    }
