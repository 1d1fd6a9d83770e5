#pragma once
// Temporal smoothing of landmark positions with the One-Euro filter (Casiez et al., CHI 2012):
// a low-pass filter whose cut-off rises with the speed of the signal, so a still face stops
// jittering while real motion is followed with little lag.
#include <array>

#include "face_reenact/landmarks/landmark_detector.h"

namespace face_reenact::landmarks {

struct SmoothingOptions {
  bool enabled = false;
  float min_cutoff_hz = 1.5f;  // cut-off at rest: lower = smoother, more lag on slow motion
  float beta = 0.02f;         // cut-off growth per (pixel / second / inter-ocular unit) of speed
  float derivative_cutoff_hz = 1.0f;

  bool IsValid(std::string* error) const;
};

class OneEuroFilter {
 public:
  OneEuroFilter() = default;
  OneEuroFilter(float min_cutoff_hz, float beta, float derivative_cutoff_hz)
      : min_cutoff_(min_cutoff_hz), beta_(beta), d_cutoff_(derivative_cutoff_hz) {}
  // `dt` in seconds (> 0; a non-positive or non-finite dt passes the value through). `scale`
  // divides the speed before it raises the cut-off, so beta is independent of face size.
  float Filter(float value, float dt, float scale = 1.f);
  void Reset() { initialised_ = false; }

 private:
  float min_cutoff_ = 1.5f, beta_ = 0.02f, d_cutoff_ = 1.f;
  bool initialised_ = false;
  float previous_ = 0, previous_derivative_ = 0;
};

// One filter per coordinate of the 68 points, scaled by the inter-ocular distance.
class LandmarkSmoother {
 public:
  explicit LandmarkSmoother(const SmoothingOptions& options = {}) : options_(options) { Reset(); }
  // Smooths in place; the first call (and the first after Reset) passes through.
  void Apply(double timestamp_s, Shape68* points);
  void Reset();

 private:
  SmoothingOptions options_;
  std::array<OneEuroFilter, 2 * kNumLandmarks> filters_;
  double last_timestamp_ = 0;
  bool has_last_ = false;
};

}  // namespace face_reenact::landmarks
