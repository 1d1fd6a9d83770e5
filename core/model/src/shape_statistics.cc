#include "face_reenact/model/shape_statistics.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <random>

#include "face_reenact/common/error.h"

namespace face_reenact {

RigidTransform fit_rigid(const Eigen::VectorXf& x, const Eigen::VectorXf& y, const Eigen::VectorXf& weights) {
  if (x.size() != y.size() || x.size() % 3 != 0 || x.size() == 0)
    throw Error("fit_rigid: point sets must be non-empty 3N vectors of equal size");
  const Eigen::Index n = x.size() / 3;
  if (weights.size() != 0 && weights.size() != n) throw Error("fit_rigid: one weight per point expected");
  auto w = [&](Eigen::Index i) { return weights.size() ? static_cast<double>(weights[i]) : 1.0; };
  double wsum = 0;
  Eigen::Vector3d cx = Eigen::Vector3d::Zero(), cy = Eigen::Vector3d::Zero();
  for (Eigen::Index i = 0; i < n; ++i) {
    wsum += w(i);
    cx += w(i) * x.segment<3>(3 * i).cast<double>();
    cy += w(i) * y.segment<3>(3 * i).cast<double>();
  }
  if (!(wsum > 0)) throw Error("fit_rigid: total weight is zero");
  cx /= wsum;
  cy /= wsum;
  Eigen::Matrix3d h = Eigen::Matrix3d::Zero();
  for (Eigen::Index i = 0; i < n; ++i)
    h += w(i) * (x.segment<3>(3 * i).cast<double>() - cx) * (y.segment<3>(3 * i).cast<double>() - cy).transpose();
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(h, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  // Reflection guard: a rigid motion never mirrors the head.
  if ((svd.matrixV() * svd.matrixU().transpose()).determinant() < 0) d(2, 2) = -1;
  RigidTransform t;
  t.rotation = svd.matrixV() * d * svd.matrixU().transpose();
  t.translation = cy - t.rotation * cx;
  return t;
}

void apply_rigid(const RigidTransform& t, Eigen::Ref<Eigen::VectorXf> points) {
  const Eigen::Matrix3f r = t.rotation.cast<float>();
  const Eigen::Vector3f tr = t.translation.cast<float>();
  for (Eigen::Index i = 0; i + 2 < points.size(); i += 3) points.segment<3>(i) = r * points.segment<3>(i) + tr;
}

namespace {

Eigen::MatrixXd orthonormalize(const Eigen::MatrixXd& y) {
  Eigen::HouseholderQR<Eigen::MatrixXd> qr(y);
  return qr.householderQ() * Eigen::MatrixXd::Identity(y.rows(), y.cols());
}

}  // namespace

Eigen::VectorXf align_samples(Eigen::MatrixXf* samples, const Eigen::VectorXf& weights, int max_iterations,
                              double tolerance, ProcrustesSummary* summary) {
  Eigen::MatrixXf& s = *samples;
  if (s.cols() == 0 || s.rows() % 3 != 0) throw Error("align_samples: need 3N x S samples");
  const double points = static_cast<double>(s.rows() / 3);
  Eigen::VectorXf mean = s.rowwise().mean();
  ProcrustesSummary sum;
  for (int it = 0; it < max_iterations; ++it) {
    for (Eigen::Index c = 0; c < s.cols(); ++c) {
      Eigen::VectorXf col = s.col(c);
      apply_rigid(fit_rigid(col, mean, weights), col);
      s.col(c) = col;
    }
    Eigen::VectorXf next = s.rowwise().mean();
    sum.iterations = it + 1;
    sum.final_mean_change = std::sqrt((next - mean).squaredNorm() / points);
    mean = next;
    if (sum.final_mean_change < tolerance) break;
  }
  sum.mean_residual = std::sqrt((s.colwise() - mean).squaredNorm() / (points * static_cast<double>(s.cols())));
  if (summary) *summary = sum;
  return mean;
}

double rigid_motion_share(const Eigen::VectorXf& mean, const Eigen::MatrixXf& basis, const Eigen::VectorXf& sigma,
                          const Eigen::VectorXf& weights) {
  const Eigen::Index n = mean.size() / 3;
  if (mean.size() == 0 || mean.size() % 3 != 0 || basis.rows() != mean.size() || sigma.size() != basis.cols())
    throw Error("rigid_motion_share: need a 3N mean, a 3N x K basis and K sigmas");
  if (weights.size() != 0 && weights.size() != n) throw Error("rigid_motion_share: one weight per point expected");
  auto w = [&](Eigen::Index i) { return weights.size() ? static_cast<double>(weights[i]) : 1.0; };
  double wsum = 0;
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  for (Eigen::Index i = 0; i < n; ++i) {
    wsum += w(i);
    c += w(i) * mean.segment<3>(3 * i).cast<double>();
  }
  if (!(wsum > 0)) throw Error("rigid_motion_share: total weight is zero");
  c /= wsum;
  // The six motion fields with sqrt(w) folded in, so that plain dot products are the weighted ones.
  Eigen::MatrixXd fields = Eigen::MatrixXd::Zero(3 * n, 6);
  for (Eigen::Index i = 0; i < n; ++i) {
    const double sw = std::sqrt(w(i));
    const Eigen::Vector3d p = mean.segment<3>(3 * i).cast<double>() - c;
    for (int a = 0; a < 3; ++a) {
      fields(3 * i + a, a) = sw;
      fields.block<3, 1>(3 * i, 3 + a) = sw * Eigen::Vector3d::Unit(a).cross(p);
    }
  }
  const Eigen::MatrixXd q = orthonormalize(fields);
  double total = 0, rigid = 0;
  for (Eigen::Index k = 0; k < basis.cols(); ++k) {
    Eigen::VectorXd e = basis.col(k).cast<double>();
    for (Eigen::Index i = 0; i < n; ++i) e.segment<3>(3 * i) *= std::sqrt(w(i));
    const double var = static_cast<double>(sigma[k]) * sigma[k];
    total += var * e.squaredNorm();
    rigid += var * (q.transpose() * e).squaredNorm();
  }
  return total > 0 ? rigid / total : 0;
}

bool PcaOptions::IsValid(std::string* why) const {
  auto bad = [&](const char* m) {
    if (why) *why = m;
    return false;
  };
  if (min_components < 1) return bad("min_components must be >= 1");
  if (max_components < min_components) return bad("max_components must be >= min_components");
  if (!(variance_target > 0 && variance_target <= 1)) return bad("variance_target must be in (0, 1]");
  if (subspace_size < max_components) return bad("subspace_size must be >= max_components");
  if (subspace_iterations < 1) return bad("subspace_iterations must be >= 1");
  if (dense_limit < 2) return bad("dense_limit must be >= 2");
  return true;
}

namespace {

// Deterministic standard normals (own Box-Muller so the model does not depend on the
// standard library's distribution implementation).
Eigen::MatrixXd gaussian_matrix(Eigen::Index rows, Eigen::Index cols, uint64_t seed) {
  std::mt19937_64 rng(seed);
  auto uniform = [&] { return (static_cast<double>(rng() >> 11) + 0.5) * (1.0 / 9007199254740992.0); };
  Eigen::MatrixXd m(rows, cols);
  for (Eigen::Index i = 0; i < m.size(); ++i)
    m.data()[i] = std::sqrt(-2 * std::log(uniform())) * std::cos(6.283185307179586 * uniform());
  return m;
}

}  // namespace

PcaResult pca_of_centered_samples(const Eigen::MatrixXf& a, const PcaOptions& o) {
  std::string why;
  if (!o.IsValid(&why)) throw Error("invalid PCA options: " + why);
  const Eigen::Index s = a.cols();
  if (s < 2) throw Error("PCA needs at least 2 samples");
  if (!a.allFinite()) throw Error("PCA input contains NaN or infinite values");
  // Gram matrix of the samples scaled so that its eigenvalues are the covariance's variances.
  Eigen::MatrixXf gf = Eigen::MatrixXf::Zero(s, s);
  gf.selfadjointView<Eigen::Lower>().rankUpdate(a.transpose());
  Eigen::MatrixXd g = gf.cast<double>().selfadjointView<Eigen::Lower>();
  g /= static_cast<double>(s - 1);
  PcaResult r;
  r.total_variance = g.trace();
  if (!(r.total_variance > 0)) throw Error("PCA input has no variance (all samples identical)");

  Eigen::VectorXd values;   // decreasing
  Eigen::MatrixXd vectors;  // S x L
  if (s <= o.dense_limit) {
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(g);
    if (es.info() != Eigen::Success) throw Error("PCA eigen-decomposition did not converge");
    values = es.eigenvalues().reverse();
    vectors = es.eigenvectors().rowwise().reverse();
    r.dense = true;
  } else {
    // Randomised subspace iteration on the Gram matrix: the spectrum of shape samples decays
    // fast, so a block of a few hundred vectors captures the leading components to machine
    // precision after a handful of multiplications.
    const Eigen::Index l = std::min<Eigen::Index>(o.subspace_size, s);
    Eigen::MatrixXd q = orthonormalize(g * gaussian_matrix(s, l, o.seed));
    for (int it = 1; it < o.subspace_iterations; ++it) q = orthonormalize(g * q);
    Eigen::MatrixXd small = q.transpose() * g * q;
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(0.5 * (small + small.transpose()));
    if (es.info() != Eigen::Success) throw Error("PCA eigen-decomposition did not converge");
    values = es.eigenvalues().reverse();
    vectors = q * es.eigenvectors().rowwise().reverse();
    r.dense = false;
  }
  values = values.cwiseMax(0.0);
  r.spectrum = values;
  // Components with numerically zero variance carry no information (and would divide by ~0).
  Eigen::Index usable = 0;
  while (usable < values.size() && values[usable] > values[0] * 1e-10) ++usable;
  double cum = 0;
  r.components_for_target = static_cast<int>(values.size()) + 1;
  for (Eigen::Index k = 0; k < values.size(); ++k) {
    cum += values[k];
    if (cum >= o.variance_target * r.total_variance) {
      r.components_for_target = static_cast<int>(k + 1);
      break;
    }
  }
  Eigen::Index keep = std::max<Eigen::Index>(o.min_components, r.components_for_target);
  keep = std::min<Eigen::Index>({keep, o.max_components, usable});
  if (keep < 1) throw Error("PCA found no component with nonzero variance");

  // Basis vectors: A v / |A v| with |A v|^2 = lambda (S - 1); re-orthonormalised in double to
  // remove the float round-off of the product.
  Eigen::MatrixXf v = vectors.leftCols(keep).cast<float>();
  Eigen::MatrixXd e = (a * v).cast<double>();
  for (Eigen::Index k = 0; k < keep; ++k) e.col(k) /= std::sqrt(values[k] * static_cast<double>(s - 1));
  Eigen::MatrixXd qd = orthonormalize(e);
  for (Eigen::Index k = 0; k < keep; ++k) {
    if (qd.col(k).dot(e.col(k)) < 0) qd.col(k) *= -1;  // undo QR's sign choice
    // Fix the sign convention: the largest entry of each component is positive.
    Eigen::Index imax;
    qd.col(k).cwiseAbs().maxCoeff(&imax);
    if (qd(imax, k) < 0) qd.col(k) *= -1;
  }
  r.basis = qd.cast<float>();
  r.sigma = values.head(keep).cwiseSqrt().cast<float>();
  r.explained_variance = values.head(keep).sum() / r.total_variance;
  return r;
}

}  // namespace face_reenact
