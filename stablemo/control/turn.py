"""The body turns by an asked angle: "turns 90 degrees to the left" turns 90 degrees.

The root's yaw velocity (HumanML3D features, column 0) is scaled over the asked frames so that the
body's facing (hips and shoulders) turns by the angle asked, at every sampler step on the network's
predicted x0; the rest of each feature row is relative to the root, so the body turns with it, its
steps and poses as the network made them, and a walked circle keeps its pace and widens or
tightens. The network decides when and how the body turns; only how far is set. Scaling by k
turns the facing by k times the root's own turn plus what the body adds on its own (its facing
against the root at the span's two ends), so k is solved for exactly.

Where the network barely turned (under MIN_TURN_DEG) or turned the other way than asked, nothing
is changed: stretching a wobble into a turn spins a body that is not stepping round, and the
behaviour suite's side check should see a wrong side rather than have it hidden. k is bounded to
[K_MIN, K_MAX] (a turn three times its generated size still steps; beyond that the feet pivot
visibly), so a much too small turn is made larger but may stay short.

Which turn a text asks for is read by stablemo.text.turns; `Pipeline.generate` reads it for a
planned request (`Request(plan=True)`, `stablemo generate`, the server, the behaviour suite) and a
timeline's windows, or takes `Request(turns=[Turn(...), ...])` from the caller.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import torch

from stablemo.diffusion.hooks import StepState
from stablemo.errors import StableMoError
from stablemo.motion.features import feature_slices
from stablemo.motion.heading import unwrap
from stablemo.motion.skeleton import get_skeleton

END_WINDOW_S = 0.25  # the facing at either end of the span: averaged over this much (a step's sway)
MIN_TURN_DEG = 15.0  # the network's own turn must be at least this, in the asked direction
K_MIN, K_MAX = 1.0 / 3.0, 3.0  # bounds of the scale on the root's turn


@dataclass(frozen=True)
class Turn:
    """The body turns `degrees` (> 0, at most 720) over frames [start, end) of a motion (end None:
    to its last frame), to `side`: "left" (counterclockwise seen from above), "right", or None (the
    way the network turns it)."""

    degrees: float
    side: str | None = None
    start: int = 0
    end: int | None = None

    def resolve(self, length: int, what: str = "turns") -> "Turn":
        """This turn checked against a motion of `length` frames, `end` filled in."""
        try:
            degrees = float(self.degrees)
        except (TypeError, ValueError):
            raise StableMoError(f"{what}.degrees: expected a number, got {self.degrees!r}") from None
        if not (math.isfinite(degrees) and 0 < degrees <= 720):
            raise StableMoError(f"{what}.degrees: expected a number in (0, 720], got {self.degrees!r}")
        if self.side not in (None, "left", "right"):
            raise StableMoError(f"{what}.side: expected 'left', 'right' or None, got {self.side!r}")
        end = length if self.end is None else self.end
        for name, value in (("start", self.start), ("end", end)):
            if isinstance(value, bool) or not isinstance(value, numbers.Integral):
                raise StableMoError(f"{what}.{name}: expected a whole number of frames, got {value!r}")
        start, end = int(self.start), int(end)
        if not 0 <= start < end <= length:
            raise StableMoError(f"{what}: frames [{start}, {end}) do not lie in a motion of {length} frames "
                                f"(0 <= start < end <= {length})")
        return Turn(degrees, self.side, start, end)


def _facing_offset(features: torch.Tensor, skeleton) -> torch.Tensor:
    """(B, T) radians: the body's facing (hips + shoulders, as stablemo.motion.heading.facing_yaw)
    against its root's, from the root-relative joints stored in the root's facing frame."""
    skel = get_skeleton(skeleton)
    ric = feature_slices(skel)["ric"]
    r_hip, l_hip, r_sdr, l_sdr = skel.face_joints

    def joint(j: int) -> torch.Tensor:  # (B, T, 3); joint 0 (the root) is not stored: it is the origin
        if j == 0:
            return torch.zeros_like(features[..., :3])
        return features[..., ric.start + 3 * (j - 1): ric.start + 3 * j]

    across = (joint(r_hip) - joint(l_hip)) + (joint(r_sdr) - joint(l_sdr))
    return torch.atan2(across[..., 2], -across[..., 0])  # atan2(forward x, forward z), forward = y x across


def turn_scale(features: torch.Tensor, lengths, turns, skeleton, fps: float) -> torch.Tensor:
    """(B,) the factor on each sample's root yaw velocity over its turn's frames that makes its
    facing turn as asked (1 where the sample has no turn, or where nothing is changed: see the
    module docstring). features: (B, T, D) de-normalised; turns: per sample a resolved Turn or None."""
    B, T, _ = features.shape
    dev = features.device
    k = torch.ones(B, device=dev, dtype=features.dtype)
    w = max(1, round(END_WINDOW_S * fps))
    # the root's facing yaw per frame: recover_root's half-angle (cos a, 0, sin a, 0) turns the world
    # by 2a about y, so the facing (atan2(x, z)) is -2a; frame 0 faces +z
    root = torch.cat([torch.zeros_like(features[:, :1, 0]), -2.0 * features[:, :-1, 0].cumsum(1)], 1)  # (B, T)
    body = unwrap(root + _facing_offset(features, skeleton), dim=1)  # (B, T)
    for i, turn in enumerate(turns):
        if turn is None:
            continue
        s, e = turn.start, min(turn.end, int(lengths[i]))
        if e - s < 2 * w + 1:
            continue
        d_root = root[i, e - w:e].mean() - root[i, s:s + w].mean()
        d_body = body[i, e - w:e].mean() - body[i, s:s + w].mean()
        sign = {"left": 1.0, "right": -1.0}.get(turn.side, float(torch.sign(d_body)))
        if sign == 0 or float(d_root) * sign < math.radians(MIN_TURN_DEG):
            continue
        want = sign * math.radians(turn.degrees)
        k[i] = ((want - (d_body - d_root)) / d_root).clamp(K_MIN, K_MAX)
    return k


def apply_turns(features: torch.Tensor, lengths, turns, skeleton, fps: float,
                k: torch.Tensor | None = None) -> torch.Tensor:
    """Features (B, T, D) de-normalised, each sample's root yaw velocity scaled over its turn's
    frames (by k: (B,), default turn_scale): the body turns as asked, everything else as generated."""
    k = turn_scale(features, lengths, turns, skeleton, fps) if k is None else k
    if bool((k == 1).all()):
        return features
    T = features.shape[1]
    frames = torch.arange(T, device=features.device)[None]  # (1, T)
    start = torch.tensor([0 if t is None else t.start for t in turns], device=features.device)[:, None]
    end = torch.tensor([0 if t is None else t.end for t in turns], device=features.device)[:, None]
    # column 0 at frame f turns the root from f to f + 1: the span's turns are rows start..end-2
    inside = (frames >= start) & (frames < end - 1)
    out = features.clone()
    out[..., 0] = torch.where(inside, features[..., 0] * k[:, None], features[..., 0])
    return out


def said_turns(texts, spans, shares=None) -> list[Turn | None] | None:
    """Per text the Turn it says (stablemo.text.turns) over its span [start, end) of frames, times
    its share (the part of the text's span a window makes; default 1); None when no text says one."""
    from stablemo.text.turns import asked_turn

    shares = [1.0] * len(texts) if shares is None else shares
    out = []
    for text, (start, end), share in zip(texts, spans, shares):
        asked = asked_turn(text)
        out.append(None if asked is None else Turn(asked.degrees * share, asked.side, int(start), int(end)))
    return out if any(t is not None for t in out) else None


@dataclass
class TurnAsAsked:
    """A sample hook: every step, the x0 of each sample with a turn turns as asked (apply_turns).
    mean/std: (D,) the model's feature statistics; turns: per sample a resolved Turn or None."""

    mean: torch.Tensor
    std: torch.Tensor
    skeleton: object
    turns: list

    def active(self, step: int, steps: int) -> bool:
        return True

    def __call__(self, state: StepState) -> torch.Tensor | None:
        x0 = state.x0
        mean, std = self.mean.to(x0.device).float(), self.std.to(x0.device).float()
        feats = x0.float() * std + mean
        fps = get_skeleton(self.skeleton).fps
        k = turn_scale(feats, state.lengths, self.turns, self.skeleton, fps)
        turned = k != 1  # (B,)
        if not bool(turned.any()):
            return None
        out = ((apply_turns(feats, state.lengths, self.turns, self.skeleton, fps, k) - mean) / std).to(x0.dtype)
        # samples left as they were come back bit for bit: the samplers take any change as an edit
        # (a multistep sampler then steps first order), and a normalisation round trip is a change
        return torch.where(turned[:, None, None], out, x0)


__all__ = ["K_MAX", "K_MIN", "MIN_TURN_DEG", "Turn", "TurnAsAsked", "apply_turns", "said_turns", "turn_scale"]
