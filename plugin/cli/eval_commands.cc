// `face-reenact eval fit DIR`: the model fitted to each annotated photo alone, its landmarks
// against the annotation beside the detector's (tracker/photo_fit.h holds the yardstick; this
// file only parses, prints and draws).
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "command_registry.h"
#include "face_reenact/common/byte_io.h"
#include "face_reenact/common/error.h"
#include "face_reenact/common/paths.h"
#include "face_reenact/gpu/cpu_renderer.h"
#include "face_reenact/landmarks/drawing.h"
#include "face_reenact/model/model_file.h"
#include "face_reenact/reenact/fit_overlay.h"
#include "face_reenact/capture/recording.h"
#include "face_reenact/live/frame_grabber.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/tracker/face_tracker.h"
#include "face_reenact/tracker/landmark_binding.h"
#include "face_reenact/tracker/photo_fit.h"
#include "face_reenact/tracker/rgbd_input.h"
#include "face_reenact/tracker/solver.h"

namespace face_reenact::cli {
namespace {

namespace fs = std::filesystem;
namespace lm = face_reenact::landmarks;
using tracker::SolverOptions;

struct EvalFitArgs {
  std::string folder, out, draw, model, shape_predictor;
  double fov_deg = 60.0;
  int max_images = 0;
  bool json = false;
  bool tracker_landmarks = false;
  int contour_rounds = -1;
};

lm::Image image_of(const cv::Mat& bgr) {
  lm::Image im;
  im.width = bgr.cols;
  im.height = bgr.rows;
  im.format = lm::PixelFormat::kBGR8;
  const cv::Mat c = bgr.isContinuous() ? bgr : bgr.clone();
  im.pixels.assign(c.data, c.data + c.total() * c.elemSize());
  return im;
}

void print_table(const tracker::FitEvalReport& r) {
  std::printf("%s: %d annotated photos, %d fitted", r.folder.c_str(), r.images, r.scored);
  if (r.no_face) std::printf(", %d without a face", r.no_face);
  if (r.fit_failed) std::printf(", %d fits failed", r.fit_failed);
  if (r.unreadable) std::printf(", %d unreadable", r.unreadable);
  if (r.bad_annotation) std::printf(", %d bad annotations", r.bad_annotation);
  std::printf(" (camera: %.0f degrees wide)\n\n", r.options.horizontal_fov_deg);
  std::printf("%-44s %8s %8s %8s %8s %8s %8s\n", "photo", "det all", "det in", "det jaw", "fit all", "fit in", "fit jaw");
  for (const tracker::FitEvalImage& e : r.per_image) {
    const std::string name = fs::path(e.path).filename().string();
    if (!e.scored) {
      std::printf("%-44s %s: %s\n", name.c_str(), e.status.c_str(), e.reason.c_str());
      continue;
    }
    std::printf("%-44s %8.4f %8.4f %8.4f %8.4f %8.4f %8.4f\n", name.c_str(), e.detector.all, e.detector.inner,
                e.detector.jaw, e.fit.all, e.fit.inner, e.fit.jaw);
  }
  std::printf("\n%-44s %8.4f %8.4f %8.4f %8.4f %8.4f %8.4f\n", "mean", r.detector_all.mean, r.detector_inner.mean,
              r.detector_jaw.mean, r.fit_all.mean, r.fit_inner.mean, r.fit_jaw.mean);
  std::printf("%-44s %8.4f %8.4f %8.4f %8.4f %8.4f %8.4f\n", "median", r.detector_all.median, r.detector_inner.median,
              r.detector_jaw.median, r.fit_all.median, r.fit_inner.median, r.fit_jaw.median);
  const tracker::ShapeErrors& d = r.detector_part_mean;
  const tracker::ShapeErrors& f = r.fit_part_mean;
  std::printf("\nper part (mean):  brows %.4f | %.4f   nose %.4f | %.4f   eyes %.4f | %.4f   mouth %.4f | %.4f  "
              "(detector | fit)\n",
              d.brows, f.brows, d.nose, f.nose, d.eyes, f.eyes, d.mouth, f.mouth);
  std::printf("\nNME: mean point distance over the annotation's outer-eye-corner distance; 'in' = the 51 inner points, "
              "'jaw' = the 17 of the jaw line.\n");
  if (r.scored > 0) {
    std::printf("bar: fit <= detector + %.3f over all points: %s (%.4f vs %.4f); fit <= detector on the inner points: "
                "%s (%.4f vs %.4f)\n",
                tracker::FitEvalReport::kMaxOverallExcess, r.overall_within_bar() ? "met" : "NOT met", r.fit_all.mean,
                r.detector_all.mean, r.inner_within_bar() ? "met" : "NOT met", r.fit_inner.mean, r.detector_inner.mean);
  }
  std::printf("fit: %.0f ms per photo on average\n", r.fit_ms_mean);
}

void run_eval_fit(const EvalFitArgs& a) {
  std::error_code ec;
  if (!fs::is_directory(a.folder, ec)) throw Error("eval fit: '" + a.folder + "' is not a folder");
  if (!a.out.empty() && !fs::is_directory(fs::absolute(a.out).parent_path(), ec)) {
    throw Error("eval fit: the folder of --out '" + a.out + "' does not exist");
  }
  if (!a.draw.empty()) {
    fs::create_directories(a.draw, ec);
    if (!fs::is_directory(a.draw, ec)) throw Error("eval fit: cannot create --draw folder '" + a.draw + "'");
  }
  tracker::PhotoFitOptions options;
  options.horizontal_fov_deg = a.fov_deg;
  if (a.tracker_landmarks) {
    for (SolverOptions* s : {&options.tracker.tracking_solver, &options.tracker.recovery_solver,
                             &options.tracker.calibration_solver}) {
      s->energy.all_inner_landmarks = false;
      s->energy.use_brow_landmarks = false;
    }
  }
  if (a.contour_rounds >= 0) options.contour_rounds = a.contour_rounds;
  std::string why;
  if (!options.IsValid(&why)) throw Error("eval fit: " + why);

  const FaceModel face_model = load_face_model(resolve_model_path(a.model));
  tracker::PhotoFitter fitter(tracker::TrackerModel::FromFaceModel(face_model), options);
  // The detector as `landmarks --eval` runs it on photos.
  lm::DetectorOptions detector_options;
  detector_options.shape_predictor_path = a.shape_predictor;
  lm::LandmarkDetector detector(detector_options);

  std::unique_ptr<gpu::CpuRenderer> renderer;
  if (!a.draw.empty()) renderer = std::make_unique<gpu::CpuRenderer>(fitter.model().render);
  std::vector<lm::Image> tiles;
  int done = 0;
  const bool progress = !a.json && isatty(STDERR_FILENO);
  const tracker::FitEvalObserver observer = [&](const tracker::FitEvalImage& e, const cv::Mat& bgr,
                                                const tracker::PhotoFit& fit, const lm::Shape68* truth) {
    ++done;
    if (progress) std::fprintf(stderr, "\r[eval fit] %d photos", done);
    if (!renderer || bgr.empty() || fit.camera.width != bgr.cols) return;
    cv::Mat drawn = bgr.clone();
    // The annotation in blue under the detector's (green) and the fit's (red) points.
    if (truth) {
      const double r = std::max(1.5, bgr.cols / 300.0);
      for (const auto& p : *truth) cv::circle(drawn, cv::Point2f(p.x(), p.y()), static_cast<int>(r), {255, 96, 0}, -1, cv::LINE_AA);
    }
    const std::vector<tracker::InputLandmark> detected = tracker::DetectedLandmarks(fit.detected, 1.0f);
    char status[160];
    if (e.scored) {
      std::snprintf(status, sizeof status, "NME detector %.3f  fit %.3f (inner %.3f, jaw %.3f)", e.detector.all,
                    e.fit.all, e.fit.inner, e.fit.jaw);
    } else {
      std::snprintf(status, sizeof status, "%s", e.status.c_str());
    }
    reenact::DrawFitOverlay(&drawn, fitter.model(), *renderer, fit.camera,
                            e.scored ? &fit.params : nullptr, detected, status);
    const std::string name = fs::path(e.path).stem().string() + ".png";
    if (!cv::imwrite((fs::path(a.draw) / name).string(), drawn)) throw Error("eval fit: cannot write '" + name + "' in " + a.draw);
    tiles.push_back(image_of(drawn));
  };
  const tracker::FitEvalReport report =
      tracker::EvaluateFitOnAnnotatedPhotos(a.folder, &fitter, &detector, a.max_images, observer);
  if (progress) std::fprintf(stderr, "\n");
  if (!tiles.empty()) {
    const lm::Image sheet = lm::contact_sheet(tiles, 6, 320);
    cv::Mat m(sheet.height, sheet.width, CV_8UC3, const_cast<uint8_t*>(sheet.pixels.data()));
    if (!cv::imwrite((fs::path(a.draw) / "sheet.png").string(), m)) throw Error("eval fit: cannot write the contact sheet");
  }
  const nlohmann::json json = report.ToJson();
  if (!a.out.empty()) {
    const std::string text = json.dump(1) + "\n";
    write_file_atomic(a.out, std::span<const uint8_t>(reinterpret_cast<const uint8_t*>(text.data()), text.size()));
  }
  if (a.json) {
    std::printf("%s\n", json.dump(1).c_str());
  } else {
    print_table(report);
  }
}

struct EvalBindingsArgs {
  std::vector<std::string> inputs;
  std::string points = "17-29", out, model;
  int frames = 0;
  double fov_deg = 60.0;
  double radius_mm = 25.0;
  bool all_inner_landmarks = false, brow_landmarks = false;
  // Each frame fitted alone as `eval fit` fits a photo (PhotoFitter: every inner point, the brows,
  // the jaw on the contour), every `every`-th frame: the bindings the yardstick's fit needs,
  // measured on frames that are not its photos.
  bool photo_fit = false;
  int every = 1;
};

// "17-29,31" -> {17, ..., 29, 31}.
std::vector<int> parse_points(const std::string& text) {
  std::vector<int> out;
  size_t pos = 0;
  while (pos < text.size()) {
    const size_t comma = std::min(text.find(',', pos), text.size());
    const std::string part = text.substr(pos, comma - pos);
    const size_t dash = part.find('-');
    try {
      const int a = std::stoi(part.substr(0, dash));
      const int b = dash == std::string::npos ? a : std::stoi(part.substr(dash + 1));
      if (a < 0 || b > 67 || a > b) throw std::out_of_range("range");
      for (int i = a; i <= b; ++i) out.push_back(i);
    } catch (const std::exception&) {
      throw Error("eval bindings: --points '" + text + "': give iBUG indices 0..67 like 17-29,31");
    }
    pos = comma + 1;
  }
  return out;
}

void run_eval_bindings(const EvalBindingsArgs& a) {
  if (!a.out.empty() && !fs::is_directory(fs::absolute(a.out).parent_path())) {
    throw Error("eval bindings: the folder of --out '" + a.out + "' does not exist");
  }
  const FaceModel face_model = load_face_model(resolve_model_path(a.model));
  const tracker::TrackerModel model = tracker::TrackerModel::FromFaceModel(face_model);
  tracker::BindingSearchOptions so;
  so.points = parse_points(a.points);
  so.radius_m = a.radius_mm / 1000.0;
  tracker::LandmarkBindingSearch search(model, face_model.mirror_vertex, so);
  std::unique_ptr<tracker::PhotoFitter> photo_fitter;
  std::unique_ptr<lm::LandmarkDetector> detector;
  if (a.photo_fit) {
    tracker::PhotoFitOptions po;
    po.horizontal_fov_deg = a.fov_deg;
    photo_fitter = std::make_unique<tracker::PhotoFitter>(model, po);
    detector = std::make_unique<lm::LandmarkDetector>(lm::DetectorOptions{});
  }
  for (const std::string& input : a.inputs) {
    capture::VideoReader::Options vo;
    vo.horizontal_fov_deg = a.fov_deg;
    std::unique_ptr<capture::FrameSource> source = live::open_offline_source(input, "eval bindings: --input", vo);
    tracker::RgbdInput rgbd{tracker::RgbdInputOptions()};
    tracker::TrackerOptions to;
    for (SolverOptions* s : {&to.calibration_solver, &to.tracking_solver, &to.recovery_solver}) {
      s->energy.all_inner_landmarks = a.all_inner_landmarks;
      s->energy.use_brow_landmarks = a.brow_landmarks;
    }
    tracker::FaceTracker tracker(model, to);
    capture::RgbdFrame frame;
    int read = 0, used = 0;
    while ((a.frames <= 0 || read < a.frames) && source->read_next(&frame)) {
      ++read;
      if (photo_fitter) {
        if ((read - 1) % a.every != 0) continue;
        const tracker::PhotoFit fit = photo_fitter->Fit(frame.color, detector.get());
        if (!fit.ok || !fit.tracked.agreement.agrees() || !fit.tracked.agreement.landmark_warning.empty()) continue;
        used += search.Add(fit.params, fit.camera, tracker::DetectedLandmarks(fit.detected, 1.0f));
        continue;
      }
      const tracker::InputFrame in = rgbd.Convert(frame);
      const tracker::TrackedFrame t = tracker.Track(in);
      const bool fit = tracker::tracking_status_has_fit(t.status);
      rgbd.SetTrackedPose(t.params, fit);
      // Only fits that agree with their landmarks (fit_agreement.h): a fit off the face would
      // pull every binding towards its error.
      if (!fit || !t.agreement.agrees() || !t.agreement.landmark_warning.empty()) continue;
      used += search.Add(t.params, in.camera, in.landmarks);
    }
    std::fprintf(stderr, "[eval bindings] %s: %d frames, %d with a fit that agrees\n", input.c_str(), read, used);
  }
  const auto results = search.Results();
  const nlohmann::json json = {{"frames", search.frames_used()},
                               {"inputs", a.inputs},
                               {"radius_mm", a.radius_mm},
                               {"unit", "mean distance from the detector's point over the eye distance (outer corners)"},
                               {"points", tracker::to_json(results, face_model.base_vertex)}};
  if (!a.out.empty()) {
    const std::string text = json.dump(1) + "\n";
    write_file_atomic(a.out, std::span<const uint8_t>(reinterpret_cast<const uint8_t*>(text.data()), text.size()));
  }
  std::printf("%5s %7s %12s %9s %12s %9s %9s\n", "ibug", "frames", "now (hm08)", "error", "best (hm08)", "error", "moved mm");
  for (const auto& r : results) {
    std::printf("%5d %7d %12d %9.4f %12d %9.4f %9.1f\n", r.ibug_index, r.frames, face_model.base_vertex[static_cast<size_t>(r.current_vertex)],
                r.current_error, face_model.base_vertex[static_cast<size_t>(r.best_vertex)], r.best_error, r.best_moved_mm);
  }
}

void add_eval(CLI::App& app) {
  CLI::App* eval = app.add_subcommand("eval", "Yardsticks on real data");
  eval->require_subcommand(1);
  auto args = std::make_shared<EvalFitArgs>();
  CLI::App* fit = eval->add_subcommand(
      "fit", "Fit the model to each photo with a 68-point .pts annotation alone (RGB only) and report the fitted "
             "landmarks' error against the annotation beside the detector's (NME; all, inner 51, jaw line)");
  fit->add_option("folder", args->folder, "folder of photos with .pts annotations beside them (recursive)")->required();
  fit->add_option("--out", args->out, "write the report as JSON to this file");
  fit->add_flag("--json", args->json, "print the JSON report instead of the table");
  fit->add_option("--draw", args->draw,
                  "folder for one picture per photo (annotation blue, detector green, fit red, the mesh) and sheet.png");
  fit->add_option("--fov", args->fov_deg, "horizontal field of view assumed for the photos (degrees, default 60)")
      ->check(CLI::Range(10.0, 150.0));
  fit->add_option("--max-images", args->max_images, "stop after N photos (0: all)")->check(CLI::NonNegativeNumber);
  fit->add_flag("--tracker-landmarks", args->tracker_landmarks,
                "fit the tracker's landmark set (without the brows, the eye points and the nose base) instead of the 38 inner points and the brows");
  fit->add_option("--contour-rounds", args->contour_rounds,
                  "rounds of the jaw line fitted to the face's contour (default 3; 0: the inner points and brows only)")
      ->check(CLI::Range(0, 20));
  fit->add_option("--model", args->model, "face model file (default: the installed/generated face-model.frm)");
  fit->add_option("--shape-predictor", args->shape_predictor, "dlib 68-point model (default: libdlib-data's)");
  fit->callback([args] { run_eval_fit(*args); });

  auto bargs = std::make_shared<EvalBindingsArgs>();
  CLI::App* bind = eval->add_subcommand(
      "bindings", "Track videos and measure, for each iBUG point, which model vertex near its current binding projects "
                  "closest to the detector's point (authoring data/ibug68_landmarks.json from real faces)");
  bind->add_option("--input", bargs->inputs, "video, recording or .oni (repeatable)")->required();
  bind->add_option("--points", bargs->points, "iBUG points to search, e.g. 17-29 (default)");
  bind->add_option("--frames", bargs->frames, "at most N frames per input (0: all)")->check(CLI::NonNegativeNumber);
  bind->add_option("--fov", bargs->fov_deg, "horizontal field of view of the videos (degrees, default 60)")->check(CLI::Range(10.0, 150.0));
  bind->add_option("--radius", bargs->radius_mm, "candidate vertices within this many mm of the current binding (default 25)")
      ->check(CLI::Range(1.0, 100.0));
  bind->add_option("--out", bargs->out, "write the results as JSON");
  bind->add_flag("--all-inner-landmarks", bargs->all_inner_landmarks, "track with the eye points and the nose base too");
  bind->add_flag("--brow-landmarks", bargs->brow_landmarks,
                 "track with the brows too (not for searching the brows themselves: the fit would hold them where they are bound)");
  bind->add_flag("--photo-fit", bargs->photo_fit,
                 "fit each frame alone as `eval fit` fits a photo (every inner point, the brows, the jaw on the contour) instead of tracking");
  bind->add_option("--every", bargs->every, "with --photo-fit: every N-th frame (default 1)")->check(CLI::Range(1, 10000));
  bind->add_option("--model", bargs->model, "face model file (default: the installed/generated face-model.frm)");
  bind->callback([bargs] { run_eval_bindings(*bargs); });
}

}  // namespace

FR_REGISTER_COMMANDS(eval, add_eval);

}  // namespace face_reenact::cli
