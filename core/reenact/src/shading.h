#pragma once
// The lighting the re-rendering uses, shared by the compositor and the virtual mirror (internal to
// fr_reenact).
#include <algorithm>
#include <array>
#include <cmath>

#include <Eigen/Core>

#include "face_reenact/gpu/image_formation.h"

namespace face_reenact::reenact::internal {

using Gamma = std::array<float, gpu::kNumShParameters>;

// The lighting used to re-render and to learn the albedo map: the tracked SH lighting with one
// directional shape for all three channels (the mean of the channels' shapes relative to their
// DC terms), each channel keeping its own DC. The tracker fits 27 coefficients to the directions
// it sees; a per-channel directional fit extrapolates to unseen normal directions (an opened
// jaw's chin, a raised brow, the cheeks at a turned head) with strong colour casts. A single
// directional shape keeps the light's colour the same from every direction, and whatever
// per-channel differences the target shows in the directions seen end up in the albedo map.
inline Gamma rendering_lighting(const Gamma& gamma) {
  Gamma out = gamma;
  float shape[gpu::kNumShCoefficients] = {};
  int channels = 0;
  for (int c = 0; c < 3; ++c) {
    const float dc = gamma[static_cast<size_t>(c * 9)];
    if (!(dc > 1e-4f)) continue;
    for (int k = 1; k < gpu::kNumShCoefficients; ++k) shape[k] += gamma[static_cast<size_t>(c * 9 + k)] / dc;
    ++channels;
  }
  if (channels == 0) return gamma;
  for (int c = 0; c < 3; ++c) {
    const float dc = gamma[static_cast<size_t>(c * 9)];
    for (int k = 1; k < gpu::kNumShCoefficients; ++k) out[static_cast<size_t>(c * 9 + k)] = dc * shape[k] / channels;
  }
  return out;
}

// Irradiance of channel c, floored at a fraction of the ambient (DC) part: SH fits can go
// negative in directions they were never fitted to, and real rooms are never that dark.
inline float irradiance(const Gamma& gamma, const std::array<float, 9>& basis, int c) {
  float e = 0.f;
  for (int k = 0; k < gpu::kNumShCoefficients; ++k) e += gamma[static_cast<size_t>(c * 9 + k)] * basis[static_cast<size_t>(k)];
  const float ambient = gamma[static_cast<size_t>(c * 9)] * basis[0];
  return std::max(e, 0.15f * ambient);
}

// The normal the light is evaluated at for a surface point at camera-space `position`: `normal`,
// turned towards the camera (about the axis across both) until it faces the camera at least
// kMinLitFacing (the cosine of the angle to the view ray). The tracker fits the SH light to the
// pixels it sees, whose normals face the camera; at grazing and turned-away normals the fit is an
// extrapolation, and a second-order one changes fast there. On the webcam clip (a window behind
// the speaker) it put 1.15 at a normal facing straight down and 0.81 at one turned 17 degrees
// further towards the camera: where d6's grimace rolls the output's lower lip out, the strip of
// its underside seen edge-on (under a pixel wide, so drawn as every other pixel) took a 1.4 times
// brighter shading than the target's lip there, a dotted light line along the lower lip. Beyond
// the cone the light is the cone edge's in the same direction: continuous, and never brighter or
// darker than what some surface the fit saw receives. (The albedo map observes only vertices
// facing the camera at 0.5 and more, inside the cone, so it is unaffected.)
inline constexpr float kMinLitFacing = 0.3f;
inline Eigen::Vector3f lit_normal(const Eigen::Vector3f& normal, const Eigen::Vector3f& position) {
  const float distance = position.norm();
  if (!(distance > 0.f)) return normal;
  const Eigen::Vector3f to_camera = -position / distance;
  const float facing = normal.dot(to_camera);
  if (facing >= kMinLitFacing) return normal;
  const Eigen::Vector3f across = normal - facing * to_camera;  // the normal's part across the view ray
  const float across_norm = across.norm();
  if (!(across_norm > 1e-6f)) return to_camera;  // facing straight away: no direction to keep
  return kMinLitFacing * to_camera + std::sqrt(1.f - kMinLitFacing * kMinLitFacing) * (across / across_norm);
}

// The SH basis of a surface facing the camera (normal -z), and the irradiance of channel c there,
// at least 0: the light a face receives head-on (the mouth's entering light, the mirror's exposure
// reference).
inline const std::array<float, 9>& camera_facing_basis() {
  static const auto facing = gpu::sh_basis(Eigen::Vector3f(0.f, 0.f, -1.f));
  return facing;
}
inline float camera_facing_irradiance(const Gamma& gamma, int c) {
  return std::max(0.f, irradiance(gamma, camera_facing_basis(), c));
}

// How a surface point's shading changes from irradiance `before` to `after`, per channel (the
// frame texture's move from the tracked normal to the output's; the mirror's new light against
// the tracked one). A channel that `before` gives next to no irradiance (under 2 % of its
// brightest channel's, or none) says nothing of the change: the tracker's light can put a
// channel's ambient at or below zero (the Breaking Bad still, held and tracked for seconds: blue's
// ambient below 0 by frame 30, green's by frame 50), and dividing by a floor there scaled that
// channel by the callers' clamp, which turned the whole face pink even in pass-through. Such a
// channel takes the change of the channels' summed irradiance; the same irradiance is no change.
inline Eigen::Vector3f shading_change(const Eigen::Vector3f& after, const Eigen::Vector3f& before) {
  constexpr float kMinIrradiance = 1e-4f, kMinShareOfBrightest = 0.02f;
  const float sum_after = after.cwiseMax(0.f).sum(), sum_before = before.cwiseMax(0.f).sum();
  const float shared = sum_before > kMinIrradiance && sum_after > 0.f ? sum_after / sum_before : 1.0f;
  const float usable = std::max(kMinIrradiance, kMinShareOfBrightest * before.maxCoeff());
  Eigen::Vector3f change;
  for (int c = 0; c < 3; ++c) {
    if (after[c] == before[c])
      change[c] = 1.0f;
    else if (before[c] > usable && after[c] > 0.f)
      change[c] = after[c] / before[c];
    else
      change[c] = shared;
  }
  return change;
}

}  // namespace face_reenact::reenact::internal
