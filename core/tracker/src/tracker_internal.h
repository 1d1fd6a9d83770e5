#pragma once
// Small helpers shared by the tracker's sources (not part of the public API).
#include <Eigen/Core>
#include <algorithm>
#include <cstdio>
#include <string>
#include <vector>

#include "face_reenact/common/error.h"
#include "face_reenact/common/timing.h"
#include "face_reenact/gpu/image_formation.h"
#include "face_reenact/tracker/tracker_model.h"

namespace face_reenact::tracker::internal {

using Clock = SteadyClock;

constexpr double kRadToDeg = 57.29577951308232;

// The same coefficients, value for value (identity or albedo: what decides whether parts made for
// one may serve another).
template <class A, class B>
bool same_coefficients(const Eigen::MatrixBase<A>& a, const Eigen::MatrixBase<B>& b) {
  return a.size() == b.size() && (a.array() == b.array()).all();
}
// `v` in double, zero-padded (or cut) to `n`: a parameter vector as the model's full coefficients.
inline Eigen::VectorXd padded(const Eigen::VectorXf& v, int n) {
  Eigen::VectorXd out = Eigen::VectorXd::Zero(n);
  const int k = std::min<int>(n, static_cast<int>(v.size()));
  out.head(k) = v.head(k).cast<double>();
  return out;
}

// printf into a string (messages of a few hundred characters at most).
template <typename... Args>
std::string format(const char* fmt, Args... args) {
  char buf[512];
  std::snprintf(buf, sizeof buf, fmt, args...);
  return buf;
}

// The upper median (the element at size / 2 once ordered); T() when empty.
template <typename T>
T median(std::vector<T> values) {
  if (values.empty()) return T();
  std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(values.size() / 2), values.end());
  return values[values.size() / 2];
}

// Model-frame position of vertex v at `shape`'s identity and expression.
inline Eigen::Vector3d model_vertex(const TrackerModel& model, const gpu::FaceParameters& shape, int v) {
  const auto& r = model.render;
  Eigen::Vector3d x = r.mean_shape.segment<3>(3 * v).cast<double>();
  const int n_id = std::min<int>(static_cast<int>(shape.alpha.size()), model.num_identity());
  for (int k = 0; k < n_id; ++k) x += r.identity_basis.block<3, 1>(3 * v, k).cast<double>() * shape.alpha[k];
  const int n_exp = std::min<int>(static_cast<int>(shape.delta.size()), model.num_expression());
  for (int k = 0; k < n_exp; ++k) {
    if (shape.delta[k] != 0.f) x += r.expression_basis.block<3, 1>(3 * v, k).cast<double>() * shape.delta[k];
  }
  return x;
}

// Pinhole projection of a camera-frame point, in pixels.
inline Eigen::Vector2d project(const gpu::PinholeCamera& cam, const Eigen::Vector3d& x) {
  return {cam.fx * x.x() / x.z() + cam.cx, cam.fy * x.y() / x.z() + cam.cy};
}

}  // namespace face_reenact::tracker::internal
