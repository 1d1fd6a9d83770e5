#pragma once
// The Gauss-Newton loop both solvers run (Sec. 6.1), in one place: per scheduled level,
// linearise at x (synthesis, then analysis), solve the step, take the largest of the steps
// dx, dx/2, dx/4, ... that lowers the energy with the step's correspondences held, and
// linearise again there. The CPU and the Vulkan solver differ only in where that work runs,
// so each supplies it as a GaussNewtonBackend; the step control, the per-iteration records,
// the terminations and the summary's wording are this loop's alone.
#include <Eigen/Core>

#include <vector>

#include "face_reenact/tracker/solver.h"

namespace face_reenact::tracker::internal {

// What one linearisation found.
struct Linearized {
  TermEnergies energy;         // at the linearisation point
  Eigen::Index residuals = 0;  // rows of the system a step would solve
  bool has_data = false;       // every frame has a pixel or landmark on the rendered face
};

class GaussNewtonBackend {
 public:
  virtual ~GaussNewtonBackend() = default;
  // Renders at x on `level` and linearises there, adding the times. `step_follows`: the loop
  // solves a step from this linearisation next, unless a stop is requested or it has no data
  // (a backend may compute that step now, in the same pass).
  virtual Linearized Linearize(const LevelSchedule& level, const Eigen::VectorXd& x, bool step_follows,
                               double* synthesis_ms, double* analysis_ms) = 0;
  // The Gauss-Newton step from the last linearisation: sets *dx and rec's PCG fields, adds the
  // solve's time to rec->analysis_ms.
  virtual void SolveStep(const LevelSchedule& level, const Eigen::VectorXd& x, Eigen::VectorXd* dx,
                         IterationRecord* rec) = 0;
  // The energy at x_try with the last linearisation's correspondences; x_try is
  // x + 0.5^halving dx with the expression weights clamped when the options ask.
  virtual double TrialEnergy(int halving, const Eigen::VectorXd& x_try) = 0;
  // Analysis time of a step computed for an iteration that did not run (a stop request), which
  // the loop adds to the summary at the end of the level.
  virtual double TakeUnusedStepMs() { return 0; }
};


// Where x holds expression weights, clamped to [0, 1] when options.clamp_expression.
struct ExpressionSpan {
  int offset = 0;
  int count = 0;
};

// Projects the expression weights of x onto [0, 1] when options.clamp_expression: the loop does
// it to every trial point, and a backend forming the loop's trial points ahead does the same.
void ClampExpressions(const SolverOptions& options, const std::vector<ExpressionSpan>& expressions, Eigen::VectorXd* x);

// The unknowns of a joint solve over several frames (calibration, Sec. 6.3), as both solvers
// lay them out: x = [shared identity/albedo (S) | frame 0's own (P) | frame 1's own | ...], each
// frame's own being its expression, lighting and pose; with one frame exactly the layout's x.
class JointUnknowns {
 public:
  JointUnknowns(const ParameterLayout& layout, int frames);
  int shared() const { return shared_; }
  int own() const { return own_; }
  int frames() const { return frames_; }
  int size() const { return shared_ + frames_ * own_; }
  // x from the frames' parameters (the shared blocks from frame 0's).
  Eigen::VectorXd Pack(const std::vector<gpu::FaceParameters>& params) const;
  // Frame f's unknowns in the layout's order (shared, then its own).
  Eigen::VectorXd FrameX(const Eigen::VectorXd& x, int f) const;
  // Where frame f's local unknown `local` (layout order) sits in x.
  int Global(int local, int f) const { return local < shared_ ? local : shared_ + f * own_ + (local - shared_); }
  // Each frame's expression weights in x (clamped to [0, 1] by the loop).
  std::vector<ExpressionSpan> ExpressionSpans() const;

 private:
  ParameterLayout layout_;
  int shared_, own_, frames_;
};

// Every frame's pyramid (BuildPyramid with options.pyramid and its threads), pointers to them in
// frame order, and the time it took. Throws face_reenact::Error on a frame BuildPyramid refuses.
struct FramePyramids {
  std::vector<std::vector<InputFrame>> pyramids;
  std::vector<const std::vector<InputFrame>*> pointers;
  double ms = 0;
};
FramePyramids BuildFramePyramids(const std::vector<InputFrame>& frames, const SolverOptions& options);

// The checks every joint solve makes before it starts, with the CPU solver's messages: valid
// options and layout, one start per frame, valid start parameters, and every scheduled level
// present and valid in every frame's pyramid. Throws face_reenact::Error.
void CheckJointSolve(const TrackerModel& model, const ParameterLayout& layout, const SolverOptions& options,
                     const std::vector<const std::vector<InputFrame>*>& pyramids,
                     const std::vector<gpu::FaceParameters>& params);

// The summary's words for each way a level or the solve ends, appended to summary.message:
// RunGaussNewton's, and the Vulkan solver's device-driven loop (which makes the same decisions on
// the device) reports its events in the same words. `frames` > 1 only changes the wording of a
// face-less frame.
std::string LevelConvergedWords(int level, int iteration);
std::string NoDataWords(int level, int frames);
std::string StepLostFaceWords(int level);
std::string NonFiniteWords(int level, int iteration);
// The solve's last words when nothing stopped it: kNoProgress when steps were tried and none was
// accepted, else the schedule's count of accepted steps.
void FinishSummary(int schedule_levels, int accepted_steps, int attempted_steps, SolverSummary* summary);

// Runs options.schedule from *x (validated by the caller) and leaves the parameters of the
// last accepted step in *x. `frames` > 1 only changes the wording of a face-less frame.
SolverSummary RunGaussNewton(const SolverOptions& options, const std::vector<ExpressionSpan>& expressions, int frames,
                             GaussNewtonBackend* backend, Eigen::VectorXd* x);

}  // namespace face_reenact::tracker::internal
