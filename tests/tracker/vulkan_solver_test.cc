// The Vulkan tracker solver against its oracle, the double-precision CPU solver: the same
// residuals and Jacobian rows on the same linearisation, the same normal equations from both
// device strategies, the same fitted parameters from a full solve, and the same answers to bad
// input. Runs on lavapipe with validation (including synchronization validation) on; any
// validation message fails the test. Small images keep it fast.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <limits>
#include <nlohmann/json.hpp>
#include <stop_token>

#include "face_reenact/common/error.h"
#include "face_reenact/tracker/face_tracker.h"
#include "face_reenact/tracker/solver.h"
#include "face_reenact/tracker/fit_agreement.h"
#include "face_reenact/tracker/vulkan_solver.h"
#include "gpu_test_support.h"
#include "tracker_test_support.h"

namespace face_reenact::tracker {
namespace {

using gpu::testing::ValidatedGpuTest;
using testing::real_model;
using testing::rotation_error;
using testing::sphere_model;
using testing::test_camera;
using testing::true_parameters;

const TrackerModel& model_for_tests() {
  static const TrackerModel sphere = sphere_model();
  return real_model() ? *real_model() : sphere;
}

gpu::FaceParameters truth_for_tests() { return true_parameters(model_for_tests(), 0.55f, 7); }

// About the motion between two frames: a few degrees, a centimetre, neutral expression, white light.
gpu::FaceParameters start_for_tests(const gpu::FaceParameters& truth) {
  gpu::FaceParameters s = truth;
  s.euler += Eigen::Vector3f(0.03f, -0.025f, 0.02f);
  s.translation += Eigen::Vector3f(0.005f, -0.004f, 0.006f);
  s.delta.setZero();
  s.gamma = gpu::ambient_sh(Eigen::Vector3f::Ones());
  return s;
}


double relative(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
  const double scale = std::max(b.norm(), 1e-12);
  return (a - b).norm() / scale;
}

// The CPU's system linearised on the render the device made (same pixels, same vertex normals).
struct CpuSystem {
  Linearization lin;
  Eigen::VectorXd r;
  JacobianMatrix j;
  TermEnergies e;
};
CpuSystem CpuSystemOnTheDevicesRender(const TrackerModel& model, const ParameterLayout& layout,
                                      const gpu::FaceParameters& start, const VulkanLinearSystem& device,
                                      const InputFrame& frame, const EnergyOptions& energy) {
  CpuSystem c;
  c.lin = Linearize(model, layout, start, device.vertex_state, device.gbuffer, frame, energy);
  EvaluateResiduals(model, c.lin, energy, layout.Pack(start), &c.r, &c.j, &c.e);
  return c;
}

// The device's residuals, Jacobian rows and energy per term against the CPU's on the same
// linearisation.
void ExpectTheCpusRowsPerTerm(const VulkanLinearSystem& gpu_system, const Linearization& lin, const Eigen::VectorXd& r,
                              const JacobianMatrix& j, const TermEnergies& e) {
  for (int t = 0; t <= kNumTerms; ++t) ASSERT_EQ(gpu_system.term_rows[t], lin.term_rows[t]) << "term boundary " << t;
  for (int t = 0; t < kNumTerms; ++t) {
    const Eigen::Index begin = lin.term_rows[t], rows = lin.term_rows[t + 1] - begin;
    if (rows == 0) continue;
    const double r_error = relative(gpu_system.residuals.segment(begin, rows), r.segment(begin, rows));
    const double j_error =
        relative(gpu_system.jacobian.middleRows(begin, rows).cast<double>(), j.middleRows(begin, rows).cast<double>());
    std::cout << term_name(static_cast<Term>(t)) << ": " << rows << " rows, relative error r " << r_error << ", J "
              << j_error << ", energy " << gpu_system.energy.value[t] << " vs " << e.value[t] << "\n";
    EXPECT_LT(r_error, 1e-4) << term_name(static_cast<Term>(t));
    EXPECT_LT(j_error, 1e-4) << term_name(static_cast<Term>(t));
    EXPECT_NEAR(gpu_system.energy.value[t], e.value[t], 1e-4 * std::max(1.0, e.value[t])) << term_name(static_cast<Term>(t));
  }
}

class VulkanSolverTest : public ValidatedGpuTest {
 protected:
  VulkanSolver& solver() {
    static std::unique_ptr<VulkanSolver> s = std::make_unique<VulkanSolver>(context(), model_for_tests());
    return *s;
  }
  const CpuSolver& cpu() {
    static const CpuSolver s(model_for_tests());
    return s;
  }
};

TEST_F(VulkanSolverTest, ResidualsAndJacobianRowsMatchTheCpuOnTheSameLinearisation) {
  const TrackerModel& model = model_for_tests();
  const gpu::FaceParameters truth = truth_for_tests();
  const gpu::PinholeCamera camera = test_camera(160, 120);
  const InputFrame frame = RenderSyntheticFrame(cpu().renderer(), model, truth, camera);
  const ParameterLayout layout = ParameterLayout::Calibration(std::min(model.num_identity(), 10),
                                                              std::min(model.num_albedo(), 5), model.num_expression());
  const gpu::FaceParameters start = start_for_tests(truth);
  EnergyOptions energy;
  const Eigen::VectorXd v = Eigen::VectorXd::LinSpaced(layout.num_parameters(), -1.0, 1.0);
  const VulkanLinearSystem gpu_system = solver().Inspect(frame, layout, energy, start, v);
  const auto [lin, r, j, e] = CpuSystemOnTheDevicesRender(model, layout, start, gpu_system, frame, energy);
  ASSERT_GT(lin.num_point, 100);
  ASSERT_GT(lin.num_plane, 100);
  ASSERT_GT(lin.landmarks.size(), 5u);
  ExpectTheCpusRowsPerTerm(gpu_system, lin, r, j, e);

  // Normal equations: the assembled path's J^T J, J^T r, and the matrix-free J^T (J v).
  const Eigen::MatrixXd jd = j.cast<double>();
  const Eigen::MatrixXd jtj = jd.transpose() * jd;
  const Eigen::VectorXd jtr = jd.transpose() * r;
  const Eigen::VectorXd product = jd.transpose() * (jd * v);
  const double jtj_error = relative(gpu_system.jtj, jtj), jtr_error = relative(gpu_system.jtr, jtr);
  const double mf_jtr_error = relative(gpu_system.jtr_matrix_free, jtr);
  const double product_error = relative(gpu_system.normal_product, product);
  std::cout << "J^T J " << jtj_error << ", J^T r " << jtr_error << " (matrix-free " << mf_jtr_error << "), J^T J v "
            << product_error << "\n";
  EXPECT_LT(jtj_error, 1e-4);
  EXPECT_LT(jtr_error, 1e-4);
  EXPECT_LT(mf_jtr_error, 1e-4);
  EXPECT_LT(product_error, 1e-4);
}

// The level's input is made on the device from its colour and depth (tracker_input.comp): holes
// of every kind (NaN, 0, infinity, beyond the far plane), a depth step across the face and the
// image border give the same points, normals (none across a jump or beside a hole) and colour
// gradients as the CPU's InputNormal and InputColorGradient, so the same rows.
TEST_F(VulkanSolverTest, InputWithHolesAndDepthStepsGivesTheCpusRows) {
  const TrackerModel& model = model_for_tests();
  const gpu::FaceParameters truth = truth_for_tests();
  InputFrame frame = RenderSyntheticFrame(cpu().renderer(), model, truth, test_camera(160, 120));
  const float holes[] = {std::nanf(""), 0.f, std::numeric_limits<float>::infinity(), 2.f * frame.camera.far_plane};
  for (int j = 0; j < frame.height(); ++j) {
    for (int i = 0; i < frame.width(); ++i) {
      float& d = frame.depth[static_cast<size_t>(j) * frame.width() + i];
      if (i > 85 && std::isfinite(d)) d += 0.04f;  // a step larger than max_depth_jump_m
      if ((i * 7 + j * 3) % 41 == 0) d = holes[(i + j) % 4];
    }
  }
  const ParameterLayout layout = ParameterLayout::Tracking(model.num_expression());
  const gpu::FaceParameters start = start_for_tests(truth);
  EnergyOptions energy;
  ASSERT_TRUE(energy.color_follows_projection);
  const Eigen::VectorXd v = Eigen::VectorXd::Ones(layout.num_parameters());
  const VulkanLinearSystem g = solver().Inspect(frame, layout, energy, start, v);
  const auto [lin, r, j, e] = CpuSystemOnTheDevicesRender(model, layout, start, g, frame, energy);
  ASSERT_GT(lin.num_plane, 100);
  ASSERT_LT(lin.num_plane, lin.num_point);  // some pixels lost their normal to a hole or the step
  ExpectTheCpusRowsPerTerm(g, lin, r, j, e);
}

// Same for the tracking layout on a colour-only frame (no depth: colour and landmarks only).
TEST_F(VulkanSolverTest, ColourOnlyFrameMatchesTheCpu) {
  const TrackerModel& model = model_for_tests();
  const gpu::FaceParameters truth = truth_for_tests();
  InputFrame frame = RenderSyntheticFrame(cpu().renderer(), model, truth, test_camera(160, 120));
  frame.depth.clear();
  const ParameterLayout layout = ParameterLayout::Tracking(model.num_expression());
  gpu::FaceParameters start = start_for_tests(truth);
  for (int k = 0; k < start.delta.size(); ++k) start.delta[k] = 0.03f * static_cast<float>(k % 7);
  EnergyOptions energy;
  energy.w_reg_expression = 0.5;       // the expression prior rows with both of their weights
  energy.w_expression_sparsity = 0.1;  // (the reweighted L1 reads the base expression)
  const Eigen::VectorXd v = Eigen::VectorXd::Ones(layout.num_parameters());
  const VulkanLinearSystem g = solver().Inspect(frame, layout, energy, start, v);
  const auto [lin, r, j, e] = CpuSystemOnTheDevicesRender(model, layout, start, g, frame, energy);
  EXPECT_EQ(lin.num_point, 0);
  for (int t = 0; t <= kNumTerms; ++t) ASSERT_EQ(g.term_rows[t], lin.term_rows[t]) << "term boundary " << t;
  EXPECT_LT(relative(g.residuals, r), 1e-4);
  const Eigen::MatrixXd jd = j.cast<double>();
  EXPECT_LT(relative(g.jacobian.cast<double>(), jd), 1e-4);
  EXPECT_LT(relative(g.normal_product, jd.transpose() * (jd * v)), 1e-4);
}

// EnergyOptions::pixel_sampling 2 (the tracker's solves) and 4 (the calibration of a large face):
// the device takes the CPU's lattice of pixels, so the same rows, on an RGB-D frame (every dense
// term).
TEST_F(VulkanSolverTest, SampledPixelsGiveTheCpusRows) {
  const TrackerModel& model = model_for_tests();
  const gpu::FaceParameters truth = truth_for_tests();
  const InputFrame frame = RenderSyntheticFrame(cpu().renderer(), model, truth, test_camera(160, 120));
  const ParameterLayout layout = ParameterLayout::Tracking(model.num_expression());
  const gpu::FaceParameters start = start_for_tests(truth);
  const Eigen::VectorXd v = Eigen::VectorXd::Ones(layout.num_parameters());
  for (const int sampling : {2, 4}) {
    SCOPED_TRACE(sampling);
    EnergyOptions energy;
    energy.pixel_sampling = sampling;
    const VulkanLinearSystem g = solver().Inspect(frame, layout, energy, start, v);
    const auto [lin, r, j, e] = CpuSystemOnTheDevicesRender(model, layout, start, g, frame, energy);
    const Linearization every = Linearize(model, layout, start, g.vertex_state, g.gbuffer, frame, EnergyOptions{});
    ASSERT_GT(lin.num_point, 50);
    EXPECT_NEAR(lin.num_color, every.num_color / static_cast<double>(sampling), 0.02 * every.num_color);
    ExpectTheCpusRowsPerTerm(g, lin, r, j, e);
  }
}

// A full coarse-to-fine solve lands where the CPU solver lands, with either strategy.
TEST_F(VulkanSolverTest, SolveReachesTheCpuResultWithBothStrategies) {
  const TrackerModel& model = model_for_tests();
  const gpu::FaceParameters truth = truth_for_tests();
  const InputFrame frame = RenderSyntheticFrame(cpu().renderer(), model, truth, test_camera(320, 240));
  const ParameterLayout layout = ParameterLayout::Tracking(model.num_expression());
  SolverOptions options;  // paper schedule: 7 x 4 on level 2 (80x60), 1 x 4 on level 1 (160x120)
  gpu::FaceParameters cpu_fit = start_for_tests(truth);
  const SolverSummary cpu_summary = cpu().Solve(frame, layout, options, &cpu_fit);
  ASSERT_EQ(cpu_summary.termination, Termination::kScheduleDone) << cpu_summary.FullReport();
  for (VulkanStrategy strategy : {VulkanStrategy::kMatrixFree, VulkanStrategy::kAssembled}) {
    solver().set_strategy(strategy);
    gpu::FaceParameters fit = start_for_tests(truth);
    const SolverSummary s = solver().Solve(frame, layout, options, &fit);
    std::cout << vulkan_strategy_name(strategy) << ": " << s.BriefReport() << "\n  cpu: " << cpu_summary.BriefReport()
              << "\n  rotation vs cpu " << rotation_error(fit, cpu_fit) * 180 / M_PI << " deg, translation vs cpu "
              << (fit.translation - cpu_fit.translation).norm() * 1000 << " mm; vs truth "
              << rotation_error(fit, truth) * 180 / M_PI << " deg / "
              << (fit.translation - truth.translation).norm() * 1000 << " mm (cpu "
              << rotation_error(cpu_fit, truth) * 180 / M_PI << " deg / "
              << (cpu_fit.translation - truth.translation).norm() * 1000 << " mm), expression max diff "
              << (fit.delta - cpu_fit.delta).cwiseAbs().maxCoeff() << "\n";
    EXPECT_EQ(s.termination, Termination::kScheduleDone) << s.FullReport();
    EXPECT_FALSE(s.iterations.empty());
    EXPECT_LT(s.final_energy.total(), 0.5 * s.initial_energy.total()) << s.FullReport();
    // float on the device against double on the CPU: observed 1e-5 mm and 1e-5 in the weights.
    EXPECT_LT(rotation_error(fit, cpu_fit), 0.05 * M_PI / 180) << vulkan_strategy_name(strategy);
    EXPECT_LT((fit.translation - cpu_fit.translation).norm(), 5e-5) << vulkan_strategy_name(strategy);
    EXPECT_LT((fit.delta - cpu_fit.delta).cwiseAbs().maxCoeff(), 1e-3) << vulkan_strategy_name(strategy);
    EXPECT_LT(rotation_error(fit, truth), 2.0 * rotation_error(start_for_tests(truth), truth) / 3);
  }
  solver().set_strategy(VulkanStrategy::kAuto);
}

// The device-driven loop (the frame's schedule recorded once and submitted once, tracker_loop.comp
// making RunGaussNewton's decisions on the device) against the host-driven loop on the same
// frame: the same iterations, halvings and words, and the same fit up to float rounding (the
// device keeps x in float). With the paper's whole schedule and with early termination (3 %),
// where the device skips the recorded iterations a converged level does not need.
TEST_F(VulkanSolverTest, TheDeviceDrivenLoopTakesTheHostDrivenLoopsSteps) {
  const TrackerModel& model = model_for_tests();
  const gpu::FaceParameters truth = truth_for_tests();
  const InputFrame frame = RenderSyntheticFrame(cpu().renderer(), model, truth, test_camera(320, 240));
  const ParameterLayout layout = ParameterLayout::Tracking(model.num_expression());
  VulkanSolverOptions host_options;
  host_options.device_loop = false;
  VulkanSolver device_driven(context(), model), host_driven(context(), model, host_options);
  {  // a first frame also uploads the renderer's draw list (a submission of its own)
    device_driven.set_strategy(VulkanStrategy::kMatrixFree);
    gpu::FaceParameters warm = start_for_tests(truth);
    device_driven.Solve(frame, layout, SolverOptions{}, &warm);
  }
  const std::string suffix = ", device-driven loop";
  for (VulkanStrategy strategy : {VulkanStrategy::kMatrixFree, VulkanStrategy::kAssembled}) {
    device_driven.set_strategy(strategy);
    host_driven.set_strategy(strategy);
    for (const double tolerance : {1e-9, 0.03}) {
      SCOPED_TRACE(std::string(vulkan_strategy_name(strategy)) + ", function tolerance " + std::to_string(tolerance));
      SolverOptions options;
      options.function_tolerance = tolerance;
      gpu::FaceParameters d_fit = start_for_tests(truth), h_fit = d_fit;
      const SolverSummary d = device_driven.Solve(frame, layout, options, &d_fit);
      const SolverSummary h = host_driven.Solve(frame, layout, options, &h_fit);
      std::cout << "device-driven: " << d.BriefReport() << "\n  host-driven: " << h.BriefReport() << "\n";
      EXPECT_EQ(d.device_submissions, 1) << d.FullReport();
      EXPECT_GE(h.device_submissions, static_cast<int>(h.iterations.size()) + 2);
      ASSERT_NE(d.message.find(suffix), std::string::npos) << d.message;
      std::string words = d.message;
      words.erase(words.find(suffix), suffix.size());
      EXPECT_EQ(words, h.message);
      EXPECT_EQ(d.termination, h.termination);
      ASSERT_EQ(d.iterations.size(), h.iterations.size()) << d.FullReport() << "\n" << h.FullReport();
      if (tolerance > 0.01) EXPECT_LT(d.iterations.size(), 8u) << "no level ended early: the test does not see skipped blocks";
      for (size_t i = 0; i < d.iterations.size(); ++i) {
        const IterationRecord &a = d.iterations[i], &b = h.iterations[i];
        EXPECT_EQ(a.level, b.level) << i;
        EXPECT_EQ(a.iteration, b.iteration) << i;
        EXPECT_EQ(a.step_halvings, b.step_halvings) << i;
        EXPECT_EQ(a.pcg_iterations, b.pcg_iterations) << i;
        EXPECT_NEAR(double(a.residuals), double(b.residuals), 0.01 * double(b.residuals)) << i;
        // A render's correspondences at pixels on the pruning thresholds (point distance, robust
        // colour weight) follow the last float bits, which the atomic compaction's order changes
        // from run to run, host-driven too: the energy at a new render moved by up to 1 % between
        // two host-driven runs of this frame (0.2860 and 0.2831 after level 1), the steps did not.
        EXPECT_NEAR(a.energy_before.total(), b.energy_before.total(), 1e-3 * b.energy_before.total()) << i;
        EXPECT_NEAR(a.energy_after.total(), b.energy_after.total(), 2e-2 * b.energy_after.total()) << i;
        EXPECT_NEAR(a.step_norm, b.step_norm, 1e-3 * b.step_norm + 1e-9) << i;
        if (context().timestamps_supported()) EXPECT_GT(a.analysis_ms, 0.0) << i;
      }
      EXPECT_NEAR(d.initial_energy.total(), h.initial_energy.total(), 1e-5 * h.initial_energy.total());
      EXPECT_NEAR(d.final_energy.total(), h.final_energy.total(), 2e-2 * h.final_energy.total());
      EXPECT_LT(rotation_error(d_fit, h_fit), 0.01 * M_PI / 180);
      EXPECT_LT((d_fit.translation - h_fit.translation).norm(), 2e-5);
      EXPECT_LT((d_fit.delta - h_fit.delta).cwiseAbs().maxCoeff(), 1e-3);
      EXPECT_GT(d.analysis_ms, 0.0);
      EXPECT_LE(d.synthesis_ms + d.analysis_ms, d.total_ms + 1e-6);
    }
  }
}

// The device-driven loop records a level's blocks only as far as the last frames needed them (a
// converged level's skipped iterations would cost their barriers and recording). A frame that
// needs more - a start a few degrees and a centimetre away, after frames tracked at rest - stops
// where the recorded blocks end and its remaining blocks follow in a second submission: the same
// steps as the host-driven loop. The next such frame records enough at once.
TEST_F(VulkanSolverTest, AFrameNeedingMoreStepsThanTheLastFramesResumesInASecondSubmission) {
  const TrackerModel& model = model_for_tests();
  const gpu::FaceParameters truth = truth_for_tests();
  const InputFrame frame = RenderSyntheticFrame(cpu().renderer(), model, truth, test_camera(320, 240));
  const ParameterLayout layout = ParameterLayout::Tracking(model.num_expression());
  SolverOptions options;
  options.function_tolerance = 0.03;  // the tracker's
  VulkanSolverOptions matrix_free;
  matrix_free.strategy = VulkanStrategy::kMatrixFree;
  VulkanSolverOptions host_options = matrix_free;
  host_options.device_loop = false;
  VulkanSolver device_driven(context(), model, matrix_free), host_driven(context(), model, host_options);
  SolverSummary rest;
  for (int k = 0; k < 3; ++k) {
    gpu::FaceParameters p = truth;
    rest = device_driven.Solve(frame, layout, options, &p);
  }
  gpu::FaceParameters d_fit = start_for_tests(truth), h_fit = d_fit;
  const SolverSummary d = device_driven.Solve(frame, layout, options, &d_fit);
  const SolverSummary h = host_driven.Solve(frame, layout, options, &h_fit);
  std::cout << "at rest: " << rest.BriefReport() << "\nresumed: " << d.FullReport() << "\n";
  ASSERT_GT(d.iterations.size(), rest.iterations.size()) << "the far start needs no more steps: nothing resumes";
  EXPECT_EQ(rest.device_submissions, 1);
  EXPECT_EQ(d.device_submissions, 2);
  EXPECT_EQ(d.termination, h.termination);
  ASSERT_EQ(d.iterations.size(), h.iterations.size()) << d.FullReport() << "\n" << h.FullReport();
  for (size_t i = 0; i < d.iterations.size(); ++i) {
    EXPECT_EQ(d.iterations[i].level, h.iterations[i].level) << i;
    EXPECT_EQ(d.iterations[i].iteration, h.iterations[i].iteration) << i;
    EXPECT_EQ(d.iterations[i].step_halvings, h.iterations[i].step_halvings) << i;
    EXPECT_NEAR(d.iterations[i].step_norm, h.iterations[i].step_norm, 1e-3 * h.iterations[i].step_norm + 1e-9) << i;
  }
  EXPECT_NEAR(d.final_energy.total(), h.final_energy.total(), 2e-2 * h.final_energy.total());  // see above
  EXPECT_LT(rotation_error(d_fit, h_fit), 0.01 * M_PI / 180);
  EXPECT_LT((d_fit.translation - h_fit.translation).norm(), 2e-5);
  gpu::FaceParameters again = start_for_tests(truth);
  EXPECT_EQ(device_driven.Solve(frame, layout, options, &again).device_submissions, 1);
}

// The device-driven loop sizes J ahead. A frame whose linearisation needs more rows is solved
// host-driven (the same result), J grows, and the next frame is driven from the device again.
TEST_F(VulkanSolverTest, AFrameBeyondTheDeviceLoopsJacobianIsSolvedHostDrivenAndJGrows) {
  const TrackerModel& model = model_for_tests();
  const gpu::FaceParameters truth = truth_for_tests();
  const InputFrame frame = RenderSyntheticFrame(cpu().renderer(), model, truth, test_camera(320, 240));
  const ParameterLayout layout = ParameterLayout::Tracking(model.num_expression());
  VulkanSolverOptions small;
  small.device_loop_rows = 64;
  small.strategy = VulkanStrategy::kMatrixFree;
  VulkanSolver solver(context(), model, small);
  SolverOptions options;
  gpu::FaceParameters first_fit = start_for_tests(truth), second_fit = first_fit;
  const SolverSummary first = solver.Solve(frame, layout, options, &first_fit);
  const SolverSummary second = solver.Solve(frame, layout, options, &second_fit);
  EXPECT_EQ(first.message.find("device-driven"), std::string::npos) << first.message;
  EXPECT_GT(first.device_submissions, 2);  // the device-driven try, then two per step
  EXPECT_NE(second.message.find("device-driven loop"), std::string::npos) << second.message;
  EXPECT_EQ(second.device_submissions, 1);
  ASSERT_EQ(first.iterations.size(), second.iterations.size());
  EXPECT_NEAR(first.final_energy.total(), second.final_energy.total(), 2e-2 * first.final_energy.total());  // see the test above
  EXPECT_LT(rotation_error(first_fit, second_fit), 0.01 * M_PI / 180);
}

// The calibration's joint solve (Sec. 6.3) on the device: three views of one face (frontal,
// turned either way), identity and albedo shared, the rest per frame, from the mean face. Each
// frame's J^T J is assembled on the device and the joint system solved on the host: the same
// steps as CpuSolver::SolveFrames in float, so the same identity, poses and energy, with the
// shared prior counted once (a prior counted per frame would not give the CPU's energy).
TEST_F(VulkanSolverTest, CalibrationReachesTheCpuResult) {
  const TrackerModel& model = model_for_tests();
  const gpu::FaceParameters truth = truth_for_tests();
  const int n_id = std::min(model.num_identity(), 20), n_alb = std::min(model.num_albedo(), 5);
  const ParameterLayout layout = ParameterLayout::Calibration(n_id, n_alb, model.num_expression());
  std::vector<InputFrame> frames;
  std::vector<gpu::FaceParameters> starts;
  for (const float yaw : {-0.25f, 0.0f, 0.25f}) {
    gpu::FaceParameters t = truth;
    t.euler.y() += yaw;
    frames.push_back(RenderSyntheticFrame(cpu().renderer(), model, t, test_camera(160, 120)));
    gpu::FaceParameters s = start_for_tests(t);
    s.alpha.setZero();
    s.beta.setZero();
    starts.push_back(s);
  }
  SolverOptions options;
  options.schedule = {{1, 6, 4}, {0, 2, 4}};
  std::vector<gpu::FaceParameters> cpu_fit = starts, fit = starts;
  const SolverSummary cpu_summary = cpu().SolveFrames(frames, layout, options, &cpu_fit);
  const SolverSummary s = solver().SolveFrames(frames, layout, options, &fit);
  std::cout << "vulkan: " << s.BriefReport() << "\n" << s.message << "\n  cpu: " << cpu_summary.BriefReport() << "\n";
  ASSERT_EQ(cpu_summary.termination, Termination::kScheduleDone) << cpu_summary.FullReport();
  EXPECT_EQ(s.termination, Termination::kScheduleDone) << s.FullReport();
  EXPECT_EQ(s.iterations.size(), cpu_summary.iterations.size());
  EXPECT_NEAR(s.initial_energy.total(), cpu_summary.initial_energy.total(), 1e-4 * cpu_summary.initial_energy.total());
  EXPECT_NEAR(s.final_energy.total(), cpu_summary.final_energy.total(), 2e-3 * cpu_summary.final_energy.total());
  EXPECT_LT(s.final_energy.total(), 0.2 * s.initial_energy.total());
  EXPECT_EQ(fit[0].alpha, fit[2].alpha);  // shared
  EXPECT_EQ(fit[0].beta, fit[1].beta);
  const Eigen::VectorXf id_scale = model.identity_sigma.head(n_id);
  EXPECT_LT(((fit[0].alpha.head(n_id) - cpu_fit[0].alpha.head(n_id)).cwiseQuotient(id_scale)).cwiseAbs().maxCoeff(), 0.02);
  for (size_t f = 0; f < frames.size(); ++f) {
    EXPECT_LT(rotation_error(fit[f], cpu_fit[f]), 0.05 * M_PI / 180) << "frame " << f;
    EXPECT_LT((fit[f].translation - cpu_fit[f].translation).norm(), 1e-4) << "frame " << f;
    EXPECT_LT((fit[f].delta - cpu_fit[f].delta).cwiseAbs().maxCoeff(), 5e-3) << "frame " << f;
  }
  for (size_t i = 0; i < std::min(s.iterations.size(), cpu_summary.iterations.size()); ++i) {
    EXPECT_EQ(s.iterations[i].step_halvings, cpu_summary.iterations[i].step_halvings) << "step " << i;
  }
  // What the CPU's joint solve refuses, this one refuses too.
  std::vector<gpu::FaceParameters> too_few(2, starts[0]);
  EXPECT_THROW(solver().SolveFrames(frames, layout, options, &too_few), Error);
  EXPECT_THROW(solver().SolveFrames({}, layout, options, &too_few), Error);
}

// Solve(frame) makes the pyramid on the device (tracker_pyramid.comp) from the frame's colour and
// depth: the same levels as BuildPyramid, holes, a silhouette, odd sizes and the border included,
// and a frame solved from them lands where the same frame solved from the host's pyramid does.
TEST_F(VulkanSolverTest, ThePyramidMadeOnTheDeviceIsTheHostsPyramid) {
  const TrackerModel& model = model_for_tests();
  const gpu::FaceParameters truth = truth_for_tests();
  InputFrame frame = RenderSyntheticFrame(cpu().renderer(), model, truth, test_camera(166, 122));
  for (int j = 0; j < frame.height(); ++j) {
    for (int i = 0; i < frame.width(); ++i) {
      float& d = frame.depth[static_cast<size_t>(j) * frame.width() + i];
      if (!std::isfinite(d) || d <= 0.f) d = 1.4f;  // a background, for a silhouette
      if ((i * 5 + j * 11) % 37 == 0) d = (i + j) % 2 ? std::nanf("") : 0.f;
    }
  }
  const PyramidOptions options;
  const std::vector<InputFrame> host = BuildPyramid(frame, options, 2, false);
  const std::vector<InputFrame> device = solver().InspectPyramid(frame, options);
  ASSERT_EQ(device.size(), host.size());
  EXPECT_TRUE(device[0].color.empty());
  for (size_t l = 1; l < host.size(); ++l) {
    ASSERT_EQ(device[l].width(), host[l].width());
    ASSERT_EQ(device[l].height(), host[l].height());
    ASSERT_EQ(device[l].landmarks.size(), host[l].landmarks.size());
    EXPECT_EQ(device[l].landmarks[3].position, host[l].landmarks[3].position);
    ASSERT_EQ(device[l].color.size(), host[l].color.size());
    ASSERT_EQ(device[l].depth.size(), host[l].depth.size());
    float color_error = 0.f, depth_error = 0.f;
    for (size_t k = 0; k < host[l].color.size(); ++k) color_error = std::max(color_error, std::abs(device[l].color[k] - host[l].color[k]));
    for (size_t k = 0; k < host[l].depth.size(); ++k) depth_error = std::max(depth_error, std::abs(device[l].depth[k] - host[l].depth[k]));
    std::cout << "level " << l << ": colour max difference " << color_error << ", depth " << depth_error << "\n";
    EXPECT_LT(color_error, 1e-6f) << "level " << l;
    EXPECT_LT(depth_error, 1e-6f) << "level " << l;
  }

  const ParameterLayout layout = ParameterLayout::Tracking(model.num_expression());
  SolverOptions solve;
  solve.schedule = {{2, 3, 4}, {1, 1, 4}};
  solver().set_strategy(VulkanStrategy::kMatrixFree);
  gpu::FaceParameters from_frame = start_for_tests(truth), from_pyramid = start_for_tests(truth);
  const SolverSummary a = solver().Solve(frame, layout, solve, &from_frame);
  const SolverSummary b = solver().Solve(BuildPyramid(frame, solve.pyramid, 1, false), layout, solve, &from_pyramid);
  ASSERT_EQ(a.iterations.size(), b.iterations.size()) << a.FullReport() << "\n" << b.FullReport();
  EXPECT_NEAR(a.final_energy.total(), b.final_energy.total(), 1e-5 * b.final_energy.total());
  EXPECT_LT(rotation_error(from_frame, from_pyramid), 1e-5);
  EXPECT_LT((from_frame.translation - from_pyramid.translation).norm(), 1e-6);
  EXPECT_LT((from_frame.delta - from_pyramid.delta).cwiseAbs().maxCoeff(), 1e-4);
}

// The solver keeps each level's input buffers from frame to frame (allocating them per frame
// cost a real GPU more than the level's analysis). A frame after a larger one, with fewer
// landmarks and another pose, must solve exactly as on a solver that never saw the first.
TEST_F(VulkanSolverTest, KeptLevelInputsDoNotLeakIntoTheNextFrame) {
  const TrackerModel& model = model_for_tests();
  const gpu::FaceParameters truth = truth_for_tests();
  const ParameterLayout layout = ParameterLayout::Tracking(model.num_expression());
  SolverOptions options;
  options.schedule = {{2, 3, 4}, {1, 1, 4}};
  options.linear_solver = LinearSolverType::kMatrixFree;
  const InputFrame larger = RenderSyntheticFrame(cpu().renderer(), model, truth, test_camera(320, 240));
  gpu::FaceParameters moved = truth;
  moved.euler.y() += 0.08f;
  moved.translation.x() -= 0.01f;
  InputFrame next = RenderSyntheticFrame(cpu().renderer(), model, moved, test_camera(160, 120));
  next.landmarks.resize(next.landmarks.size() / 2);

  VulkanSolver reused(context(), model);
  reused.set_strategy(VulkanStrategy::kFromSolverOptions);
  gpu::FaceParameters first = start_for_tests(truth);
  reused.Solve(larger, layout, options, &first);
  gpu::FaceParameters after = start_for_tests(moved);
  const SolverSummary s = reused.Solve(next, layout, options, &after);

  VulkanSolver fresh(context(), model);
  fresh.set_strategy(VulkanStrategy::kFromSolverOptions);
  gpu::FaceParameters alone = start_for_tests(moved);
  const SolverSummary f = fresh.Solve(next, layout, options, &alone);
  // Equal up to the order of the device's float reductions (rows are compacted with atomics):
  // observed 1e-7 rad, 1e-9 m and 3e-6 in the weights; a stale pixel or landmark moves far more.
  ASSERT_EQ(s.iterations.size(), f.iterations.size()) << s.FullReport() << "\n" << f.FullReport();
  EXPECT_NEAR(s.final_energy.total(), f.final_energy.total(), 1e-5 * f.final_energy.total());
  EXPECT_LT((after.euler - alone.euler).cwiseAbs().maxCoeff(), 1e-5);
  EXPECT_LT((after.translation - alone.translation).norm(), 1e-6);
  EXPECT_LT((after.delta - alone.delta).cwiseAbs().maxCoeff(), 1e-4);
  EXPECT_GE(s.input_ms, 0.0);
  EXPECT_LE(s.input_ms, s.total_ms);
}

TEST_F(VulkanSolverTest, AutoStrategyMeasuresBothAndKeepsTheFaster) {
  const TrackerModel& model = model_for_tests();
  const gpu::FaceParameters truth = truth_for_tests();
  const InputFrame frame = RenderSyntheticFrame(cpu().renderer(), model, truth, test_camera(160, 120));
  const ParameterLayout layout = ParameterLayout::Tracking(model.num_expression());
  SolverOptions options;
  options.schedule = {{1, 2, 4}};
  solver().set_strategy(VulkanStrategy::kAuto);
  EXPECT_EQ(solver().strategy_choice().chosen, VulkanStrategy::kAuto);
  gpu::FaceParameters fit = start_for_tests(truth);
  const SolverSummary s = solver().Solve(frame, layout, options, &fit);
  const VulkanStrategyChoice& c = solver().strategy_choice();
  ASSERT_NE(c.chosen, VulkanStrategy::kAuto) << s.FullReport();
  EXPECT_GT(c.matrix_free_ms, 0);
  EXPECT_GT(c.assembled_ms, 0);
  EXPECT_GT(c.residuals, 0);
  EXPECT_EQ(c.chosen, c.matrix_free_ms <= c.assembled_ms ? VulkanStrategy::kMatrixFree : VulkanStrategy::kAssembled);
  EXPECT_NE(s.message.find(vulkan_strategy_name(c.chosen)), std::string::npos) << s.message;
  // The solver is also selectable through SolverOptions::linear_solver.
  solver().set_strategy(VulkanStrategy::kFromSolverOptions);
  options.linear_solver = LinearSolverType::kAssembled;
  fit = start_for_tests(truth);
  const SolverSummary a = solver().Solve(frame, layout, options, &fit);
  EXPECT_NE(a.message.find("assembled"), std::string::npos) << a.message;
  solver().set_strategy(VulkanStrategy::kAuto);
}

// Bad input: the same termination or error as the CPU solver, never a crash.
TEST_F(VulkanSolverTest, NoFaceInTheInputStopsLikeTheCpu) {
  const TrackerModel& model = model_for_tests();
  const gpu::FaceParameters truth = truth_for_tests();
  const InputFrame frame = RenderSyntheticFrame(cpu().renderer(), model, truth, test_camera(160, 120));
  const ParameterLayout layout = ParameterLayout::Tracking(model.num_expression());
  SolverOptions options;
  options.schedule = {{1, 2, 2}};
  gpu::FaceParameters away = truth;
  away.translation.z() = -0.5f;  // behind the camera: nothing rendered, no landmark visible
  const gpu::FaceParameters start = away;
  gpu::FaceParameters cpu_away = away;
  const SolverSummary c = cpu().Solve(frame, layout, options, &cpu_away);
  const SolverSummary g = solver().Solve(frame, layout, options, &away);
  EXPECT_EQ(c.termination, Termination::kNoValidResiduals);
  EXPECT_EQ(g.termination, c.termination) << g.FullReport();
  EXPECT_EQ(away.translation, start.translation);  // left unchanged
  EXPECT_EQ(away.euler, start.euler);
  // The same where the device drives the loop (the strategy known from the start).
  VulkanSolverOptions matrix_free;
  matrix_free.strategy = VulkanStrategy::kMatrixFree;
  VulkanSolver device_driven(context(), model, matrix_free);
  gpu::FaceParameters device_away = start;
  const SolverSummary d = device_driven.Solve(frame, layout, options, &device_away);
  EXPECT_EQ(d.termination, Termination::kNoValidResiduals) << d.FullReport();
  EXPECT_NE(d.message.find("device-driven loop"), std::string::npos) << d.message;
  EXPECT_EQ(device_away.translation, start.translation);
  EXPECT_EQ(device_away.euler, start.euler);

  // A frame with no depth, no colour term and no landmarks has nothing to fit either.
  InputFrame empty = frame;
  empty.depth.assign(empty.depth.size(), 0.f);
  empty.landmarks.clear();
  options.energy.use_color = false;
  gpu::FaceParameters p = truth;
  const SolverSummary e = solver().Solve(empty, layout, options, &p);
  EXPECT_EQ(e.termination, Termination::kNoValidResiduals) << e.FullReport();
}

TEST_F(VulkanSolverTest, ARequestedStopEndsTheSolveLikeTheCpu) {
  const TrackerModel& model = model_for_tests();
  const gpu::FaceParameters truth = truth_for_tests();
  const InputFrame frame = RenderSyntheticFrame(cpu().renderer(), model, truth, test_camera(160, 120));
  const ParameterLayout layout = ParameterLayout::Tracking(model.num_expression());
  std::stop_source stop;
  stop.request_stop();
  SolverOptions options;
  options.schedule = {{1, 2, 2}};
  options.stop = stop.get_token();
  gpu::FaceParameters start = truth;
  start.translation.x() += 0.01f;
  gpu::FaceParameters c_params = start, g_params = start;
  const SolverSummary c = cpu().Solve(frame, layout, options, &c_params);
  const SolverSummary g = solver().Solve(frame, layout, options, &g_params);
  EXPECT_EQ(c.termination, Termination::kStopped) << c.FullReport();
  EXPECT_EQ(g.termination, Termination::kStopped) << g.FullReport();
  EXPECT_TRUE(g.iterations.empty());
  EXPECT_EQ(g_params.translation, start.translation);
}

TEST_F(VulkanSolverTest, InvalidStartParametersAndOptionsAreErrorsLikeTheCpu) {
  const TrackerModel& model = model_for_tests();
  const gpu::FaceParameters truth = truth_for_tests();
  const InputFrame frame = RenderSyntheticFrame(cpu().renderer(), model, truth, test_camera(160, 120));
  const ParameterLayout layout = ParameterLayout::Tracking(model.num_expression());
  SolverOptions options;
  gpu::FaceParameters nan_start = truth;
  nan_start.euler.x() = std::nanf("");
  gpu::FaceParameters cpu_nan = nan_start;
  EXPECT_THROW(cpu().Solve(frame, layout, options, &cpu_nan), Error);
  EXPECT_THROW(solver().Solve(frame, layout, options, &nan_start), Error);

  SolverOptions bad = options;
  bad.schedule.clear();
  gpu::FaceParameters p = truth;
  EXPECT_THROW(cpu().Solve(frame, layout, bad, &p), Error);
  EXPECT_THROW(solver().Solve(frame, layout, bad, &p), Error);
  bad = options;
  bad.damping = -1;
  EXPECT_THROW(solver().Solve(frame, layout, bad, &p), Error);
  bad = options;
  bad.schedule = {{5, 1, 1}};  // beyond the pyramid
  EXPECT_THROW(solver().Solve(frame, layout, bad, &p), Error);

  InputFrame broken = frame;
  broken.color.resize(3);
  EXPECT_THROW(solver().Solve(broken, layout, options, &p), Error);
  // A NaN or infinite colour value anywhere (the device path checks them while uploading), with
  // the CPU's words; the solver works on afterwards.
  for (const float bad_value : {std::nanf(""), -std::numeric_limits<float>::infinity()}) {
    for (const size_t at : {size_t{0}, frame.color.size() / 2 + 1, frame.color.size() - 1}) {
      InputFrame non_finite = frame;
      non_finite.color[at] = bad_value;
      std::string cpu_words, device_words;
      try {
        cpu().Solve(non_finite, layout, options, &p);
      } catch (const Error& e) {
        cpu_words = e.what();
      }
      try {
        solver().Solve(non_finite, layout, options, &p);
      } catch (const Error& e) {
        device_words = e.what();
      }
      EXPECT_FALSE(device_words.empty()) << "colour value " << at;
      EXPECT_EQ(device_words, cpu_words) << "colour value " << at;
    }
  }
  gpu::FaceParameters after = start_for_tests(truth);
  EXPECT_NE(solver().Solve(frame, layout, options, &after).termination, Termination::kNonFinite);
  ParameterLayout too_big = ParameterLayout::Calibration(model.num_identity(), model.num_albedo(), model.num_expression());
  too_big.num_identity += 1000;  // more than the model has
  EXPECT_THROW(solver().Solve(frame, too_big, options, &p), Error);
  EXPECT_THROW(solver().Solve(frame, layout, options, nullptr), Error);
  EXPECT_EQ(p.translation, truth.translation);  // nothing was changed by the failed calls

  VulkanSolverOptions vo;
  vo.strategy = static_cast<VulkanStrategy>(42);
  std::string why;
  EXPECT_FALSE(vo.IsValid(&why));
  EXPECT_THROW(VulkanSolver(context(), model, vo), Error);
}

// Landmarks alone (no depth, colour term off): no pixel carries a term, the solve runs on the
// landmark and regulariser rows only and lands where the CPU lands.
TEST_F(VulkanSolverTest, LandmarksAloneMatchTheCpu) {
  const TrackerModel& model = model_for_tests();
  const gpu::FaceParameters truth = truth_for_tests();
  InputFrame frame = RenderSyntheticFrame(cpu().renderer(), model, truth, test_camera(160, 120));
  frame.depth.clear();
  ParameterLayout layout = ParameterLayout::Tracking(model.num_expression());
  SolverOptions options;
  options.energy.use_color = false;
  options.schedule = {{1, 5, 4}};
  gpu::FaceParameters start = truth;  // expression known: landmarks alone cannot separate it from pose
  start.euler += Eigen::Vector3f(0.03f, -0.02f, 0.02f);
  start.translation += Eigen::Vector3f(0.004f, -0.003f, 0.0f);
  gpu::FaceParameters cpu_fit = start, fit = start;
  const SolverSummary c = cpu().Solve(frame, layout, options, &cpu_fit);
  solver().set_strategy(VulkanStrategy::kMatrixFree);
  const SolverSummary g = solver().Solve(frame, layout, options, &fit);
  solver().set_strategy(VulkanStrategy::kAuto);
  ASSERT_EQ(g.termination, c.termination) << g.FullReport() << "\n" << c.FullReport();
  ASSERT_FALSE(g.iterations.empty());
  EXPECT_EQ(g.iterations[0].residuals, c.iterations[0].residuals);
  EXPECT_NEAR(g.initial_energy[Term::kLandmark], c.initial_energy[Term::kLandmark], 1e-4 * c.initial_energy.total());
  EXPECT_LT(g.final_energy.total(), 0.1 * g.initial_energy.total()) << g.FullReport();
  EXPECT_LT(rotation_error(fit, cpu_fit), 0.05 * M_PI / 180);
  EXPECT_LT((fit.translation - cpu_fit.translation).norm(), 5e-5);
}

// The photo fit's landmarks on the GPU as on the CPU: the brows and the jaw line in E_lan, the jaw
// points on vertices of their own (InputLandmark::model_vertex, ContourLandmarks), one of them not
// a vertex at all (left out by both).
TEST_F(VulkanSolverTest, OwnLandmarkVerticesAndBrowsMatchTheCpu) {
  const TrackerModel& model = model_for_tests();
  const gpu::FaceParameters truth = truth_for_tests();
  InputFrame frame = RenderSyntheticFrame(cpu().renderer(), model, truth, test_camera(160, 120));
  frame.depth.clear();
  std::array<int, 68> contour{};
  contour.fill(-1);
  for (const auto& l : ContourLandmarks(model, truth, frame.camera)) contour[static_cast<size_t>(l.ibug_index)] = l.vertex;
  int own = 0;
  for (auto& l : frame.landmarks) {
    if (l.ibug_index < 17) l.model_vertex = contour[static_cast<size_t>(l.ibug_index)], own += l.confidence > 0;
    if (l.ibug_index == 5) l.model_vertex = model.num_vertices();  // not a vertex
  }
  ASSERT_GT(own, 4);
  ParameterLayout layout = ParameterLayout::Tracking(model.num_expression());
  SolverOptions options;
  options.energy.use_color = false;
  options.energy.inner_landmarks_only = false;
  options.energy.use_brow_landmarks = true;
  options.schedule = {{1, 3, 4}};
  gpu::FaceParameters start = truth;
  start.euler += Eigen::Vector3f(0.02f, -0.02f, 0.01f);
  gpu::FaceParameters cpu_fit = start, fit = start;
  const SolverSummary c = cpu().Solve(frame, layout, options, &cpu_fit);
  const SolverSummary g = solver().Solve(frame, layout, options, &fit);
  ASSERT_EQ(g.termination, c.termination) << g.FullReport() << "\n" << c.FullReport();
  ASSERT_FALSE(g.iterations.empty());
  EXPECT_EQ(g.iterations[0].residuals, c.iterations[0].residuals);
  EXPECT_NEAR(g.initial_energy[Term::kLandmark], c.initial_energy[Term::kLandmark], 1e-4 * c.initial_energy.total());
  EXPECT_LT(rotation_error(fit, cpu_fit), 0.05 * M_PI / 180);
}

// TrackerOptions::solver is what a FaceTracker solves with: kAuto keeps the CPU solver where the
// only Vulkan device is a CPU implementation, kVulkan takes the device, and a device that is not
// there is a clear error for a forced choice.
TEST(TrackerSolverOption, TheTrackerSolvesWithTheSolverItsOptionsName) {
  if (!real_model()) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  TrackerOptions o;
  EXPECT_EQ(o.solver, SolverBackend::kCpu);
  {
    FaceTracker cpu(*real_model(), o);
    EXPECT_EQ(cpu.solver_description(), "cpu (forced)");
    EXPECT_FALSE(cpu.solves_on_gpu());
  }
  o.solver_device = "llvmpipe";
  o.solver = SolverBackend::kAuto;
  {
    FaceTracker automatic(*real_model(), o);
    EXPECT_EQ(automatic.solver_description().rfind("cpu (auto: ", 0), 0u) << automatic.solver_description();
    EXPECT_NE(automatic.solver_description().find("llvmpipe"), std::string::npos) << automatic.solver_description();
    EXPECT_FALSE(automatic.solves_on_gpu());
  }
  o.solver = SolverBackend::kVulkan;
  {
    FaceTracker forced(*real_model(), o);
    EXPECT_EQ(forced.solver_description().rfind("vulkan on llvmpipe", 0), 0u) << forced.solver_description();
    EXPECT_TRUE(forced.solves_on_gpu());
    forced.SetTrackingSolver({});  // the program takes the solve back to the CPU
    EXPECT_FALSE(forced.solves_on_gpu());
  }
  o.solver_device = "no-such-vulkan-device";
  try {
    FaceTracker t(*real_model(), o);
    ADD_FAILURE() << "a forced Vulkan solver on a missing device was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("no usable Vulkan device for the tracker"), std::string::npos) << e.what();
  }
}

// `face-reenact bench track` reports the Vulkan strategies next to the CPU reference.
TEST(VulkanTrackBenchCli, ReportsBothStrategiesTheAutoChoiceAndRatios) {
  const std::string model = testing::real_model_path();
  if (model.empty()) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const char* cli = std::getenv("FR_CLI");
  ASSERT_NE(cli, nullptr);
  int status = -1;
  const std::string out = testing::run_shell_command(std::string("FR_VULKAN_DEVICE=llvmpipe ") + cli + " bench track --model " + model +
                                          " --frames 1 --width 160 --height 120 --json 2>/dev/null",
                                      &status);
  ASSERT_EQ(status, 0) << out;
  const auto doc = nlohmann::json::parse(out);
  ASSERT_FALSE(doc["vulkan"].contains("error")) << doc["vulkan"].dump();
  EXPECT_NE(std::string(doc["vulkan"]["device"]).find("llvmpipe"), std::string::npos);
  const double cpu_energy = doc["solvers"]["cpu_matrix_free"]["mean_final_energy"];
  for (const char* name : {"vulkan_matrix_free", "vulkan_matrix_free_host_loop", "vulkan_assembled", "vulkan_auto"}) {
    const auto& s = doc["solvers"][name];
    ASSERT_EQ(s["levels"].size(), 2u) << name << ": " << out;
    EXPECT_EQ(s["levels"][0]["level"], 2);
    EXPECT_GT(double(s["levels"][0]["residuals"]), 50.0);
    EXPECT_GT(double(s["levels"][0]["analysis_ms_per_frame"]), 0.0);
    EXPECT_GT(double(s["total_ms_per_frame"]), 0.0);
    // 0.5 %: on this one 160x120 frame a step is accepted or halved once more depending on the
    // order of the device's float sums (its rows are compacted with atomics), which ends at
    // 0.6995 or 0.7014 against the CPU's 0.6995 (one row in ten, with the builds before too).
    EXPECT_NEAR(double(s["mean_final_energy"]), cpu_energy, 5e-3 * std::max(1.0, cpu_energy)) << name;
    EXPECT_GT(double(doc["vulkan"]["ratio_to_cpu_matrix_free"][name]), 0.0);
    // Submissions (each a host sync) are counted: one per frame where the device drives the
    // loop, at least one per Gauss-Newton iteration where the host does.
    double iterations = 0;
    for (const auto& l : s["levels"]) iterations += double(l["gauss_newton_per_frame"]);
    if (std::string(name) == "vulkan_matrix_free_host_loop") {
      EXPECT_GE(double(s["device_submissions_per_frame"]), iterations) << name;
    } else {
      EXPECT_EQ(double(s["device_submissions_per_frame"]), 1.0) << name;
    }
    // The host's share of those submissions: recording their command buffers.
    EXPECT_GT(double(s["device_recording_ms_per_frame"]), 0.0) << name;
    EXPECT_LT(double(s["device_recording_ms_per_frame"]), double(s["device_submission_ms_per_frame"])) << name;
  }
  EXPECT_EQ(double(doc["solvers"]["cpu_matrix_free"]["device_recording_ms_per_frame"]), 0.0);
  EXPECT_GT(double(doc["vulkan"]["device_loop_over_host_loop"]), 0.0);
  EXPECT_EQ(double(doc["solvers"]["cpu_matrix_free"]["device_submissions_per_frame"]), 0.0);
  const std::string chosen = doc["vulkan"]["auto_choice"]["chosen"];
  EXPECT_TRUE(chosen == "matrix-free" || chosen == "assembled") << chosen;
  // The calibration row on the device: the same joint solve as the CPU's, to the same energy.
  const auto& calibration = doc["vulkan"]["calibration"];
  ASSERT_TRUE(calibration.is_object()) << doc["vulkan"].dump();
  EXPECT_EQ(calibration["unknowns"], doc["calibration"]["unknowns"]);
  EXPECT_GT(int(calibration["gauss_newton"]), 0);
  EXPECT_NEAR(double(calibration["final_energy"]), double(doc["calibration"]["final_energy"]),
              2e-3 * double(doc["calibration"]["final_energy"]));
  EXPECT_GT(double(doc["vulkan"]["calibration_ratio_to_cpu"]), 0.0);

  testing::run_shell_command(std::string(cli) + " bench track --model " + model + " --frames 1 --vulkan sideways 2>&1", &status);
  EXPECT_NE(status, 0);
}

}  // namespace
}  // namespace face_reenact::tracker
