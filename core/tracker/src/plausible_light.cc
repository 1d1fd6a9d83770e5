#include "face_reenact/tracker/plausible_light.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <Eigen/Dense>

namespace face_reenact::tracker {
namespace {

constexpr int kDirections = 128;

// The constraint rows a_i: a_i . gamma_c >= 0 <=> E_c(n_i) + kNegativeLobe * gamma_c0 y_0 >= 0,
// for n_i on a Fibonacci sphere (evenly spread, no pole clustering).
const std::vector<std::array<float, gpu::kNumShCoefficients>>& constraint_rows() {
  static const auto rows = [] {
    std::vector<std::array<float, gpu::kNumShCoefficients>> out;
    const float golden = static_cast<float>(M_PI * (3.0 - std::sqrt(5.0)));
    for (int i = 0; i < kDirections; ++i) {
      const float z = 1.f - 2.f * (static_cast<float>(i) + 0.5f) / kDirections;
      const float r = std::sqrt(std::max(0.f, 1.f - z * z));
      const float phi = golden * static_cast<float>(i);
      std::array<float, gpu::kNumShCoefficients> a = gpu::sh_basis(Eigen::Vector3f(r * std::cos(phi), r * std::sin(phi), z));
      a[0] *= 1.f + kNegativeLobe;
      out.push_back(a);
    }
    return out;
  }();
  return rows;
}

// The rows as the columns of A^T (9 x 128), for the projection's least squares.
const Eigen::MatrixXd& constraint_matrix_transposed() {
  static const Eigen::MatrixXd at = [] {
    const auto& rows = constraint_rows();
    Eigen::MatrixXd m(gpu::kNumShCoefficients, static_cast<Eigen::Index>(rows.size()));
    for (size_t i = 0; i < rows.size(); ++i)
      for (int k = 0; k < gpu::kNumShCoefficients; ++k) m(k, static_cast<Eigen::Index>(i)) = rows[i][static_cast<size_t>(k)];
    return m;
  }();
  return at;
}

}  // namespace

float LowestRelativeIrradiance(const ShLight& light, int channel) {
  const float* g = light.data() + channel * gpu::kNumShCoefficients;
  float largest = 0.f;
  for (int k = 0; k < gpu::kNumShCoefficients; ++k) largest = std::max(largest, std::abs(g[k]));
  if (largest < 1e-6f) return 0.f;  // no light in this channel (a projection may leave round-off)
  const float y0 = gpu::sh_basis(Eigen::Vector3f::UnitZ())[0];
  const float mean = g[0] * y0;
  float lowest = std::numeric_limits<float>::infinity();
  for (const auto& a : constraint_rows()) {
    float e = g[0] * y0;  // the row's own DC entry carries the margin; the irradiance has none
    for (int k = 1; k < gpu::kNumShCoefficients; ++k) e += a[static_cast<size_t>(k)] * g[k];
    lowest = std::min(lowest, e);
  }
  if (mean > 0.f) return lowest / mean;
  if (lowest >= 0.f) return 0.f;
  return -std::numeric_limits<float>::infinity();
}

LightProjection ProjectToPlausibleLight(ShLight* light) {
  LightProjection out;
  const Eigen::MatrixXd& at = constraint_matrix_transposed();
  const int m = static_cast<int>(at.cols());
  // The nearest x to g with A x >= 0 is x = g + A^T lambda, where lambda >= 0 minimises
  // |A^T lambda + g|: a non-negative least-squares problem (9 x 128), solved exactly by Lawson and
  // Hanson's active-set method (finite; each pass adds the constraint that lowers the residual
  // most and drops those whose multiplier would turn negative).
  double moved2 = 0;
  for (int c = 0; c < 3; ++c) {
    float* g = light->data() + c * gpu::kNumShCoefficients;
    if (!std::all_of(g, g + gpu::kNumShCoefficients, [](float v) { return std::isfinite(v); })) continue;
    Eigen::VectorXd x(gpu::kNumShCoefficients);
    for (int k = 0; k < gpu::kNumShCoefficients; ++k) x[k] = g[k];
    if ((at.transpose() * x).minCoeff() >= 0.0) continue;  // plausible: left bit for bit
    const Eigen::VectorXd b = -x;
    Eigen::VectorXd lambda = Eigen::VectorXd::Zero(m);
    std::vector<char> active(static_cast<size_t>(m), 0);
    const double tol = 1e-10 * std::max(1.0, x.norm());
    for (int outer = 0; outer < 3 * m; ++outer) {
      const Eigen::VectorXd w = at.transpose() * (b - at * lambda);
      int best = -1;
      for (int i = 0; i < m; ++i)
        if (!active[static_cast<size_t>(i)] && w[i] > tol && (best < 0 || w[i] > w[best])) best = i;
      if (best < 0) break;
      active[static_cast<size_t>(best)] = 1;
      for (int inner = 0; inner < 3 * m; ++inner) {
        std::vector<int> p;
        for (int i = 0; i < m; ++i)
          if (active[static_cast<size_t>(i)]) p.push_back(i);
        Eigen::MatrixXd ap(gpu::kNumShCoefficients, static_cast<Eigen::Index>(p.size()));
        for (size_t j = 0; j < p.size(); ++j) ap.col(static_cast<Eigen::Index>(j)) = at.col(p[j]);
        const Eigen::VectorXd sp = ap.completeOrthogonalDecomposition().solve(b);
        if (sp.minCoeff() > 0.0) {
          lambda.setZero();
          for (size_t j = 0; j < p.size(); ++j) lambda[p[j]] = sp[static_cast<Eigen::Index>(j)];
          break;
        }
        double alpha = 1.0;
        for (size_t j = 0; j < p.size(); ++j) {
          const double s = sp[static_cast<Eigen::Index>(j)], l = lambda[p[j]];
          if (s <= 0.0 && l - s > 0.0) alpha = std::min(alpha, l / (l - s));
        }
        for (size_t j = 0; j < p.size(); ++j) {
          double& l = lambda[p[j]];
          l += alpha * (sp[static_cast<Eigen::Index>(j)] - l);
          if (l <= tol) {
            l = 0.0;
            active[static_cast<size_t>(p[j])] = 0;
          }
        }
      }
    }
    const Eigen::VectorXd projected = x + at * lambda;
    for (int k = 0; k < gpu::kNumShCoefficients; ++k) {
      const float v = static_cast<float>(projected[k]);
      moved2 += double(v - g[k]) * (v - g[k]);
      g[k] = v;
    }
    out.changed = true;
  }
  out.moved = static_cast<float>(std::sqrt(moved2));
  return out;
}

}  // namespace face_reenact::tracker
