"""Joint-trajectory control errors (OmniControl, Xie et al. ICLR 2024; MotionLCM reports the same).

For each controlled entry (sample b, frame t, joint j with hint_mask = 1) the error is
d = ‖Ĵ_{b,t,j} − H_{b,t,j}‖ in metres (global joint positions of the generated motion vs the hint).
  Avg. err  = Σ d / Σ m
  Traj. err = fraction of samples with any controlled d > threshold (samples without hints skipped)
  Loc. err  = fraction of controlled entries with d > threshold
"""

from __future__ import annotations

import numpy as np
import torch

from stablemo.errors import StableMoError
from stablemo.motion.skeleton import get_skeleton


def control_errors(joints, hints, hint_mask, threshold: float = 0.5) -> dict[str, float]:
    """joints, hints: (B, T, J, 3); hint_mask: (B, T, J) or (B, T, J, 3) bool. Returns the three errors."""
    j = torch.as_tensor(np.asarray(joints) if not torch.is_tensor(joints) else joints).detach().double().cpu()
    h = torch.as_tensor(np.asarray(hints) if not torch.is_tensor(hints) else hints).detach().double().cpu()
    m = torch.as_tensor(np.asarray(hint_mask) if not torch.is_tensor(hint_mask) else hint_mask).detach().cpu()
    if j.shape != h.shape or j.ndim != 4 or j.shape[-1] != 3:
        raise StableMoError(f"control: joints {tuple(j.shape)} and hints {tuple(h.shape)} must both be (B, T, J, 3)")
    if m.ndim == 4:
        m = m.bool().any(-1)
    m = m.bool()
    if tuple(m.shape) != tuple(j.shape[:3]):
        raise StableMoError(f"control: hint_mask {tuple(m.shape)} does not match joints {tuple(j.shape[:3])}")
    if not m.any():
        raise StableMoError("control: hint_mask selects no entries")
    d = torch.linalg.norm(j - h, dim=-1)  # (B, T, J)
    far = (d > threshold) & m
    controlled = m.flatten(1).any(1)
    return {
        "avg_err": float((d * m).sum() / m.sum()),
        "traj_err": float(far.flatten(1).any(1)[controlled].double().mean()),
        "loc_err": float(far.sum() / m.sum()),
    }


# ----------------------------------------------------------------------------- protocol

PROTOCOL_JOINTS = ("pelvis", "left_foot", "right_foot", "head", "left_wrist", "right_wrist")
CONTROL_CHOICES = (*PROTOCOL_JOINTS, "all", "keyframes")


class ControlProtocol:
    """OmniControl / MotionLCM's control evaluation: hints are the scored test motions' own global
    joint positions at `joints`, on frames drawn per sample at `density` ('100%', '25%': that share
    of the frames; '5', '2', '1': that many frames), at random from the replication's generator.
    joint 'all': the six protocol joints together; 'keyframes': every joint (whole poses, the
    in-betweening case)."""

    def __init__(self, joint: str, density: str, skeleton="humanml3d"):
        from stablemo.control.files import joint_index

        self.skeleton = get_skeleton(skeleton)
        if joint == "keyframes":
            self.joints = list(range(self.skeleton.num_joints))
        else:
            names = PROTOCOL_JOINTS if joint == "all" else (joint,)
            self.joints = [joint_index(n, self.skeleton) for n in names]
        self.name = joint
        self.density = density.strip()
        try:
            if self.density.endswith("%"):
                self.share, self.count = float(self.density[:-1]) / 100.0, None
                if not 0 < self.share <= 1:
                    raise ValueError
            else:
                self.share, self.count = None, int(self.density)
                if self.count < 1:
                    raise ValueError
        except ValueError:
            raise StableMoError(f"--density: expected 100%, 25%, … or a frame count (5, 2, 1), got {density!r}") from None

    def hints(self, features: list[torch.Tensor], rng: np.random.Generator) -> list:
        """One JointControl per motion (raw features (L_i, D)) from its own joints."""
        from stablemo.control.spec import JointControl
        from stablemo.motion import features_to_joints

        out = []
        for feats in features:
            joints = features_to_joints(feats[None].float(), self.skeleton)[0].numpy()
            T = len(joints)
            n = T if self.count is None and self.share == 1 else (
                max(1, int(round(self.share * T))) if self.count is None else min(self.count, T))
            frames = np.sort(rng.choice(T, n, replace=False)) if n < T else np.arange(T)
            mask = np.zeros((T, self.skeleton.num_joints), bool)
            mask[np.ix_(frames, self.joints)] = True
            out.append(JointControl(joints, mask))
        return out


def acceleration_spikes(joints, hint_mask, reference, skeleton="humanml3d", window: int = 2) -> float:
    """Share of hinted frames near which the root or a foot accelerates harder than the reference
    motions' 99th percentile: max over frames t-window..t+window of |second difference| (m/s²) of
    the pelvis, ankles and toes, against that percentile over every frame of `reference`.

    joints: (B, T, J, 3); hint_mask: (B, T, J) bool (frames with any hint count); reference: list
    of (L_i, J, 3). A target reached by a jerk shows here; natural motion gives ~ the share a
    (2 window + 1)-frame max has of exceeding a 99th percentile.
    """
    skel = get_skeleton(skeleton)
    parts, fps = [0, *skel.feet_left, *skel.feet_right], skel.fps  # the root and the contact joints

    def accel(x):  # (..., T, J, 3) -> (..., T-2) max over the parts
        a = (x[..., 2:, :, :] - 2 * x[..., 1:-1, :, :] + x[..., :-2, :, :])[..., parts, :]
        return torch.linalg.norm(a, dim=-1).amax(-1) * fps * fps

    ref = torch.cat([accel(torch.as_tensor(np.asarray(r), dtype=torch.float64)) for r in reference])
    p99 = torch.quantile(ref, 0.99)
    j = torch.as_tensor(np.asarray(joints), dtype=torch.float64)
    a = torch.nn.functional.pad(accel(j), (1, 1))  # (B, T): frame t's acceleration at index t
    near = torch.nn.functional.max_pool1d(a[:, None], 2 * window + 1, stride=1, padding=window)[:, 0]
    frames = torch.as_tensor(np.asarray(hint_mask)).any(-1)
    if not frames.any():
        raise StableMoError("control: hint_mask selects no frames")
    return float((near[frames] > p99).double().mean())
