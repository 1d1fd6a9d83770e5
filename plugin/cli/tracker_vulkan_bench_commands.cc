// The Vulkan columns of `face-reenact bench track` (registered in tracker_commands.cc): the same
// frames, warm start and schedule as the CPU reference, tracked by tracker::VulkanSolver with
// each strategy, reported per level like the paper's Table 1, and the same calibration. Each
// strategy drives its Gauss-Newton loop from the device (one submission per frame); the
// matrix-free strategy is timed host-driven too (two submissions per step), in the same run.
#include <cstdio>
#include <map>
#include <memory>

#include "face_reenact/common/error.h"
#include "face_reenact/gpu/context.h"
#include "face_reenact/tracker/vulkan_solver.h"
#include "tracker_bench_vulkan.h"

namespace face_reenact::cli {
namespace {

using namespace face_reenact::tracker;

struct BenchedStrategy {
  std::string name;
  VulkanStrategy strategy;
  bool device_loop = true;  // VulkanSolverOptions::device_loop
};

std::vector<BenchedStrategy> strategies_of(const std::string& which) {
  const BenchedStrategy mf{"matrix-free", VulkanStrategy::kMatrixFree};
  const BenchedStrategy host{"matrix-free-host-loop", VulkanStrategy::kMatrixFree, false};
  const BenchedStrategy as{"assembled", VulkanStrategy::kAssembled};
  const BenchedStrategy au{"auto", VulkanStrategy::kAuto};
  if (which == "all") return {mf, host, as, au};
  if (which == "matrix-free") return {mf, host};
  if (which == "assembled") return {as};
  if (which == "auto") return {au};
  if (which == "none") return {};
  throw Error("bench track: --vulkan must be all, auto, matrix-free, assembled or none (got '" + which + "')");
}

std::string json_name(const std::string& strategy) {
  std::string s = "vulkan_" + strategy;
  for (char& c : s) {
    if (c == '-') c = '_';
  }
  return s;
}

}  // namespace

void add_vulkan_track_bench(const TrackerModel& model, const std::vector<InputFrame>& frames,
                            const gpu::FaceParameters& start, const ParameterLayout& layout, const SolverOptions& options,
                            const CalibrationBench& calibration, const VulkanTrackBenchArgs& args, nlohmann::json* doc) {
  const auto strategies = strategies_of(args.strategies);
  nlohmann::json& v = (*doc)["vulkan"];
  v = nlohmann::json::object();
  if (strategies.empty()) {
    v["error"] = "skipped (--vulkan none)";
    return;
  }
  std::unique_ptr<gpu::Context> context;
  try {
    gpu::Context::Options o;
    o.device = args.device;
    context = std::make_unique<gpu::Context>(o);
  } catch (const Error& e) {
    v["error"] = std::string("no usable Vulkan device: ") + e.what();
    return;
  }
  v["device"] = context->device_info().name;
  v["device_type"] = context->device_info().type;
  v["driver"] = context->device_info().driver_name + " " + context->device_info().driver_info;
  VulkanSolver solver(*context, model);
  VulkanSolverOptions host_driven;
  host_driven.device_loop = false;
  VulkanSolver host_loop_solver(*context, model, host_driven);
  for (const auto& [name, strategy, device_loop] : strategies) {
    VulkanSolver& s = device_loop ? solver : host_loop_solver;
    s.set_strategy(strategy);
    (*doc)["solvers"][json_name(name)] = time_track_solver(
        [&](const InputFrame& frame, gpu::FaceParameters* p) { return s.Solve(frame, layout, options, p); }, frames,
        start);
    if (strategy == VulkanStrategy::kAuto) {
      const VulkanStrategyChoice& c = solver.strategy_choice();
      v["auto_choice"] = {{"chosen", vulkan_strategy_name(c.chosen)},
                          {"matrix_free_ms", c.matrix_free_ms},
                          {"assembled_ms", c.assembled_ms},
                          {"residuals", c.residuals}};
    }
  }
  v["calibration"] = time_calibration(
      [&](const std::vector<InputFrame>& f, const ParameterLayout& l, const SolverOptions& o,
          std::vector<gpu::FaceParameters>* p) { return solver.SolveFrames(f, l, o, p); },
      calibration);
  if (doc->contains("calibration") && double((*doc)["calibration"]["total_ms"]) > 0) {
    v["calibration_ratio_to_cpu"] = double(v["calibration"]["total_ms"]) / double((*doc)["calibration"]["total_ms"]);
  }
  // Ratios of the per-frame totals to the CPU reference's matrix-free solver (> 1: slower).
  const auto& solvers = (*doc)["solvers"];
  if (solvers.contains("cpu_matrix_free")) {
    const double cpu = solvers["cpu_matrix_free"]["total_ms_per_frame"];
    for (const BenchedStrategy& b : strategies) {
      const double ms = solvers[json_name(b.name)]["total_ms_per_frame"];
      if (cpu > 0) v["ratio_to_cpu_matrix_free"][json_name(b.name)] = ms / cpu;
    }
  }
  if (solvers.contains("vulkan_matrix_free") && solvers.contains("vulkan_matrix_free_host_loop")) {
    const double device = solvers["vulkan_matrix_free"]["total_ms_per_frame"];
    const double host = solvers["vulkan_matrix_free_host_loop"]["total_ms_per_frame"];
    if (host > 0) v["device_loop_over_host_loop"] = device / host;
  }
  if (solvers.contains("vulkan_matrix_free") && solvers.contains("vulkan_assembled")) {
    const double mf = solvers["vulkan_matrix_free"]["total_ms_per_frame"];
    const double as = solvers["vulkan_assembled"]["total_ms_per_frame"];
    if (mf > 0) v["assembled_over_matrix_free"] = as / mf;
  }
}

void print_vulkan_track_bench(const nlohmann::json& doc) {
  if (!doc.contains("vulkan")) return;
  const auto& v = doc["vulkan"];
  if (v.contains("error")) {
    std::printf("vulkan: %s\n", std::string(v["error"]).c_str());
    return;
  }
  std::printf("vulkan device: %s (%s; %s)\n", std::string(v["device"]).c_str(), std::string(v["device_type"]).c_str(),
              std::string(v["driver"]).c_str());
  if (v.contains("ratio_to_cpu_matrix_free")) {
    for (const auto& [name, ratio] : v["ratio_to_cpu_matrix_free"].items()) {
      std::printf("  %-22s %.2fx the CPU reference's time per frame\n", name.c_str(), double(ratio));
    }
  }
  if (v.contains("device_loop_over_host_loop")) {
    std::printf("  matrix-free, loop driven from the device / from the host: %.2f\n", double(v["device_loop_over_host_loop"]));
  }
  if (v.contains("assembled_over_matrix_free")) {
    std::printf("  assembled / matrix-free on the device: %.2f\n", double(v["assembled_over_matrix_free"]));
  }
  if (v.contains("calibration")) {
    print_calibration_bench("Vulkan", v["calibration"]);
    if (v.contains("calibration_ratio_to_cpu")) {
      std::printf("  calibration on the device: %.2fx the CPU reference's time\n", double(v["calibration_ratio_to_cpu"]));
    }
  }
  if (v.contains("auto_choice")) {
    const auto& c = v["auto_choice"];
    std::printf("  auto: chose %s (first step, %.0f residuals: matrix-free %.2f ms, assembled %.2f ms)\n",
                std::string(c["chosen"]).c_str(), double(c["residuals"]), double(c["matrix_free_ms"]),
                double(c["assembled_ms"]));
  }
}

}  // namespace face_reenact::cli
