// The brows from the detector's brow points (brow_reader.h, issue #26 §4): the reader on renders
// of the real model (the actor's own offset learned, bad and missing points, the median of the
// last readings), and the face tracker reading a brow raise, a frown and one brow raised on
// RGB-only frames. The real clip liveportrait_d14 is read in real_clip_expression_test.cc.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>

#include "face_reenact/model/face_model.h"
#include "face_reenact/tracker/brow_reader.h"
#include "face_reenact/tracker/face_tracker.h"
#include "tracker_test_support.h"

namespace face_reenact::tracker {
namespace {

struct BrowPose {
  const char* name;
  std::array<float, kNumBrowBlendshapes> weight;  // brow_blendshape_names() order
};

gpu::FaceParameters with_brows(gpu::FaceParameters p, const std::array<float, kNumBrowBlendshapes>& w) {
  for (int b = 0; b < kNumBrowBlendshapes; ++b) p.delta[arkit_blendshape_index(brow_blendshape_names()[size_t(b)])] = w[size_t(b)];
  return p;
}

TEST(BrowReaderOptions, DefaultsValidAndBadValuesRejected) {
  std::string why;
  EXPECT_TRUE(BrowReaderOptions{}.IsValid(&why)) << why;
  BrowReaderOptions o;
  o.min_history = 0;
  EXPECT_FALSE(o.IsValid(&why));
  o = BrowReaderOptions{};
  o.min_history = o.history_frames + 1;
  EXPECT_FALSE(o.IsValid(&why));
  o = BrowReaderOptions{};
  o.dead_zone = 1.0;
  EXPECT_FALSE(o.IsValid(&why));
  o = BrowReaderOptions{};
  o.dead_zone = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(o.IsValid(&why));
  o = BrowReaderOptions{};
  o.median_frames = 0;
  EXPECT_FALSE(o.IsValid(&why));
  o = BrowReaderOptions{};
  o.min_confidence = 2.f;
  EXPECT_FALSE(o.IsValid(&why));
  TrackerOptions t;
  t.brows.history_frames = 0;
  EXPECT_FALSE(t.IsValid(&why));
  EXPECT_NE(why.find("brow"), std::string::npos) << why;
}

// The reader against a fixed fit: the model's own brow points, with every brow point of this
// "actor" 2 px higher than the model's (where a detector puts this person's brows): at rest it
// reads nothing once it has learned that, and a raise or a frown reads back within 0.15 of the
// rendered weights; a model without brow landmarks, missing, doubtful or NaN points give no
// reading and teach nothing.
TEST(BrowReader, ReadsRaisesAndFrownsAgainstTheActorsOwnRestingBrows) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  BrowReaderOptions o;
  o.median_frames = 1;
  BrowReader reader(*model, o);
  ASSERT_TRUE(reader.usable());
  const gpu::CpuRenderer renderer(model->render);
  const gpu::PinholeCamera camera = testing::test_camera(320, 240);
  gpu::FaceParameters fit = testing::true_parameters(*model, 0.3f, 7);
  fit.delta.setZero();
  auto frame = [&](const std::array<float, kNumBrowBlendshapes>& w) {
    InputFrame f = RenderSyntheticFrame(renderer, *model, with_brows(fit, w), camera);
    for (InputLandmark& l : f.landmarks)
      if (l.ibug_index >= 17 && l.ibug_index <= 26) l.position.y() -= 2.f;
    return f;
  };
  const std::array<float, kNumBrowBlendshapes> rest{};
  for (int k = 0; k + 1 < o.min_history; ++k) {
    const BrowReading r = reader.Read(frame(rest), fit, camera);
    EXPECT_FALSE(r.ok);
    EXPECT_NE(r.message.find("learning"), std::string::npos) << r.message;
  }
  BrowReading r = reader.Read(frame(rest), fit, camera);
  ASSERT_TRUE(r.ok) << r.message;
  for (float w : r.weight) EXPECT_LT(w, 0.05f);
  EXPECT_LT(r.residual, 0.005);

  // The fit's own brow weights are not what is read (the solve may have set them).
  gpu::FaceParameters solved = with_brows(fit, {0.f, 1.f, 1.f, 0.f, 0.f});
  for (const BrowPose& b : {BrowPose{"raise", {0.8f, 0.7f, 0.7f, 0.f, 0.f}}, BrowPose{"frown", {0.f, 0.f, 0.f, 0.8f, 0.8f}},
                            BrowPose{"right outer brow up", {0.f, 0.f, 0.9f, 0.f, 0.f}}}) {
    SCOPED_TRACE(b.name);
    r = reader.Read(frame(b.weight), solved, camera);
    ASSERT_TRUE(r.ok) << r.message;
    for (int k = 0; k < kNumBrowBlendshapes; ++k) EXPECT_NEAR(r.weight[size_t(k)], b.weight[size_t(k)], 0.15f) << brow_blendshape_names()[size_t(k)];
    Eigen::VectorXf delta = Eigen::VectorXf::Zero(model->num_expression());
    reader.Write(r, &delta);
    for (int k = 0; k < kNumBrowBlendshapes; ++k)
      EXPECT_EQ(delta[arkit_blendshape_index(brow_blendshape_names()[size_t(k)])], r.weight[size_t(k)]);
  }

  // Bad points: no reading, and nothing learned (a fresh reader still needs its whole history).
  BrowReader fresh(*model, o);
  InputFrame missing = frame(rest);
  std::erase_if(missing.landmarks, [](const InputLandmark& l) { return l.ibug_index == 19; });
  InputFrame doubtful = frame(rest);
  for (InputLandmark& l : doubtful.landmarks)
    if (l.ibug_index == 42) l.confidence = 0.1f;
  InputFrame not_a_number = frame(rest);
  for (InputLandmark& l : not_a_number.landmarks)
    if (l.ibug_index == 24) l.position.x() = std::numeric_limits<float>::quiet_NaN();
  InputFrame no_landmarks = frame(rest);
  no_landmarks.landmarks.clear();
  for (int k = 0; k < 3 * o.min_history; ++k) {
    for (const InputFrame* f : {&missing, &doubtful, &not_a_number, &no_landmarks}) {
      r = fresh.Read(*f, fit, camera);
      EXPECT_FALSE(r.ok);
      EXPECT_NE(r.message.find("no confident brow"), std::string::npos) << r.message;
    }
  }
  EXPECT_FALSE(fresh.Read(frame(rest), fit, camera).ok);
  // A fit behind the camera: no reading.
  gpu::FaceParameters behind = fit;
  behind.translation.z() = -behind.translation.z();
  r = fresh.Read(frame(rest), behind, camera);
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.message.find("in front of the camera"), std::string::npos) << r.message;

  // A model without the brow landmarks cannot read them.
  TrackerModel no_brows = *model;
  std::erase_if(no_brows.landmarks, [](const TrackerLandmark& l) { return l.ibug_index >= 17 && l.ibug_index <= 26; });
  BrowReader unusable(no_brows, o);
  EXPECT_FALSE(unusable.usable());
  r = unusable.Read(frame(rest), fit, camera);
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.message.find("no brow points"), std::string::npos) << r.message;
  o.enabled = false;
  EXPECT_EQ(BrowReader(*model, o).Read(frame(rest), fit, camera).message, "off");
}

// The median of the last three readings: a single frame whose points jump reads as its
// neighbours, a held raise comes through one frame late.
TEST(BrowReader, ASingleFramesJumpIsTakenOutByTheMedian) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  BrowReader reader(*model);
  ASSERT_EQ(reader.options().median_frames, 3);
  const gpu::CpuRenderer renderer(model->render);
  const gpu::PinholeCamera camera = testing::test_camera(320, 240);
  gpu::FaceParameters fit = testing::true_parameters(*model, 0.3f, 7);
  fit.delta.setZero();
  auto frame = [&](const std::array<float, kNumBrowBlendshapes>& w) {
    return RenderSyntheticFrame(renderer, *model, with_brows(fit, w), camera);
  };
  const std::array<float, kNumBrowBlendshapes> rest{}, raise{0.8f, 0.7f, 0.7f, 0.f, 0.f};
  for (int k = 0; k < reader.options().min_history + 2; ++k) reader.Read(frame(rest), fit, camera);
  BrowReading r = reader.Read(frame(raise), fit, camera);  // one frame: rest, rest, raise
  ASSERT_TRUE(r.ok) << r.message;
  for (float w : r.weight) EXPECT_LT(w, 0.05f);
  r = reader.Read(frame(rest), fit, camera);  // rest, raise, rest
  for (float w : r.weight) EXPECT_LT(w, 0.05f);
  reader.Read(frame(raise), fit, camera);     // raise, rest, raise: reads the raise
  r = reader.Read(frame(raise), fit, camera);  // rest, raise, raise
  EXPECT_GT(r.weight[0], 0.6f);
  EXPECT_GT(r.weight[1], 0.5f);
}

// The tracker on RGB-only renders: the brow weights of its fits follow the rendered ones within
// 0.15 (the bar), each side on its own; --no-brows (enabled false) leaves them to the
// solve, which reads none of them.
TEST(Brows, TheTrackerReadsRaisesAndFrownsOnFramesWithoutDepth) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  for (bool enabled : {true, false}) {
    SCOPED_TRACE(enabled ? "brows read" : "brows off");
    TrackerOptions o;
    o.brows.enabled = enabled;
    o.calibration_frames = 1;
    o.min_face_width_px = 20;
    o.calibration_solver.schedule = {{2, 8, 6}, {1, 2, 6}};
    FaceTracker tracker(*model, o);
    const CpuSolver& solver = tracker.cpu_solver();
    gpu::FaceParameters p = testing::true_parameters(*model, 0.3f, 5);
    p.delta.setZero();
    auto frame = [&](const std::array<float, kNumBrowBlendshapes>& w) {
      InputFrame f = RenderSyntheticFrame(solver.renderer(), solver.model(), with_brows(p, w), testing::test_camera(320, 240));
      f.depth.clear();  // a video
      return f;
    };
    const std::array<float, kNumBrowBlendshapes> rest{};
    TrackedFrame t;
    for (int k = 0; k < o.brows.min_history + 2; ++k) t = tracker.Track(frame(rest));
    ASSERT_TRUE(tracking_status_has_fit(t.status)) << t.message;
    EXPECT_EQ(t.brows.ok, enabled) << t.brows.message;
    for (const BrowPose& b : {BrowPose{"raise", {0.8f, 0.7f, 0.7f, 0.f, 0.f}}, BrowPose{"frown", {0.f, 0.f, 0.f, 0.8f, 0.8f}},
                              BrowPose{"left outer brow up", {0.f, 0.9f, 0.f, 0.f, 0.f}},
                              BrowPose{"half raise", {0.4f, 0.4f, 0.4f, 0.f, 0.f}}, BrowPose{"rest", rest}}) {
      SCOPED_TRACE(b.name);
      // Held for three frames (the reader's median).
      for (int k = 0; k < 3; ++k) t = tracker.Track(frame(b.weight));
      ASSERT_TRUE(tracking_status_has_fit(t.status)) << t.message;
      float read_max = 0;
      for (int k = 0; k < kNumBrowBlendshapes; ++k) {
        const float read = t.params.delta[arkit_blendshape_index(brow_blendshape_names()[size_t(k)])];
        read_max = std::max(read_max, read);
        if (enabled) EXPECT_NEAR(read, b.weight[size_t(k)], 0.15f) << brow_blendshape_names()[size_t(k)];
      }
      if (!enabled && b.name != std::string("rest")) EXPECT_LT(read_max, 0.5f) << "the solve alone reads brows?";
    }
  }
}

}  // namespace
}  // namespace face_reenact::tracker
