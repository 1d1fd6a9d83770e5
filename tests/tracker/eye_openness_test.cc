// Blinks and winks from the detector's eye points (eye_openness.h): the aspect ratio on known
// geometry, the reader against the actor's own open eye (independent eyes, the history, bad
// points) and the face tracker writing it into the eyeBlink weights of RGB-only frames. The real
// clip liveportrait_d14 is read in real_clip_expression_test.cc.
#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "face_reenact/model/face_model.h"
#include "face_reenact/tracker/eye_openness.h"
#include "face_reenact/tracker/face_tracker.h"
#include "tracker_test_support.h"

namespace face_reenact::tracker {
namespace {

// Six iBUG points of an eye `width` wide whose lids are `opening` apart (pixels).
std::array<Eigen::Vector2f, 6> eye(float x, float width, float opening) {
  const float h = 0.5f * opening;
  return {Eigen::Vector2f(x, 100), Eigen::Vector2f(x + width / 3, 100 - h), Eigen::Vector2f(x + 2 * width / 3, 100 - h),
          Eigen::Vector2f(x + width, 100), Eigen::Vector2f(x + 2 * width / 3, 100 + h),
          Eigen::Vector2f(x + width / 3, 100 + h)};
}

// A frame whose only landmarks are the two eyes: the person's right (36-41, image left) and left.
InputFrame eyes_frame(float right_opening, float left_opening, float confidence = 1.f) {
  InputFrame f;
  auto add = [&](int first, const std::array<Eigen::Vector2f, 6>& p) {
    for (int k = 0; k < 6; ++k) f.landmarks.push_back(InputLandmark{first + k, p[size_t(k)], confidence});
  };
  add(36, eye(100, 30, right_opening));
  add(42, eye(160, 30, left_opening));
  return f;
}

TEST(EyeOpenness, AspectRatioOfKnownEyes) {
  EXPECT_NEAR(EyeAspectRatio(eye(0, 30, 9)), 0.3, 1e-6);
  EXPECT_NEAR(EyeAspectRatio(eye(0, 30, 0)), 0.0, 1e-6);
  std::array<Eigen::Vector2f, 6> corners_together = eye(0, 0, 4);
  EXPECT_TRUE(std::isnan(EyeAspectRatio(corners_together)));
  // Lids drawn past each other: open again unsigned, shut along the face's down direction.
  const Eigen::Vector2f down(0, 1);
  EXPECT_NEAR(EyeAspectRatio(eye(0, 30, -6)), 0.2, 1e-6);
  EXPECT_NEAR(EyeAspectRatio(eye(0, 30, -6), &down), 0.0, 1e-6);
  EXPECT_NEAR(EyeAspectRatio(eye(0, 30, 9), &down), 0.3, 1e-6);
}

TEST(EyeOpenness, TheModelsOpeningCurveFallsFromOpenToShut) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const EyeOpeningCurve c = EyeOpeningCurve::FromModel(*model);
  ASSERT_FALSE(c.empty());
  for (int e = 0; e < 2; ++e) {
    EXPECT_EQ(c.fraction[size_t(e)].front(), 1.0);
    EXPECT_LT(c.fraction[size_t(e)].back(), 0.1);  // the eyeBlink blendshape shuts the eye
    EXPECT_EQ(c.WeightFor(e, 1.0), 0.f);
    EXPECT_GT(c.WeightFor(e, 0.0), 0.6f);
    EXPECT_LT(c.WeightFor(e, 0.75), c.WeightFor(e, 0.25));
  }
  EXPECT_EQ(EyeOpeningCurve{}.WeightFor(0, 0.25), 0.75f);  // no model: linear
}

TEST(EyeOpenness, ReadsEachEyeAgainstItsOwnOpenEye) {
  EyeOpennessOptions o;
  EyeOpennessReader reader(o);
  // Open eyes (ratio 0.35 and 0.40: people's eyes differ) with a little noise.
  for (int k = 0; k < o.min_history - 1; ++k) {
    const EyeOpennessReading r = reader.Read(eyes_frame(10.5f + 0.3f * float(k % 3), 12.f - 0.3f * float(k % 2)));
    EXPECT_FALSE(r.ok);
    EXPECT_NE(r.message.find("learning the open eye"), std::string::npos) << r.message;
  }
  EyeOpennessReading r = reader.Read(eyes_frame(10.5f, 12.f));
  ASSERT_TRUE(r.ok) << r.message;
  EXPECT_EQ(r.blink[0], 0.f);
  EXPECT_EQ(r.blink[1], 0.f);
  EXPECT_NEAR(r.open_ratio[0], 0.4, 0.02);   // the person's left: 12 px of 30
  EXPECT_NEAR(r.open_ratio[1], 0.36, 0.02);  // the right: ~10.8 px
  // A wink of the left eye: that eye reads closed, the other open.
  r = reader.Read(eyes_frame(10.5f, 1.f));
  ASSERT_TRUE(r.ok);
  EXPECT_EQ(r.blink[0], 1.f);
  EXPECT_EQ(r.blink[1], 0.f);
  // The right eye half shut: between the dead zone and closed.
  r = reader.Read(eyes_frame(5.5f, 12.f));
  ASSERT_TRUE(r.ok);
  EXPECT_EQ(r.blink[0], 0.f);
  EXPECT_GT(r.blink[1], 0.4f);
  EXPECT_LT(r.blink[1], 0.8f);
  // Open again but a little narrower than usual (noise, a look down): nothing.
  r = reader.Read(eyes_frame(10.5f * 0.9f, 12.f * 0.9f));
  EXPECT_EQ(r.blink[0], 0.f);
  EXPECT_EQ(r.blink[1], 0.f);
}

TEST(EyeOpenness, MissingOrDoubtfulPointsGiveNoReadingAndTeachNothing) {
  EyeOpennessReader reader;
  for (int k = 0; k < 20; ++k) reader.Read(eyes_frame(10.5f, 12.f));
  // Closed eyes with pruned (low-confidence) points: no reading, and the history keeps them out,
  // so the open eye is still the one learned.
  for (int k = 0; k < 200; ++k) EXPECT_FALSE(reader.Read(eyes_frame(1.f, 1.f, 0.1f)).ok);
  InputFrame one_eye = eyes_frame(10.5f, 12.f);
  one_eye.landmarks.resize(6);
  EXPECT_FALSE(reader.Read(one_eye).ok);
  InputFrame nan_point = eyes_frame(10.5f, 12.f);
  nan_point.landmarks[2].position.x() = std::numeric_limits<float>::quiet_NaN();
  EXPECT_FALSE(reader.Read(nan_point).ok);
  InputFrame collapsed = eyes_frame(10.5f, 12.f);
  for (int k = 6; k < 12; ++k) collapsed.landmarks[size_t(k)].position = Eigen::Vector2f(5, 5);
  const EyeOpennessReading bad = reader.Read(collapsed);
  EXPECT_FALSE(bad.ok);
  EXPECT_EQ(bad.message, "degenerate eye points");
  const EyeOpennessReading r = reader.Read(eyes_frame(10.5f, 12.f));
  ASSERT_TRUE(r.ok) << r.message;
  EXPECT_NEAR(r.open_ratio[0], 0.4, 0.01);
  reader.Reset();
  EXPECT_FALSE(reader.Read(eyes_frame(10.5f, 12.f)).ok);
  EyeOpennessOptions o;
  std::string why;
  EXPECT_TRUE(o.IsValid(&why)) << why;
  o.closed_ratio = 0.9;  // above the dead zone's start
  EXPECT_FALSE(o.IsValid(&why));
  o = EyeOpennessOptions{};
  o.min_history = 0;
  EXPECT_FALSE(o.IsValid(&why));
}

// RGB-only renders of the real model: the lids are read from the model's own eye points, each eye
// on its own, and written into the fit (the colour lid reader needs depth).
TEST(EyeOpenness, TheTrackerReadsAWinkOnFramesWithoutDepth) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  TrackerOptions o;
  // The model's own eye points are exact: they meet when the eye shuts and carry no noise (dlib's
  // settings, the defaults, are measured on the real clip below).
  o.eye_openness.closed_ratio = 0.0;
  o.eye_openness.dead_zone = 0.02;
  o.calibration_frames = 1;
  o.min_face_width_px = 20;
  o.calibration_solver.schedule = {{2, 8, 6}, {1, 2, 6}};
  FaceTracker tracker(*model, o);
  const CpuSolver& solver = tracker.cpu_solver();
  const int left = arkit_blendshape_index("eyeBlinkLeft"), right = arkit_blendshape_index("eyeBlinkRight");
  gpu::FaceParameters p = testing::true_parameters(*model, 0.3f, 5);
  p.delta.setZero();
  auto frame = [&](float blink_left, float blink_right) {
    gpu::FaceParameters q = p;
    q.delta[left] = blink_left;
    q.delta[right] = blink_right;
    InputFrame f = RenderSyntheticFrame(solver.renderer(), solver.model(), q, testing::test_camera(320, 240));
    f.depth.clear();  // a video
    return f;
  };
  for (int k = 0; k < o.eye_openness.min_history; ++k) tracker.Track(frame(0.f, 0.f));
  TrackedFrame t = tracker.Track(frame(0.f, 0.f));
  ASSERT_TRUE(tracking_status_has_fit(t.status)) << t.message;
  EXPECT_TRUE(t.gaze.lids_read) << t.gaze.lids_message;
  EXPECT_LT(t.params.delta[left], 0.15f);
  EXPECT_LT(t.params.delta[right], 0.15f);
  t = tracker.Track(frame(1.f, 0.f));
  ASSERT_TRUE(tracking_status_has_fit(t.status)) << t.message;
  EXPECT_GT(t.params.delta[left], 0.85f);
  EXPECT_LT(t.params.delta[right], 0.15f);
  t = tracker.Track(frame(0.f, 1.f));
  EXPECT_LT(t.params.delta[left], 0.15f);
  EXPECT_GT(t.params.delta[right], 0.85f);
  t = tracker.Track(frame(1.f, 1.f));
  EXPECT_GT(t.params.delta[left], 0.85f);
  EXPECT_GT(t.params.delta[right], 0.85f);
  // Part-way: within 0.15 (the weight comes from the model's opening curve, which is not linear).
  for (float w : {0.25f, 0.5f, 0.75f}) {
    t = tracker.Track(frame(w, w));
    EXPECT_NEAR(t.params.delta[left], w, 0.15f) << w;
    EXPECT_NEAR(t.params.delta[right], w, 0.15f) << w;
  }
  // Switched off with the lids.
  o.gaze.read_lids = false;
  FaceTracker without(*model, o);
  for (int k = 0; k < o.eye_openness.min_history + 1; ++k) without.Track(frame(0.f, 0.f));
  t = without.Track(frame(1.f, 0.f));
  EXPECT_FALSE(t.gaze.lids_read);
}

}  // namespace
}  // namespace face_reenact::tracker
