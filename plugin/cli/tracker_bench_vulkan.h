#pragma once
// The Vulkan columns of `face-reenact bench track` (tracker_vulkan_bench_commands.cc): the
// VulkanSolver tracks the same synthetic frames as the CPU reference, per strategy.
#include <functional>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

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

struct VulkanTrackBenchArgs {
  std::string strategies = "all";  // all | auto | matrix-free | assembled | none
  std::string device;              // gpu::Context selector (empty: FR_VULKAN_DEVICE or automatic)
};

// Adds doc["solvers"]["vulkan_<strategy>"] (same fields as the CPU solvers) and doc["vulkan"]
// (device, auto choice, ratios to the CPU). Frame 0 is the untimed warm-up, as for the CPU.
// A missing Vulkan device is reported in doc["vulkan"]["error"], not thrown; bad arguments throw.
void add_vulkan_track_bench(const tracker::TrackerModel& model, const std::vector<tracker::InputFrame>& frames,
                            const gpu::FaceParameters& start, const tracker::ParameterLayout& layout,
                            const VulkanTrackBenchArgs& args, nlohmann::json* doc);

// Prints the Vulkan summary lines (device, ratios, auto choice) after the table.
void print_vulkan_track_bench(const nlohmann::json& doc);

}  // namespace face_reenact::cli
