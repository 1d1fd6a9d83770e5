// The model fitted to one photo and the annotated-photo yardstick (photo_fit.h), and
// `face-reenact eval fit` end to end: the error measure on shapes with known offsets, the fit's
// own landmarks, real photos of ../shared/data/faces-68 (skipped when that folder is absent), and
// bad input (a malformed or short .pts, a photo without a face, a file that is not an image).
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <string>
#include <vector>

#include "face_reenact/common/subprocess.h"
#include "face_reenact/gpu/cpu_renderer.h"
#include "face_reenact/landmarks/evaluation.h"
#include "face_reenact/common/error.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/model/model_file.h"
#include "face_reenact/tracker/energy.h"
#include "face_reenact/tracker/landmark_binding.h"
#include "face_reenact/tracker/photo_fit.h"
#include "face_reenact/tracker/solver.h"
#include "support/temp_dir.h"
#include "tracker_test_support.h"

namespace face_reenact::tracker {
namespace {

namespace fs = std::filesystem;
using landmarks::Shape68;

std::string shared_faces() {
  const char* s = std::getenv("FR_SHARED_DATA");
  const std::string dir = std::string(s ? s : "") + "/faces-68";
  return s && fs::is_directory(dir) ? dir : "";
}

std::string cli() {
  const char* c = std::getenv("FR_CLI");
  return c ? c : "";
}

Shape68 square_shape() {
  Shape68 s{};
  for (int i = 0; i < 68; ++i) s[static_cast<size_t>(i)] = {10.f * (i % 9), 10.f * (i / 9)};
  s[36] = {0.f, 0.f};
  s[45] = {100.f, 0.f};  // eye distance 100 px
  return s;
}

void write_text(const fs::path& path, const std::string& text) { std::ofstream(path) << text; }

std::string pts_text(const Shape68& s, int points) {
  std::string t = "version: 1\nn_points: " + std::to_string(points) + "\n{\n";
  for (int i = 0; i < points; ++i) {
    // 1-based, the 300-W convention read_pts undoes.
    t += std::to_string(s[static_cast<size_t>(i % 68)].x() + 1) + " " + std::to_string(s[static_cast<size_t>(i % 68)].y() + 1) + "\n";
  }
  return t + "}\n";
}

TEST(ShapeErrors, AreTheMeanOffsetOverTheEyeDistancePerPart) {
  const Shape68 truth = square_shape();
  Shape68 moved = truth;
  // Jaw points 5 px off, brows 10, nose 20, eyes 0, mouth 30 (eye distance 100 px).
  for (int i = 0; i < 68; ++i) {
    const float d = i < 17 ? 5.f : i < 27 ? 10.f : i < 36 ? 20.f : i < 48 ? 0.f : 30.f;
    moved[static_cast<size_t>(i)].y() += d;
  }
  const ShapeErrors e = MeasureShapeErrors(moved, truth);
  EXPECT_NEAR(e.jaw, 0.05, 1e-6);
  EXPECT_NEAR(e.brows, 0.10, 1e-6);
  EXPECT_NEAR(e.nose, 0.20, 1e-6);
  EXPECT_NEAR(e.eyes, 0.0, 1e-6);
  EXPECT_NEAR(e.mouth, 0.30, 1e-6);
  EXPECT_NEAR(e.inner, (10 * 0.1 + 9 * 0.2 + 12 * 0.0 + 20 * 0.3) / 51, 1e-6);
  EXPECT_NEAR(e.all, (17 * 0.05 + 10 * 0.1 + 9 * 0.2 + 20 * 0.3) / 68, 1e-6);
}

TEST(ProjectModelLandmarks, AreTheLandmarkVerticesThroughTheCamera) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const gpu::PinholeCamera camera = testing::test_camera();
  const gpu::FaceParameters p = testing::true_parameters(*model, 0.6f, 11);
  const ProjectedLandmarks projected = ProjectModelLandmarks(*model, p, camera);
  int bound = 0;
  for (bool b : projected.bound) bound += b;
  EXPECT_EQ(bound, static_cast<int>(model->landmarks.size()));
  // The nose tip (30) of a face 0.6 m in front of the camera lies inside the image, between the
  // eye corners horizontally.
  const Eigen::Vector2f tip = projected.points[30];
  EXPECT_GT(tip.x(), 0.f);
  EXPECT_LT(tip.x(), camera.width);
  EXPECT_GT(tip.y(), 0.f);
  EXPECT_LT(tip.y(), camera.height);
  EXPECT_GT(tip.x(), std::min(projected.points[36].x(), projected.points[45].x()));
  EXPECT_LT(tip.x(), std::max(projected.points[36].x(), projected.points[45].x()));
  // A face behind the camera: every point as far off as it gets, so an error measured says so.
  gpu::FaceParameters behind = p;
  behind.translation.z() = -0.6f;
  for (const auto& q : ProjectModelLandmarks(*model, behind, camera).points) EXPECT_GE(q.x(), 1e8f);
}

// The jaw line on the face's outline: every jaw point, the chin included, lies on the outline
// of the rendered face (within the mesh's vertex spacing), where the bound vertices of a turned
// head lie inside the cheek; every other point keeps its binding; turning the head slides the
// points over the cheek.
TEST(ContourLandmarks, LieOnTheFacesOutlineAsTheHeadTurns) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const gpu::PinholeCamera camera = testing::test_camera();
  const gpu::CpuRenderer renderer(model->render);
  gpu::RenderOptions face_only;
  face_only.parts = 1u << static_cast<int>(FacePart::Face);
  face_only.cull_back_faces = false;
  gpu::FaceParameters p = testing::true_parameters(*model, 0.6f, 11);
  // Pixels from `x` to the nearest pixel the face does not cover (0 outside the face).
  auto depth_inside = [](const gpu::GBuffer& g, const Eigen::Vector2f& x) {
    const int cx = static_cast<int>(std::lround(x.x())), cy = static_cast<int>(std::lround(x.y()));
    double nearest = 1e9;
    for (int j = cy - 30; j <= cy + 30; ++j) {
      for (int i = cx - 30; i <= cx + 30; ++i) {
        const bool covered = i >= 0 && j >= 0 && i < g.width && j < g.height && g.covered(i, j);
        if (!covered) nearest = std::min(nearest, std::hypot(double(i) - x.x(), double(j) - x.y()));
      }
    }
    return nearest;
  };
  auto check = [&](const gpu::FaceParameters& q, int last_checked, int* bound_inside) {
    const gpu::GBuffer g = renderer.render(q, camera, face_only);
    const std::vector<TrackerLandmark> contour = ContourLandmarks(*model, q, camera);
    EXPECT_EQ(contour.size(), model->landmarks.size());
    const ProjectedLandmarks bound = ProjectModelLandmarks(*model, q, camera);
    const ProjectedLandmarks slid = ProjectModelLandmarks(*model, q, camera, &contour);
    int moved = 0;
    *bound_inside = 0;
    for (size_t i = 0; i < contour.size(); ++i) {
      const int k = contour[i].ibug_index;
      if (k > 16) {
        EXPECT_EQ(contour[i].vertex, model->landmarks[i].vertex) << "point " << k;
        continue;
      }
      if (k <= last_checked) EXPECT_LE(depth_inside(g, slid.points[k]), 3.5) << "point " << k << " is inside the face";
      *bound_inside += depth_inside(g, bound.points[k]) > 6.0;
      moved += contour[i].vertex != model->landmarks[i].vertex;
    }
    return moved;
  };
  int bound_inside = 0;
  check(p, 16, &bound_inside);
  // About 29 degrees: the cheek of points 0-7 turns away, its contour moves over it. (On the
  // other side the face part's outline is its border towards the ear, which no one traces.)
  p.euler.y() += 0.5f;
  EXPECT_GT(check(p, 8, &bound_inside), 3);
  EXPECT_GT(bound_inside, 3) << "the turned head's bound jaw vertices were on its outline already";
}

// A landmark's own vertex (InputLandmark::model_vertex) replaces the model's binding in E_lan; one
// that is not a vertex of the model is left out, never read.
TEST(LandmarkVertex, AnInputPointCanNameItsOwnVertex) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const CpuSolver solver(*model);
  const gpu::FaceParameters p = testing::true_parameters(*model, 0.6f, 11);
  InputFrame frame = RenderSyntheticFrame(solver.renderer(), *model, p, testing::test_camera(320, 240));
  const EnergyOptions eo;
  const ParameterLayout layout = ParameterLayout::Tracking(model->num_expression());
  int wing = -1;  // the vertex of the nose wing, 31
  for (const auto& l : model->landmarks) {
    if (l.ibug_index == 31) wing = l.vertex;
  }
  ASSERT_GE(wing, 0);
  auto uses = [&](const InputFrame& f, int* total) {
    const auto landmarks = solver.LinearizeAt(f, layout, eo, p).landmarks;
    *total = static_cast<int>(landmarks.size());
    return std::count_if(landmarks.begin(), landmarks.end(), [&](const LandmarkSample& l) { return l.vertex == wing; });
  };
  int before_total = 0, after_total = 0, invalid_total = 0;
  const auto before = uses(frame, &before_total);
  bool tip = false;
  for (auto& l : frame.landmarks) {
    if (l.ibug_index == 30 && l.confidence > 0) tip = true, l.model_vertex = wing;  // the nose tip's point on the wing's vertex
  }
  ASSERT_TRUE(tip);
  EXPECT_EQ(uses(frame, &after_total), before + 1);
  EXPECT_EQ(after_total, before_total);
  for (auto& l : frame.landmarks) {
    if (l.ibug_index == 30) l.model_vertex = 1 << 30;
  }
  uses(frame, &invalid_total);
  EXPECT_EQ(invalid_total, before_total - 1);
}

// The binding search finds the vertex the points really sit on: frames whose nasal-bridge point
// 29 is drawn at another midline vertex than the binding's (every other point exact) name that
// vertex, at zero error, whatever the pose.
TEST(LandmarkBindingSearch, FindsTheVertexThePointsSitOn) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const FaceModel face = load_face_model(testing::real_model_path());
  BindingSearchOptions o;
  o.points = {29};
  LandmarkBindingSearch search(*model, face.mirror_vertex, o);
  int bound = -1;
  for (const auto& l : model->landmarks) {
    if (l.ibug_index == 29) bound = l.vertex;
  }
  ASSERT_GE(bound, 0);
  // Another midline face vertex about 8 mm from the binding on the mean face.
  const auto& mean = model->render.mean_shape;
  int other = -1;
  double closest = 1e9;
  for (int v = 0; v < model->num_vertices(); ++v) {
    if (face.mirror_vertex[static_cast<size_t>(v)] != v || model->render.vertex_part[static_cast<size_t>(v)] != 0) continue;
    const double d = std::abs((mean.segment<3>(3 * v) - mean.segment<3>(3 * bound)).norm() - 0.008);
    if (d < closest) closest = d, other = v;
  }
  ASSERT_GE(other, 0);
  const gpu::PinholeCamera camera = testing::test_camera();
  for (int f = 0; f < 3; ++f) {
    gpu::FaceParameters p = testing::true_parameters(*model, 0.6f, 20 + f);
    std::vector<TrackerLandmark> drawn = model->landmarks;
    for (auto& l : drawn) {
      if (l.ibug_index == 29) l.vertex = other;
    }
    const ProjectedLandmarks points = ProjectModelLandmarks(*model, p, camera, &drawn);
    std::vector<InputLandmark> detected;
    for (int k = 0; k < 68; ++k) detected.push_back({k, points.points[static_cast<size_t>(k)], 1.f});
    EXPECT_TRUE(search.Add(p, camera, detected));
  }
  EXPECT_FALSE(search.Add(testing::true_parameters(*model, 0.6f, 1), camera, {}));  // no eye corners: no unit
  const auto results = search.Results();
  ASSERT_EQ(results.size(), 1u);
  EXPECT_EQ(results[0].frames, 3);
  EXPECT_EQ(results[0].best_vertex, other);
  EXPECT_LT(results[0].best_error, 1e-4);
  EXPECT_GT(results[0].current_error, 0.01);
  EXPECT_NEAR(results[0].best_moved_mm, 8.0, 2.0);
  BindingSearchOptions bad;
  EXPECT_THROW(LandmarkBindingSearch(*model, face.mirror_vertex, bad), Error);  // no points
}

TEST(EvalBindingsCli, MeasuresTheBindingsOnAVideoAndRefusesBadPoints) {
  if (cli().empty()) GTEST_SKIP() << "FR_CLI not set";
  if (!testing::real_model()) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const char* shared = std::getenv("FR_SHARED_DATA");
  const std::string video = std::string(shared ? shared : "") + "/videos/liveportrait_d0.mp4";
  face_reenact::testing::TempDir out("fr-eval-bindings");
  const SubprocessResult bad = run_subprocess({cli(), "eval", "bindings", "--input", video, "--points", "17-70"});
  EXPECT_EQ(bad.exit_code, 1) << bad.output;
  EXPECT_NE(bad.output.find("--points"), std::string::npos) << bad.output;
  if (!shared || !fs::exists(video)) GTEST_SKIP() << "no " << video << " (FR_SHARED_DATA)";
  const std::string json = out.path() + "/bindings.json";
  const SubprocessResult run =
      run_subprocess({cli(), "eval", "bindings", "--input", video, "--frames", "6", "--points", "27-29", "--out", json});
  ASSERT_EQ(run.exit_code, 0) << run.output;
  std::ifstream in(json);
  const nlohmann::json report = nlohmann::json::parse(in);
  EXPECT_GT(report["frames"].get<int>(), 0);
  ASSERT_EQ(report["points"].size(), 3u);
  for (const auto& p : report["points"]) {
    EXPECT_LE(p["best_error"].get<double>(), p["current_error"].get<double>() + 1e-12) << p.dump();
  }
  // Each frame fitted alone as `eval fit` fits a photo: every third of six frames.
  const SubprocessResult zero = run_subprocess({cli(), "eval", "bindings", "--input", video, "--photo-fit", "--every", "0"});
  EXPECT_NE(zero.exit_code, 0) << zero.output;
  EXPECT_NE(zero.output.find("--every"), std::string::npos) << zero.output;
  const SubprocessResult photo = run_subprocess({cli(), "eval", "bindings", "--input", video, "--photo-fit", "--every",
                                                 "3", "--frames", "6", "--points", "36,45", "--out", json});
  ASSERT_EQ(photo.exit_code, 0) << photo.output;
  std::ifstream photo_in(json);
  const nlohmann::json photo_report = nlohmann::json::parse(photo_in);
  EXPECT_GT(photo_report["frames"].get<int>(), 0);
  EXPECT_LE(photo_report["frames"].get<int>(), 2);
  ASSERT_EQ(photo_report["points"].size(), 2u);
}

TEST(PhotoFitOptions, RefuseWhatIsNotOnePhoto) {
  PhotoFitOptions o;
  std::string why;
  EXPECT_TRUE(o.IsValid(&why)) << why;
  o.tracker.calibration_frames = 5;
  EXPECT_FALSE(o.IsValid(&why));
  EXPECT_NE(why.find("calibration"), std::string::npos) << why;
  o = PhotoFitOptions();
  o.horizontal_fov_deg = 0;
  EXPECT_FALSE(o.IsValid(&why));
}

// A folder with every kind of bad input beside one real photo (when the shared data is there).
struct BadFolder {
  face_reenact::testing::TempDir dir{"fr-photo-fit"};
  bool has_real = false;
  BadFolder() {
    const fs::path d = dir.path();
    const Shape68 s = square_shape();
    // A photo without a face: a flat grey image, well annotated.
    cv::imwrite((d / "grey.png").string(), cv::Mat(240, 320, CV_8UC3, cv::Scalar(128, 128, 128)));
    write_text(d / "grey.pts", pts_text(s, 68));
    // A malformed annotation (a line that is not two numbers).
    cv::imwrite((d / "malformed.png").string(), cv::Mat(240, 320, CV_8UC3, cv::Scalar(90, 90, 90)));
    write_text(d / "malformed.pts", "version: 1\nn_points: 68\n{\n1 2\nthree four\n}\n");
    // Another point count (the 49-point convention).
    cv::imwrite((d / "short.png").string(), cv::Mat(240, 320, CV_8UC3, cv::Scalar(60, 60, 60)));
    write_text(d / "short.pts", pts_text(s, 49));
    // Not an image at all.
    write_text(d / "broken.jpg", "this is not a JPEG");
    write_text(d / "broken.pts", pts_text(s, 68));
    const std::string faces = shared_faces();
    if (!faces.empty()) {
      fs::copy_file(faces + "/takeo.ppm", d / "takeo.ppm");
      fs::copy_file(faces + "/takeo.pts", d / "takeo.pts");
      has_real = true;
    }
  }
};

const FitEvalImage* entry(const FitEvalReport& r, const std::string& name) {
  for (const FitEvalImage& e : r.per_image) {
    if (fs::path(e.path).filename() == name) return &e;
  }
  return nullptr;
}

TEST(EvaluateFitOnAnnotatedPhotos, SaysWhatIsWrongWithEachBadPhotoAndGoesOn) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  BadFolder folder;
  PhotoFitter fitter(*model, PhotoFitOptions());
  landmarks::LandmarkDetector detector;
  const FitEvalReport r = EvaluateFitOnAnnotatedPhotos(folder.dir.path(), &fitter, &detector);
  EXPECT_EQ(r.images, folder.has_real ? 5 : 4);
  EXPECT_EQ(r.bad_annotation, 2);
  EXPECT_EQ(r.unreadable, 1);
  EXPECT_EQ(r.no_face, 1);
  ASSERT_NE(entry(r, "malformed.png"), nullptr);
  EXPECT_EQ(entry(r, "malformed.png")->status, "bad annotation");
  EXPECT_NE(entry(r, "malformed.png")->reason.find("malformed.pts"), std::string::npos) << entry(r, "malformed.png")->reason;
  EXPECT_EQ(entry(r, "short.png")->status, "bad annotation");
  EXPECT_NE(entry(r, "short.png")->reason.find("49"), std::string::npos) << entry(r, "short.png")->reason;
  EXPECT_EQ(entry(r, "broken.jpg")->status, "unreadable image");
  EXPECT_EQ(entry(r, "grey.png")->status, "no face");
  if (!folder.has_real) GTEST_SKIP() << "no ../shared/data/faces-68 (FR_SHARED_DATA): the real photo was not fitted";
  // takeo.ppm, a frontal face: the fit's landmarks land near the annotation. The bounds guard the
  // figures measured at this commit (all 0.047, inner 0.037, jaw 0.077, eyes 0.022, mouth 0.035;
  // the detector 0.035 / 0.029 / 0.051): the jaw bound fails without the contour fit (0.23 on the
  // fixed silhouette vertices), the eyes' without the eye points (the folder's 0.077), not the
  // issue's bar, which the jaw line and the brows still miss (docs/tracking-pipeline.md, "A
  // yardstick on real photos").
  const FitEvalImage* takeo = entry(r, "takeo.ppm");
  ASSERT_NE(takeo, nullptr);
  ASSERT_EQ(takeo->status, "fitted") << takeo->reason;
  EXPECT_EQ(r.scored, 1);
  EXPECT_LT(takeo->detector.all, 0.05);
  EXPECT_LT(takeo->fit.inner, 0.05);
  EXPECT_LT(takeo->fit.eyes, 0.035);
  EXPECT_LT(takeo->fit.mouth, 0.05);
  EXPECT_LT(takeo->fit.jaw, 0.11);
  EXPECT_LT(takeo->fit.all, 0.065);
  EXPECT_LT(takeo->pose_disagreement_deg, 15.0);
  // The points it scored are in the entry (and the report), so a binding's systematic offset
  // can be told from a miss of the model's reach.
  const landmarks::Shape68 truth = landmarks::read_pts((fs::path(folder.dir.path()) / "takeo.pts").string());
  EXPECT_NEAR(MeasureShapeErrors(takeo->fit_points, truth).all, takeo->fit.all, 1e-9);
  EXPECT_NEAR(MeasureShapeErrors(takeo->detector_points, truth).inner, takeo->detector.inner, 1e-9);
  const nlohmann::json j = r.ToJson();
  EXPECT_EQ(j["scored"], 1);
  for (const auto& e : j["per_image"]) {
    if (e["status"] != "fitted") continue;
    ASSERT_EQ(e["fit_points"].size(), 68u);
    EXPECT_NEAR(e["fit_points"][30][0].get<double>(), takeo->fit_points[30].x(), 1e-3);
    EXPECT_EQ(e["detector_points"].size(), 68u);
  }
  EXPECT_TRUE(j["fit_nme"]["inner"]["mean"].is_number());
  EXPECT_EQ(j["fit_nme_per_point_mean"].size(), 68u);
}

TEST(EvalFitCli, ReportsAFolderAndRefusesWhatIsNotOne) {
  if (cli().empty()) GTEST_SKIP() << "FR_CLI not set";
  if (!testing::real_model()) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  BadFolder folder;
  face_reenact::testing::TempDir out("fr-eval-fit-out");
  const std::string json = out.path() + "/report.json";
  const std::string draw = out.path() + "/drawn";
  const SubprocessResult run = run_subprocess({cli(), "eval", "fit", folder.dir.path(), "--out", json, "--draw", draw});
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_NE(run.output.find("bad annotation"), std::string::npos) << run.output;
  EXPECT_NE(run.output.find("no face"), std::string::npos) << run.output;
  std::ifstream in(json);
  const nlohmann::json report = nlohmann::json::parse(in);
  EXPECT_EQ(report["bad_annotation"], 2);
  EXPECT_EQ(report["per_image"].size(), folder.has_real ? 5u : 4u);
  EXPECT_TRUE(fs::exists(draw + "/grey.png"));
  EXPECT_TRUE(fs::exists(draw + "/sheet.png"));
  if (folder.has_real) {
    EXPECT_TRUE(fs::exists(draw + "/takeo.png"));
    EXPECT_NE(run.output.find("bar: fit <= detector"), std::string::npos) << run.output;
  }

  const SubprocessResult missing = run_subprocess({cli(), "eval", "fit", out.path() + "/nothing-here"});
  EXPECT_EQ(missing.exit_code, 1) << missing.output;
  EXPECT_NE(missing.output.find("is not a folder"), std::string::npos) << missing.output;
  fs::create_directories(out.path() + "/empty");
  const SubprocessResult empty = run_subprocess({cli(), "eval", "fit", out.path() + "/empty"});
  EXPECT_EQ(empty.exit_code, 1) << empty.output;
  EXPECT_NE(empty.output.find("no image with a .pts annotation"), std::string::npos) << empty.output;
}

}  // namespace
}  // namespace face_reenact::tracker
