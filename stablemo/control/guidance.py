"""Joint control by guidance on the predicted x0 (OmniControl's spatial guidance, in motion space).

At every sampler step the hook moves the predicted clean motion towards the joint targets:

1. Root in-painting, exact and analytic, where the pelvis (the root) is a target: the root's
   path is moved by an offset that is exact at every pelvis target and C1-smooth between them
   (no kink at a target), in the heading the motion already has, and written back as the root's
   velocities and height. The motion starts at the origin, which acts as a target at frame 0.
2. Gradient steps for every other target on the joints' root-relative positions (ric) of the
   predicted x0, through the features -> joints map only (never through the network): with the
   root fixed that map is a rotation plus an offset per frame, so the gradient is closed-form and a
   unit step lands a joint on its target. The update is smoothed over time (a Gaussian of `smooth`
   frames), so a sparse target moves its neighbourhood with it instead of one frame (no velocity
   spike at a keyframe); iterating converges at the targets. More iterations at the last step,
   where the result is final.

Batched over samples and targets: no Python loop over samples or frames.
"""

from __future__ import annotations

import math

import torch

from stablemo.control.heading import gait_angle, steer_heading, text_gait
from stablemo.diffusion.hooks import StepState
from stablemo.motion.extract_torch import known_neighbours
from stablemo.motion.features import feature_slices, features_to_joints, recover_root
from stablemo.motion.quaternion import qinv, qrot
from stablemo.motion.skeleton import get_skeleton


def smooth_offsets(delta: torch.Tensor, anchors: torch.Tensor) -> torch.Tensor:
    """Offsets known at anchor frames, interpolated C1-smoothly over every frame (cubic Hermite
    with Catmull-Rom tangents, held constant before the first and after the last anchor, where the
    tangent is zero), so a correction bends a path without a kink at the targets.

    delta: (B, T, C), read at anchors only; anchors: (B, T) bool. Samples without anchors get 0.
    """
    B, T, _ = delta.shape
    frames = torch.arange(T, device=delta.device)
    idx = frames[None, :].expand(B, T)
    # last anchor <= t (-1: none) and first anchor > t (T: none)
    prev, first_ge = known_neighbours(anchors)
    nxt = torch.cat([first_ge[:, 1:], torch.full_like(first_ge[:, :1], T)], 1)
    before = torch.cat([torch.full_like(prev[:, :1], -1), prev[:, :-1]], 1)  # last anchor < t

    def at(index):  # delta at anchor frames (clamped; callers mask the missing ones)
        return torch.gather(delta, 1, index.clamp(0, T - 1)[..., None].expand(-1, -1, delta.shape[-1]))

    # tangents at every frame as if it were an anchor (only anchors' are used)
    has_before, has_next = before >= 0, nxt < T
    span = torch.where(has_before, nxt - before, nxt - idx).clamp(min=1).to(delta.dtype)[..., None]
    left = torch.where(has_before[..., None], at(before), delta)
    tangent = torch.where(has_next[..., None], (at(nxt) - left) / span, torch.zeros_like(delta))
    # Hermite between prev and nxt
    inside = (prev >= 0) & has_next
    width = (nxt - prev).clamp(min=1).to(delta.dtype)
    u = ((idx - prev).to(delta.dtype) / width).clamp(0, 1)[..., None]
    h00, h10 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u
    h01, h11 = -2 * u**3 + 3 * u**2, u**3 - u**2
    ta = torch.gather(tangent, 1, prev.clamp(0)[..., None].expand_as(delta))
    tb = torch.gather(tangent, 1, nxt.clamp(max=T - 1)[..., None].expand_as(delta))
    w = width[..., None]
    curve = h00 * at(prev) + h10 * w * ta + h01 * at(nxt) + h11 * w * tb
    held = torch.where((prev >= 0)[..., None], at(prev), at(first_ge))  # after the last / before the first
    out = torch.where(inside[..., None], curve, held)
    return torch.where(anchors.any(1)[:, None, None], out, torch.zeros_like(out))


def project_root(features: torch.Tensor, targets: torch.Tensor, mask: torch.Tensor,
                 lengths: torch.Tensor) -> torch.Tensor:
    """Root channels corrected so the root passes through its targets, smoothly.

    features: (B, T, D) de-normalised; targets: (B, T, 3) root positions; mask: (B, T) bool (True =
    target); lengths: (B,). The offset between the root's path and its targets, known at the target
    frames (and 0 at frame 0, where every motion starts at the origin), is interpolated C1-smoothly
    over time (smooth_offsets) and added to the path; the new path's steps are written back as the
    root's velocities in the heading the motion already has, and its height as the root height.
    Samples without a root target are returned unchanged.
    """
    B, T, _ = features.shape
    frames = torch.arange(T, device=features.device)
    mask = mask & (frames[None, :] < lengths[:, None])
    if not mask.any():
        return features
    q, pos = recover_root(features)  # q: (B, T, 4), pos: (B, T, 3)
    miss = targets - pos  # read at target frames only
    height = smooth_offsets(miss[..., 1:2], mask)[..., 0]
    anchors = mask.clone()
    anchors[:, 0] = True  # the motion starts at the origin: no offset there
    planar_miss = torch.where(mask[..., None], miss[..., [0, 2]], torch.zeros_like(miss[..., [0, 2]]))
    planar = pos[..., [0, 2]] + smooth_offsets(planar_miss, anchors)  # (B, T, 2)
    step = planar[:, 1:] - planar[:, :-1]  # (B, T-1, 2) global steps
    step3 = torch.stack([step[..., 0], torch.zeros_like(step[..., 0]), step[..., 1]], -1)
    local = qrot(q[:, 1:], step3)  # velocity k-1 lives in the facing frame of k (see recover_root)
    has_target = mask.any(1)[:, None]
    out = features.clone()
    out[..., 3] = torch.where(has_target, features[..., 3] + height, features[..., 3])
    out[:, :-1, 1:3] = torch.where(has_target[..., None], local[..., [0, 2]], features[:, :-1, 1:3])
    return out


def steers_heading(mask: torch.Tensor, skeleton) -> torch.Tensor:
    """(B,) bool: the samples whose body should face along their pelvis path: the pelvis is a
    target on at least two frames and no hip or shoulder is (those fix the facing themselves, as
    whole-pose keyframes do). mask: (B, T, J) bool."""
    skel = get_skeleton(skeleton)
    facing_set = mask[:, :, list(skel.face_joints)].flatten(1).any(1)
    return (mask[:, :, 0].sum(1) >= 2) & ~facing_set


def _gaussian(smooth: float, device, dtype) -> torch.Tensor | None:
    if smooth <= 0:
        return None
    radius = int(math.ceil(3 * smooth))
    k = torch.exp(-0.5 * (torch.arange(-radius, radius + 1, device=device, dtype=dtype) / smooth) ** 2)
    return k / k.sum()


# A targeted limb end is brought within this share of its limb's straight length (upper + lower
# bone) from the limb's first joint: a little bent, as an arm or leg reaching for something is.
REACH_SHARE = 0.9


class JointGuidance:
    """A sample hook steering x0 towards joint targets (see the module docstring).

    targets: (B, T, J, 3) dataset units; mask: (B, T, J) bool; mean/std: (D,) the model's feature
    statistics; iters: gradient iterations at each step, final_iters: at the last step; smooth:
    the update's temporal Gaussian (frames); follow: the share of the mean horizontal miss of the
    targets at a frame without a pelvis target that the root takes (the rest moves the pose).
    """

    def __init__(self, targets: torch.Tensor, mask: torch.Tensor, mean: torch.Tensor, std: torch.Tensor,
                 skeleton, iters: int = 10, final_iters: int = 40, smooth: float = 2.0, follow: float = 0.5,
                 face_travel: bool = True, named_gaits: torch.Tensor | None = None, own_gait: bool = True):
        self.targets, self.mask = targets.float(), mask.bool()
        self.face_travel = bool(face_travel)
        self.named_gaits = named_gaits
        self.own_gait = bool(own_gait)
        self.mean, self.std = mean.float(), std.float()
        self.skeleton = get_skeleton(skeleton)
        self.iters, self.final_iters = int(iters), int(final_iters)
        self.smooth, self.follow = float(smooth), float(follow)
        # Only the joints' root-relative positions (ric) take gradient steps: the root moves by
        # projection (its velocities are integrated over the whole motion, badly conditioned for
        # plain steps); rotations, velocities and contacts are left to the network, which re-derives
        # them from the positions at the next step.

    def active(self, step: int, steps: int) -> bool:
        return True

    def _root_targets(self, feats, targets, mask) -> tuple[torch.Tensor, torch.Tensor]:
        """Root targets (B, T, 3) and their mask (B, T): the pelvis's where it is a target, else the
        root moved by `follow` x the mean horizontal miss of the frame's other targets, and further
        where a targeted limb end would still be out of its limb's reach (_reach_move)."""
        joints = features_to_joints(feats, self.skeleton)
        w = mask.to(feats.dtype)[..., None]  # (B, T, J, 1)
        miss = ((targets - joints) * w).sum(2) / w.sum(2).clamp(min=1)  # (B, T, 3)
        move = self.follow * miss * torch.tensor([1.0, 0.0, 1.0], device=feats.device)
        virtual = joints[:, :, 0] + move + self._reach_move(joints, targets, mask, move)
        pelvis = mask[..., 0]
        others = mask.any(2) & ~pelvis
        if self.follow <= 0:
            others = torch.zeros_like(others)
        root = torch.where(pelvis[..., None], targets[:, :, 0], virtual)
        return root, pelvis | others

    def _reach_move(self, joints, targets, mask, move) -> torch.Tensor:
        """(B, T, 3) horizontal root move that brings each targeted limb end (a wrist, an ankle:
        Skeleton.ik_limbs) within REACH_SHARE of its limb's length from the limb's first joint, after
        the root moved by `move`: the mean over the frame's targeted ends of the horizontal distance
        beyond the one at which the target is in reach at its height (all of it if its height alone
        is out of reach). The pose steps below move only the targeted joint, so without this a
        target far from the body stretched the arm (a wrist 0.7 m in front of the pelvis), and the
        rigid body of the finishing step (stablemo.inference.finish) could not reach it: the wrist
        targets of the benchmark were missed by 18 cm on mean after it, 6 mm before."""
        total = torch.zeros_like(move)
        count = torch.zeros_like(move[..., :1])
        flat = torch.tensor([1.0, 0.0, 1.0], device=joints.device, dtype=joints.dtype)
        for upper, mid, end in self.skeleton.ik_limbs:
            m = mask[:, :, end, None].to(joints.dtype)  # (B, T, 1)
            if not m.any():
                continue
            reach = REACH_SHARE * float(self.skeleton.bone_lengths[mid] + self.skeleton.bone_lengths[end])
            ray = targets[:, :, end] - (joints[:, :, upper] + move)  # (B, T, 3)
            across = (ray * flat).norm(dim=-1, keepdim=True)  # horizontal distance
            # the horizontal distance at which the target is within reach, given its height
            allowed = (reach * reach - ray[..., 1:2].square()).clamp(min=0).sqrt()
            beyond = (across - allowed).clamp(min=0) / across.clamp(min=1e-9)
            total = total + m * beyond * ray * flat
            count = count + m
        return total / count.clamp(min=1)

    def __call__(self, state: StepState) -> torch.Tensor:
        x0 = state.x0
        dev = x0.device
        mean, std = self.mean.to(dev), self.std.to(dev)
        targets, mask = self.targets.to(dev), self.mask.to(dev)
        lengths = torch.tensor(state.lengths, device=dev)
        feats = x0 * std + mean
        with torch.no_grad():
            root, root_mask = self._root_targets(feats, targets, mask)
            named = None if self.named_gaits is None else self.named_gaits.to(dev)
            # the network's own walk, before its path is moved
            if self.own_gait:
                gait = gait_angle(feats, lengths, self.skeleton.fps, self.skeleton.per_metre, named)
            else:
                gait = text_gait(named, feats.shape[0], dev)
            feats = project_root(feats, root, root_mask, lengths)
            if self.face_travel:
                steer = steers_heading(mask, self.skeleton)
                if steer.any():
                    feats = steer_heading(feats, lengths, self.skeleton.fps, self.skeleton.per_metre, steer, gait)
        iters = self.final_iters if state.step == state.steps - 1 else self.iters
        if not mask[:, :, 1:].any():
            iters = 0  # root targets only (a pelvis path): the projection above met them; every pose step would be zero
        # With the root fixed, joint j >= 1 sits at R_t^T ric_j + o_t (R_t the heading, o_t the root's
        # horizontal place): half the squared miss has the gradient R_t (joint - target) in ric_j, a
        # unit step lands the joint on its target, and no autograd is needed.
        q, root = recover_root(feats)  # (B, T, 4), (B, T, 3)
        q = q[:, :, None, :].expand(-1, -1, targets.shape[2] - 1, -1)
        offset = (root * torch.tensor([1.0, 0.0, 1.0], device=dev))[:, :, None, :]  # (B, T, 1, 3)
        weight = mask[:, :, 1:, None].to(x0.dtype)  # (B, T, J-1, 1)
        goal = targets[:, :, 1:]
        ric_cols = feature_slices(self.skeleton)["ric"]
        ric = feats[..., ric_cols].unflatten(-1, (-1, 3))  # (B, T, J-1, 3)
        frame_mask = state.mask.to(dev)[:, :, None, None]
        kernel = _gaussian(self.smooth, dev, x0.dtype)
        for _ in range(iters):
            joints = qrot(qinv(q), ric) + offset
            grad = qrot(q, (joints - goal) * weight)  # (B, T, J-1, 3)
            if kernel is not None:  # the update smoothed over time, per coordinate
                B, T = grad.shape[:2]
                g = grad.flatten(2).transpose(1, 2).reshape(-1, 1, T)
                g = torch.nn.functional.conv1d(g, kernel.view(1, 1, -1), padding=kernel.numel() // 2)
                grad = g.reshape(B, -1, T).transpose(1, 2).unflatten(-1, (-1, 3))
            ric = ric - torch.where(frame_mask, grad, torch.zeros((), device=dev))
        feats = feats.clone()
        feats[..., ric_cols] = ric.flatten(-2)
        # samples without a target come back bit-identical (the sampler treats them as unedited)
        controlled = mask.flatten(1).any(1)[:, None, None]
        return torch.where(controlled, (feats - mean) / std, x0).detach()


__all__ = ["JointGuidance", "project_root", "steers_heading"]
