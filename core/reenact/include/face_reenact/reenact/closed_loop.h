#pragma once
// The reenactment's yardsticks (docs/reenactment.md).
// - The closed loop: the reenacted output is tracked again, and its expressions are compared with
//   the source actor's and its calibrated identity with the target actor's. On actors with ground
//   truth (`face-reenact demo`) the references are the true ones, and the source's tracking and
//   the target's calibration are scored on the way; on real video (`reenact --closed-loop`) they
//   are the source's tracked expression and the target's calibrated identity.
// - The rendering's fidelity: the re-rendered face region against the frame it re-renders (PSNR,
//   SSIM), for a pass-through, where the output should be the input.
// The front-end runs the actors through the pipeline and feeds each frame here; the figures are
// the library's.
#include <Eigen/Core>
#include <memory>
#include <string>
#include <utility>
#include <vector>
#include <opencv2/core.hpp>

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
    // The loop's expression error per blendshape (mean absolute difference from the source's, in
    // arkit_blendshape_names() order; empty when no loop frame was counted): which expressions the
    // output carries and which it loses.
    std::vector<double> expression_error_by_blendshape;
    // The `n` blendshapes of largest error, largest first, as (name, error).
    std::vector<std::pair<std::string, double>> WorstBlendshapes(int n) const;
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
  std::vector<double> blendshape_error_sums_;  // per blendshape, summed over expression_'s frames
};

// The face region of an output frame against the frame it re-renders. Both CV_8UC3 of one size,
// `mask` CV_8UC1 of that size (non-zero: the face). PSNR in dB over the masked pixels' three
// channels (infinite where they are equal); SSIM of the luma (BT.601) with Gaussian windows of
// sigma 1.5 and the constants of Wang et al. 2004, averaged over the masked pixels. NaN for both,
// and 0 pixels, when the mask is empty. Throws Error on mismatched inputs.
struct FaceFidelity {
  double psnr_db = 0, ssim = 0;
  int pixels = 0;
};
FaceFidelity MeasureFaceFidelity(const cv::Mat& reference_bgr, const cv::Mat& output_bgr, const cv::Mat& mask);

// Means over a clip's frames (frames with an empty mask are not counted); NaN where none was.
class FaceFidelityTally {
 public:
  void Add(const FaceFidelity& f);
  struct Summary {
    int frames = 0;
    double psnr_db = 0, ssim = 0;  // means over the frames (a frame's infinite PSNR counts as 99 dB)
    double psnr_db_min = 0;        // the worst frame
  };
  Summary summary() const;

 private:
  int frames_ = 0;
  double psnr_sum_ = 0, ssim_sum_ = 0, psnr_min_ = 0;
};

}  // namespace face_reenact::reenact
