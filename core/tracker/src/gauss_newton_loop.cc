#include "gauss_newton_loop.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "face_reenact/common/error.h"
#include "tracker_internal.h"

namespace face_reenact::tracker::internal {
namespace {

// True when options.stop was requested, with the summary's termination and message set.
bool EndIfStopRequested(const SolverOptions& options, int level, int iteration, SolverSummary* summary) {
  if (!options.stop.stop_requested()) return false;
  summary->termination = Termination::kStopped;
  summary->message += "level " + std::to_string(level) + ": stopped before iteration " + std::to_string(iteration) +
                      " (stop requested); parameters of the last accepted step";
  return true;
}

}  // namespace

std::string LevelConvergedWords(int level, int iteration) {
  return "level " + std::to_string(level) + " converged at iteration " + std::to_string(iteration) +
         " (no step along the Gauss-Newton direction lowered the energy); ";
}

std::string NoDataWords(int level, int frames) {
  return "level " + std::to_string(level) + ": no pixel or landmark of the input overlaps the rendered face" +
         (frames > 1 ? " in at least one frame" : "") + "; parameters left unchanged";
}

std::string StepLostFaceWords(int level) {
  return "level " + std::to_string(level) + ": a step moved the face out of the input; kept the parameters before it";
}

std::string NonFiniteWords(int level, int iteration) {
  return "level " + std::to_string(level) + " iteration " + std::to_string(iteration) +
         ": the linear solve produced a non-finite step; kept the last good parameters";
}

void FinishSummary(int schedule_levels, int accepted_steps, int attempted_steps, SolverSummary* summary) {
  if (attempted_steps > 0 && accepted_steps == 0) {
    summary->termination = Termination::kNoProgress;
    summary->message += "no Gauss-Newton step lowered the energy: the start is already a (local) minimum";
  } else {
    summary->message += "ran the schedule of " + std::to_string(schedule_levels) + " level(s), " +
                        std::to_string(accepted_steps) + " of " + std::to_string(attempted_steps) + " steps accepted";
  }
}

void ClampExpressions(const SolverOptions& options, const std::vector<ExpressionSpan>& expressions, Eigen::VectorXd* x) {
  if (!options.clamp_expression) return;
  for (const ExpressionSpan& span : expressions) {
    for (int q = 0; q < span.count; ++q) {
      double& d = (*x)[span.offset + q];
      d = std::clamp(d, 0.0, 1.0);
    }
  }
}

JointUnknowns::JointUnknowns(const ParameterLayout& layout, int frames)
    : layout_(layout),
      shared_(layout.num_identity + layout.num_albedo),
      own_(layout.num_parameters() - shared_),
      frames_(frames) {}

Eigen::VectorXd JointUnknowns::Pack(const std::vector<gpu::FaceParameters>& params) const {
  Eigen::VectorXd x(size());
  x.head(shared_) = layout_.Pack(params[0]).head(shared_);
  for (int f = 0; f < frames_; ++f) x.segment(shared_ + f * own_, own_) = layout_.Pack(params[f]).tail(own_);
  return x;
}

Eigen::VectorXd JointUnknowns::FrameX(const Eigen::VectorXd& x, int f) const {
  Eigen::VectorXd out(shared_ + own_);
  out.head(shared_) = x.head(shared_);
  out.tail(own_) = x.segment(shared_ + f * own_, own_);
  return out;
}

std::vector<ExpressionSpan> JointUnknowns::ExpressionSpans() const {
  std::vector<ExpressionSpan> spans;
  for (int f = 0; f < frames_; ++f) spans.push_back({Global(layout_.offset(Block::kExpression), f), layout_.num_expression});
  return spans;
}

FramePyramids BuildFramePyramids(const std::vector<InputFrame>& frames, const SolverOptions& options) {
  const auto start = Clock::now();
  FramePyramids out;
  out.pyramids.reserve(frames.size());
  for (const InputFrame& f : frames) {
    out.pyramids.push_back(BuildPyramid(f, options.pyramid, options.ResolvedThreads(), options.SolvesFullResolution()));
  }
  for (const auto& p : out.pyramids) out.pointers.push_back(&p);
  out.ms = ms_since(start);
  return out;
}

void CheckJointSolve(const TrackerModel& model, const ParameterLayout& layout, const SolverOptions& options,
                     const std::vector<const std::vector<InputFrame>*>& pyramids,
                     const std::vector<gpu::FaceParameters>& params) {
  std::string why;
  if (!options.IsValid(&why)) throw Error(why);
  if (!layout.IsValid(&why, model.num_identity(), model.num_albedo(), model.num_expression())) throw Error(why);
  if (pyramids.empty()) throw Error("calibration: no frames");
  if (params.size() != pyramids.size()) {
    throw Error("calibration: " + std::to_string(pyramids.size()) + " frames but " + std::to_string(params.size()) +
                " parameter sets");
  }
  const int num_frames = static_cast<int>(pyramids.size());
  for (int f = 0; f < num_frames; ++f) {
    if (!params[f].IsValid(&why, model.num_identity(), model.num_expression(), model.num_albedo())) {
      throw Error("tracker start parameters" + (num_frames > 1 ? " of frame " + std::to_string(f) : std::string()) + ": " + why);
    }
    for (const auto& level : options.schedule) {
      if (level.level >= static_cast<int>(pyramids[f]->size())) {
        throw Error("solver: the pyramid has fewer levels than the schedule uses");
      }
      if (!(*pyramids[f])[level.level].IsValid(&why)) throw Error(why);
    }
  }
}

SolverSummary RunGaussNewton(const SolverOptions& options, const std::vector<ExpressionSpan>& expressions, int frames,
                             GaussNewtonBackend* backend, Eigen::VectorXd* x) {
  SolverSummary summary;
  auto keep = [&](const IterationRecord& rec) {
    summary.iterations.push_back(rec);
    summary.synthesis_ms += rec.synthesis_ms;
    summary.analysis_ms += rec.analysis_ms;
  };
  int accepted_steps = 0, attempted_steps = 0;
  bool first_level = true, stop_all = false;
  Eigen::VectorXd dx, x_try;
  for (const LevelSchedule& level : options.schedule) {
    Linearized lin = backend->Linearize(level, *x, level.gauss_newton_iterations > 0, &summary.synthesis_ms,
                                        &summary.analysis_ms);
    TermEnergies energy = lin.energy;
    if (first_level) summary.initial_energy = energy;
    first_level = false;
    summary.final_energy = energy;
    if (!lin.has_data) {
      summary.termination = Termination::kNoValidResiduals;
      summary.message += NoDataWords(level.level, frames);
      stop_all = true;
      break;
    }
    for (int it = 0; it < level.gauss_newton_iterations; ++it) {
      if (EndIfStopRequested(options, level.level, it, &summary)) {
        stop_all = true;
        break;
      }
      ++attempted_steps;
      IterationRecord rec;
      rec.level = level.level;
      rec.iteration = it;
      rec.energy_before = energy;
      rec.residuals = lin.residuals;
      backend->SolveStep(level, *x, &dx, &rec);
      if (!dx.allFinite()) {
        summary.termination = Termination::kNonFinite;
        summary.message += NonFiniteWords(level.level, it);
        keep(rec);
        stop_all = true;
        break;
      }
      // Step control on the energy with this step's correspondences held (the function the
      // Gauss-Newton step models): comparing energies of different renders would mix in the
      // change of the pixel set, which is not what the step optimises. Costs no rendering.
      const double before = energy.total();
      bool accepted = false;
      double scale = 1.0, linear_energy = 0.0;
      const auto t_control = Clock::now();
      for (int h = 0; h <= options.max_step_halvings; ++h, scale *= 0.5) {
        x_try = *x + scale * dx;
        ClampExpressions(options, expressions, &x_try);
        linear_energy = backend->TrialEnergy(h, x_try);
        rec.step_halvings = h;
        if ((std::isfinite(linear_energy) && linear_energy <= before) || options.max_step_halvings == 0) {
          accepted = true;
          break;
        }
      }
      rec.analysis_ms += ms_since(t_control);
      rec.step_norm = accepted ? (x_try - *x).norm() : 0.0;
      if (!accepted) {
        rec.energy_after = energy;
        keep(rec);
        summary.message += LevelConvergedWords(level.level, it);
        break;  // next level
      }
      ++accepted_steps;
      const bool converged = before - linear_energy <= options.function_tolerance * before;
      const Eigen::VectorXd x_before = *x;
      *x = x_try;
      // The next synthesis: re-render at the new parameters and linearise there.
      lin = backend->Linearize(level, *x, !converged && it + 1 < level.gauss_newton_iterations, &rec.synthesis_ms,
                               &rec.analysis_ms);
      energy = lin.energy;
      rec.energy_after = energy;
      keep(rec);
      summary.final_energy = energy;
      if (!lin.has_data) {
        *x = x_before;  // a step that loses the face is not kept
        summary.termination = Termination::kNoValidResiduals;
        summary.message += StepLostFaceWords(level.level);
        stop_all = true;
        break;
      }
      if (converged) break;  // on this level
    }
    summary.analysis_ms += backend->TakeUnusedStepMs();
    if (stop_all) break;
  }
  if (!stop_all) FinishSummary(static_cast<int>(options.schedule.size()), accepted_steps, attempted_steps, &summary);
  return summary;
}

}  // namespace face_reenact::tracker::internal
