#include "face_reenact/tracker/solver.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <thread>

#include "face_reenact/common/error.h"
#include "tracker_internal.h"

namespace face_reenact::tracker {
using internal::fail;
using internal::Clock;
namespace {
std::string energy_line(const TermEnergies& e) {
  char buf[256];
  std::snprintf(buf, sizeof(buf), "E=%.6g (point %.4g, plane %.4g, color %.4g, landmark %.4g, reg %.4g)", e.total(),
                e[Term::kPoint], e[Term::kPlane], e[Term::kColor], e[Term::kLandmark], e[Term::kRegularizer]);
  return buf;
}

// One linearisation with its residuals and Jacobian.
struct State {
  Linearization lin;
  Eigen::VectorXd r;
  JacobianMatrix j;
  bool has_jacobian = false;  // J is evaluated only when a step is solved from this state
  TermEnergies energy;
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
  if (schedule.empty()) return fail(why, "solver: the level schedule is empty");
  for (const auto& s : schedule) {
    if (s.level < 0 || s.level >= pyramid.levels) {
      return fail(why, "solver: scheduled level " + std::to_string(s.level) + " is outside the " +
                           std::to_string(pyramid.levels) + "-level pyramid");
    }
    if (s.gauss_newton_iterations < 0 || s.gauss_newton_iterations > 1000) return fail(why, "solver: Gauss-Newton iterations must be 0..1000");
    if (s.pcg_iterations < 1 || s.pcg_iterations > 10000) return fail(why, "solver: PCG iterations must be 1..10000");
  }
  if (!(damping >= 0) || !std::isfinite(damping)) return fail(why, "solver: damping must be finite and non-negative");
  if (max_step_halvings < 0 || max_step_halvings > 30) return fail(why, "solver: max_step_halvings must be 0..30");
  if (!(function_tolerance >= 0)) return fail(why, "solver: function_tolerance must be non-negative");
  if (!(pcg_relative_tolerance >= 0)) return fail(why, "solver: pcg_relative_tolerance must be non-negative");
  if (threads < 0 || threads > 64) return fail(why, "solver: threads must be 0..64 (0 = one per hardware thread)");
  return true;
}

bool internal::EndIfStopRequested(const SolverOptions& options, int level, int iteration, SolverSummary* summary) {
  if (!options.stop.stop_requested()) return false;
  summary->termination = Termination::kStopped;
  summary->message += "level " + std::to_string(level) + ": stopped before iteration " + std::to_string(iteration) +
                      " (stop requested); parameters of the last accepted step";
  return true;
}

int SolverOptions::ResolvedThreads() const {
  if (threads > 0) return threads;
  return static_cast<int>(std::clamp(std::thread::hardware_concurrency(), 1u, 8u));
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
  const std::vector<InputFrame> pyramid = BuildPyramid(frame, options.pyramid);
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
  if (params->size() != frames.size()) {
    throw Error("calibration: " + std::to_string(frames.size()) + " frames but " + std::to_string(params->size()) +
                " parameter sets");
  }
  const auto start = Clock::now();
  std::vector<std::vector<InputFrame>> pyramids;
  pyramids.reserve(frames.size());
  for (const InputFrame& f : frames) pyramids.push_back(BuildPyramid(f, options.pyramid));
  const double pyramid_ms = ms_since(start);
  std::vector<const std::vector<InputFrame>*> pointers;
  for (const auto& p : pyramids) pointers.push_back(&p);
  SolverSummary s = SolvePyramids(pointers, layout, options, params);
  s.pyramid_ms = pyramid_ms;
  s.total_ms += pyramid_ms;
  return s;
}

SolverSummary CpuSolver::SolvePyramids(const std::vector<const std::vector<InputFrame>*>& pyramids,
                                       const ParameterLayout& layout, const SolverOptions& options,
                                       std::vector<gpu::FaceParameters>* params) const {
  std::string why;
  if (!options.IsValid(&why)) throw Error(why);
  if (!layout.IsValid(&why, model_.num_identity(), model_.num_albedo(), model_.num_expression())) throw Error(why);
  const int num_frames = static_cast<int>(pyramids.size());
  for (int f = 0; f < num_frames; ++f) {
    if (!(*params)[f].IsValid(&why, model_.num_identity(), model_.num_expression(), model_.num_albedo())) {
      throw Error("tracker start parameters" + (num_frames > 1 ? " of frame " + std::to_string(f) : std::string()) + ": " + why);
    }
    for (const auto& level : options.schedule) {
      if (level.level >= static_cast<int>(pyramids[f]->size())) {
        throw Error("solver: the pyramid has fewer levels than the schedule uses");
      }
      if (!(*pyramids[f])[level.level].IsValid(&why)) throw Error(why);
    }
  }
  const auto start = Clock::now();
  SolverSummary summary;
  // Unknowns: [shared identity/albedo (S) | frame 0's own (P) | frame 1's own | ...]; with one
  // frame this is exactly the layout's x.
  const int shared = layout.num_identity + layout.num_albedo;
  const int own = layout.num_parameters() - shared;
  const int n = shared + num_frames * own;
  const std::vector<gpu::FaceParameters> bases = *params;
  Eigen::VectorXd x(n);
  x.head(shared) = layout.Pack(bases[0]).head(shared);
  for (int f = 0; f < num_frames; ++f) x.segment(shared + f * own, own) = layout.Pack(bases[f]).tail(own);
  auto frame_x = [&](const Eigen::VectorXd& global, int f) {
    Eigen::VectorXd out(shared + own);
    out.head(shared) = global.head(shared);
    out.tail(own) = global.segment(shared + f * own, own);
    return out;
  };
  const int o_exp_own = layout.offset(Block::kExpression) - shared;
  const int threads = options.ResolvedThreads();
  PcgScratch scratch;
  scratch.Resize(n);
  Eigen::VectorXd b(n), dx(n), rg;
  const PcgOptions pcg_base{1, options.pcg_relative_tolerance};
  auto sum = [](const std::vector<State>& states) {
    TermEnergies e;
    for (const State& st : states) {
      for (int t = 0; t < kNumTerms; ++t) e.value[t] += st.energy.value[t];
    }
    return e;
  };
  // Renders every frame at x and linearises; the caller times it.
  auto linearise = [&](int level, const Eigen::VectorXd& at, std::vector<State>* states, double* synth_ms,
                       double* analysis_ms) {
    for (int f = 0; f < num_frames; ++f) {
      const InputFrame& frame = (*pyramids[f])[level];
      const Eigen::VectorXd xf = frame_x(at, f);
      const auto t0 = Clock::now();
      const gpu::FaceParameters p = layout.Unpack(xf, bases[f]);
      const gpu::VertexState vs = renderer_.evaluate(p);
      const gpu::GBuffer g = renderer_.rasterize(vs, frame.camera, options.render);
      *synth_ms += ms_since(t0);
      const auto t1 = Clock::now();
      State& st = (*states)[f];
      st.lin = Linearize(model_, layout, p, vs, g, frame, options.energy, /*regularize_shared=*/f == 0);
      EvaluateResiduals(model_, st.lin, options.energy, xf, &st.r, nullptr, &st.energy, threads);
      st.has_jacobian = false;
      *analysis_ms += ms_since(t1);
    }
  };
  auto ensure_jacobians = [&](const Eigen::VectorXd& at, std::vector<State>* states) {
    for (int f = 0; f < num_frames; ++f) {
      State& st = (*states)[f];
      if (st.has_jacobian) continue;
      EvaluateResiduals(model_, st.lin, options.energy, frame_x(at, f), &st.r, &st.j, &st.energy, threads);
      st.has_jacobian = true;
    }
  };
  // The joint system: the frames' Jacobian blocks as they are (no zeros stored), their residuals
  // stacked in the same row order (no copy with one frame).
  auto system = [&](const std::vector<State>& states, const Eigen::VectorXd** r) {
    if (num_frames == 1) {
      *r = &states[0].r;
      return StackedJacobian(states[0].j);
    }
    StackedJacobian j(shared, own);
    Eigen::Index rows = 0;
    for (const State& st : states) rows += st.r.size();
    rg.resize(rows);
    Eigen::Index row = 0;
    for (const State& st : states) {
      j.AddFrame(st.j);
      rg.segment(row, st.r.size()) = st.r;
      row += st.r.size();
    }
    *r = &rg;
    return j;
  };

  int accepted_steps = 0, attempted_steps = 0;
  bool first_level = true;
  bool stop_all = false;
  std::vector<State> cur(num_frames);
  Eigen::VectorXd trial_r;
  for (const LevelSchedule& level : options.schedule) {
    double synth = 0, analysis = 0;
    linearise(level.level, x, &cur, &synth, &analysis);
    summary.synthesis_ms += synth;
    summary.analysis_ms += analysis;
    TermEnergies energy = sum(cur);
    if (first_level) summary.initial_energy = energy;
    first_level = false;
    summary.final_energy = energy;
    bool empty_frame = false;
    for (const State& st : cur) empty_frame = empty_frame || st.lin.term_rows[kNumTerms - 1] == 0;
    if (empty_frame) {
      summary.termination = Termination::kNoValidResiduals;
      summary.message += "level " + std::to_string(level.level) +
                         ": no pixel or landmark of the input overlaps the rendered face" +
                         (num_frames > 1 ? " in at least one frame" : "") + "; parameters left unchanged";
      stop_all = true;
      break;
    }
    PcgOptions pcg = pcg_base;
    pcg.max_iterations = level.pcg_iterations;
    for (int it = 0; it < level.gauss_newton_iterations; ++it) {
      if (internal::EndIfStopRequested(options, level.level, it, &summary)) {
        stop_all = true;
        break;
      }
      ++attempted_steps;
      IterationRecord rec;
      rec.level = level.level;
      rec.iteration = it;
      rec.energy_before = energy;
      const auto t_solve = Clock::now();
      ensure_jacobians(x, &cur);
      const Eigen::VectorXd* r = nullptr;
      const StackedJacobian j = system(cur, &r);
      rec.residuals = r->size();
      j.MultiplyTransposed(*r, &b);
      b = -b;
      dx.setZero();
      PcgSummary ps;
      if (options.linear_solver == LinearSolverType::kAssembled) {
        AssembledNormalOperator op(j, options.damping);
        ps = Pcg(op, b, pcg, &scratch, &dx);
      } else {
        MatrixFreeNormalOperator op(j, options.damping);
        ps = Pcg(op, b, pcg, &scratch, &dx);
      }
      rec.analysis_ms += ms_since(t_solve);
      rec.pcg_iterations = ps.iterations;
      rec.pcg_relative_residual = ps.initial_residual_norm > 0 ? ps.final_residual_norm / ps.initial_residual_norm : 0;
      if (!dx.allFinite()) {
        summary.termination = Termination::kNonFinite;
        summary.message += "level " + std::to_string(level.level) + " iteration " + std::to_string(it) +
                           ": the linear solve produced a non-finite step; kept the last good parameters";
        summary.iterations.push_back(rec);
        stop_all = true;
        break;
      }
      // Step control on the energy with this step's correspondences held (the function the
      // Gauss-Newton step models): comparing energies of different renders would mix in the
      // change of the pixel set, which is not what the step optimises. Costs no rendering.
      bool accepted = false;
      double scale = 1.0, linear_energy = 0.0;
      const double before = energy.total();
      Eigen::VectorXd x_try;
      const auto t_control = Clock::now();
      for (int h = 0; h <= options.max_step_halvings; ++h, scale *= 0.5) {
        x_try = x + scale * dx;
        if (options.clamp_expression) {
          for (int f = 0; f < num_frames; ++f) {
            for (int q = 0; q < layout.num_expression; ++q) {
              double& d = x_try[shared + f * own + o_exp_own + q];
              d = std::clamp(d, 0.0, 1.0);
            }
          }
        }
        linear_energy = 0;
        for (int f = 0; f < num_frames; ++f) {
          TermEnergies e;
          EvaluateResiduals(model_, cur[f].lin, options.energy, frame_x(x_try, f), &trial_r, nullptr, &e, threads);
          linear_energy += e.total();
        }
        rec.step_halvings = h;
        if ((std::isfinite(linear_energy) && linear_energy <= before) || options.max_step_halvings == 0) {
          accepted = true;
          break;
        }
      }
      rec.analysis_ms += ms_since(t_control);
      rec.step_norm = accepted ? (x_try - x).norm() : 0.0;
      if (!accepted) {
        rec.energy_after = energy;
        summary.iterations.push_back(rec);
        summary.synthesis_ms += rec.synthesis_ms;
        summary.analysis_ms += rec.analysis_ms;
        summary.message += "level " + std::to_string(level.level) + " converged at iteration " + std::to_string(it) +
                           " (no step along the Gauss-Newton direction lowered the energy); ";
        break;  // next level
      }
      ++accepted_steps;
      const Eigen::VectorXd x_before = x;
      x = x_try;
      // The next synthesis: re-render at the new parameters and linearise there.
      linearise(level.level, x, &cur, &rec.synthesis_ms, &rec.analysis_ms);
      energy = sum(cur);
      rec.energy_after = energy;
      summary.iterations.push_back(rec);
      summary.synthesis_ms += rec.synthesis_ms;
      summary.analysis_ms += rec.analysis_ms;
      summary.final_energy = energy;
      bool lost = false;
      for (const State& st : cur) lost = lost || st.lin.term_rows[kNumTerms - 1] == 0;
      if (lost) {
        x = x_before;  // a step that loses the face is not kept
        summary.termination = Termination::kNoValidResiduals;
        summary.message += "level " + std::to_string(level.level) + ": a step moved the face out of the input; kept the parameters before it";
        stop_all = true;
        break;
      }
      if (before - linear_energy <= options.function_tolerance * before) break;  // converged on this level
    }
    if (stop_all) break;
  }
  if (!stop_all && attempted_steps > 0 && accepted_steps == 0) {
    summary.termination = Termination::kNoProgress;
    summary.message += "no Gauss-Newton step lowered the energy: the start is already a (local) minimum";
  } else if (!stop_all) {
    summary.message += "ran the schedule of " + std::to_string(options.schedule.size()) + " level(s), " +
                       std::to_string(accepted_steps) + " of " + std::to_string(attempted_steps) + " steps accepted";
  }
  for (int f = 0; f < num_frames; ++f) (*params)[f] = layout.Unpack(frame_x(x, f), bases[f]);
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
