// The tracking pipeline (face_tracker.h): options, pose from landmarks, calibration then
// tracking on a synthetic sequence, and robustness: frames without a face, invalid and NaN
// depth, broken frames, a face leaving and re-entering, a sudden jump, recalibration requested
// from another thread, a replaced solver. Frames are 320x240 renders of the real model, so the
// whole file runs in seconds.
#include <gtest/gtest.h>

#include <array>
#include <atomic>
#include <cstdio>
#include <cmath>
#include <limits>
#include <random>
#include <stop_token>
#include <thread>

#include "face_reenact/common/error.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/tracker/evaluation.h"
#include "face_reenact/tracker/plausible_light.h"
#include "face_reenact/tracker/face_tracker.h"
#include "tracker_test_support.h"

namespace face_reenact::tracker {
namespace {

constexpr double kDeg = 180.0 / M_PI;

// A moving face: frame k of a smooth head motion with changing expression.
gpu::FaceParameters sequence_parameters(const TrackerModel& m, int k) {
  gpu::FaceParameters p = testing::true_parameters(m, 0.5f, 11);
  const float t = static_cast<float>(k);
  p.euler += Eigen::Vector3f(0.03f * std::sin(0.5f * t), 0.12f * std::sin(0.35f * t), 0.02f * std::cos(0.4f * t));
  p.translation += Eigen::Vector3f(0.01f * std::sin(0.3f * t), 0.005f * std::cos(0.45f * t), 0.01f * std::sin(0.2f * t));
  for (int e = 0; e < m.num_expression(); e += 9) p.delta[e] = 0.3f + 0.25f * std::sin(0.6f * t + e);
  return p;
}

// What a landmark detector reports: only the points inside the image.
InputFrame render_frame(const CpuSolver& solver, const gpu::FaceParameters& p, int w = 320, int h = 240) {
  InputFrame f = RenderSyntheticFrame(solver.renderer(), solver.model(), p, testing::test_camera(w, h));
  std::vector<InputLandmark> inside;
  for (const auto& l : f.landmarks) {
    if (l.position.x() >= 0 && l.position.y() >= 0 && l.position.x() <= w - 1 && l.position.y() <= h - 1) inside.push_back(l);
  }
  f.landmarks = inside;
  return f;
}

TrackerOptions fast_options(int calibration_frames) {
  TrackerOptions o;
  o.calibration_frames = calibration_frames;
  o.min_face_width_px = 20;  // the ~80 px faces here are solved on levels 2 and 1, as in the paper
  o.calibration_solver.schedule = {{2, 8, 6}, {1, 2, 6}};
  return o;
}

TEST(FaceTrackerOptions, DefaultsValidAndBadValuesRejected) {
  TrackerOptions o;
  std::string why;
  ASSERT_TRUE(o.IsValid(&why)) << why;
  auto expect_invalid = [](TrackerOptions bad, const std::string& needle) {
    std::string w;
    EXPECT_FALSE(bad.IsValid(&w)) << needle;
    EXPECT_NE(w.find(needle), std::string::npos) << w;
    // The constructor refuses them too (the sphere model keeps this test model-free).
    EXPECT_THROW(FaceTracker(testing::sphere_model(), bad), Error) << needle;
  };
  TrackerOptions bad = o;
  bad.calibration_frames = 0;
  expect_invalid(bad, "calibration_frames");
  bad = o;
  bad.calibration_frame_stride = 0;
  expect_invalid(bad, "calibration_frame_stride");
  bad = o;
  bad.calibration_start = static_cast<CalibrationStart>(7);
  expect_invalid(bad, "calibration_start");
  bad = o;
  bad.tracking_solver.schedule.clear();
  expect_invalid(bad, "tracking_solver");
  bad = o;
  bad.calibration_solver.energy.w_col = -1;
  expect_invalid(bad, "calibration_solver");
  bad = o;
  bad.recovery_solver.schedule = {{5, 1, 1}};
  expect_invalid(bad, "recovery_solver");
  bad = o;
  bad.loss.min_landmarks = 1;
  expect_invalid(bad, "min_landmarks");
  bad = o;
  bad.loss.max_energy_ratio = 0.5;
  expect_invalid(bad, "max_energy_ratio");
  bad = o;
  bad.loss.lost_landmark_error_px = std::numeric_limits<double>::quiet_NaN();
  expect_invalid(bad, "lost_landmark_error_px");
  bad = o;
  bad.default_face_distance_m = 0;
  expect_invalid(bad, "default_face_distance_m");
  bad = o;
  bad.calibration_min_face_width_px = -2;
  expect_invalid(bad, "calibration_min_face_width_px");
  bad = o;
  bad.calibration_identity_components = -2;
  expect_invalid(bad, "component");
  bad = o;
  bad.relaxed_recalibration_frames = bad.calibration_frames - 1;
  expect_invalid(bad, "relaxed_recalibration_frames");
  bad = o;
  bad.relaxed_margin = std::numeric_limits<float>::quiet_NaN();
  expect_invalid(bad, "relaxed_margin");
  bad = o;
  bad.relaxed_recalibration_above = -0.1f;
  expect_invalid(bad, "relaxed_recalibration_above");
  // More components than the model has is a model/options mismatch.
  TrackerOptions too_many = o;
  too_many.calibration_identity_components = 1000;
  EXPECT_THROW(FaceTracker(testing::sphere_model(), too_many), Error);
}

TEST(FaceTrackerOptions, CalibrationWindowNeedsRoomForTheFramesAndNoStride) {
  TrackerOptions o;
  o.calibration_window_frames = 60;
  EXPECT_TRUE(o.IsValid(nullptr));
  std::string why;
  o.calibration_window_frames = o.calibration_frames - 1;
  EXPECT_FALSE(o.IsValid(&why));
  EXPECT_NE(why.find("at least calibration_frames"), std::string::npos) << why;
  o.calibration_window_frames = 60;
  o.calibration_frame_stride = 4;
  EXPECT_FALSE(o.IsValid(&why));
  EXPECT_NE(why.find("calibration_frame_stride"), std::string::npos) << why;
  o.calibration_frame_stride = 1;
  o.calibration_window_frames = -1;
  EXPECT_FALSE(o.IsValid(&why));
}

TEST(CalibrationPoseSwap, WidensTheSpreadOfHeadPosesOrKeepsTheSet) {
  auto yaw = [](double deg) { return gpu::rotation_from_euler(Eigen::Vector3f(float(M_PI), float(deg / kDeg), 0.f)); };
  EXPECT_EQ(calibration_pose_swap({}, yaw(10)), -1);
  // {0, 2, 20}: 2 degrees next to 0 is the redundant one; -20 replaces it (spread 4+2+18 -> 20+20+40).
  EXPECT_EQ(calibration_pose_swap({yaw(0), yaw(2), yaw(20)}, yaw(-20)), 1);
  // A still head: the same pose again changes nothing (the earliest frames stay).
  EXPECT_EQ(calibration_pose_swap({yaw(0), yaw(0), yaw(0)}, yaw(0)), -1);
  // A candidate inside an already wide set does not narrow it.
  EXPECT_EQ(calibration_pose_swap({yaw(-25), yaw(0), yaw(25)}, yaw(3)), -1);
  // Pitch counts as much as yaw: a nod widens a set of yaws.
  const Eigen::Matrix3f nod = gpu::rotation_from_euler(Eigen::Vector3f(float(M_PI + 20 / kDeg), 0.f, 0.f));
  EXPECT_EQ(calibration_pose_swap({yaw(0), yaw(1), yaw(-20), yaw(20)}, nod), 1);
}

TEST(FaceTrackerOptions, StatusNames) {
  EXPECT_STREQ(tracking_status_name(TrackingStatus::kCalibrating), "calibrating");
  EXPECT_STREQ(tracking_status_name(TrackingStatus::kCalibrated), "calibrated");
  EXPECT_STREQ(tracking_status_name(TrackingStatus::kTracking), "tracking");
  EXPECT_STREQ(tracking_status_name(TrackingStatus::kRecovered), "recovered");
  EXPECT_STREQ(tracking_status_name(TrackingStatus::kLost), "lost");
  EXPECT_STREQ(tracking_status_name(TrackingStatus::kNoFace), "no_face");
  EXPECT_STREQ(tracking_status_name(TrackingStatus::kBadInput), "bad_input");
  EXPECT_TRUE(tracking_status_has_fit(TrackingStatus::kRecovered));
  EXPECT_FALSE(tracking_status_has_fit(TrackingStatus::kLost));
  EXPECT_STREQ(landmark_source_choice_name(LandmarkSourceChoice::kRecording), "recording");
  EXPECT_STREQ(landmark_source_choice_name(LandmarkSourceChoice::kDetector), "detector");
}

TEST(FaceTrackerOptions, ScheduleFollowsTheFaceSize) {
  SolverOptions paper;  // levels 2 then 1
  // A face 160 px wide is 40 px on level 2: the paper's schedule stands.
  EXPECT_EQ(AdaptScheduleToFaceSize(paper, 160, 40).schedule[0].level, 2);
  // 100 px: level 1 is the coarsest with 40 px; the schedule moves one level finer.
  SolverOptions s = AdaptScheduleToFaceSize(paper, 100, 40);
  EXPECT_EQ(s.schedule[0].level, 1);
  EXPECT_EQ(s.schedule[1].level, 0);
  EXPECT_EQ(s.schedule[0].gauss_newton_iterations, 7);
  // 30 px: everything on level 0 (never below it).
  s = AdaptScheduleToFaceSize(paper, 30, 40);
  EXPECT_EQ(s.schedule[0].level, 0);
  EXPECT_EQ(s.schedule[1].level, 0);
  // Disabled, or no face size known: unchanged.
  EXPECT_EQ(AdaptScheduleToFaceSize(paper, 30, 0).schedule[0].level, 2);
  EXPECT_EQ(AdaptScheduleToFaceSize(paper, 0, 40).schedule[0].level, 2);
  InputFrame f;
  EXPECT_EQ(LandmarkExtentPx(f, 0.f), 0.0);
  f.landmarks = {{36, {10.f, 5.f}, 1.f}, {45, {50.f, 6.f}, 1.f}, {30, {90.f, 6.f}, 0.f}};
  EXPECT_DOUBLE_EQ(LandmarkExtentPx(f, 0.f), 40.0);  // the zero-confidence point does not count
}

// The other way: a face wider than the bound on the finest solved level is solved on coarser
// levels (its pyramid deepened), with hysteresis, and never so coarse that the coarsest level
// holds it under the minimum.
TEST(FaceTrackerOptions, ALargeFaceIsSolvedOnCoarserLevels) {
  SolverOptions paper;  // levels 2 then 1, a pyramid of 3
  // 180 px: 90 on level 1, within 96: as scheduled.
  EXPECT_EQ(LargeFaceCoarsening(paper, 180, 96, 20, 0), 0);
  // 200 px: 100 on level 1: one level coarser (50 on level 2, 25 on level 3).
  EXPECT_EQ(LargeFaceCoarsening(paper, 200, 96, 20, 0), 1);
  // 800 px (a face filling a 1280-wide frame): still 100 on level 3; three levels coarser puts
  // the finest solve on level 4 (50 px) and the coarsest on 5 (25).
  EXPECT_EQ(LargeFaceCoarsening(paper, 800, 96, 20, 0), 3);
  // Hysteresis: coarser since the last frame, a face at 170 px (85 on level 1, over 0.8 x 96)
  // stays a level coarser; at 150 px (75, under 76.8) it comes back.
  EXPECT_EQ(LargeFaceCoarsening(paper, 170, 96, 20, 1), 1);
  EXPECT_EQ(LargeFaceCoarsening(paper, 150, 96, 20, 1), 0);
  // The minimum on the coarsest level wins: 200 px with a 30 px minimum would be 25 on level 3.
  EXPECT_EQ(LargeFaceCoarsening(paper, 200, 96, 30, 0), 0);
  // Off, or no face size known.
  EXPECT_EQ(LargeFaceCoarsening(paper, 800, 0, 20, 2), 0);
  EXPECT_EQ(LargeFaceCoarsening(paper, 0, 96, 20, 2), 0);
  const SolverOptions c = CoarsenSchedule(paper, 2);
  ASSERT_EQ(c.schedule.size(), paper.schedule.size());
  EXPECT_EQ(c.schedule[0].level, 4);
  EXPECT_EQ(c.schedule[1].level, 3);
  EXPECT_EQ(c.schedule[0].gauss_newton_iterations, paper.schedule[0].gauss_newton_iterations);
  EXPECT_EQ(c.pyramid.levels, 5);
  EXPECT_EQ(CoarsenSchedule(paper, 0).schedule[0].level, 2);
  TrackerOptions o;
  std::string why;
  o.max_face_width_px = -1;
  EXPECT_FALSE(o.IsValid(&why));
  EXPECT_NE(why.find("max_face_width_px"), std::string::npos) << why;
}

// The calibration of a large face: on every fourth pixel where its finest level holds the face
// wider than the bound, the rest of its options as they were.
TEST(FaceTrackerOptions, ALargeFaceIsCalibratedOnEveryFourthPixel) {
  const TrackerOptions defaults;
  const SolverOptions& calibration = defaults.calibration_solver;  // level 2, every other pixel
  ASSERT_EQ(calibration.energy.pixel_sampling, 2);
  const int bound = defaults.calibration_sparse_face_width_px;  // 56; the minimum 40, the maximum 80
  const auto sampling = [&](double face_width_px, int bound_px) {
    TrackerOptions o;
    o.calibration_sparse_face_width_px = bound_px;
    return CalibrationSolverForFace(o, face_width_px).energy.pixel_sampling;
  };
  // A 640x480 webcam's face (80 px): 40 on level 1, every other pixel.
  EXPECT_EQ(sampling(80, bound), 2);
  // 110 px: 55 on level 1, within the bound.
  EXPECT_EQ(sampling(110, bound), 2);
  // A 512x512 portrait's (250 px): 62 on level 2, every fourth pixel.
  EXPECT_EQ(sampling(250, bound), 4);
  // 1000 px: 62 on level 4, two levels coarser than the schedule's (at most 80 px): every fourth
  // pixel too.
  EXPECT_EQ(sampling(1000, bound), 4);
  EXPECT_EQ(FinestScheduledLevel(CalibrationSolverForFace(defaults, 1000)), 4);
  EXPECT_EQ(FinestScheduledLevel(CalibrationSolverForFace(defaults, 250)), 2);
  // Off, no face size known, or every pixel asked for: as given.
  EXPECT_EQ(sampling(250, 0), 2);
  EXPECT_EQ(sampling(0, bound), 2);
  SolverOptions every = calibration;
  every.energy.pixel_sampling = 1;
  EXPECT_EQ(SparserSamplingForLargeFace(every, 250, bound).energy.pixel_sampling, 1);
  const SolverOptions sparse = SparserSamplingForLargeFace(calibration, 250, bound);
  EXPECT_EQ(sparse.schedule[0].level, calibration.schedule[0].level);
  EXPECT_EQ(sparse.schedule[0].gauss_newton_iterations, calibration.schedule[0].gauss_newton_iterations);
  TrackerOptions o;
  std::string why;
  o.calibration_sparse_face_width_px = -1;
  EXPECT_FALSE(o.IsValid(&why));
  EXPECT_NE(why.find("calibration_sparse_face_width_px"), std::string::npos) << why;
  o = TrackerOptions();
  o.calibration_max_face_width_px = 5000;
  EXPECT_FALSE(o.IsValid(&why));
  EXPECT_NE(why.find("calibration_max_face_width_px"), std::string::npos) << why;
}

TEST(PoseFromLandmarks, RecoversATurnedHeadWithAndWithoutDepth) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const CpuSolver solver(*model);
  gpu::FaceParameters truth = testing::true_parameters(*model, 0.5f, 5);
  truth.euler += Eigen::Vector3f(0.1f, 0.45f, -0.15f);  // ~26 degrees of yaw
  const InputFrame frame = render_frame(solver, truth);
  const Eigen::Matrix3f rt = gpu::rotation_from_euler(truth.euler);
  for (bool depth : {true, false}) {
    InputFrame f = frame;
    if (!depth) f.depth.clear();
    const PoseInitResult r = InitializePoseFromLandmarks(*model, f, truth, PoseInitOptions());
    ASSERT_TRUE(r.ok) << r.message;
    EXPECT_EQ(r.used_depth, depth);
    const double angle = Eigen::AngleAxisf(gpu::rotation_from_euler(r.euler).transpose() * rt).angle() * kDeg;
    // 2 degrees: since synthetic frames show the eyeballs (a camera sees them), the depth-based
    // start reads 1.65 degrees here (under 1 before); the Gauss-Newton solve refines it.
    EXPECT_LT(angle, 2.0) << "depth " << depth;
    EXPECT_LT((r.translation - truth.translation).norm(), depth ? 0.005f : 0.02f) << "depth " << depth;
    EXPECT_LT(r.mean_error_px, 1.0);
  }
  // Too few landmarks: a clear refusal, no pose.
  InputFrame sparse = frame;
  sparse.landmarks.resize(3);
  const PoseInitResult r = InitializePoseFromLandmarks(*model, sparse, truth, PoseInitOptions());
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.message.find("landmarks"), std::string::npos);
  PoseInitOptions bad;
  bad.max_iterations = 0;
  EXPECT_FALSE(InitializePoseFromLandmarks(*model, frame, truth, bad).ok);
}

TEST(FaceTracker, CalibratesThenTracksASequence) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  FaceTracker tracker(*model, fast_options(3));
  EXPECT_FALSE(tracker.calibrated());
  EXPECT_EQ(tracker.neutral().alpha.norm(), 0.f);
  const gpu::CpuRenderer& renderer = tracker.cpu_solver().renderer();
  double worst_rotation = 0, worst_translation = 0, mean_geometric = 0;
  int evaluated = 0;
  for (int k = 0; k < 8; ++k) {
    const gpu::FaceParameters truth = sequence_parameters(*model, k);
    const TrackedFrame t = tracker.Track(render_frame(tracker.cpu_solver(), truth));
    EXPECT_EQ(t.frame_index, k);
    ASSERT_TRUE(t.has_parameters) << t.message;
    if (k < 2) {
      EXPECT_EQ(t.status, TrackingStatus::kCalibrating) << t.message;
      EXPECT_NE(t.message.find("calibrating: " + std::to_string(k + 1) + " of 3"), std::string::npos) << t.message;
    } else if (k == 2) {
      EXPECT_EQ(t.status, TrackingStatus::kCalibrated) << t.message;
      EXPECT_GT(t.times.calibration_ms, 0.0);
    } else {
      EXPECT_EQ(t.status, TrackingStatus::kTracking) << t.message;
    }
    EXPECT_EQ(k == 0, t.pose_reinitialized);
    EXPECT_GT(t.times.total_ms, 0.0);
    EXPECT_GT(t.times.synthesis_ms + t.times.analysis_ms, 0.0);
    EXPECT_GT(t.residuals, 100);
    EXPECT_GE(t.landmarks_used, 30);
    EXPECT_LT(t.landmark_error_px, 3.0) << "frame " << k;
    if (k >= 2) {
      const FitErrors e = CompareToGroundTruth(renderer, *model, t.params, truth, testing::test_camera(320, 240));
      std::printf("frame %d %s: surface %.2f mm (max %.2f), rotation %.2f deg, translation %.2f mm, expression %.3f\n", k,
                  tracking_status_name(t.status), e.geometric_mm_mean, e.geometric_mm_max, e.rotation_deg,
                  e.translation_mm, e.expression_mean_abs);
      worst_rotation = std::max(worst_rotation, e.rotation_deg);
      worst_translation = std::max(worst_translation, e.translation_mm);
      mean_geometric += e.geometric_mm_mean;
      ++evaluated;
    }
  }
  mean_geometric /= evaluated;
  // Loose versions of the targets (1 degree, 2 mm, 1.5 mm) on noise-free renders. The
  // calibrated identity trades off against the pose (measured here: surface 0.33-0.48 mm,
  // 0.53-0.70 degrees, 3.2-3.4 mm of the model origin; with the point-to-point term in the
  // calibration, before 2026-11-23: 1.0-1.1 mm, 1.3-1.4 degrees, 8 mm); docs/tracker.md has the
  // numbers and the reason.
  EXPECT_LT(worst_rotation, 1.2);
  EXPECT_LT(worst_translation, 5.0);
  EXPECT_LT(mean_geometric, 0.8);
  ASSERT_TRUE(tracker.calibrated());
  EXPECT_GT(tracker.neutral().alpha.norm(), 0.f);  // identity was fitted
  EXPECT_EQ(tracker.neutral().delta.size(), model->num_expression());
  EXPECT_GE(tracker.neutral().delta.minCoeff(), 0.f);
  EXPECT_LE(tracker.neutral().delta.maxCoeff(), 1.f);
  EXPECT_GT(tracker.neutral().delta.sum(), 0.f);  // the mean of the calibration expressions
  EXPECT_FALSE(tracker.calibration_summary().iterations.empty());
}

// An actor with a neutral face and an identity far from the mean: the fits before calibration
// (mean identity) read expressions into the shape difference. Started from those expressions the
// joint solve keeps much of them. CalibrationStart::kLowerEnergy also solves from neutral (the
// default start) and keeps the lower final energy; here that is the neutral start, which
// recovers a neutral near zero. Prints the figures, so the docs' can be checked.
TEST(FaceTracker, CalibrationOfANeutralActorFindsANeutralExpression) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  gpu::FaceParameters actor = testing::true_parameters(*model, 0.5f, 3);
  for (int k = 0; k < model->num_identity(); ++k) actor.alpha[k] = 1.5f * u(rng) * model->identity_sigma[k];
  actor.delta.setZero();
  auto max_weight = [](const Eigen::VectorXf& d) { return d.size() ? d.cwiseAbs().maxCoeff() : 0.f; };
  float pre_calibration = 0;
  float fits_total = 0;            // neutral's sum of weights, started from the fits' expressions
  double fits_energy = 0;          // that solve's final energy
  for (const CalibrationStart start : {CalibrationStart::kPerFrameFits, CalibrationStart::kLowerEnergy}) {
    TrackerOptions o = fast_options(3);
    o.calibration_start = start;
    FaceTracker tracker(*model, o);
    TrackedFrame t;
    for (int k = 0; k < 3; ++k) {
      gpu::FaceParameters p = actor;
      p.euler.y() += 0.12f * static_cast<float>(k - 1);
      t = tracker.Track(render_frame(tracker.cpu_solver(), p));
      ASSERT_TRUE(t.has_parameters) << t.message;
      if (k == 0) pre_calibration = std::max(pre_calibration, max_weight(t.params.delta));
    }
    ASSERT_TRUE(tracker.calibrated());
    const FaceTracker::CalibrationStartReport& r = tracker.calibration_start_report();
    const float largest = max_weight(tracker.neutral().delta);
    const float total = tracker.neutral().delta.cwiseAbs().sum();
    std::printf("start %s: kept %s, E neutral %.4f, E fits %.4f; neutral expression largest weight %.3f, sum of 52 %.3f "
                "(before calibration: %.3f)\n",
                calibration_start_name(start), calibration_start_name(r.kept), r.neutral_energy, r.per_frame_fits_energy,
                largest, total, pre_calibration);
    if (start == CalibrationStart::kPerFrameFits) {
      EXPECT_EQ(r.kept, CalibrationStart::kPerFrameFits);
      EXPECT_TRUE(std::isnan(r.neutral_energy)) << "only one start was asked for";
      fits_total = total;
      fits_energy = r.per_frame_fits_energy;
      continue;
    }
    // Both starts were solved; the kept one is the lower energy and its solve is the summary.
    ASSERT_TRUE(std::isfinite(r.neutral_energy) && std::isfinite(r.per_frame_fits_energy)) << t.message;
    EXPECT_NEAR(r.per_frame_fits_energy, fits_energy, 1e-3 * fits_energy) << "the same solve as kPerFrameFits";
    const double lower = std::min(r.neutral_energy, r.per_frame_fits_energy);
    EXPECT_EQ(r.kept, r.neutral_energy <= r.per_frame_fits_energy ? CalibrationStart::kNeutral : CalibrationStart::kPerFrameFits);
    EXPECT_DOUBLE_EQ(tracker.calibration_summary().final_energy.total(), lower);
    EXPECT_NE(t.message.find("against"), std::string::npos) << "the message names both energies: " << t.message;
    // Measured: kept neutral; largest 0.09 / sum 0.54, against sum 2.4 from the fits (0.85
    // before calibration); the neutral is read by the tracking re-fit (neutral_from_tracking).
    EXPECT_EQ(r.kept, CalibrationStart::kNeutral);
    EXPECT_LT(largest, 0.35f);
    EXPECT_LT(total, 2.5f);
    EXPECT_GT(fits_total, 2.0f * total) << "starting from the fits' expressions should keep much of them";
  }
  EXPECT_GT(pre_calibration, 0.5f) << "the fits before calibration should read a false expression here";
}

// The default joint calibration solve, long as it is, ends at its lowest energy: each accepted
// step is judged with the correspondences held, so a term whose Gauss-Newton model is biased
// against the re-rendered energy shows up as an energy that climbs again after its low. The
// projective point-to-point term did (on a 640x480 recording: 1.74 -> 2.42 over the last 37 of
// 60 iterations); the calibration leaves it out. Run with it too, so the check is shown to bite.
TEST(FaceTracker, TheCalibrationSolveDoesNotClimbAfterItsLowestEnergy) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const CpuSolver solver(*model);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  gpu::FaceParameters actor = testing::true_parameters(*model, 0.45f, 5);
  for (int k = 0; k < model->num_identity(); ++k) actor.alpha[k] = 1.5f * u(rng) * model->identity_sigma[k];
  std::vector<InputFrame> frames;
  std::vector<gpu::FaceParameters> starts;
  for (int k = 0; k < 3; ++k) {
    gpu::FaceParameters p = actor;
    p.euler.y() += 0.15f * static_cast<float>(k - 1);
    frames.push_back(render_frame(solver, p));
    // The start: the mean face, neutral, at a pose a mean-identity fit would give (a few mm and
    // a degree off).
    p.alpha.setZero();
    p.beta.setZero();
    p.delta.setZero();
    p.translation.z() -= 0.004f;
    p.euler.x() -= 0.02f;
    starts.push_back(p);
  }
  const ParameterLayout layout =
      ParameterLayout::Calibration(model->num_identity(), model->num_albedo(), model->num_expression());
  auto climb = [&](const SolverOptions& so, const char* name) {
    std::vector<gpu::FaceParameters> p = starts;
    const SolverSummary s = solver.SolveFrames(frames, layout, so, &p);
    double lowest = s.initial_energy.total();
    for (const IterationRecord& r : s.iterations) lowest = std::min(lowest, r.energy_after.total());
    const double rise = s.final_energy.total() / lowest - 1.0;
    std::printf("%s: %zu iterations, E %.4f -> lowest %.4f, final %.4f (%.1f %% above the lowest)\n", name,
                s.iterations.size(), s.initial_energy.total(), lowest, s.final_energy.total(), 100.0 * rise);
    return rise;
  };
  const SolverOptions calibration = AdaptScheduleToFaceSize(TrackerOptions{}.calibration_solver, 90.0, 40);
  EXPECT_FALSE(calibration.energy.use_point);
  SolverOptions with_point = calibration;
  with_point.energy.use_point = true;
  // The check's own sensitivity: the energy the climb was found in, with the point term and the
  // colour held in the image (EnergyOptions::color_follows_projection off), climbs. Measured on
  // these noise-free renders: 0.1 % by default, 0.7 % then (1.4 % before the robust colour, 39 %
  // on the recording above); with the point term and the colour read through the projection, 0.0 %.
  // At the paper's weight the climb on these renders is small and moves with the fit (0.7 %, then
  // 0.1 % once the lip points were re-bound, 2026-11-27), so the check is shown to bite at 4x
  // the point term's weight: 9.6 % (2x: 0.2 %, 8x: 210 %).
  with_point.energy.color_follows_projection = false;
  with_point.energy.w_point *= 4.0;
  EXPECT_LT(climb(calibration, "default calibration"), 0.005);
  EXPECT_GT(climb(with_point, "with the point-to-point term at 4x, colour held in the image"), 0.005);
}

TEST(FaceTracker, SurvivesBadFramesAndRecovers) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  FaceTracker tracker(*model, fast_options(1));
  const CpuSolver& solver = tracker.cpu_solver();
  const gpu::CpuRenderer& renderer = solver.renderer();
  const gpu::PinholeCamera camera = testing::test_camera(320, 240);
  int k = 0;
  auto truth_at = [&](int i) { return sequence_parameters(*model, i); };

  // No face before anything was ever fitted: no parameters at all.
  InputFrame blank;
  blank.camera = camera;
  blank.color.assign(3 * 320 * 240, 0.3f);
  blank.depth.assign(320 * 240, 0.f);
  TrackedFrame t = tracker.Track(blank);
  EXPECT_EQ(t.status, TrackingStatus::kNoFace);
  EXPECT_FALSE(t.has_parameters);
  EXPECT_NE(t.message.find("no face"), std::string::npos) << t.message;

  t = tracker.Track(render_frame(solver, truth_at(k++)));
  ASSERT_EQ(t.status, TrackingStatus::kCalibrated) << t.message;
  t = tracker.Track(render_frame(solver, truth_at(k++)));
  ASSERT_EQ(t.status, TrackingStatus::kTracking) << t.message;
  const gpu::FaceParameters good = t.params;

  // No face: the last good parameters are held, the status says so.
  t = tracker.Track(blank);
  EXPECT_EQ(t.status, TrackingStatus::kNoFace);
  ASSERT_TRUE(t.has_parameters);
  EXPECT_TRUE(t.params.translation.isApprox(good.translation));
  // The face is back: re-initialised from the landmarks, no user action.
  gpu::FaceParameters truth = truth_at(k++);
  t = tracker.Track(render_frame(solver, truth));
  EXPECT_EQ(t.status, TrackingStatus::kRecovered) << t.message;
  EXPECT_TRUE(t.pose_reinitialized);
  EXPECT_LT(CompareToGroundTruth(renderer, *model, t.params, truth, camera).rotation_deg, 2.0);

  // All-invalid depth, then a NaN depth map: fitted from colour and landmarks, and said so.
  for (float bad_depth : {0.f, std::numeric_limits<float>::quiet_NaN()}) {
    truth = truth_at(k++);
    InputFrame f = render_frame(solver, truth);
    std::fill(f.depth.begin(), f.depth.end(), bad_depth);
    t = tracker.Track(f);
    EXPECT_TRUE(tracking_status_has_fit(t.status)) << t.message;
    EXPECT_NE(t.message.find("no valid depth"), std::string::npos) << t.message;
    const FitErrors e = CompareToGroundTruth(renderer, *model, t.params, truth, camera);
    EXPECT_LT(e.rotation_deg, 5.0);     // measured 3.3-3.5 degrees: no depth to pin the pose
    EXPECT_LT(e.translation_mm, 30.0);  // depth from colour and landmarks alone is loose
  }

  // Broken frames: a clear status, the last good fit held, nothing thrown.
  InputFrame nan_colour = render_frame(solver, truth_at(k));
  nan_colour.color[100] = std::numeric_limits<float>::quiet_NaN();
  t = tracker.Track(nan_colour);
  EXPECT_EQ(t.status, TrackingStatus::kBadInput);
  EXPECT_NE(t.message.find("colour"), std::string::npos) << t.message;
  EXPECT_TRUE(t.has_parameters);
  InputFrame wrong_size = render_frame(solver, truth_at(k));
  wrong_size.color.resize(10);
  EXPECT_EQ(tracker.Track(wrong_size).status, TrackingStatus::kBadInput);
  InputFrame bad_landmark = render_frame(solver, truth_at(k));
  bad_landmark.landmarks[0].ibug_index = 99;
  EXPECT_EQ(tracker.Track(bad_landmark).status, TrackingStatus::kBadInput);
  // Landmarks far outside the image (a broken detector): handled, never a crash.
  InputFrame wild = render_frame(solver, truth_at(k));
  for (auto& l : wild.landmarks) l.position = Eigen::Vector2f(3e30f, -2e30f);
  t = tracker.Track(wild);
  EXPECT_FALSE(tracking_status_has_fit(t.status)) << t.message;
  EXPECT_FALSE(t.message.empty());
  InputFrame tiny;
  tiny.camera = testing::test_camera(3, 3);
  tiny.color.assign(27, 0.5f);
  t = tracker.Track(tiny);
  EXPECT_EQ(t.status, TrackingStatus::kBadInput);
  EXPECT_NE(t.message.find("too small"), std::string::npos) << t.message;

  // The face leaves the image sideways over a few frames, then comes back elsewhere.
  int no_face = 0;
  for (float dx : {0.1f, 0.2f, 0.35f}) {
    gpu::FaceParameters away = truth_at(k++);
    away.translation.x() += dx;
    t = tracker.Track(render_frame(solver, away));
    no_face += t.status == TrackingStatus::kNoFace;
    EXPECT_NE(t.status, TrackingStatus::kBadInput) << t.message;
  }
  EXPECT_GE(no_face, 1);
  int frames_to_recover = 0;
  for (int i = 0; i < 4; ++i) {
    truth = truth_at(k++);
    truth.translation.x() -= 0.06f;
    t = tracker.Track(render_frame(solver, truth));
    ++frames_to_recover;
    if (tracking_status_has_fit(t.status)) break;
  }
  EXPECT_LE(frames_to_recover, 2) << t.message;
  EXPECT_LT(CompareToGroundTruth(renderer, *model, t.params, truth, camera).rotation_deg, 2.0) << t.message;

  // A sudden jump (a cut in the video): the warm start is far off, the pose is re-initialised.
  t = tracker.Track(render_frame(solver, truth_at(k++)));
  EXPECT_TRUE(tracking_status_has_fit(t.status)) << t.message;
  truth = truth_at(k++);
  truth.translation += Eigen::Vector3f(0.07f, -0.04f, 0.05f);
  truth.euler.y() += 0.3f;
  t = tracker.Track(render_frame(solver, truth));
  EXPECT_EQ(t.status, TrackingStatus::kRecovered) << t.message;
  EXPECT_TRUE(t.pose_reinitialized);
  EXPECT_LT(CompareToGroundTruth(renderer, *model, t.params, truth, camera).rotation_deg, 2.0) << t.message;
}

TEST(FaceTracker, RecalibratesOnRequestFromAnotherThreadAndResets) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  FaceTracker tracker(*model, fast_options(1));
  const CpuSolver& solver = tracker.cpu_solver();
  ASSERT_EQ(tracker.Track(render_frame(solver, sequence_parameters(*model, 0))).status, TrackingStatus::kCalibrated);
  const Eigen::VectorXf first_identity = tracker.neutral().alpha;
  ASSERT_EQ(tracker.Track(render_frame(solver, sequence_parameters(*model, 1))).status, TrackingStatus::kTracking);
  std::thread ui([&] { tracker.RequestCalibration(); });
  ui.join();
  const TrackedFrame t = tracker.Track(render_frame(solver, sequence_parameters(*model, 2)));
  EXPECT_EQ(t.status, TrackingStatus::kCalibrated) << t.message;  // one calibration frame
  EXPECT_TRUE(tracker.calibrated());
  EXPECT_GT((tracker.neutral().alpha - first_identity).norm(), 0.f);  // fitted again on new frames
  tracker.Reset();
  EXPECT_FALSE(tracker.calibrated());
  EXPECT_EQ(tracker.neutral().alpha.norm(), 0.f);
  EXPECT_FALSE(tracker.last_good().has_parameters);
  const TrackedFrame again = tracker.Track(render_frame(solver, sequence_parameters(*model, 3)));
  EXPECT_EQ(again.frame_index, 0);
  EXPECT_EQ(again.status, TrackingStatus::kCalibrated);
}

// The landmark tracker left a small face for a more prominent one (InputFrame::new_face): the
// new person's identity is calibrated from their own frames, their pose comes from the
// landmarks (not the other face's fit), and the frame says why.
TEST(FaceTracker, ANewFaceRestartsTheCalibrationAndThePose) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  FaceTracker tracker(*model, fast_options(2));
  const CpuSolver& solver = tracker.cpu_solver();
  tracker.Track(render_frame(solver, sequence_parameters(*model, 0)));
  ASSERT_EQ(tracker.Track(render_frame(solver, sequence_parameters(*model, 1))).status, TrackingStatus::kCalibrated);
  const Eigen::VectorXf first_identity = tracker.neutral().alpha;
  TrackedFrame t = tracker.Track(render_frame(solver, sequence_parameters(*model, 2)));
  ASSERT_EQ(t.status, TrackingStatus::kTracking) << t.message;
  EXPECT_FALSE(t.new_face);

  InputFrame other = render_frame(solver, sequence_parameters(*model, 3));
  other.new_face = true;
  t = tracker.Track(other);
  EXPECT_TRUE(t.new_face);
  EXPECT_EQ(t.status, TrackingStatus::kCalibrating) << t.message;
  EXPECT_TRUE(t.pose_reinitialized) << t.message;
  EXPECT_NE(t.message.find("more prominent face"), std::string::npos) << t.message;
  EXPECT_NE(t.message.find("1 of 2 frames"), std::string::npos) << t.message;  // a fresh collection
  t = tracker.Track(render_frame(solver, sequence_parameters(*model, 4)));
  EXPECT_FALSE(t.new_face);
  EXPECT_EQ(t.status, TrackingStatus::kCalibrated) << t.message;
  EXPECT_GT((tracker.neutral().alpha - first_identity).norm(), 0.f);  // fitted again on the new frames
}

TEST(FaceTracker, CalibratesFromLandmarkPosesWithoutTrackingFirst) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  TrackerOptions o = fast_options(2);
  o.track_while_calibrating = false;
  FaceTracker tracker(*model, o);
  const CpuSolver& solver = tracker.cpu_solver();
  TrackedFrame t = tracker.Track(render_frame(solver, sequence_parameters(*model, 0)));
  EXPECT_EQ(t.status, TrackingStatus::kCalibrating) << t.message;
  EXPECT_FALSE(t.has_parameters);
  EXPECT_NE(t.message.find("not fitted yet"), std::string::npos) << t.message;
  EXPECT_EQ(t.times.synthesis_ms, 0.0);  // no solve ran
  const gpu::FaceParameters truth = sequence_parameters(*model, 1);
  t = tracker.Track(render_frame(solver, truth));
  ASSERT_EQ(t.status, TrackingStatus::kCalibrated) << t.message;
  ASSERT_TRUE(t.has_parameters);
  EXPECT_LT(CompareToGroundTruth(solver.renderer(), *model, t.params, truth, testing::test_camera(320, 240)).rotation_deg, 2.5);
  t = tracker.Track(render_frame(solver, sequence_parameters(*model, 2)));
  EXPECT_EQ(t.status, TrackingStatus::kTracking) << t.message;
}

// The paper's calibration sequence is the actor turning the head: within a window the tracker
// keeps the frames with the most varied head poses. Here a turned, a frontal and an opposite
// turned view, then a near-frontal one that ends the window: the set keeps both turned views,
// calibrates on the window's last frame and fits that frame (not in the set) with the new
// identity.
TEST(FaceTracker, ACalibrationWindowKeepsTheMostVariedPosesAndFitsTheFrameThatEndsIt) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  TrackerOptions o = fast_options(2);
  o.calibration_window_frames = 4;
  FaceTracker tracker(*model, o);
  const CpuSolver& solver = tracker.cpu_solver();
  const float yaw[4] = {-0.25f, 0.0f, 0.25f, 0.02f};
  for (int k = 0; k < 4; ++k) {
    gpu::FaceParameters truth = sequence_parameters(*model, 0);
    truth.euler.y() += yaw[k];
    const TrackedFrame t = tracker.Track(render_frame(solver, truth));
    ASSERT_TRUE(t.has_parameters) << t.message;
    if (k < 3) {
      EXPECT_EQ(t.status, TrackingStatus::kCalibrating) << t.message;
      EXPECT_NE(t.message.find("watching " + std::to_string(k + 1) + " of 4"), std::string::npos) << t.message;
    } else {
      EXPECT_EQ(t.status, TrackingStatus::kCalibrated) << t.message;
      const FitErrors e = CompareToGroundTruth(solver.renderer(), *model, t.params, truth, testing::test_camera(320, 240));
      EXPECT_LT(e.rotation_deg, 2.0);  // the set's last frame is 13 degrees away
      EXPECT_LT(t.landmark_error_px, 3.0);
    }
    if (k == 1) EXPECT_EQ(tracker.calibration_frame_indices(), (std::vector<int64_t>{0, 1}));
    if (k == 2) EXPECT_EQ(tracker.calibration_frame_indices(), (std::vector<int64_t>{0, 2}));  // the frontal view gave way
  }
  EXPECT_TRUE(tracker.calibrated());
}

// With exact eye landmarks (EnergyOptions::all_inner_landmarks) closed eyes are read: the dense
// terms barely see an eyelid at the tracking levels. Before the landmark visibility became a
// depth test the eye landmarks never counted, and a held blink read 0.005.
TEST(FaceTracker, ReadsClosedEyesFromTheEyeLandmarks) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  TrackerOptions o = fast_options(2);
  for (SolverOptions* s : {&o.calibration_solver, &o.tracking_solver, &o.recovery_solver}) s->energy.all_inner_landmarks = true;
  FaceTracker tracker(*model, o);
  const CpuSolver& solver = tracker.cpu_solver();
  const int left = arkit_blendshape_index("eyeBlinkLeft"), right = arkit_blendshape_index("eyeBlinkRight");
  gpu::FaceParameters truth = testing::true_parameters(*model, 0.6f, 11);
  truth.delta.setZero();
  TrackedFrame t;
  for (int k = 0; k < 7; ++k) {
    truth.delta[left] = truth.delta[right] = k < 3 ? 0.f : 1.f;
    t = tracker.Track(render_frame(solver, truth));
    ASSERT_TRUE(t.has_parameters) << t.message;
    if (k == 2) {
      EXPECT_LT(t.params.delta[left], 0.1f);
      EXPECT_LT(t.params.delta[right], 0.1f);
    }
  }
  EXPECT_EQ(t.status, TrackingStatus::kTracking) << t.message;
  std::printf("closed eyes read as eyeBlinkLeft %.2f, eyeBlinkRight %.2f\n", t.params.delta[left], t.params.delta[right]);
  EXPECT_GT(t.params.delta[left], 0.3f);
  EXPECT_GT(t.params.delta[right], 0.3f);
}

TEST(FaceTracker, UsesAReplacementSolver) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  FaceTracker tracker(*model, fast_options(1));
  std::atomic<int> calls{0};
  const CpuSolver& cpu = tracker.cpu_solver();
  tracker.SetTrackingSolver([&](const InputFrame& frame, const ParameterLayout& layout, const SolverOptions& options,
                                gpu::FaceParameters* params) {
    ++calls;
    return cpu.Solve(frame, layout, options, params);
  });
  tracker.Track(render_frame(cpu, sequence_parameters(*model, 0)));
  const TrackedFrame t = tracker.Track(render_frame(cpu, sequence_parameters(*model, 1)));
  EXPECT_EQ(t.status, TrackingStatus::kTracking) << t.message;
  // Two frames, and the neutral's re-fit of the one calibration frame (neutral_from_tracking).
  EXPECT_EQ(calls.load(), 3);
  tracker.SetTrackingSolver({});
  tracker.Track(render_frame(cpu, sequence_parameters(*model, 2)));
  EXPECT_EQ(calls.load(), 3);
  // A solver that fails (throws) makes that frame kBadInput, not a crash.
  tracker.SetTrackingSolver([](const InputFrame&, const ParameterLayout&, const SolverOptions&,
                               gpu::FaceParameters*) -> SolverSummary { throw Error("device lost"); });
  const TrackedFrame failed = tracker.Track(render_frame(cpu, sequence_parameters(*model, 3)));
  EXPECT_EQ(failed.status, TrackingStatus::kBadInput);
  EXPECT_NE(failed.message.find("device lost"), std::string::npos) << failed.message;
  EXPECT_TRUE(failed.has_parameters);
}

// A face wider than TrackerOptions::max_face_width_px on the finest solved level is tracked on
// coarser levels: at 640x480 this test's face is ~150 px wide, 75 on level 1; with a bound of 60
// the per-frame solves run on levels 3 and 2 (their pyramid deepened), with the default 96 on the
// paper's 2 and 1, and the face is tracked either way.
TEST(FaceTracker, ALargeFaceIsTrackedOnCoarserLevels) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  for (const int bound : {96, 60}) {
    TrackerOptions o = fast_options(1);
    o.max_face_width_px = bound;
    o.min_face_width_px = 10;  // a level coarser leaves the face ~18 px on the coarsest (20 refuses that)
    FaceTracker tracker(*model, o);
    const CpuSolver& cpu = tracker.cpu_solver();
    std::vector<std::pair<int, int>> finest_and_pyramid;
    tracker.SetTrackingSolver([&](const InputFrame& frame, const ParameterLayout& layout, const SolverOptions& options,
                                  gpu::FaceParameters* params) {
      int finest = 99;
      for (const auto& l : options.schedule) finest = std::min(finest, l.level);
      finest_and_pyramid.emplace_back(finest, options.pyramid.levels);
      return cpu.Solve(frame, layout, options, params);
    });
    TrackedFrame t;
    for (int k = 0; k < 3; ++k) t = tracker.Track(render_frame(cpu, sequence_parameters(*model, k), 640, 480));
    EXPECT_EQ(t.status, TrackingStatus::kTracking) << bound << ": " << t.message;
    ASSERT_FALSE(finest_and_pyramid.empty());
    for (const auto& [finest, pyramid] : finest_and_pyramid) {
      EXPECT_EQ(finest, bound == 96 ? 1 : 2) << bound;
      EXPECT_GE(pyramid, finest + 2) << bound;  // the coarser level of the two exists
    }
  }
}

// Whatever the solve leaves, the tracker never reports a light no room gives (plausible_light.h):
// here the solve is followed by blue's light turned negative, as the Breaking Bad still's fit
// drifted; the tracked frame's light has a non-negative ambient and no negative light beyond the
// truncation's ringing, and red and green are the solve's own.
TEST(FaceTracker, ALightNoRoomGivesIsNeverReported) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  FaceTracker tracker(*model, fast_options(1));
  const CpuSolver& cpu = tracker.cpu_solver();
  gpu::FaceParameters solved;
  tracker.SetTrackingSolver([&](const InputFrame& frame, const ParameterLayout& layout, const SolverOptions& options,
                                gpu::FaceParameters* params) {
    SolverSummary s = cpu.Solve(frame, layout, options, params);
    for (int k = 0; k < 9; ++k) params->gamma[static_cast<size_t>(18 + k)] = -0.7f * params->gamma[static_cast<size_t>(k)];
    solved = *params;
    return s;
  });
  tracker.Track(render_frame(cpu, sequence_parameters(*model, 0)));
  const TrackedFrame t = tracker.Track(render_frame(cpu, sequence_parameters(*model, 1)));
  ASSERT_EQ(t.status, TrackingStatus::kTracking) << t.message;
  EXPECT_LT(LowestRelativeIrradiance(solved.gamma, 2), -1.f);  // what the solve gave
  EXPECT_GE(t.params.gamma[18], -1e-6f);
  EXPECT_GE(LowestRelativeIrradiance(t.params.gamma, 2), -kNegativeLobe - 0.01f);
  for (int k = 0; k < 18; ++k) EXPECT_EQ(t.params.gamma[static_cast<size_t>(k)], solved.gamma[static_cast<size_t>(k)]);
  // The frame says so (the report counts such frames), and by how much.
  EXPECT_TRUE(t.light.changed);
  float moved = 0.f;
  for (int k = 18; k < 27; ++k) moved += std::pow(t.params.gamma[static_cast<size_t>(k)] - solved.gamma[static_cast<size_t>(k)], 2.f);
  EXPECT_NEAR(t.light.moved, std::sqrt(moved), 1e-4f);
  LightProjectionTally tally;
  tally.Add(t.light);
  tally.Add(LightProjection{});
  EXPECT_EQ(tally.frames, 2);
  EXPECT_EQ(tally.projected, 1);
  EXPECT_NEAR(tally.moved_mean(), t.light.moved, 1e-6);
}

// The calibration's joint solve can be replaced too (the Vulkan solver's SolveFrames in `track`):
// the replacement is called once per calibration with the calibration layout, its result is the
// identity, a failure (throw) leaves the tracker uncalibrated with a message, and an empty
// function restores the CPU's.
TEST(FaceTracker, UsesAReplacementCalibrationSolver) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  FaceTracker tracker(*model, fast_options(2));
  const CpuSolver& cpu = tracker.cpu_solver();
  int calls = 0;
  tracker.SetCalibrationSolver([&](const std::vector<InputFrame>& frames, const ParameterLayout& layout,
                                   const SolverOptions& options, std::vector<gpu::FaceParameters>* params) {
    ++calls;
    EXPECT_EQ(frames.size(), 2u);
    EXPECT_GT(layout.num_identity, 0);
    return cpu.SolveFrames(frames, layout, options, params);
  });
  tracker.Track(render_frame(cpu, sequence_parameters(*model, 0)));
  TrackedFrame t = tracker.Track(render_frame(cpu, sequence_parameters(*model, 1)));
  EXPECT_EQ(t.status, TrackingStatus::kCalibrated) << t.message;
  EXPECT_EQ(calls, 1);
  EXPECT_GT(tracker.neutral().alpha.norm(), 0.f);

  FaceTracker failing(*model, fast_options(2));
  failing.SetCalibrationSolver([](const std::vector<InputFrame>&, const ParameterLayout&, const SolverOptions&,
                                  std::vector<gpu::FaceParameters>*) -> SolverSummary { throw Error("device lost"); });
  failing.Track(render_frame(cpu, sequence_parameters(*model, 0)));
  t = failing.Track(render_frame(cpu, sequence_parameters(*model, 1)));
  EXPECT_FALSE(failing.calibrated());
  EXPECT_NE(t.message.find("device lost"), std::string::npos) << t.message;
  failing.SetCalibrationSolver({});
  for (int f = 2; f < 4 && !failing.calibrated(); ++f) failing.Track(render_frame(cpu, sequence_parameters(*model, f)));
  EXPECT_TRUE(failing.calibrated());
}

// A live session shutting down requests its stop while a Track() call is under way (here: from
// inside the per-frame solve, just before the calibration solve of the same call): the
// calibration ends before its first iteration and is not applied, and the frames stay collected.
TEST(FaceTracker, AStopDuringTrackEndsTheCalibrationWithoutApplyingIt) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  std::stop_source stop;
  TrackerOptions o = fast_options(2);
  o.stop = stop.get_token();
  FaceTracker tracker(*model, o);
  const CpuSolver& cpu = tracker.cpu_solver();
  int solves = 0;
  tracker.SetTrackingSolver([&](const InputFrame& frame, const ParameterLayout& layout, const SolverOptions& options,
                                gpu::FaceParameters* params) {
    EXPECT_TRUE(options.stop.stop_possible());  // the tracker's stop reaches every solve
    SolverSummary s = cpu.Solve(frame, layout, options, params);
    if (++solves == 2) stop.request_stop();
    return s;
  });
  TrackedFrame t = tracker.Track(render_frame(cpu, sequence_parameters(*model, 0)));
  ASSERT_EQ(t.status, TrackingStatus::kCalibrating) << t.message;
  t = tracker.Track(render_frame(cpu, sequence_parameters(*model, 1)));
  EXPECT_EQ(t.status, TrackingStatus::kCalibrating) << t.message;
  EXPECT_NE(t.message.find("stopped before it finished"), std::string::npos) << t.message;
  EXPECT_FALSE(tracker.calibrated());
  EXPECT_EQ(tracker.neutral().alpha.norm(), 0.f);  // still the mean face
  EXPECT_EQ(tracker.calibration_summary().termination, Termination::kStopped);
  EXPECT_TRUE(tracker.calibration_summary().iterations.empty());
  EXPECT_EQ(tracker.calibration_frames_collected(), 2);
  // Later calls (a front-end's last frames) keep the set at its size and stay uncalibrated.
  t = tracker.Track(render_frame(cpu, sequence_parameters(*model, 2)));
  EXPECT_EQ(tracker.calibration_frames_collected(), 2);
  EXPECT_FALSE(tracker.calibrated());
  EXPECT_NE(t.message.find("stopped"), std::string::npos) << t.message;
}

// The live front-ends calibrate in the background (TrackerOptions::background_calibration): the
// frame that completes the set starts the joint solve on a thread of its own and returns at once,
// the frames meanwhile are held (kCalibrating, the last fit, no solve), and the first frame after
// the solve has finished applies it. Here the joint solve is held back by the test until released,
// so the frames "meanwhile" are certain; the identity and neutral must be exactly the ones the same
// frames give in the foreground.
TEST(FaceTracker, ABackgroundCalibrationLetsFramesPassAndGivesTheForegroundIdentity) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  TrackerOptions o = fast_options(2);
  FaceTracker foreground(*model, o);
  o.background_calibration = true;
  FaceTracker background(*model, o);
  const CpuSolver& cpu = background.cpu_solver();
  std::atomic<bool> release{false};
  std::atomic<int> joint_solves{0};
  // Waits for the test's release (or the tracker's stop), then solves as the CPU would.
  auto held_solver = [&](const std::vector<InputFrame>& frames, const ParameterLayout& layout, const SolverOptions& options,
                         std::vector<gpu::FaceParameters>* params) {
    ++joint_solves;
    while (!release.load() && !options.stop.stop_requested()) std::this_thread::sleep_for(std::chrono::milliseconds(2));
    return cpu.SolveFrames(frames, layout, options, params);
  };
  background.SetCalibrationSolver(held_solver);

  for (int k = 0; k < 2; ++k) {
    const InputFrame frame = render_frame(cpu, sequence_parameters(*model, k));
    const TrackedFrame f = foreground.Track(frame);
    const TrackedFrame b = background.Track(frame);
    ASSERT_EQ(f.status, k == 0 ? TrackingStatus::kCalibrating : TrackingStatus::kCalibrated) << f.message;
    ASSERT_EQ(b.status, TrackingStatus::kCalibrating) << b.message;
    EXPECT_EQ(b.times.calibration_ms, 0.0);  // the solve is not in this call
    if (k == 1) EXPECT_NE(b.message.find("fitting the identity over 2 frames"), std::string::npos) << b.message;
  }
  // While the solve is held: frames return without a solve, holding the last fit.
  for (int k = 2; k < 5; ++k) {
    const TrackedFrame b = background.Track(render_frame(cpu, sequence_parameters(*model, k)));
    EXPECT_EQ(b.status, TrackingStatus::kCalibrating) << b.message;
    EXPECT_NE(b.message.find("hold still"), std::string::npos) << b.message;
    EXPECT_TRUE(b.has_parameters);
    EXPECT_EQ(b.times.synthesis_ms + b.times.analysis_ms, 0.0);
    const FaceTracker::CalibrationProgress p = background.calibration_progress();
    EXPECT_TRUE(p.solving);
    EXPECT_EQ(p.Brief().rfind("fitting the identity over 2 frames, ", 0), 0u) << p.Brief();
    EXPECT_FALSE(background.calibrated());
  }
  EXPECT_EQ(joint_solves.load(), 1);
  release.store(true);
  // The first frame after the solve has finished applies it and is tracked with the new identity.
  const InputFrame next = render_frame(cpu, sequence_parameters(*model, 5));
  TrackedFrame applied;
  for (int tries = 0; tries < 3000; ++tries) {
    applied = background.Track(next);
    if (applied.status != TrackingStatus::kCalibrating) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  ASSERT_EQ(applied.status, TrackingStatus::kCalibrated) << applied.message;
  EXPECT_NE(applied.message.find("calibrated over 2 frames"), std::string::npos) << applied.message;
  EXPECT_LT(applied.landmark_error_px, 3.0) << applied.message;
  ASSERT_TRUE(background.calibrated());
  EXPECT_FALSE(background.calibration_progress().solving);
  EXPECT_EQ(background.neutral().alpha, foreground.neutral().alpha);
  EXPECT_EQ(background.neutral().beta, foreground.neutral().beta);
  EXPECT_EQ(background.neutral().delta, foreground.neutral().delta);
  EXPECT_EQ(background.calibration_warning(), foreground.calibration_warning());
  EXPECT_EQ(background.Track(render_frame(cpu, sequence_parameters(*model, 6))).status, TrackingStatus::kTracking);
}

// In the background too, a calibration not at rest is followed by one on the most relaxed frames
// after it: the actor smiles for the two calibration frames, then rests. The frames of the second
// solve are held like the first's, and the identity it gives is kept (the smile leaves the neutral).
TEST(FaceTracker, ABackgroundCalibrationNotAtRestRunsAgainOnRelaxedFrames) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  TrackerOptions o = fast_options(2);
  o.background_calibration = true;
  o.relaxed_recalibration_frames = 4;
  FaceTracker tracker(*model, o);
  const CpuSolver& cpu = tracker.cpu_solver();
  auto frame = [&](int k) {
    gpu::FaceParameters p = testing::true_parameters(*model, 0.5f, 11);
    p.delta.setZero();
    if (k < 2) {
      for (const char* name : {"mouthSmileLeft", "mouthSmileRight"}) p.delta[arkit_blendshape_index(name)] = 1.f;
    }
    p.euler.y() += 0.05f * std::sin(0.4f * static_cast<float>(k));
    return render_frame(cpu, p);
  };
  // Tracks frames from *k on until one comes back with another status than kCalibrating.
  auto until_not_calibrating = [&](int* k) {
    TrackedFrame t;
    for (int tries = 0; tries < 3000; ++tries) {
      t = tracker.Track(frame(*k));
      ++*k;
      if (t.status != TrackingStatus::kCalibrating) break;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return t;
  };
  int k = 0;
  TrackedFrame t = until_not_calibrating(&k);
  ASSERT_EQ(t.status, TrackingStatus::kCalibrated) << t.message;
  ASSERT_FALSE(tracker.calibration_warning().empty()) << "the smile should be in the first neutral";
  EXPECT_NE(t.message.find("watching the next 4 frames"), std::string::npos) << t.message;
  ASSERT_TRUE(tracker.relaxed_recalibration().searched);
  // The watch: four tracked frames, the last of which starts the solve on the relaxed ones.
  for (int w = 0; w < 4; ++w) {
    t = tracker.Track(frame(k++));
    ASSERT_EQ(t.status, TrackingStatus::kTracking) << t.message;
  }
  EXPECT_NE(t.message.find("calibrating again on the 2 most relaxed of the 4 frames"), std::string::npos) << t.message;
  EXPECT_TRUE(tracker.calibration_progress().solving);
  t = until_not_calibrating(&k);
  ASSERT_EQ(t.status, TrackingStatus::kCalibrated) << t.message;
  EXPECT_NE(t.message.find("calibrated again on the 2 most relaxed frames"), std::string::npos) << t.message;
  const FaceTracker::RelaxedRecalibration& rr = tracker.relaxed_recalibration();
  EXPECT_TRUE(rr.recalibrated);
  EXPECT_LT(rr.relaxed_weight, rr.first_weight - 0.2f) << rr.message;
  EXPECT_TRUE(tracker.calibration_warning().empty()) << tracker.calibration_warning();
  for (int64_t f : rr.frame_indices) EXPECT_GE(f, 2);
  EXPECT_LT(t.landmark_error_px, 3.0) << t.message;
  // Once: the frames after it are tracked, with no further watch.
  for (int w = 0; w < 6; ++w) EXPECT_EQ(tracker.Track(frame(k++)).status, TrackingStatus::kTracking);
  EXPECT_FALSE(tracker.watching_for_relaxed_face());
}

// A watch for relaxed frames under way ends with a requested calibration (the Calibrate button): the
// new one starts from its own frames, and the report of the old watch is gone.
TEST(FaceTracker, ARequestedCalibrationEndsTheWatchForRelaxedFrames) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  TrackerOptions o = fast_options(2);
  o.relaxed_recalibration_frames = 50;
  FaceTracker tracker(*model, o);
  const CpuSolver& cpu = tracker.cpu_solver();
  auto frame = [&](int k, float smile) {
    gpu::FaceParameters p = testing::true_parameters(*model, 0.5f, 11);
    p.delta.setZero();
    for (const char* name : {"mouthSmileLeft", "mouthSmileRight"}) p.delta[arkit_blendshape_index(name)] = smile;
    p.euler.y() += 0.05f * std::sin(0.4f * static_cast<float>(k));
    return render_frame(cpu, p);
  };
  tracker.Track(frame(0, 1.f));
  ASSERT_EQ(tracker.Track(frame(1, 1.f)).status, TrackingStatus::kCalibrated);
  ASSERT_TRUE(tracker.watching_for_relaxed_face());
  EXPECT_EQ(tracker.Track(frame(2, 0.f)).status, TrackingStatus::kTracking);
  tracker.RequestCalibration();
  EXPECT_EQ(tracker.Track(frame(3, 0.f)).status, TrackingStatus::kCalibrating);
  EXPECT_FALSE(tracker.watching_for_relaxed_face());
  EXPECT_FALSE(tracker.relaxed_recalibration().searched);
  // Calibrated at rest this time: no watch, no warning.
  EXPECT_EQ(tracker.Track(frame(4, 0.f)).status, TrackingStatus::kCalibrated);
  EXPECT_FALSE(tracker.watching_for_relaxed_face());
  EXPECT_TRUE(tracker.calibration_warning().empty()) << tracker.calibration_warning();
}

// A background calibration under way ends without being applied when a new one is requested (a
// new person sat down), on Reset, or when the tracker goes away; none of them waits for the solve.
TEST(FaceTracker, ABackgroundCalibrationEndsOnRequestResetAndDestruction) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  TrackerOptions o = fast_options(2);
  o.background_calibration = true;
  const auto start_held = [&](FaceTracker* tracker, std::atomic<int>* stopped) {
    const CpuSolver* cpu = &tracker->cpu_solver();
    tracker->SetCalibrationSolver([stopped, cpu](const std::vector<InputFrame>& frames, const ParameterLayout& layout,
                                                 const SolverOptions& options, std::vector<gpu::FaceParameters>* params) {
      while (!options.stop.stop_requested()) std::this_thread::sleep_for(std::chrono::milliseconds(2));  // never released
      ++*stopped;
      return cpu->SolveFrames(frames, layout, options, params);
    });
    for (int k = 0; k < 2; ++k) tracker->Track(render_frame(*cpu, sequence_parameters(*model, k)));
    ASSERT_TRUE(tracker->calibration_progress().solving);
  };
  std::atomic<int> stopped{0};
  {
    FaceTracker tracker(*model, o);
    start_held(&tracker, &stopped);
    tracker.RequestCalibration();
    const TrackedFrame t = tracker.Track(render_frame(tracker.cpu_solver(), sequence_parameters(*model, 2)));
    EXPECT_EQ(stopped.load(), 1);
    EXPECT_EQ(t.status, TrackingStatus::kCalibrating) << t.message;
    EXPECT_NE(t.message.find("1 of 2 frames"), std::string::npos) << t.message;  // a fresh collection
    EXPECT_FALSE(tracker.calibrated());
    EXPECT_FALSE(tracker.calibration_progress().solving);

    start_held(&tracker, &stopped);
    tracker.Reset();
    EXPECT_EQ(stopped.load(), 2);
    EXPECT_FALSE(tracker.calibration_progress().solving);
    EXPECT_EQ(tracker.Track(render_frame(tracker.cpu_solver(), sequence_parameters(*model, 3))).frame_index, 0);

    FaceTracker leaving(*model, o);
    start_held(&leaving, &stopped);
  }  // `leaving` goes with its solve under way
  EXPECT_EQ(stopped.load(), 3);
}

// The yardstick of fit_agreement.h on noise-free renders: the true parameters agree with the
// frame's landmarks; a head turned 30 degrees, a face shifted off its landmarks and a turn of 20
// degrees in 33 ms each disagree, and the reason names which.
TEST(FitAgreement, MeasuresPoseLandmarksAndSpeedAgainstTheFramesLandmarks) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const CpuSolver solver(*model);
  const gpu::FaceParameters truth = sequence_parameters(*model, 0);
  const InputFrame frame = render_frame(solver, truth);
  const FitAgreementOptions o;
  const FitAgreement good = MeasureFitAgreement(*model, frame, truth, o);
  EXPECT_TRUE(good.agrees()) << good.failure;
  EXPECT_LT(good.pose_disagreement_deg, 2.0);
  EXPECT_LT(good.landmark_nme, 0.01);
  EXPECT_GE(good.landmarks_used, 40);
  EXPECT_TRUE(std::isnan(good.rotation_speed_deg_s));  // no previous fit given

  gpu::FaceParameters turned = truth;
  turned.euler.y() += static_cast<float>(30.0 / kDeg);
  const FitAgreement t = MeasureFitAgreement(*model, frame, turned, o);
  EXPECT_NEAR(t.pose_disagreement_deg, 30.0, 3.0);
  EXPECT_NE(t.failure.find("head pose"), std::string::npos) << t.failure;

  gpu::FaceParameters shifted = truth;
  shifted.translation.x() += 0.01f;  // 1 cm: about a sixth of the eye distance
  const FitAgreement sh = MeasureFitAgreement(*model, frame, shifted, o);
  EXPECT_LT(sh.pose_disagreement_deg, 3.0);
  EXPECT_GT(sh.landmark_nme, 0.05);
  EXPECT_TRUE(sh.agrees()) << sh.failure;  // the pose is right: a warning, not a failure
  EXPECT_NE(sh.landmark_warning.find("inner landmarks"), std::string::npos) << sh.landmark_warning;

  gpu::FaceParameters before = truth;
  before.euler.y() -= static_cast<float>(20.0 / kDeg);
  const FitAgreement fast = MeasureFitAgreement(*model, frame, truth, o, &before, 0.033);
  EXPECT_NEAR(fast.rotation_change_deg, 20.0, 0.1);
  EXPECT_NE(fast.failure.find("head turned"), std::string::npos) << fast.failure;
  EXPECT_TRUE(MeasureFitAgreement(*model, frame, truth, o, &before, 0.2).agrees());  // 100 degrees/s

  FitAgreementOptions off;
  off.max_pose_disagreement_deg = 0;
  off.max_landmark_nme = 0;
  off.max_rotation_speed_deg_s = 0;
  const FitAgreement unchecked = MeasureFitAgreement(*model, frame, turned, off);
  EXPECT_TRUE(unchecked.agrees());
  EXPECT_TRUE(unchecked.landmark_warning.empty());
  EXPECT_NEAR(unchecked.pose_disagreement_deg, 30.0, 3.0);  // still measured
  // No landmarks: nothing to measure, nothing to refuse.
  InputFrame bare = frame;
  bare.landmarks.clear();
  const FitAgreement none = MeasureFitAgreement(*model, bare, turned, o);
  EXPECT_TRUE(none.agrees());
  EXPECT_TRUE(std::isnan(none.pose_disagreement_deg));
  EXPECT_TRUE(std::isnan(none.landmark_nme));
  FitAgreementOptions bad;
  bad.max_landmark_nme = -1;
  std::string why;
  EXPECT_FALSE(bad.IsValid(&why));
  TrackerOptions tracker_options;
  tracker_options.loss.agreement.max_pose_disagreement_deg = std::nan("");
  EXPECT_FALSE(tracker_options.IsValid(&why));
  EXPECT_NE(why.find("max_pose_disagreement_deg"), std::string::npos) << why;
}

TEST(FitAgreement, TallySummarisesAndListsTheFramesBeyondTheLimits) {
  const Distribution d = Summarize({4, std::nan(""), 1, 3, 2, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20});
  EXPECT_EQ(d.count, 20);
  EXPECT_DOUBLE_EQ(d.mean, 10.5);
  EXPECT_DOUBLE_EQ(d.median, 10);  // nearest rank
  EXPECT_DOUBLE_EQ(d.p95, 19);
  EXPECT_DOUBLE_EQ(d.max, 20);
  EXPECT_EQ(Summarize({}).count, 0);
  EXPECT_TRUE(std::isnan(Summarize({std::nan("")}).median));

  FitAgreementTally tally;
  FitAgreement ok;
  ok.pose_disagreement_deg = 3;
  ok.landmark_nme = 0.02;
  FitAgreement off_pose = ok;
  off_pose.pose_disagreement_deg = 40;
  FitAgreement off_points = ok;
  off_points.landmark_nme = 0.08;
  tally.Add(0, true, false, ok, "tracking");
  tally.Add(1, true, false, off_pose, "calibrated");
  tally.Add(2, true, false, off_points, "tracking");
  tally.Add(3, false, true, off_pose, "lost: head pose 40.0 degrees from the landmarks' (limit 15)");
  const FitAgreementTally::Summary s = tally.summary();
  EXPECT_EQ(s.fit_frames, 3);
  EXPECT_EQ(s.pose_disagreement_deg.count, 3);
  EXPECT_DOUBLE_EQ(s.pose_disagreement_deg.max, 40);
  EXPECT_EQ(s.beyond_pose, 1);
  EXPECT_EQ(s.beyond_landmarks, 1);
  EXPECT_EQ(s.refused_frames, 1);
  ASSERT_EQ(s.beyond.size(), 2u);
  EXPECT_EQ(s.beyond[0].frame, 1);
  EXPECT_EQ(s.beyond[0].what, "pose");
  EXPECT_EQ(s.beyond[0].message, "calibrated");
  EXPECT_EQ(s.beyond[1].what, "landmarks");
}

// A solve that lands with the head turned away from the face (as on real video, 50-70 degrees
// while the person faced the camera) must not be reported as tracking. Here every solve of one
// frame is turned by 40 degrees after it ran, and the landmark-distance check is set out of reach,
// so only the agreement check can catch it: the frame is lost with the reason, the next one
// recovers from the landmarks. With the check off the same frame passes as "tracking".
TEST(FaceTracker, AFitTurnedAwayFromTheLandmarksIsNeverReportedTracking) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  for (const bool check : {true, false}) {
    TrackerOptions o = fast_options(2);
    o.loss.lost_landmark_error_px = 1e6;
    o.loss.reinit_landmark_error_px = 1e6;
    if (!check) {
      o.loss.agreement.max_pose_disagreement_deg = 0;
      o.loss.agreement.max_landmark_nme = 0;
      o.loss.agreement.max_rotation_speed_deg_s = 0;
    }
    FaceTracker tracker(*model, o);
    const CpuSolver& cpu = tracker.cpu_solver();
    int frame = 0;
    tracker.SetTrackingSolver([&](const InputFrame& input, const ParameterLayout& layout, const SolverOptions& options,
                                  gpu::FaceParameters* params) {
      SolverSummary s = cpu.Solve(input, layout, options, params);
      if (frame == 4) params->euler.y() += static_cast<float>(40.0 / kDeg);
      return s;
    });
    for (frame = 0; frame < 6; ++frame) {
      const TrackedFrame t = tracker.Track(render_frame(cpu, sequence_parameters(*model, frame)));
      SCOPED_TRACE("frame " + std::to_string(frame) + (check ? " (check on)" : " (check off)") + ": " + t.message);
      if (frame < 4) {
        EXPECT_TRUE(t.disagreement.empty());
        EXPECT_LT(t.agreement.pose_disagreement_deg, 3.0);
        continue;
      }
      if (frame == 4 && check) {
        EXPECT_EQ(t.status, TrackingStatus::kLost);
        EXPECT_NE(t.message.find("head pose"), std::string::npos);
        EXPECT_NE(t.disagreement.find("head pose"), std::string::npos);
        EXPECT_GT(t.agreement.pose_disagreement_deg, 30.0);
      } else if (frame == 4) {
        EXPECT_EQ(t.status, TrackingStatus::kTracking);  // what the check is there for
        EXPECT_GT(t.agreement.pose_disagreement_deg, 30.0);
      } else if (check) {
        EXPECT_EQ(t.status, TrackingStatus::kRecovered);
        EXPECT_LT(t.agreement.pose_disagreement_deg, 3.0);
      }
    }
  }
}

}  // namespace
}  // namespace face_reenact::tracker
