#pragma once
// The model fitted to one photo alone, and the real-data yardstick built on it (`face-reenact
// eval fit`): on photos with hand-annotated 68-point landmarks (300-W `.pts`), how far the fitted
// model's own landmarks lie from the annotation, beside how far the detector's lie. The detector's
// points are the fit's only landmark evidence, so a fit that keeps their accuracy adds the whole
// model (pose, identity, expression) without losing any of what the detector saw; a fit that
// lands farther off says which part of the model (the correspondence of its landmark vertices,
// its expression space) misses real faces. docs/tracking-pipeline.md, "A yardstick on real photos".
#include <array>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "face_reenact/gpu/image_formation.h"
#include "face_reenact/landmarks/landmark_detector.h"
#include "face_reenact/tracker/face_tracker.h"
#include "face_reenact/tracker/fit_agreement.h"
#include "face_reenact/tracker/tracker_model.h"

namespace face_reenact::tracker {

struct PhotoFitOptions {
  // A photo carries no intrinsics: the camera is a pinhole with this horizontal field of view
  // (the tracker's default for videos).
  double horizontal_fov_deg = 60.0;
  // The fit: the tracker's calibration over the one photo (identity, albedo, expression,
  // lighting, pose jointly, RGB only), then its per-frame solve with that identity. `IsValid`
  // requires calibration_frames 1 and no calibration window. Unlike the tracker's default, E_lan
  // takes all 38 inner points and the brows (EnergyOptions::all_inner_landmarks,
  // use_brow_landmarks): the tracker leaves the eyes and the nose base out because on video dlib's
  // eye points do not follow a closing lid and pulled the pose of synthetic actors, and the brows
  // because the paper's 38 points have none; a photo has no previous frame to hold the face, and
  // on faces-68 the eyes came 0.077 -> 0.022 eye distances from the annotation with their points,
  // the brows 0.100 -> 0.036 with theirs (docs/tracking-pipeline.md, "A yardstick on real photos").
  // The calibration's dense terms on every pixel, on the schedule's level however large the face
  // (no calibration_max_face_width_px): a photo is fitted once, with nobody waiting for a first
  // frame, and its colour is all the evidence there is besides the landmarks.
  TrackerOptions tracker = [] {
    TrackerOptions t;
    t.calibration_frames = 1;
    t.calibration_solver.energy.pixel_sampling = 1;
    t.calibration_max_face_width_px = 0;
    for (SolverOptions* s : {&t.calibration_solver, &t.tracking_solver, &t.recovery_solver}) {
      s->energy.all_inner_landmarks = true;
      s->energy.use_brow_landmarks = true;
    }
    return t;
  }();

  // The jaw line: after the tracker's fit, the 17 jaw points are added to E_lan matched to the
  // face's occluding contour (ContourLandmarks: the vertex the contour passes through at each
  // point's height, chosen again after each round), and identity, expression, lighting and pose
  // are solved again (contour_iterations Gauss-Newton steps of the calibration solve per round):
  // the face's outline is evidence of its width and its chin that the inner points do not give.
  // 0 rounds: no contour fit (the jaw points are still measured on the contour).
  int contour_rounds = 3;
  int contour_iterations = 10;

  bool IsValid(std::string* why) const;
};

// One photo's fit.
struct PhotoFit {
  bool ok = false;            // a fit with parameters of its own (tracking_status_has_fit)
  std::string message;        // why not, or the tracker's message for this frame
  gpu::PinholeCamera camera;  // the photo's assumed camera
  landmarks::LandmarkResult detected;
  TrackedFrame tracked;       // the tracker's result (status, parameters, agreement, times)
  gpu::FaceParameters params; // the fit (the tracker's, refined by the contour rounds)
  ProjectedLandmarks fitted;  // the fit's 68 landmarks, the jaw line on the contour (valid when ok)
  double detect_ms = 0, fit_ms = 0;
};

// Fits photos one at a time; each fit starts from nothing (the tracker is reset), so the order of
// the photos does not matter. Thread-compatible.
class PhotoFitter {
 public:
  // Throws face_reenact::Error on invalid options or model.
  PhotoFitter(TrackerModel model, const PhotoFitOptions& options);
  ~PhotoFitter();

  // `bgr`: CV_8UC3. The detector's landmarks are taken with `hint` (e.g. which face of several).
  // Never throws for image content: no face or a failed fit is ok == false with the reason.
  PhotoFit Fit(const cv::Mat& bgr, landmarks::LandmarkDetector* detector, const landmarks::TrackingHint& hint = {});

  const TrackerModel& model() const { return tracker_->model(); }
  const PhotoFitOptions& options() const { return options_; }

 private:
  PhotoFitOptions options_;
  std::unique_ptr<FaceTracker> tracker_;
};

// Normalised mean errors of one 68-point shape against an annotation (landmarks::nme_outer_eye:
// over the annotation's outer-eye-corner distance), over all 68 points, the 51 inner points
// (brows, nose, eyes, mouth), the 17 of the jaw line, and per part of the inner ones (iBUG 17-26,
// 27-35, 36-47, 48-67), which says where a fit misses.
struct ShapeErrors {
  double all = 0, inner = 0, jaw = 0;
  double brows = 0, nose = 0, eyes = 0, mouth = 0;
};
ShapeErrors MeasureShapeErrors(const landmarks::Shape68& predicted, const landmarks::Shape68& truth);

struct FitEvalImage {
  std::string path;
  // "fitted"; "no face" (the detector found none); "fit failed" (the tracker's reason);
  // "unreadable image"; "bad annotation" (a malformed .pts, or another point count).
  std::string status;
  std::string reason;
  bool scored = false;  // detector and fit both measured
  ShapeErrors detector, fit;
  std::string tracking_status;  // the tracker's status name for the fitted photo
  Eigen::Vector3d euler_deg = Eigen::Vector3d::Zero();  // the fitted head rotation (FaceParameters::euler)
  Eigen::VectorXf expression;  // the fitted blendshape weights (FaceParameters::delta)
  double pose_disagreement_deg = FitAgreement::kNaN;  // fit_agreement.h's, against the detector's points
  // The 68 points in pixels (scored images): where the detector and the fit put each, so a
  // binding's systematic offset can be told from a miss of the model's reach.
  landmarks::Shape68 detector_points{}, fit_points{};
  double detect_ms = 0, fit_ms = 0;
};

struct FitEvalReport {
  std::string folder;
  PhotoFitOptions options;
  int images = 0;   // annotated images found
  int scored = 0;   // with both a detection and a fit
  int no_face = 0, fit_failed = 0, unreadable = 0, bad_annotation = 0;
  // Over the scored images: the per-image NMEs' distribution (fit_agreement.h's Summarize).
  Distribution detector_all, detector_inner, detector_jaw, fit_all, fit_inner, fit_jaw;
  ShapeErrors detector_part_mean, fit_part_mean;  // per part (brows, nose, eyes, mouth), mean over the scored images
  // Per iBUG point, the mean over the scored images of its distance from the annotation (in eye
  // distances): which of the model's landmark vertices misses where annotators put the point.
  std::array<double, landmarks::kNumLandmarks> detector_point_mean{}, fit_point_mean{};
  // The bar (#26): the fit may not make the landmarks worse than the points it was fitted
  // to: mean fitted NME at most the detector's + max_overall_excess over all 68, at most the
  // detector's on the inner 51.
  static constexpr double kMaxOverallExcess = 0.003;
  bool overall_within_bar() const { return fit_all.mean <= detector_all.mean + kMaxOverallExcess; }
  bool inner_within_bar() const { return fit_inner.mean <= detector_inner.mean; }
  double fit_ms_mean = 0;
  std::vector<FitEvalImage> per_image;

  nlohmann::json ToJson() const;
};

// Called after each image (e.g. to draw it or print progress).
using FitEvalObserver = std::function<void(const FitEvalImage& entry, const cv::Mat& bgr, const PhotoFit& fit,
                                           const landmarks::Shape68* truth)>;

// Every image with a .pts beside it under `folder` (landmarks::list_annotated_images), at most
// `max_images` (<= 0: all). Where a photo shows several faces, the detection overlapping the
// annotated face is fitted (the 300-W protocol; the annotation picks the face, never its points).
// Throws face_reenact::Error when the folder is missing or holds no annotated image; a bad image
// or annotation is an entry with its reason.
FitEvalReport EvaluateFitOnAnnotatedPhotos(const std::string& folder, PhotoFitter* fitter,
                                           landmarks::LandmarkDetector* detector, int max_images = 0,
                                           const FitEvalObserver& observer = {});

}  // namespace face_reenact::tracker
