#include "face_reenact/landmarks/smoothing.h"

#include <cmath>
#include <numbers>

namespace face_reenact::landmarks {
namespace {
float smoothing_factor(float dt, float cutoff_hz) {
  const float tau = 1.f / (2.f * std::numbers::pi_v<float> * cutoff_hz);
  return 1.f / (1.f + tau / dt);
}
}  // namespace

bool SmoothingOptions::IsValid(std::string* error) const {
  if (!(min_cutoff_hz > 0.f && std::isfinite(min_cutoff_hz)) || !(beta >= 0.f && std::isfinite(beta)) ||
      !(derivative_cutoff_hz > 0.f && std::isfinite(derivative_cutoff_hz))) {
    if (error) *error = "smoothing options: need min_cutoff_hz > 0, beta >= 0, derivative_cutoff_hz > 0";
    return false;
  }
  return true;
}

float OneEuroFilter::Filter(float value, float dt, float scale) {
  if (!initialised_ || !(dt > 0.f) || !std::isfinite(dt) || !std::isfinite(value)) {
    initialised_ = std::isfinite(value);
    previous_ = value;
    previous_derivative_ = 0.f;
    return value;
  }
  const float derivative = (value - previous_) / dt;
  const float a_d = smoothing_factor(dt, d_cutoff_);
  previous_derivative_ = a_d * derivative + (1.f - a_d) * previous_derivative_;
  const float speed = std::abs(previous_derivative_) / (scale > 0.f ? scale : 1.f);
  const float cutoff = min_cutoff_ + beta_ * speed;
  const float a = smoothing_factor(dt, cutoff);
  previous_ = a * value + (1.f - a) * previous_;
  return previous_;
}

void LandmarkSmoother::Reset() {
  for (auto& f : filters_) f = OneEuroFilter(options_.min_cutoff_hz, options_.beta, options_.derivative_cutoff_hz);
  has_last_ = false;
}

void LandmarkSmoother::Apply(double timestamp_s, Shape68* points) {
  if (!options_.enabled || points == nullptr) return;
  const float dt = has_last_ ? float(timestamp_s - last_timestamp_) : 0.f;
  last_timestamp_ = timestamp_s;
  has_last_ = true;
  // Speeds in inter-ocular units per second, so beta does not depend on the face's size.
  float iod = outer_eye_distance(*points);
  if (!(iod > 1.f)) iod = 1.f;
  const float scale = iod / 100.f;
  for (int i = 0; i < kNumLandmarks; ++i) {
    Eigen::Vector2f& p = (*points)[size_t(i)];
    p.x() = filters_[size_t(2 * i)].Filter(p.x(), dt, scale);
    p.y() = filters_[size_t(2 * i + 1)].Filter(p.y(), dt, scale);
  }
}

}  // namespace face_reenact::landmarks
