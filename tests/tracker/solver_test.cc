// The CPU reference solver fits parameters back from synthetic input rendered by the CPU
// renderer at known parameters: per term alone (what each term can determine) and all together,
// tracking and calibration, and fails gracefully on inputs it cannot fit.
#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <random>
#include <stop_token>

#include "face_reenact/common/error.h"
#include "face_reenact/tracker/solver.h"
#include "tracker_test_support.h"

namespace face_reenact::tracker {
namespace {

using testing::real_model;
using testing::rotation_error;
using testing::sphere_model;
using testing::test_camera;
using testing::true_parameters;


// Mean camera-space distance (m) of the skin vertices, and mean absolute vertex colour error.
struct FitError {
  double rotation = 0, translation = 0, geometry = 0, color = 0;
};

// Colour is compared where it is observable: on the pixels both renders cover.
FitError fit_error(const gpu::CpuRenderer& renderer, const gpu::FaceParameters& fit, const gpu::FaceParameters& truth) {
  const gpu::VertexState a = renderer.evaluate(fit), b = renderer.evaluate(truth);
  const auto& parts = renderer.model().vertex_part;
  double geo = 0;
  int count = 0;
  for (int v = 0; v < renderer.model().num_vertices(); ++v) {
    if (parts[v] != 0) continue;  // FacePart::Face
    geo += (a.camera_positions.segment<3>(3 * v) - b.camera_positions.segment<3>(3 * v)).norm();
    ++count;
  }
  const gpu::PinholeCamera cam = test_camera(320, 240);
  const gpu::GBuffer ga = renderer.rasterize(a, cam, {}), gb = renderer.rasterize(b, cam, {});
  double col = 0;
  int pixels = 0;
  for (size_t p = 0; p < ga.triangle.size(); ++p) {
    if (ga.triangle[p] < 0 || gb.triangle[p] < 0) continue;
    for (int k = 0; k < 3; ++k) col += std::abs(ga.color[3 * p + k] - gb.color[3 * p + k]) / 3;
    ++pixels;
  }
  FitError e;
  e.rotation = rotation_error(fit, truth);
  e.translation = (fit.translation - truth.translation).norm();
  e.geometry = geo / count;
  e.color = pixels ? col / pixels : 1.0;
  return e;
}

std::ostream& operator<<(std::ostream& os, const FitError& e) {
  return os << "rotation " << e.rotation << " rad, translation " << e.translation * 1000 << " mm, geometry "
            << e.geometry * 1000 << " mm, colour " << e.color;
}

// scale 1: ~4 degrees about each axis and 1-1.5 cm (a re-initialisation); scale 0.3: about
// the motion between two frames at 30 fps. Expressions start neutral, light white ambient.
gpu::FaceParameters perturbed_start(const gpu::FaceParameters& truth, float scale = 1.0f) {
  gpu::FaceParameters s = truth;
  s.euler += scale * Eigen::Vector3f(0.07f, -0.06f, 0.05f);
  s.translation += scale * Eigen::Vector3f(0.012f, -0.01f, 0.015f);
  s.delta.setZero();
  s.gamma = gpu::ambient_sh(Eigen::Vector3f::Ones());
  return s;
}

EnergyOptions only(Term t) {
  EnergyOptions o;
  o.use_point = t == Term::kPoint;
  o.use_plane = t == Term::kPlane;
  o.use_color = t == Term::kColor;
  o.use_landmarks = t == Term::kLandmark;
  o.use_regularizer = true;
  return o;
}

class TrackerSolverTest : public ::testing::Test {
 protected:
  void SetUp() override {
    model_ = real_model();
    if (!model_) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
    solver_ = std::make_unique<CpuSolver>(*model_);
    camera_ = test_camera(640, 480);
    truth_ = true_parameters(*model_, 0.55f, 99);
    frame_ = RenderSyntheticFrame(solver_->renderer(), *model_, truth_, camera_);
  }
  FitError fit(const SolverOptions& options, const ParameterLayout& layout, gpu::FaceParameters start,
               SolverSummary* summary_out = nullptr, gpu::FaceParameters* fitted = nullptr) {
    const FitError before = fit_error(solver_->renderer(), start, truth_);
    SolverSummary summary = solver_->Solve(frame_, layout, options, &start);
    const FitError after = fit_error(solver_->renderer(), start, truth_);
    std::cout << "start: " << before << "\nfit:   " << after << "\n" << summary.FullReport();
    EXPECT_LT(summary.final_energy.total(), summary.initial_energy.total());
    if (summary_out) *summary_out = summary;
    if (fitted) *fitted = start;
    return after;
  }
  ParameterLayout tracking() const { return ParameterLayout::Tracking(model_->num_expression()); }

  const TrackerModel* model_ = nullptr;
  std::unique_ptr<CpuSolver> solver_;
  gpu::PinholeCamera camera_;
  gpu::FaceParameters truth_;
  InputFrame frame_;
};

// The paper's schedule (7 x 4 on the coarsest level, 1 x 4 on the next) from frame-to-frame
// motion.
TEST_F(TrackerSolverTest, AllTermsRecoverPoseExpressionAndLighting) {
  SolverOptions o;
  SolverSummary summary;
  const FitError e = fit(o, tracking(), perturbed_start(truth_, 0.3f), &summary);
  EXPECT_EQ(summary.termination, Termination::kScheduleDone) << summary.message;
  EXPECT_LT(e.rotation, 0.005);
  EXPECT_LT(e.translation, 0.002);
  EXPECT_LT(e.geometry, 0.0008);
  EXPECT_LT(e.color, 0.01);
  ASSERT_FALSE(summary.iterations.empty());
  EXPECT_EQ(summary.iterations.front().level, 2);
  EXPECT_EQ(summary.iterations.back().level, 1);
  EXPECT_GT(summary.synthesis_ms, 0);
  EXPECT_GT(summary.analysis_ms, 0);
}

// A re-initialisation-sized offset needs more iterations than one frame's budget.
TEST_F(TrackerSolverTest, AllTermsRecoverFromALargeOffset) {
  SolverOptions o;
  o.schedule = {{2, 20, 4}, {1, 3, 4}};
  const FitError e = fit(o, tracking(), perturbed_start(truth_, 1.0f));
  EXPECT_LT(e.rotation, 0.01);
  EXPECT_LT(e.translation, 0.002);
  EXPECT_LT(e.geometry, 0.001);
  EXPECT_LT(e.color, 0.01);
}

TEST_F(TrackerSolverTest, MatrixFreeAndAssembledSolvesAgree) {
  SolverOptions o;
  o.schedule = {{2, 3, 4}};
  gpu::FaceParameters a, b;
  fit(o, tracking(), perturbed_start(truth_, 0.3f), nullptr, &a);
  o.linear_solver = LinearSolverType::kAssembled;
  fit(o, tracking(), perturbed_start(truth_, 0.3f), nullptr, &b);
  EXPECT_LT((a.euler - b.euler).norm(), 1e-4);
  EXPECT_LT((a.translation - b.translation).norm(), 1e-5);
  EXPECT_LT((a.delta - b.delta).cwiseAbs().maxCoeff(), 1e-3);
}

SolverOptions single_term(Term t) {
  SolverOptions o{only(t)};
  o.schedule = {{2, 15, 4}, {1, 2, 4}};
  return o;
}

// Point-to-point with projective association (the same pixel in both images) alone is weak: the
// residual of a pixel lies along its ray, so it pins depth but resists sliding sideways (the
// paper adds the plane term for this reason; docs/tracker.md). It recovers offsets along the
// view direction, which is what this checks.
// Threads change how fast, never what: the same solve with 1 and 3 threads ends bit-identical.
TEST_F(TrackerSolverTest, ThreadCountDoesNotChangeTheResult) {
  gpu::FaceParameters one = perturbed_start(truth_), three = one;
  SolverOptions o;
  o.threads = 1;
  const SolverSummary s1 = solver_->Solve(frame_, tracking(), o, &one);
  o.threads = 3;
  const SolverSummary s3 = solver_->Solve(frame_, tracking(), o, &three);
  EXPECT_EQ(s1.final_energy.total(), s3.final_energy.total());
  EXPECT_EQ(one.euler, three.euler);
  EXPECT_EQ(one.translation, three.translation);
  EXPECT_EQ(one.delta, three.delta);
  EXPECT_EQ(s1.iterations.size(), s3.iterations.size());
}

// The solver keeps the identity shape and albedo a tracking solve holds fixed for the next solve
// (CpuSolver::FixedPartsCache). A solve under another identity must not be served the kept one:
// after solving with the true identity, a solve with a different identity (and albedo) gives
// the bits a fresh solver gives, and so does the true identity again.
TEST_F(TrackerSolverTest, KeptIdentityPartsFollowTheIdentity) {
  ASSERT_GT(model_->num_identity(), 0);
  ASSERT_GT(model_->num_albedo(), 0);
  SolverOptions o;
  gpu::FaceParameters other = perturbed_start(truth_);
  other.alpha[0] += 1.5f;
  other.beta[0] -= 1.0f;
  auto solve = [&](const CpuSolver& solver, gpu::FaceParameters start) {
    solver.Solve(frame_, tracking(), o, &start);
    return start;
  };
  const gpu::FaceParameters true_kept = solve(*solver_, perturbed_start(truth_));
  const gpu::FaceParameters other_kept = solve(*solver_, other);
  const gpu::FaceParameters true_again = solve(*solver_, perturbed_start(truth_));
  const CpuSolver fresh(*model_);
  const gpu::FaceParameters other_fresh = solve(fresh, other);
  EXPECT_EQ(other_kept.euler, other_fresh.euler);
  EXPECT_EQ(other_kept.translation, other_fresh.translation);
  EXPECT_EQ(other_kept.delta, other_fresh.delta);
  EXPECT_NE(other_kept.delta, true_kept.delta);  // the identity changed what the solve found
  EXPECT_EQ(true_again.delta, true_kept.delta);
  EXPECT_EQ(true_again.translation, true_kept.translation);

  // The cache itself: the same identity is the kept parts, another identity new ones.
  CpuSolver::FixedPartsCache cache;
  const auto first = cache.For(*model_, truth_, 2);
  EXPECT_EQ(cache.For(*model_, truth_, 1), first);
  const auto changed = cache.For(*model_, other, 2);
  ASSERT_NE(changed, first);
  EXPECT_NE(changed->shape[0], first->shape[0]);
  EXPECT_NE(changed->albedo[0], first->albedo[0]);
  const FixedModelParts made = ComputeFixedModelParts(*model_, other, 1);
  EXPECT_EQ(changed->shape, made.shape);
  EXPECT_EQ(changed->albedo, made.albedo);
}

// The solver keeps its syntheses' G-buffers from one solve to the next (CpuSolver::SynthesisBuffers),
// one per pyramid level, each clearing only what its last draw covered. After solves of another
// face (nearer, turned and aside, so its draws covered other pixels) and of a smaller image, a
// solve gives the bits a fresh solver gives.
TEST_F(TrackerSolverTest, KeptSynthesisBuffersChangeNoSolve) {
  SolverOptions o;
  auto solve = [&](const CpuSolver& solver, const InputFrame& frame, gpu::FaceParameters start) {
    const SolverSummary s = solver.Solve(frame, tracking(), o, &start);
    return std::pair{start, s.final_energy.total()};
  };
  gpu::FaceParameters near = truth_;
  near.translation += Eigen::Vector3f(0.05f, 0.f, -0.15f);
  near.euler.y() += 0.3f;
  const InputFrame near_frame = RenderSyntheticFrame(solver_->renderer(), *model_, near, camera_);
  const InputFrame small_frame = RenderSyntheticFrame(solver_->renderer(), *model_, truth_, test_camera(320, 240));
  solve(*solver_, near_frame, perturbed_start(near));
  solve(*solver_, small_frame, perturbed_start(truth_));
  solve(*solver_, near_frame, perturbed_start(near));
  const auto [kept, kept_energy] = solve(*solver_, frame_, perturbed_start(truth_));
  const CpuSolver fresh(*model_);
  const auto [made, made_energy] = solve(fresh, frame_, perturbed_start(truth_));
  EXPECT_EQ(kept_energy, made_energy);
  EXPECT_EQ(kept.euler, made.euler);
  EXPECT_EQ(kept.translation, made.translation);
  EXPECT_EQ(kept.delta, made.delta);
  EXPECT_EQ(kept.gamma, made.gamma);

  // The set itself: one is kept, and a solve running beside another (which took it) takes none.
  CpuSolver::SynthesisBuffers buffers;
  EXPECT_TRUE(buffers.Take().empty());
  std::vector<gpu::GBuffer> levels(2);
  levels[1].width = 7;
  buffers.Give(std::move(levels));
  std::vector<gpu::GBuffer> taken = buffers.Take();
  ASSERT_EQ(taken.size(), 2u);
  EXPECT_EQ(taken[1].width, 7);
  EXPECT_TRUE(buffers.Take().empty());
  buffers.Give(std::move(taken));
  buffers.Give(std::vector<gpu::GBuffer>(1));  // the later one is dropped
  EXPECT_EQ(buffers.Take().size(), 2u);
}

// A camera sees the eyeballs (and teeth in an open mouth), so the tracker must draw them: with
// the skin alone, the eye pixels match the eye sockets ~2 cm behind the measured eyes, and the
// truth is no longer the minimum of the geometric terms (a calibration of the demo's target
// started at the truth slid 4 mm nearer).
TEST_F(TrackerSolverTest, TheTruthIsTheGeometricMinimumOfWhatACameraSees) {
  const InputFrame seen = RenderSyntheticFrame(solver_->renderer(), *model_, truth_, camera_, {gpu::kAllParts, true});
  const SolverOptions defaults;
  EXPECT_EQ(defaults.render.parts, gpu::kAllParts);
  const auto geometric = [&](const gpu::RenderOptions& render) {
    const TermEnergies e = solver_->Energy(seen, tracking(), defaults.energy, truth_, render);
    return e[Term::kPoint] + e[Term::kPlane];
  };
  EXPECT_LT(geometric(defaults.render), 1e-6);
  // The check can fail: the skin-only render leaves the eye sockets in the data term.
  EXPECT_GT(geometric({gpu::kSkinParts, true}), 1e-3);
  // And a solve started at the truth stays there.
  gpu::FaceParameters start = truth_;
  SolverSummary summary = solver_->Solve(seen, tracking(), defaults, &start);
  const FitError e = fit_error(solver_->renderer(), start, truth_);
  std::cout << "from the truth: " << e << "\n" << summary.BriefReport() << "\n";
  EXPECT_LT(e.rotation, 0.002);
  EXPECT_LT(e.translation, 0.0005);
}

TEST_F(TrackerSolverTest, PointTermAloneRecoversDepthOffsets) {
  gpu::FaceParameters start = truth_;
  start.translation.z() += 0.015f;
  const FitError e = fit(single_term(Term::kPoint), tracking(), start);
  // The 52 blendshapes absorb part of what remains, hence ~1 mm rather than exact.
  EXPECT_LT(e.rotation, 0.015);
  EXPECT_LT(e.translation, 0.0015);
  EXPECT_LT(e.geometry, 0.0015);
}

TEST_F(TrackerSolverTest, PlaneTermAloneRecoversPoseAndShape) {
  const FitError e = fit(single_term(Term::kPlane), tracking(), perturbed_start(truth_, 0.3f));
  EXPECT_LT(e.rotation, 0.01);
  EXPECT_LT(e.translation, 0.003);
  EXPECT_LT(e.geometry, 0.0012);
}

// 38 inner landmarks cannot pin 52 blendshapes and the pose at once, so this fits the pose with
// the expression known (held at the truth).
TEST_F(TrackerSolverTest, LandmarkTermAloneRecoversPose) {
  gpu::FaceParameters start = perturbed_start(truth_, 1.0f);
  start.delta = truth_.delta;
  const FitError e = fit(single_term(Term::kLandmark), ParameterLayout::Tracking(0), start);
  EXPECT_LT(e.rotation, 0.01);
  EXPECT_LT(e.translation, 0.003);
}

// The sparsity prior (EnergyOptions::w_expression_sparsity) on the case it is for: 38 landmarks
// cannot tell 52 blendshapes apart, and the quadratic prior of Eq. 11 spreads an expression over
// many small weights. Reweighted L1 keeps the blendshapes the truth does not use near zero
// without giving up the ones it uses (some shrinkage of those is the price).
TEST_F(TrackerSolverTest, ExpressionSparsityKeepsUnusedBlendshapesAtZero) {
  struct Result {
    double unused_mass = 0, mean_abs_error = 0;
  };
  auto run = [&](double sparsity) {
    SolverOptions o = single_term(Term::kLandmark);
    o.energy.w_expression_sparsity = sparsity;
    gpu::FaceParameters p = truth_;
    p.delta.setZero();
    SolverSummary summary = solver_->Solve(frame_, tracking(), o, &p);
    EXPECT_EQ(summary.termination, Termination::kScheduleDone) << summary.message;
    Result r;
    for (int k = 0; k < p.delta.size(); ++k) {
      if (truth_.delta[k] == 0.f) r.unused_mass += p.delta[k];
      r.mean_abs_error += std::abs(p.delta[k] - truth_.delta[k]) / p.delta.size();
    }
    std::cout << "sparsity " << sparsity << ": unused blendshapes sum " << r.unused_mass << ", mean abs error "
              << r.mean_abs_error << "\n";
    return r;
  };
  const Result quadratic = run(0.0);
  const Result sparse = run(0.1);
  EXPECT_LT(sparse.unused_mass, 0.5 * quadratic.unused_mass);
  EXPECT_LT(sparse.mean_abs_error, quadratic.mean_abs_error + 0.02);
}

// With the correspondences held in the image as well (EnergyOptions::color_follows_projection
// off), the colour term determines the lighting: its derivative reaches the pose only through the
// shading, nearly degenerate with rotating the light, so it starts from the true shape and is
// judged on appearance.
TEST_F(TrackerSolverTest, ColorTermAloneRecoversLighting) {
  gpu::FaceParameters start = truth_;
  start.gamma = gpu::ambient_sh(Eigen::Vector3f(0.6f, 0.7f, 0.9f));
  const FitError before = fit_error(solver_->renderer(), start, truth_);
  SolverOptions o = single_term(Term::kColor);
  o.energy.color_follows_projection = false;
  o.energy.color_parts = gpu::kAllParts;  // the render's colour is the model's albedo everywhere
  const FitError e = fit(o, tracking(), start);
  // Pose is left free and drifts along the rotation/lighting near-degeneracy; what the colour
  // term determines is the appearance.
  EXPECT_LT(e.color, 0.015);
  EXPECT_LT(e.color, before.color / 5);
  EXPECT_LT(e.translation, 1e-6);  // the colour term has no translation derivative then
}

// Read through the projection (the default), the colour term sees a face that is shifted
// against the image: alone, from a start 5 mm (about 5 pixels) off sideways, it moves the face
// back onto the image (pose and lighting solved, the expression held at the truth as in the
// landmark test). The distance is the one thing colour alone cannot tell (a face slightly nearer
// looks the same, slightly larger), so the sideways offset is what is judged. With the
// correspondences held in the image the colour term cannot move the face at all.
TEST_F(TrackerSolverTest, ColorThroughTheProjectionAlignsAShiftedFace) {
  gpu::FaceParameters start = truth_;
  start.translation += Eigen::Vector3f(0.004f, -0.003f, 0.0f);
  auto sideways = [&](const gpu::FaceParameters& p) { return (p.translation - truth_.translation).head<2>().norm(); };
  SolverOptions o = single_term(Term::kColor);
  o.schedule = {{2, 10, 4}, {1, 5, 4}};
  o.energy.color_parts = gpu::kAllParts;  // the render's colour is the model's albedo everywhere
  gpu::FaceParameters moved;
  const FitError e = fit(o, ParameterLayout::Tracking(0), start, nullptr, &moved);
  std::cout << "sideways offset " << sideways(start) * 1000 << " -> " << sideways(moved) * 1000 << " mm\n";
  EXPECT_LT(sideways(moved), 0.1 * sideways(start));
  EXPECT_LT(e.rotation, 0.01);
  o.energy.color_follows_projection = false;
  gpu::FaceParameters held = start;
  solver_->Solve(frame_, ParameterLayout::Tracking(0), o, &held);
  EXPECT_NEAR((held.translation - truth_.translation).norm(), (start.translation - truth_.translation).norm(), 1e-6);
}

TEST_F(TrackerSolverTest, CalibrationRecoversIdentityAndAlbedo) {
  SolverOptions o;
  o.schedule = {{2, 10, 8}, {1, 4, 8}};
  gpu::FaceParameters start = perturbed_start(truth_);
  start.alpha.setZero();
  start.beta.setZero();
  const FitError before = fit_error(solver_->renderer(), start, truth_);
  const FitError e =
      fit(o, ParameterLayout::Calibration(model_->num_identity(), model_->num_albedo(), model_->num_expression()), start);
  EXPECT_LT(e.geometry, 0.0015);
  EXPECT_LT(e.geometry, before.geometry / 3);
  EXPECT_LT(e.color, 0.015);
  EXPECT_LT(e.color, before.color / 3);
}

TEST_F(TrackerSolverTest, TrackingWarmStartsFromThePreviousFrame) {
  SolverOptions o;
  gpu::FaceParameters current = perturbed_start(truth_);
  gpu::FaceParameters truth = truth_;
  for (int frame = 0; frame < 3; ++frame) {
    truth.euler.y() += 0.03f;
    truth.translation.x() += 0.004f;
    truth.delta[0] = 0.2f + 0.2f * frame;
    const InputFrame input = RenderSyntheticFrame(solver_->renderer(), *model_, truth, camera_);
    const SolverSummary s = solver_->Solve(input, tracking(), o, &current);
    const FitError e = fit_error(solver_->renderer(), current, truth);
    std::cout << "frame " << frame << ": " << e << "\n";
    EXPECT_LT(e.rotation, 0.01);
    EXPECT_LT(e.geometry, 0.001);
    EXPECT_LT(s.final_energy.total(), s.initial_energy.total() + 1e-12);
  }
}

TEST_F(TrackerSolverTest, ColorOnlyFramesStillTrackWithLandmarks) {
  InputFrame colour_only = frame_;
  colour_only.depth.clear();
  gpu::FaceParameters start = perturbed_start(truth_, 0.3f);
  start.delta = truth_.delta;  // without depth, 38 landmarks cannot separate pose from 52 blendshapes
  const SolverSummary s = solver_->Solve(colour_only, ParameterLayout::Tracking(0), SolverOptions{}, &start);
  const FitError e = fit_error(solver_->renderer(), start, truth_);
  std::cout << e << "\n" << s.BriefReport() << "\n";
  EXPECT_LT(e.rotation, 0.02);
  EXPECT_LT(e.translation, 0.003);
  EXPECT_EQ(s.final_energy[Term::kPoint], 0.0);
}

// Sensor-like input: depth noise (1.5 mm), holes (8 % of pixels), colour noise, landmark jitter
// (1 px) and two landmarks with zero confidence and far-off positions.
TEST_F(TrackerSolverTest, NoisyInputWithHolesStillTracks) {
  InputFrame noisy = frame_;
  std::mt19937 rng(5);
  std::normal_distribution<float> g;
  std::uniform_real_distribution<float> u(0.f, 1.f);
  for (size_t p = 0; p < noisy.depth.size(); ++p) {
    if (noisy.depth[p] > 0) noisy.depth[p] += 0.0015f * g(rng);
    if (u(rng) < 0.08f) noisy.depth[p] = u(rng) < 0.5f ? 0.f : std::nanf("");
  }
  for (float& c : noisy.color) c = std::clamp(c + 0.02f * g(rng), 0.f, 1.f);
  for (auto& l : noisy.landmarks) l.position += Eigen::Vector2f(g(rng), g(rng));
  noisy.landmarks[40].confidence = 0.f;
  noisy.landmarks[40].position += Eigen::Vector2f(200.f, 100.f);
  noisy.landmarks[50].confidence = 0.f;
  noisy.landmarks[50].position -= Eigen::Vector2f(150.f, 10.f);
  gpu::FaceParameters start = perturbed_start(truth_, 0.3f);
  const SolverSummary s = solver_->Solve(noisy, tracking(), SolverOptions{}, &start);
  const FitError e = fit_error(solver_->renderer(), start, truth_);
  std::cout << e << "\n" << s.BriefReport() << "\n";
  EXPECT_EQ(s.termination, Termination::kScheduleDone) << s.message;
  EXPECT_LT(e.rotation, 0.01);
  EXPECT_LT(e.translation, 0.002);
  EXPECT_LT(e.geometry, 0.0015);
  EXPECT_LT(e.color, 0.01);
}

TEST_F(TrackerSolverTest, FaceOutOfViewIsReportedNotFitted) {
  InputFrame empty = frame_;
  std::fill(empty.depth.begin(), empty.depth.end(), 0.f);  // nothing measured
  empty.landmarks.clear();
  gpu::FaceParameters start = perturbed_start(truth_);
  const gpu::FaceParameters before = start;
  const SolverSummary s = solver_->Solve(empty, tracking(), SolverOptions{}, &start);
  EXPECT_EQ(s.termination, Termination::kNoValidResiduals) << s.message;
  EXPECT_EQ(start.euler, before.euler);
  EXPECT_EQ(start.translation, before.translation);
  // Face behind the camera: nothing is rendered.
  start.translation.z() = -1.0f;
  const SolverSummary behind = solver_->Solve(frame_, tracking(), SolverOptions{}, &start);
  EXPECT_EQ(behind.termination, Termination::kNoValidResiduals) << behind.message;
}

TEST_F(TrackerSolverTest, InvalidRequestsThrowClearErrors) {
  gpu::FaceParameters start = perturbed_start(truth_);
  start.euler.x() = std::nanf("");
  EXPECT_THROW(solver_->Solve(frame_, tracking(), SolverOptions{}, &start), Error);
  start = perturbed_start(truth_);
  SolverOptions o;
  o.schedule = {{3, 1, 4}};
  try {
    solver_->Solve(frame_, tracking(), o, &start);
    ADD_FAILURE() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("level 3"), std::string::npos) << e.what();
  }
  o = SolverOptions{};
  o.damping = -1;
  EXPECT_THROW(solver_->Solve(frame_, tracking(), o, &start), Error);
  o = SolverOptions{};
  o.threads = -1;
  EXPECT_THROW(solver_->Solve(frame_, tracking(), o, &start), Error);
  EXPECT_THROW(solver_->Solve(frame_, ParameterLayout::Tracking(200), SolverOptions{}, &start), Error);
  InputFrame broken = frame_;
  broken.color.resize(10);
  EXPECT_THROW(solver_->Solve(broken, tracking(), SolverOptions{}, &start), Error);
}

// The same solve on the test sphere, so the solver is exercised even without a face model.
// A stop requested before the solve (or between its iterations) ends it before the next
// Gauss-Newton iteration, leaving the parameters of the last accepted step.
TEST_F(TrackerSolverTest, ARequestedStopEndsTheSolveBeforeItsNextIteration) {
  std::stop_source stop;
  SolverOptions o;
  o.stop = stop.get_token();
  const gpu::FaceParameters start = perturbed_start(truth_, 0.3f);
  gpu::FaceParameters p = start;
  const SolverSummary running = solver_->Solve(frame_, tracking(), o, &p);
  EXPECT_NE(running.termination, Termination::kStopped);  // a stop that can come but did not
  EXPECT_FALSE(running.iterations.empty());
  stop.request_stop();
  p = start;
  const SolverSummary s = solver_->Solve(frame_, tracking(), o, &p);
  EXPECT_EQ(s.termination, Termination::kStopped) << s.FullReport();
  EXPECT_STREQ(termination_name(s.termination), "stopped");
  EXPECT_NE(s.message.find("stop requested"), std::string::npos) << s.message;
  EXPECT_TRUE(s.iterations.empty());
  EXPECT_EQ(p.euler, start.euler);
  EXPECT_EQ(p.translation, start.translation);
  EXPECT_EQ(s.final_energy.total(), s.initial_energy.total());
  // The multi-frame (calibration) solve too.
  std::vector<gpu::FaceParameters> frames_params = {start, start};
  const SolverSummary c = solver_->SolveFrames(
      {frame_, frame_}, ParameterLayout::Calibration(model_->num_identity(), model_->num_albedo(), model_->num_expression()),
      o, &frames_params);
  EXPECT_EQ(c.termination, Termination::kStopped) << c.FullReport();
  EXPECT_EQ(frames_params[1].alpha, start.alpha);
}

TEST(TrackerSolverSphere, RecoversPoseOnTestGeometry) {
  const TrackerModel model = sphere_model();
  const CpuSolver solver(model);
  const gpu::FaceParameters truth = true_parameters(model, 0.5f, 8);
  const InputFrame frame = RenderSyntheticFrame(solver.renderer(), model, truth, test_camera(320, 240));
  gpu::FaceParameters start = truth;
  start.translation += Eigen::Vector3f(0.01f, 0.008f, -0.01f);
  start.gamma = gpu::ambient_sh(Eigen::Vector3f::Ones());
  SolverOptions o;
  o.schedule = {{2, 15, 4}, {1, 3, 4}};
  const SolverSummary s = solver.Solve(frame, ParameterLayout::Tracking(model.num_expression()), o, &start);
  std::cout << s.FullReport();
  EXPECT_LT((start.translation - truth.translation).norm(), 0.002);
  EXPECT_LT(s.final_energy.total(), 0.1 * s.initial_energy.total());
}

}  // namespace
}  // namespace face_reenact::tracker

namespace face_reenact::tracker {
namespace {

// The multi-frame system on the test sphere (fast, and runs without a face model): two views
// share identity/albedo; stacking must keep every frame's own block apart.
TEST(TrackerCalibration, SphereTwoViewsShareIdentity) {
  const TrackerModel model = sphere_model();
  const CpuSolver solver(model);
  const gpu::PinholeCamera camera = test_camera(160, 120);
  const gpu::FaceParameters truth = true_parameters(model, 0.4f, 17);
  std::vector<InputFrame> frames;
  std::vector<gpu::FaceParameters> truths, params;
  for (float dx : {-0.02f, 0.02f}) {
    gpu::FaceParameters t = truth;
    t.translation.x() += dx;
    truths.push_back(t);
    frames.push_back(RenderSyntheticFrame(solver.renderer(), model, t, camera));
    gpu::FaceParameters s = t;
    s.translation.z() += 0.005f;
    s.alpha.setZero();
    s.beta.setZero();
    params.push_back(s);
  }
  const auto surface_error = [&](const gpu::FaceParameters& a, const gpu::FaceParameters& b) {
    const gpu::VertexState x = solver.renderer().evaluate(a), y = solver.renderer().evaluate(b);
    return (x.camera_positions - y.camera_positions).cwiseAbs().mean();
  };
  const double before = surface_error(params[0], truths[0]);
  SolverOptions o;
  o.schedule = {{1, 10, 8}, {0, 2, 8}};
  const ParameterLayout layout = ParameterLayout::Calibration(model.num_identity(), model.num_albedo(), model.num_expression());
  const SolverSummary s = solver.SolveFrames(frames, layout, o, &params);
  std::cout << s.FullReport();
  EXPECT_LT(s.final_energy.total(), 0.1 * s.initial_energy.total());
  EXPECT_EQ(params[0].alpha, params[1].alpha);
  EXPECT_EQ(params[0].beta, params[1].beta);
  for (int f = 0; f < 2; ++f) {
    EXPECT_LT(surface_error(params[f], truths[f]), before / 3) << "view " << f;
    EXPECT_NEAR(params[f].translation.x(), truths[f].translation.x(), 0.002) << "view " << f;
  }
}

// Sec. 6.3: identity and albedo shared by three views (frontal, turned left and right), pose,
// expression and lighting per frame.
TEST(TrackerCalibration, SharedIdentityFromThreeViews) {
  const TrackerModel* model = real_model();
  if (!model) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const CpuSolver solver(*model);
  const gpu::PinholeCamera camera = test_camera(640, 480);
  const gpu::FaceParameters truth = true_parameters(*model, 0.55f, 99);
  std::vector<InputFrame> frames;
  std::vector<gpu::FaceParameters> truths, params;
  for (float yaw : {0.0f, 0.35f, -0.35f}) {
    gpu::FaceParameters t = truth;
    t.euler.y() += yaw;
    truths.push_back(t);
    frames.push_back(RenderSyntheticFrame(solver.renderer(), *model, t, camera));
    gpu::FaceParameters s = perturbed_start(t, 0.3f);
    s.alpha.setZero();
    s.beta.setZero();
    params.push_back(s);
  }
  SolverOptions o;
  o.schedule = {{2, 10, 8}, {1, 3, 8}};
  const ParameterLayout layout =
      ParameterLayout::Calibration(model->num_identity(), model->num_albedo(), model->num_expression());
  const FitError single_before = fit_error(solver.renderer(), params[0], truths[0]);
  const SolverSummary s = solver.SolveFrames(frames, layout, o, &params);
  std::cout << s.FullReport();
  EXPECT_LT(s.final_energy.total(), s.initial_energy.total());
  for (size_t f = 0; f < frames.size(); ++f) {
    const FitError e = fit_error(solver.renderer(), params[f], truths[f]);
    std::cout << "view " << f << ": " << e << "\n";
    // Identity and rigid pose trade off slightly (the same ~1.2 degree / 3 mm offset in every
    // view); the surface itself is within 1.5 mm.
    EXPECT_LT(e.rotation, 0.03);
    EXPECT_LT(e.translation, 0.004);
    EXPECT_LT(e.geometry, 0.0015);
    EXPECT_LT(e.color, 0.01);
    // The identity is shared: every frame carries the same coefficients.
    EXPECT_EQ(params[f].alpha, params[0].alpha);
    EXPECT_EQ(params[f].beta, params[0].beta);
  }
  EXPECT_LT(fit_error(solver.renderer(), params[0], truths[0]).geometry, single_before.geometry / 5);
  // Mismatched inputs are refused.
  std::vector<gpu::FaceParameters> two(params.begin(), params.begin() + 2);
  EXPECT_THROW(solver.SolveFrames(frames, layout, o, &two), Error);
  std::vector<gpu::FaceParameters> none;
  EXPECT_THROW(solver.SolveFrames({}, layout, o, &none), Error);
}

}  // namespace
}  // namespace face_reenact::tracker
