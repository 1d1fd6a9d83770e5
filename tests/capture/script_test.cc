// --script and --identity files, timelines and lighting (no GPU needed).
#include <cmath>

#include "capture_test_support.h"
#include "face_reenact/capture/synth.h"
#include "face_reenact/common/error.h"
#include "face_reenact/model/face_model.h"

namespace face_reenact::capture {
namespace {

TEST(CaptureScriptTest, KeyframesInterpolateSmoothly) {
  const Timeline t = parse_script(R"({"keyframes": [
      {"time": 0, "expression": {"jawOpen": 0.0}, "head": {"yaw_deg": -20, "translation": [0, 0, 0.8]}},
      {"time": 1, "expression": {"jawOpen": 1.0, "eyeBlinkLeft": 0.5}, "head": {"yaw_deg": 20},
       "light": {"direction": [0, 0, -1], "intensity": 0.5, "ambient": 0.2, "color": [1, 0.9, 0.8]}},
      {"time": 2}]})",
                                  "script.json");
  const int jaw = arkit_blendshape_index("jawOpen");
  EXPECT_FLOAT_EQ(t.at(-1).expression[jaw], 0.0f);
  EXPECT_FLOAT_EQ(t.at(0.5).expression[jaw], 0.5f);  // smoothstep is symmetric
  EXPECT_LT(t.at(0.25).expression[jaw], 0.25f);      // eases in
  EXPECT_FLOAT_EQ(t.at(1).expression[jaw], 1.0f);
  EXPECT_FLOAT_EQ(t.at(2).expression[jaw], 0.0f);  // unlisted blendshapes are 0 in a keyframe
  EXPECT_FLOAT_EQ(t.at(0.5).head_deg.y(), 0.0f);
  EXPECT_FLOAT_EQ(t.at(2).head_deg.y(), 20.0f);     // head held from the previous keyframe
  EXPECT_FLOAT_EQ(t.at(2).translation.z(), 0.8f);
  EXPECT_FLOAT_EQ(t.at(5).light.intensity, 0.5f);  // held after the last keyframe
  // Weights stay within [0, 1] everywhere (no overshoot).
  for (double s = 0; s <= 2; s += 0.01)
    for (int k = 0; k < 52; ++k) {
      ASSERT_GE(t.at(s).expression[k], 0.0f);
      ASSERT_LE(t.at(s).expression[k], 1.0f);
    }
  const Eigen::Vector3f e = t.at(0).euler();
  EXPECT_NEAR(e.x(), M_PI, 1e-6);
  EXPECT_NEAR(e.y(), -20 * M_PI / 180, 1e-6);
}

TEST(CaptureScriptTest, ErrorsNameTheKeyPath) {
  struct Case {
    const char* text;
    std::vector<const char*> expect;
  };
  const std::vector<Case> cases = {
      {R"({"keyframes": [{"time": 0, "expression": {"jawOpn": 0.2}}]})", {"s.json", "keyframes[0].expression.jawOpn", "unknown ARKit"}},
      {R"({"keyframes": [{"time": 0, "expression": {"jawOpen": 1.2}}]})", {"keyframes[0].expression.jawOpen", "out of range"}},
      {R"({"keyframes": [{"time": 0, "expression": {"jawOpen": NaN}}]})", {"s.json", "invalid JSON"}},
      {R"({"keyframes": [{"time": 0, "expression": {"jawOpen": null}}]})", {"keyframes[0].expression.jawOpen", "null"}},
      {R"({"keyframes": [{"time": 0, "hed": {}}]})", {"keyframes[0].hed", "unknown key"}},
      {R"({"keyframes": [{"time": 0, "head": {"yaw": 3}}]})", {"keyframes[0].head.yaw", "unknown key"}},
      {R"({"keyframes": [{"time": 0, "head": {"yaw_deg": 120}}]})", {"keyframes[0].head.yaw_deg", "out of range"}},
      {R"({"keyframes": [{"time": 0, "head": {"translation": [0, 0, 0.1]}}]})", {"keyframes[0].head.translation[2]", "0.3 m"}},
      {R"({"keyframes": [{"time": 0, "head": {"translation": [0, 0]}}]})", {"keyframes[0].head.translation", "3 numbers"}},
      {R"({"keyframes": [{"time": 0, "light": {"direction": [0, 0, 0]}}]})", {"keyframes[0].light.direction", "zero"}},
      {R"({"keyframes": [{"time": 0, "light": {"intensity": -1}}]})", {"keyframes[0].light.intensity", "out of range"}},
      {R"({"keyframes": [{"time": 1}, {"time": 1}]})", {"keyframes[1].time", "increase"}},
      {R"({"keyframes": [{"expression": {}}]})", {"keyframes[0].time", "missing"}},
      {R"({"keyframes": []})", {"keyframes", "non-empty"}},
      {R"({"frames": []})", {"frames", "unknown key"}},
      {R"([1, 2])", {"s.json", "expected an object"}},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.text);
    bool thrown = false;
    try {
      parse_script(c.text, "s.json");
    } catch (const Error& e) {
      thrown = true;
      for (const char* part : c.expect)
        EXPECT_NE(std::string(e.what()).find(part), std::string::npos) << "message: " << e.what() << " lacks " << part;
    }
    EXPECT_TRUE(thrown);
  }
}

TEST(CaptureRandomTimelineTest, PlausibleAndDeterministic) {
  const int frames = 30 * 20;
  const Timeline a = random_timeline(5, frames, 30), b = random_timeline(5, frames, 30), c = random_timeline(6, frames, 30);
  ASSERT_EQ(static_cast<int>(a.keys().size()), frames);
  const int jaw = arkit_blendshape_index("jawOpen"), blink = arkit_blendshape_index("eyeBlinkLeft");
  const int smile = arkit_blendshape_index("mouthSmileLeft");
  double max_jaw = 0, max_smile = 0, max_yaw = 0, max_step_deg = 0;
  int blink_frames = 0;
  bool differs = false;
  for (int i = 0; i < frames; ++i) {
    const PerformanceState& s = a.keys()[static_cast<size_t>(i)].state;
    EXPECT_EQ(s.expression, b.keys()[static_cast<size_t>(i)].state.expression);
    differs = differs || s.expression != c.keys()[static_cast<size_t>(i)].state.expression;
    for (int k = 0; k < 52; ++k) {
      ASSERT_GE(s.expression[k], 0.0f);
      ASSERT_LE(s.expression[k], 1.0f);
    }
    max_jaw = std::max(max_jaw, double(s.expression[jaw]));
    max_smile = std::max(max_smile, double(s.expression[smile]));
    blink_frames += s.expression[blink] > 0.9f;
    ASSERT_LE(std::abs(s.head_deg.y()), 30.0f);
    ASSERT_LE(std::abs(s.head_deg.x()), 15.0f);
    ASSERT_LE(std::abs(s.head_deg.z()), 10.0f);
    ASSERT_GT(s.translation.z(), 0.5f);
    max_yaw = std::max(max_yaw, double(std::abs(s.head_deg.y())));
    if (i > 0)
      max_step_deg = std::max(max_step_deg, double((s.head_deg - a.keys()[static_cast<size_t>(i - 1)].state.head_deg).norm()));
  }
  EXPECT_TRUE(differs);
  EXPECT_GT(max_jaw, 0.2);          // talks
  EXPECT_GE(blink_frames, 3);       // blinks within 20 s
  EXPECT_GT(max_yaw, 5.0);          // looks around
  EXPECT_LT(max_step_deg, 3.0);     // smoothly (< 90 deg/s)
  (void)max_smile;
}

// The calibration sequence (Sec. 6.3) before the performance: at rest but for blinks, facing
// the camera, turning 25 degrees each way, then the performance exactly as without the turn.
TEST(CaptureRandomTimelineTest, CalibrationTurnAtRestThenTheSamePerformance) {
  const double fps = 30, turn_s = 2;
  const int turn = static_cast<int>(turn_s * fps), after = 90;
  const Timeline with = random_timeline(9001, turn + after, fps, turn_s), without = random_timeline(9001, after, fps);
  ASSERT_EQ(static_cast<int>(with.keys().size()), turn + after);
  const int blink_l = arkit_blendshape_index("eyeBlinkLeft"), blink_r = arkit_blendshape_index("eyeBlinkRight");
  double min_yaw = 0, max_yaw = 0, max_pitch = 0, max_step_deg = 0;
  for (int i = 0; i < turn; ++i) {
    const PerformanceState& s = with.keys()[static_cast<size_t>(i)].state;
    for (int k = 0; k < 52; ++k)
      if (k != blink_l && k != blink_r) ASSERT_EQ(s.expression[k], 0.f) << "frame " << i << " weight " << k;
    if (i < turn * 4 / 5) {  // the turn proper; the rest eases into the performance's first pose
      min_yaw = std::min(min_yaw, double(s.head_deg.y()));
      max_yaw = std::max(max_yaw, double(s.head_deg.y()));
      max_pitch = std::max(max_pitch, double(std::abs(s.head_deg.x())));
    }
    EXPECT_EQ(s.translation, without.keys()[0].state.translation);
    EXPECT_EQ(s.light.direction, without.keys()[0].state.light.direction);
  }
  EXPECT_NEAR(with.keys()[0].state.head_deg.norm(), 0.0, 1e-6);  // starts facing the camera
  EXPECT_GT(max_yaw, 24.0);
  EXPECT_LT(min_yaw, -24.0);
  EXPECT_LE(max_yaw, 25.0);
  EXPECT_LE(max_pitch, 6.0);
  for (int i = 1; i < turn + after; ++i) {
    const double step = (with.keys()[static_cast<size_t>(i)].state.head_deg - with.keys()[static_cast<size_t>(i - 1)].state.head_deg).norm();
    max_step_deg = std::max(max_step_deg, step);
  }
  EXPECT_LT(max_step_deg, 4.0);  // a brisk turn (peak ~110 deg/s), smooth into the performance
  for (int i = 0; i < after; ++i) {
    const PerformanceState& a = with.keys()[static_cast<size_t>(turn + i)].state;
    const PerformanceState& b = without.keys()[static_cast<size_t>(i)].state;
    EXPECT_EQ(a.head_deg, b.head_deg) << i;
    EXPECT_EQ(a.translation, b.translation) << i;
    for (int k = 0; k < 52; ++k)  // blinks keep their own clock
      if (k != blink_l && k != blink_r) ASSERT_EQ(a.expression[k], b.expression[k]) << "frame " << i << " weight " << k;
  }
  EXPECT_THROW(random_timeline(1, 10, 30, -1), Error);
  EXPECT_THROW(random_timeline(1, 10, 30, std::nan("")), Error);
}

TEST(CaptureLightTest, ShCoefficientsReproduceLambertianShading) {
  LightState l;
  l.direction = Eigen::Vector3f(0, 0, -1);
  l.intensity = 1.0f;
  l.ambient = 0.25f;
  l.color = Eigen::Vector3f(1, 0.5f, 2);
  const auto g = sh_from_light(l);
  auto irradiance = [&](const Eigen::Vector3f& n, int c) {
    const auto y = gpu::sh_basis(n);
    float e = 0;
    for (int k = 0; k < 9; ++k) e += g[static_cast<size_t>(c * 9 + k)] * y[static_cast<size_t>(k)];
    return e;
  };
  // Facing the light: ambient + ~1 (the 3-band approximation of max(0, cos) is within ~10%).
  EXPECT_NEAR(irradiance(Eigen::Vector3f(0, 0, -1), 0), 1.25f, 0.1f);
  EXPECT_NEAR(irradiance(Eigen::Vector3f(0, 0, -1), 2), 2.5f, 0.2f);
  // Sideways (max(0, cos) = 0; 3 bands ring by ~0.1) and away from the light: ~ambient.
  EXPECT_NEAR(irradiance(Eigen::Vector3f(1, 0, 0), 0), 0.25f, 0.12f);
  EXPECT_NEAR(irradiance(Eigen::Vector3f(0, 0, 1), 0), 0.25f, 0.1f);
  l.intensity = 0;
  const auto amb = sh_from_light(l);
  for (int k = 1; k < 9; ++k) EXPECT_EQ(amb[static_cast<size_t>(k)], 0.0f);
}

FaceModel tiny_model() {
  FaceModel m;
  m.identity_basis = Eigen::MatrixXf::Zero(3, 3);
  m.identity_sigma = Eigen::Vector3f(0.01f, 0.005f, 0.002f);
  m.albedo_basis = Eigen::MatrixXf::Zero(3, 2);
  m.albedo_sigma = Eigen::Vector2f(0.1f, 0.05f);
  return m;
}

TEST(CaptureIdentityTest, FilesAreValidated) {
  const FaceModel m = tiny_model();
  const SynthIdentity id = parse_identity(R"({"alpha": [0.01, -0.005], "beta": [0.1]})", m, "id.json");
  EXPECT_EQ(id.alpha.size(), 3);
  EXPECT_FLOAT_EQ(id.alpha[1], -0.005f);
  EXPECT_FLOAT_EQ(id.alpha[2], 0.0f);
  EXPECT_EQ(id.beta.size(), 2);
  EXPECT_THROW_WITH(parse_identity(R"({"alpha": [0.1]})", m, "id.json"), "id.json", "alpha[0]", "out of range");
  EXPECT_THROW_WITH(parse_identity(R"({"alpha": [0, 0, 0, 0]})", m, "id.json"), "alpha", "only 3");
  EXPECT_THROW_WITH(parse_identity(R"({"alfa": []})", m, "id.json"), "alfa", "unknown key");
  EXPECT_THROW_WITH(parse_identity(R"({"beta": [null]})", m, "id.json"), "beta[0]", "null");
  const SynthIdentity r1 = random_identity(m, 4), r2 = random_identity(m, 4), r3 = random_identity(m, 5);
  EXPECT_EQ(r1.alpha, r2.alpha);
  EXPECT_NE(r1.alpha, r3.alpha);
  EXPECT_LT(std::abs(r1.alpha[0]), 5 * 0.01f);
}

}  // namespace
}  // namespace face_reenact::capture
