// Fused CPU kernel for the finishing step (stablemo.inference.finish), built on first use by
// stablemo.fast.kernels.motion_kernels().
//
// frame_columns: the feature columns after the root's rotation and velocity (root height, ric, 6D
// rotations, local velocities, foot contacts) of one frame of a joint-major motion (J, 3, B, T).
// The PyTorch twin (stablemo.motion.extract_torch.body_columns) makes ~150 passes over the batch,
// one per elementwise step, and was half of the step's time; here each frame's joints stay in
// registers. Every expression is the twin's, in its order, and the build does not contract or
// reorder floating point (-ffp-contract=off, no -ffast-math): the two agree to the last bit or two
// (the twin's reductions may sum in another order), and the ric columns exactly.

#include <torch/extension.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <vector>

namespace {

template <typename S>
struct Quat {
  S w, x, y, z;
};

// qbetween's shortest arc from direction a to b, with its half turn where they are (nearly) opposite
template <typename S>
Quat<S> between(const S* a, S bx, S by, S bz) {
  const S ax = a[0], ay = a[1], az = a[2];
  const S scale = std::sqrt((ax * ax + ay * ay + az * az) * (bx * bx + by * by + bz * bz));
  const S w = scale + (ax * bx + ay * by + az * bz);
  const S cx = ay * bz - az * by, cy = az * bx - ax * bz, cz = ax * by - ay * bx;
  const S size = std::sqrt(w * w + cx * cx + cy * cy + cz * cz);
  const S floor = scale < S(1e-30) ? S(1e-30) : scale;
  if (!(size <= S(1e-9) * floor) && size != S(0)) return {w / size, cx / size, cy / size, cz / size};
  // an axis perpendicular to a: a × the coordinate axis least aligned with it (the first on ties)
  const S m[3] = {std::abs(ax), std::abs(ay), std::abs(az)};
  const int k = m[1] < m[0] ? (m[2] < m[1] ? 2 : 1) : (m[2] < m[0] ? 2 : 0);
  const S h[3] = {S(k == 0), S(k == 1), S(k == 2)};
  const S px = ay * h[2] - az * h[1], py = az * h[0] - ax * h[2], pz = ax * h[1] - ay * h[0];
  const S n = std::sqrt(px * px + py * py + pz * pz);
  return {S(0), px / n, py / n, pz / n};
}

template <typename S>
void frame_columns(const S* x, const S* r, const int64_t* parent, const S* raw, const int64_t* before,
                   const int64_t* contact, int64_t contacts, S threshold, int64_t J, int64_t BT, int64_t T,
                   int64_t row, S* out, std::vector<Quat<S>>& swing) {
  // row: b * T + t of the frame; joint j's coordinate c at frame t + dt is x[(j * 3 + c) * BT + row + dt]
  auto at = [&](int64_t j, int64_t c, int64_t dt) { return x[(j * 3 + c) * BT + row + dt]; };
  const S* q = r + row * 4;
  const S c = q[0] * q[0] - q[2] * q[2];  // yaw_rotate: the root's turn about y
  const S s = S(2) * q[0] * q[2];
  S* o = out;
  *o++ = at(0, 1, 0);  // root height
  const S rx = at(0, 0, 0), rz = at(0, 2, 0);
  for (int64_t j = 1; j < J; ++j) {  // ric: root-relative in xz, absolute height, turned
    const S vx = at(j, 0, 0) - rx, vy = at(j, 1, 0), vz = at(j, 2, 0) - rz;
    *o++ = c * vx + s * vz;
    *o++ = vy;
    *o++ = c * vz - s * vx;
  }
  for (int64_t i = 0; i < J - 1; ++i) {  // bone i ends at joint i + 1
    const int64_t j = i + 1, p = parent[j];
    swing[i] = between(raw + j * 3, at(j, 0, 0) - at(p, 0, 0), at(j, 1, 0) - at(p, 1, 0), at(j, 2, 0) - at(p, 2, 0));
  }
  for (int64_t i = 0; i < J - 1; ++i) {  // local = (previous swing, or r)^-1 * swing, as 6D
    const Quat<S> a = before[i] == J - 1 ? Quat<S>{q[0], q[1], q[2], q[3]} : swing[before[i]];
    const S w1 = a.w, x1 = -a.x, y1 = -a.y, z1 = -a.z;
    const Quat<S>& b = swing[i];
    const S w = w1 * b.w - x1 * b.x - y1 * b.y - z1 * b.z;
    const S x2 = w1 * b.x + x1 * b.w + y1 * b.z - z1 * b.y;
    const S y2 = w1 * b.y - x1 * b.z + y1 * b.w + z1 * b.x;
    const S z2 = w1 * b.z + x1 * b.y - y1 * b.x + z1 * b.w;
    *o++ = S(1) - S(2) * (y2 * y2 + z2 * z2);
    *o++ = S(2) * (x2 * y2 + w * z2);
    *o++ = S(2) * (x2 * z2 - w * y2);
    *o++ = S(2) * (x2 * y2 - w * z2);
    *o++ = S(1) - S(2) * (x2 * x2 + z2 * z2);
    *o++ = S(2) * (y2 * z2 + w * x2);
  }
  for (int64_t j = 0; j < J; ++j) {  // local velocities, turned
    const S vx = at(j, 0, 1) - at(j, 0, 0), vy = at(j, 1, 1) - at(j, 1, 0), vz = at(j, 2, 1) - at(j, 2, 0);
    *o++ = c * vx + s * vz;
    *o++ = vy;
    *o++ = c * vz - s * vx;
  }
  for (int64_t k = 0; k < contacts; ++k) {  // foot contacts: moved less than the threshold
    const int64_t j = contact[k];
    const S dx = at(j, 0, 1) - at(j, 0, 0), dy = at(j, 1, 1) - at(j, 1, 0), dz = at(j, 2, 1) - at(j, 2, 0);
    *o++ = (dx * dx + dy * dy + dz * dz) < threshold ? S(1) : S(0);
  }
}

// finish_rows: the finishing step's output in one pass: per frame, the kept leading columns lead
// (B, T-1, L) (the root's rotation and path), then body_columns, and the joints recovered from those
// features (features_to_joints, its expressions in its order: the written joints are the features'
// recovery) given the recovered root path root (B, T-1, 3); frames from n[b] on are zero in both.
torch::Tensor finish_rows(torch::Tensor x, torch::Tensor r, torch::Tensor lead, torch::Tensor n, torch::Tensor root,
                          torch::Tensor parent, torch::Tensor raw, torch::Tensor before, torch::Tensor contact,
                          double threshold, torch::Tensor joints) {
  TORCH_CHECK(x.dim() == 4 && x.size(1) == 3 && x.is_contiguous() && x.device().is_cpu() && x.size(3) >= 2,
              "finish_rows: x must be a contiguous (J, 3, B, T) CPU tensor, T >= 2");
  const int64_t J = x.size(0), B = x.size(2), T = x.size(3);
  TORCH_CHECK(r.dim() == 3 && r.size(0) == B && r.size(1) == T && r.size(2) == 4 && r.is_contiguous() &&
                  r.scalar_type() == x.scalar_type(),
              "finish_rows: r must be a contiguous (B, T, 4) tensor of x's dtype");
  TORCH_CHECK(lead.dim() == 3 && lead.size(0) == B && lead.size(1) == T - 1 && lead.is_contiguous() &&
                  lead.scalar_type() == x.scalar_type() && root.dim() == 3 && root.size(0) == B &&
                  root.size(1) == T - 1 && root.size(2) == 3 && root.is_contiguous() &&
                  root.scalar_type() == x.scalar_type() && n.numel() == B && n.scalar_type() == torch::kLong &&
                  n.is_contiguous(),
              "finish_rows: lead (B, T-1, L), root (B, T-1, 3) of x's dtype and n (B,) long expected");
  TORCH_CHECK(joints.dim() == 4 && joints.size(0) == B && joints.size(1) == T - 1 && joints.size(2) == J &&
                  joints.size(3) == 3 && joints.is_contiguous() && joints.scalar_type() == x.scalar_type(),
              "finish_rows: joints must be a contiguous (B, T-1, J, 3) tensor of x's dtype");
  TORCH_CHECK(parent.numel() == J && before.numel() == J - 1 && raw.numel() == J * 3 &&
                  parent.scalar_type() == torch::kLong && before.scalar_type() == torch::kLong &&
                  contact.scalar_type() == torch::kLong && raw.scalar_type() == x.scalar_type() &&
                  parent.is_contiguous() && before.is_contiguous() && contact.is_contiguous() && raw.is_contiguous(),
              "finish_rows: skeleton tables of the wrong size or type");
  const int64_t contacts = contact.numel(), L = lead.size(2);
  const int64_t D = L + 1 + 3 * (J - 1) + 6 * (J - 1) + 3 * J + contacts;
  auto out = torch::empty({B, T - 1, D}, x.options());
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "finish_rows", [&] {
    const scalar_t* xp = x.data_ptr<scalar_t>();
    const scalar_t* rp = r.data_ptr<scalar_t>();
    const scalar_t* lp = lead.data_ptr<scalar_t>();
    const scalar_t* rootp = root.data_ptr<scalar_t>();
    const scalar_t* rawp = raw.data_ptr<scalar_t>();
    const int64_t* np_ = n.data_ptr<int64_t>();
    const int64_t* pp = parent.data_ptr<int64_t>();
    const int64_t* bp = before.data_ptr<int64_t>();
    const int64_t* cp = contact.data_ptr<int64_t>();
    scalar_t* op = out.data_ptr<scalar_t>();
    scalar_t* jp = joints.data_ptr<scalar_t>();
    const scalar_t thr = static_cast<scalar_t>(threshold);
    at::parallel_for(0, B * (T - 1), 64, [&](int64_t begin, int64_t end) {
      std::vector<Quat<scalar_t>> swing(J - 1);
      for (int64_t i = begin; i < end; ++i) {
        const int64_t b = i / (T - 1), t = i % (T - 1);
        scalar_t* o = op + i * D;
        scalar_t* jo = jp + i * J * 3;
        if (t >= np_[b]) {  // padding
          std::fill(o, o + D, scalar_t(0));
          std::fill(jo, jo + J * 3, scalar_t(0));
          continue;
        }
        std::copy(lp + i * L, lp + (i + 1) * L, o);
        frame_columns<scalar_t>(xp, rp, pp, rawp, bp, cp, contacts, thr, J, B * T, T, b * T + t, o + L, swing);
        // features_to_joints: the root where recover_root puts it (its height the features'), each
        // other joint its ric turned back by the root's inverse rotation and moved by the root in xz
        const scalar_t* q = rp + (b * T + t) * 4;
        const scalar_t qy = q[2] * scalar_t(-1);
        const scalar_t c = q[0] * q[0] - qy * qy, s = scalar_t(2) * q[0] * qy;
        const scalar_t* pos = rootp + i * 3;
        const scalar_t height = o[L];
        jo[0] = pos[0];
        jo[1] = height;
        jo[2] = pos[2];
        const scalar_t ox = pos[0] * scalar_t(1), oy = height * scalar_t(0), oz = pos[2] * scalar_t(1);
        for (int64_t j = 1; j < J; ++j) {
          const scalar_t* v = o + L + 1 + (j - 1) * 3;
          jo[j * 3 + 0] = (c * v[0] + s * v[2]) + ox;
          jo[j * 3 + 1] = v[1] + oy;
          jo[j * 3 + 2] = (c * v[2] - s * v[0]) + oz;
        }
      }
    });
  });
  return out;
}

// place_body: the rigid rebuild's placement (stablemo.motion.rigid.rigid_joint_major, after the
// branching joints' shapes and the root's height): per frame, every bone's step (the body's length
// along its generated direction, or a branching joint's turned shape), the trunk from its parents,
// each two-bone limb pulled towards its goal (rigid.two_bone's expressions in its order), then the
// joints past the limbs' ends. In PyTorch these are ~200 operations, a few on all joints at once.
template <typename S>
void place_frame(const S* x, const S* turned, const int64_t* turned_of, const S* raw, const S* root, const S* forward,
                 const S* w, const S* goal, const int64_t* parent, const int64_t* trunk, int64_t nt,
                 const int64_t* limb, const S* side, const S* rest, const S* len, int64_t nl, const int64_t* beyond,
                 int64_t nb, int64_t J, int64_t BT, int64_t e, S* out) {
  const S eps = S(1e-9);
  S ST[64][3];
  for (int64_t j = 1; j < J; ++j) {  // rigid._unit of the bone, its rest direction where it has none
    S d[3];
    if (turned_of[j] >= 0) {
      for (int c = 0; c < 3; ++c) d[c] = turned[(turned_of[j] * 3 + c) * BT + e];
    } else {
      const int64_t p = parent[j];
      S v[3];
      for (int c = 0; c < 3; ++c) v[c] = x[(j * 3 + c) * BT + e] - x[(p * 3 + c) * BT + e];
      const S size = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
      const S sc = size < eps ? eps : size;
      for (int c = 0; c < 3; ++c) d[c] = size > eps ? v[c] / sc : raw[j * 3 + c];
    }
    for (int c = 0; c < 3; ++c) ST[j][c] = len[j] * d[c];
  }
  auto step = [&](int64_t j, int64_t c) { return ST[j][c]; };
  S P[64][3];
  for (int c = 0; c < 3; ++c) P[0][c] = root[c * BT + e];
  for (int64_t k = 0; k < nt; ++k) {
    const int64_t j = trunk[k], p = parent[j];
    for (int c = 0; c < 3; ++c) P[j][c] = P[p][c] + step(j, c);
  }
  for (int64_t l = 0; l < nl; ++l) {
    const int64_t up = limb[l * 3], mid = limb[l * 3 + 1], end = limb[l * 3 + 2];
    const S l1 = len[mid], l2 = len[end], wl = w[l * BT + e];
    S upper[3], middle[3], target[3], fb[3];
    for (int c = 0; c < 3; ++c) {
      upper[c] = P[up][c];
      middle[c] = upper[c] + step(mid, c);
      const S kept = middle[c] + step(end, c);
      target[c] = kept + wl * (goal[(l * 3 + c) * BT + e] - kept);
      fb[c] = side[l] * forward[c * BT + e];
    }
    // two_bone
    S v[3], aim[3];
    for (int c = 0; c < 3; ++c) v[c] = target[c] - upper[c];
    const S dist = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    const S dcl = dist < eps ? eps : dist;
    for (int c = 0; c < 3; ++c) aim[c] = dist > eps ? v[c] / dcl : rest[l * 3 + c];
    const S lo = std::abs(l1 - l2) + S(1e-6), hi = l1 + l2;
    const S d = std::min(std::max(dist, lo), hi);
    S tp[3], bend[3], alt[3];
    for (int c = 0; c < 3; ++c) tp[c] = middle[c] - upper[c];
    const S dp = tp[0] * aim[0] + tp[1] * aim[1] + tp[2] * aim[2];
    for (int c = 0; c < 3; ++c) bend[c] = tp[c] - dp * aim[c];
    const S across = std::sqrt(bend[0] * bend[0] + bend[1] * bend[1] + bend[2] * bend[2]);
    const S acl = across < eps ? eps : across;
    const S df = fb[0] * aim[0] + fb[1] * aim[1] + fb[2] * aim[2];
    for (int c = 0; c < 3; ++c) alt[c] = fb[c] - df * aim[c];
    const S an = std::sqrt(alt[0] * alt[0] + alt[1] * alt[1] + alt[2] * alt[2]);
    const S ancl = an < eps ? eps : an;
    const bool use_bend = across > S(1e-4) * l1;
    for (int c = 0; c < 3; ++c) bend[c] = use_bend ? bend[c] / acl : alt[c] / ancl;
    S cos_a = (l1 * l1 + d * d - l2 * l2) / (S(2) * l1 * d);
    cos_a = std::min(std::max(cos_a, S(-1)), S(1));
    S sin2 = S(1) - cos_a * cos_a;
    const S sin_a = std::sqrt(sin2 < S(0) ? S(0) : sin2);
    for (int c = 0; c < 3; ++c) {
      P[mid][c] = upper[c] + l1 * (cos_a * aim[c] + sin_a * bend[c]);
      P[end][c] = upper[c] + d * aim[c];
    }
  }
  for (int64_t k = 0; k < nb; ++k) {
    const int64_t j = beyond[k], p = parent[j];
    for (int c = 0; c < 3; ++c) P[j][c] = P[p][c] + step(j, c);
  }
  for (int64_t j = 0; j < J; ++j)
    for (int c = 0; c < 3; ++c) out[(j * 3 + c) * BT + e] = P[j][c];
}

torch::Tensor place_body(torch::Tensor x, torch::Tensor turned, torch::Tensor turned_of, torch::Tensor raw,
                         torch::Tensor root, torch::Tensor forward, torch::Tensor w, torch::Tensor goal,
                         torch::Tensor parent, torch::Tensor trunk, torch::Tensor limb, torch::Tensor side,
                         torch::Tensor rest, torch::Tensor len, torch::Tensor beyond) {
  TORCH_CHECK(x.dim() == 4 && x.size(1) == 3 && x.is_contiguous() && x.device().is_cpu() && x.size(0) <= 64,
              "place_body: x must be a contiguous (J, 3, B, T) CPU tensor, J <= 64");
  const int64_t J = x.size(0), B = x.size(2), T = x.size(3), BT = B * T, L = limb.size(0);
  for (const auto& t : {turned, raw, root, forward, w, goal, side, rest, len})
    TORCH_CHECK(t.is_contiguous() && t.scalar_type() == x.scalar_type(), "place_body: inputs of x's dtype");
  for (const auto& t : {turned_of, parent, trunk, limb, beyond})
    TORCH_CHECK(t.is_contiguous() && t.scalar_type() == torch::kLong, "place_body: index tables must be long");
  TORCH_CHECK(root.numel() == 3 * BT && forward.numel() == 3 * BT && w.numel() == L * BT && goal.numel() == L * 3 * BT &&
                  parent.numel() == J && turned_of.numel() == J && raw.numel() == J * 3 && limb.dim() == 2 &&
                  limb.size(1) == 3 && side.numel() == L && rest.numel() == L * 3 && len.numel() == J &&
                  turned.numel() % (3 * BT) == 0,
              "place_body: inputs of the wrong size");
  const int64_t* to = turned_of.data_ptr<int64_t>();
  for (int64_t j = 0; j < J; ++j)
    TORCH_CHECK(to[j] < turned.numel() / (3 * BT), "place_body: turned_of points past turned");
  auto out = torch::empty_like(x);
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "place_body", [&] {
    const scalar_t *xp = x.data_ptr<scalar_t>(), *tdp = turned.data_ptr<scalar_t>(), *rawp = raw.data_ptr<scalar_t>();
    const scalar_t *rp = root.data_ptr<scalar_t>(), *fp = forward.data_ptr<scalar_t>();
    const scalar_t *wp = w.data_ptr<scalar_t>(), *gp = goal.data_ptr<scalar_t>(), *sidep = side.data_ptr<scalar_t>();
    const scalar_t *restp = rest.data_ptr<scalar_t>(), *lenp = len.data_ptr<scalar_t>();
    const int64_t *pp = parent.data_ptr<int64_t>(), *tp = trunk.data_ptr<int64_t>(), *lp = limb.data_ptr<int64_t>();
    const int64_t* bp = beyond.data_ptr<int64_t>();
    scalar_t* op = out.data_ptr<scalar_t>();
    at::parallel_for(0, BT, 256, [&](int64_t begin, int64_t end) {
      for (int64_t e = begin; e < end; ++e)
        place_frame<scalar_t>(xp, tdp, to, rawp, rp, fp, wp, gp, pp, tp, trunk.numel(), lp, sidep, restp, lenp, L, bp,
                              beyond.numel(), J, BT, e, op);
    });
  });
  return out;
}

}  // namespace

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("place_body", &place_body, "the rigid rebuild's placement of trunk, limbs (two-bone IK) and feet, one pass",
        py::arg("x"), py::arg("turned"), py::arg("turned_of"), py::arg("raw"), py::arg("root"), py::arg("forward"),
        py::arg("w"), py::arg("goal"), py::arg("parent"), py::arg("trunk"), py::arg("limb"), py::arg("side"),
        py::arg("rest"), py::arg("len"), py::arg("beyond"));
  m.def("finish_rows", &finish_rows, "lead columns, body columns and recovered joints of the finishing step, one pass",
        py::arg("x"), py::arg("r"), py::arg("lead"), py::arg("n"), py::arg("root"), py::arg("parent"), py::arg("raw"),
        py::arg("before"), py::arg("contact"), py::arg("threshold"), py::arg("joints"));
}
