#pragma once
// The reenactment checked in a closed loop on actors with ground truth (`face-reenact demo`,
// docs/reenactment.md): the reenacted output is tracked again, and its expressions are compared
// with the source actor's true ones and its calibrated identity with the target actor's true one;
// the source's tracking and the target's calibration are scored on the way. The front-end runs the
// actors through the pipeline and feeds each frame here; the figures are the library's.
#include <Eigen/Core>
#include <memory>

#include "face_reenact/gpu/image_formation.h"
#include "face_reenact/tracker/evaluation.h"
#include "face_reenact/tracker/face_tracker.h"
#include "face_reenact/tracker/tracker_model.h"

namespace face_reenact::reenact {

// Mean absolute difference over the 52 blendshape weights (missing weights count as 0).
double ExpressionError(const Eigen::VectorXf& got, const Eigen::VectorXf& truth);

class ClosedLoopScore {
 public:
  // `camera`: the target's (the identities are compared as seen from it, tracker::CompareIdentities).
  // Keeps a copy of `model`.
  ClosedLoopScore(tracker::TrackerModel model, const gpu::PinholeCamera& camera);
  ~ClosedLoopScore();

  // The source actor's tracked frame against its true expression (counted once its tracker is
  // calibrated and the frame has a fit).
  void AddSource(const tracker::TrackedFrame& source, bool source_calibrated, const Eigen::VectorXf& source_truth);
  // The target's calibrated identity against its true one (a frame the pipeline tracked).
  void AddTargetIdentity(const Eigen::VectorXf& fitted_alpha, const Eigen::VectorXf& true_alpha);
  // The output tracked again (`loop`, by a tracker calibrated on the output with identity
  // `loop_alpha`), for a frame that was reenacted with the full source expression: its expression
  // against the source's truth and against what was rendered, its identity against the target's.
  void AddLoop(const tracker::TrackedFrame& loop, bool loop_calibrated, const Eigen::VectorXf& loop_alpha,
               const Eigen::VectorXf& source_truth, const Eigen::VectorXf& rendered_expression,
               const Eigen::VectorXf& target_true_alpha);

  // Means over the frames counted; NaN where none was.
  struct Summary {
    int loop_frames = 0;
    double expression_error = 0, jaw_open_error = 0, expression_error_vs_rendered = 0;
    double identity_error_mm = 0, identity_vertex_error_mm = 0;
    double source_expression_error = 0;
    double target_identity_error_mm = 0, target_identity_vertex_error_mm = 0;
  };
  Summary summary() const;

 private:
  struct Mean {
    double sum = 0;
    int n = 0;
    void add(double v) { sum += v, ++n; }
    double value() const;
  };
  // Distance of a fitted identity from a true one, recomputed only when either changes (they
  // change at a calibration, not every frame).
  class IdentityMeter;
  tracker::TrackerModel model_;  // before the meters, which hold a reference to it
  std::unique_ptr<IdentityMeter> target_identity_, loop_identity_;
  Mean expression_, jaw_, rendered_, identity_, identity_vertex_, source_, target_identity_mm_, target_identity_vertex_;
};

}  // namespace face_reenact::reenact
