// The Vulkan columns of `face-reenact bench track` (registered in tracker_commands.cc): the same
// frames, warm start and schedule as the CPU reference, tracked by tracker::VulkanSolver with
// each strategy, reported per level like the paper's Table 1.
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

struct Totals {
  double residuals = 0, synthesis_ms = 0, analysis_ms = 0;
  int iterations = 0;
};

std::vector<std::pair<std::string, VulkanStrategy>> strategies_of(const std::string& which) {
  const std::pair<std::string, VulkanStrategy> mf{"matrix-free", VulkanStrategy::kMatrixFree};
  const std::pair<std::string, VulkanStrategy> as{"assembled", VulkanStrategy::kAssembled};
  const std::pair<std::string, VulkanStrategy> au{"auto", VulkanStrategy::kAuto};
  if (which == "all") return {mf, as, au};
  if (which == "matrix-free") return {mf};
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
                            const gpu::FaceParameters& start, const ParameterLayout& layout, int timed_frames,
                            const VulkanTrackBenchArgs& args, nlohmann::json* doc) {
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
  for (const auto& [name, strategy] : strategies) {
    solver.set_strategy(strategy);
    SolverOptions options;
    gpu::FaceParameters current = start;
    std::map<int, Totals> levels;
    double pyramid_ms = 0, total_ms = 0, final_energy = 0;
    for (size_t f = 0; f < frames.size(); ++f) {
      const SolverSummary s = solver.Solve(frames[f], layout, options, &current);
      if (f == 0) continue;  // warm-up (and, for auto, the strategy measurement)
      pyramid_ms += s.pyramid_ms;
      total_ms += s.total_ms;
      final_energy += s.final_energy.total();
      for (const auto& it : s.iterations) {
        Totals& l = levels[it.level];
        l.residuals += static_cast<double>(it.residuals);
        l.synthesis_ms += it.synthesis_ms;
        l.analysis_ms += it.analysis_ms;
        ++l.iterations;
      }
    }
    nlohmann::json levels_doc = nlohmann::json::array();
    for (auto it = levels.rbegin(); it != levels.rend(); ++it) {
      const Totals& l = it->second;
      levels_doc.push_back({{"level", it->first},
                            {"gauss_newton_per_frame", static_cast<double>(l.iterations) / timed_frames},
                            {"residuals", l.iterations ? l.residuals / l.iterations : 0.0},
                            {"synthesis_ms_per_frame", l.synthesis_ms / timed_frames},
                            {"analysis_ms_per_frame", l.analysis_ms / timed_frames}});
    }
    (*doc)["solvers"][json_name(name)] = {{"levels", levels_doc},
                                          {"pyramid_ms_per_frame", pyramid_ms / timed_frames},
                                          {"total_ms_per_frame", total_ms / timed_frames},
                                          {"mean_final_energy", final_energy / timed_frames}};
    if (strategy == VulkanStrategy::kAuto) {
      const VulkanStrategyChoice& c = solver.strategy_choice();
      v["auto_choice"] = {{"chosen", vulkan_strategy_name(c.chosen)},
                          {"matrix_free_ms", c.matrix_free_ms},
                          {"assembled_ms", c.assembled_ms},
                          {"residuals", c.residuals}};
    }
  }
  // Ratios of the per-frame totals to the CPU reference's matrix-free solver (> 1: slower).
  const auto& solvers = (*doc)["solvers"];
  if (solvers.contains("cpu_matrix_free")) {
    const double cpu = solvers["cpu_matrix_free"]["total_ms_per_frame"];
    for (const auto& [name, strategy] : strategies) {
      const double ms = solvers[json_name(name)]["total_ms_per_frame"];
      if (cpu > 0) v["ratio_to_cpu_matrix_free"][json_name(name)] = ms / cpu;
    }
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
  if (v.contains("assembled_over_matrix_free")) {
    std::printf("  assembled / matrix-free on the device: %.2f\n", double(v["assembled_over_matrix_free"]));
  }
  if (v.contains("auto_choice")) {
    const auto& c = v["auto_choice"];
    std::printf("  auto: chose %s (first step, %.0f residuals: matrix-free %.2f ms, assembled %.2f ms)\n",
                std::string(c["chosen"]).c_str(), double(c["residuals"]), double(c["matrix_free_ms"]),
                double(c["assembled_ms"]));
  }
}

}  // namespace face_reenact::cli
