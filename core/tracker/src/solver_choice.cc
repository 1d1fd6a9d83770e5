#include "face_reenact/tracker/solver_choice.h"

#include <algorithm>
#include <memory>
#include <vector>

#include "face_reenact/common/error.h"
#include "face_reenact/gpu/context.h"
#include "face_reenact/tracker/vulkan_solver.h"

namespace face_reenact::tracker {
namespace {
// The device context and the solver on it; members are destroyed in reverse order, so the
// solver goes before the context it uses.
struct VulkanBackend {
  std::unique_ptr<gpu::Context> context;
  std::unique_ptr<VulkanSolver> solver;
};
}  // namespace

const char* solver_backend_name(SolverBackend backend) {
  switch (backend) {
    case SolverBackend::kAuto: return "auto";
    case SolverBackend::kCpu: return "cpu";
    case SolverBackend::kVulkan: return "vulkan";
  }
  return "?";
}

bool parse_solver_backend(const std::string& text, SolverBackend* backend) {
  if (text == "auto") *backend = SolverBackend::kAuto;
  else if (text == "cpu") *backend = SolverBackend::kCpu;
  else if (text == "vulkan") *backend = SolverBackend::kVulkan;
  else return false;
  return true;
}

TrackingSolverChoice ChooseTrackingSolver(SolverBackend backend, const TrackerModel& model, const std::string& device) {
  TrackingSolverChoice choice;
  if (backend == SolverBackend::kCpu) {
    choice.backend = SolverBackend::kCpu;
    choice.description = "cpu (forced)";
    return choice;
  }
  if (backend == SolverBackend::kAuto) {
    // The device list alone says whether the pick is a CPU implementation: no device is
    // created (every live pipeline and `send --input` asks, on lavapipe machines too).
    std::vector<gpu::DeviceInfo> devices;
    try {
      devices = gpu::Context::enumerate_devices(device);
    } catch (const Error& e) {
      choice.description = std::string("cpu (auto: no usable Vulkan device: ") + e.what() + ")";
      return choice;
    }
    const auto picked = std::find_if(devices.begin(), devices.end(), [](const gpu::DeviceInfo& d) { return d.would_pick; });
    if (picked != devices.end() && picked->type == "cpu") {
      choice.description = "cpu (auto: the Vulkan device '" + picked->name +
                           "' is a CPU implementation, where the CPU solver is faster)";
      return choice;
    }
  }
  auto vulkan = std::make_shared<VulkanBackend>();
  try {
    gpu::Context::Options o;
    o.device = device;
    vulkan->context = std::make_unique<gpu::Context>(o);
  } catch (const Error& e) {
    if (backend == SolverBackend::kVulkan) throw Error(std::string("no usable Vulkan device for the tracker: ") + e.what());
    choice.backend = SolverBackend::kCpu;
    choice.description = std::string("cpu (auto: no usable Vulkan device: ") + e.what() + ")";
    return choice;
  }
  const gpu::DeviceInfo& info = vulkan->context->device_info();
  vulkan->solver = std::make_unique<VulkanSolver>(*vulkan->context, model);
  choice.backend = SolverBackend::kVulkan;
  choice.description = "vulkan on " + info.name + " (" + info.type + ", " +
                       (backend == SolverBackend::kAuto ? "auto" : "forced") + ")";
  choice.solve = [vulkan](const InputFrame& frame, const ParameterLayout& layout, const SolverOptions& options,
                          gpu::FaceParameters* params) {
    return vulkan->solver->Solve(frame, layout, options, params);
  };
  choice.calibrate = [vulkan](const std::vector<InputFrame>& frames, const ParameterLayout& layout,
                              const SolverOptions& options, std::vector<gpu::FaceParameters>* params) {
    return vulkan->solver->SolveFrames(frames, layout, options, params);
  };
  return choice;
}

}  // namespace face_reenact::tracker
