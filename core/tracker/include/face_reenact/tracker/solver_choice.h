#pragma once
// Which solver runs the Gauss-Newton solves of the tracking loop (per frame and the calibration):
// the CPU reference or the Vulkan compute solver, and on which device. `kAuto` takes the Vulkan
// solver on a real GPU and the CPU solver when the only Vulkan device is a CPU implementation
// (Mesa's lavapipe), where `face-reenact bench track` measured the Vulkan solver 5-6x slower than
// the CPU reference (docs/tracker.md, "Vulkan solver"). Either can be forced. Within the Vulkan
// solver, the J/J^T-versus-J^T J strategy is timed and chosen by the solver itself
// (VulkanStrategy::kAuto).
#include <string>

#include "face_reenact/tracker/face_tracker.h"
#include "face_reenact/tracker/tracker_model.h"

namespace face_reenact::tracker {

const char* solver_backend_name(SolverBackend backend);
// "auto", "cpu", "vulkan"; false for anything else.
bool parse_solver_backend(const std::string& text, SolverBackend* backend);

struct TrackingSolverChoice {
  SolverBackend backend = SolverBackend::kCpu;  // what was chosen (never kAuto)
  // For FaceTracker::SetTrackingSolver; empty = the tracker's own CPU solver. A Vulkan choice
  // owns its device context and solver (shared by copies of the function).
  FrameSolveFunction solve;
  // For FaceTracker::SetCalibrationSolver, from the same device and solver (empty for the CPU).
  FramesSolveFunction calibrate;
  std::string description;  // "vulkan on NVIDIA ... (auto: a GPU)", "cpu (auto: only a CPU Vulkan device)"
};

// Chooses (and for Vulkan, creates) the solver. `device` selects the Vulkan device as
// gpu::Context does (empty: FR_VULKAN_DEVICE or automatic). kVulkan throws face_reenact::Error
// when no usable device exists; kAuto then falls back to the CPU and says why.
TrackingSolverChoice ChooseTrackingSolver(SolverBackend backend, const TrackerModel& model,
                                          const std::string& device = {});

}  // namespace face_reenact::tracker
