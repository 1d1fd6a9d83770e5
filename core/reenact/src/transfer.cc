#include "face_reenact/reenact/transfer.h"

#include <algorithm>
#include <cmath>

#include "face_reenact/common/error.h"
#include "face_reenact/stream/stream_state.h"

namespace face_reenact::reenact {

bool SourceExpression::IsValid(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (!std::isfinite(blend_weight) || blend_weight < 0.0f || blend_weight > 1.0f)
    return fail("source expression: blend_weight must be in [0, 1]");
  const float lo = neutral_subtracted ? -1.5f : -0.5f;
  for (int i = 0; i < kNumExpressionWeights; ++i) {
    const float w = weights[static_cast<size_t>(i)];
    if (!std::isfinite(w) || w < lo || w > 1.5f)
      return fail("source expression: weight " + std::to_string(i) + " is " + std::to_string(w) + ", outside [" +
                  std::to_string(lo) + ", 1.5]");
    if (!neutral_subtracted) {
      const float n = neutral[static_cast<size_t>(i)];
      if (!std::isfinite(n) || n < -0.5f || n > 1.5f)
        return fail("source expression: neutral weight " + std::to_string(i) + " is outside [-0.5, 1.5]");
    }
  }
  std::string sub;
  if (view && !view->IsValid(&sub)) return fail("source expression: " + sub);
  return true;
}

std::array<float, kNumExpressionWeights> SourceExpression::relative() const {
  if (neutral_subtracted) return weights;
  std::array<float, kNumExpressionWeights> r{};
  for (size_t i = 0; i < r.size(); ++i) r[i] = weights[i] - neutral[i];
  return r;
}

namespace {
float at(const Eigen::VectorXf& v, int i) { return i < v.size() ? v[i] : 0.0f; }
}  // namespace

SourceExpression SourceFromParameters(const gpu::FaceParameters& tracked, const gpu::FaceParameters& neutral) {
  SourceExpression s;
  for (int i = 0; i < kNumExpressionWeights; ++i) {
    s.weights[static_cast<size_t>(i)] = at(tracked.delta, i);
    s.neutral[static_cast<size_t>(i)] = at(neutral.delta, i);
  }
  s.neutral_subtracted = false;
  s.blend_weight = 1.0f;
  return s;
}

SourceExpression SourceFromTrackedFrame(const tracker::TrackedFrame& tracked, const gpu::FaceParameters& neutral) {
  SourceExpression s = SourceFromParameters(tracked.params, neutral);
  if (!tracked.has_parameters || !tracker::tracking_status_has_fit(tracked.status)) s.blend_weight = 0.0f;
  return s;
}

SourceExpression SourceFromRemote(const stream::RemoteExpression& remote) {
  static_assert(stream::kNumCoefficients == kNumExpressionWeights, "the stream carries the 52 ARKit weights");
  SourceExpression s;
  s.neutral_subtracted = true;
  if (!remote.has_frame) {
    s.blend_weight = 0.0f;
    return s;
  }
  for (int i = 0; i < kNumExpressionWeights; ++i) {
    const float w = remote.expression[static_cast<size_t>(i)];
    // The receiver enforces the protocol's limits; clamp anyway so IsValid always holds.
    s.weights[static_cast<size_t>(i)] = std::isfinite(w) ? std::clamp(w, -1.5f, 1.5f) : 0.0f;
  }
  s.blend_weight = std::isfinite(remote.weight) ? std::clamp(remote.weight, 0.0f, 1.0f) : 0.0f;
  return s;
}

Eigen::VectorXf TransferExpression(const Eigen::VectorXf& target_neutral, const Eigen::VectorXf& target_own,
                                   const SourceExpression& source, int size) {
  std::string why;
  if (!source.IsValid(&why)) throw Error(why);
  if (size < kNumExpressionWeights) throw Error("expression transfer: size must be at least 52");
  const std::array<float, kNumExpressionWeights> rel = source.relative();
  const float w = source.blend_weight;
  Eigen::VectorXf out(size);
  for (int i = 0; i < size; ++i) {
    const float own = at(target_own, i);
    if (i >= kNumExpressionWeights) {
      out[i] = own;
      continue;
    }
    const float transferred = std::clamp(at(target_neutral, i) + rel[static_cast<size_t>(i)], 0.0f, 1.0f);
    out[i] = std::clamp(w * transferred + (1.0f - w) * own, 0.0f, 1.0f);
  }
  return out;
}

gpu::FaceParameters TransferParameters(const gpu::FaceParameters& target_tracked,
                                       const gpu::FaceParameters& target_neutral, const SourceExpression& source) {
  gpu::FaceParameters out = target_tracked;
  const int size = std::max<int>(kNumExpressionWeights, static_cast<int>(target_tracked.delta.size()));
  out.delta = TransferExpression(target_neutral.delta, target_tracked.delta, source, size);
  return out;
}

const char* reenact_mode_name(ReenactMode mode) {
  switch (mode) {
    case ReenactMode::kReenact: return "reenact";
    case ReenactMode::kPassThrough: return "pass-through";
    case ReenactMode::kOff: return "off";
    case ReenactMode::kOverlay: return "overlay";
    case ReenactMode::kMirror: return "mirror";
  }
  return "unknown";
}

const char* appearance_name(Appearance appearance) {
  switch (appearance) {
    case Appearance::kFrameTexture: return "frame-texture";
    case Appearance::kAlbedoMap: return "albedo-map";
  }
  return "unknown";
}

const char* tracking_status_name(TrackingStatus status) {
  switch (status) {
    case TrackingStatus::kCalibrating: return "calibrating";
    case TrackingStatus::kTracking: return "tracking";
    case TrackingStatus::kLost: return "lost";
  }
  return "unknown";
}

}  // namespace face_reenact::reenact
