// The model fitted to one photo, and the annotated-photo yardstick (photo_fit.h).
#include "face_reenact/tracker/photo_fit.h"

#include <algorithm>
#include <cmath>

#include "face_reenact/capture/media_file.h"
#include "face_reenact/capture/recording.h"
#include "face_reenact/common/error.h"
#include "face_reenact/common/json_number.h"
#include "face_reenact/common/timing.h"
#include "face_reenact/landmarks/evaluation.h"
#include "face_reenact/tracker/rgbd_input.h"
#include "tracker_internal.h"

namespace face_reenact::tracker {

namespace {

nlohmann::json errors_json(const ShapeErrors& e) {
  return {{"all", e.all},     {"inner", e.inner}, {"jaw", e.jaw},     {"brows", e.brows},
          {"nose", e.nose},   {"eyes", e.eyes},   {"mouth", e.mouth}};
}

// Mean per part over the scored images.
ShapeErrors part_mean(const std::vector<FitEvalImage>& images, ShapeErrors FitEvalImage::*which) {
  ShapeErrors m;
  int n = 0;
  for (const FitEvalImage& e : images) {
    if (!e.scored) continue;
    const ShapeErrors& x = e.*which;
    m.all += x.all, m.inner += x.inner, m.jaw += x.jaw;
    m.brows += x.brows, m.nose += x.nose, m.eyes += x.eyes, m.mouth += x.mouth;
    ++n;
  }
  if (n == 0) return m;
  for (double* v : {&m.all, &m.inner, &m.jaw, &m.brows, &m.nose, &m.eyes, &m.mouth}) *v /= n;
  return m;
}

}  // namespace

bool PhotoFitOptions::IsValid(std::string* why) const {
  if (!(horizontal_fov_deg >= 10.0 && horizontal_fov_deg <= 150.0)) {
    return fail_why(why, "photo fit: the field of view must be 10..150 degrees");
  }
  if (tracker.calibration_frames != 1 || tracker.calibration_window_frames != 0) {
    return fail_why(why, "photo fit: one photo is one calibration frame (calibration_frames 1, no window)");
  }
  if (tracker.background_calibration) return fail_why(why, "photo fit: the calibration runs in the foreground");
  if (contour_rounds < 0 || contour_rounds > 20) return fail_why(why, "photo fit: contour_rounds must be 0..20");
  if (contour_iterations < 1 || contour_iterations > 200) return fail_why(why, "photo fit: contour_iterations must be 1..200");
  return tracker.IsValid(why);
}

PhotoFitter::PhotoFitter(TrackerModel model, const PhotoFitOptions& options) : options_(options) {
  std::string why;
  if (!options_.IsValid(&why)) throw Error(why);
  tracker_ = std::make_unique<FaceTracker>(std::move(model), options_.tracker);
}

PhotoFitter::~PhotoFitter() = default;

PhotoFit PhotoFitter::Fit(const cv::Mat& bgr, landmarks::LandmarkDetector* detector,
                          const landmarks::TrackingHint& hint) {
  PhotoFit out;
  if (bgr.empty() || bgr.type() != CV_8UC3 || bgr.cols < 16 || bgr.rows < 16) {
    out.message = "not an 8-bit colour image of at least 16x16 pixels";
    return out;
  }
  const cv::Mat image = bgr.isContinuous() ? bgr : bgr.clone();
  out.camera = capture::camera_from_fov(image.cols, image.rows, options_.horizontal_fov_deg);
  auto t0 = internal::Clock::now();
  out.detected = detector->Detect(
      landmarks::ImageView{image.data, image.cols, image.rows, image.step[0], landmarks::PixelFormat::kBGR8}, hint);
  out.detect_ms = ms_since(t0);
  if (!out.detected.has_landmarks) {
    out.message = "no face: " + out.detected.reason;
    return out;
  }

  capture::RgbdFrame frame;
  frame.color = image;
  frame.camera = out.camera;
  InputFrame input = MakeInputFrameNoLandmarks(frame, /*use_depth=*/false);
  input.landmarks = DetectedLandmarks(out.detected, 1.0f);

  t0 = internal::Clock::now();
  tracker_->Reset();
  out.tracked = tracker_->Track(input, out.detect_ms);
  out.message = out.tracked.message;
  // A photo that did not calibrate (too few landmarks for the calibration's checks) has at best
  // the mean face's fit, which is not the photo's fit.
  out.ok = out.tracked.status == TrackingStatus::kCalibrated && out.tracked.has_parameters;
  if (!out.ok && out.message.empty()) out.message = tracking_status_name(out.tracked.status);
  if (!out.ok) return out;
  const TrackerModel& model = tracker_->model();
  out.params = out.tracked.params;
  if (options_.contour_rounds > 0) {
    // The calibration's solve for this face (its level and sampling), with the jaw line's rounds.
    SolverOptions so = CalibrationSolverForFace(
        options_.tracker, LandmarkExtentPx(input, options_.tracker.loss.min_landmark_confidence));
    so.energy.inner_landmarks_only = false;  // the jaw line (and the brows) too
    so.schedule.resize(1);
    so.schedule[0].gauss_newton_iterations = options_.contour_iterations;
    const ParameterLayout layout =
        ParameterLayout::Calibration(model.num_identity(), model.num_albedo(), model.num_expression());
    std::vector<gpu::FaceParameters> params{out.params};
    for (int round = 0; round < options_.contour_rounds; ++round) {
      std::array<int, 68> vertex_of{};
      vertex_of.fill(-1);
      for (const auto& l : ContourLandmarks(model, params[0], out.camera)) {
        if (l.ibug_index >= 0 && l.ibug_index < 68) vertex_of[static_cast<size_t>(l.ibug_index)] = l.vertex;
      }
      for (auto& l : input.landmarks) {
        if (l.ibug_index >= 0 && l.ibug_index < 17) l.model_vertex = vertex_of[static_cast<size_t>(l.ibug_index)];
      }
      std::vector<gpu::FaceParameters> trial = params;
      const SolverSummary summary = tracker_->cpu_solver().SolveFrames({input}, layout, so, &trial);
      // A solve that found nothing to fit or went non-finite keeps the fit it started from.
      if (summary.termination == Termination::kNoValidResiduals || summary.termination == Termination::kNonFinite) break;
      params = std::move(trial);
    }
    out.params = params[0];
  }
  const std::vector<TrackerLandmark> contour = ContourLandmarks(model, out.params, out.camera);
  out.fitted = ProjectModelLandmarks(model, out.params, out.camera, &contour);
  out.fit_ms = ms_since(t0);
  return out;
}

ShapeErrors MeasureShapeErrors(const landmarks::Shape68& predicted, const landmarks::Shape68& truth) {
  using Mask = std::array<bool, landmarks::kNumLandmarks>;
  auto range = [](int from, int to) {
    Mask m{};
    for (int i = from; i < to; ++i) m[static_cast<size_t>(i)] = true;
    return m;
  };
  auto nme = [&](const Mask& use) { return static_cast<double>(landmarks::nme_outer_eye(predicted, truth, use)); };
  ShapeErrors e;
  e.all = nme(range(0, 68));
  e.inner = nme(range(17, 68));
  e.jaw = nme(range(0, 17));
  e.brows = nme(range(17, 27));
  e.nose = nme(range(27, 36));
  e.eyes = nme(range(36, 48));
  e.mouth = nme(range(48, 68));
  return e;
}

nlohmann::json FitEvalReport::ToJson() const {
  nlohmann::json j;
  j["folder"] = folder;
  j["normalisation"] = "mean point distance over the annotation's outer-eye-corner distance (points 36, 45)";
  j["camera_horizontal_fov_deg"] = options.horizontal_fov_deg;
  j["images"] = images;
  j["scored"] = scored;
  j["no_face"] = no_face;
  j["fit_failed"] = fit_failed;
  j["unreadable"] = unreadable;
  j["bad_annotation"] = bad_annotation;
  j["detector_nme"] = {{"all", to_json(detector_all)}, {"inner", to_json(detector_inner)}, {"jaw", to_json(detector_jaw)}};
  j["fit_nme"] = {{"all", to_json(fit_all)}, {"inner", to_json(fit_inner)}, {"jaw", to_json(fit_jaw)}};
  j["detector_nme_per_part_mean"] = errors_json(detector_part_mean);
  j["fit_nme_per_part_mean"] = errors_json(fit_part_mean);
  j["detector_nme_per_point_mean"] = detector_point_mean;
  j["fit_nme_per_point_mean"] = fit_point_mean;
  j["bar"] = {{"rule", "mean fitted NME <= detector's + 0.003 over all 68 points, <= detector's on the inner 51"},
              {"overall_within", scored > 0 && overall_within_bar()},
              {"inner_within", scored > 0 && inner_within_bar()}};
  j["fit_ms_mean"] = fit_ms_mean;
  nlohmann::json per = nlohmann::json::array();
  for (const FitEvalImage& e : per_image) {
    nlohmann::json p{{"path", e.path}, {"status", e.status}};
    if (!e.reason.empty()) p["reason"] = e.reason;
    if (e.scored) {
      p["detector_nme"] = errors_json(e.detector);
      p["fit_nme"] = errors_json(e.fit);
      p["tracking_status"] = e.tracking_status;
      p["euler_deg"] = {e.euler_deg.x(), e.euler_deg.y(), e.euler_deg.z()};
      p["expression"] = std::vector<float>(e.expression.data(), e.expression.data() + e.expression.size());
      p["pose_disagreement_deg"] = json_number(e.pose_disagreement_deg);
      auto points_json = [](const landmarks::Shape68& s) {
        nlohmann::json a = nlohmann::json::array();
        for (const auto& q : s) a.push_back({q.x(), q.y()});
        return a;
      };
      p["detector_points"] = points_json(e.detector_points);
      p["fit_points"] = points_json(e.fit_points);
    }
    p["detect_ms"] = e.detect_ms;
    p["fit_ms"] = e.fit_ms;
    per.push_back(std::move(p));
  }
  j["per_image"] = std::move(per);
  return j;
}

FitEvalReport EvaluateFitOnAnnotatedPhotos(const std::string& folder, PhotoFitter* fitter,
                                           landmarks::LandmarkDetector* detector, int max_images,
                                           const FitEvalObserver& observer) {
  FitEvalReport report;
  report.folder = folder;
  report.options = fitter->options();
  std::vector<std::string> paths = landmarks::list_annotated_images(folder);
  if (max_images > 0 && static_cast<int>(paths.size()) > max_images) paths.resize(static_cast<size_t>(max_images));
  std::vector<double> det_all, det_inner, det_jaw, fit_all, fit_inner, fit_jaw, fit_ms;
  for (const std::string& path : paths) {
    ++report.images;
    FitEvalImage e;
    e.path = path;
    landmarks::Shape68 truth{};
    cv::Mat bgr;
    PhotoFit fit;
    try {
      truth = landmarks::read_pts(landmarks::annotation_path(path));
    } catch (const Error& err) {
      e.status = "bad annotation";
      e.reason = err.what();
      ++report.bad_annotation;
    }
    if (e.status.empty()) {
      try {
        bgr = capture::read_still_image(path);
      } catch (const Error& err) {
        e.status = "unreadable image";
        e.reason = err.what();
        ++report.unreadable;
      }
    }
    if (e.status.empty()) {
      fit = fitter->Fit(bgr, detector, landmarks::annotated_face_hint(truth));
      e.detect_ms = fit.detect_ms;
      e.fit_ms = fit.fit_ms;
      if (!fit.detected.has_landmarks) {
        e.status = "no face";
        e.reason = fit.message;
        ++report.no_face;
      } else if (!fit.ok) {
        e.status = "fit failed";
        e.reason = fit.message;
        ++report.fit_failed;
      } else {
        e.status = "fitted";
        e.scored = true;
        e.detector = MeasureShapeErrors(fit.detected.points, truth);
        e.fit = MeasureShapeErrors(fit.fitted.points, truth);
        e.tracking_status = tracking_status_name(fit.tracked.status);
        e.euler_deg = fit.params.euler.cast<double>() * (180.0 / M_PI);
        e.expression = fit.params.delta;
        e.pose_disagreement_deg = fit.tracked.agreement.pose_disagreement_deg;
        e.detector_points = fit.detected.points;
        e.fit_points = fit.fitted.points;
        ++report.scored;
        det_all.push_back(e.detector.all);
        det_inner.push_back(e.detector.inner);
        det_jaw.push_back(e.detector.jaw);
        fit_all.push_back(e.fit.all);
        fit_inner.push_back(e.fit.inner);
        fit_jaw.push_back(e.fit.jaw);
        fit_ms.push_back(e.fit_ms);
        const double iod = std::max(1e-6f, (truth[36] - truth[45]).norm());
        for (size_t k = 0; k < truth.size(); ++k) {
          report.detector_point_mean[k] += (fit.detected.points[k] - truth[k]).norm() / iod;
          report.fit_point_mean[k] += (fit.fitted.points[k] - truth[k]).norm() / iod;
        }
      }
    }
    if (observer) observer(e, bgr, fit, e.status == "bad annotation" ? nullptr : &truth);
    report.per_image.push_back(std::move(e));
  }
  report.detector_all = Summarize(det_all);
  report.detector_inner = Summarize(det_inner);
  report.detector_jaw = Summarize(det_jaw);
  report.fit_all = Summarize(fit_all);
  report.fit_inner = Summarize(fit_inner);
  report.fit_jaw = Summarize(fit_jaw);
  for (size_t k = 0; k < report.fit_point_mean.size() && report.scored > 0; ++k) {
    report.detector_point_mean[k] /= report.scored;
    report.fit_point_mean[k] /= report.scored;
  }
  report.detector_part_mean = part_mean(report.per_image, &FitEvalImage::detector);
  report.fit_part_mean = part_mean(report.per_image, &FitEvalImage::fit);
  report.fit_ms_mean = Summarize(fit_ms).mean;
  if (!std::isfinite(report.fit_ms_mean)) report.fit_ms_mean = 0;
  return report;
}

}  // namespace face_reenact::tracker
