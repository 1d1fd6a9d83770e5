// The demo's closed loop (closed_loop.h).
#include "face_reenact/reenact/closed_loop.h"

#include <cmath>
#include <limits>
#include <utility>

#include "face_reenact/gpu/cpu_renderer.h"
#include "face_reenact/reenact/transfer.h"

namespace face_reenact::reenact {

double ExpressionError(const Eigen::VectorXf& got, const Eigen::VectorXf& truth) {
  double sum = 0;
  for (int i = 0; i < kNumExpressionWeights; ++i) sum += std::abs(expression_weight(got, i) - expression_weight(truth, i));
  return sum / kNumExpressionWeights;
}

class ClosedLoopScore::IdentityMeter {
 public:
  IdentityMeter(const tracker::TrackerModel& model, const gpu::PinholeCamera& camera)
      : model_(model), renderer_(model_.render), camera_(camera) {}
  const tracker::IdentityErrors& Compare(const Eigen::VectorXf& fit, const Eigen::VectorXf& truth) {
    if (!has_ || fit.size() != fit_.size() || fit != fit_ || truth.size() != truth_.size() || truth != truth_) {
      last_ = tracker::CompareIdentities(renderer_, model_, fit, truth, camera_, kDistanceM);
      fit_ = fit;
      truth_ = truth;
      has_ = true;
    }
    return last_;
  }

 private:
  static constexpr float kDistanceM = 0.6f;  // the neutral faces are compared 0.6 m in front of the camera
  const tracker::TrackerModel& model_;
  gpu::CpuRenderer renderer_;
  gpu::PinholeCamera camera_;
  bool has_ = false;
  Eigen::VectorXf fit_, truth_;
  tracker::IdentityErrors last_;
};

double ClosedLoopScore::Mean::value() const { return n ? sum / n : std::numeric_limits<double>::quiet_NaN(); }

ClosedLoopScore::ClosedLoopScore(tracker::TrackerModel model, const gpu::PinholeCamera& camera)
    : model_(std::move(model)),
      target_identity_(std::make_unique<IdentityMeter>(model_, camera)),
      loop_identity_(std::make_unique<IdentityMeter>(model_, camera)) {}

ClosedLoopScore::~ClosedLoopScore() = default;

void ClosedLoopScore::AddSource(const tracker::TrackedFrame& source, bool source_calibrated,
                                const Eigen::VectorXf& source_truth) {
  if (source.has_parameters && tracker::tracking_status_has_fit(source.status) && source_calibrated)
    source_.add(ExpressionError(source.params.delta, source_truth));
}

void ClosedLoopScore::AddTargetIdentity(const Eigen::VectorXf& fitted_alpha, const Eigen::VectorXf& true_alpha) {
  const tracker::IdentityErrors& e = target_identity_->Compare(fitted_alpha, true_alpha);
  target_identity_mm_.add(e.surface_mm_mean);
  target_identity_vertex_.add(e.vertex_mm_mean);
}

void ClosedLoopScore::AddLoop(const tracker::TrackedFrame& loop, bool loop_calibrated, const Eigen::VectorXf& loop_alpha,
                              const Eigen::VectorXf& source_truth, const Eigen::VectorXf& rendered_expression,
                              const Eigen::VectorXf& target_true_alpha) {
  if (!loop_calibrated || !loop.has_parameters || !tracker::tracking_status_has_fit(loop.status)) return;
  expression_.add(ExpressionError(loop.params.delta, source_truth));
  rendered_.add(ExpressionError(loop.params.delta, rendered_expression));
  jaw_.add(std::abs(expression_weight(loop.params.delta, kJawOpenIndex) - expression_weight(source_truth, kJawOpenIndex)));
  const tracker::IdentityErrors& e = loop_identity_->Compare(loop_alpha, target_true_alpha);
  identity_.add(e.surface_mm_mean);
  identity_vertex_.add(e.vertex_mm_mean);
}

ClosedLoopScore::Summary ClosedLoopScore::summary() const {
  Summary s;
  s.loop_frames = expression_.n;
  s.expression_error = expression_.value();
  s.jaw_open_error = jaw_.value();
  s.expression_error_vs_rendered = rendered_.value();
  s.identity_error_mm = identity_.value();
  s.identity_vertex_error_mm = identity_vertex_.value();
  s.source_expression_error = source_.value();
  s.target_identity_error_mm = target_identity_mm_.value();
  s.target_identity_vertex_error_mm = target_identity_vertex_.value();
  return s;
}

}  // namespace face_reenact::reenact
