"""Training speed-ups that change no gradient beyond float rounding.

Profiled on the paper UNet (batch 8 x 196, one CPU thread, docs/training.md), the stock training
step spends ~48 % of its time in oneDNN's convolution backward (3.2x its forward for the same
FLOPs), ~7 % in PyTorch's scalar Mish backward and ~13 % in the per-parameter AdamW loop. This
module replaces the first two with autograd Functions built on plain GEMMs and vectorised passes:

- `GemmConv1dFunction`: a Conv1d as one GEMM over unfolded frames (as stablemo.fast.gemm does for
  inference) with its backward as two more GEMMs: grad_weight = grad_rows^T @ cols and
  grad_cols = grad_rows @ weight, folded back onto the frames by k strided adds. The unfolded
  matrix (k times the input) is not kept for the backward: it is made again there from the input,
  so the saved tensors are the stock convolution's (input and weight);
- `MishFunction`: mish(x) = x n / (n + 2) with n = e^x (e^x + 2) forward (stablemo.fast.blocks)
  and its derivative n / (n + 2) + 4 x e^x (1 + e^x) / (n + 2)^2 backward, from the saved input.

Three more keep fewer activations for the backward (the step's peak memory, docs/training.md):
`NormMishFunction` (norm + AdaGN + Mish keeping only its input, the rest made again in the
backward), `DropoutFunction` (a bool mask instead of the float noise, the same draw) and
`DeferredContext` (each cross-attention's text context made where it is read, not in `prepare`, so
its backward runs with its attention's instead of at the step's end).

`accelerate_training(model)` swaps nn.Conv1d / nn.Mish / nn.Dropout modules, the cross-attentions,
the UNet's residual blocks and the UNet itself (its head) for versions that use these under
autograd on the CPU (and exactly the stock computation when no
gradient is recorded, under autocast and on CUDA, where they were not measured), holding the same Parameter objects under the same names: `state_dict()` is unchanged,
so checkpoints, EMA and export see the stock model.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from stablemo.fast.blocks import adopt, adopt_unet
from stablemo.nets.layers import LinearCrossAttention, MaskedGroupNorm, zero_pad_bct
from stablemo.nets.unet import CondUNet1D, ResBlock1D

# exp clamp: for x > 20, n / (n + 2) is exactly 1 in float32 (mish(x) = x, mish'(x) = 1)
_EXP_MAX = 20.0


def _mish_parts(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(e, n) with e = e^min(x, 20), n = e (e + 2) = (1 + e)^2 - 1, formed without cancellation."""
    e = x.clamp(max=_EXP_MAX).exp()
    return e, torch.addcmul(e, e, e).add_(e)


def _mish_grad(x: torch.Tensor) -> torch.Tensor:
    """mish'(x) = n / (n + 2) + 4 x e^x (1 + e^x) / (n + 2)^2, a new tensor shaped like x.

    d/dx [x tanh(softplus(x))] = tanh(sp) + x sech^2(sp) sigmoid(x), with tanh(sp) = n / d and
    sech^2(sp) sigmoid(x) = 4 (n + 1) / d^2 * e / (1 + e) = 4 e (1 + e) / d^2, d = n + 2."""
    e, n = _mish_parts(x)
    d = n.add(2.0)
    slope = torch.addcmul(e, e, e).mul_(4.0).mul_(x).div_(d.square())
    return n.div_(d).add_(slope)


def _mish_values(x: torch.Tensor) -> torch.Tensor:
    """mish(x) = x n / (n + 2), a new tensor (x is not changed)."""
    e, n = _mish_parts(x)
    return n.div_(e.copy_(n).add_(2.0)).mul_(x)


class MishFunction(torch.autograd.Function):
    """mish with a vectorised backward (PyTorch's CPU mish forward + backward took 77 ms against
    21 ms here on a (8, 1024, 200) frames-major tensor, the layout the UNet's norms return)."""

    @staticmethod
    def forward(ctx, x: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(x)
        return _mish_values(x)

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:
        (x,) = ctx.saved_tensors
        return grad * _mish_grad(x)


def train_mish(x: torch.Tensor) -> torch.Tensor:
    """F.mish, through MishFunction when a gradient is recorded for a float32/float64 CPU x (CUDA's
    mish kernel is fused already)."""
    if torch.is_grad_enabled() and x.requires_grad and x.dtype in (torch.float32, torch.float64) and x.device.type == "cpu":
        return MishFunction.apply(x)
    return F.mish(x)


def _unfold(frames: torch.Tensor, k: int, s: int, p: int, T_out: int) -> torch.Tensor:
    """(B, T, C) frames -> (B * T_out, k * C) im2col rows (zero outside the frames)."""
    B, _, C = frames.shape
    padded = (F.pad(frames, (0, 0, p, p)) if p else frames).contiguous()  # (B, T + 2p, C), rows of C
    return padded.as_strided((B, T_out, k * C), (padded.stride(0), s * C, 1)).reshape(B * T_out, k * C)


class GemmConv1dFunction(torch.autograd.Function):
    """conv1d(x, weight, bias, stride, padding) as GEMMs forward and backward (see module docstring).

    x: (B, C, T) (frames-major or not), weight: (O, C, k) -> (B, O, T_out), returned as a view of a
    frames-major (B, T_out, O) buffer so that the next layer's unfold needs no transpose copy."""

    @staticmethod
    def forward(ctx, x, weight, bias, stride: int, padding: int):
        B, C, T = x.shape
        O, _, k = weight.shape
        T_out = (T + 2 * padding - k) // stride + 1
        frames = x.transpose(1, 2)  # (B, T, C)
        w_rows = weight.permute(0, 2, 1).reshape(O, k * C)  # (O, k*C): tap-major, as the unfolded rows
        cols = _unfold(frames, k, stride, padding, T_out)
        y = torch.addmm(bias, cols, w_rows.t()) if bias is not None else cols @ w_rows.t()
        # the weight itself, not w_rows (a copy): saving it would keep ~1 GB more for the paper UNet
        ctx.save_for_backward(x, weight)
        ctx.conf = (k, stride, padding, T_out, bias is not None)
        return y.view(B, T_out, O).transpose(1, 2)

    @staticmethod
    def backward(ctx, grad_y):
        x, weight = ctx.saved_tensors
        k, s, p, T_out, has_bias = ctx.conf
        B, C, T = x.shape
        O = weight.shape[0]
        g_rows = grad_y.transpose(1, 2).reshape(B * T_out, O)  # (B*T_out, O), a view when frames-major
        grad_x = grad_w = grad_b = None
        if ctx.needs_input_grad[1]:
            cols = _unfold(x.transpose(1, 2), k, s, p, T_out)  # made again: not kept from the forward
            grad_w = (g_rows.t() @ cols).view(O, k, C).permute(0, 2, 1)  # (O, C, k)
        if has_bias and ctx.needs_input_grad[2]:
            grad_b = g_rows.sum(dim=0)
        if ctx.needs_input_grad[0]:
            g_cols = (g_rows @ weight.permute(0, 2, 1).reshape(O, k * C)).view(B, T_out, k, C)
            # col2im: output row o read input frames o*s - p + j; add each tap back onto them
            full = torch.zeros(B, T + 2 * p, C, dtype=g_cols.dtype, device=g_cols.device)
            span = (T_out - 1) * s + 1
            for j in range(k):
                full[:, j : j + span : s] += g_cols[:, :, j]
            grad_x = full[:, p : p + T].transpose(1, 2)
        return grad_x, grad_w, grad_b, None, None


class CastConv1dFunction(torch.autograd.Function):
    """conv1d (or conv_transpose1d) under CPU autocast (bf16-mixed) computed as autocast computes
    it -- input, weight and bias cast to the autocast dtype, oneDNN's convolution, the same
    convolution_backward -- but keeping the float32 weight for the backward (cast again there)
    instead of its copy. Autocast's cast is an autograd node that keeps the copy (2 B per weight)
    until the layer's backward, and the down path's copies are still alive at the end of the
    backward, where the step's memory peaks; the cast again costs one pass over the layer's weight."""

    @staticmethod
    def forward(ctx, x, weight, bias, stride: int, padding: int, output_padding: int, transposed: bool,
                dtype: torch.dtype):
        with torch.autocast("cpu", enabled=False):
            xc = x.to(dtype)
            w, b = weight.to(dtype), None if bias is None else bias.to(dtype)
            y = (F.conv_transpose1d(xc, w, b, stride, padding, output_padding) if transposed
                 else F.conv1d(xc, w, b, stride, padding))
        ctx.save_for_backward(xc, weight)
        ctx.conf = (stride, padding, output_padding, transposed, bias is not None, x.dtype)
        return y

    @staticmethod
    def backward(ctx, grad_y):
        xc, weight = ctx.saved_tensors
        stride, padding, output_padding, transposed, has_bias, x_dtype = ctx.conf
        need = [ctx.needs_input_grad[0], ctx.needs_input_grad[1], has_bias and ctx.needs_input_grad[2]]
        bias_size = [weight.shape[1 if transposed else 0]] if has_bias else None
        gx, gw, gb = torch.ops.aten.convolution_backward(
            grad_y.to(xc.dtype), xc, weight.to(xc.dtype), bias_size, [stride], [padding], [1], transposed,
            [output_padding], 1, need)
        return (None if gx is None else gx.to(x_dtype), None if gw is None else gw.to(weight.dtype),
                None if gb is None else gb.to(weight.dtype), None, None, None, None, None)


def _recording_on_cpu(layer: nn.Module, x: torch.Tensor) -> bool:
    """A gradient is recorded through `layer` (its input or its weight needs one), on the CPU."""
    return torch.is_grad_enabled() and (x.requires_grad or layer.weight.requires_grad) and x.device.type == "cpu"


def _plain_conv(layer: nn.Module, x: torch.Tensor) -> bool:
    """A 1-d convolution of the form the training Functions cover: (B, C, T) input, groups 1, no
    dilation, zero padding given as a number."""
    return (x.dim() == 3 and layer.groups == 1 and layer.dilation == (1,) and layer.padding_mode == "zeros"
            and not isinstance(layer.padding, str))


def _cast_ok(layer: nn.Module, x: torch.Tensor) -> bool:
    """CPU autocast with a gradient recorded, a float32 weight: the layer goes through its Cast Function."""
    return _recording_on_cpu(layer, x) and torch.is_autocast_enabled("cpu") and layer.weight.dtype == torch.float32


class TrainConvTranspose1d(nn.ConvTranspose1d):
    """nn.ConvTranspose1d through CastConv1dFunction under CPU autocast; the stock forward otherwise."""

    @classmethod
    def from_stock(cls, conv: nn.ConvTranspose1d) -> TrainConvTranspose1d:
        fast = cls(conv.in_channels, conv.out_channels, conv.kernel_size, conv.stride, conv.padding,
                   conv.output_padding, conv.groups, conv.bias is not None, conv.dilation, conv.padding_mode,
                   device="meta")
        fast.weight, fast.bias = conv.weight, conv.bias
        return fast.train(conv.training)

    def forward(self, x: torch.Tensor, output_size=None) -> torch.Tensor:
        if output_size is None and _cast_ok(self, x) and _plain_conv(self, x):
            return CastConv1dFunction.apply(x, self.weight, self.bias, self.stride[0], self.padding[0],
                                            self.output_padding[0], True, torch.get_autocast_dtype("cpu"))
        return super().forward(x, output_size)


class CastLinearFunction(torch.autograd.Function):
    """F.linear under CPU autocast as autocast computes it (input, weight and bias cast, the same
    products forward and backward), keeping the float32 weight for the backward instead of its
    copy: CastConv1dFunction's saving for the attention and AdaGN projections."""

    @staticmethod
    def forward(ctx, x, weight, bias, dtype: torch.dtype):
        with torch.autocast("cpu", enabled=False):
            xc = x.to(dtype)
            y = F.linear(xc, weight.to(dtype), None if bias is None else bias.to(dtype))
        ctx.save_for_backward(xc, weight)
        ctx.conf = (bias is not None, x.dtype)
        return y

    @staticmethod
    def backward(ctx, grad_y):
        xc, weight = ctx.saved_tensors
        has_bias, x_dtype = ctx.conf
        g = grad_y.to(xc.dtype)
        gx = gw = gb = None
        if ctx.needs_input_grad[0]:
            gx = (g @ weight.to(xc.dtype)).to(x_dtype)
        rows = g.reshape(-1, g.shape[-1])  # (N, O)
        if ctx.needs_input_grad[1]:
            gw = (rows.t() @ xc.reshape(-1, xc.shape[-1])).to(weight.dtype)
        if has_bias and ctx.needs_input_grad[2]:
            gb = rows.sum(0).to(weight.dtype)
        return gx, gw, gb, None


class TrainLinear(nn.Linear):
    """nn.Linear through CastLinearFunction under CPU autocast with a gradient recorded; the stock
    forward otherwise."""

    @classmethod
    def from_stock(cls, linear: nn.Linear) -> TrainLinear:
        fast = cls(linear.in_features, linear.out_features, linear.bias is not None, device="meta")
        fast.weight, fast.bias = linear.weight, linear.bias
        return fast.train(linear.training)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if _cast_ok(self, x):
            return CastLinearFunction.apply(x, self.weight, self.bias, torch.get_autocast_dtype("cpu"))
        return super().forward(x)


class TrainConv1d(nn.Conv1d):
    """nn.Conv1d through GemmConv1dFunction while a gradient is recorded (CPU, float32/float64,
    groups 1, no dilation, zero padding), through CastConv1dFunction under CPU autocast; the stock
    forward otherwise (inference, CUDA, other layouts)."""

    gemm = True

    @classmethod
    def from_stock(cls, conv: nn.Conv1d, gemm: bool = True) -> TrainConv1d:
        """gemm False: oneDNN's convolution in float32 too (the faster one on some CPUs); the
        autocast path is the same either way."""
        fast = cls(conv.in_channels, conv.out_channels, conv.kernel_size, conv.stride, conv.padding, conv.dilation,
                   conv.groups, conv.bias is not None, conv.padding_mode, device="meta")
        fast.weight, fast.bias = conv.weight, conv.bias
        fast.gemm = bool(gemm)
        return fast.train(conv.training)

    def _gemm_ok(self, x: torch.Tensor) -> bool:
        # CPU only: measured against oneDNN's convolution here; cuDNN's is another matter (not measured)
        return (self.gemm and _recording_on_cpu(self, x) and _plain_conv(self, x)
                and x.dtype in (torch.float32, torch.float64) and x.dtype == self.weight.dtype
                and not torch.is_autocast_enabled(x.device.type))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if _cast_ok(self, x) and _plain_conv(self, x):
            return CastConv1dFunction.apply(x, self.weight, self.bias, self.stride[0], self.padding[0], 0, False,
                                            torch.get_autocast_dtype("cpu"))
        if not self._gemm_ok(x):
            return super().forward(x)
        return GemmConv1dFunction.apply(x, self.weight, self.bias, self.stride[0], self.padding[0])


class TrainMish(nn.Mish):
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return train_mish(x)


def _low_memory_ok(x: torch.Tensor) -> bool:
    """The recomputing layers below apply: a gradient is recorded for a float32/float64 CPU tensor
    outside autocast (elsewhere the stock computation runs)."""
    return (torch.is_grad_enabled() and x.requires_grad and x.device.type == "cpu"
            and x.dtype in (torch.float32, torch.float64) and not torch.is_autocast_enabled("cpu"))


class NormMishFunction(torch.autograd.Function):
    """mish(frame_norm(x) * weight + bias) keeping only x for the backward.

    The stock chain (layer_norm over each frame's channel groups, the affine with AdaGN folded in,
    Mish) saves three tensors of x's size: the norm's input, its normalised output (for the
    affine's weight gradient) and the affine's output (for Mish). This saves the input alone and
    makes the other two again in the backward from it (one layer_norm and one affine pass): the
    forward is the unfused training layers' (norm, then MishFunction) bit for bit, the backward
    PyTorch's own layer_norm backward plus the affine's and Mish's derivatives.

    x: (B, C, T); weight, bias: (B or 1, 1, C), the affine per frame and channel (frames-major) ->
    (B, C, T), a view of a frames-major (B, T, C) tensor."""

    @staticmethod
    def forward(ctx, x, weight, bias, groups: int, eps: float):
        B, C, T = x.shape
        y, _, _ = torch.native_layer_norm(x.transpose(1, 2).reshape(B, T, groups, C // groups), (C // groups,),
                                          None, None, eps)
        ctx.save_for_backward(x, weight, bias)
        ctx.conf = (groups, eps)
        return _mish_values(torch.addcmul(bias, y.view(B, T, C), weight)).transpose(1, 2)

    @staticmethod
    def backward(ctx, grad):
        x, weight, bias = ctx.saved_tensors
        groups, eps = ctx.conf
        B, C, T = x.shape
        frames = x.transpose(1, 2).reshape(B, T, groups, C // groups)  # a view when x is frames-major
        y, mean, rstd = torch.native_layer_norm(frames, (C // groups,), None, None, eps)  # made again
        y = y.view(B, T, C)
        g_z = _mish_grad(torch.addcmul(bias, y, weight)).mul_(grad.transpose(1, 2))  # (B, T, C)
        g_w = (g_z * y).sum_to_size(weight.shape) if ctx.needs_input_grad[1] else None
        g_b = g_z.sum_to_size(bias.shape) if ctx.needs_input_grad[2] else None
        g_x = None
        if ctx.needs_input_grad[0]:
            g_y = g_z.mul_(weight).view(B, T, groups, C // groups)
            g_x = torch.ops.aten.native_layer_norm_backward(g_y, frames, [C // groups], mean, rstd, None, None,
                                                            [True, False, False])[0]
            g_x = g_x.view(B, T, C).transpose(1, 2)
        return g_x, g_w, g_b, None, None


def train_norm_mish(norm: MaskedGroupNorm, x: torch.Tensor, mask: torch.Tensor, scale: torch.Tensor | None = None,
                    shift: torch.Tensor | None = None) -> torch.Tensor:
    """mish(norm(x, mask, scale, shift)) (AdaGN: scale, shift (B, C, 1)); through NormMishFunction
    for the frame norm while a gradient is recorded on the CPU, the stock ops otherwise."""
    if norm.mode != "frame" or not _low_memory_ok(x) or x.dtype != norm.weight.dtype:
        return train_mish(norm(x, mask, scale, shift))
    weight, bias = norm.weight[:, None], norm.bias[:, None]  # (C, 1), as MaskedGroupNorm folds them
    if scale is not None:
        weight, bias = weight * scale, torch.addcmul(shift, bias, scale)  # (B, C, 1)
    return NormMishFunction.apply(x, weight.transpose(-1, -2), bias.transpose(-1, -2), norm.num_groups, norm.eps)


class DropoutFunction(torch.autograd.Function):
    """Dropout saving a bool mask (1 byte per element) for the backward instead of the float
    noise (4 bytes) PyTorch's CPU dropout keeps; the same draw (empty_like(x).bernoulli_(1 - p),
    divided by 1 - p, times x) and so the same output, bit for bit, from the same generator."""

    @staticmethod
    def forward(ctx, x, p: float):
        noise = torch.empty_like(x).bernoulli_(1 - p).div_(1 - p)
        ctx.save_for_backward(noise != 0)
        ctx.scale = torch.ones((), dtype=x.dtype).div_(1 - p)  # the kept entries' factor, as in noise
        return x * noise

    @staticmethod
    def backward(ctx, grad):
        (keep,) = ctx.saved_tensors
        return grad * keep * ctx.scale, None


class TrainDropout(nn.Dropout):
    """nn.Dropout through DropoutFunction while a gradient is recorded on the CPU (training mode,
    0 < p < 1, not in place); the stock dropout otherwise."""

    @classmethod
    def from_stock(cls, stock: nn.Dropout) -> TrainDropout:
        return cls(stock.p, stock.inplace).train(stock.training)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if (self.training and 0.0 < self.p < 1.0 and not self.inplace and torch.is_grad_enabled()
                and x.requires_grad and x.device.type == "cpu" and x.is_floating_point()):
            return DropoutFunction.apply(x, self.p)
        return super().forward(x)


class DeferredContext:
    """A cross-attention's text context, made where the attention first reads it instead of in
    `prepare` (same ops, same inputs, same values).

    Why: `CondUNet1D.prepare` makes all 18 contexts of the paper UNet before the forward, so their
    autograd nodes are the oldest of the step, and the backward (which runs the newest ready node
    first) leaves them, their saved tensors and their incoming gradients until the very end, when
    every weight gradient is alive too: ~130 MiB of saved tensors and 72 MiB of (B, H, d, d)
    gradients at the paper config, batch 8, at the step's peak. Made at the read, each context's
    backward runs right after its attention's. The context is made under the grad mode of
    `prepare` (with grad, outside autocast: the only case deferred) and kept, so several readers
    share one, as they would share the tensor."""

    def __init__(self, attn: LinearCrossAttention, text: torch.Tensor, text_mask: torch.Tensor):
        self.attn, self.text, self.text_mask = attn, text, text_mask
        self.value: torch.Tensor | None = None

    def get(self) -> torch.Tensor:
        if self.value is None:
            with torch.enable_grad(), torch.autocast("cpu", enabled=False):
                self.value = LinearCrossAttention.context(self.attn, self.text, self.text_mask)
        return self.value


class TrainLinearCrossAttention(LinearCrossAttention):
    """LinearCrossAttention whose `context` is a DeferredContext while a gradient is recorded on
    the CPU outside autocast (stock otherwise); the same children and parameters."""

    def __init__(self, stock: LinearCrossAttention):
        nn.Module.__init__(self)
        adopt(self, stock)
        self.num_heads = stock.num_heads

    def context(self, text: torch.Tensor, text_mask: torch.Tensor):
        if (torch.is_grad_enabled() and text.device.type == "cpu" and not torch.is_autocast_enabled("cpu")
                and (text.requires_grad or any(p.requires_grad for p in self.parameters()))):
            return DeferredContext(self, text, text_mask)
        return super().context(text, text_mask)

    def read(self, q_logits: torch.Tensor, context) -> torch.Tensor:
        return super().read(q_logits, context.get() if isinstance(context, DeferredContext) else context)


def _all_valid(mask: torch.Tensor) -> bool:
    """True when no frame is padding, so zeroing the padded frames would only copy the tensor. Only
    asked on the CPU, where it costs a few microseconds (on a GPU it would be a synchronisation)."""
    return mask.device.type == "cpu" and bool(mask.all())


def pad_zero(x: torch.Tensor, mask: torch.Tensor, full: bool) -> torch.Tensor:
    """zero_pad_bct, skipped (x itself) when the batch has no padding (`full`)."""
    return x if full else zero_pad_bct(x, mask)


class TrainResBlock1D(ResBlock1D):
    """ResBlock1D with the vectorised Mish backward and no masking pass for a batch without padding;
    the same children and parameters (state_dict unchanged)."""

    def __init__(self, stock: ResBlock1D):
        nn.Module.__init__(self)
        adopt(self, stock)

    def forward(self, x: torch.Tensor, adagn: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        full = _all_valid(mask)
        scale, shift = adagn[:, :, None].chunk(2, dim=1)  # (B, C_out, 1) each
        h = pad_zero(train_norm_mish(self.norm1, self.conv1(x), mask, 1 + scale, shift), mask, full)
        return pad_zero(train_norm_mish(self.norm2, self.conv2(self.dropout(h)), mask) + self.skip(x), mask, full)


class TrainCondUNet1D(CondUNet1D):
    """CondUNet1D whose output head's norm + Mish is train_norm_mish; same children and parameters."""

    def __init__(self, stock: CondUNet1D):
        adopt_unet(self, stock)

    def head(self, h: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        if self.final_conv is not None:  # the official layout's head is the 1x1 convolution alone
            h = zero_pad_bct(train_norm_mish(self.final_norm, self.final_conv(h), mask), mask)
        return zero_pad_bct(self.out(h), mask)


def accelerate_training(model: nn.Module, gemm_conv: bool = True) -> nn.Module:
    """Swap, in place and children first, nn.Conv1d -> TrainConv1d (its float32 GEMMs unless
    `gemm_conv` is False: oneDNN's convolution, the faster one on some CPUs, docs/training.md),
    nn.Linear -> TrainLinear and nn.ConvTranspose1d -> TrainConvTranspose1d (autocast only), nn.Mish ->
    TrainMish, nn.Dropout -> TrainDropout, LinearCrossAttention -> TrainLinearCrossAttention and the
    UNet's ResBlock1D / CondUNet1D -> TrainResBlock1D / TrainCondUNet1D (exact types only: an
    already swapped or subclassed layer is left alone). Returns the model (a replacement when
    `model` itself is such a layer). Parameters and state_dict keys are unchanged."""
    from stablemo.fast import swap_layers

    table = {nn.Mish: lambda stock: TrainMish(), nn.Dropout: TrainDropout.from_stock, ResBlock1D: TrainResBlock1D,
             LinearCrossAttention: TrainLinearCrossAttention, CondUNet1D: TrainCondUNet1D,
             nn.Conv1d: lambda stock: TrainConv1d.from_stock(stock, gemm=gemm_conv), nn.Linear: TrainLinear.from_stock,
             nn.ConvTranspose1d: TrainConvTranspose1d.from_stock}
    return swap_layers(model, table)
