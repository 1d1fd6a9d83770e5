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
    }
  }
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
                            e.scored ? &fit.tracked.params : nullptr, detected, status);
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
                "fit the tracker's landmark set (without the eye points and the nose base) instead of all 38 inner points");
  fit->add_option("--model", args->model, "face model file (default: the installed/generated face-model.frm)");
  fit->add_option("--shape-predictor", args->shape_predictor, "dlib 68-point model (default: libdlib-data's)");
  fit->callback([args] { run_eval_fit(*args); });
}

}  // namespace

FR_REGISTER_COMMANDS(eval, add_eval);

}  // namespace face_reenact::cli
