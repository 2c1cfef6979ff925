// Fused CPU kernels for stablemo.diffusion.accelerate (built on first use by stablemo.diffusion.fused).
//
// frame_norm_act: the UNet's per-frame group norm ("frame" mode of MaskedGroupNorm), its affine
// (per sample, so that AdaGN's scale and shift can be folded in), optionally Mish, a residual and
// the zeroing of padded frames, in one pass over a frames-major (B, T, C) activation. In PyTorch
// the same is ~12 element-wise passes (layer_norm, addcmul, seven for Mish, add, padding), each
// streaming the activation through the caches again.

#include <torch/extension.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>

namespace {

struct Strided {  // a (B, T, ...) operand: base pointer and its batch and frame strides
  const void* data = nullptr;
  int64_t sb = 0, st = 0;
};

template <bool kMish>
void norm_rows(const float* x, float* out, const float* weight, const float* bias, int64_t T, int64_t C,
               int64_t groups, int64_t x_sb, int64_t x_st, int64_t w_sb, int64_t b_sb, float eps,
               Strided mask, Strided residual, int64_t begin, int64_t end) {
  const int64_t width = C / groups;
  for (int64_t r = begin; r < end; ++r) {
    const int64_t b = r / T, t = r % T;
    float* out_row = out + r * C;
    if (mask.data && !static_cast<const bool*>(mask.data)[b * mask.sb + t * mask.st]) {
      std::fill(out_row, out_row + C, 0.f);  // a padded frame: exactly zero, whatever its input
      continue;
    }
    const float* row = x + b * x_sb + t * x_st;
    const float* w_row = weight + b * w_sb;
    const float* b_row = bias + b * b_sb;
    const float* res_row = residual.data ? static_cast<const float*>(residual.data) + b * residual.sb + t * residual.st
                                         : nullptr;
    for (int64_t g = 0; g < groups; ++g) {
      const float* xg = row + g * width;
      float sum = 0.f;
#pragma omp simd reduction(+ : sum)
      for (int64_t i = 0; i < width; ++i) sum += xg[i];
      const float mean = sum / width;
      float squares = 0.f;  // two passes over a group held in L1: no cancellation of E[x^2] - mean^2
#pragma omp simd reduction(+ : squares)
      for (int64_t i = 0; i < width; ++i) {
        const float d = xg[i] - mean;
        squares += d * d;
      }
      const float rstd = 1.f / std::sqrt(squares / width + eps);
      const float* wg = w_row + g * width;
      const float* bg = b_row + g * width;
      float* og = out_row + g * width;
#pragma omp simd
      for (int64_t i = 0; i < width; ++i) {
        float y = (xg[i] - mean) * rstd * wg[i] + bg[i];
        if (kMish) {  // mish(y) = y n / (n + 2), n = e^y (e^y + 2); e^y clamped where mish(y) = y in float32
          const float e = std::exp(std::fmin(y, 20.f));
          const float n = e * (e + 2.f);
          y = y * n / (n + 2.f);
        }
        og[i] = y;
      }
      if (res_row) {
        const float* rg = res_row + g * width;
#pragma omp simd
        for (int64_t i = 0; i < width; ++i) og[i] += rg[i];
      }
    }
  }
}

}  // namespace

// x: (B, T, C) float32 with unit channel stride (any batch and frame strides); weight, bias:
// (B, C) or (1, C) float32 with unit channel stride; mask: optional (B, T) bool, false = padded
// frame (written as zeros); residual: optional (B, T, C) float32 with unit channel stride, added
// after the activation. Returns a new contiguous (B, T, C) tensor.
torch::Tensor frame_norm_act(const torch::Tensor& x, const torch::Tensor& weight, const torch::Tensor& bias,
                             int64_t groups, double eps, bool mish, const c10::optional<torch::Tensor>& mask,
                             const c10::optional<torch::Tensor>& residual) {
  TORCH_CHECK(x.dim() == 3 && x.scalar_type() == torch::kFloat && x.device().is_cpu() && x.stride(2) == 1,
              "frame_norm_act: x must be a (B, T, C) float32 CPU tensor with unit channel stride");
  const int64_t B = x.size(0), T = x.size(1), C = x.size(2);
  TORCH_CHECK(groups > 0 && C % groups == 0, "frame_norm_act: channels not divisible into groups");
  for (const auto* p : {&weight, &bias}) {
    TORCH_CHECK(p->dim() == 2 && (p->size(0) == 1 || p->size(0) == B) && p->size(1) == C && p->stride(1) == 1 &&
                    p->scalar_type() == torch::kFloat && p->device().is_cpu(),
                "frame_norm_act: weight and bias must be (B or 1, C) float32 CPU tensors with unit channel stride");
  }
  Strided mask_view, residual_view;
  if (mask.has_value()) {
    const auto& m = *mask;
    TORCH_CHECK(m.dim() == 2 && m.size(0) == B && m.size(1) == T && m.scalar_type() == torch::kBool && m.device().is_cpu(),
                "frame_norm_act: mask must be a (B, T) bool CPU tensor");
    mask_view = {m.data_ptr<bool>(), m.stride(0), m.stride(1)};
  }
  if (residual.has_value()) {
    const auto& res = *residual;
    TORCH_CHECK(res.dim() == 3 && res.size(0) == B && res.size(1) == T && res.size(2) == C && res.stride(2) == 1 &&
                    res.scalar_type() == torch::kFloat && res.device().is_cpu(),
                "frame_norm_act: residual must be a (B, T, C) float32 CPU tensor with unit channel stride");
    residual_view = {res.data_ptr<float>(), res.stride(0), res.stride(1)};
  }
  auto out = torch::empty({B, T, C}, x.options());
  const float* xp = x.data_ptr<float>();
  const float* wp = weight.data_ptr<float>();
  const float* bp = bias.data_ptr<float>();
  float* op = out.data_ptr<float>();
  const int64_t x_sb = x.stride(0), x_st = x.stride(1);
  const int64_t w_sb = weight.size(0) == 1 ? 0 : weight.stride(0);
  const int64_t b_sb = bias.size(0) == 1 ? 0 : bias.stride(0);
  const float e = static_cast<float>(eps);
  at::parallel_for(0, B * T, 8, [&](int64_t begin, int64_t end) {
    if (mish) {
      norm_rows<true>(xp, op, wp, bp, T, C, groups, x_sb, x_st, w_sb, b_sb, e, mask_view, residual_view, begin, end);
    } else {
      norm_rows<false>(xp, op, wp, bp, T, C, groups, x_sb, x_st, w_sb, b_sb, e, mask_view, residual_view, begin,
                       end);
    }
  });
  return out;
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("frame_norm_act", &frame_norm_act, "per-frame group norm + per-sample affine (+ Mish, + residual), one pass",
        py::arg("x"), py::arg("weight"), py::arg("bias"), py::arg("groups"), py::arg("eps"), py::arg("mish"),
        py::arg("mask") = py::none(), py::arg("residual") = py::none());
}
