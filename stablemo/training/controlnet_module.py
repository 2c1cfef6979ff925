"""ControlNetTraining: a motion ControlNet trained on a frozen bundle (teacher or consistency student).

One step, per batch of clean clips x0 (B, T, D) (MotionLCM, Dai et al. ECCV 2024, Sec. 3.3, Eq. 9):
1. hints: per sample one joint of TRAIN_JOINTS and a random set of frames (hints.sample_hint_mask),
   the targets being the clip's own global joint positions;
2. noise x0 to t (uniform over the schedule, or drawn from `train_timesteps`: a 1-step student
   only ever sees t = 999 at inference);
3. the controlled model's x0 estimate (a student's through its consistency function);
4. loss = masked MSE(x0_hat, x0) + lambda * sum m |R(x0_hat) - R(x0)|^2 / sum m, R = global joint
   positions (differentiable recovery), m = the hint mask; optionally (velocity_weight > 0, ours,
   not MotionLCM's) + mu * the same masked squared error of the hinted joints' per-frame velocities
   (m/s) where two neighbouring frames are hints: a global position is the sum of every earlier
   step, so its error's gradient couples all frames, while a step's error is local; and
   (root_weight > 0, ours) + nu * the squared error of the 4 root feature channels (normalised) on
   the frames whose pelvis is a hint, the local quantities a dense pelvis path all but determines;
   and (skate_weight > 0, ours) + kappa * the squared horizontal speed (m/s) of the foot joint that
   carries the body: per frame pair, the four foot joints weighted by a softmin of their heights
   (SKATE_SOFTMIN_M) and by how near the floor the lowest one is (SKATE_FLOOR_M), both detached so
   that lifting a foot never pays. A body pulled along a path whose legs do not carry it slides the
   foot it stands on, which the finishing step can hold only within its anchors' reach. The
   estimate's own feet rather than the clip's contact labels: from t = 999 the estimate's gait need
   not be in the clip's phase; nor the estimate's contact channels, which the demo student's
   ControlNet output holds flat along paths (tried first). Fine-tuning the shipped ControlNet with
   either made its stance feet slide more (docs/control.md): not in the shipped recipe.
With recon_target "base" (ours; pelvis hints only) the reconstruction's goal is not the clip but the
frozen base's own estimate from the same x_t and text, and the hint is the clip's pelvis path
smoothed over a gait cycle, scaled to that estimate's length and walked at its pace
(pace.path_on_reference), at its pelvis heights. From t = 999 the clip's gait phase is not in x_t,
so an MSE to the clip teaches the conditional mean: legs blurred across phases, contact channels
flat, the stance foot sliding. The base's estimate is one sharp motion, so the ControlNet learns to
keep that body and move it along the path: every channel but the root's rotation velocity (the
turning the path needs) is the base's, the body-frame velocity included, so the body faces where it
walks as the text walked it (forward, backward, sideways), and the pace the path is timed at is its
legs' own, as the page times a drawn path by the motion on screen. A root-only ControlNet
(control.root_only) is held on the root channels it sets. Tried on 2026-12-06 as a fine-tune of the
full ControlNet shipped then, and as the root-only form; the root-only form with steps on the floor
(control.floor_steps), trained this way and then against the clips, is shipped since 2026-12-07
(docs/control.md).
Only the ControlNet trains; the base stays frozen and in eval mode. Its EMA is what export writes.
Randomness comes from (seed, step, batch, rank), so a resumed run repeats the uninterrupted one.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import torch
from lightning.pytorch import LightningModule

from stablemo.checks import check_weight
from stablemo.control.controlnet import ROOT_CHANNELS, ControlledModel
from stablemo.control.hints import (
    PATH_SCALE,
    TRAIN_JOINTS,
    hint_input,
    sample_hint_mask,
)
from stablemo.control.pace import path_on_reference
from stablemo.data.stats import same_statistics
from stablemo.diffusion.schedule import NoiseSchedule
from stablemo.errors import StableMoError
from stablemo.inference.bundle import load_bundle, skeleton_name, weights_sha256
from stablemo.inference.config import InferenceConfig
from stablemo.inference.kinds import model_kind
from stablemo.motion import features_to_joints
from stablemo.motion.skeleton import get_skeleton
from stablemo.training.ema import EMA
from stablemo.training.geometry import METRES_PER_UNIT
from stablemo.training.module import CHECKPOINT_KEY, derive_seed, masked_mse

# the skate term's weights (metres): the foot joint within ~1 cm of the lowest carries the body, and
# a lowest foot joint more than ~5 cm above the floor (the stance measure's margin) carries nothing
SKATE_SOFTMIN_M = 0.01
SKATE_FLOOR_M = 0.05
RECON_TARGETS = ("clip", "base")
# recon_target "base": a clip's pelvis path is smoothed over about a gait cycle (s) before it is
# walked at the base's pace, as a drawn path has no sway of its own
GAIT_CYCLE_S = 1.0


class ControlNetTraining(LightningModule):
    """Args:
        base: inference bundle to control (kind "diffusion" or "consistency"), frozen.
        control: ControlNet kwargs (hint encoder channels, layers, path: the hint's path channels; for a
            DiT/RetNet also blocks, the copied count).
        hint_joints: joints a training hint is drawn from (HumanML3D indices).
        hint_scale: target positions are divided by this in the hint (dataset units).
        dense_prob, empty_prob: share of dense hints and of samples without a hint.
        joint_weight: lambda of the joint-position loss (MotionLCM: 1).
        velocity_weight: mu of the hinted joints' velocity loss (0: MotionLCM's loss alone).
        root_weight: nu of the root-channel loss on pelvis-hinted frames (0: MotionLCM's loss alone).
        skate_weight: kappa of the standing foot's speed loss (0: MotionLCM's loss alone).
        init: a ControlNet bundle on this same base whose ControlNet weights start the run (a
            fine-tune; None: MotionLCM's zero-initialised injections).
        recon_target: "clip" (MotionLCM: the clip's features and joints) or "base" (the frozen base's
            own estimate, the clip's path walked at its pace; see above; pelvis-only hint_joints).
        train_timesteps: timesteps drawn from (None: uniform over the schedule).
        cond_drop_prob: captions replaced by "" (a diffusion base samples with CFG).
        ema_decay, ema_warmup: EMA of the ControlNet's weights (exported).
        lr, weight_decay: AdamW on the ControlNet.
        lr_step, lr_gamma: the learning rate is multiplied by lr_gamma every lr_step optimiser steps
            (None: a constant lr, which a resumed run may change).
        sample_steps, sample_cfg: the exported bundle's default steps and guidance (None: the base's).
        seed: seeds every draw.
    """

    def __init__(
        self,
        base: str,
        control: dict[str, Any] | None = None,
        hint_joints: Sequence[int] = TRAIN_JOINTS,
        hint_scale: float = 1.0,
        dense_prob: float = 0.25,
        empty_prob: float = 0.0,
        joint_weight: float = 1.0,
        velocity_weight: float = 0.0,
        root_weight: float = 0.0,
        skate_weight: float = 0.0,
        init: str | None = None,
        recon_target: str = "clip",
        train_timesteps: Sequence[int] | None = None,
        cond_drop_prob: float = 0.0,
        ema_decay: float = 0.999,
        ema_warmup: float = 10.0,
        lr: float = 1e-4,
        weight_decay: float = 0.0,
        lr_step: int | None = None,
        lr_gamma: float = 0.1,
        sample_steps: int | None = None,
        sample_cfg: float | None = None,
        seed: int = 0,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        bundle = load_bundle(base)
        config = bundle.config
        self.base_kind = config.get("kind", "diffusion")
        if self.base_kind not in ("diffusion", "consistency"):
            raise StableMoError(f"base: {base} is a {self.base_kind!r} bundle; a ControlNet controls a "
                                "'diffusion' or 'consistency' bundle")
        if hint_scale <= 0 or not dense_prob + empty_prob <= 1 or min(dense_prob, empty_prob) < 0:
            raise StableMoError("hint_scale > 0 and dense_prob, empty_prob >= 0 with a sum <= 1 are required")
        if lr_step is not None and (lr_step < 1 or not 0 < lr_gamma <= 1):
            raise StableMoError(f"lr_step >= 1 and 0 < lr_gamma <= 1 are required, got {lr_step}, {lr_gamma}")
        for name, value in (("joint_weight", joint_weight), ("velocity_weight", velocity_weight),
                            ("root_weight", root_weight), ("skate_weight", skate_weight)):
            check_weight(name, value)
        if recon_target not in RECON_TARGETS:
            raise StableMoError(f"recon_target: expected one of {RECON_TARGETS}, got {recon_target!r}")
        if recon_target == "base" and [int(j) for j in hint_joints] != [0]:
            raise StableMoError(f"recon_target: 'base' re-times the pelvis path only; give hint_joints [0], got {list(hint_joints)}")
        self.base_config = config
        self.base_sha256 = weights_sha256(base)
        self.skeleton = get_skeleton(skeleton_name(config))
        bad = [j for j in hint_joints if not 0 <= int(j) < self.skeleton.num_joints]
        if bad or not hint_joints:
            raise StableMoError(f"hint_joints: need joint indices in [0, {self.skeleton.num_joints}), got {list(hint_joints)}")
        self.schedule = NoiseSchedule(**config.get("schedule", {}))
        self.prediction_type = config.get("prediction_type", "sample")
        num_t = self.schedule.num_train_timesteps
        if train_timesteps is not None and (not train_timesteps or any(not 0 <= int(t) < num_t for t in train_timesteps)):
            raise StableMoError(f"train_timesteps: need values in [0, {num_t}), got {list(train_timesteps)}")
        if control and control.get("root_only") and control.get("heading_scale") is None:
            # the root-only form's facing turns in the base's normalised rotation-velocity units
            control = {**control, "heading_scale": 1.0 / float(config["std"][0])}
            self.hparams.control = control  # exported as trained
        if control and control.get("floor_steps") is True:
            # its steps on the floor are turned into the body's frame with the base's statistics
            stats = {"mean": [float(v) for v in config["mean"][:3]], "std": [float(v) for v in config["std"][:3]]}
            control = {**control, "floor_steps": stats}
            self.hparams.control = control
        base_model = model_kind(self.base_kind, base).build_model(config, base)
        base_model.load_state_dict(bundle.state_dict)
        self.model = ControlledModel(base_model.eval().requires_grad_(False), self.base_kind,
                                     self.skeleton.num_joints, control)
        if init is not None:
            self._start_from(init, control)
        self.ema = EMA(self.model.control, decay=ema_decay, warmup=ema_warmup)
        self.register_buffer("mean", torch.tensor(config["mean"], dtype=torch.float32), persistent=False)
        self.register_buffer("std", torch.tensor(config["std"], dtype=torch.float32), persistent=False)
        # a student's guidance w, as it samples (LCM convention, scale 1 + w)
        self.w = float(config["consistency"]["w"]) if self.base_kind == "consistency" else None

    def _start_from(self, init: str, control: dict[str, Any] | None) -> None:
        """Load the ControlNet weights of bundle `init` (checked: a ControlNet of this architecture
        on this very base) into self.model.control."""
        try:
            bundle = load_bundle(init)
        except StableMoError as err:  # name the option: the same message would fit `base`
            raise StableMoError(f"init: {err}") from None
        section = bundle.config.get("controlnet")
        if bundle.config.get("kind") != "controlnet" or not isinstance(section, dict):
            raise StableMoError(f"init: {init} is a {bundle.config.get('kind', 'diffusion')!r} bundle, not a ControlNet")
        if dict(section.get("control") or {}) != dict(control or {}):
            raise StableMoError(f"init: {init} has control {section.get('control')}, this run {dict(control or {})}; "
                                "give the run the same control settings")
        base = {f"base.{k}": v for k, v in self.model.base.state_dict().items()}
        if set(k for k in bundle.state_dict if k.startswith("base.")) != set(base) or any(
                not torch.equal(bundle.state_dict[k], v.to(bundle.state_dict[k].dtype)) for k, v in base.items()):
            raise StableMoError(f"init: {init}'s ControlNet was trained on another base than {self.hparams.base}")
        weights = {k[len("control."):]: v for k, v in bundle.state_dict.items() if k.startswith("control.")}
        missing, unexpected = self.model.control.load_state_dict(weights, strict=False)
        if missing or unexpected:
            raise StableMoError(f"init: {init}'s ControlNet weights do not fit this run's "
                                f"(missing {len(missing)}, unexpected {len(unexpected)})")

    def train(self, mode: bool = True):
        super().train(mode)
        self.model.base.eval()  # frozen: no dropout in the base, whatever Lightning asks
        return self

    def setup(self, stage: str) -> None:
        dm = getattr(self.trainer, "datamodule", None) if self._trainer is not None else None
        if dm is not None and getattr(dm, "mean", None) is not None:
            for name in ("mean", "std"):
                if not same_statistics(getattr(self, name).cpu(), torch.as_tensor(getattr(dm, name)).float()):
                    raise StableMoError(f"data: the dataset's {name} differs from the base bundle's; "
                                        "train the ControlNet on the base's dataset, or give --data.stats_dir the folder the base was trained on")

    def on_train_start(self) -> None:
        # a resumed run trains at the lr it was given, also when it changed: a constant one holds as
        # configured, a decaying one continues its curve (the scheduler's state) at the new level
        from stablemo.training.module import follow_configured_lrs

        optimizer = self.trainer.optimizers[0]
        if self.hparams.lr_step is None:
            for group in optimizer.param_groups:
                group["lr"] = self.hparams.lr
        else:
            follow_configured_lrs(optimizer, self.trainer.lr_scheduler_configs[0].scheduler,
                                  [float(self.hparams.lr)] * len(optimizer.param_groups))

    def configure_optimizers(self):
        hp = self.hparams
        params = [p for p in self.model.control.parameters() if p.requires_grad]
        optimizer = torch.optim.AdamW(params, lr=hp.lr, weight_decay=hp.weight_decay)
        if hp.lr_step is None:
            return optimizer
        scheduler = torch.optim.lr_scheduler.StepLR(optimizer, step_size=hp.lr_step, gamma=hp.lr_gamma)
        return {"optimizer": optimizer, "lr_scheduler": {"scheduler": scheduler, "interval": "step", "frequency": 1}}

    # ------------------------------------------------------------------ loss

    def _x0_estimate(self, out: torch.Tensor, x_t: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """What the base's sampler takes as x0 from the network output (a student: its consistency function)."""
        if self.base_kind == "consistency":
            from stablemo.distill.student import consistency_fn

            c = self.base_config["consistency"]
            return consistency_fn(c["mode"], self.schedule, c.get("edges"), x_t, out, t,
                                  c.get("sigma_data", 0.5), c.get("timestep_scale", 10.0))
        return self.schedule.predict_x0(out, x_t, t, self.prediction_type)

    def joints(self, x: torch.Tensor) -> torch.Tensor:
        """Normalised features (B, T, D) -> global joints (B, T, J, 3)."""
        return features_to_joints(x * self.std + self.mean, self.skeleton)

    def losses(self, batch: dict, generator: torch.Generator) -> dict[str, torch.Tensor]:
        hp = self.hparams
        x0, mask = batch["motion"], batch["mask"]  # (B, T, D), (B, T)
        B, device = x0.shape[0], x0.device
        multiple = self.model.length_multiple
        if x0.shape[1] % multiple:
            raise StableMoError(f"data.pad_multiple: batches have {x0.shape[1]} frames; the network needs a multiple of {multiple}")
        drop = torch.rand(B, generator=generator) < hp.cond_drop_prob
        texts = ["" if d else c for d, c in zip(drop.tolist(), batch["text"])]
        if hp.train_timesteps is None:
            t = torch.randint(0, self.schedule.num_train_timesteps, (B,), generator=generator)
        else:
            choices = torch.tensor([int(s) for s in hp.train_timesteps])
            t = choices[torch.randint(0, len(choices), (B,), generator=generator)]
        t = t.to(device)
        noise = torch.randn(x0.shape, generator=generator).to(device, x0.dtype)
        hint_mask = sample_hint_mask(mask, self.skeleton.num_joints, generator, tuple(int(j) for j in hp.hint_joints),
                                     hp.dense_prob, hp.empty_prob)  # (B, T, J)
        x_t = self.schedule.q_sample(x0, t, noise)
        cond = None if self.w is None else torch.full((B,), self.w, device=device)
        with torch.no_grad():
            text, text_mask = self.model.encode_text(texts)
            goal, true_joints = x0, self.joints(x0)  # (B, T, D), (B, T, J, 3)
            if hp.recon_target == "base":
                goal = self._x0_estimate(self.model.base_forward(x_t, t, text, text_mask, mask, cond), x_t, t)
                true_joints = self.paths_on(self.joints(goal), true_joints, mask)
        hint = hint_input(true_joints, hint_mask, hp.hint_scale, path=self.model.control.path)
        out = self.model(x_t, t, text, text_mask, mask, hint, cond)
        x0_hat = self._x0_estimate(out, x_t, t)
        frames = mask.float().sum(1)
        # "base": the root's rotation velocity (channel 0) is the ControlNet's to change, and a
        # root-only ControlNet is held on the root channels it sets (its others are the base's):
        # over all channels their error would weigh 3/262 against the joint term, and the
        # body-frame velocity, the shortest way to a target, would walk the body sideways
        kept = slice(None)
        if hp.recon_target == "base":
            kept = slice(1, ROOT_CHANNELS) if (hp.control or {}).get("root_only") else slice(1, None)
        recon = (masked_mse(x0_hat[..., kept], goal[..., kept], mask) * frames).sum() / frames.sum().clamp(min=1.0)
        joints_hat = self.joints(x0_hat)  # (B, T, J, 3)
        sq = (joints_hat - true_joints).square().sum(-1)  # (B, T, J)
        m = hint_mask.float()
        joint = (sq * m).sum() / m.sum().clamp(min=1.0)
        err = ((sq.detach().sqrt() * m).sum() / m.sum().clamp(min=1.0))
        loss = recon + hp.joint_weight * joint
        terms = {"recon": recon, "joint": joint, "joint_err": err}
        if hp.velocity_weight:
            step_sq = (torch.diff(joints_hat - true_joints, dim=1) * PATH_SCALE).square().sum(-1)  # (B, T-1, J), (m/s)^2
            pairs = m[:, 1:] * m[:, :-1]
            terms["velocity"] = (step_sq * pairs).sum() / pairs.sum().clamp(min=1.0)
            loss = loss + hp.velocity_weight * terms["velocity"]
        if hp.root_weight:
            pelvis = m[..., 0]  # (B, T): frames whose pelvis is a target
            root_sq = (x0_hat[..., :ROOT_CHANNELS] - goal[..., :ROOT_CHANNELS]).square().mean(-1)
            terms["root"] = (root_sq * pelvis).sum() / pelvis.sum().clamp(min=1.0)
            loss = loss + hp.root_weight * terms["root"]
        if hp.skate_weight:
            terms["skate"] = self.skate(joints_hat, mask)
            loss = loss + hp.skate_weight * terms["skate"]
        return {"loss": loss, **terms}

    def paths_on(self, base_joints: torch.Tensor, clip_joints: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """The hint targets of recon_target "base": base_joints (B, T, J, 3) with the pelvis's ground
        path replaced, per sample over its valid frames, by the clip's (clip_joints (B, T, J, 3))
        walked as the base's pelvis walks (pace.path_on_reference); its heights stay the base's."""
        targets = base_joints.clone()
        smooth = max(1, round(GAIT_CYCLE_S * self.skeleton.fps))
        for b, n in enumerate(mask.sum(1).tolist()):
            if n < 2:
                continue
            xz = path_on_reference(clip_joints[b, :n, 0][:, [0, 2]].double().cpu().numpy(),
                                   base_joints[b, :n, 0][:, [0, 2]].double().cpu().numpy(),
                                   self.skeleton.per_metre, smooth)
            xz = torch.as_tensor(xz, dtype=targets.dtype, device=targets.device)
            targets[b, :n, 0, 0], targets[b, :n, 0, 2] = xz[:, 0], xz[:, 1]
        return targets

    def skate(self, joints_hat: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """Mean over valid frame pairs i -> i+1 near the floor of the squared horizontal speed
        ((m/s)^2) of the foot joint the body stands on (see the module docstring). joints_hat
        (B, T, J, 3) in dataset units, floor at y = 0; mask (B, T)."""
        skel = self.skeleton
        metres = METRES_PER_UNIT[skel.units]
        feet = joints_hat[:, :, list(skel.contact_joints)] * metres  # (B, T, 4, 3)
        with torch.no_grad():
            height = 0.5 * (feet[:, 1:, :, 1] + feet[:, :-1, :, 1])  # (B, T-1, 4) over the pair
            lowest = height.amin(-1, keepdim=True)
            share = torch.softmax(-(height - lowest) / SKATE_SOFTMIN_M, dim=-1)
            on_floor = torch.sigmoid((SKATE_FLOOR_M - lowest) / (0.2 * SKATE_FLOOR_M))  # (B, T-1, 1)
            pairs = (mask[:, 1:] & mask[:, :-1]).bool()[..., None]  # (B, T-1, 1)
            # selected rather than multiplied by zero: a padded frame's garbage may be non-finite
            w = torch.where(pairs, share * on_floor, torch.zeros_like(share))
        speed_sq = (torch.diff(feet[..., [0, 2]], dim=1) * skel.fps).square().sum(-1)  # (B, T-1, 4)
        return torch.where(w > 0, speed_sq * w, torch.zeros_like(w)).sum() / w.sum().clamp(min=1e-6)

    # ------------------------------------------------------------------ loop

    def training_step(self, batch: dict, batch_idx: int):
        hp = self.hparams
        generator = torch.Generator().manual_seed(derive_seed("controlnet", hp.seed, self.global_step, batch_idx, self.global_rank))
        devices = [batch["motion"].device] if batch["motion"].device.type == "cuda" else []
        with torch.random.fork_rng(devices=devices):  # the copy's dropout layers draw per step too
            torch.manual_seed(derive_seed("dropout", hp.seed, self.global_step, batch_idx, self.global_rank))
            out = self.losses(batch, generator)
        if not torch.isfinite(out["loss"]):
            raise StableMoError(f"controlnet loss became {out['loss'].item()} at step {self.global_step}; lower the learning rate")
        B = len(batch["text"])
        self.log("train/loss", out["loss"], prog_bar=True, batch_size=B)
        self.log("train/recon", out["recon"], batch_size=B)
        self.log("train/joint", out["joint"], batch_size=B)
        self.log("train/joint_err_m", out["joint_err"], prog_bar=True, batch_size=B)
        for name in ("velocity", "root", "skate"):
            if name in out:
                self.log(f"train/{name}", out[name], batch_size=B)
        return out["loss"]

    def optimizer_step(self, *args, **kwargs) -> None:
        super().optimizer_step(*args, **kwargs)
        self.ema.update(self.model.control)

    def validation_step(self, batch: dict, batch_idx: int):
        generator = torch.Generator().manual_seed(derive_seed("controlnet-val", self.hparams.seed, batch_idx))
        with self.ema.swapped_into(self.model.control):
            out = self.losses(batch, generator)
        B = len(batch["text"])
        self.log("val/loss", out["loss"], prog_bar=True, batch_size=B, sync_dist=True)
        self.log("val/joint_err_m", out["joint_err"], prog_bar=True, batch_size=B, sync_dist=True)
        return out["loss"]

    # ------------------------------------------------------------------ export

    def bundle_config(self) -> dict:
        hp = self.hparams
        config = {k: v for k, v in self.base_config.items() if k not in ("format", "version", "training", "inference")}
        config["kind"] = "controlnet"
        config["controlnet"] = {"base_kind": self.base_kind, "joints": self.skeleton.num_joints,
                                "hint_scale": hp.hint_scale, "control": dict(hp.control or {})}
        inference = InferenceConfig.from_bundle(self.base_config)
        if inference.sampler not in model_kind(self.base_kind).samplers(self.base_config, self.schedule):
            # a base whose inference section names a sampler it cannot run (an older student
            # export): derive the section from the base's own keys (a student's steps and w)
            derived = InferenceConfig.from_bundle({k: v for k, v in self.base_config.items() if k != "inference"})
            inference = replace(derived, min_length=inference.min_length, max_length=inference.max_length,
                                fps=inference.fps)
        changes = {k: v for k, v in (("steps", hp.sample_steps), ("cfg", hp.sample_cfg)) if v is not None}
        config["inference"] = replace(inference, **changes).to_dict()
        config["training"] = {"base": str(hp.base), "base_weights_sha256": self.base_sha256,
                              "global_step": int(self.global_step), "ema_decay": hp.ema_decay,
                              "ema_updates": self.ema.num_updates, "joint_weight": hp.joint_weight,
                              "velocity_weight": hp.velocity_weight, "root_weight": hp.root_weight,
                              "skate_weight": hp.skate_weight, "recon_target": hp.recon_target, "init": None if hp.init is None else str(hp.init),
                              "train_timesteps": None if hp.train_timesteps is None else list(hp.train_timesteps)}
        return config

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        # export: the frozen base's weights from the state dict, the ControlNet's from its EMA
        checkpoint[CHECKPOINT_KEY] = {"bundle": self.bundle_config(), "weights_prefix": "model.",
                                      "ema": self.ema.state_dict(), "ema_prefix": "control."}

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        extra = checkpoint.get(CHECKPOINT_KEY) or {}
        if "ema" not in extra:
            raise StableMoError("checkpoint: no ControlNet EMA section; was it written by ControlNetTraining?")
        self.ema.load_state_dict(extra["ema"])
