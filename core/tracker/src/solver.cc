#include "face_reenact/tracker/solver.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <thread>
#include <utility>

#include "face_reenact/common/error.h"
#include "face_reenact/common/parallel.h"
#include "gauss_newton_loop.h"
#include "tracker_internal.h"

namespace face_reenact::tracker {
using internal::Clock;
namespace {
std::string energy_line(const TermEnergies& e) {
  char buf[256];
  std::snprintf(buf, sizeof(buf), "E=%.6g (point %.4g, plane %.4g, color %.4g, landmark %.4g, reg %.4g)", e.total(),
                e[Term::kPoint], e[Term::kPlane], e[Term::kColor], e[Term::kLandmark], e[Term::kRegularizer]);
  return buf;
}

// One frame's linearisation with its residuals and Jacobian.
struct FrameState {
  Linearization lin;
  Eigen::VectorXd r;
  JacobianMatrix j;
  bool has_jacobian = false;  // J is evaluated only when the loop says a step follows
  TermEnergies energy;
  // Per pyramid level, kept: every synthesis of this frame on a level reuses its memory and
  // clears only what the last one drew there (CpuSolver::SynthesisBuffers).
  std::vector<gpu::GBuffer> gbuffers;
};

// The Gauss-Newton loop's work on the CPU, for one frame or several frames solved jointly
// (calibration): x = [shared identity/albedo | frame 0's own | frame 1's own | ...].
class CpuGaussNewton final : public internal::GaussNewtonBackend {
 public:
  CpuGaussNewton(const TrackerModel& model, const gpu::CpuRenderer& renderer, const ParameterLayout& layout,
                 const SolverOptions& options, const std::vector<const std::vector<InputFrame>*>& pyramids,
                 const std::vector<gpu::FaceParameters>& bases, CpuSolver::FixedPartsCache* fixed_parts,
                 CpuSolver::SynthesisBuffers* buffers)
      : model_(model),
        renderer_(renderer),
        layout_(layout),
        options_(options),
        pyramids_(pyramids),
        bases_(bases),
        unknowns_(layout, static_cast<int>(pyramids.size())),
        threads_(options.ResolvedThreads()),
        fixed_parts_(fixed_parts),
        buffers_(buffers),
        states_(pyramids.size()),
        fixed_(pyramids.size()) {
    scratch_.Resize(unknowns_.size());
    b_.resize(unknowns_.size());
    if (!states_.empty()) states_[0].gbuffers = buffers_->Take();
  }
  ~CpuGaussNewton() override {
    if (!states_.empty()) buffers_->Give(std::move(states_[0].gbuffers));
  }
  CpuGaussNewton(const CpuGaussNewton&) = delete;
  CpuGaussNewton& operator=(const CpuGaussNewton&) = delete;

  // When a step follows, r and J are evaluated in one pass here (the step's time, booked by
  // SolveStep), not r now and r with J again for the step.
  internal::Linearized Linearize(const LevelSchedule& level, const Eigen::VectorXd& x, bool step_follows,
                                 double* synthesis_ms, double* analysis_ms) override {
    internal::Linearized out;
    out.has_data = true;
    for (size_t f = 0; f < states_.size(); ++f) {
      const InputFrame& frame = (*pyramids_[f])[level.level];
      const Eigen::VectorXd xf = unknowns_.FrameX(x, static_cast<int>(f));
      const auto t0 = Clock::now();
      const gpu::FaceParameters p = layout_.Unpack(xf, bases_[f]);
      // The synthesis' colours serve the robust colour weight alone, read where the colour follows
      // the projection (RGB-D: Linearize).
      const bool colors = ColorFollowsProjection(options_.energy, frame);
      const gpu::VertexState vs =
          renderer_.evaluate(p, nullptr, threads_, colors ? gpu::VertexColors::kShaded : gpu::VertexColors::kNone);
      FrameState& st = states_[f];
      // The synthesis' normals serve the depth terms alone (Linearize).
      gpu::RenderOptions render = options_.render;
      render.normals = UsesDepthTerms(options_.energy, frame);
      render.colors = colors;
      const size_t level_index = static_cast<size_t>(level.level);
      if (st.gbuffers.size() <= level_index) st.gbuffers.resize(level_index + 1);
      gpu::GBuffer& gbuffer = st.gbuffers[level_index];
      renderer_.rasterize(vs, frame.camera, render, &gbuffer, threads_);
      *synthesis_ms += ms_since(t0);
      const auto t1 = Clock::now();
      st.lin = tracker::Linearize(model_, layout_, p, vs, gbuffer, frame, options_.energy,
                                  /*regularize_shared=*/f == 0);
      if (layout_.num_identity == 0 && layout_.num_albedo == 0) {
        // Tracking: the identity shape and albedo stay the base's for the whole solve.
        if (!fixed_[f]) fixed_[f] = fixed_parts_->For(model_, bases_[f], threads_);
        st.lin.fixed = fixed_[f];
      } else if (SharesIdentity()) {
        if (f == 0) shared_parts_ = FixedModelPartsAt(model_, st.lin, xf, shared_parts_, threads_);
        st.lin.fixed = shared_parts_;
      }
      const auto t2 = Clock::now();
      st.has_jacobian = step_follows;
      EvaluateResiduals(model_, st.lin, options_.energy, xf, &st.r, st.has_jacobian ? &st.j : nullptr, &st.energy,
                        threads_);
      if (step_follows) {
        *analysis_ms += ms_since(t1, t2);
        step_ms_ += ms_since(t2);
      } else {
        *analysis_ms += ms_since(t1);
      }
      for (int t = 0; t < kNumTerms; ++t) out.energy.value[t] += st.energy.value[t];
      out.residuals += st.r.size();
      out.has_data = out.has_data && st.lin.term_rows[kNumTerms - 1] > 0;
    }
    return out;
  }

  void SolveStep(const LevelSchedule& level, const Eigen::VectorXd&, Eigen::VectorXd* dx,
                 IterationRecord* rec) override {
    const auto start = Clock::now();
    for (const FrameState& st : states_) {
      if (!st.has_jacobian) throw Error("CPU solver: a step was asked for that no linearisation prepared");
    }
    rec->analysis_ms += TakeUnusedStepMs();
    const Eigen::VectorXd* r = nullptr;
    const StackedJacobian j = System(&r);
    const PcgOptions pcg{level.pcg_iterations, options_.pcg_relative_tolerance};
    PcgSummary ps;
    if (options_.linear_solver == LinearSolverType::kAssembled) {
      j.MultiplyTransposed(*r, &b_);
      b_ = -b_;
      dx->setZero(b_.size());
      AssembledNormalOperator op(j, options_.damping);
      ps = Pcg(op, b_, pcg, &scratch_, dx);
    } else {
      // J^T r and the preconditioner's diag(J^T J) in one pass over J.
      j.MultiplyTransposedWithColumnSquaredNorms(*r, &b_, &column_norms_);
      b_ = -b_;
      dx->setZero(b_.size());
      MatrixFreeNormalOperator op(j, options_.damping, column_norms_);
      ps = Pcg(op, b_, pcg, &scratch_, dx);
    }
    rec->analysis_ms += ms_since(start);
    rec->pcg_iterations = ps.iterations;
    rec->pcg_relative_residual = ps.initial_residual_norm > 0 ? ps.final_residual_norm / ps.initial_residual_norm : 0;
  }

  double TakeUnusedStepMs() override { return std::exchange(step_ms_, 0.0); }

  double TrialEnergy(int /*halving*/, const Eigen::VectorXd& x_try) override {
    if (SharesIdentity()) {
      // The trial identity's parts, once for every frame (and the next linearisation's, where the
      // step is taken).
      shared_parts_ =
          FixedModelPartsAt(model_, states_[0].lin, unknowns_.FrameX(x_try, 0), shared_parts_, threads_);
      for (FrameState& st : states_) st.lin.fixed = shared_parts_;
    }
    double total = 0;
    for (size_t f = 0; f < states_.size(); ++f) {
      TermEnergies e;
      EvaluateResiduals(model_, states_[f].lin, options_.energy, unknowns_.FrameX(x_try, static_cast<int>(f)), &trial_r_, nullptr,
                        &e, threads_);
      total += e.total();
    }
    return total;
  }

 private:
  // A calibration: several frames solving one identity. Their evaluations at a step's coefficients
  // share one set of its per-vertex parts (all the model's vertices at once, where each frame's
  // evaluation made those of its own pixels' vertices: 7.6 % of a calibration's time, measured on
  // d12). A frame whose coefficients differ (none: the identity is x's shared block) makes its own.
  bool SharesIdentity() const { return states_.size() > 1 && (layout_.num_identity > 0 || layout_.num_albedo > 0); }

  // The joint system: the frames' Jacobian blocks as they are (no zeros stored), their
  // residuals stacked in the same row order (no copy with one frame).
  StackedJacobian System(const Eigen::VectorXd** r) {
    if (states_.size() == 1) {
      *r = &states_[0].r;
      StackedJacobian j(states_[0].j);
      j.SetThreads(threads_);
      return j;
    }
    StackedJacobian j(unknowns_.shared(), unknowns_.own());
    j.SetThreads(threads_);
    Eigen::Index rows = 0;
    for (const FrameState& st : states_) rows += st.r.size();
    stacked_r_.resize(rows);
    Eigen::Index row = 0;
    for (const FrameState& st : states_) {
      j.AddFrame(st.j);
      stacked_r_.segment(row, st.r.size()) = st.r;
      row += st.r.size();
    }
    *r = &stacked_r_;
    return j;
  }

  const TrackerModel& model_;
  const gpu::CpuRenderer& renderer_;
  const ParameterLayout& layout_;
  const SolverOptions& options_;
  const std::vector<const std::vector<InputFrame>*>& pyramids_;
  const std::vector<gpu::FaceParameters>& bases_;
  const internal::JointUnknowns unknowns_;
  const int threads_;
  CpuSolver::FixedPartsCache* fixed_parts_;
  CpuSolver::SynthesisBuffers* buffers_;
  std::vector<FrameState> states_;
  // Per frame, taken on its first linearisation when the layout solves neither identity nor albedo
  // (the solver keeps the last identity's: CpuSolver::FixedPartsCache).
  std::vector<std::shared_ptr<const FixedModelParts>> fixed_;
  std::shared_ptr<const FixedModelParts> shared_parts_;  // SharesIdentity(): the last x's
  PcgScratch scratch_;
  Eigen::VectorXd b_, column_norms_, stacked_r_, trial_r_;
  double step_ms_ = 0;  // J evaluated by Linearize for the coming step
};

}  // namespace

const char* termination_name(Termination t) {
  switch (t) {
    case Termination::kScheduleDone: return "schedule done";
    case Termination::kNoValidResiduals: return "no valid residuals";
    case Termination::kNoProgress: return "no progress";
    case Termination::kNonFinite: return "non-finite step";
    case Termination::kStopped: return "stopped";
  }
  return "?";
}

bool SolverOptions::IsValid(std::string* why) const {
  if (!energy.IsValid(why) || !pyramid.IsValid(why) || !render.IsValid(why)) return false;
  if (schedule.empty()) return fail_why(why, "solver: the level schedule is empty");
  for (const auto& s : schedule) {
    if (s.level < 0 || s.level >= pyramid.levels) {
      return fail_why(why, "solver: scheduled level " + std::to_string(s.level) + " is outside the " +
                           std::to_string(pyramid.levels) + "-level pyramid");
    }
    if (s.gauss_newton_iterations < 0 || s.gauss_newton_iterations > 1000) return fail_why(why, "solver: Gauss-Newton iterations must be 0..1000");
    if (s.pcg_iterations < 1 || s.pcg_iterations > 10000) return fail_why(why, "solver: PCG iterations must be 1..10000");
  }
  if (!(damping >= 0) || !std::isfinite(damping)) return fail_why(why, "solver: damping must be finite and non-negative");
  if (max_step_halvings < 0 || max_step_halvings > 30) return fail_why(why, "solver: max_step_halvings must be 0..30");
  if (!(function_tolerance >= 0)) return fail_why(why, "solver: function_tolerance must be non-negative");
  if (!(pcg_relative_tolerance >= 0)) return fail_why(why, "solver: pcg_relative_tolerance must be non-negative");
  if (threads < 0 || threads > 64) return fail_why(why, "solver: threads must be 0..64 (0 = one per hardware thread)");
  return true;
}

int SolverOptions::ResolvedThreads() const { return ResolvedThreadCount(threads); }

bool SolverOptions::SolvesFullResolution() const {
  return std::any_of(schedule.begin(), schedule.end(), [](const LevelSchedule& l) { return l.level == 0; });
}

std::string SolverSummary::BriefReport() const {
  char buf[160];
  std::snprintf(buf, sizeof(buf), "%zu iterations, %.1f ms (synthesis %.1f, analysis %.1f): ", iterations.size(), total_ms,
                synthesis_ms, analysis_ms);
  return std::string(buf) + termination_name(termination) + "; " + energy_line(initial_energy) + " -> " +
         energy_line(final_energy);
}

std::string SolverSummary::FullReport() const {
  std::string out = BriefReport() + "\n" + message + "\n";
  char buf[320];
  for (const auto& it : iterations) {
    std::snprintf(buf, sizeof(buf),
                  "level %d it %d: %lld residuals, E %.6g -> %.6g, pcg %d (rel %.2e), |dx| %.3g, halvings %d, "
                  "synthesis %.2f ms, analysis %.2f ms\n",
                  it.level, it.iteration, static_cast<long long>(it.residuals), it.energy_before.total(),
                  it.energy_after.total(), it.pcg_iterations, it.pcg_relative_residual, it.step_norm, it.step_halvings,
                  it.synthesis_ms, it.analysis_ms);
    out += buf;
  }
  return out;
}

std::shared_ptr<const FixedModelParts> CpuSolver::FixedPartsCache::For(const TrackerModel& model,
                                                                       const gpu::FaceParameters& params, int threads) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (last_ && internal::same_coefficients(last_->alpha, internal::padded(params.alpha, model.num_identity())) &&
        internal::same_coefficients(last_->beta, internal::padded(params.beta, model.num_albedo())))
      return last_;
  }
  auto parts = std::make_shared<const FixedModelParts>(ComputeFixedModelParts(model, params, threads));
  std::lock_guard<std::mutex> lock(mutex_);
  last_ = parts;
  return parts;
}

std::vector<gpu::GBuffer> CpuSolver::SynthesisBuffers::Take() {
  std::lock_guard<std::mutex> lock(mutex_);
  return std::exchange(kept_, {});
}

void CpuSolver::SynthesisBuffers::Give(std::vector<gpu::GBuffer> levels) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (kept_.empty()) kept_ = std::move(levels);  // else a solve beside this one kept its own
}

CpuSolver::CpuSolver(TrackerModel model) : model_(std::move(model)), renderer_(model_.render) {
  std::string why;
  if (!model_.IsValid(&why)) throw Error("tracker: " + why);
}

Linearization CpuSolver::LinearizeAt(const InputFrame& frame, const ParameterLayout& layout, const EnergyOptions& options,
                                     const gpu::FaceParameters& params, const gpu::RenderOptions& render) const {
  const gpu::VertexState state = renderer_.evaluate(params);
  const gpu::GBuffer g = renderer_.rasterize(state, frame.camera, render);
  return Linearize(model_, layout, params, state, g, frame, options);
}

TermEnergies CpuSolver::Energy(const InputFrame& frame, const ParameterLayout& layout, const EnergyOptions& options,
                               const gpu::FaceParameters& params, const gpu::RenderOptions& render) const {
  const Linearization lin = LinearizeAt(frame, layout, options, params, render);
  TermEnergies e;
  Eigen::VectorXd r;
  EvaluateResiduals(model_, lin, options, layout.Pack(params), &r, nullptr, &e);
  return e;
}

SolverSummary SolveOnPyramidOf(const InputFrame& frame, const SolverOptions& options,
                               const std::function<SolverSummary(const std::vector<InputFrame>& pyramid)>& solve) {
  std::string why;
  if (!options.IsValid(&why)) throw Error(why);
  const auto start = Clock::now();
  const std::vector<InputFrame> pyramid =
      BuildPyramid(frame, options.pyramid, options.ResolvedThreads(), options.SolvesFullResolution());
  const double pyramid_ms = ms_since(start);
  SolverSummary s = solve(pyramid);
  s.pyramid_ms = pyramid_ms;
  s.total_ms += pyramid_ms;
  return s;
}

SolverSummary CpuSolver::Solve(const InputFrame& frame, const ParameterLayout& layout, const SolverOptions& options,
                               gpu::FaceParameters* params) const {
  return SolveOnPyramidOf(frame, options, [&](const std::vector<InputFrame>& pyramid) {
    return Solve(pyramid, layout, options, params);
  });
}

SolverSummary CpuSolver::Solve(const std::vector<InputFrame>& pyramid, const ParameterLayout& layout,
                               const SolverOptions& options, gpu::FaceParameters* params) const {
  std::vector<gpu::FaceParameters> one{*params};
  SolverSummary s = SolvePyramids({&pyramid}, layout, options, &one);
  *params = one[0];
  return s;
}

SolverSummary CpuSolver::SolveFrames(const std::vector<InputFrame>& frames, const ParameterLayout& layout,
                                     const SolverOptions& options, std::vector<gpu::FaceParameters>* params) const {
  std::string why;
  if (!options.IsValid(&why)) throw Error(why);
  if (frames.empty()) throw Error("calibration: no frames");
  const internal::FramePyramids pyramids = internal::BuildFramePyramids(frames, options);
  SolverSummary s = SolvePyramids(pyramids.pointers, layout, options, params);
  s.pyramid_ms = pyramids.ms;
  s.total_ms += pyramids.ms;
  return s;
}

SolverSummary CpuSolver::SolvePyramids(const std::vector<const std::vector<InputFrame>*>& pyramids,
                                       const ParameterLayout& layout, const SolverOptions& options,
                                       std::vector<gpu::FaceParameters>* params) const {
  internal::CheckJointSolve(model_, layout, options, pyramids, *params);
  const auto start = Clock::now();
  const internal::JointUnknowns unknowns(layout, static_cast<int>(pyramids.size()));
  const std::vector<gpu::FaceParameters> bases = *params;
  Eigen::VectorXd x = unknowns.Pack(bases);
  CpuGaussNewton backend(model_, renderer_, layout, options, pyramids, bases, &fixed_parts_, &synthesis_buffers_);
  SolverSummary summary = internal::RunGaussNewton(options, unknowns.ExpressionSpans(), unknowns.frames(), &backend, &x);
  for (int f = 0; f < unknowns.frames(); ++f) (*params)[f] = layout.Unpack(unknowns.FrameX(x, f), bases[f]);
  summary.total_ms = ms_since(start);
  return summary;
}

InputFrame RenderSyntheticFrame(const gpu::CpuRenderer& renderer, const TrackerModel& model,
                                const gpu::FaceParameters& params, const gpu::PinholeCamera& camera,
                                const gpu::RenderOptions& render, float background) {
  const gpu::VertexState st = renderer.evaluate(params);
  const gpu::GBuffer g = renderer.rasterize(st, camera, render);
  InputFrame f;
  f.camera = camera;
  const size_t n = static_cast<size_t>(camera.width) * camera.height;
  f.color.assign(3 * n, background);
  f.depth.assign(n, 0.f);
  for (size_t p = 0; p < n; ++p) {
    if (g.triangle[p] < 0) continue;
    for (int k = 0; k < 3; ++k) f.color[3 * p + k] = g.color[3 * p + k];
    f.depth[p] = g.position[3 * p + 2];
  }
  for (const auto& l : model.landmarks) {
    const Eigen::Vector3f x = st.camera_positions.segment<3>(3 * l.vertex);
    if (!(x.z() > camera.near_plane)) continue;
    InputLandmark in;
    in.ibug_index = l.ibug_index;
    in.position = Eigen::Vector2f(camera.fx * x.x() / x.z() + camera.cx, camera.fy * x.y() / x.z() + camera.cy);
    in.confidence = 1.0f;
    f.landmarks.push_back(in);
  }
  return f;
}

}  // namespace face_reenact::tracker
