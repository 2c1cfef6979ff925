"""ConsistencyDistillation: LCM-style or phased (PCM) distillation of a trained bundle, as a LightningModule.

One training step (LCM / MotionLCM Sec. 3.2, PCM / MotionPCM; docs/distillation.md), per sample
of a batch of clean clips x0 (B, T, D):
1. draw a grid index i: t_hi = tau_i, t_lo = max(tau_i - k, 0); noise x0 to t_hi; draw w ~ U[w_min, w_max];
2. teacher (frozen, eval): CFG-augmented x0 at (x_hi, t_hi), then the DDIM step to t_lo (ratio form);
3. target network (EMA of the student, eval, no grad) gives the consistency target at (x_lo, t_lo);
   for PCM the target is the state at the lower edge of t_hi's phase (x_lo itself when t_lo is that edge);
4. student: consistency function at (x_hi, t_hi); pseudo-Huber loss over valid frames;
5. optional (PCM): hinge adversarial loss with a discriminator on the frozen teacher's features;
   real = data noised to t' in [s_m, s_m + T/M), fake = the student's edge state moved to t'.
6. optional: a bone-length term on the student's clean estimate (stablemo.training.geometry): its
   bones against the data clip's, which a body keeps whatever motion the noise leads to.
The target follows the student by EMA (mu) after every optimiser step.
"""

from __future__ import annotations

import copy
from typing import Any

import torch
from lightning.pytorch import LightningModule

from stablemo.data.stats import same_statistics
from stablemo.diffusion.schedule import NoiseSchedule
from stablemo.distill.consistency import (
    CLEAN,
    cfg_x0,
    ddim_grid,
    ddim_jump,
    lower_edge,
    masked_pseudo_huber,
    phase_edges,
)
from stablemo.distill.discriminator import (
    TeacherFeatureDiscriminator,
    hinge_d_loss,
    hinge_g_loss,
)
from stablemo.distill.student import MODES, ConsistencyStudent, consistency_fn
from stablemo.errors import StableMoError
from stablemo.inference.bundle import load_bundle, skeleton_name, weights_sha256
from stablemo.inference.config import InferenceConfig, student_inference
from stablemo.nets.model import MotionDiffusionModel
from stablemo.training.geometry import GeometricLoss, geometry_weights
from stablemo.training.module import CHECKPOINT_KEY, derive_seed


def _frozen(module: torch.nn.Module) -> torch.nn.Module:
    module.eval()
    module.requires_grad_(False)
    return module


class ConsistencyDistillation(LightningModule):
    """Args:
        teacher: path of the teacher's inference bundle (stablemo export).
        mode: "lcm" or "pcm".
        ddim_steps: N, the DDIM grid (skip k = T / N).
        phases: M, PCM phases (ignored for LCM).
        w_min, w_max: guidance range drawn per sample (LCM convention: CFG scale = 1 + w).
        w_default: the guidance the exported student samples with.
        huber_c: pseudo-Huber constant (features are z-normalised).
        ema_decay: mu of the target network.
        lr, weight_decay, warmup_steps: AdamW with linear warm-up then constant.
        w_lr_scale: learning-rate multiplier for the zero-initialised guidance embedding (w_proj).
        adversarial: add the PCM adversarial loss (weight adv_weight; discriminator lr disc_lr).
        sample_steps: default inference steps recorded in the exported bundle.
        geometry: {bone_lengths: weight (m²), rotations: weight} (stablemo.training.geometry) on the
            student's x0 estimate: a body keeps its bones, and its rotation columns agree with its
            joints, whatever motion the noise leads to; the other geometric terms compare with the
            data clip's joints and contacts, which the teacher's trajectory from noise does not
            reproduce, so they are refused.
        seed: seeds every random draw from (seed, step, rank).
    """

    def __init__(
        self,
        teacher: str,
        mode: str = "lcm",
        ddim_steps: int = 50,
        phases: int = 4,
        w_min: float = 0.5,
        w_max: float = 2.5,
        w_default: float = 1.5,
        huber_c: float = 0.03,
        ema_decay: float = 0.95,
        lr: float = 1e-4,
        w_lr_scale: float = 1.0,
        weight_decay: float = 0.0,
        warmup_steps: int = 100,
        adversarial: bool = False,
        adv_weight: float = 0.1,
        disc_lr: float = 1e-4,
        disc_layers: list[str] | None = None,
        sigma_data: float = 0.5,
        timestep_scale: float = 10.0,
        w_dim: int = 256,
        sample_steps: int = 1,
        geometry: dict[str, float] | None = None,
        seed: int = 0,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        if mode not in MODES:
            raise StableMoError(f"mode: expected one of {MODES}, got {mode!r}")
        if not 0 <= w_min <= w_max:
            raise StableMoError(f"w_min/w_max: need 0 <= w_min <= w_max, got {w_min}, {w_max}")
        if adversarial and mode != "pcm":
            raise StableMoError("adversarial: the adversarial loss is defined for mode 'pcm'")
        self.geometry_weights = geometry_weights(geometry)
        if set(self.geometry_weights) - {"bone_lengths", "rotations"}:
            raise StableMoError(f"model.geometry: distillation takes only bone_lengths and rotations, got "
                                f"{', '.join(sorted(self.geometry_weights))} (the other terms compare with the data "
                                "clip, not with the teacher's motion from the same noise)")
        bundle = load_bundle(teacher)
        if bundle.config.get("kind", "diffusion") != "diffusion":
            raise StableMoError(f"{teacher}: the teacher must be a diffusion bundle, got kind {bundle.config.get('kind')!r}")
        self.teacher_config = bundle.config
        self.teacher_sha256 = weights_sha256(teacher)
        self.geometric_loss = GeometricLoss(self.geometry_weights, skeleton_name(bundle.config),
                                            bundle.config["mean"], bundle.config["std"]) if self.geometry_weights else None
        self.prediction_type = bundle.config.get("prediction_type", "sample")
        self.schedule = NoiseSchedule(**bundle.config["schedule"])
        self.grid = ddim_grid(self.schedule.num_train_timesteps, ddim_steps)
        self.skip = self.schedule.num_train_timesteps // ddim_steps
        self.edges = phase_edges(self.schedule.num_train_timesteps, ddim_steps, phases) if mode == "pcm" else None

        teacher_net = MotionDiffusionModel(**bundle.config["model"])
        teacher_net.load_state_dict(bundle.state_dict)
        # teacher and target are not trained by the optimiser: kept out of parameters() but
        # registered so they move with the module
        self.teacher = _frozen(teacher_net)
        self.student = ConsistencyStudent(bundle.config["model"], w_dim=w_dim)
        self.student.model.load_state_dict(bundle.state_dict)
        self.target = _frozen(copy.deepcopy(self.student))
        self.discriminator = TeacherFeatureDiscriminator(self.teacher, disc_layers) if adversarial else None
        self.automatic_optimization = False

    # ------------------------------------------------------------------ setup

    def setup(self, stage: str) -> None:
        dm = getattr(self.trainer, "datamodule", None) if self._trainer is not None else None
        if dm is not None and getattr(dm, "mean", None) is not None:
            for name in ("mean", "std"):
                if not same_statistics(self.teacher_config[name], torch.as_tensor(getattr(dm, name)).float()):
                    raise StableMoError(f"data: the dataset's {name} differs from the teacher's; distil on the teacher's dataset")
        if self.discriminator is not None and not len(self.discriminator.heads):
            T = 4 * self.teacher.length_multiple
            text, text_mask = self.teacher.encode_text(["a person walks"])
            x = torch.zeros(1, T, self.teacher_config_dim)
            self.discriminator.build(x, torch.zeros(1, dtype=torch.long), text, text_mask,
                                     torch.ones(1, T, dtype=torch.bool))

    @property
    def teacher_config_dim(self) -> int:
        return int(self.teacher_config["model"]["denoiser"]["input_dim"])

    def on_train_start(self) -> None:
        """A resumed run trains at the learning rates it was given, not the checkpoint's (Lightning
        restores the optimisers' states after configure_optimizers); unchanged ones are untouched."""
        from stablemo.training.module import follow_configured_lrs

        hp = self.hparams
        optimizers = self.trainer.optimizers
        follow_configured_lrs(optimizers[0], self.trainer.lr_scheduler_configs[0].scheduler,
                              [float(hp.lr), float(hp.lr * hp.w_lr_scale)])
        if len(optimizers) > 1:  # the discriminator's, without a scheduler
            follow_configured_lrs(optimizers[1], None, [float(hp.disc_lr)] * len(optimizers[1].param_groups))

    def configure_optimizers(self):
        hp = self.hparams
        # the guidance embedding starts at zero and is the only new layer: it may learn faster
        w_params = [p for p in self.student.w_proj.parameters() if p.requires_grad]
        ids = {id(p) for p in w_params}
        rest = [p for p in self.student.parameters() if p.requires_grad and id(p) not in ids]
        opt = torch.optim.AdamW([{"params": rest}, {"params": w_params, "lr": hp.lr * hp.w_lr_scale}],
                                lr=hp.lr, weight_decay=hp.weight_decay)
        warm = max(int(hp.warmup_steps), 1)
        sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda step: min(1.0, (step + 1) / warm))
        if self.discriminator is None:
            return [opt], [sched]
        opt_d = torch.optim.AdamW(self.discriminator.parameters(), lr=hp.disc_lr, betas=(0.0, 0.99))
        return [opt, opt_d], [sched]

    # ------------------------------------------------------------------ pieces

    def _x0(self, network, x, t, *conditions) -> torch.Tensor:
        """x0 estimate of a teacher (text, masks) or student (w, text, masks) network at (x, t)."""
        out = network(x, t, *conditions)
        return self.schedule.predict_x0(out, x, t, self.prediction_type)

    def _f(self, x_t, x0, t) -> torch.Tensor:
        hp = self.hparams
        return consistency_fn(hp.mode, self.schedule, self.edges, x_t, x0, t, hp.sigma_data, hp.timestep_scale)

    def distillation_loss(self, batch: dict, generator: torch.Generator) -> dict[str, torch.Tensor]:
        """The consistency loss of one batch (and what the adversarial part needs)."""
        hp = self.hparams
        x0, mask, texts = batch["motion"], batch["mask"], list(batch["text"])
        B, device = x0.shape[0], x0.device
        idx = torch.randint(0, len(self.grid), (B,), generator=generator)
        t_hi = torch.tensor(self.grid, dtype=torch.long)[idx].to(device)
        t_lo = (t_hi - self.skip).clamp(min=0)
        noise = torch.randn(x0.shape, generator=generator).to(device, x0.dtype)
        w = (hp.w_min + (hp.w_max - hp.w_min) * torch.rand(B, generator=generator)).to(device)
        x_hi = self.schedule.q_sample(x0, t_hi, noise)

        with torch.no_grad():
            # conditional and unconditional (the teacher's own null caption "") in one forward
            text_cu, mask_cu = self.teacher.encode_text(texts + [""] * B)
            both = self._x0(self.teacher, torch.cat([x_hi, x_hi]), torch.cat([t_hi, t_hi]),
                            text_cu, mask_cu, torch.cat([mask, mask]))
            x0_cond, x0_uncond = both.chunk(2)
            x_lo = ddim_jump(self.schedule, x_hi, cfg_x0(x0_cond, x0_uncond, w), t_hi, t_lo)

            text_t, mask_t = self.target.encode_text(texts)
            x0_target = self._x0(self.target, x_lo, t_lo, w, text_t, mask_t, mask)
            if hp.mode == "lcm":
                target = self._f(x_lo, x0_target, t_lo)
            else:
                edge = lower_edge(t_hi, self.edges)
                jumped = ddim_jump(self.schedule, x_lo, x0_target, t_lo, edge)
                target = torch.where((t_lo == edge)[:, None, None], x_lo, jumped)

        text_s, mask_s = self.student.encode_text(texts)
        x0_student = self._x0(self.student, x_hi, t_hi, w, text_s, mask_s, mask)
        pred = self._f(x_hi, x0_student, t_hi)
        consistency = masked_pseudo_huber(pred, target, mask, hp.huber_c)
        out = {"loss": consistency, "consistency": consistency, "pred": pred, "t_hi": t_hi,
               "x0": x0, "mask": mask, "text": (text_cu[:B], mask_cu[:B])}
        if self.geometric_loss is not None:
            out["bone_lengths"] = self.geometric_loss.terms(x0_student, x0, mask)["bone_lengths"].mean()
            out["loss"] = consistency + self.geometry_weights["bone_lengths"] * out["bone_lengths"]
        return out

    def _adversarial_pair(self, out: dict, generator: torch.Generator):
        """(fake, real, t') at a random level t' in [s_m, s_m + T/M) above each sample's edge."""
        edge = lower_edge(out["t_hi"], self.edges)
        width = self.schedule.num_train_timesteps // self.hparams.phases
        base = edge.clamp(min=0)
        t_prime = (base + (torch.rand(base.shape, generator=generator).to(base.device) * width).long()).clamp(
            max=self.schedule.num_train_timesteps - 1)
        abar = self.schedule.alphas_cumprod.to(base.device)
        abar_s = torch.where(edge == CLEAN, torch.ones_like(abar[base]), abar[base])
        ratio = (abar[t_prime] / abar_s).clamp(max=1.0)[:, None, None]
        eps = torch.randn(out["pred"].shape, generator=generator).to(out["pred"])
        fake = ratio.sqrt() * out["pred"] + (1 - ratio).sqrt() * eps
        eps_real = torch.randn(out["pred"].shape, generator=generator).to(out["pred"])
        real = self.schedule.q_sample(out["x0"], t_prime, eps_real)
        return fake, real, t_prime

    # ------------------------------------------------------------------ loop

    def training_step(self, batch: dict, batch_idx: int):
        hp = self.hparams
        generator = torch.Generator().manual_seed(derive_seed("distill", hp.seed, self.global_step, batch_idx, self.global_rank))
        optimizers = self.optimizers()
        opt = optimizers[0] if isinstance(optimizers, (list, tuple)) else optimizers
        out = self.distillation_loss(batch, generator)
        loss = out["loss"]
        self.log("train/consistency", out["consistency"], prog_bar=True, batch_size=len(batch["text"]))
        if "bone_lengths" in out:
            self.log("train/loss_bone", out["bone_lengths"], batch_size=len(batch["text"]))

        if self.discriminator is not None:
            fake, real, t_prime = self._adversarial_pair(out, generator)
            text, text_mask = out["text"]
            g_loss = hinge_g_loss(self.discriminator(fake, t_prime, text, text_mask, out["mask"]))
            loss = loss + hp.adv_weight * g_loss
            self.log("train/adv_g", g_loss, batch_size=len(batch["text"]))

        if not torch.isfinite(loss):
            raise StableMoError(f"distillation loss became {loss.item()} at step {self.global_step}; "
                                "lower the learning rate or the w range")
        opt.zero_grad(set_to_none=True)
        self.manual_backward(loss)
        self.clip_gradients(opt, gradient_clip_val=1.0, gradient_clip_algorithm="norm")
        opt.step()
        self.lr_schedulers().step()

        if self.discriminator is not None:
            opt_d = optimizers[1]
            d_loss = hinge_d_loss(self.discriminator(real, t_prime, text, text_mask, out["mask"]),
                                  self.discriminator(fake.detach(), t_prime, text, text_mask, out["mask"]))
            opt_d.zero_grad(set_to_none=True)
            self.manual_backward(d_loss)
            opt_d.step()
            self.log("train/adv_d", d_loss, batch_size=len(batch["text"]))

        self._update_target()
        return loss.detach()

    @torch.no_grad()
    def _update_target(self) -> None:
        mu = self.hparams.ema_decay
        for (name, p_t), p_s in zip(self.target.state_dict().items(), self.student.state_dict().values()):
            if p_t.is_floating_point():
                p_t.mul_(mu).add_(p_s.detach(), alpha=1 - mu)
            else:
                p_t.copy_(p_s)

    def validation_step(self, batch: dict, batch_idx: int):
        generator = torch.Generator().manual_seed(derive_seed("distill-val", self.hparams.seed, batch_idx))
        out = self.distillation_loss(batch, generator)
        self.log("val/consistency", out["consistency"], prog_bar=True, batch_size=len(batch["text"]),
                 sync_dist=True)
        if "bone_lengths" in out:
            self.log("val/loss_bone", out["bone_lengths"], batch_size=len(batch["text"]), sync_dist=True)
        return out["loss"]

    # ------------------------------------------------------------------ export

    def bundle(self) -> tuple[dict, dict[str, torch.Tensor]]:
        """(bundle config, weights) of the student, from the EMA target network."""
        hp = self.hparams
        config = {k: v for k, v in self.teacher_config.items()
                  if k not in ("format", "version", "training", "inference")}
        teacher_inference = InferenceConfig.from_bundle(self.teacher_config).to_dict()
        config["kind"] = "consistency"
        config["consistency"] = {
            "mode": hp.mode, "ddim_steps": hp.ddim_steps, "phases": hp.phases if hp.mode == "pcm" else None,
            "edges": self.edges, "w": hp.w_default, "w_dim": hp.w_dim, "sigma_data": hp.sigma_data,
            "timestep_scale": hp.timestep_scale, "steps": hp.sample_steps,
        }
        config["inference"] = student_inference({**config, "inference": teacher_inference}).to_dict()
        config["training"] = {"teacher": str(hp.teacher), "teacher_weights_sha256": self.teacher_sha256,
                              "global_step": int(self.global_step),
                              "ema_decay": hp.ema_decay, "adversarial": hp.adversarial}
        return config, {k: v.detach().clone() for k, v in self.target.state_dict().items()}

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        config, _ = self.bundle()
        # export reads the student (target) weights from the state dict under this prefix
        checkpoint[CHECKPOINT_KEY] = {"bundle": config, "weights_prefix": "target."}
