// Fused CPU kernels for stablemo.diffusion.accelerate (built on first use by stablemo.diffusion.fused).
//
// frame_norm_act: the UNet's per-frame group norm ("frame" mode of MaskedGroupNorm), its affine
// (per sample, so that AdaGN's scale and shift can be folded in), optionally Mish, a residual and
// the zeroing of padded frames, in one pass over a frames-major (B, T, C) activation. In PyTorch
// the same is ~12 element-wise passes (layer_norm, addcmul, seven for Mish, add, padding), each
// streaming the activation through the caches again.
//
// unfold_same: im2col of a stride-1 'same' convolution in one pass.
//
// read_context: the reading side of LinearCrossAttention (per-head softmax of the query logits and
// the product with each head's text context) in one pass over the frames.

#include <torch/extension.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <vector>

#if defined(__AVX512F__)
#include <immintrin.h>
#endif

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


// Softmax of n logits into p (max-shifted, as torch.softmax).
inline void softmax_row(const float* x, float* p, int64_t n) {
  float top = x[0];
  for (int64_t i = 1; i < n; ++i) top = std::max(top, x[i]);
#pragma omp simd
  for (int64_t i = 0; i < n; ++i) p[i] = expf(x[i] - top);  // its own loop: vectorised (libmvec)
  float sum = 0.f;
#pragma omp simd reduction(+ : sum)
  for (int64_t i = 0; i < n; ++i) sum += p[i];
  const float inv = 1.f / sum;
#pragma omp simd
  for (int64_t i = 0; i < n; ++i) p[i] *= inv;
}

// out rows (rows x d, row stride ld) = p (rows x d, contiguous) @ ctx (d x d, contiguous).
void rows_times_context(const float* p, const float* ctx, float* out, int64_t rows, int64_t d, int64_t ld) {
  int64_t r = 0;
#if defined(__AVX512F__)
  // 6 rows x 64 columns of accumulators (24 of the 32 vector registers): each context row loaded
  // once per 6 output rows, 24 FMAs per 4 loads and 6 broadcasts
  if (d % 64 == 0) {
    const int64_t tiled = rows - rows % 6;
    for (int64_t e = 0; e < d; e += 64) {  // a 64-column slice of the context stays in L1 for all tiles
      for (r = 0; r < tiled; r += 6) {
        __m512 acc[6][4];
        for (int i = 0; i < 6; ++i)
          for (int j = 0; j < 4; ++j) acc[i][j] = _mm512_setzero_ps();
        for (int64_t i = 0; i < d; ++i) {
          const float* c = ctx + i * d + e;
          const __m512 c0 = _mm512_loadu_ps(c), c1 = _mm512_loadu_ps(c + 16), c2 = _mm512_loadu_ps(c + 32),
                       c3 = _mm512_loadu_ps(c + 48);
          for (int k = 0; k < 6; ++k) {
            const __m512 w = _mm512_set1_ps(p[(r + k) * d + i]);
            acc[k][0] = _mm512_fmadd_ps(w, c0, acc[k][0]);
            acc[k][1] = _mm512_fmadd_ps(w, c1, acc[k][1]);
            acc[k][2] = _mm512_fmadd_ps(w, c2, acc[k][2]);
            acc[k][3] = _mm512_fmadd_ps(w, c3, acc[k][3]);
          }
        }
        for (int k = 0; k < 6; ++k)
          for (int j = 0; j < 4; ++j) _mm512_storeu_ps(out + (r + k) * ld + e + 16 * j, acc[k][j]);
      }
    }
    r = tiled;
  }
#endif
  for (; r < rows; ++r) {  // the rows left over (all of them without AVX-512)
    float* o = out + r * ld;
    std::fill(o, o + d, 0.f);
    for (int64_t i = 0; i < d; ++i) {
      const float w = p[r * d + i];
      const float* c = ctx + i * d;
#pragma omp simd
      for (int64_t e = 0; e < d; ++e) o[e] += w * c[e];
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


// im2col of a 'same' convolution (stride 1, k = 2p + 1): frames (B, T, C) float32 with contiguous
// rows -> (B, T, k*C), row t = frames t-p .. t+p flattened, zero outside 0 .. T-1. One pass that
// writes each output row once (PyTorch needs a strided copy plus the padded edge rows).
torch::Tensor unfold_same(const torch::Tensor& frames, int64_t k, int64_t p) {
  TORCH_CHECK(frames.dim() == 3 && frames.scalar_type() == torch::kFloat && frames.device().is_cpu() &&
                  frames.stride(2) == 1 && frames.stride(1) == frames.size(2),
              "unfold_same: frames must be a (B, T, C) float32 CPU tensor with contiguous rows");
  TORCH_CHECK(k == 2 * p + 1 && p >= 0, "unfold_same: needs k = 2p + 1");
  const int64_t B = frames.size(0), T = frames.size(1), C = frames.size(2), sb = frames.stride(0);
  auto out = torch::empty({B, T, k * C}, frames.options());
  const float* src = frames.data_ptr<float>();
  float* dst = out.data_ptr<float>();
  at::parallel_for(0, B * T, 4, [&](int64_t begin, int64_t end) {
    for (int64_t r = begin; r < end; ++r) {
      const int64_t b = r / T, t = r % T;
      float* row = dst + r * k * C;
      for (int64_t j = 0; j < k; ++j) {
        const int64_t s = t - p + j;
        if (s < 0 || s >= T) {
          std::fill(row + j * C, row + (j + 1) * C, 0.f);
        } else {
          std::memcpy(row + j * C, src + b * sb + s * C, C * sizeof(float));
        }
      }
    }
  });
  return out;
}

// The reading side of LinearCrossAttention: query logits (B, T, H*d) with contiguous rows, per-head
// text contexts (B, H, d, d) contiguous -> (B, T, H*d), head h of frame t = softmax(q[t, h]) @
// context[h]. PyTorch needs a softmax pass, permuting copies and a batched product of small
// matrices for this; here each block of frames is read once and written once.
torch::Tensor read_context(const torch::Tensor& q, const torch::Tensor& context) {
  TORCH_CHECK(q.dim() == 3 && q.scalar_type() == torch::kFloat && q.device().is_cpu() && q.stride(2) == 1 &&
                  q.stride(1) == q.size(2),
              "read_context: q must be a (B, T, C) float32 CPU tensor with contiguous rows");
  TORCH_CHECK(context.dim() == 4 && context.is_contiguous() && context.scalar_type() == torch::kFloat &&
                  context.size(0) == q.size(0) && context.size(2) == context.size(3) &&
                  context.size(1) * context.size(2) == q.size(2),
              "read_context: context must be a contiguous (B, H, d, d) float32 tensor with H*d = C");
  const int64_t B = q.size(0), T = q.size(1), C = q.size(2), H = context.size(1), d = context.size(2);
  const int64_t sb = q.stride(0);
  auto out = torch::empty({B, T, C}, q.options());
  const float* qp = q.data_ptr<float>();
  const float* cp = context.data_ptr<float>();
  float* op = out.data_ptr<float>();
  constexpr int64_t kRows = 24;
  const int64_t blocks = (T + kRows - 1) / kRows;
  at::parallel_for(0, B * H * blocks, 1, [&](int64_t begin, int64_t end) {
    std::vector<float> probs(kRows * d);
    for (int64_t task = begin; task < end; ++task) {
      const int64_t b = task / (H * blocks), h = (task / blocks) % H, t0 = (task % blocks) * kRows;
      const int64_t rows = std::min(kRows, T - t0);
      for (int64_t r = 0; r < rows; ++r) softmax_row(qp + b * sb + (t0 + r) * C + h * d, probs.data() + r * d, d);
      rows_times_context(probs.data(), cp + (b * H + h) * d * d, op + (b * T + t0) * C + h * d, rows, d, C);
    }
  });
  return out;
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("frame_norm_act", &frame_norm_act, "per-frame group norm + per-sample affine (+ Mish, + residual), one pass",
        py::arg("x"), py::arg("weight"), py::arg("bias"), py::arg("groups"), py::arg("eps"), py::arg("mish"),
        py::arg("mask") = py::none(), py::arg("residual") = py::none());
  m.def("unfold_same", &unfold_same, "im2col of a stride-1 'same' convolution, one pass",
        py::arg("frames"), py::arg("k"), py::arg("p"));
  m.def("read_context", &read_context, "per-head softmax of query logits times the per-head text contexts",
        py::arg("q"), py::arg("context"));
}
