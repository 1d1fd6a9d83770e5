// The focal length of a camera that does not say (focal_length.h, issue #26 §5): on RGB-only
// renders of the real model through a known field of view between 40 and 90 degrees, given to the
// tracker as the 60 degrees a video is assumed to have, the estimate is within 10 %; the tracker
// fits every frame after its calibration through the estimated camera; when the estimate is off
// (the front-ends' --fov / --intrinsics) the frames' own camera stays; and bad input falls back
// to 60 degrees with a message.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <vector>

#include "face_reenact/tracker/face_tracker.h"
#include "face_reenact/tracker/focal_length.h"
#include "tracker_test_support.h"

namespace face_reenact::tracker {
namespace {

// An actor at rest turning the head (the paper's calibration sequence), `distance` m away, frame k
// of `frames`, rendered through `fov_deg` and handed over with the 60-degree camera a video gets.
std::vector<InputFrame> turning_head(const CpuSolver& solver, double fov_deg, float distance, int frames, uint32_t seed) {
  const TrackerModel& m = solver.model();
  const gpu::PinholeCamera assumed = WithHorizontalFov(testing::test_camera(640, 480), 60.0);
  const gpu::PinholeCamera truth = WithHorizontalFov(assumed, fov_deg);
  std::vector<InputFrame> out;
  for (int k = 0; k < frames; ++k) {
    gpu::FaceParameters p = testing::true_parameters(m, distance, seed);
    p.delta.setZero();  // at rest while calibrating
    const float turn = frames > 1 ? -1.f + 2.f * k / (frames - 1) : 0.f;
    p.euler += Eigen::Vector3f(0.05f * turn * turn, 0.35f * turn, 0.f);
    InputFrame f = RenderSyntheticFrame(solver.renderer(), m, p, truth);
    f.camera = assumed;
    f.depth.clear();  // RGB-only
    out.push_back(std::move(f));
  }
  return out;
}

TEST(FocalLength, OptionsAndCameraHelpers) {
  FocalLengthOptions o;
  std::string why;
  EXPECT_TRUE(o.IsValid(&why)) << why;
  EXPECT_FALSE(o.estimate);  // only the front-ends know a camera is an assumption
  o.min_fov_deg = 90;
  o.max_fov_deg = 40;
  EXPECT_FALSE(o.IsValid(&why));
  o = FocalLengthOptions();
  o.grid_points = 2;
  EXPECT_FALSE(o.IsValid(&why));
  o = FocalLengthOptions();
  o.threads = -1;
  EXPECT_FALSE(o.IsValid(&why));
  TrackerOptions to;
  to.focal_length.fallback_fov_deg = 0;
  EXPECT_FALSE(to.IsValid(&why));
  const gpu::PinholeCamera c = WithHorizontalFov(testing::test_camera(640, 480), 75.0);
  EXPECT_NEAR(HorizontalFovDeg(c), 75.0, 1e-4);
  EXPECT_EQ(c.fx, c.fy);
  EXPECT_EQ(c.cx, testing::test_camera(640, 480).cx);
}

TEST(FocalLength, EstimatesTheFieldOfViewOfRgbOnlyRendersWithinTenPercent) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const CpuSolver solver(*model);
  const FocalLengthOptions options;
  for (const double fov : {45.0, 60.0, 85.0}) {
    for (const uint32_t seed : {11u, 23u}) {
      const FocalLengthEstimate e = EstimateFocalLength(*model, turning_head(solver, fov, 0.6f, 5, seed), options);
      std::printf("true %.0f deg, seed %u: %s (error %.1f %%)\n", fov, seed, e.message.c_str(),
                  100.0 * (e.horizontal_fov_deg - fov) / fov);
      ASSERT_TRUE(e.estimated) << e.message;
      EXPECT_NEAR(e.horizontal_fov_deg, fov, 0.1 * fov) << e.message;
      EXPECT_EQ(e.frames, 5);
      EXPECT_EQ(static_cast<int>(e.energy_by_fov.size()), options.grid_points);
    }
  }
}

// The grid's fits run side by side on the pool (FocalLengthOptions::threads); each writes only
// its own grid point, so the search reads the same energies and lens on one thread as on four.
TEST(FocalLength, TheGridReadsTheSameOnAnyThreadCount) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const CpuSolver solver(*model);
  const std::vector<InputFrame> frames = turning_head(solver, 70.0, 0.6f, 5, 31u);
  FocalLengthOptions one, four;
  one.threads = 1;
  four.threads = 4;
  const FocalLengthEstimate a = EstimateFocalLength(*model, frames, one);
  const FocalLengthEstimate b = EstimateFocalLength(*model, frames, four);
  ASSERT_TRUE(a.estimated) << a.message;
  EXPECT_EQ(a.horizontal_fov_deg, b.horizontal_fov_deg);
  EXPECT_EQ(a.energy, b.energy);
  ASSERT_EQ(a.energy_by_fov.size(), b.energy_by_fov.size());
  for (size_t i = 0; i < a.energy_by_fov.size(); ++i) EXPECT_EQ(a.energy_by_fov[i], b.energy_by_fov[i]) << "grid point " << i;
}

TEST(FocalLength, BadInputFallsBackToSixtyDegreesWithAMessage) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const CpuSolver solver(*model);
  const FocalLengthOptions options;
  // No landmarks at all.
  std::vector<InputFrame> frames = turning_head(solver, 50.0, 0.6f, 3, 11);
  for (auto& f : frames) f.landmarks.clear();
  FocalLengthEstimate e = EstimateFocalLength(*model, frames, options);
  EXPECT_FALSE(e.estimated);
  EXPECT_EQ(e.horizontal_fov_deg, 60.0);
  EXPECT_NE(e.message.find("no calibration frame"), std::string::npos) << e.message;
  // Nothing at all, and landmarks that are not a face (every point at one place).
  EXPECT_FALSE(EstimateFocalLength(*model, {}, options).estimated);
  frames = turning_head(solver, 50.0, 0.6f, 3, 11);
  for (auto& f : frames)
    for (auto& l : f.landmarks) l.position = Eigen::Vector2f(320.f, 240.f);
  e = EstimateFocalLength(*model, frames, options);
  EXPECT_FALSE(e.estimated);
  EXPECT_EQ(e.horizontal_fov_deg, 60.0);
  EXPECT_FALSE(e.message.empty());
  // NaN landmark positions are skipped, never fitted.
  frames = turning_head(solver, 50.0, 0.6f, 3, 11);
  for (auto& f : frames)
    for (auto& l : f.landmarks) l.position.x() = std::nanf("");
  EXPECT_FALSE(EstimateFocalLength(*model, frames, options).estimated);
}

// The tracker: the estimate made by the first calibration is the camera of every later fit; with
// the estimate off (the front-ends' --fov) the frames' own camera stays and nothing is searched.
TEST(FocalLength, TheTrackerFitsLaterFramesThroughTheEstimateAndAGivenCameraOverridesIt) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const CpuSolver solver(*model);
  const double true_fov = 80.0;
  const std::vector<InputFrame> frames = turning_head(solver, true_fov, 0.6f, 6, 23);
  for (const bool estimate : {true, false}) {
    TrackerOptions o;
    o.calibration_frames = 5;
    o.calibration_solver.schedule = {{1, 6, 4}};
    o.focal_length.estimate = estimate;
    FaceTracker tracker(*model, o);
    for (int k = 0; k < 6; ++k) {
      const TrackedFrame t = tracker.Track(frames[k]);
      ASSERT_TRUE(t.has_parameters) << t.message;
      if (k < 4 || !estimate) {
        EXPECT_EQ(t.camera.fx, frames[k].camera.fx) << "frame " << k;  // the assumed 60 degrees
        continue;
      }
      // The calibrated frame and the next: through the estimate, principal point kept.
      EXPECT_NEAR(HorizontalFovDeg(t.camera), true_fov, 0.1 * true_fov) << "frame " << k << ": " << t.message;
      EXPECT_EQ(t.camera.cx, frames[k].camera.cx);
      EXPECT_TRUE(tracking_status_has_fit(t.status)) << t.message;
      // The fit is in that camera: its landmarks land where the frame's are.
      InputFrame seen = frames[k];
      seen.camera = t.camera;
      EXPECT_LT(LandmarkReprojectionError(*model, seen, t.params, 0.05f, true), 3.0) << "frame " << k;
      if (k == 4) EXPECT_NE(t.message.find("camera: estimated"), std::string::npos) << t.message;
    }
    EXPECT_EQ(tracker.focal_length_report().searched, estimate);
    if (estimate) EXPECT_TRUE(tracker.focal_length_report().estimate.estimated);
    tracker.Reset();
    EXPECT_FALSE(tracker.focal_length_report().searched);
  }
}

// Frames with depth carry the sensor's intrinsics: never searched, even with the estimate on.
TEST(FocalLength, FramesWithDepthKeepTheirCamera) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const CpuSolver solver(*model);
  TrackerOptions o;
  o.calibration_frames = 1;
  o.calibration_solver.schedule = {{1, 3, 4}};
  o.focal_length.estimate = true;
  FaceTracker tracker(*model, o);
  gpu::FaceParameters p = testing::true_parameters(*model, 0.6f, 11);
  const InputFrame f = RenderSyntheticFrame(solver.renderer(), *model, p, testing::test_camera(320, 240));
  ASSERT_TRUE(f.has_depth());
  for (int k = 0; k < 2; ++k) {
    const TrackedFrame t = tracker.Track(f);
    EXPECT_EQ(t.camera.fx, f.camera.fx) << t.message;
  }
  EXPECT_TRUE(tracker.calibrated());
  EXPECT_FALSE(tracker.focal_length_report().searched);
}

}  // namespace
}  // namespace face_reenact::tracker
