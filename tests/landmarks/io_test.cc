// Frame sources, drawings, smoothing and the CLI on single images and bad input.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>

#include "face_reenact/common/error.h"
#include "face_reenact/common/subprocess.h"
#include "face_reenact/landmarks/drawing.h"
#include "face_reenact/landmarks/smoothing.h"
#include "test_data.h"

namespace face_reenact::landmarks {
namespace {
namespace fs = std::filesystem;

TEST(FrameSourceTest, MissingCorruptAndWrongFilesAreClearErrors) {
  const fs::path dir = test::temp_dir("fr_landmarks_io");
  EXPECT_THROW(open_frame_source((dir / "missing.png").string()), Error);
  EXPECT_THROW(open_frame_source(dir.string()), Error);
  {
    std::ofstream f(dir / "broken.png", std::ios::binary);
    f << "\x89PNG\r\n\x1a\n but then nothing useful";
  }
  try {
    open_frame_source((dir / "broken.png").string());
    ADD_FAILURE() << "broken PNG accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("broken.png"), std::string::npos);
  }
  {
    std::ofstream f(dir / "text.avi", std::ios::binary);
    f << "not a video at all";
  }
  bool threw = false;
  try {
    auto src = open_frame_source((dir / "text.avi").string());
    Frame frame;
    EXPECT_FALSE(src->Next(&frame));  // if the demuxer opens it, it must yield nothing
  } catch (const Error&) {
    threw = true;
  }
  (void)threw;
  fs::remove_all(dir);
}

TEST(FrameSourceTest, RegisteredOpenersTakePrecedence) {
  class OneFrame : public FrameSource {
   public:
    bool Next(Frame* f) override {
      if (done_) return false;
      done_ = true;
      f->image.width = 2;
      f->image.height = 1;
      f->image.pixels = {1, 2, 3, 4, 5, 6};
      return true;
    }
    std::string Describe() const override { return "one frame"; }

   private:
    bool done_ = false;
  };
  register_frame_source(".frtest", [](const std::string&) { return std::make_unique<OneFrame>(); });
  const fs::path dir = test::temp_dir("fr_landmarks_io_reg");
  { std::ofstream(dir / "x.frtest") << "x"; }
  auto src = open_frame_source((dir / "x.frtest").string());
  Frame f;
  ASSERT_TRUE(src->Next(&f));
  EXPECT_EQ(f.image.width, 2);
  EXPECT_FALSE(src->Next(&f));
  fs::remove_all(dir);
}

TEST(FrameSourceTest, ReadsTheRealVideos) {
  FR_REQUIRE_SHARED(dir, "videos");
  for (const auto& [name, w, h] : {std::tuple{"webcam_talking_640x480.wmv", 640, 480},
                                   std::tuple{"multi_face.avi", 640, 480},
                                   std::tuple{"liveportrait_d0.mp4", 512, 512}}) {
    auto src = open_frame_source(dir + "/" + name);
    EXPECT_FALSE(src->is_still_image());
    Frame f;
    int n = 0;
    while (n < 5 && src->Next(&f)) ++n;
    EXPECT_EQ(n, 5) << name;
    EXPECT_EQ(f.image.width, w) << name;
    EXPECT_EQ(f.image.height, h) << name;
    EXPECT_EQ(f.index, 4);
    EXPECT_GT(f.timestamp_s, 0.0);
  }
}

TEST(DrawingTest, DrawsAndWritesPng) {
  Image img;
  img.width = 101;
  img.height = 77;
  img.format = PixelFormat::kGray8;
  img.pixels.assign(size_t(101 * 77), 50);
  LandmarkResult r;
  r.has_landmarks = true;
  r.status = DetectionStatus::kOk;
  r.face_box = Box{10, 10, 60, 60};
  for (int i = 0; i < kNumLandmarks; ++i) {
    r.points[size_t(i)] = Eigen::Vector2f(10.f + float(i % 10) * 6.f, 10.f + float(i / 10) * 8.f);
    r.confidence[size_t(i)] = float(i) / 67.f;
    r.visible[size_t(i)] = i % 3 != 0;
  }
  r.points[5] = {-1000.f, 1e9f};  // far outside: drawing must clip, not crash
  const Image drawn = draw_landmarks(img.view(), r, "caption");
  ASSERT_EQ(drawn.width, 101);
  ASSERT_EQ(drawn.format, PixelFormat::kBGR8);
  EXPECT_NE(drawn.pixels, std::vector<uint8_t>(drawn.pixels.size(), 50));
  const Image sheet = contact_sheet({drawn, drawn, drawn}, 2, 50);
  EXPECT_EQ(sheet.width, 100);
  EXPECT_GT(sheet.height, 0);
  const fs::path dir = test::temp_dir("fr_landmarks_draw");
  save_png((dir / "x.png").string(), sheet.view());
  EXPECT_EQ(load_image((dir / "x.png").string()).width, 100);
  EXPECT_THROW(save_png((dir / "no" / "such" / "dir.png").string(), sheet.view()), Error);
  EXPECT_THROW(save_png((dir / "y.png").string(), ImageView{}), Error);
  fs::remove_all(dir);
}

TEST(SmoothingTest, OneEuroRemovesNoiseButFollowsMotion) {
  OneEuroFilter filter(1.5f, 0.02f, 1.0f);
  std::mt19937 rng(3);
  std::normal_distribution<float> noise(0.f, 1.f);
  const float dt = 1.f / 30.f;
  // At rest: noise variance drops a lot.
  double raw_var = 0, filt_var = 0;
  for (int i = 0; i < 300; ++i) {
    const float n = noise(rng);
    const float y = filter.Filter(100.f + n, dt);
    if (i > 30) {
      raw_var += double(n) * n;
      filt_var += double(y - 100.f) * (y - 100.f);
    }
  }
  EXPECT_LT(filt_var, 0.25 * raw_var);
  // Fast real motion (300 px/s, 10 px per frame): the speed term keeps the lag under one
  // frame of motion and far below a fixed low-pass with the same rest cut-off.
  auto ramp_lag = [&](OneEuroFilter f) {
    float lag = 0;
    for (int i = 0; i < 60; ++i) {
      const float x = 300.f * float(i) * dt;
      lag = x - f.Filter(x, dt);
    }
    return std::abs(lag);
  };
  const float lag = ramp_lag(OneEuroFilter(1.5f, 0.02f, 1.0f));
  const float fixed_lag = ramp_lag(OneEuroFilter(1.5f, 0.f, 1.0f));
  EXPECT_LT(lag, 10.f);
  EXPECT_LT(lag, 0.25f * fixed_lag) << lag << " vs " << fixed_lag;
  filter.Reset();
  // Non-finite or non-positive dt passes values through instead of producing NaN.
  EXPECT_EQ(filter.Filter(5.f, 0.f), 5.f);
  EXPECT_EQ(filter.Filter(6.f, std::nanf("")), 6.f);
}

TEST(SmoothingTest, LandmarkSmootherOnlyWhenEnabled) {
  Shape68 pts;
  for (int i = 0; i < kNumLandmarks; ++i) pts[size_t(i)] = Eigen::Vector2f(float(i), float(i));
  pts[36] = {0, 0};
  pts[45] = {100, 0};
  LandmarkSmoother off;
  Shape68 a = pts;
  off.Apply(0.0, &a);
  a[3].x() += 5;
  Shape68 b = a;
  off.Apply(0.033, &b);
  EXPECT_EQ(b[3], a[3]);
  SmoothingOptions on_opts;
  on_opts.enabled = true;
  LandmarkSmoother on(on_opts);
  Shape68 c = pts;
  on.Apply(0.0, &c);
  Shape68 d = pts;
  d[3].x() += 5;
  on.Apply(0.033, &d);
  EXPECT_GT(d[3].x(), pts[3].x());
  EXPECT_LT(d[3].x(), pts[3].x() + 5);
}

TEST(CliImageTest, ImageInputWritesJsonAndDrawing) {
  FR_REQUIRE_MODEL();
  FR_REQUIRE_SHARED(image, "faces-68/takeo.ppm");
  const char* cli = std::getenv("FR_CLI");
  ASSERT_NE(cli, nullptr);
  const fs::path dir = test::temp_dir("fr_landmarks_cli_image");
  const std::string json = (dir / "t.json").string(), png = (dir / "t.png").string();
  const SubprocessResult run = run_subprocess({cli, "landmarks", "--input", image, "--out", json, "--draw", png});
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const nlohmann::json j = nlohmann::json::parse(test::read_text(json));
  EXPECT_EQ(j["kind"], "image");
  ASSERT_EQ(j["frames"].size(), 1u);
  const auto& f = j["frames"][0];
  EXPECT_EQ(f["status"], "ok");
  EXPECT_EQ(f["points"].size(), 68u);
  EXPECT_EQ(f["visible"].size(), 68u);
  EXPECT_EQ(f["width"], 150);
  const Image drawn = load_image(png);
  EXPECT_EQ(drawn.width, 150);
  EXPECT_EQ(drawn.height, 225);
  fs::remove_all(dir);
}

TEST(CliImageTest, BadInputExitsWithAClearError) {
  const char* cli = std::getenv("FR_CLI");
  ASSERT_NE(cli, nullptr);
  SubprocessResult run = run_subprocess({cli, "landmarks", "--input", "/nonexistent/face.png"});
  EXPECT_EQ(run.exit_code, 1);
  EXPECT_NE(run.output.find("/nonexistent/face.png"), std::string::npos) << run.output;
  run = run_subprocess({cli, "landmarks"});
  EXPECT_EQ(run.exit_code, 1);
  EXPECT_NE(run.output.find("--input"), std::string::npos) << run.output;
  run = run_subprocess({cli, "landmarks", "--input", "a.png", "--eval", "dir"});
  EXPECT_NE(run.exit_code, 0);
  run = run_subprocess({cli, "landmarks", "--input", "a.png", "--samples", "0"});
  EXPECT_NE(run.exit_code, 0);
}

TEST(CliImageTest, NoFaceImageIsReportedNotFailed) {
  FR_REQUIRE_MODEL();
  const char* cli = std::getenv("FR_CLI");
  ASSERT_NE(cli, nullptr);
  const fs::path dir = test::temp_dir("fr_landmarks_cli_noface");
  Image black;
  black.width = 64;
  black.height = 48;
  black.pixels.assign(size_t(64 * 48 * 3), 0);
  save_png((dir / "black.png").string(), black.view());
  const SubprocessResult run =
      run_subprocess({cli, "landmarks", "--input", (dir / "black.png").string(), "--out", (dir / "b.json").string()});
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const nlohmann::json j = nlohmann::json::parse(test::read_text((dir / "b.json").string()));
  EXPECT_EQ(j["frames"][0]["status"], "no_face");
  EXPECT_FALSE(j["frames"][0].contains("points"));
  fs::remove_all(dir);
}

}  // namespace
}  // namespace face_reenact::landmarks
