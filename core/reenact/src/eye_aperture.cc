#include "eye_aperture.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <opencv2/imgproc.hpp>

#include "image_sampling.h"

namespace face_reenact::reenact::internal {

namespace {
// Samples of the curve per segment between two lid points: at a 640x480 eye (30-40 px wide, a
// segment 6-10 px) a chord every 2-3 px, which strays from the curve by under a tenth of a pixel.
constexpr int kSamplesPerSegment = 4;

// The uniform Catmull-Rom curve between b and c (a before, d after) at t in [0, 1).
Eigen::Vector2f catmull_rom(const Eigen::Vector2f& a, const Eigen::Vector2f& b, const Eigen::Vector2f& c,
                            const Eigen::Vector2f& d, float t) {
  const float t2 = t * t, t3 = t2 * t;
  return 0.5f * ((2.f * b) + (c - a) * t + (2.f * a - 5.f * b + 4.f * c - d) * t2 + (3.f * b - a - 3.f * c + d) * t3);
}

std::vector<Eigen::Vector2f> closed_curve(const std::array<Eigen::Vector2f, 6>& p) {
  std::vector<Eigen::Vector2f> out;
  out.reserve(6 * kSamplesPerSegment);
  for (size_t k = 0; k < 6; ++k)
    for (int s = 0; s < kSamplesPerSegment; ++s)
      out.push_back(catmull_rom(p[(k + 5) % 6], p[k], p[(k + 1) % 6], p[(k + 2) % 6],
                                static_cast<float>(s) / static_cast<float>(kSamplesPerSegment)));
  return out;
}
}  // namespace

EyeAperture::EyeAperture(const std::array<Eigen::Vector2f, 6>& frame_points, const std::array<Eigen::Vector2f, 6>& motion) {
  std::array<Eigen::Vector2f, 6> moved;
  for (size_t k = 0; k < 6; ++k) moved[k] = frame_points[k] + motion[k];
  frame_ = closed_curve(frame_points);
  output_ = closed_curve(moved);
  // The motion along the curve: linear between the points' own (a smooth enough field for a lid).
  motion_.reserve(frame_.size());
  for (size_t k = 0; k < 6; ++k)
    for (int s = 0; s < kSamplesPerSegment; ++s) {
      const float t = static_cast<float>(s) / static_cast<float>(kSamplesPerSegment);
      motion_.push_back((1.f - t) * motion[k] + t * motion[(k + 1) % 6]);
    }
}

float EyeAperture::SignedDistance(const Eigen::Vector2f& p, Which which, Eigen::Vector2f* motion_at) const {
  const std::vector<Eigen::Vector2f>& c = which == Which::kFrame ? frame_ : output_;
  float best = std::numeric_limits<float>::max();
  size_t best_k = 0;
  float best_t = 0.f;
  bool inside = false;
  const size_t n = c.size();
  for (size_t k = 0, prev = n - 1; k < n; prev = k++) {
    const Eigen::Vector2f& a = c[prev];
    const Eigen::Vector2f& b = c[k];
    // Crossings of the ray from p to +x (even-odd rule).
    if ((a.y() > p.y()) != (b.y() > p.y()) && p.x() < (b.x() - a.x()) * (p.y() - a.y()) / (b.y() - a.y()) + a.x())
      inside = !inside;
    const Eigen::Vector2f ab = b - a;
    const float len2 = ab.squaredNorm();
    const float t = len2 > 0.f ? std::clamp((p - a).dot(ab) / len2, 0.0f, 1.0f) : 0.f;
    const float d = (a + t * ab - p).squaredNorm();
    if (d < best) best = d, best_k = prev, best_t = t;
  }
  if (motion_at) *motion_at = (1.f - best_t) * motion_[best_k] + best_t * motion_[(best_k + 1) % n];
  const float d = std::sqrt(best);
  return inside ? d : -d;
}

Eigen::Vector2f EyeAperture::FrameLidPoint(const Eigen::Vector2f& p, const Eigen::Vector2f& motion) const {
  const Eigen::Vector2f q = p - motion;
  if (SignedDistance(q, Which::kFrame) < 0.f) return q;
  Eigen::Vector2f nearest = frame_[0];
  for (const Eigen::Vector2f& c : frame_)
    if ((c - q).squaredNorm() < (nearest - q).squaredNorm()) nearest = c;
  const Eigen::Vector2f out = nearest - q;
  return out.norm() > 1e-3f ? Eigen::Vector2f(nearest + out.normalized()) : nearest;
}

cv::Rect EyeAperture::Bounds(Which which, int margin, int w, int h) const {
  return grown_within(cv::boundingRect(PixelOutline(which)), margin, w, h);
}

std::vector<cv::Point> EyeAperture::PixelOutline(Which which) const {
  const std::vector<Eigen::Vector2f>& c = which == Which::kFrame ? frame_ : output_;
  std::vector<cv::Point> out;
  out.reserve(c.size());
  for (const Eigen::Vector2f& q : c) out.emplace_back(pixel_round(q.x()), pixel_round(q.y()));
  return out;
}

}  // namespace face_reenact::reenact::internal
