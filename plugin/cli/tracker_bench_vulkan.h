#pragma once
// The Vulkan columns of `face-reenact bench track` (tracker_vulkan_bench_commands.cc): the
// VulkanSolver tracks the same synthetic frames as the CPU reference, per strategy.
#include <functional>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "face_reenact/tracker/face_tracker.h"
#include "face_reenact/tracker/input_frame.h"
#include "face_reenact/tracker/parameter_layout.h"
#include "face_reenact/tracker/solver.h"
#include "face_reenact/tracker/tracker_model.h"

namespace face_reenact::cli {

// One solver of the `bench track` table: tracks `frames` in order from `start` (frame 0 is the
// untimed warm-up) and returns {"levels": [per level: gauss_newton_per_frame, residuals,
// synthesis_ms_per_frame, analysis_ms_per_frame], pyramid_ms_per_frame, input_ms_per_frame,
// total_ms_per_frame, mean_final_energy}, averaged over the timed frames. Shared by the CPU and Vulkan columns.
using BenchSolveFunction = std::function<tracker::SolverSummary(const tracker::InputFrame&, gpu::FaceParameters*)>;
nlohmann::json time_track_solver(const BenchSolveFunction& solve, const std::vector<tracker::InputFrame>& frames,
                                 gpu::FaceParameters start);

// The calibration row of the table (Sec. 6.3 as FaceTracker runs it): identity and albedo shared
// over the first frames, expression, lighting and pose per frame, the tracker's calibration
// schedule, started from the mean face at the true poses.
struct CalibrationBench {
  std::vector<tracker::InputFrame> frames;
  std::vector<gpu::FaceParameters> starts;
  tracker::ParameterLayout layout;
  tracker::SolverOptions options;
};
// Times one calibration solve: {frames, unknowns, gauss_newton, residuals (per iteration),
// pyramid_ms, input_ms, synthesis_ms, analysis_ms, total_ms, final_energy, termination}.
nlohmann::json time_calibration(const tracker::FramesSolveFunction& calibrate, const CalibrationBench& bench);
// Prints one calibration line ("calibration (WHO): ...") from time_calibration's object.
void print_calibration_bench(const char* who, const nlohmann::json& calibration);

struct VulkanTrackBenchArgs {
  std::string strategies = "all";  // all | auto | matrix-free | assembled | none
  std::string device;              // gpu::Context selector (empty: FR_VULKAN_DEVICE or automatic)
};

// Adds doc["solvers"]["vulkan_<strategy>"] (same fields as the CPU solvers) and doc["vulkan"]
// (device, auto choice, ratios to the CPU, and "calibration": `calibration` solved by
// VulkanSolver::SolveFrames, as doc["calibration"] holds the CPU's). Frame 0 is the untimed
// warm-up, as for the CPU. A missing Vulkan device is reported in doc["vulkan"]["error"], not
// thrown; bad arguments throw.
// `options`: the per-frame solve's, as the CPU rows have them.
void add_vulkan_track_bench(const tracker::TrackerModel& model, const std::vector<tracker::InputFrame>& frames,
                            const gpu::FaceParameters& start, const tracker::ParameterLayout& layout,
                            const tracker::SolverOptions& options, const CalibrationBench& calibration,
                            const VulkanTrackBenchArgs& args, nlohmann::json* doc);

// Prints the Vulkan summary lines (device, ratios, auto choice) after the table.
void print_vulkan_track_bench(const nlohmann::json& doc);

}  // namespace face_reenact::cli
