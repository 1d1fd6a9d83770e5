// The Gauss-Newton loop both solvers share (core/tracker/src/gauss_newton_loop.h), driven by a
// scripted backend on E(x) = |x - target|^2, so that each of its rules is checked by itself:
// step halving, clamping, the terminations, a lost face, convergence and where time is booked.
// The CPU and Vulkan solver tests check the same loop on the real energy.
#include "gauss_newton_loop.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <stop_token>
#include <string>
#include <utility>

namespace face_reenact::tracker::internal {
namespace {

class QuadraticBackend final : public GaussNewtonBackend {
 public:
  explicit QuadraticBackend(Eigen::VectorXd target) : target_(std::move(target)) {}

  // Step = overshoot * (target - x): 1 is the exact Gauss-Newton step; 2.5 raises E at full
  // length and needs one halving; a negative factor points uphill at every length.
  double overshoot = 1.0;
  bool non_finite_step = false;
  double face_lost_beyond = std::numeric_limits<double>::infinity();  // x[0] past this: no data
  double step_ms = 3.0;                                               // booked by a fused pass
  int linearizations = 0, solves = 0, trials = 0;
  bool last_step_follows = false;

  double Energy(const Eigen::VectorXd& x) const { return (x - target_).squaredNorm(); }

  Linearized Linearize(const LevelSchedule&, const Eigen::VectorXd& x, bool step_follows, double* synthesis_ms,
                       double* analysis_ms) override {
    ++linearizations;
    last_step_follows = step_follows;
    *synthesis_ms += 1.0;
    *analysis_ms += 2.0;
    Linearized l;
    l.energy.value[static_cast<int>(Term::kPoint)] = Energy(x);
    l.residuals = x.size();
    l.has_data = x[0] <= face_lost_beyond;
    pending_ms_ = step_follows && l.has_data ? step_ms : 0.0;
    return l;
  }

  void SolveStep(const LevelSchedule&, const Eigen::VectorXd& x, Eigen::VectorXd* dx, IterationRecord* rec) override {
    ++solves;
    *dx = overshoot * (target_ - x);
    if (non_finite_step) (*dx)[0] = std::numeric_limits<double>::quiet_NaN();
    rec->analysis_ms += TakeUnusedStepMs();
    rec->pcg_iterations = 4;
  }

  double TrialEnergy(int, const Eigen::VectorXd& x_try) override {
    ++trials;
    return Energy(x_try);
  }

  double TakeUnusedStepMs() override { return std::exchange(pending_ms_, 0.0); }

 private:
  Eigen::VectorXd target_;
  double pending_ms_ = 0;
};

SolverOptions OneLevel(int gauss_newton_iterations) {
  SolverOptions o;
  o.schedule = {{0, gauss_newton_iterations, 4}};
  o.clamp_expression = false;
  return o;
}

TEST(GaussNewtonLoop, EveryIterationOfTheScheduleRunsAndIsRecorded) {
  QuadraticBackend b(Eigen::Vector2d(0.3, -0.2));
  b.overshoot = 0.5;  // each step halves the distance: E falls by 4x and never converges here
  SolverOptions o = OneLevel(5);
  Eigen::VectorXd x = Eigen::Vector2d(1.0, 1.0);
  const SolverSummary s = RunGaussNewton(o, {}, 1, &b, &x);
  EXPECT_EQ(s.termination, Termination::kScheduleDone) << s.message;
  EXPECT_NEAR(x[0], 0.3 + 0.7 / 32, 1e-12);
  EXPECT_NEAR(x[1], -0.2 + 1.2 / 32, 1e-12);
  ASSERT_EQ(s.iterations.size(), 5u);
  EXPECT_NEAR(s.initial_energy.total(), 0.49 + 1.44, 1e-12);
  EXPECT_NEAR(s.iterations[0].energy_after.total(), (0.49 + 1.44) / 4, 1e-12);
  EXPECT_NEAR(s.final_energy.total(), (0.49 + 1.44) / 1024, 1e-12);
  EXPECT_EQ(s.iterations[0].step_halvings, 0);
  EXPECT_EQ(s.iterations[0].residuals, 2);
  EXPECT_NE(s.message.find("5 of 5 steps accepted"), std::string::npos) << s.message;
  // One linearisation per level and one per accepted step; the last one solves nothing.
  EXPECT_EQ(b.linearizations, 6);
  EXPECT_FALSE(b.last_step_follows);
  // Every millisecond a backend books reaches the summary once: 6 x (1 synthesis + 2 analysis)
  // and the 5 fused steps (3 each); the step control's own time is on top.
  EXPECT_DOUBLE_EQ(s.synthesis_ms, 6.0);
  EXPECT_GE(s.analysis_ms, 6 * 2.0 + 5 * 3.0);
  EXPECT_LT(s.analysis_ms, 6 * 2.0 + 5 * 3.0 + 50.0);
}

TEST(GaussNewtonLoop, AStepThatRaisesTheEnergyIsHalved) {
  QuadraticBackend b(Eigen::Vector2d(0.0, 0.0));
  b.overshoot = 2.5;  // full step: E x 2.25; half step: E x 0.0625
  SolverOptions o = OneLevel(1);
  Eigen::VectorXd x = Eigen::Vector2d(1.0, 0.0);
  const SolverSummary s = RunGaussNewton(o, {}, 1, &b, &x);
  ASSERT_EQ(s.iterations.size(), 1u);
  EXPECT_EQ(s.iterations[0].step_halvings, 1);
  EXPECT_NEAR(x[0], -0.25, 1e-12);
  EXPECT_NEAR(s.iterations[0].step_norm, 1.25, 1e-12);
  EXPECT_EQ(b.trials, 2);
}

TEST(GaussNewtonLoop, WithoutHalvingsEveryStepIsTakenAsThePaperDoes) {
  QuadraticBackend b(Eigen::Vector2d(0.0, 0.0));
  b.overshoot = 2.5;
  SolverOptions o = OneLevel(1);
  o.max_step_halvings = 0;
  Eigen::VectorXd x = Eigen::Vector2d(1.0, 0.0);
  const SolverSummary s = RunGaussNewton(o, {}, 1, &b, &x);
  EXPECT_EQ(s.termination, Termination::kScheduleDone);
  EXPECT_NEAR(x[0], -1.5, 1e-12);  // the energy rose, and the step was kept
}

TEST(GaussNewtonLoop, ExpressionWeightsAreClampedToTheirRangeInEveryFrame) {
  // x = [shared | frame 0: 2 weights | frame 1: 2 weights]; the targets lie outside [0, 1].
  Eigen::VectorXd target(5);
  target << 3.0, 1.7, -0.4, 0.5, 2.0;
  QuadraticBackend b(target);
  SolverOptions o = OneLevel(3);
  o.clamp_expression = true;
  Eigen::VectorXd x = Eigen::VectorXd::Constant(5, 0.5);
  const SolverSummary s = RunGaussNewton(o, {{1, 2}, {3, 2}}, 2, &b, &x);
  EXPECT_NE(s.termination, Termination::kNonFinite) << s.message;
  EXPECT_NEAR(x[0], 3.0, 1e-12);  // not an expression weight
  EXPECT_DOUBLE_EQ(x[1], 1.0);
  EXPECT_DOUBLE_EQ(x[2], 0.0);
  EXPECT_NEAR(x[3], 0.5, 1e-12);
  EXPECT_DOUBLE_EQ(x[4], 1.0);
}

TEST(GaussNewtonLoop, AnUphillDirectionEndsWithNoProgressAndTheStartKept) {
  QuadraticBackend b(Eigen::Vector2d(0.0, 0.0));
  b.overshoot = -1.0;
  SolverOptions o = OneLevel(3);
  Eigen::VectorXd x = Eigen::Vector2d(1.0, 2.0);
  const SolverSummary s = RunGaussNewton(o, {}, 1, &b, &x);
  EXPECT_EQ(s.termination, Termination::kNoProgress) << s.message;
  EXPECT_EQ(x, Eigen::VectorXd(Eigen::Vector2d(1.0, 2.0)));
  ASSERT_EQ(s.iterations.size(), 1u);  // the level ends at the first rejected direction
  EXPECT_EQ(s.iterations[0].step_halvings, o.max_step_halvings);
  EXPECT_EQ(s.iterations[0].step_norm, 0.0);
  EXPECT_EQ(b.trials, o.max_step_halvings + 1);
}

TEST(GaussNewtonLoop, ANonFiniteStepStopsWithTheLastGoodParameters) {
  QuadraticBackend b(Eigen::Vector2d(0.0, 0.0));
  b.non_finite_step = true;
  SolverOptions o = OneLevel(3);
  Eigen::VectorXd x = Eigen::Vector2d(1.0, 2.0);
  const SolverSummary s = RunGaussNewton(o, {}, 1, &b, &x);
  EXPECT_EQ(s.termination, Termination::kNonFinite);
  EXPECT_EQ(x, Eigen::VectorXd(Eigen::Vector2d(1.0, 2.0)));
  ASSERT_EQ(s.iterations.size(), 1u);
  EXPECT_GE(s.analysis_ms, 2.0 + 3.0);  // the failed solve's time is booked too
  EXPECT_EQ(b.trials, 0);
}

TEST(GaussNewtonLoop, AStepThatLosesTheFaceIsUndone) {
  QuadraticBackend b(Eigen::Vector2d(2.0, 0.0));
  b.face_lost_beyond = 1.5;  // the step to x[0] = 2 moves the face out of the input
  SolverOptions o = OneLevel(3);
  Eigen::VectorXd x = Eigen::Vector2d(1.0, 1.0);
  const SolverSummary s = RunGaussNewton(o, {}, 1, &b, &x);
  EXPECT_EQ(s.termination, Termination::kNoValidResiduals);
  EXPECT_NE(s.message.find("moved the face out"), std::string::npos) << s.message;
  EXPECT_EQ(x, Eigen::VectorXd(Eigen::Vector2d(1.0, 1.0)));
}

TEST(GaussNewtonLoop, NoFaceAtTheStartSolvesNothingAndSaysWhichFrames) {
  QuadraticBackend b(Eigen::Vector2d(0.0, 0.0));
  b.face_lost_beyond = 0.5;
  SolverOptions o = OneLevel(3);
  Eigen::VectorXd x = Eigen::Vector2d(1.0, 1.0);
  SolverSummary s = RunGaussNewton(o, {}, 1, &b, &x);
  EXPECT_EQ(s.termination, Termination::kNoValidResiduals);
  EXPECT_TRUE(s.iterations.empty());
  EXPECT_EQ(b.solves, 0);
  EXPECT_EQ(s.message.find("at least one frame"), std::string::npos) << s.message;
  s = RunGaussNewton(o, {}, 3, &b, &x);
  EXPECT_NE(s.message.find("at least one frame"), std::string::npos) << s.message;
}

TEST(GaussNewtonLoop, ALevelEndsWhenAStepGainsLessThanTheTolerance) {
  QuadraticBackend b(Eigen::Vector2d(0.0, 0.0));
  SolverOptions o;
  o.schedule = {{2, 7, 4}, {1, 1, 4}};
  o.clamp_expression = false;
  o.function_tolerance = 1e-9;
  Eigen::VectorXd x = Eigen::Vector2d(1.0, 1.0);
  const SolverSummary s = RunGaussNewton(o, {}, 1, &b, &x);
  // Level 2: the exact step, then one that gains nothing; level 1: one step, nothing to gain.
  ASSERT_EQ(s.iterations.size(), 3u) << s.FullReport();
  EXPECT_EQ(s.iterations[0].level, 2);
  EXPECT_EQ(s.iterations[2].level, 1);
  EXPECT_EQ(s.termination, Termination::kScheduleDone);
}

TEST(GaussNewtonLoop, AStopEndsBeforeTheNextIterationAndBooksThePreparedStep) {
  QuadraticBackend b(Eigen::Vector2d(0.0, 0.0));
  std::stop_source stop;
  stop.request_stop();
  SolverOptions o = OneLevel(3);
  o.stop = stop.get_token();
  Eigen::VectorXd x = Eigen::Vector2d(1.0, 1.0);
  const SolverSummary s = RunGaussNewton(o, {}, 1, &b, &x);
  EXPECT_EQ(s.termination, Termination::kStopped);
  EXPECT_TRUE(s.iterations.empty());
  EXPECT_EQ(x, Eigen::VectorXd(Eigen::Vector2d(1.0, 1.0)));
  EXPECT_DOUBLE_EQ(s.analysis_ms, 2.0 + 3.0);  // the step prepared for iteration 0 is not lost
}

}  // namespace
}  // namespace face_reenact::tracker::internal
