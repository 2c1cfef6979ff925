"""The finishing step's compiled passes (motion_kernels.cpp, built on first use by
stablemo.fast.kernels): the rigid rebuild's placement of trunk, limbs and feet (place_body), and the
output rows (finish_rows: the kept leading columns, stablemo.motion.extract_torch.body_columns and the
joints recovered from those features, features_to_joints), one pass per frame each, equal to the
PyTorch path to float rounding and the joints to the bit (tests/test_fast_motion.py). Batches of at
least MIN_FUSED_FRAMES frames use it (a benchmark's or an evaluation's; a single prompt, the demo's,
never builds it); otherwise, where the kernel cannot be built (no compiler,
STABLEMO_FUSED_KERNELS=0) and off the CPU, stablemo.inference.finish assembles them with PyTorch."""

from __future__ import annotations

import functools

import numpy as np
import torch

from stablemo.fast.kernels import motion_kernels
from stablemo.motion import extract_torch
from stablemo.motion.skeleton import Skeleton, get_skeleton

# frames (batch x frames) from which the kernel is worth its one-off build (~30 s): on one core the
# PyTorch path takes ~0.5 ms per 200 frames, the kernel ~0.1 ms (32 x 197 frames: 15-20 ms, 3 ms)
MIN_FUSED_FRAMES = 2048


@functools.lru_cache(maxsize=None)
def _tables(skel: Skeleton, dtype: torch.dtype) -> tuple[torch.Tensor, ...]:
    """The skeleton as the kernel reads it: parents (J,), rest directions (J, 3), the rotation each
    bone's is relative to (J-1,), contact joints (K,)."""
    parents = torch.tensor([max(p, 0) for p in skel.parents], dtype=torch.long)
    raw = torch.tensor(np.array(skel.raw_offsets), dtype=dtype)
    before = torch.tensor(extract_torch.rotation_before(skel), dtype=torch.long)
    return parents, raw, before, torch.tensor(list(skel.contact_joints), dtype=torch.long)


def _kernels_for(x: torch.Tensor, frames: int):
    """The compiled motion passes for joints x, or None where they do not run: off the CPU, another
    dtype, recording autograd, fewer than MIN_FUSED_FRAMES frames (a single prompt never builds
    them), or no compiler."""
    if (x.device.type != "cpu" or x.dtype not in (torch.float32, torch.float64) or x.requires_grad
            or frames < MIN_FUSED_FRAMES):
        return None
    return motion_kernels()


def finish_rows(x: torch.Tensor, r: torch.Tensor, lead: torch.Tensor, n: torch.Tensor, root: torch.Tensor,
                skeleton: Skeleton | str) -> tuple[torch.Tensor, torch.Tensor] | None:
    """(features (B, T-1, L + D-3), joints (B, T-1, J, 3)), zero from frame n[b] on, of joint-major
    joints x (J, 3, B, T) (frame T-1 the one after the last row, for its velocities) with root
    rotations r (B, T, 4), kept leading columns lead (B, T-1, L) and recovered root path root
    (B, T-1, 3) (recover_root's; the height is the body's); None where the kernel does not run."""
    skel = get_skeleton(skeleton)
    b, t = x.shape[2:]
    module = _kernels_for(x, b * t)
    if module is None:
        return None
    joints = x.new_empty(b, t - 1, skel.num_joints, 3)
    feats = module.finish_rows(x.contiguous(), r.to(x.dtype).contiguous(), lead.to(x.dtype).contiguous(),
                               n.long().contiguous(), root.to(x.dtype).contiguous(), *_tables(skel, x.dtype),
                               float(skel.contact_threshold), joints)
    return feats, joints


def place_body(x: torch.Tensor, turned: dict[int, torch.Tensor], root: torch.Tensor, forward: torch.Tensor,
               w: torch.Tensor, goal: torch.Tensor, skel: Skeleton, trunk: list[int], beyond: list[int],
               side: torch.Tensor, raw: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor | None:
    """The rigid rebuild's per-frame steps in one compiled pass (stablemo.motion.rigid.rigid_joint_major
    hands it its inputs: joints x (J, 3, B, T), the branching joints' children's turned directions
    {joint: (3, B, T)}, root and forward (3, B, T), each limb's hold w (L, B, T) and goal
    (L, 3, B, T), the trunk's and the feet's joints in order, each limb's bend side (L,), the rest
    directions (J, 3), the body's lengths (J,)) -> the body (J, 3, B, T); None where the kernel does
    not run."""
    j, _, b, t = x.shape
    module = _kernels_for(x, b * t)
    if module is None:
        return None
    long = functools.partial(torch.tensor, dtype=torch.long)
    kids = sorted(turned)
    turned_of = long([kids.index(c) if c in turned else -1 for c in range(j)])
    stacked = torch.stack([turned[c] for c in kids]) if kids else x.new_zeros(0, 3, b, t)
    mids = [mid for _, mid, _ in skel.ik_limbs]
    return module.place_body(x.contiguous(), stacked.contiguous(), turned_of, raw.contiguous(), root.contiguous(),
                             forward.contiguous(), w.contiguous(), goal.contiguous(),
                             long([max(p, 0) for p in skel.parents]), long(trunk),
                             long([list(limb) for limb in skel.ik_limbs]), side.contiguous(),
                             raw[mids].contiguous(), lengths.contiguous(), long(beyond))


__all__ = ["MIN_FUSED_FRAMES", "finish_rows", "place_body"]
