// `face-reenact track`: the tracking pipeline (calibration, tracking, recovery) on a recording
// or a video, writing per-frame parameters (JSON Lines, replayable by `send --replay`), a JSON
// report with per-stage times and, with ground truth, the accuracy, optionally the fitted meshes
// and the paper's data-term ablation (Fig. 12). docs/tracker.md describes the outputs.
//
// `face-reenact bench track`: the cost of one tracked frame like the paper's Table 1, per
// pyramid level (residuals, synthesis, analysis) and per frame, for the CPU reference solver
// with both normal-equation operators (J then J^T applied per PCG step, and J^T J assembled),
// plus the cost of the multi-frame calibration.
// Input: synthetic frames rendered by the CPU renderer from the real model, the face moving a
// little between frames, each frame warm-started from the previous result.
#include <unistd.h>

#include <Eigen/Geometry>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <algorithm>
#include <map>
#include <optional>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "camera_options.h"
#include "tracking_options.h"
#include "command_registry.h"
#include "report_json.h"
#include "video_output.h"
#include "face_reenact/capture/recording.h"
#include "face_reenact/common/error.h"
#include "face_reenact/common/json_number.h"
#include "face_reenact/common/paths.h"
#include "face_reenact/common/timing.h"
#include "face_reenact/live/frame_grabber.h"
#include "face_reenact/live/input_spec.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/model/mesh_export.h"
#include "face_reenact/model/model_file.h"
#include "face_reenact/reenact/fit_overlay.h"
#include "face_reenact/tracker/evaluation.h"
#include "face_reenact/tracker/face_tracker.h"
#include "face_reenact/tracker/fit_agreement.h"
#include "face_reenact/tracker/rgbd_input.h"
#include "face_reenact/tracker/solver.h"
#include "face_reenact/tracker/solver_choice.h"
#include "tracker_bench_vulkan.h"

namespace face_reenact::cli {
namespace {

using namespace face_reenact::tracker;

struct TrackBenchArgs {
  std::string model;
  int frames = 10;
  int width = 640;
  int height = 480;
  float distance = 0.55f;
  int calibration_frames = 5;  // frames of the timed calibration
  double tracking_tolerance = 0;  // SolverOptions::function_tolerance of every row (0: the paper's whole schedule)
  bool json = false;
  VulkanTrackBenchArgs vulkan;  // the Vulkan columns (tracker_vulkan_bench_commands.cc)
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
  // The CPU solvers with their default thread count, and matrix-free on one thread: the same
  // steps, so the ratio of the two matrix-free rows is what the threads bring; and matrix-free on
  // the tracker's every other pixel (EnergyOptions::pixel_sampling 2), what that brings.
  const int threads = SolverOptions{}.ResolvedThreads();
  doc["cpu_threads"] = threads;
  struct CpuRow {
    const char* name;
    LinearSolverType type;
    int threads;
    int pixel_sampling = 1;
  };
  std::vector<CpuRow> rows = {{"cpu_matrix_free", LinearSolverType::kMatrixFree, threads},
                              {"cpu_matrix_free_half_pixels", LinearSolverType::kMatrixFree, threads, 2},
                              {"cpu_assembled", LinearSolverType::kAssembled, threads}};
  if (threads > 1) rows.push_back({"cpu_matrix_free_1_thread", LinearSolverType::kMatrixFree, 1});  // else the same row
  // The paper's schedule, ended early per level where --tracking-tolerance asks (as the tracker does).
  SolverOptions schedule;
  if (a.tracking_tolerance > 0) schedule.function_tolerance = a.tracking_tolerance;
  doc["tracking_tolerance"] = a.tracking_tolerance;
  for (const CpuRow& row : rows) {
    SolverOptions options = schedule;
    options.linear_solver = row.type;
    options.threads = row.threads;
    options.energy.pixel_sampling = row.pixel_sampling;
    // Frame 0 is the warm-up from the truth.
    doc["solvers"][row.name] = time_track_solver(
        [&](const InputFrame& frame, gpu::FaceParameters* p) { return solver.Solve(frame, layout, options, p); },
        frames, truths[0]);
  }
  CalibrationBench calibration;
  {
    const int n = std::min(a.calibration_frames, static_cast<int>(frames.size()));
    calibration.frames.assign(frames.begin(), frames.begin() + n);
    calibration.starts.assign(truths.begin(), truths.begin() + n);
    calibration.layout = ParameterLayout::Calibration(model.num_identity(), model.num_albedo(), model.num_expression());
    calibration.options = TrackerOptions{}.calibration_solver;
    doc["calibration"] = time_calibration(
        [&](const std::vector<InputFrame>& f, const ParameterLayout& l, const SolverOptions& o,
            std::vector<gpu::FaceParameters>* p) { return solver.SolveFrames(f, l, o, p); },
        calibration);
  }
  {
    // The gaze reading that follows each tracked frame's solve (gaze.h), on the true fits.
    const GazeEstimator gaze(model);
    const GazeOptions options;
    double ms = 0;
    int readings = 0, lids = 0;
    for (size_t f = 1; f < frames.size(); ++f) {
      gpu::FaceParameters p = truths[f];
      const GazeReading r = gaze.Read(solver.renderer(), frames[f], &p, options);
      ms += r.ms;
      readings += r.ok;
      lids += r.lids_read;
    }
    const double n = std::max<double>(1.0, static_cast<double>(frames.size()) - 1);
    doc["gaze"] = {{"ms_per_frame", ms / n}, {"frames", frames.size() - 1}, {"readings", readings}, {"lids_readings", lids}};
  }
  add_vulkan_track_bench(model, frames, truths[0], layout, schedule, calibration, a.vulkan, &doc);
  if (a.json) {
    std::printf("%s\n", doc.dump(2).c_str());
    return;
  }
  std::printf("bench track: %dx%d synthetic frames, %d frames, %d unknowns, paper schedule (7x4 on level 2, 1x4 on level 1)%s, "
              "%d CPU threads\n",
              a.width, a.height, a.frames, layout.num_parameters(),
              a.tracking_tolerance > 0 ? (", a level ended once a step gains under " + std::to_string(a.tracking_tolerance)).c_str()
                                       : "",
              int(doc["cpu_threads"]));
  std::printf("%-28s %5s %6s %10s %13s %13s\n", "solver", "level", "GN/fr", "residuals", "synthesis ms", "analysis ms");
  for (const auto& [name, s] : doc["solvers"].items()) {
    for (const auto& l : s["levels"]) {
      std::printf("%-28s %5d %6.1f %10.0f %13.2f %13.2f\n", name.c_str(), int(l["level"]), double(l["gauss_newton_per_frame"]),
                  double(l["residuals"]), double(l["synthesis_ms_per_frame"]), double(l["analysis_ms_per_frame"]));
    }
    // What the level rows do not hold: the pyramid, the input made ready for the device and the
    // rest of the loop (step control, host bookkeeping), so the columns add up to the total.
    double rest = double(s["total_ms_per_frame"]) - double(s["pyramid_ms_per_frame"]) - double(s["input_ms_per_frame"]);
    for (const auto& l : s["levels"]) rest -= double(l["synthesis_ms_per_frame"]) + double(l["analysis_ms_per_frame"]);
    std::printf("%-28s total per frame %.2f ms (pyramid %.2f, input %.2f, rest %.2f ms), mean final energy %.4g",
                name.c_str(), double(s["total_ms_per_frame"]), double(s["pyramid_ms_per_frame"]),
                double(s["input_ms_per_frame"]), rest, double(s["mean_final_energy"]));
    // Each device submission is also a host wait for the device (gpu::Context::submit_and_wait).
    const double submissions = s["device_submissions_per_frame"];
    if (submissions > 0) {
      std::printf(", %.1f device submissions and host syncs per frame (%.2f ms inside them, %.2f of it recording)",
                  submissions, double(s["device_submission_ms_per_frame"]), double(s["device_recording_ms_per_frame"]));
    }
    std::printf("\n");
  }
  if (doc["solvers"].contains("cpu_matrix_free_1_thread")) {
    std::printf("cpu_matrix_free on %d threads: speed-up %.2fx over one thread (same steps; below 1 = slower)\n", int(doc["cpu_threads"]),
                double(doc["solvers"]["cpu_matrix_free_1_thread"]["total_ms_per_frame"]) /
                    double(doc["solvers"]["cpu_matrix_free"]["total_ms_per_frame"]));
  }
  std::printf("cpu_matrix_free on every other pixel (the tracker's): %.2f of every pixel's time per frame\n",
              double(doc["solvers"]["cpu_matrix_free_half_pixels"]["total_ms_per_frame"]) /
                  double(doc["solvers"]["cpu_matrix_free"]["total_ms_per_frame"]));
  const auto& c = doc["calibration"];
  print_calibration_bench("CPU", c);
  std::printf("gaze and lids (CPU, after each solve): %.2f ms per frame (gaze read on %d of %d frames, lids on %d)\n",
              double(doc["gaze"]["ms_per_frame"]), int(doc["gaze"]["readings"]), int(doc["gaze"]["frames"]),
              int(doc["gaze"]["lids_readings"]));
  print_vulkan_track_bench(doc);
}

// ------------------------------------------------------------------------------ track

using Clock = std::chrono::steady_clock;

struct TrackArgs {
  std::string input;
  std::string out;
  std::string report;
  std::string export_mesh;
  std::string overlay;  // OUT.mp4 or a folder: the fit drawn over each frame
  std::string landmarks = "detector";
  std::string model;
  bool ablation = false;
  int frames = 0;  // 0 = all
  int calibration_frames = 5;
  int calibration_frame_stride = 1;
  int calibration_window = TrackerOptions{}.calibration_window_frames;
  int relaxed_recalibration = TrackerOptions{}.relaxed_recalibration_frames;
  bool all_inner_landmarks = false;
  bool no_eye_corners = false;
  bool brow_landmarks = false;
  bool no_gaze = false;
  bool no_lids = false;
  bool no_brows = false;
  std::string calibration_start = "neutral";
  int min_face_width = TrackerOptions{}.min_face_width_px;
  int calibration_min_face_width = TrackerOptions{}.calibration_min_face_width_px;  // -1: --min-face-width
  int calibration_sparse_face_width = TrackerOptions{}.calibration_sparse_face_width_px;  // 0: never sparser
  int calibration_max_face_width = TrackerOptions{}.calibration_max_face_width_px;  // 0: never coarser
  int max_face_width = TrackerOptions{}.max_face_width_px;
  CameraArgs camera;  // --fov / --intrinsics: none = estimated for videos and webcams
  double tracking_tolerance = -1;  // < 0: TrackerOptions' default
  bool every_pixel = false;         // the solves' dense terms on every pixel (the paper's)
  bool no_agreement_check = false;
  std::string solver = "auto";
  std::string device;
  bool quiet = false;
};

// One energy configuration of the ablation (Fig. 12); "all" is the tracker's default.
struct EnergyConfig {
  const char* name;
  bool depth;   // E_point + E_plane
  bool colour;  // E_col
};
constexpr EnergyConfig kAllTerms{"all", true, true};
constexpr EnergyConfig kAblation[] = {
    {"feature", false, false}, {"feature_color", false, true}, {"feature_depth", true, false}, {"all", true, true}};

// The tracker options of `face-reenact track` for one energy configuration.
TrackerOptions track_options(const TrackArgs& a, const EnergyConfig& config, bool depth_available) {
  TrackerOptions o;
  o.calibration_frames = a.calibration_frames;
  o.calibration_frame_stride = a.calibration_frame_stride;
  o.calibration_window_frames = a.calibration_window;
  o.relaxed_recalibration_frames = a.relaxed_recalibration;
  for (SolverOptions* s : {&o.calibration_solver, &o.tracking_solver, &o.recovery_solver}) {
    s->energy.all_inner_landmarks = a.all_inner_landmarks;
    s->energy.eye_corner_landmarks = !a.no_eye_corners;
    s->energy.use_brow_landmarks = a.brow_landmarks;
  }
  if (a.tracking_tolerance >= 0) o.tracking_solver.function_tolerance = a.tracking_tolerance;
  if (a.every_pixel)
    for (SolverOptions* s : {&o.calibration_solver, &o.tracking_solver, &o.recovery_solver}) s->energy.pixel_sampling = 1;
  o.gaze.enabled = !a.no_gaze;
  o.gaze.read_lids = !a.no_lids;
  o.brows.enabled = !a.no_brows;
  if (!parse_calibration_start(a.calibration_start, &o.calibration_start))
    throw Error("track: --calibration-start must be neutral, per-frame-fits or lower-energy");
  o.min_face_width_px = a.min_face_width;
  o.calibration_min_face_width_px = a.calibration_min_face_width;
  o.calibration_sparse_face_width_px = a.calibration_sparse_face_width;
  o.calibration_max_face_width_px = a.calibration_max_face_width;
  o.max_face_width_px = a.max_face_width;
  o.landmark_source = a.landmarks == "recording" ? LandmarkSourceChoice::kRecording : LandmarkSourceChoice::kDetector;
  if (a.no_agreement_check) {
    // Measured and reported still (the report's "agreement"), but no fit is refused for it.
    o.loss.agreement.max_pose_disagreement_deg = 0;
    o.loss.agreement.max_landmark_nme = 0;
    o.loss.agreement.max_rotation_speed_deg_s = 0;
  }
  for (SolverOptions* s : {&o.calibration_solver, &o.tracking_solver, &o.recovery_solver}) {
    // The depth terms a solver uses (the calibration has no point term), when there is depth.
    const bool depth = config.depth && depth_available;
    s->energy.use_point = s->energy.use_point && depth;
    s->energy.use_plane = s->energy.use_plane && depth;
    s->energy.use_color = config.colour;
  }
  return o;
}

nlohmann::json vector_json(const Eigen::VectorXf& v, int size) {
  nlohmann::json a = nlohmann::json::array();
  for (int k = 0; k < size; ++k) a.push_back(k < v.size() ? static_cast<double>(v[k]) : 0.0);
  return a;
}

nlohmann::json energy_json(const TermEnergies& e) {
  nlohmann::json j;
  for (int t = 0; t < kNumTerms; ++t) j[term_name(static_cast<Term>(t))] = e.value[t];
  j["total"] = e.total();
  return j;
}

// One parameter-file line (docs/tracker.md, "face-reenact track"); the keys `frame`,
// `timestamp_us`, `expression`, `neutral` and `pose` are those `send --replay` reads.
nlohmann::json frame_json(const TrackedFrame& t, int64_t frame_number, int64_t timestamp_us, const FaceTracker& tracker,
                          int num_expression) {
  nlohmann::json j;
  j["frame"] = frame_number;
  j["timestamp_us"] = timestamp_us;
  j["status"] = tracking_status_name(t.status);
  j["message"] = t.message;
  j["has_fit"] = t.has_parameters;
  j["fit_is_current"] = tracking_status_has_fit(t.status);
  // Frames never fitted carry the neutral expression (a replay shows a neutral face there).
  const gpu::FaceParameters& p = t.has_parameters ? t.params : tracker.neutral();
  j["expression"] = vector_json(p.delta, num_expression);
  j["neutral"] = vector_json(tracker.neutral().delta, num_expression);
  if (t.has_parameters) {
    const Eigen::Vector3f rot = gpu::head_rotation_axis_angle(p.euler);
    j["pose"] = {{"rotation", {rot.x(), rot.y(), rot.z()}},
                 {"translation", {p.translation.x(), p.translation.y(), p.translation.z()}}};
    j["euler"] = {p.euler.x(), p.euler.y(), p.euler.z()};
    j["translation"] = {p.translation.x(), p.translation.y(), p.translation.z()};
    j["gamma"] = std::vector<float>(p.gamma.begin(), p.gamma.end());
  }
  j["energy"] = energy_json(t.energy);
  j["landmarks"] = t.landmarks_used;
  j["landmark_error_px"] = t.landmark_error_px;
  j["pose_reinitialized"] = t.pose_reinitialized;
  // How far the fitted light was moved to one a room could give (null: it was one already).
  j["light_projected"] = t.light.changed ? nlohmann::json(t.light.moved) : nlohmann::json();
  // The gaze reading (null when none was made: gaze off, eyes closed, no fit).
  j["gaze"] = t.gaze.ok ? nlohmann::json{{"horizontal", t.gaze.horizontal}, {"vertical", t.gaze.vertical},
                                         {"pixels", t.gaze.pixels}, {"eyeball_pixels", t.gaze.eyeball_pixels},
                                         {"energy", t.gaze.energy}, {"straight_energy", t.gaze.straight_energy},
                                         // read with an iris of a real size (GazeOptions::real_iris_check)
                                         {"real_iris", t.gaze.real_iris},
                                         // each eye's own turn where they turned apart (crossed), else null
                                         {"per_eye", t.gaze.vergence_read ? nlohmann::json{t.gaze.per_eye[0], t.gaze.per_eye[1]}
                                                                          : nlohmann::json()}}
                        : nlohmann::json();
  // The lids read from the colour (null when they were not: open eyes, or gaze off).
  j["lids"] = t.gaze.lids_read ? nlohmann::json{{"blink", {t.gaze.blink[0], t.gaze.blink[1]}},
                                               {"open_fraction", {t.gaze.open_fraction[0], t.gaze.open_fraction[1]}}}
                               : nlohmann::json();
  // The brows read from the brow points (brow_reader.h; null when they were not: no points yet,
  // the first frames of an actor, or off).
  j["brows"] = t.brows.ok ? nlohmann::json{{"weights", t.brows.weight}, {"residual", t.brows.residual}} : nlohmann::json();
  // The fit against the frame's landmarks (fit_agreement.h; null where not measured).
  auto measure = [](double v) { return json_number(v); };
  j["agreement"] = {{"pose_disagreement_deg", measure(t.agreement.pose_disagreement_deg)},
                    {"landmark_nme", measure(t.agreement.landmark_nme)},
                    {"landmark_nme_by_part", {measure(t.agreement.nme_brows), measure(t.agreement.nme_nose),
                                              measure(t.agreement.nme_eyes), measure(t.agreement.nme_mouth)}},
                    {"landmark_pose_error_px", measure(t.agreement.landmark_pose_error_px)},
                    {"fit_error_px", measure(t.agreement.fit_error_px)},
                    {"eye_distance_px", measure(t.agreement.eye_distance_px)},
                    {"rotation_change_deg", measure(t.agreement.rotation_change_deg)},
                    {"rotation_speed_deg_s", measure(t.agreement.rotation_speed_deg_s)},
                    {"refused", t.disagreement.empty() ? nlohmann::json() : nlohmann::json(t.disagreement)}};
  j["times_ms"] = {{"landmarks", t.times.landmarks_ms}, {"pose_init", t.times.pose_init_ms},
                   {"pyramid", t.times.pyramid_ms},     {"synthesis", t.times.synthesis_ms},
                   {"analysis", t.times.analysis_ms},   {"gaze", t.times.gaze_ms},
                   {"calibration", t.times.calibration_ms}, {"total", t.times.total_ms}};
  return j;
}

MeshInstance mesh_of(const gpu::CpuRenderer& renderer, const gpu::FaceParameters& p, bool camera_frame) {
  const gpu::VertexState st = renderer.evaluate(p);
  MeshInstance m;
  if (camera_frame) {
    m.positions = st.camera_positions;
    m.colours = st.colors;
  } else {
    m.positions = st.model_positions;
    m.colours = st.albedo;
  }
  m.colours = m.colours.cwiseMax(0.f).cwiseMin(1.f);
  return m;
}

struct RunTotals {
  int frames = 0;
  int tracked_frames = 0;  // frames whose tracking time counts in ms_per_frame
  double read_ms = 0, convert_ms = 0, landmarks_ms = 0, pose_init_ms = 0, pyramid_ms = 0, synthesis_ms = 0,
         analysis_ms = 0, gaze_ms = 0, total_ms = 0, calibration_ms = 0;
  int64_t gauss_newton_iterations = 0;
  std::map<std::string, int> statuses;
  int64_t calibration_frame = -1;
  // Ground truth, over frames with a current fit after the calibration.
  int evaluated = 0;
  double geo_mean = 0, geo_max = 0, vertex_mean = 0, vertex_max = 0, align = 0, rot = 0, trans = 0, expr = 0;
  // Recovery: frames from the first frame with a face after a no-face/lost stretch to a fit.
  int recoveries = 0;
  int max_frames_to_recover = 0;
  std::vector<int64_t> face_switches;  // frames where a more prominent face took over
  FitAgreementTally agreement;
  LightProjectionTally light;
};

// Runs the tracker over the whole input with one energy configuration. Writes the parameter
// file and meshes when their paths are given. Returns the report section of this run.
nlohmann::json run_track(const TrackArgs& a, const FaceModel& face_model, const TrackerModel& model,
                         const EnergyConfig& config, const std::string& params_path, const std::string& mesh_dir,
                         const std::string& overlay_path, const std::string& label) {
  std::error_code ec;
  const bool is_recording = std::filesystem::is_directory(a.input, ec);
  const capture::VideoReader::Options vo = video_options(a.camera, "track");
  // A recording, a video, or an OpenNI device / .oni file (every frame in order).
  std::unique_ptr<capture::FrameSource> source = live::open_offline_source(a.input, "track: --input", vo);
  const capture::RecordingInfo info = source->info();
  const bool depth = info.has_depth;
  if (a.landmarks == "recording" && !is_recording) {
    throw Error("track: --landmarks recording needs a recording folder; '" + a.input + "' is not one");
  }
  RgbdInputOptions io;
  io.landmark_source = a.landmarks == "recording" ? LandmarkSourceChoice::kRecording : LandmarkSourceChoice::kDetector;
  io.use_depth = depth && config.depth;
  PreloadLandmarkModel(io);  // read while the tracker is made
  TrackerOptions to = track_options(a, config, depth);
  to.focal_length.estimate = estimate_focal_length(a.camera, info);
  if (!parse_solver_backend(a.solver, &to.solver)) throw Error("track: --solver must be auto, cpu or vulkan");
  to.solver_device = a.device;
  FaceTracker tracker(model, to);
  RgbdInput input(io);
  const gpu::CpuRenderer renderer(model.render);

  std::ofstream params_file;
  std::string params_partial;
  if (!params_path.empty()) {
    // A file is written beside and moved into place at the end, so an interrupted run leaves the
    // last complete one; a device or pipe (/dev/null, /dev/stdout) is written directly: moving a
    // file onto it would replace the device node itself (as root, /dev/null became a plain file).
    std::error_code exists_ec;
    const bool special = std::filesystem::exists(params_path, exists_ec) &&
                         !std::filesystem::is_regular_file(params_path, exists_ec);
    params_partial = special ? params_path : params_path + ".partial";
    params_file.open(params_partial, std::ios::binary | std::ios::trunc);
    if (!params_file) throw Error("track: cannot write '" + params_partial + "'");
  }
  std::unique_ptr<FrameOutput> overlay;
  if (!overlay_path.empty()) overlay = std::make_unique<FrameOutput>(overlay_path, info.fps, cv::Size(info.camera.width, info.camera.height));
  const std::vector<FacePart> skin = {FacePart::Face, FacePart::Scalp, FacePart::Ear, FacePart::Neck};
  const bool tty = isatty(2) != 0;
  const int total_frames = a.frames > 0 ? (info.frame_count > 0 ? std::min(a.frames, info.frame_count) : a.frames)
                                        : info.frame_count;
  RunTotals r;
  int64_t last_timestamp_us = -1;
  int no_face_run_start = -1;  // first frame of the current stretch without a fit, -1 when tracking
  capture::RgbdFrame frame;
  for (int f = 0; a.frames <= 0 || f < a.frames; ++f) {
    const auto t_read = Clock::now();
    if (!source->read_next(&frame)) break;
    r.read_ms += ms_since(t_read);
    RgbdInputInfo ii;
    const InputFrame in = input.Convert(frame, &ii);
    r.convert_ms += ii.conversion_ms;
    const TrackedFrame t = tracker.Track(in, ii.landmarks_ms);
    input.SetTrackedPose(t.params, tracking_status_has_fit(t.status));
    ++r.frames;
    ++r.statuses[tracking_status_name(t.status)];
    r.landmarks_ms += t.times.landmarks_ms;
    r.pose_init_ms += t.times.pose_init_ms;
    r.pyramid_ms += t.times.pyramid_ms;
    r.synthesis_ms += t.times.synthesis_ms;
    r.analysis_ms += t.times.analysis_ms;
    r.gaze_ms += t.times.gaze_ms;
    r.gauss_newton_iterations += t.gauss_newton_iterations;
    if (t.status == TrackingStatus::kCalibrated) {
      r.calibration_ms += t.times.calibration_ms;
      r.calibration_frame = frame.index;
    }
    r.total_ms += t.times.total_ms - t.times.calibration_ms;
    ++r.tracked_frames;
    const bool fit = tracking_status_has_fit(t.status);
    r.agreement.Add(frame.index, fit, t.fit_refused(), t.agreement, t.message);
    if (fit) r.light.Add(t.light);
    if (t.new_face) r.face_switches.push_back(frame.index);
    if (!fit && no_face_run_start < 0 && f > 0) no_face_run_start = f;
    if (fit && no_face_run_start >= 0) {
      ++r.recoveries;
      r.max_frames_to_recover = std::max(r.max_frames_to_recover, f - no_face_run_start);
      no_face_run_start = -1;
    }
    std::optional<FitErrors> errors;
    if (fit && tracker.calibrated() && frame.ground_truth.params) {
      errors = CompareToGroundTruth(renderer, model, t.params, *frame.ground_truth.params, frame.camera);
      const FitErrors& e = *errors;
      ++r.evaluated;
      r.geo_mean += e.geometric_mm_mean;
      r.geo_max = std::max(r.geo_max, e.geometric_mm_max);
      r.vertex_mean += e.vertex_mm_mean;
      r.vertex_max = std::max(r.vertex_max, e.vertex_mm_max);
      r.align += e.alignment_px_mean;
      r.rot += e.rotation_deg;
      r.trans += e.translation_mm;
      r.expr += e.expression_mean_abs;
    }
    if (params_file.is_open()) {
      int64_t ts = static_cast<int64_t>(std::llround(frame.timestamp_s * 1e6));
      ts = std::max(ts, last_timestamp_us + 1);  // the replay format needs strictly increasing times
      last_timestamp_us = ts;
      nlohmann::json line = frame_json(t, frame.index, ts, tracker, model.num_expression());
      if (errors) {
        // Per frame, so a report's mean or max can be traced to the frames (and the vertex) behind it.
        line["errors"] = {{"geometric_mm_mean", errors->geometric_mm_mean},
                          {"geometric_mm_max", errors->geometric_mm_max},
                          {"geometric_max_vertex", errors->geometric_max_vertex},
                          {"vertex_mm_mean", errors->vertex_mm_mean},
                          {"vertex_mm_max", errors->vertex_mm_max},
                          {"alignment_px_mean", errors->alignment_px_mean},
                          {"rotation_deg", errors->rotation_deg},
                          {"translation_mm", errors->translation_mm},
                          {"expression_mean_abs", errors->expression_mean_abs}};
      }
      params_file << line.dump() << '\n';
      if (!params_file) throw Error("track: writing '" + params_partial + "' failed (disk full?)");
    }
    if (overlay) {
      cv::Mat drawn = frame.color.clone();
      // The status and the measures; the reasons are in the parameter file's lines.
      reenact::DrawFitOverlay(&drawn, model, renderer, t.camera, fit ? &t.params : nullptr, in.landmarks,
                              reenact::OverlayStatusLine("frame " + std::to_string(frame.index) + ": " +
                                                             tracking_status_name(t.status),
                                                         t.agreement.pose_disagreement_deg, t.agreement.landmark_nme));
      overlay->write(drawn, frame.index);
    }
    if (!mesh_dir.empty() && t.has_parameters && fit) {
      char name[64];
      std::snprintf(name, sizeof(name), "frame_%06d.ply", frame.index);
      export_mesh(face_model, mesh_of(renderer, t.params, true), skin, (std::filesystem::path(mesh_dir) / name).string());
    }
    if (!a.quiet && (tty || f % 10 == 0)) {
      const std::string of = total_frames > 0 ? "/" + std::to_string(total_frames) : "";  // unknown for devices
      std::fprintf(stderr, "%strack%s: frame %d%s %-11s %6.0f ms%s", tty ? "\r" : "", label.c_str(), f + 1, of.c_str(),
                   tracking_status_name(t.status), t.times.total_ms, tty ? "   " : "\n");
    }
  }
  if (!a.quiet && tty) std::fprintf(stderr, "\n");
  if (overlay) overlay->close();
  if (r.frames == 0) throw Error("track: '" + a.input + "' has no frames");
  if (params_file.is_open()) {
    params_file.close();
    if (!params_file) throw Error("track: writing '" + params_partial + "' failed");
    if (params_partial != params_path) {
      std::filesystem::rename(params_partial, params_path, ec);
      if (ec) throw Error("track: cannot move '" + params_partial + "' to '" + params_path + "': " + ec.message());
    }
  }
  if (!mesh_dir.empty() && tracker.calibrated()) {
    // neutral.ply: the actor's identity with no expression at all; the calibrated rest expression
    // (what Eq. 15 subtracts: a resting face is rarely all zeros) goes to its own file.
    gpu::FaceParameters identity = tracker.neutral();
    identity.delta.setZero();
    export_mesh(face_model, mesh_of(renderer, identity, false), skin, (std::filesystem::path(mesh_dir) / "neutral.ply").string());
    export_mesh(face_model, mesh_of(renderer, tracker.neutral(), false), skin,
                (std::filesystem::path(mesh_dir) / "calibrated_rest_expression.ply").string());
  }

  nlohmann::json j;
  j["frames"] = r.frames;
  j["ms_per_frame"] = r.total_ms / r.tracked_frames;
  j["landmarks_ms"] = r.landmarks_ms / r.frames;
  j["pose_init_ms"] = r.pose_init_ms / r.frames;
  j["pyramid_ms"] = r.pyramid_ms / r.frames;
  j["synthesis_ms"] = r.synthesis_ms / r.frames;
  j["analysis_ms"] = r.analysis_ms / r.frames;
  j["gauss_newton_iterations_per_frame"] = static_cast<double>(r.gauss_newton_iterations) / r.frames;
  j["gaze_ms"] = r.gaze_ms / r.frames;
  j["read_ms"] = r.read_ms / r.frames;
  j["convert_ms"] = r.convert_ms / r.frames;
  j["calibration_ms"] = r.calibration_ms;
  j["calibrated"] = tracker.calibrated();
  j["calibration_frame"] = r.calibration_frame;
  // Null when the calibrated neutral looks at rest (TrackerOptions::rest_warning_weight).
  j["calibration_warning"] =
      tracker.calibration_warning().empty() ? nlohmann::json() : nlohmann::json(tracker.calibration_warning());
  // The calibration again on the most relaxed frames after one not at rest (null: none was needed).
  j["relaxed_recalibration_frames"] = tracker.options().relaxed_recalibration_frames;
  j["relaxed_recalibration"] = relaxed_recalibration_json(tracker.relaxed_recalibration());
  // Depth against colour on the calibration's first frame with depth (null without depth).
  const tracker::DepthAlignment& da = tracker.depth_alignment();
  j["depth_alignment"] = da.measured ? nlohmann::json{{"shift_px", {da.shift_x, da.shift_y}},
                                                      {"edge_agreement_gain", da.agreement_unshifted > 0
                                                                                  ? da.agreement_best / da.agreement_unshifted
                                                                                  : 0.0},
                                                      {"edge_pixels", da.edge_pixels},
                                                      {"misaligned", da.misaligned},
                                                      {"message", da.message}}
                                     : nlohmann::json();
  if (tracker.calibrated()) {
    // Which start the joint solve kept and the final energy from each start solved (null: not solved).
    const FaceTracker::CalibrationStartReport& cs = tracker.calibration_start_report();
    auto energy = [](double e) { return json_number(e); };
    j["calibration_start"] = {{"option", calibration_start_name(tracker.options().calibration_start)},
                              {"kept", calibration_start_name(cs.kept)},
                              {"energy_from_neutral", energy(cs.neutral_energy)},
                              {"energy_from_per_frame_fits", energy(cs.per_frame_fits_energy)}};
  }
  j["statuses"] = r.statuses;
  j["recoveries"] = r.recoveries;
  j["max_frames_to_recover"] = r.max_frames_to_recover;
  j["face_switches"] = r.face_switches;
  j["agreement"] = agreement_json(r.agreement.summary());
  j["light"] = light_json(r.light);
  j["agreement_check"] = !a.no_agreement_check;
  j["energy_terms"] = {{"landmark", true}, {"regularizer", true}, {"color", config.colour},
                       {"point", config.depth && depth}, {"plane", config.depth && depth}};
  j["depth_used"] = depth && config.depth;
  j["min_face_width_px"] = tracker.options().min_face_width_px;
  j["calibration_min_face_width_px"] = tracker.options().ResolvedCalibrationMinFaceWidth();
  j["max_face_width_px"] = tracker.options().max_face_width_px;
  j["calibration_window_frames"] = tracker.options().calibration_window_frames;
  j["all_inner_landmarks"] = tracker.options().tracking_solver.energy.all_inner_landmarks;
  j["pixel_sampling"] = tracker.options().tracking_solver.energy.pixel_sampling;  // 2: every other pixel
  // What the calibration's solve ran with (every fourth pixel for a large face), else the option's.
  j["calibration_pixel_sampling"] = tracker.calibrated() ? tracker.calibration_start_report().pixel_sampling
                                                         : tracker.options().calibration_solver.energy.pixel_sampling;
  j["calibration_sparse_face_width_px"] = tracker.options().calibration_sparse_face_width_px;
  j["calibration_max_face_width_px"] = tracker.options().calibration_max_face_width_px;
  j["calibration_level"] = tracker.calibrated() ? tracker.calibration_start_report().level : -1;
  j["eye_corner_landmarks"] = tracker.options().tracking_solver.energy.eye_corner_landmarks;
  j["brow_landmarks"] = tracker.options().tracking_solver.energy.use_brow_landmarks;
  j["gaze"] = tracker.options().gaze.enabled;
  j["lids"] = tracker.options().gaze.enabled && tracker.options().gaze.read_lids;
  j["brows"] = tracker.options().brows.enabled;
  j["landmark_source"] = landmark_source_choice_name(io.landmark_source);
  j["solver"] = tracker.solver_description();
  j["camera"] = camera_json(info, a.camera, tracker.focal_length_report());
  j["intrinsics"] = intrinsics_description(a.input, info, j["camera"]);
  const bool truth = r.evaluated > 0;
  j["ground_truth"] = truth;
  j["frames_evaluated"] = r.evaluated;
  auto metric = [&](double v) { return truth ? nlohmann::json(v) : nlohmann::json(nullptr); };
  const double n = std::max(r.evaluated, 1);
  j["geometric_error_mm_mean"] = metric(r.geo_mean / n);
  j["geometric_error_mm_max"] = metric(r.geo_max);
  // Corresponding vertices: the surface error plus sliding along the skin (evaluation.h).
  j["vertex_error_mm_mean"] = metric(r.vertex_mean / n);
  j["vertex_error_mm_max"] = metric(r.vertex_max);
  j["alignment_error_px_mean"] = metric(r.align / n);
  j["rotation_error_deg_mean"] = metric(r.rot / n);
  j["translation_error_mm_mean"] = metric(r.trans / n);
  j["expression_error_mean"] = metric(r.expr / n);
  if (tracker.calibrated()) {
    const gpu::FaceParameters& nu = tracker.neutral();
    j["neutral"] = {{"alpha", vector_json(nu.alpha, model.num_identity())},
                    {"beta", vector_json(nu.beta, model.num_albedo())},
                    {"expression", vector_json(nu.delta, model.num_expression())}};
  }
  return j;
}

void run_track_command(const TrackArgs& a) {
  if (a.landmarks != "detector" && a.landmarks != "recording") {
    throw Error("track: --landmarks must be 'detector' or 'recording', not '" + a.landmarks + "'");
  }
  std::error_code ec;
  const live::InputSpec input_spec = live::parse_target_spec(a.input, "track: --input");
  if (input_spec.kind == live::InputKind::kRecording && !std::filesystem::exists(a.input, ec))
    throw Error("track: '" + a.input + "': no such file or folder");
  const auto out_parent = std::filesystem::absolute(a.out).parent_path();
  if (!std::filesystem::is_directory(out_parent, ec)) throw Error("track: the folder of --out '" + a.out + "' does not exist");
  if (!a.overlay.empty() && std::filesystem::path(a.overlay).extension() == ".mp4") check_output_file(a.overlay, "--overlay");
  if (!a.export_mesh.empty()) {
    std::filesystem::create_directories(a.export_mesh, ec);
    if (ec || !std::filesystem::is_directory(a.export_mesh)) {
      throw Error("track: cannot create --export-mesh folder '" + a.export_mesh + "'");
    }
  }
  const std::string model_path = resolve_model_path(a.model);
  const FaceModel face_model = load_face_model(model_path);
  const TrackerModel model = TrackerModel::FromFaceModel(face_model);
  const auto start = Clock::now();
  nlohmann::json report = run_track(a, face_model, model, kAllTerms, a.out, a.export_mesh, a.overlay, "");
  report["input"] = a.input;
  report["model"] = model_path;
  if (a.ablation) {
    nlohmann::json ab;
    for (const EnergyConfig& c : kAblation) {
      if (std::string(c.name) == "all") {
        ab[c.name] = report;
        ab[c.name].erase("neutral");
        continue;
      }
      if (c.depth && !report["depth_used"].get<bool>()) {
        ab[c.name] = "skipped: the input has no depth";
        continue;
      }
      nlohmann::json r = run_track(a, face_model, model, c, "", "", "", std::string(" [") + c.name + "]");
      r.erase("neutral");
      ab[c.name] = r;
    }
    report["ablation"] = ab;
  }
  report["wall_s"] = ms_since(start) / 1000.0;
  if (!a.report.empty()) {
    std::ofstream rf(a.report, std::ios::binary | std::ios::trunc);
    rf << report.dump(2) << '\n';
    if (!rf) throw Error("track: cannot write --report '" + a.report + "'");
  }
  if (!a.quiet) {
    auto num = [](const nlohmann::json& v) { return v.is_number() ? v.get<double>() : std::nan(""); };
    std::printf("track: %d frames, %.1f ms/frame (calibration %.0f ms), landmarks: %s, depth: %s\n",
                report["frames"].get<int>(), num(report["ms_per_frame"]), num(report["calibration_ms"]),
                report["landmark_source"].get<std::string>().c_str(), report["depth_used"].get<bool>() ? "yes" : "no");
    if (report["calibration_warning"].is_string())
      std::printf("  warning: %s\n", report["calibration_warning"].get<std::string>().c_str());
    std::printf("  %s\n", camera_line(report["camera"]).c_str());
    const nlohmann::json& ag = report["agreement"];
    std::printf("  against the landmarks (%d frames with a fit): pose %.1f deg median, %.1f p95, %.1f max; inner points "
                "%.1f%% of the eye distance median, %.1f%% max; %d/%d beyond %.0f deg / %.0f%%; %d fits refused%s\n",
                ag["fit_frames"].get<int>(), num(ag["pose_disagreement_deg"]["median"]), num(ag["pose_disagreement_deg"]["p95"]),
                num(ag["pose_disagreement_deg"]["max"]), 100 * num(ag["landmark_nme"]["median"]),
                100 * num(ag["landmark_nme"]["max"]), ag["fit_frames_beyond"]["pose"].get<int>(),
                ag["fit_frames_beyond"]["landmarks"].get<int>(), num(ag["limits"]["pose_disagreement_deg"]),
                100 * num(ag["limits"]["landmark_nme"]), ag["refused_frames"].get<int>(),
                report["agreement_check"].get<bool>() ? "" : " (check off)");
    if (report["ground_truth"].get<bool>()) {
      std::printf("  vs ground truth (%d frames after calibration): surface %.2f mm mean, %.2f mm max; 2D %.2f px; "
                  "rotation %.2f deg; translation %.2f mm; expression %.3f\n",
                  report["frames_evaluated"].get<int>(), num(report["geometric_error_mm_mean"]),
                  num(report["geometric_error_mm_max"]), num(report["alignment_error_px_mean"]),
                  num(report["rotation_error_deg_mean"]), num(report["translation_error_mm_mean"]),
                  num(report["expression_error_mean"]));
    }
    if (a.ablation) {
      for (const auto& [name, r] : report["ablation"].items()) {
        if (!r.is_object()) {
          std::printf("  ablation %-14s %s\n", name.c_str(), r.get<std::string>().c_str());
        } else if (r["ground_truth"].get<bool>()) {
          std::printf("  ablation %-14s surface %.2f mm mean, %.2f mm max; 2D %.2f px; rotation %.2f deg\n", name.c_str(),
                      num(r["geometric_error_mm_mean"]), num(r["geometric_error_mm_max"]),
                      num(r["alignment_error_px_mean"]), num(r["rotation_error_deg_mean"]));
        } else {
          std::printf("  ablation %-14s %.1f ms/frame (no ground truth)\n", name.c_str(), num(r["ms_per_frame"]));
        }
      }
    }
  }
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
  track->add_option("--calibration-frames", args->calibration_frames, "Frames of the timed calibration (default 5)")
      ->check(CLI::Range(1, 64));
  track->add_option("--tracking-tolerance", args->tracking_tolerance,
                    "End a level once an accepted step lowers the energy by less than this fraction, as the tracker "
                    "does (default 0: the paper's whole schedule; the tracker's own is " +
                        std::to_string(TrackerOptions{}.tracking_solver.function_tolerance) + ")")
      ->check(CLI::Range(0.0, 1.0));
  track->add_flag("--json", args->json, "Machine-readable output");
  track->add_option("--vulkan", args->vulkan.strategies,
                    "Vulkan solver strategies to run: all (default), auto, matrix-free (driven from the device, and "
                    "from the host for comparison), assembled, none");
  track->add_option("--device", args->vulkan.device, "Vulkan device: index or name part (see 'face-reenact devices')");
  track->callback([args] { run_bench_track(*args); });

  auto targs = std::make_shared<TrackArgs>();
  CLI::App* tc = app.add_subcommand("track", "Track a face in a recording or video: calibration, per-frame parameters, report");
  tc->add_option("--input", targs->input,
                 "Recording folder (face-reenact-rgbd), video file (mp4, avi, wmv: RGB only), or an OpenNI device or "
                 ".oni file (openni, openni:FILE.oni)")
      ->required();
  tc->add_option("--out", targs->out, "Per-frame parameters, JSON Lines (replayable with 'send --replay')")->required();
  tc->add_option("--report", targs->report, "JSON report: times per stage and, with ground truth, the errors");
  tc->add_option("--overlay", targs->overlay,
                 "The fit drawn over each frame (visible mesh edges, detector landmarks green, the fit's red, status "
                 "and agreement): OUT.mp4, or a folder for one PNG per frame");
  tc->add_option("--export-mesh", targs->export_mesh, "Folder for the fitted mesh per frame (PLY, camera frame, metres) and neutral.ply");
  tc->add_option("--landmarks", targs->landmarks, "Landmark source: 'detector' (default) or 'recording' (stored ground-truth landmarks)");
  tc->add_flag("--ablation", targs->ablation, "Also track with feature only, feature+colour, feature+depth (paper Fig. 12) and report each");
  tc->add_option("--frames", targs->frames, "Track at most this many frames (default: all)")->check(CLI::Range(1, 100000000));
  tc->add_option("--calibration-frames", targs->calibration_frames, "Frames of the joint identity calibration (default 5)")
      ->check(CLI::Range(1, 64));
  tc->add_option("--calibration-frame-stride", targs->calibration_frame_stride,
                 "Take the calibration frames at least this many frames apart (default 1: consecutive)")
      ->check(CLI::Range(1, 1000));
  tc->add_option("--calibration-window", targs->calibration_window,
                 "Watch this many usable frames (the actor turning the head) and calibrate on the --calibration-frames "
                 "among them with the most varied head poses (default 0: the first usable frames)")
      ->check(CLI::Range(0, 100000));
  tc->add_option("--relaxed-recalibration", targs->relaxed_recalibration,
                 "After a calibration not at rest, watch this many tracked frames for the most relaxed ones and "
                 "calibrate again on them, keeping the new identity if its neutral is more at rest (default " +
                     std::to_string(TrackerOptions{}.relaxed_recalibration_frames) + "; 0: off)")
      ->check(CLI::Range(0, 100000));
  tc->add_flag("--all-inner-landmarks", targs->all_inner_landmarks,
              "Also fit the 12 eye points and the nose base (33): for exact landmarks such as a recording's, where they "
              "read blinks; off by default (dlib's eye points do not follow a closing eyelid, and its 33 is not the "
              "model's)");
  tc->add_flag("--no-eye-corners", targs->no_eye_corners,
               "Leave the four eye corners (iBUG 36, 39, 42, 45) out of the landmark term too (fitted by default on "
               "frames without depth: they hold the model's eyes on the real ones)");
  tc->add_flag("--brow-landmarks", targs->brow_landmarks,
               "Also fit the brows (iBUG 17-26) in the solve's landmark term (off by default: the paper's 38 points "
               "have none; the brow blendshapes are read from the brow points after the solve, see --no-brows)");
  tc->add_flag("--no-brows", targs->no_brows,
               "Do not read the brow blendshapes from the detector's brow points after each solve (they are then the "
               "solver's, which barely sees a brow move)");
  char default_tolerance[32];
  std::snprintf(default_tolerance, sizeof default_tolerance, "%g", TrackerOptions{}.tracking_solver.function_tolerance);
  tc->add_option("--tracking-tolerance", targs->tracking_tolerance,
                 "End a frame's solve on a level once a step lowers the energy by less than this fraction (default " +
                     std::string(default_tolerance) +
                     "; 0 runs the paper's whole schedule, 7 + 1 iterations, on every frame)")
      ->check(CLI::Range(0.0, 1.0));
  tc->add_flag("--every-pixel", targs->every_pixel,
               "Fit the dense terms (colour, depth) on every pixel the face covers, as the paper does, in the "
               "calibration and in each frame's solve (default: every other pixel, in a checkerboard, at 0.45-0.75 "
               "of the cost and the same accuracy; a large face's calibration every fourth, see "
               "--calibration-sparse-face-width)");
  tc->add_flag("--no-gaze", targs->no_gaze,
               "Do not read the gaze and the lids from the colour around the eyes (the eyeLook and eyeBlink weights "
               "are then the solver's, which cannot see the iris turn or, without the eye landmarks, a lid close)");
  tc->add_flag("--no-lids", targs->no_lids,
               "Read the gaze but not the lids (eyeBlink): from the colour around the eyes on RGB-D input, from the "
               "detector's eye points on video");
  tc->add_option("--calibration-start", targs->calibration_start,
                 "Expressions the joint calibration starts from: neutral (default), per-frame-fits, or lower-energy "
                 "(both, keeping the lower final energy: a better surface on some actors, twice the time)")
      ->check(CLI::IsMember(std::vector<std::string>{calibration_start_name(CalibrationStart::kNeutral),
                                                     calibration_start_name(CalibrationStart::kPerFrameFits),
                                                     calibration_start_name(CalibrationStart::kLowerEnergy)}));
  tc->add_option("--min-face-width", targs->min_face_width,
                 "Track on pyramid levels where the face is at least this wide (px; default " +
                     std::to_string(TrackerOptions{}.min_face_width_px) + ", 0 = the paper's levels 2 and 1)")
      ->check(CLI::Range(0, 4096));
  add_max_face_width_option(tc, &targs->max_face_width);
  tc->add_option("--calibration-min-face-width", targs->calibration_min_face_width,
                 "The same for the calibration solve (px; default " +
                     std::to_string(TrackerOptions{}.calibration_min_face_width_px) +
                     ", -1 = --min-face-width, 0 = its schedule's level 2)")
      ->check(CLI::Range(-1, 4096));
  tc->add_option("--calibration-sparse-face-width", targs->calibration_sparse_face_width,
                 "Calibrate a face wider than this on the calibration's level on every fourth pixel instead of every "
                 "other one (px; default " +
                     std::to_string(TrackerOptions{}.calibration_sparse_face_width_px) + ", 0 = never)")
      ->check(CLI::Range(0, 4096));
  tc->add_option("--calibration-max-face-width", targs->calibration_max_face_width,
                 "Calibrate a face wider than this on the calibration's level on coarser levels (px; default " +
                     std::to_string(TrackerOptions{}.calibration_max_face_width_px) + ", 0 = never)")
      ->check(CLI::Range(0, 4096));
  add_camera_options(tc, &targs->camera);
  tc->add_flag("--no-agreement-check", targs->no_agreement_check,
              "Keep fits that disagree with the landmarks (pose beyond 15 degrees of the landmarks', inner points "
              "beyond 5% of the eye distance, a head turning faster than 600 degrees/s) instead of re-solving or "
              "losing them; the report's \"agreement\" still measures them");
  tc->add_option("--model", targs->model, "Face model file (default: the installed/generated face-model.frm)");
  tc->add_option("--solver", targs->solver,
                 "Per-frame solver: auto (Vulkan on a GPU, the CPU reference when Vulkan is a CPU driver), cpu, vulkan")
      ->check(CLI::IsMember({"auto", "cpu", "vulkan"}));
  tc->add_option("--device", targs->device, "Vulkan device for --solver vulkan/auto (index or name; default FR_VULKAN_DEVICE or automatic)");
  tc->add_flag("--quiet", targs->quiet, "No progress line or summary");
  tc->callback([targs] { run_track_command(*targs); });
}

}  // namespace

nlohmann::json time_calibration(const FramesSolveFunction& calibrate, const CalibrationBench& bench) {
  std::vector<gpu::FaceParameters> p = bench.starts;
  const SolverSummary s = calibrate(bench.frames, bench.layout, bench.options, &p);
  double residuals = 0;
  for (const auto& it : s.iterations) residuals += static_cast<double>(it.residuals);
  const int n = static_cast<int>(bench.frames.size());
  const int shared = bench.layout.num_identity + bench.layout.num_albedo;
  return {{"frames", n},
          {"unknowns", shared + n * (bench.layout.num_parameters() - shared)},
          {"gauss_newton", s.iterations.size()},
          {"residuals", s.iterations.empty() ? 0.0 : residuals / s.iterations.size()},
          {"pyramid_ms", s.pyramid_ms},
          {"input_ms", s.input_ms},
          {"synthesis_ms", s.synthesis_ms},
          {"analysis_ms", s.analysis_ms},
          {"total_ms", s.total_ms},
          {"final_energy", s.final_energy.total()},
          {"termination", termination_name(s.termination)}};
}

void print_calibration_bench(const char* who, const nlohmann::json& c) {
  std::printf("calibration (%s): %d frames, %d unknowns, %d GN iterations, %.0f residuals per iteration: %.0f ms "
              "(synthesis %.0f, analysis %.0f), final energy %.4g\n",
              who, int(c["frames"]), int(c["unknowns"]), int(c["gauss_newton"]), double(c["residuals"]),
              double(c["total_ms"]), double(c["synthesis_ms"]), double(c["analysis_ms"]), double(c["final_energy"]));
}

nlohmann::json time_track_solver(const BenchSolveFunction& solve, const std::vector<InputFrame>& frames,
                                 gpu::FaceParameters start) {
  struct LevelTotals {
    double residuals = 0, synthesis_ms = 0, analysis_ms = 0;
    int iterations = 0;
  };
  const double timed = std::max<double>(1.0, static_cast<double>(frames.size()) - 1.0);
  std::map<int, LevelTotals> levels;
  double pyramid_ms = 0, input_ms = 0, total_ms = 0, final_energy = 0, submissions = 0, submission_ms = 0,
         recording_ms = 0;
  for (size_t f = 0; f < frames.size(); ++f) {
    const SolverSummary s = solve(frames[f], &start);
    if (f == 0) continue;  // warm-up (for the Vulkan solver's auto strategy, the measurement)
    submissions += s.device_submissions;
    submission_ms += s.device_submission_ms;
    recording_ms += s.device_recording_ms;
    pyramid_ms += s.pyramid_ms;
    input_ms += s.input_ms;
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
                          {"gauss_newton_per_frame", l.iterations / timed},
                          {"residuals", l.iterations ? l.residuals / l.iterations : 0.0},
                          {"synthesis_ms_per_frame", l.synthesis_ms / timed},
                          {"analysis_ms_per_frame", l.analysis_ms / timed}});
  }
  return {{"levels", levels_doc},
          {"pyramid_ms_per_frame", pyramid_ms / timed},
          {"input_ms_per_frame", input_ms / timed},
          {"total_ms_per_frame", total_ms / timed},
          {"device_submissions_per_frame", submissions / timed},
          {"device_submission_ms_per_frame", submission_ms / timed},
          {"device_recording_ms_per_frame", recording_ms / timed},
          {"mean_final_energy", final_energy / timed}};
}

FR_REGISTER_COMMANDS(tracker, add_tracker_commands);

}  // namespace face_reenact::cli
