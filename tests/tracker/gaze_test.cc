// Gaze reading (gaze.h): conjugate gaze recovered from renders of the real model at known
// eyeLook weights, the lids from renders at known eyeBlink weights, closed eyes and models
// without eyes give no gaze, bad options are refused, and the tracker writes both readings into
// its fits (and leaves them to the solve when switched off).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include "face_reenact/common/error.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/tracker/face_tracker.h"
#include "face_reenact/tracker/gaze.h"
#include "face_reenact/tracker/solver.h"
#include "tracker_test_support.h"

namespace face_reenact::tracker {
namespace {

const char* kLook[8] = {"eyeLookOutLeft", "eyeLookInLeft", "eyeLookUpLeft", "eyeLookDownLeft",
                        "eyeLookOutRight", "eyeLookInRight", "eyeLookUpRight", "eyeLookDownRight"};

// The fitted face of the tests: the ground truth of tracker_test_support with no expression but
// the gaze, `distance` m away.
gpu::FaceParameters face_looking(const TrackerModel& m, const GazeEstimator& gaze, float horizontal, float vertical,
                                 float distance = 0.6f, uint32_t seed = 11) {
  gpu::FaceParameters p = testing::true_parameters(m, distance, seed);
  p.delta.setZero();
  for (const auto& w : gaze.WeightsFor(horizontal, vertical)) p.delta[w.index] = w.value;
  return p;
}

float weight(const gpu::FaceParameters& p, const char* name) { return p.delta[arkit_blendshape_index(name)]; }

TEST(GazeOptions, DefaultsValidAndBadValuesRejected) {
  GazeOptions o;
  std::string why;
  EXPECT_TRUE(o.IsValid(&why)) << why;
  auto expect_invalid = [](GazeOptions bad, const std::string& needle) {
    std::string w;
    EXPECT_FALSE(bad.IsValid(&w)) << needle;
    EXPECT_NE(w.find(needle), std::string::npos) << w;
    TrackerOptions t;
    t.gaze = bad;
    EXPECT_FALSE(t.IsValid(&w));
    EXPECT_THROW(FaceTracker(testing::sphere_model(), t), Error) << needle;
  };
  GazeOptions bad = o;
  bad.min_eye_pixels = 0;
  expect_invalid(bad, "min_eye_pixels");
  bad = o;
  bad.grid_steps = 2;
  expect_invalid(bad, "grid_steps");
  bad = o;
  bad.refine_steps = 0;
  expect_invalid(bad, "refine_steps");
  bad = o;
  bad.prior = std::numeric_limits<double>::quiet_NaN();
  expect_invalid(bad, "prior");
  bad = o;
  bad.min_improvement = -0.1;
  expect_invalid(bad, "min_improvement");
  bad = o;
  bad.min_open_fraction = 1.5;
  expect_invalid(bad, "min_open_fraction");
  bad = o;
  bad.min_vertical_rows = 0;
  expect_invalid(bad, "min_vertical_rows");
  bad = o;
  bad.lids_below_open_fraction = -0.1;
  expect_invalid(bad, "lids_below_open_fraction");
  bad = o;
  bad.lids_from_weight = std::numeric_limits<double>::quiet_NaN();
  expect_invalid(bad, "lids_from_weight");
  bad = o;
  bad.lid_steps = 1;
  expect_invalid(bad, "lid_steps");
  bad = o;
  bad.min_vergence = 0;
  expect_invalid(bad, "min_vergence");
  bad = o;
  bad.vergence_improvement = 1;
  expect_invalid(bad, "vergence_improvement");
  bad = o;
  bad.max_blink_for_vergence = std::numeric_limits<double>::quiet_NaN();
  expect_invalid(bad, "max_blink_for_vergence");
  bad = o;
  bad.real_iris_check_above = 1.5;
  expect_invalid(bad, "real_iris_check_above");
  bad = o;
  bad.real_iris_disagreement = std::numeric_limits<double>::quiet_NaN();
  expect_invalid(bad, "real_iris_disagreement");
  bad = o;
  bad.real_iris_crossed_min_turn = -0.1;
  expect_invalid(bad, "real_iris_crossed_min_turn");
  bad = o;
  bad.threads = -1;
  expect_invalid(bad, "threads");
}

TEST(Gaze, WeightsForAConjugateGaze) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const GazeEstimator gaze(*model);
  ASSERT_TRUE(gaze.available());
  gpu::FaceParameters p = face_looking(*model, gaze, 0.4f, -0.25f);
  // To the person's left: the left eye out, the right eye in; down on both.
  EXPECT_FLOAT_EQ(weight(p, "eyeLookOutLeft"), 0.4f);
  EXPECT_FLOAT_EQ(weight(p, "eyeLookInRight"), 0.4f);
  EXPECT_FLOAT_EQ(weight(p, "eyeLookInLeft"), 0.f);
  EXPECT_FLOAT_EQ(weight(p, "eyeLookOutRight"), 0.f);
  EXPECT_FLOAT_EQ(weight(p, "eyeLookDownLeft"), 0.25f);
  EXPECT_FLOAT_EQ(weight(p, "eyeLookDownRight"), 0.25f);
  EXPECT_FLOAT_EQ(weight(p, "eyeLookUpLeft"), 0.f);
  p = face_looking(*model, gaze, -0.3f, 0.5f);
  EXPECT_FLOAT_EQ(weight(p, "eyeLookInLeft"), 0.3f);
  EXPECT_FLOAT_EQ(weight(p, "eyeLookOutRight"), 0.3f);
  EXPECT_FLOAT_EQ(weight(p, "eyeLookUpRight"), 0.5f);
}

// The fit holds the eyes straight (what the solve reads); the render of the true face looks
// aside and up or down. The reading finds the true weights.
TEST(Gaze, ReadsTheGazeOfARenderedFace) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const CpuSolver solver(*model);
  const GazeEstimator gaze(*model);
  GazeOptions options;
  options.read_vertical = true;
  // Up is read short: the upper lid covers the top of the iris, and an iris turned up goes under
  // it (eyeLookUp moves the eyeball's front half as far as eyeLookOut). At 1 m the opening is too
  // short for a vertical reading at all (GazeOptions::min_vertical_rows).
  struct Case {
    float h, v, distance, v_tolerance;
  };
  for (const Case c : {Case{0.4f, 0.f, 0.6f, 0.1f}, Case{-0.3f, 0.5f, 0.6f, 0.25f}, Case{0.f, -0.3f, 0.6f, 0.1f},
                       Case{0.f, 0.f, 0.6f, 0.1f}, Case{0.45f, 0.f, 1.0f, 0.f}}) {
    SCOPED_TRACE(::testing::Message() << "h " << c.h << " v " << c.v << " at " << c.distance << " m");
    const gpu::FaceParameters truth = face_looking(*model, gaze, c.h, c.v, c.distance);
    const InputFrame frame = RenderSyntheticFrame(solver.renderer(), *model, truth, testing::test_camera());
    gpu::FaceParameters fit = face_looking(*model, gaze, 0.f, 0.f, c.distance);
    const GazeReading r = gaze.Read(solver.renderer(), frame, &fit, options);
    if (c.h == 0.f && c.v == 0.f) {
      // Straight ahead: no gaze stands out (GazeOptions::min_improvement), or one near 0.
      if (!r.ok) EXPECT_NE(r.message.find("no clear gaze"), std::string::npos) << r.message;
    } else {
      ASSERT_TRUE(r.ok) << r.message;
    }
    std::printf("h %.2f v %.2f at %.1f m: read %.3f %.3f over %d px, %.2f ms\n", c.h, c.v, c.distance, r.horizontal,
                r.vertical, r.pixels, r.ms);
    EXPECT_NEAR(r.horizontal, c.h, 0.06);
    EXPECT_NEAR(r.vertical, c.v, c.v_tolerance);
    if (r.ok) EXPECT_EQ(r.vertical_read, c.distance < 0.8f);
    for (const char* name : kLook) EXPECT_NEAR(weight(fit, name), weight(truth, name), std::max(0.06f, c.v_tolerance)) << name;
    // Nothing but the eyeLook weights changes.
    for (int k = 0; k < model->num_expression(); ++k) {
      bool look = false;
      for (const char* name : kLook) look = look || k == arkit_blendshape_index(name);
      if (!look) EXPECT_EQ(fit.delta[k], truth.delta[k]) << k;
    }
  }
}

// Crossed eyes (each turned towards the nose) and eyes turned apart are read eye by eye and
// written so; a conjugate gaze keeps one reading for both eyes (its eyes' own searches agree).
TEST(Gaze, ReadsEyesTurnedTowardsEachOtherEyeByEye) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const CpuSolver solver(*model);
  const GazeEstimator gaze(*model);
  // Each eye's weights: the left eye in and the right eye in (crossed) is a turn towards the
  // person's right for the left eye (< 0) and towards the left for the right eye (> 0).
  gpu::FaceParameters crossed = face_looking(*model, gaze, 0.f, 0.f);
  for (const auto& w : gaze.WeightsForEyes(-0.5f, 0.7f, 0.f)) crossed.delta[w.index] = w.value;
  EXPECT_FLOAT_EQ(weight(crossed, "eyeLookInLeft"), 0.5f);
  EXPECT_FLOAT_EQ(weight(crossed, "eyeLookInRight"), 0.7f);
  EXPECT_FLOAT_EQ(weight(crossed, "eyeLookOutLeft"), 0.f);
  EXPECT_FLOAT_EQ(weight(crossed, "eyeLookOutRight"), 0.f);
  // Eyes turned out read 0.2-0.25 too far on the eye whose iris goes into its outer corner
  // (measured -0.73 for -0.5; as one reading for both eyes that eye would read +0.47).
  struct Case {
    float left, right;
    bool apart;
    float tolerance;
  };
  for (const Case c : {Case{-0.6f, 0.6f, true, 0.1f}, Case{-0.8f, 0.4f, true, 0.1f}, Case{0.5f, -0.5f, true, 0.25f},
                       Case{0.4f, 0.4f, false, 0.1f}, Case{-0.5f, -0.5f, false, 0.1f}, Case{0.f, 0.9f, true, 0.15f},
                       Case{-0.9f, 0.f, true, 0.15f}}) {
    SCOPED_TRACE(::testing::Message() << "left " << c.left << " right " << c.right);
    gpu::FaceParameters truth = face_looking(*model, gaze, 0.f, 0.f);
    for (const auto& w : gaze.WeightsForEyes(c.left, c.right, 0.f)) truth.delta[w.index] = w.value;
    const InputFrame frame = RenderSyntheticFrame(solver.renderer(), *model, truth, testing::test_camera());
    gpu::FaceParameters fit = face_looking(*model, gaze, 0.f, 0.f);
    const GazeReading r = gaze.Read(solver.renderer(), frame, &fit, GazeOptions{});
    ASSERT_TRUE(r.ok) << r.message;
    std::printf("left %.2f right %.2f: conjugate %.3f, per eye %.3f %.3f (%s)\n", c.left, c.right, r.horizontal, r.per_eye[0],
                r.per_eye[1], r.vergence_read ? "apart" : "together");
    EXPECT_EQ(r.vergence_read, c.apart);
    if (c.apart) {
      EXPECT_NEAR(r.per_eye[0], c.left, c.tolerance);
      EXPECT_NEAR(r.per_eye[1], c.right, c.tolerance);
    } else {
      EXPECT_NEAR(r.horizontal, c.left, 0.06);
    }
    for (const auto& eye : arkit_eye_look_names())
      for (const char* name : eye) EXPECT_NEAR(weight(fit, name), weight(truth, name), c.tolerance) << name;
    // The candidates are costed on the pool's threads: one thread reads the same, to the bit.
    GazeOptions one_thread;
    one_thread.threads = 1;
    gpu::FaceParameters fit1 = face_looking(*model, gaze, 0.f, 0.f);
    const GazeReading r1 = gaze.Read(solver.renderer(), frame, &fit1, one_thread);
    EXPECT_EQ(r1.horizontal, r.horizontal);
    EXPECT_EQ(r1.per_eye, r.per_eye);
    EXPECT_EQ(r1.vergence_read, r.vergence_read);
    EXPECT_TRUE(fit1.delta == fit.delta);
    // Without the per-eye search, one reading for both.
    GazeOptions conjugate_only;
    conjugate_only.read_vergence = false;
    gpu::FaceParameters fit2 = face_looking(*model, gaze, 0.f, 0.f);
    const GazeReading r2 = gaze.Read(solver.renderer(), frame, &fit2, conjugate_only);
    EXPECT_FALSE(r2.vergence_read);
    if (r2.ok) EXPECT_EQ(weight(fit2, "eyeLookOutLeft") > 0.f, weight(fit2, "eyeLookInRight") > 0.f);
  }
}

// The model with an iris of a real size: its eyeballs' vertices beyond 22 degrees of the axis
// take the white's colour (the vertex farthest round from the front).
TrackerModel WithARealSizedIris(const TrackerModel& model) {
  TrackerModel small_iris = model;
  auto& rm = small_iris.render;
  for (const FacePart part : {FacePart::LeftEye, FacePart::RightEye}) {
    std::vector<int> eye;
    for (int v = 0; v < rm.num_vertices(); ++v)
      if (rm.vertex_part[v] == static_cast<int>(part)) eye.push_back(v);
    EXPECT_GT(eye.size(), 20u);
    if (eye.empty()) continue;
    Eigen::Vector3f centre = Eigen::Vector3f::Zero();
    for (int v : eye) centre += rm.mean_shape.segment<3>(3 * v);
    centre /= static_cast<float>(eye.size());
    auto degrees = [&](int v) {
      const Eigen::Vector3f d = (rm.mean_shape.segment<3>(3 * v) - centre).normalized();
      return std::acos(std::clamp(d.z(), -1.f, 1.f)) * 180.f / static_cast<float>(M_PI);
    };
    const int back = *std::max_element(eye.begin(), eye.end(), [&](int a, int b) { return degrees(a) < degrees(b); });
    for (int v : eye) {
      if (degrees(v) <= 22.f) continue;
      rm.mean_albedo.segment<3>(3 * v) = rm.mean_albedo.segment<3>(3 * back);
      rm.albedo_basis.middleRows(3 * v, 3) = rm.albedo_basis.middleRows(3 * back, 3);
    }
  }
  return small_iris;
}

// The renders of WithARealSizedIris and the model as built that reads them.
struct RealSizedIrisScene {
  explicit RealSizedIrisScene(const TrackerModel& model)
      : small_iris(WithARealSizedIris(model)), small_iris_solver(small_iris), solver(model), gaze(model) {}
  InputFrame Render(const gpu::FaceParameters& truth) const {
    return RenderSyntheticFrame(small_iris_solver.renderer(), small_iris, truth, testing::test_camera());
  }
  const TrackerModel small_iris;
  const CpuSolver small_iris_solver;
  const CpuSolver solver;
  const GazeEstimator gaze;
};

// The model's iris reaches about 33 degrees from the eye's axis, half as wide again as a real
// one. An eye showing a real-sized iris (the model with its eyeballs' vertices beyond 22 degrees
// of the axis coloured as their white, rendered, and read with the model as built) looking
// nearly ahead was read as the model's iris turned hard into a corner; the second reading with an
// iris of a real size (GazeOptions::real_iris_check) replaces it.
TEST(Gaze, ReadsARealSizedIrisLookingNearlyAhead) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const RealSizedIrisScene scene(*model);
  const GazeEstimator& gaze = scene.gaze;
  GazeOptions model_iris_only;
  model_iris_only.real_iris_check = false;
  double worst_model_only = 0;
  for (const float h : {0.f, 0.2f, -0.2f, 0.4f, -0.4f}) {
    SCOPED_TRACE(::testing::Message() << "h " << h);
    const gpu::FaceParameters truth = face_looking(*model, gaze, h, 0.f);
    const InputFrame frame = scene.Render(truth);
    gpu::FaceParameters fit = face_looking(*model, gaze, 0.f, 0.f), fit_model_only = fit;
    const GazeReading r = gaze.Read(scene.solver.renderer(), frame, &fit, GazeOptions{});
    const GazeReading m = gaze.Read(scene.solver.renderer(), frame, &fit_model_only, model_iris_only);
    // No reading leaves the eyes straight ahead.
    const double read = r.ok ? r.horizontal : 0.0, read_model_only = m.ok ? m.horizontal : 0.0;
    std::printf("h %.2f: read %.3f (%s), the model's iris alone %.3f (%s)\n", h, read,
                r.ok ? (r.real_iris ? "real iris" : "model's iris") : r.message.c_str(), read_model_only,
                m.ok ? "read" : m.message.c_str());
    // A small turn may not stand out from looking ahead (GazeOptions::min_improvement).
    if (r.ok) {
      EXPECT_NEAR(read, h, 0.1);
      EXPECT_FALSE(r.vergence_read);  // eyes turned together are not read as crossed
    } else {
      EXPECT_LE(std::abs(h), 0.2f) << r.message;
    }
    worst_model_only = std::max(worst_model_only, std::abs(read_model_only - h));
  }
  EXPECT_GT(worst_model_only, 0.5);  // what the second reading is for (0.2 read as 1.0)
}

// Eyes crossed hard (each turned fully in) showing an iris of a real size: the model's iris reads
// no clear gaze, the real iris' conjugate reading one hard glance, and each eye read on its own
// with the real iris finds them crossed (GazeOptions::real_iris_crossed_min_turn). Before, that
// per-eye search only refused the glance and the eyes were left looking ahead. (Milder crossings
// are not clear by the conjugate reading's gate on such renders and are not read.)
TEST(Gaze, ReadsEyesCrossedHardWithARealSizedIris) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const RealSizedIrisScene scene(*model);
  const GazeEstimator& gaze = scene.gaze;
  for (const float distance : {0.45f, 0.6f}) {
    SCOPED_TRACE(::testing::Message() << "at " << distance << " m");
    gpu::FaceParameters truth = face_looking(*model, gaze, 0.f, 0.f, distance);
    for (const auto& w : gaze.WeightsForEyes(-1.f, 1.f, 0.f)) truth.delta[w.index] = w.value;
    const InputFrame frame = scene.Render(truth);
    gpu::FaceParameters fit = face_looking(*model, gaze, 0.f, 0.f, distance);
    const GazeReading r = gaze.Read(scene.solver.renderer(), frame, &fit, GazeOptions{});
    ASSERT_TRUE(r.ok) << r.message;
    EXPECT_TRUE(r.real_iris);
    EXPECT_TRUE(r.vergence_read);
    EXPECT_LE(r.per_eye[0], -0.6f);
    EXPECT_GE(r.per_eye[1], 0.6f);
    EXPECT_GT(weight(fit, "eyeLookInLeft"), 0.6f);
    EXPECT_GT(weight(fit, "eyeLookInRight"), 0.6f);
    EXPECT_EQ(weight(fit, "eyeLookOutLeft"), 0.f);
    EXPECT_EQ(weight(fit, "eyeLookOutRight"), 0.f);
  }
}

TEST(Gaze, ClosedEyesGiveNoReadingAndLeaveTheFit) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const CpuSolver solver(*model);
  const GazeEstimator gaze(*model);
  gpu::FaceParameters truth = face_looking(*model, gaze, 0.f, 0.f);
  truth.delta[arkit_blendshape_index("eyeBlinkLeft")] = 1.f;
  truth.delta[arkit_blendshape_index("eyeBlinkRight")] = 1.f;
  const InputFrame frame = RenderSyntheticFrame(solver.renderer(), *model, truth, testing::test_camera());
  gpu::FaceParameters fit = truth;
  fit.delta[arkit_blendshape_index("eyeLookOutLeft")] = 0.3f;
  const GazeReading r = gaze.Read(solver.renderer(), frame, &fit, GazeOptions());
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.message.find("eyes closed"), std::string::npos) << r.message;
  EXPECT_EQ(weight(fit, "eyeLookOutLeft"), 0.3f);
}

// The fit holds the eyes open (the solve does not see a lid close); the render of the true face
// blinks, half or fully, or winks. The lids are read into the fit's eyeBlink weights, nothing
// else changes but the gaze; with the lids off, or without depth, they stay open.
TEST(Gaze, ReadsTheLidsOfARenderedFace) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const CpuSolver solver(*model);
  const GazeEstimator gaze(*model);
  const int left = arkit_blendshape_index("eyeBlinkLeft"), right = arkit_blendshape_index("eyeBlinkRight");
  struct Case {
    float left, right, distance;
  };
  // From about 0.8 on, the lid covers the whole eyeball at these distances: every weight from
  // there to 1 renders the same closed eye, so a closed eye is read as at least 0.8.
  for (const Case c : {Case{0.3f, 0.3f, 0.6f}, Case{0.5f, 0.5f, 0.6f}, Case{1.f, 1.f, 0.6f}, Case{1.f, 0.f, 0.6f},
                       Case{0.5f, 0.5f, 1.0f}}) {
    SCOPED_TRACE(::testing::Message() << "blink " << c.left << " / " << c.right << " at " << c.distance << " m");
    gpu::FaceParameters truth = face_looking(*model, gaze, 0.f, 0.f, c.distance);
    truth.delta[left] = c.left;
    truth.delta[right] = c.right;
    const InputFrame frame = RenderSyntheticFrame(solver.renderer(), *model, truth, testing::test_camera());
    const gpu::FaceParameters open = face_looking(*model, gaze, 0.f, 0.f, c.distance);
    gpu::FaceParameters fit = open;
    const GazeReading r = gaze.Read(solver.renderer(), frame, &fit, GazeOptions());
    std::printf("blink %.2f / %.2f at %.1f m: read %.3f / %.3f (open fractions %.2f / %.2f), %.2f ms\n", c.left, c.right,
                c.distance, r.blink[0], r.blink[1], r.open_fraction[0], r.open_fraction[1], r.ms);
    ASSERT_TRUE(r.lids_read) << r.lids_message;
    EXPECT_NEAR(fit.delta[left], c.left, c.left == 1.f ? 0.2 : 0.1);
    EXPECT_NEAR(fit.delta[right], c.right, c.right == 1.f ? 0.2 : 0.1);
    EXPECT_EQ(fit.delta[left], r.blink[0]);
    EXPECT_EQ(fit.delta[right], r.blink[1]);
    for (int k = 0; k < model->num_expression(); ++k) {
      bool eye = k == left || k == right;
      for (const char* name : kLook) eye = eye || k == arkit_blendshape_index(name);
      if (!eye) EXPECT_EQ(fit.delta[k], truth.delta[k]) << k;
    }
    GazeOptions off;
    off.read_lids = false;
    gpu::FaceParameters kept = open;
    const GazeReading no = gaze.Read(solver.renderer(), frame, &kept, off);
    EXPECT_FALSE(no.lids_read);
    EXPECT_EQ(kept.delta[left], 0.f);
    EXPECT_EQ(kept.delta[right], 0.f);
    // Without depth in the frame or in the fit (a webcam, a video file), the lids are not read.
    InputFrame colour_only = frame;
    colour_only.depth.clear();
    const GazeReading rgb = gaze.Read(solver.renderer(), colour_only, &kept, GazeOptions());
    EXPECT_FALSE(rgb.lids_read);
    EXPECT_NE(rgb.lids_message.find("no depth"), std::string::npos) << rgb.lids_message;
    EXPECT_FALSE(gaze.Read(solver.renderer(), frame, &kept, GazeOptions(), false).lids_read);
    EXPECT_EQ(kept.delta[left], 0.f);
  }
  // Open eyes: nothing to read (the fit's opening shows eyeball), and a fit with the eyes shut
  // on an open-eyed image has them opened.
  const gpu::FaceParameters truth = face_looking(*model, gaze, 0.f, 0.f);
  const InputFrame frame = RenderSyntheticFrame(solver.renderer(), *model, truth, testing::test_camera());
  gpu::FaceParameters fit = truth;
  const GazeReading r = gaze.Read(solver.renderer(), frame, &fit, GazeOptions());
  EXPECT_FALSE(r.lids_read);
  EXPECT_TRUE(r.lids_message.empty()) << r.lids_message;
  EXPECT_EQ(fit.delta[left], 0.f);
  fit.delta[left] = fit.delta[right] = 0.9f;
  const GazeReading reopened = gaze.Read(solver.renderer(), frame, &fit, GazeOptions());
  ASSERT_TRUE(reopened.lids_read) << reopened.lids_message;
  EXPECT_LT(fit.delta[left], 0.1f);
  EXPECT_LT(fit.delta[right], 0.1f);
}

TEST(Gaze, BadFramesAndModelsWithoutEyesGiveNoReading) {
  const TrackerModel sphere = testing::sphere_model();
  const GazeEstimator none(sphere);
  EXPECT_FALSE(none.available());
  const CpuSolver sphere_solver(sphere);
  gpu::FaceParameters p = gpu::frontal_pose(0.6f);
  const InputFrame frame = RenderSyntheticFrame(sphere_solver.renderer(), sphere, p, testing::test_camera());
  const GazeReading r = none.Read(sphere_solver.renderer(), frame, &p, GazeOptions());
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.message.find("no eyeballs"), std::string::npos) << r.message;

  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const CpuSolver solver(*model);
  const GazeEstimator gaze(*model);
  gpu::FaceParameters fit = face_looking(*model, gaze, 0.f, 0.f);
  InputFrame empty;
  empty.camera = testing::test_camera();
  EXPECT_FALSE(gaze.Read(solver.renderer(), empty, &fit, GazeOptions()).ok);
  // A face whose eyes are out of the image, and one behind the camera.
  InputFrame real = RenderSyntheticFrame(solver.renderer(), *model, fit, testing::test_camera());
  gpu::FaceParameters away = fit;
  away.translation.x() += 2.0f;
  EXPECT_FALSE(gaze.Read(solver.renderer(), real, &away, GazeOptions()).ok);
  gpu::FaceParameters behind = fit;
  behind.translation.z() = -0.6f;
  EXPECT_FALSE(gaze.Read(solver.renderer(), real, &behind, GazeOptions()).ok);
  // NaN colour where the eyes are: those pixels are skipped, no NaN reaches the fit.
  for (float& c : real.color) c = std::numeric_limits<float>::quiet_NaN();
  const GazeReading nan = gaze.Read(solver.renderer(), real, &fit, GazeOptions());
  EXPECT_FALSE(nan.ok);
  EXPECT_TRUE(fit.delta.allFinite());
}

// The tracker reads the gaze of every fitted frame; with the reading off, the solve alone does
// not see it (the eyeLook weights stay near 0).
TEST(Gaze, TheTrackerWritesTheReadingIntoItsFits) {
  const TrackerModel* model = testing::real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  // The last frame blinks: its lids are read too (the solve alone leaves them open).
  TrackedFrame blinking;
  const int left = arkit_blendshape_index("eyeBlinkLeft"), right = arkit_blendshape_index("eyeBlinkRight");
  auto track = [&](bool enabled) {
    TrackerOptions o;
    o.calibration_frames = 1;
    o.calibration_solver.schedule = {{2, 8, 6}, {1, 2, 6}};
    o.gaze.enabled = enabled;
    FaceTracker tracker(*model, o);
    const GazeEstimator gaze(*model);
    TrackedFrame t;
    for (int k = 0; k < 4; ++k) {
      gpu::FaceParameters truth = face_looking(*model, gaze, 0.4f, 0.f, 0.6f, 5);
      truth.euler.y() += 0.02f * k;
      t = tracker.Track(RenderSyntheticFrame(tracker.cpu_solver().renderer(), *model, truth, testing::test_camera()));
      EXPECT_TRUE(tracking_status_has_fit(t.status)) << t.message;
    }
    std::printf("gaze %s: eyeLookOutLeft %.3f, eyeLookInRight %.3f (reading ok %d, %.2f ms)\n", enabled ? "on" : "off",
                weight(t.params, "eyeLookOutLeft"), weight(t.params, "eyeLookInRight"), t.gaze.ok, t.times.gaze_ms);
    gpu::FaceParameters shut = face_looking(*model, gaze, 0.f, 0.f, 0.6f, 5);
    shut.euler.y() += 0.08f;
    shut.delta[left] = shut.delta[right] = 0.8f;
    blinking = tracker.Track(RenderSyntheticFrame(tracker.cpu_solver().renderer(), *model, shut, testing::test_camera()));
    EXPECT_TRUE(tracking_status_has_fit(blinking.status)) << blinking.message;
    std::printf("blink 0.8, gaze %s: eyeBlinkLeft %.3f, eyeBlinkRight %.3f\n", enabled ? "on" : "off",
                blinking.params.delta[left], blinking.params.delta[right]);
    return t;
  };
  const TrackedFrame on = track(true);
  EXPECT_TRUE(blinking.gaze.lids_read) << blinking.gaze.lids_message;
  EXPECT_NEAR(blinking.params.delta[left], 0.8f, 0.2f);
  EXPECT_NEAR(blinking.params.delta[right], 0.8f, 0.2f);
  EXPECT_TRUE(on.gaze.ok) << on.gaze.message;
  EXPECT_NEAR(on.gaze.horizontal, 0.4f, 0.1f);
  EXPECT_NEAR(weight(on.params, "eyeLookOutLeft"), 0.4f, 0.1f);
  EXPECT_NEAR(weight(on.params, "eyeLookInRight"), 0.4f, 0.1f);
  EXPECT_GT(on.times.gaze_ms, 0.0);
  const TrackedFrame off = track(false);
  EXPECT_FALSE(blinking.gaze.lids_read);
  EXPECT_LT(blinking.params.delta[left], 0.3f);
  EXPECT_FALSE(off.gaze.ok);
  EXPECT_LT(weight(off.params, "eyeLookOutLeft"), 0.2f);
}

}  // namespace
}  // namespace face_reenact::tracker
