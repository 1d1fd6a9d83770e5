#pragma once
// The tracker solve on Vulkan compute (paper Sec. 6.1-6.2): the same coarse-to-fine Gauss-Newton
// as CpuSolver (solver.h), with every per-pixel stage on the device:
//   synthesis  gpu::Renderer renders S(P) into its G-buffer (stays on the device);
//   analysis   tracker_classify.comp linearises per pixel (correspondence pruning, compaction),
//              tracker_landmarks.comp prunes the landmarks, tracker_vertices.comp evaluates the
//              model at x, tracker_evaluate.comp writes the residuals r and the dense Jacobian J
//              (float, column-major) of energy.cc's energy;
//   solve      Jacobi-preconditioned CG in compute shaders, with one of two strategies:
//                kMatrixFree  the paper's: each PCG step applies J then J^T (one fused pass
//                             over J per step, tracker_jt.comp, plus a reduction);
//                kAssembled   J^T J and J^T r assembled once per Gauss-Newton step by block
//                             reductions (tracker_jtj.comp), then PCG on the small dense system
//                             inside one workgroup;
//   step       the trial parameters x + 2^-h dx for every allowed halving are formed and their
//              energies evaluated on the device, and the CPU solver's rule picks the step.
// Two ways to drive that loop:
//   device-driven (Solve, the default once the strategy is known): the frame's whole schedule is
//              recorded into one command buffer and submitted once; tracker_loop.comp makes the
//              loop's decisions on the device (the counts that size J and scale the terms, the step
//              control, convergence, a face lost), indirect dispatches skip the iterations a
//              converged level does not need, and the host reads back x and the iteration
//              records once at the end. Its J is sized ahead (capacity_rows): a frame whose
//              linearisation needs more rows is solved again host-driven, and J grows.
//   host-driven (SolveFrames, the first Solve under kAuto, VulkanSolverOptions::device_loop
//              off): two submissions per Gauss-Newton step, the render with the linearisation
//              (whose counts the host reads to size J) and the analysis + solve + step energies,
//              whose energies, dx and PCG summary the host reads to apply the rule itself.
// docs/tracker.md ("Vulkan solver") lists the differences to the CPU reference and the accuracy.
#include <Eigen/Core>
#include <memory>
#include <string>
#include <vector>

#include "face_reenact/gpu/image_formation.h"
#include "face_reenact/tracker/energy.h"
#include "face_reenact/tracker/input_frame.h"
#include "face_reenact/tracker/parameter_layout.h"
#include "face_reenact/tracker/solver.h"
#include "face_reenact/tracker/tracker_model.h"

namespace face_reenact::gpu {
class Context;
}

namespace face_reenact::tracker {

enum class VulkanStrategy {
  kAuto,        // time both on the first Gauss-Newton step of the first solve, keep the faster
  kMatrixFree,  // J and J^T applied per PCG step (paper)
  kAssembled,   // J^T J assembled once per Gauss-Newton step
  kFromSolverOptions,  // follow SolverOptions::linear_solver of each Solve call
};
const char* vulkan_strategy_name(VulkanStrategy s);

struct VulkanSolverOptions {
  VulkanStrategy strategy = VulkanStrategy::kAuto;
  // Solve drives the Gauss-Newton loop from the device, one submission per frame (above); off:
  // from the host, two submissions per step (bench track compares the two).
  bool device_loop = true;
  // Rows of J the device-driven loop allocates at first (0: as many as 256 MiB hold, the whole
  // of the paper's level 1 of a 640x480 frame). A frame that needs more is solved host-driven
  // and J grows for the next.
  uint64_t device_loop_rows = 0;
  bool IsValid(std::string* why) const;
};

// What the device computed at one linearisation, rearranged into the CPU's row order (term by
// term, pixels in row-major order), for tests and diagnostics.
struct VulkanLinearSystem {
  gpu::GBuffer gbuffer;             // the render it was linearised at
  gpu::VertexState vertex_state;
  std::array<Eigen::Index, kNumTerms + 1> term_rows{};
  Eigen::VectorXd residuals;
  JacobianMatrix jacobian;          // rows x unknowns
  TermEnergies energy;              // reduced on the device
  Eigen::MatrixXd jtj;              // J^T J from the assembled path (undamped)
  Eigen::VectorXd jtr;              // J^T r from the assembled path
  Eigen::VectorXd jtr_matrix_free;  // J^T r from the matrix-free path's column sums
  Eigen::VectorXd normal_product;   // J^T (J v) from the matrix-free path, v given by the caller
};

// Per-strategy wall time of the first analysis, when kAuto measured it.
struct VulkanStrategyChoice {
  VulkanStrategy chosen = VulkanStrategy::kAuto;  // kAuto until measured
  double matrix_free_ms = 0;
  double assembled_ms = 0;
  Eigen::Index residuals = 0;  // of the step that was timed
};

class VulkanSolver {
 public:
  // Throws face_reenact::Error on an invalid model or options, or when the device lacks
  // something the passes need. `context` must outlive the solver.
  VulkanSolver(const gpu::Context& context, TrackerModel model, const VulkanSolverOptions& options = {});
  ~VulkanSolver();
  VulkanSolver(const VulkanSolver&) = delete;
  VulkanSolver& operator=(const VulkanSolver&) = delete;

  const TrackerModel& model() const;
  const VulkanSolverOptions& options() const;
  void set_strategy(VulkanStrategy strategy);  // also forgets a kAuto measurement
  const VulkanStrategyChoice& strategy_choice() const;

  // As CpuSolver::Solve (same options, termination rules and summary; errors are thrown as
  // face_reenact::Error). Not const: the device buffers are reused from call to call. From a
  // frame, the pyramid is made on the device (tracker_pyramid.comp: BuildPyramid's kernel in
  // float) from the frame's colour and depth, uploaded once; from a pyramid the host built, each
  // scheduled level is uploaded.
  SolverSummary Solve(const InputFrame& frame, const ParameterLayout& layout, const SolverOptions& options,
                      gpu::FaceParameters* params);
  SolverSummary Solve(const std::vector<InputFrame>& pyramid, const ParameterLayout& layout,
                      const SolverOptions& options, gpu::FaceParameters* params);

  // Calibration over several frames (CpuSolver::SolveFrames' problem, options and result): every
  // frame's synthesis and analysis on the device, where each frame's J^T J and J^T r are
  // assembled and read back; the host sums them into the joint system (identity and albedo
  // shared, the rest per frame) and solves it with the CPU's Jacobi PCG. The step's trial
  // energies are evaluated on the device. The layout may have at most 255 unknowns per frame.
  SolverSummary SolveFrames(const std::vector<InputFrame>& frames, const ParameterLayout& layout,
                            const SolverOptions& options, std::vector<gpu::FaceParameters>* params);

  // Renders `params` for `level_frame`, linearises and evaluates r and J on the device, forms
  // J^T J and J^T r with the assembled path and J^T (J v) with the matrix-free path, and reads
  // everything back (slow; for tests and tools). `v` must have layout.num_parameters() entries.
  VulkanLinearSystem Inspect(const InputFrame& level_frame, const ParameterLayout& layout,
                             const EnergyOptions& energy, const gpu::FaceParameters& params,
                             const Eigen::VectorXd& v, const gpu::RenderOptions& render = kTrackedParts);

  // The pyramid Solve(frame) makes on the device, read back (slow; for tests and tools): as
  // BuildPyramid(frame, options, threads, false), level 0 without pixels.
  std::vector<InputFrame> InspectPyramid(const InputFrame& frame, const PyramidOptions& options);

 private:
  void CheckSolveArguments(const ParameterLayout& layout, const SolverOptions& options,
                           const gpu::FaceParameters* params) const;
  SolverSummary SolvePrepared(const ParameterLayout& layout, const SolverOptions& options, gpu::FaceParameters* params,
                              double input_ms);

  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace face_reenact::tracker
