#pragma once
// The CPU reference tracker solve (Sec. 6.1-6.2): coarse-to-fine Gauss-Newton over a Gaussian
// pyramid of the input; every Gauss-Newton iteration re-renders the model (synthesis) with the
// CPU renderer, linearises the energy at the new G-buffer and solves the normal equations with
// Jacobi-preconditioned CG (analysis). It is the oracle a GPU path is compared against.
#include <Eigen/Core>
#include <functional>
#include <memory>
#include <mutex>
#include <stop_token>
#include <string>
#include <vector>

#include "face_reenact/gpu/cpu_renderer.h"
#include "face_reenact/tracker/energy.h"
#include "face_reenact/tracker/input_frame.h"
#include "face_reenact/tracker/parameter_layout.h"
#include "face_reenact/tracker/pcg.h"
#include "face_reenact/tracker/tracker_model.h"

namespace face_reenact::tracker {

struct LevelSchedule {
  int level = 0;  // pyramid level (0 = full resolution)
  int gauss_newton_iterations = 1;
  int pcg_iterations = 4;
};

enum class LinearSolverType { kMatrixFree, kAssembled };

struct SolverOptions {
  EnergyOptions energy;
  PyramidOptions pyramid;  // levels = 3
  // Coarse to fine, each level run in turn (paper: 7 GN x 4 PCG on the coarsest, 1 x 4 next).
  std::vector<LevelSchedule> schedule = {{2, 7, 4}, {1, 1, 4}};
  LinearSolverType linear_solver = LinearSolverType::kMatrixFree;
  // Levenberg-style damping D = lambda * diag(J^T J) (0 = plain Gauss-Newton).
  double damping = 1e-4;
  // Halve a step (up to this many times) when it raises the energy evaluated with the step's
  // correspondences held (no re-render); 0 takes every step as the paper does.
  int max_step_halvings = 4;
  // Stop a level early when an accepted step lowers E by less than this fraction.
  double function_tolerance = 1e-9;
  // Blendshape weights are projected onto [0, 1] after each step (the model's valid range).
  bool clamp_expression = true;
  double pcg_relative_tolerance = 1e-10;
  gpu::RenderOptions render = kTrackedParts;  // which parts are drawn (energy.h)
  // Threads for the per-pixel residual and Jacobian rows (0 = one per hardware thread, at most
  // 8). The result does not depend on it.
  int threads = 0;
  // A requested stop ends the solve before its next Gauss-Newton iteration (Termination::kStopped,
  // parameters: the last accepted step). The owner shutting down (a live session switching modes,
  // an OBS source removed) then waits one iteration, not a multi-second calibration.
  std::stop_token stop;

  bool IsValid(std::string* why) const;
  // `threads` with 0 resolved.
  int ResolvedThreads() const;
  // Whether the schedule solves on pyramid level 0, the input itself (BuildPyramid's keep_level0).
  bool SolvesFullResolution() const;
};

enum class Termination {
  kScheduleDone,      // every scheduled iteration ran (or each level converged)
  kNoValidResiduals,  // nothing to fit: the face is not visible in the input
  kNoProgress,        // no step lowered the energy (after halvings); result = best parameters
  kNonFinite,         // the linear solve produced NaN/Inf; parameters left at the last good
  kStopped,           // options.stop was requested; parameters: the last accepted step
};
const char* termination_name(Termination t);

struct IterationRecord {
  int level = 0;
  int iteration = 0;
  Eigen::Index residuals = 0;
  TermEnergies energy_before;  // at the linearisation point
  TermEnergies energy_after;   // after the accepted step (same level)
  int pcg_iterations = 0;
  double pcg_relative_residual = 0;
  double step_norm = 0;
  int step_halvings = 0;
  double synthesis_ms = 0;  // rendering at the new parameters
  double analysis_ms = 0;   // linearisation, residuals + J, PCG
};

struct SolverSummary {
  Termination termination = Termination::kScheduleDone;
  std::string message;          // why it stopped, in words
  TermEnergies initial_energy;  // at the start, on the first scheduled level
  TermEnergies final_energy;    // at the result, on the last scheduled level
  std::vector<IterationRecord> iterations;
  double pyramid_ms = 0;
  double input_ms = 0;  // the levels' input made ready for the device (Vulkan: normals + upload)
  double synthesis_ms = 0;
  double analysis_ms = 0;
  double total_ms = 0;
  // Device submissions this solve made, each waited for by the host (0 for the CPU solver).
  int device_submissions = 0;
  double device_submission_ms = 0;  // wall time inside those submissions (recording, submission, wait)
  double device_recording_ms = 0;   // of it, recording their command buffers on the host
  std::string BriefReport() const;
  std::string FullReport() const;
};

class CpuSolver {
 public:
  // Throws face_reenact::Error on an invalid model.
  explicit CpuSolver(TrackerModel model);
  const TrackerModel& model() const { return model_; }
  const gpu::CpuRenderer& renderer() const { return renderer_; }

  // Fits `*params` (the start; overwritten with the result) to `frame`, solving the blocks of
  // `layout`. Throws face_reenact::Error on invalid options, frame or start parameters; a frame
  // the face cannot be fitted to is not an error (see summary.termination).
  SolverSummary Solve(const InputFrame& frame, const ParameterLayout& layout, const SolverOptions& options,
                      gpu::FaceParameters* params) const;
  // The same on an already built pyramid (BuildPyramid with options.pyramid).
  SolverSummary Solve(const std::vector<InputFrame>& pyramid, const ParameterLayout& layout,
                      const SolverOptions& options, gpu::FaceParameters* params) const;

  // Calibration over several frames (Sec. 6.3): the identity and albedo blocks of `layout` are
  // shared by all frames (started from (*params)[0]), expression, lighting and pose are per
  // frame; the shared prior is counted once. On return every element of *params holds the
  // shared identity/albedo and its frame's own parameters. Energies and residual counts in the
  // summary are sums over the frames.
  SolverSummary SolveFrames(const std::vector<InputFrame>& frames, const ParameterLayout& layout,
                            const SolverOptions& options, std::vector<gpu::FaceParameters>* params) const;

  // Renders `params` for `level_frame` and linearises the energy there.
  Linearization LinearizeAt(const InputFrame& level_frame, const ParameterLayout& layout, const EnergyOptions& options,
                            const gpu::FaceParameters& params, const gpu::RenderOptions& render = kTrackedParts) const;
  // Energy of `params` on one pyramid level frame.
  TermEnergies Energy(const InputFrame& level_frame, const ParameterLayout& layout, const EnergyOptions& options,
                      const gpu::FaceParameters& params, const gpu::RenderOptions& render = kTrackedParts) const;

  // The identity shape and albedo a tracking solve holds fixed, kept for the last identity: after
  // the calibration every frame's solve holds the same one, and making it again cost a solve
  // about 1 ms (as CpuRenderer keeps its own identity parts). Not copied with the solver.
  class FixedPartsCache {
   public:
    FixedPartsCache() = default;
    FixedPartsCache(const FixedPartsCache&) {}
    FixedPartsCache& operator=(const FixedPartsCache&) { return *this; }
    std::shared_ptr<const FixedModelParts> For(const TrackerModel& model, const gpu::FaceParameters& params,
                                               int threads);

   private:
    std::mutex mutex_;
    std::shared_ptr<const FixedModelParts> last_;
  };

  // The syntheses' G-buffers, one per pyramid level, kept from one solve to the next: a buffer
  // of the same size knows the box its last draw covered and clears only that, where a new one (a
  // solve's first draw on each level, every frame) was allocated, page-faulted and cleared whole,
  // 16 values per pixel (4.9 MB on 640x480's level 1, 15 MB on 1280x720's). One set is kept, the
  // first frame's of the last solve; a solve running beside another takes none. Not copied with
  // the solver.
  class SynthesisBuffers {
   public:
    SynthesisBuffers() = default;
    SynthesisBuffers(const SynthesisBuffers&) {}
    SynthesisBuffers& operator=(const SynthesisBuffers&) { return *this; }
    std::vector<gpu::GBuffer> Take();
    void Give(std::vector<gpu::GBuffer> levels);

   private:
    std::mutex mutex_;
    std::vector<gpu::GBuffer> kept_;
  };

 private:
  SolverSummary SolvePyramids(const std::vector<const std::vector<InputFrame>*>& pyramids, const ParameterLayout& layout,
                              const SolverOptions& options, std::vector<gpu::FaceParameters>* params) const;

  TrackerModel model_;
  gpu::CpuRenderer renderer_;
  mutable FixedPartsCache fixed_parts_;
  mutable SynthesisBuffers synthesis_buffers_;
};

// The single-frame entry point every solver shares: validates `options`, builds the frame's
// pyramid (timed into the summary's pyramid_ms and total_ms) and solves on it with `solve`.
SolverSummary SolveOnPyramidOf(const InputFrame& frame, const SolverOptions& options,
                               const std::function<SolverSummary(const std::vector<InputFrame>& pyramid)>& solve);

// A synthetic input frame rendered by the CPU renderer at `params` (the test oracle and the
// benchmark input): colour and depth from the G-buffer (background: grey `background`, no
// depth), landmarks by projecting the model's landmark vertices (confidence 1).
InputFrame RenderSyntheticFrame(const gpu::CpuRenderer& renderer, const TrackerModel& model,
                                const gpu::FaceParameters& params, const gpu::PinholeCamera& camera,
                                const gpu::RenderOptions& render = kTrackedParts, float background = 0.2f);

}  // namespace face_reenact::tracker
