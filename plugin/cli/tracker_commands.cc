// `face-reenact bench track`: the cost of one tracked frame like the paper's Table 1, per
// pyramid level (residuals, synthesis, analysis) and per frame, for the CPU reference solver
// with both normal-equation operators (J then J^T applied per PCG step, and J^T J assembled).
// Input: synthetic frames rendered by the CPU renderer from the real model, the face moving a
// little between frames, each frame warm-started from the previous result.
#include <cstdio>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "command_registry.h"
#include "face_reenact/common/error.h"
#include "face_reenact/common/paths.h"
#include "face_reenact/model/model_file.h"
#include "face_reenact/tracker/solver.h"

namespace face_reenact::cli {
namespace {

using namespace face_reenact::tracker;

struct TrackBenchArgs {
  std::string model;
  int frames = 10;
  int width = 640;
  int height = 480;
  float distance = 0.55f;
  bool json = false;
};

struct LevelTotals {
  double residuals = 0, synthesis_ms = 0, analysis_ms = 0;
  int iterations = 0;
};

gpu::FaceParameters moving_face(const TrackerModel& model, int frame, float distance) {
  gpu::FaceParameters p = gpu::frontal_pose(distance);
  p.alpha = Eigen::VectorXf::Zero(model.num_identity());
  p.beta = Eigen::VectorXf::Zero(model.num_albedo());
  p.delta = Eigen::VectorXf::Zero(model.num_expression());
  const float t = static_cast<float>(frame);
  p.euler += Eigen::Vector3f(0.02f * std::sin(0.3f * t), 0.03f * std::sin(0.2f * t), 0.01f * std::cos(0.25f * t));
  p.translation += Eigen::Vector3f(0.004f * std::sin(0.2f * t), 0.003f * std::cos(0.3f * t), 0.0f);
  for (int k = 0; k < model.num_expression(); k += 7) p.delta[k] = 0.25f + 0.2f * std::sin(0.4f * t + k);
  p.gamma = gpu::ambient_sh(Eigen::Vector3f(0.9f, 0.85f, 0.8f));
  for (int c = 0; c < 3; ++c) p.gamma[c * 9 + 1] = -0.2f;
  return p;
}

void run_bench_track(const TrackBenchArgs& a) {
  const std::string model_path = resolve_model_path(a.model);
  const TrackerModel model = TrackerModel::FromFaceModel(load_face_model(model_path));
  const CpuSolver solver(model);
  gpu::PinholeCamera camera;
  camera.width = a.width;
  camera.height = a.height;
  camera.fx = camera.fy = 525.0f * a.width / 640.0f;
  camera.cx = (a.width - 1) * 0.5f;
  camera.cy = (a.height - 1) * 0.5f;
  std::string why;
  if (!camera.IsValid(&why)) throw Error("bench track: " + why);

  std::vector<InputFrame> frames;
  std::vector<gpu::FaceParameters> truths;
  for (int f = 0; f <= a.frames; ++f) {
    truths.push_back(moving_face(model, f, a.distance));
    frames.push_back(RenderSyntheticFrame(solver.renderer(), model, truths.back(), camera));
  }
  const ParameterLayout layout = ParameterLayout::Tracking(model.num_expression());
  nlohmann::json doc;
  doc["model"] = model_path;
  doc["camera"] = {{"width", a.width}, {"height", a.height}};
  doc["frames"] = a.frames;
  doc["unknowns"] = layout.num_parameters();
  for (const auto& [name, type] : {std::pair{"cpu_matrix_free", LinearSolverType::kMatrixFree},
                                   std::pair{"cpu_assembled", LinearSolverType::kAssembled}}) {
    SolverOptions options;
    options.linear_solver = type;
    gpu::FaceParameters current = truths[0];  // frame 0 is the warm-up from the truth
    std::map<int, LevelTotals> levels;
    double pyramid_ms = 0, total_ms = 0, final_energy = 0;
    for (int f = 0; f <= a.frames; ++f) {
      const SolverSummary s = solver.Solve(frames[f], layout, options, &current);
      if (f == 0) continue;
      pyramid_ms += s.pyramid_ms;
      total_ms += s.total_ms;
      final_energy += s.final_energy.total();
      for (const auto& it : s.iterations) {
        LevelTotals& l = levels[it.level];
        l.residuals += static_cast<double>(it.residuals);
        l.synthesis_ms += it.synthesis_ms;
        l.analysis_ms += it.analysis_ms;
        ++l.iterations;
      }
    }
    nlohmann::json levels_doc = nlohmann::json::array();
    for (auto it = levels.rbegin(); it != levels.rend(); ++it) {
      const LevelTotals& l = it->second;
      levels_doc.push_back({{"level", it->first},
                            {"gauss_newton_per_frame", static_cast<double>(l.iterations) / a.frames},
                            {"residuals", l.iterations ? l.residuals / l.iterations : 0.0},
                            {"synthesis_ms_per_frame", l.synthesis_ms / a.frames},
                            {"analysis_ms_per_frame", l.analysis_ms / a.frames}});
    }
    doc["solvers"][name] = {{"levels", levels_doc},
                            {"pyramid_ms_per_frame", pyramid_ms / a.frames},
                            {"total_ms_per_frame", total_ms / a.frames},
                            {"mean_final_energy", final_energy / a.frames}};
  }
  doc["vulkan"] = "no Vulkan tracker solver in this build (CPU reference only)";
  if (a.json) {
    std::printf("%s\n", doc.dump(2).c_str());
    return;
  }
  std::printf("bench track: %dx%d synthetic frames, %d frames, %d unknowns, paper schedule (7x4 on level 2, 1x4 on level 1)\n",
              a.width, a.height, a.frames, layout.num_parameters());
  std::printf("%-16s %5s %6s %10s %13s %13s\n", "solver", "level", "GN/fr", "residuals", "synthesis ms", "analysis ms");
  for (const auto& [name, s] : doc["solvers"].items()) {
    for (const auto& l : s["levels"]) {
      std::printf("%-16s %5d %6.1f %10.0f %13.2f %13.2f\n", name.c_str(), int(l["level"]), double(l["gauss_newton_per_frame"]),
                  double(l["residuals"]), double(l["synthesis_ms_per_frame"]), double(l["analysis_ms_per_frame"]));
    }
    std::printf("%-16s total per frame %.2f ms (pyramid %.2f ms), mean final energy %.4g\n", name.c_str(),
                double(s["total_ms_per_frame"]), double(s["pyramid_ms_per_frame"]), double(s["mean_final_energy"]));
  }
  std::printf("vulkan: %s\n", std::string(doc["vulkan"]).c_str());
}

void add_tracker_commands(CLI::App& app) {
  CLI::App* bench = get_or_add_subcommand(app, "bench", "Measure the cost of pipeline stages");
  auto args = std::make_shared<TrackBenchArgs>();
  CLI::App* track = bench->add_subcommand("track", "Cost of tracking one frame (Gauss-Newton/PCG), per pyramid level");
  track->add_option("--model", args->model, "Face model file (default: the installed/generated face-model.frm)");
  track->add_option("--frames", args->frames, "Timed frames per solver")->check(CLI::Range(1, 10000));
  track->add_option("--width", args->width, "Input width in pixels")->check(CLI::Range(32, 4096));
  track->add_option("--height", args->height, "Input height in pixels")->check(CLI::Range(32, 4096));
  track->add_option("--distance", args->distance, "Face distance from the camera (m)")->check(CLI::Range(0.2, 5.0));
  track->add_flag("--json", args->json, "Machine-readable output");
  track->callback([args] { run_bench_track(*args); });
}

}  // namespace

FR_REGISTER_COMMANDS(tracker, add_tracker_commands);

}  // namespace face_reenact::cli
