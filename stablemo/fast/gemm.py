"""GEMM layers: drop-in replacements for nn.Conv1d, nn.ConvTranspose1d and nn.Linear that change
no result beyond float rounding (stablemo.fast maps the stock layers to these).

- a Conv1d runs as ONE matrix product over unfolded frames, frames-major: (B*T_out, k*C_in) x
  (k*C_in, C_out). CPU conv1d kernels are tuned for images; at the UNet's shapes (C = 1024,
  k = 5, T <= 200) a plain GEMM is 1.5-2x faster. The result is returned as a (B, C, T) view of a
  (B, T, C) buffer, so the element-wise ops that follow keep that layout and the next convolution
  needs no transpose copy;
- a ConvTranspose1d runs as one matrix product (B*T, C_in) x (C_in, k*C_out) followed by the
  k overlap-adds of its taps (col2im), instead of PyTorch's slow generic path;
- float32 products with large weights (>= 1 M elements) on the CPU use a packed-weight GEMM
  (`gemm_backend()`): oneDNN's, packed once per layer, or MKL's, packed once per layer and row
  count (from the second call with that row count on: a single call does not repay the packing);
- under autocast (bf16 on CPU, fp16 on CUDA) every layer uses a low-precision copy of its weight
  that is made once, instead of casting all weights again at every network call;
- 'same' convolutions with >= 256 input and output channels unfold their frames in one pass of
  the compiled kernels (stablemo.fast.kernels); narrower ones never build them.

Each layer is made from the stock one by `from_stock`, holding the very same Parameter objects
under the same names, so `state_dict()` keys and values are unchanged. Unsupported configurations
(groups, dilation, non-zero padding modes) fall back to the stock forward.
"""

from __future__ import annotations

import functools
import os

import torch
import torch.nn.functional as F
from torch import nn

from stablemo.errors import StableMoError
from stablemo.fast import kernels as fused

_MKL_PACK = torch.backends.mkl.is_available() and hasattr(torch.ops.mkl, "_mkl_linear")
_ONEDNN_PACK = torch.backends.mkldnn.is_available() and hasattr(torch.ops.mkldnn, "_linear_pointwise")
GEMM_BACKENDS = ("onednn", "mkl", "plain")
_MIN_PACK_ROWS = 16
# Below ~1 M weight elements a packed product is no faster than a plain one (measured for 5-tap
# convolutions of 32-512 channels), while re-packing for every new row count (a new sequence
# length) costs 2-3 plain products: a small model serving varied lengths would pay it at every call.
_MIN_PACK_WEIGHT = 1 << 20
# Below this width a layer's elementwise work is a few microseconds of dispatch either way; small
# models (the demo) then neither change by a rounding nor wait for the kernels' one-time
# compilation. A layer qualifies only if all its widths reach it: the demo's first convolution reads
# the 263 HumanML3D features but writes 32 channels, and must not build the kernels for that.
MIN_FUSED_CHANNELS = 256


def _cpu_vendor() -> str:
    try:
        with open("/proc/cpuinfo") as info:
            return next((line.split(":", 1)[1].strip() for line in info if line.startswith("vendor_id")), "")
    except OSError:
        return ""


@functools.lru_cache(maxsize=None)
def _default_backend() -> str:
    # MKL picks its fastest kernels on Intel CPUs only: on an AMD EPYC (Zen 4) here its packed GEMM
    # ran the UNet's products at 99-175 GFLOP/s where oneDNN's ran them at 195-216 (K = 1024-10240,
    # 50-400 rows). On Intel (earlier sessions) MKL's packed GEMM reached ~90 % of the matmul peak.
    if _cpu_vendor() == "GenuineIntel" and _MKL_PACK:
        return "mkl"
    return "onednn" if _ONEDNN_PACK else ("mkl" if _MKL_PACK else "plain")


def gemm_backend() -> str:
    """The packed GEMM for large float32 CPU weights: "onednn", "mkl" or "plain" (F.linear).

    STABLEMO_GEMM picks one (for A/B runs); by default oneDNN, except MKL's on Intel CPUs. The
    choice is a rule, not a timing, so that the same seed gives the same output on the same machine.
    """
    name = os.environ.get("STABLEMO_GEMM", "").strip().lower()
    if not name:
        return _default_backend()
    if name not in GEMM_BACKENDS:
        raise StableMoError(f"STABLEMO_GEMM: expected one of {', '.join(GEMM_BACKENDS)}, got {name!r}")
    available = {"onednn": _ONEDNN_PACK, "mkl": _MKL_PACK, "plain": True}[name]
    return name if available else "plain"


def _compute_dtype(x: torch.Tensor) -> torch.dtype:
    device = x.device.type
    if torch.is_autocast_enabled(device):
        return torch.get_autocast_dtype(device)
    return x.dtype


class _WeightCache:
    """Reshaped (and possibly cast) weights, rebuilt whenever the parameter changes in place."""

    def _cached(self, name: str, make, dtype: torch.dtype) -> torch.Tensor:
        source = getattr(self, name)
        if source.requires_grad and torch.is_grad_enabled():  # training: stay differentiable, no cache
            return make(source).to(dtype)
        cache = self.__dict__.setdefault("_gemm_cache", {})
        key = (name, dtype, source.device, source._version, source.data_ptr())
        hit = cache.get((name, dtype))
        if hit is None or hit[0] != key:
            with torch.no_grad():
                value = make(source.detach()).to(dtype).contiguous()
            cache[(name, dtype)] = hit = (key, value)
        return hit[1]

    def _linear(self, rows: torch.Tensor, name: str, make, bias: torch.Tensor | None) -> torch.Tensor:
        """rows (M, K) @ cached weight (N, K)^T + bias; large fp32 CPU products use a packed weight.

        A plain call re-packs the weight operand every time; for the UNet's (M <= 400, K = 5120)
        products that costs 15-25 %. oneDNN's packed layout does not depend on M (its row hint
        changed nothing measurable for 37-400 rows) and a 20 MB weight packs in ~12 ms, so it is
        packed at the first call. MKL's is tied to M, so one is kept per layer for the most recent
        M (M is constant through a sampling loop); it is made at the second call with that M:
        packing a 20 MB weight costs 0.4-2 plain products, repaid after 5-10 packed calls, so a
        one-step student serving sentences of varied lengths must not pack for each of them.
        """
        weight = self._cached(name, make, rows.dtype)
        M = rows.shape[0]
        backend = gemm_backend()
        if not (backend != "plain" and rows.dtype == torch.float32 and rows.device.type == "cpu" and M >= _MIN_PACK_ROWS
                and weight.numel() >= _MIN_PACK_WEIGHT
                and not (torch.is_grad_enabled() and (weight.requires_grad or rows.requires_grad))):  # no autograd there
            return F.linear(rows, weight, bias)
        if backend == "onednn":
            packs = self.__dict__.setdefault("_onednn_packs", {})
            entry = packs.get(name)
            if entry is None or entry[0] is not weight:  # the cached weight is a new tensor after any update
                packs[name] = entry = (weight, torch.ops.mkldnn._reorder_linear_weight(weight, M))
            return torch.ops.mkldnn._linear_pointwise(rows, entry[1], bias, "none", [], "")
        packs = self.__dict__.setdefault("_mkl_packs", {})
        key = (name, M, id(weight))
        entry = packs.get(name)
        if entry is None or entry[0] != key:  # a new row count: a plain product, packing only if it repeats
            packs[name] = (key, None)
            return F.linear(rows, weight, bias)
        if entry[1] is None:
            packs[name] = entry = (key, torch.ops.mkl._mkl_reorder_linear_weight(weight, M))
        return torch.ops.mkl._mkl_linear(rows.contiguous(), entry[1], weight, bias, M)


def _unfold_frames(frames: torch.Tensor, k: int, s: int, p: int, T_out: int, fused_ok: bool = False) -> torch.Tensor:
    """(B, T, C) -> (B, T_out, k*C) with row o = frames[o*s - p : o*s - p + k] flattened (zero outside).

    In a zero-padded (B, T + 2p, C) buffer, the k frames a window reads are one contiguous run of
    k*C numbers starting at (o*s)*C: the whole im2col matrix is a strided view of it, made
    contiguous by one copy of long contiguous rows. fused_ok: the layer may use the compiled kernels.
    """
    B, T, C = frames.shape
    if s == 1 and p > 0 and k == 2 * p + 1 and T >= k:  # a 'same' convolution: no padded copy
        frames = frames if frames.stride(2) == 1 and frames.stride(1) == C else frames.contiguous()
        kernels = fused.kernels() if fused_ok else None  # narrow layers never build them
        if (kernels is not None and frames.dtype == torch.float32 and frames.device.type == "cpu"
                and not (torch.is_grad_enabled() and frames.requires_grad)):
            return kernels.unfold_same(frames, k, p)  # one pass; paired: ~9 ms less per paper-UNet forward
        return _unfold_same(frames, k, p)
    padded = F.pad(frames, (0, 0, p, p)) if p else frames.contiguous()
    return padded.as_strided((B, T_out, k * C), (padded.stride(0), s * C, 1)).contiguous()


def _unfold_same(frames: torch.Tensor, k: int, p: int) -> torch.Tensor:
    """_unfold_frames for stride 1, k = 2p + 1, T >= k, frames with contiguous rows (B, T, C).

    Rows p .. T-p-1 read only real frames: one strided copy straight from `frames`. Only the p rows
    at each end read zero padding, and they come from small padded copies of the edge frames, so
    the whole (B, T + 2p, C) padded copy (one more pass over the activation) is not made.
    Paired on the paper UNet: 4-5 ms less per forward.
    """
    B, T, C = frames.shape
    cols = torch.empty(B, T, k * C, dtype=frames.dtype, device=frames.device)
    cols[:, p : T - p] = frames.as_strided((B, T - 2 * p, k * C), (frames.stride(0), C, 1))
    head = F.pad(frames[:, : k - 1], (0, 0, p, 0))  # frames -p .. k-2: the windows of rows 0 .. p-1
    cols[:, :p] = head.as_strided((B, p, k * C), (head.stride(0), C, 1))
    tail = F.pad(frames[:, T - 2 * p :], (0, 0, 0, p))  # frames T-2p .. T+p-1: rows T-p .. T-1
    cols[:, T - p :] = tail.as_strided((B, p, k * C), (tail.stride(0), C, 1))
    return cols


def _take_parameters(fast: nn.Module, stock: nn.Module) -> nn.Module:
    """fast (built on the meta device with stock's settings) takes stock's Parameter objects."""
    fast.weight = stock.weight
    fast.bias = stock.bias
    return fast.train(stock.training)


class GemmConv1d(nn.Conv1d, _WeightCache):
    """nn.Conv1d computed as one GEMM over unfolded frames (see module docstring)."""

    @classmethod
    def from_stock(cls, conv: nn.Conv1d) -> "GemmConv1d":
        fast = cls(conv.in_channels, conv.out_channels, conv.kernel_size, conv.stride, conv.padding, conv.dilation,
                   conv.groups, conv.bias is not None, conv.padding_mode, device="meta")
        fast.fused_ok = min(conv.in_channels, conv.out_channels) >= MIN_FUSED_CHANNELS
        return _take_parameters(fast, conv)

    def _supported(self) -> bool:
        return (self.groups == 1 and self.dilation == (1,) and self.padding_mode == "zeros"
                and not isinstance(self.padding, str))

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # x: (B, C_in, T) -> (B, C_out, T_out)
        if not self._supported() or x.dim() != 3:
            return super().forward(x)
        B, C, T = x.shape
        (k,), (s,), (p,) = self.kernel_size, self.stride, self.padding
        dtype = _compute_dtype(x)
        frames = x.transpose(1, 2).to(dtype)  # (B, T, C): a free view when x is frames-major
        T_out = (T + 2 * p - k) // s + 1
        if k == 1 and s == 1 and p == 0:
            cols = frames.reshape(B * T_out, C)
        else:
            cols = _unfold_frames(frames, k, s, p, T_out, self.fused_ok).view(B * T_out, k * C)
        bias = self._cached("bias", lambda b: b, dtype) if self.bias is not None else None
        y = self._linear(cols, "weight", lambda w: w.permute(0, 2, 1).reshape(w.shape[0], -1), bias)  # (B*T_out, C_out)
        return y.view(B, T_out, -1).transpose(1, 2)


class GemmConvTranspose1d(nn.ConvTranspose1d, _WeightCache):
    """nn.ConvTranspose1d as one GEMM plus the overlap-add of its k taps (col2im)."""

    @classmethod
    def from_stock(cls, conv: nn.ConvTranspose1d) -> "GemmConvTranspose1d":
        fast = cls(conv.in_channels, conv.out_channels, conv.kernel_size, conv.stride, conv.padding,
                   conv.output_padding, conv.groups, conv.bias is not None, conv.dilation, conv.padding_mode,
                   device="meta")
        return _take_parameters(fast, conv)

    def _supported(self) -> bool:
        return (self.groups == 1 and self.dilation == (1,) and self.padding_mode == "zeros"
                and self.output_padding == (0,))

    def forward(self, x: torch.Tensor, output_size=None) -> torch.Tensor:  # (B, C_in, T) -> (B, C_out, T_out)
        if not self._supported() or output_size is not None or x.dim() != 3:
            return super().forward(x, output_size)
        B, C, T = x.shape
        (k,), (s,), (p,) = self.kernel_size, self.stride, self.padding
        dtype = _compute_dtype(x)
        frames = x.transpose(1, 2).reshape(B * T, C).to(dtype)
        # weight (C_in, C_out, k) -> (k*C_out, C_in): row j*C_out + o holds tap j of output channel o
        taps = self._linear(frames, "weight", lambda w: w.permute(2, 1, 0).reshape(-1, w.shape[0]), None)
        taps = taps.view(B, T, k, -1)  # (B, T, k, C_out)
        full = torch.zeros(B, (T - 1) * s + k, taps.shape[-1], dtype=taps.dtype, device=taps.device)
        for j in range(k):  # input frame i, tap j lands on output frame i*s + j
            full[:, j : j + (T - 1) * s + 1 : s] += taps[:, :, j]
        y = full[:, p : full.shape[1] - p]
        if self.bias is not None:
            y = y + self._cached("bias", lambda b: b, dtype)
        return y.transpose(1, 2)


class CachedCastLinear(nn.Linear, _WeightCache):
    """nn.Linear with the packed-weight product; under autocast, one cached low-precision weight."""

    @classmethod
    def from_stock(cls, linear: nn.Linear) -> "CachedCastLinear":
        fast = cls(linear.in_features, linear.out_features, linear.bias is not None, device="meta")
        return _take_parameters(fast, linear)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        dtype = _compute_dtype(x)
        bias = self._cached("bias", lambda b: b, dtype) if self.bias is not None else None
        rows = x.to(dtype).reshape(-1, x.shape[-1])
        return self._linear(rows, "weight", lambda w: w, bias).view(*x.shape[:-1], -1)
