#include "eyeball_fill.h"

#include <algorithm>
#include <cmath>

namespace face_reenact::reenact::internal {
namespace {

// The kernels' width, in pixels on the eyeball facing the camera: tighter than the compositor's
// skin fill (2 px), since the iris' edge is an edge (at 1.5 px the white a pixel or two beyond it
// took a fifth of the iris' colour).
constexpr float kSigmaPx = 1.0f;
// A neighbourhood is complete at this share of the weight fully shown surface gives it (one
// sample per pixel), as the compositor's fill counts its trusted share.
constexpr float kShareForFull = 0.3f;
// A ring is complete at this much weight: a few samples at that angle anywhere around the axis.
constexpr float kRingWeightForFull = 3.0f;
// Samples trusted less than this (an eyeball's edge, where a fit a pixel off shows the lid's rim)
// fill nothing once the eye has kMinTrustedSamples trusted ones; an eye a few pixels tall is all
// edge and keeps them.
constexpr float kTrusted = 0.5f;
constexpr int kMinTrustedSamples = 20;

}  // namespace

EyeballFill::EyeballFill(float radius_px) : radius_px_(std::max(radius_px, 1.0f)) {}

void EyeballFill::Add(const Eigen::Vector3f& direction, const Eigen::Vector3f& colour, float weight) {
  if (!(weight > 0.f) || !direction.allFinite() || !colour.allFinite()) return;
  samples_.push_back({direction, colour, std::min(weight, 1.0f), std::acos(std::clamp(direction.z(), -1.0f, 1.0f))});
  trusted_ += weight >= kTrusted;
}

float EyeballFill::Mean(const Eigen::Vector3f& direction, bool ring, Eigen::Vector3f* mean) const {
  // Distances in pixels: the chord times the radius, or along a meridian for the ring (the angle
  // from the axis times the radius).
  const float inv_two_sigma2 = 1.0f / (2.0f * kSigmaPx * kSigmaPx);
  const float cutoff2 = 9.0f * kSigmaPx * kSigmaPx;
  const float angle = ring ? std::acos(std::clamp(direction.z(), -1.0f, 1.0f)) : 0.f;
  Eigen::Vector3f sum = Eigen::Vector3f::Zero();
  float total = 0.f;
  const float least = trusted_ >= kMinTrustedSamples ? kTrusted : 0.f;
  for (const Sample& s : samples_) {
    if (s.weight < least) continue;
    float d2;
    if (ring) {
      const float d = radius_px_ * (s.angle - angle);
      d2 = d * d;
    } else {
      d2 = radius_px_ * radius_px_ * (s.direction - direction).squaredNorm();
    }
    if (d2 > cutoff2) continue;
    const float k = s.weight * std::exp(-d2 * inv_two_sigma2);
    sum += k * s.colour;
    total += k;
  }
  if (!(total > 1e-6f)) return 0.f;
  *mean = sum / total;
  const float full = ring ? kRingWeightForFull : kShareForFull * 2.0f * static_cast<float>(M_PI) * kSigmaPx * kSigmaPx;
  return std::clamp(total / full, 0.0f, 1.0f);
}

Eigen::Vector3f EyeballFill::At(const Eigen::Vector3f& direction, const Eigen::Vector3f& fallback) const {
  // Most sure first: each level takes what the one before leaves.
  const Eigen::Vector3f places[3] = {direction, Eigen::Vector3f(direction.x(), -direction.y(), direction.z()), direction};
  Eigen::Vector3f colour = Eigen::Vector3f::Zero();
  float left = 1.0f;
  for (int level = 0; level < 3 && left > 1e-4f; ++level) {
    Eigen::Vector3f mean = Eigen::Vector3f::Zero();
    const float sure = Mean(places[level], level == 2, &mean);
    if (!(sure > 0.f)) continue;
    colour += left * sure * mean;
    left *= 1.0f - sure;
  }
  return colour + left * fallback;
}

}  // namespace face_reenact::reenact::internal
