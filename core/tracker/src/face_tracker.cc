#include "face_reenact/tracker/face_tracker.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <limits>

#include "face_reenact/common/error.h"
#include "face_reenact/model/face_model.h"
#include "tracker_internal.h"

namespace face_reenact::tracker {
using internal::fail;
using internal::Clock;
namespace {
std::string format(const char* fmt, double a, double b = 0, double c = 0) {
  char buf[256];
  std::snprintf(buf, sizeof(buf), fmt, a, b, c);
  return buf;
}

// Landmarks of `frame` E_lan can use: confident, and inner points when the energy takes only those.
int usable_landmarks(const TrackerModel& model, const InputFrame& frame, float min_confidence, bool inner_only) {
  std::array<bool, 68> known{};
  for (const auto& l : model.landmarks) {
    if (inner_only && !(l.flags & kLandmarkInner)) continue;
    if (l.ibug_index >= 0 && l.ibug_index < 68) known[l.ibug_index] = true;
  }
  std::array<bool, 68> seen{};
  int count = 0;
  for (const auto& in : frame.landmarks) {
    if (in.ibug_index < 0 || in.ibug_index >= 68 || !known[in.ibug_index] || seen[in.ibug_index]) continue;
    if (!(in.confidence > min_confidence)) continue;
    seen[in.ibug_index] = true;
    ++count;
  }
  return count;
}

// True when an RGB-D frame has (almost) no valid depth inside the box of its landmarks: the
// dense geometric terms would have nothing to act on there (sensor dropout, a NaN map).
bool depth_missing_at_face(const InputFrame& frame, float min_confidence) {
  if (!frame.has_depth()) return false;
  double x0 = std::numeric_limits<double>::infinity(), y0 = x0, x1 = -x0, y1 = -x0;
  for (const auto& l : frame.landmarks) {
    if (!(l.confidence > min_confidence)) continue;
    x0 = std::min<double>(x0, l.position.x());
    y0 = std::min<double>(y0, l.position.y());
    x1 = std::max<double>(x1, l.position.x());
    y1 = std::max<double>(y1, l.position.y());
  }
  if (!(x1 >= x0)) return false;
  // Clamp in floating point first: landmarks may lie far outside the image.
  auto to_column = [&](double x) { return static_cast<int>(std::clamp(x, 0.0, frame.width() - 1.0)); };
  auto to_row = [&](double y) { return static_cast<int>(std::clamp(y, 0.0, frame.height() - 1.0)); };
  const int i0 = to_column(std::floor(x0)), i1 = to_column(std::ceil(x1));
  const int j0 = to_row(std::floor(y0)), j1 = to_row(std::ceil(y1));
  int64_t valid = 0, total = 0;
  for (int j = j0; j <= j1; ++j) {
    for (int i = i0; i <= i1; ++i) {
      ++total;
      valid += frame.depth_valid(i, j);
    }
  }
  return total > 0 && valid * 10 < total;
}

// A first guess of the light: an ambient SH term that makes the model's mean face albedo match
// the mean input colour around the landmarks (the solve fits the rest; gamma is linear in C_S).
std::array<float, gpu::kNumShParameters> initial_lighting(const TrackerModel& model, const InputFrame& frame) {
  Eigen::Vector3d albedo = Eigen::Vector3d::Zero();
  int n_face = 0;
  for (int v = 0; v < model.num_vertices(); ++v) {
    if (model.render.vertex_part[v] != static_cast<uint8_t>(FacePart::Face)) continue;
    albedo += model.render.mean_albedo.segment<3>(3 * v).cast<double>();
    ++n_face;
  }
  if (n_face == 0) albedo = Eigen::Vector3d::Constant(0.5);
  else albedo /= n_face;
  Eigen::Vector3d colour = Eigen::Vector3d::Zero();
  int n = 0;
  for (const auto& l : frame.landmarks) {
    if (!(l.confidence > 0.f)) continue;
    if (!(std::abs(l.position.x()) < 1e6f && std::abs(l.position.y()) < 1e6f)) continue;
    const int ci = static_cast<int>(std::lround(l.position.x())), cj = static_cast<int>(std::lround(l.position.y()));
    for (int dj = -2; dj <= 2; ++dj) {
      for (int di = -2; di <= 2; ++di) {
        const int i = ci + di, j = cj + dj;
        if (i < 0 || j < 0 || i >= frame.width() || j >= frame.height()) continue;
        const float* c = &frame.color[(static_cast<size_t>(j) * frame.width() + i) * 3];
        colour += Eigen::Vector3d(c[0], c[1], c[2]);
        ++n;
      }
    }
  }
  Eigen::Vector3f irradiance = Eigen::Vector3f::Ones();
  if (n > 0) {
    colour /= n;
    for (int c = 0; c < 3; ++c) irradiance[c] = static_cast<float>(std::clamp(colour[c] / std::max(albedo[c], 1e-3), 0.05, 5.0));
  }
  return gpu::ambient_sh(irradiance);
}

// The calibration's neutral expression against TrackerOptions::rest_warning_weight: "" when the
// actor looked at rest, else the strongest weights (ARKit names) and what to do about them.
std::string NotAtRestWarning(const TrackerModel& model, const Eigen::VectorXf& neutral, float threshold) {
  if (threshold <= 0.f) return "";
  std::vector<std::pair<float, int>> strong;
  for (Eigen::Index k = 0; k < neutral.size(); ++k)
    if (neutral[k] > threshold) strong.emplace_back(neutral[k], static_cast<int>(k));
  if (strong.empty()) return "";
  std::sort(strong.rbegin(), strong.rend());
  const auto& names = arkit_blendshape_names();
  std::string list;
  for (size_t i = 0; i < std::min<size_t>(strong.size(), 3); ++i) {
    const int k = strong[i].second;
    const std::string name = model.num_expression() == static_cast<int>(names.size()) ? names[static_cast<size_t>(k)]
                                                                                      : "blendshape " + std::to_string(k);
    list += (i ? ", " : "") + name + format(" %.2f", strong[i].first);
  }
  return "the face was not at rest while calibrating (" + list +
         "): part of that expression is now in the identity; calibrate again with a relaxed face and closed mouth";
}

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

}  // namespace

SolverOptions AdaptScheduleToFaceSize(const SolverOptions& options, double face_width_px, int min_face_width_px) {
  if (min_face_width_px <= 0 || !(face_width_px > 0) || options.schedule.empty()) return options;
  int coarsest = 0;
  for (const auto& l : options.schedule) coarsest = std::max(coarsest, l.level);
  // The coarsest level on which the face is still min_face_width_px wide.
  int allowed = 0;
  while (allowed < coarsest && face_width_px / static_cast<double>(1 << (allowed + 1)) >= min_face_width_px) ++allowed;
  const int shift = coarsest - allowed;
  if (shift <= 0) return options;
  SolverOptions out = options;
  for (auto& l : out.schedule) l.level = std::max(0, l.level - shift);
  return out;
}

double LandmarkExtentPx(const InputFrame& frame, float min_confidence) {
  float x0 = std::numeric_limits<float>::infinity(), x1 = -x0;
  int n = 0;
  for (const auto& l : frame.landmarks) {
    if (!(l.confidence > min_confidence)) continue;
    x0 = std::min(x0, l.position.x());
    x1 = std::max(x1, l.position.x());
    ++n;
  }
  return n >= 2 ? static_cast<double>(x1 - x0) : 0.0;
}

// ------------------------------------------------------------------------------------ names

const char* landmark_source_choice_name(LandmarkSourceChoice choice) {
  switch (choice) {
    case LandmarkSourceChoice::kDetector: return "detector";
    case LandmarkSourceChoice::kRecording: return "recording";
  }
  return "?";
}

int calibration_pose_swap(const std::vector<Eigen::Matrix3f>& kept, const Eigen::Matrix3f& candidate) {
  const size_t n = kept.size();
  if (n == 0) return -1;
  // Angle (radians) of the relative rotation between two head poses.
  auto angle = [](const Eigen::Matrix3f& a, const Eigen::Matrix3f& b) {
    const double c = std::clamp((static_cast<double>((a.transpose() * b).trace()) - 1.0) / 2.0, -1.0, 1.0);
    return std::acos(c);
  };
  std::vector<Eigen::Matrix3f> set = kept;
  auto spread = [&] {
    if (set.size() < 2) return 0.0;
    double sum = 0;
    for (size_t i = 0; i < set.size(); ++i) {
      double nearest = std::numeric_limits<double>::infinity();
      for (size_t j = 0; j < set.size(); ++j)
        if (j != i) nearest = std::min(nearest, angle(set[i], set[j]));
      sum += nearest;
    }
    return sum;
  };
  const double current = spread();
  int best = -1;
  double best_spread = current + 1e-6;  // a strict gain only (~0.00006 degrees)
  for (size_t i = 0; i < n; ++i) {
    set[i] = candidate;
    const double s = spread();
    if (s > best_spread) {
      best_spread = s;
      best = static_cast<int>(i);
    }
    set[i] = kept[i];
  }
  return best;
}

const char* calibration_start_name(CalibrationStart start) {
  switch (start) {
    case CalibrationStart::kNeutral: return "neutral";
    case CalibrationStart::kPerFrameFits: return "per-frame-fits";
    case CalibrationStart::kLowerEnergy: return "lower-energy";
  }
  return "?";
}

bool parse_calibration_start(const std::string& name, CalibrationStart* start) {
  for (const CalibrationStart c : {CalibrationStart::kNeutral, CalibrationStart::kPerFrameFits, CalibrationStart::kLowerEnergy}) {
    if (name == calibration_start_name(c)) {
      *start = c;
      return true;
    }
  }
  return false;
}

const char* tracking_status_name(TrackingStatus status) {
  switch (status) {
    case TrackingStatus::kCalibrating: return "calibrating";
    case TrackingStatus::kCalibrated: return "calibrated";
    case TrackingStatus::kTracking: return "tracking";
    case TrackingStatus::kRecovered: return "recovered";
    case TrackingStatus::kLost: return "lost";
    case TrackingStatus::kNoFace: return "no_face";
    case TrackingStatus::kBadInput: return "bad_input";
  }
  return "?";
}

bool tracking_status_has_fit(TrackingStatus status) {
  switch (status) {
    case TrackingStatus::kCalibrating:
    case TrackingStatus::kCalibrated:
    case TrackingStatus::kTracking:
    case TrackingStatus::kRecovered: return true;
    case TrackingStatus::kLost:
    case TrackingStatus::kNoFace:
    case TrackingStatus::kBadInput: return false;
  }
  return false;
}

// ------------------------------------------------------------------------------------ options

bool LossDetectionOptions::IsValid(std::string* why) const {
  if (min_landmarks < 3 || min_landmarks > 68) return fail(why, "tracker: loss.min_landmarks must be 3..68");
  if (!(min_landmark_confidence >= 0.f && min_landmark_confidence < 1.f)) {
    return fail(why, "tracker: loss.min_landmark_confidence must be in [0, 1)");
  }
  if (!(reinit_landmark_error_px > 0) || !std::isfinite(reinit_landmark_error_px)) {
    return fail(why, "tracker: loss.reinit_landmark_error_px must be positive");
  }
  if (!(lost_landmark_error_px > 0) || !std::isfinite(lost_landmark_error_px)) {
    return fail(why, "tracker: loss.lost_landmark_error_px must be positive");
  }
  if (!(max_energy_ratio > 1) || !std::isfinite(max_energy_ratio)) return fail(why, "tracker: loss.max_energy_ratio must be > 1");
  if (energy_history < 1 || energy_history > 10000) return fail(why, "tracker: loss.energy_history must be 1..10000");
  if (!(min_reference_energy >= 0) || !std::isfinite(min_reference_energy)) {
    return fail(why, "tracker: loss.min_reference_energy must be finite and non-negative");
  }
  if (min_dense_pixels < 0) return fail(why, "tracker: loss.min_dense_pixels must be non-negative");
  return true;
}

bool TrackerOptions::IsValid(std::string* why) const {
  if (calibration_frames < 1 || calibration_frames > 64) return fail(why, "tracker: calibration_frames must be 1..64");
  if (std::string(calibration_start_name(calibration_start)) == "?")
    return fail(why, "tracker: calibration_start is not one of neutral, per-frame-fits, lower-energy");
  if (calibration_frame_stride < 1 || calibration_frame_stride > 10000) {
    return fail(why, "tracker: calibration_frame_stride must be 1..10000");
  }
  if (calibration_window_frames < 0 || calibration_window_frames > 100000)
    return fail(why, "tracker: calibration_window_frames must be 0..100000 (0: the first usable frames)");
  if (calibration_window_frames > 0 && calibration_window_frames < calibration_frames)
    return fail(why, "tracker: calibration_window_frames must be at least calibration_frames");
  if (calibration_window_frames > 0 && calibration_frame_stride != 1)
    return fail(why, "tracker: calibration_window_frames chooses the frames itself: leave calibration_frame_stride at 1");
  if (calibration_identity_components < -1 || calibration_albedo_components < -1) {
    return fail(why, "tracker: calibration component counts must be -1 (all) or >= 0");
  }
  std::string inner;
  if (!calibration_solver.IsValid(&inner)) return fail(why, "tracker: calibration_solver: " + inner);
  if (!tracking_solver.IsValid(&inner)) return fail(why, "tracker: tracking_solver: " + inner);
  if (!recovery_solver.IsValid(&inner)) return fail(why, "tracker: recovery_solver: " + inner);
  if (!loss.IsValid(why)) return false;
  if (!gaze.IsValid(&inner)) return fail(why, "tracker: " + inner);
  if (min_face_width_px < 0 || min_face_width_px > 4096) return fail(why, "tracker: min_face_width_px must be 0..4096");
  if (calibration_min_face_width_px < -1 || calibration_min_face_width_px > 4096)
    return fail(why, "tracker: calibration_min_face_width_px must be -1..4096 (-1: min_face_width_px)");
  if (!(rest_warning_weight >= 0.f && rest_warning_weight <= 1.f))
    return fail(why, "tracker: rest_warning_weight must be in [0, 1] (0: no check)");
  if (!(default_face_distance_m > 0.1f && default_face_distance_m < 20.f)) {
    return fail(why, "tracker: default_face_distance_m must be in (0.1, 20) m");
  }
  return true;
}

// ------------------------------------------------------------------------------------ tracker

FaceTracker::FaceTracker(const FaceModel& model, const TrackerOptions& options)
    : FaceTracker(TrackerModel::FromFaceModel(model), options) {}

FaceTracker::FaceTracker(TrackerModel model, const TrackerOptions& options)
    : options_(options), solver_(std::move(model)), gaze_(solver_.model()) {
  std::string why;
  if (!options_.IsValid(&why)) throw Error(why);
  const TrackerModel& m = solver_.model();
  if (options_.calibration_identity_components > m.num_identity() ||
      options_.calibration_albedo_components > m.num_albedo()) {
    throw Error("tracker: calibration solves " + std::to_string(options_.calibration_identity_components) + " identity / " +
                std::to_string(options_.calibration_albedo_components) + " albedo components but the model has " +
                std::to_string(m.num_identity()) + " / " + std::to_string(m.num_albedo()));
  }
  Reset();
}

FaceTracker::~FaceTracker() = default;

void FaceTracker::Reset() {
  const TrackerModel& m = solver_.model();
  neutral_ = gpu::frontal_pose(options_.default_face_distance_m);
  neutral_.alpha = Eigen::VectorXf::Zero(m.num_identity());
  neutral_.beta = Eigen::VectorXf::Zero(m.num_albedo());
  neutral_.delta = Eigen::VectorXf::Zero(m.num_expression());
  identity_ = neutral_;
  calibrated_ = false;
  collecting_ = true;
  calibration_requested_.store(false);
  calibration_summary_ = SolverSummary();
  calibration_start_report_ = CalibrationStartReport();
  calibration_warning_.clear();
  ClearCalibrationFrames();
  previous_ = TrackedFrame();
  last_good_ = TrackedFrame();
  have_fit_ = false;
  energy_history_.clear();
  frames_seen_ = 0;
}

void FaceTracker::RequestCalibration() { calibration_requested_.store(true); }

void FaceTracker::SetTrackingSolver(PyramidSolveFunction solve) { tracking_solve_ = std::move(solve); }

void FaceTracker::SetCalibrationSolver(FramesSolveFunction solve) { calibration_solve_ = std::move(solve); }

TrackedFrame FaceTracker::Track(const InputFrame& frame, double landmarks_ms) {
  const auto start = Clock::now();
  TrackedFrame out;
  try {
    out = TrackImpl(frame, landmarks_ms);
  } catch (const std::exception& e) {
    // The frame passed validation but something below refused it (e.g. a frame too small for
    // the pyramid): report it for this frame and start the next one from the landmarks.
    out = TrackedFrame();
    out.frame_index = frames_seen_ - 1;
    out.status = TrackingStatus::kBadInput;
    out.message = std::string("frame not tracked: ") + e.what();
    if (last_good_.has_parameters) {
      out.has_parameters = true;
      out.params = last_good_.params;
    }
    have_fit_ = false;
  }
  out.times.landmarks_ms = landmarks_ms;
  out.times.total_ms = ms_since(start) + landmarks_ms;
  return out;
}

FaceTracker::Attempt FaceTracker::Solve(const InputFrame& input, gpu::FaceParameters start, bool reinit,
                                        StageTimes* times) const {
  Attempt a;
  a.reinit = reinit;
  const TrackerModel& m = solver_.model();
  if (reinit) {
    const auto t0 = Clock::now();
    PoseInitOptions po;
    po.min_landmarks = std::min(options_.loss.min_landmarks, 68);
    po.min_confidence = options_.loss.min_landmark_confidence;
    po.default_distance_m = options_.default_face_distance_m;
    const PoseInitResult pose = InitializePoseFromLandmarks(m, input, start, po);
    times->pose_init_ms += ms_since(t0);
    a.pose_message = pose.message;
    if (!pose.ok) {
      a.failure = pose.message;
      a.params = start;
      return a;
    }
    start.euler = pose.euler;
    start.translation = pose.translation;
  }
  const SolverOptions so = WithStop(
      AdaptScheduleToFaceSize(reinit ? options_.recovery_solver : options_.tracking_solver,
                              LandmarkExtentPx(input, options_.loss.min_landmark_confidence), options_.min_face_width_px));
  const auto t_pyr = Clock::now();
  const std::vector<InputFrame> pyramid = BuildPyramid(input, so.pyramid, so.ResolvedThreads());
  times->pyramid_ms += ms_since(t_pyr);
  const ParameterLayout layout = ParameterLayout::Tracking(m.num_expression());
  a.params = start;
  a.summary = tracking_solve_ ? tracking_solve_(pyramid, layout, so, &a.params) : solver_.Solve(pyramid, layout, so, &a.params);
  times->synthesis_ms += a.summary.synthesis_ms;
  times->analysis_ms += a.summary.analysis_ms;
  a.landmark_error_px = LandmarkReprojectionError(m, input, a.params, options_.loss.min_landmark_confidence,
                                                  so.energy.inner_landmarks_only);
  if (a.summary.termination == Termination::kNoValidResiduals) {
    a.failure = "no valid residuals (" + a.summary.message + ")";
  } else if (a.summary.termination == Termination::kNonFinite) {
    a.failure = "the solve diverged (" + a.summary.message + ")";
  } else if (!(a.landmark_error_px <= options_.loss.lost_landmark_error_px)) {
    a.failure = format("landmarks %.1f px from the fitted model (limit %.1f px)", a.landmark_error_px,
                       options_.loss.lost_landmark_error_px);
  }
  if (a.failure.empty() && options_.gaze.enabled) {
    // The lids only on fits that place the eyes well: with depth and the calibrated identity
    // (before the calibration, on the mean face, open eyes read 0.5-1.0 on synthetic actors).
    a.gaze = gaze_.Read(solver_.renderer(), input, &a.params, options_.gaze,
                        calibrated_ && (so.energy.use_point || so.energy.use_plane));
    times->gaze_ms += a.gaze.ms;
  }
  return a;
}

TrackedFrame FaceTracker::TrackImpl(const InputFrame& frame, double /*landmarks_ms*/) {
  TrackedFrame out;
  out.frame_index = frames_seen_++;
  if (calibration_requested_.exchange(false)) {
    collecting_ = true;
    ClearCalibrationFrames();
  }
  auto hold = [&](TrackingStatus status, const std::string& message) {
    out.status = status;
    out.message = message;
    if (last_good_.has_parameters) {
      out.has_parameters = true;
      out.params = last_good_.params;
    }
    return out;
  };
  const TrackerModel& m = solver_.model();
  std::string why;
  if (!frame.IsValid(&why)) return hold(TrackingStatus::kBadInput, "bad input frame: " + why);
  const int min_levels_size = 1 << (std::max({options_.tracking_solver.pyramid.levels, options_.recovery_solver.pyramid.levels,
                                              options_.calibration_solver.pyramid.levels}) - 1);
  if (frame.width() < 2 * min_levels_size || frame.height() < 2 * min_levels_size) {
    return hold(TrackingStatus::kBadInput, "bad input frame: " + std::to_string(frame.width()) + "x" +
                                               std::to_string(frame.height()) + " is too small for the pyramid");
  }
  const bool inner_only = options_.tracking_solver.energy.inner_landmarks_only;
  out.landmarks_used = usable_landmarks(m, frame, options_.loss.min_landmark_confidence, inner_only);
  if (out.landmarks_used < options_.loss.min_landmarks) {
    have_fit_ = false;
    return hold(TrackingStatus::kNoFace, "no face: " + std::to_string(out.landmarks_used) + " usable landmarks, " +
                                             std::to_string(options_.loss.min_landmarks) + " needed");
  }

  // All-invalid depth where the face is (sensor dropout, a NaN map): fit colour and landmarks
  // only, as for RGB-only input, instead of a fit pulled by the few depth samples left.
  const InputFrame* input = &frame;
  InputFrame no_depth;
  const bool depth_dropped = depth_missing_at_face(frame, options_.loss.min_landmark_confidence);
  if (depth_dropped) {
    no_depth.camera = frame.camera;
    no_depth.color = frame.color;
    no_depth.landmarks = frame.landmarks;
    input = &no_depth;
  }

  if (collecting_ && !options_.track_while_calibrating) {
    // Calibration frames without a per-frame solve: the landmark pose is the joint solve's start.
    gpu::FaceParameters start = identity_;
    start.delta = neutral_.delta;
    start.gamma = last_good_.has_parameters ? last_good_.params.gamma : initial_lighting(m, *input);
    PoseInitOptions po;
    po.min_landmarks = options_.loss.min_landmarks;
    po.min_confidence = options_.loss.min_landmark_confidence;
    po.default_distance_m = options_.default_face_distance_m;
    const auto t0 = Clock::now();
    const PoseInitResult pose = InitializePoseFromLandmarks(m, *input, start, po);
    out.times.pose_init_ms += ms_since(t0);
    if (!pose.ok) {
      have_fit_ = false;
      return hold(TrackingStatus::kLost, "lost: " + pose.message);
    }
    start.euler = pose.euler;
    start.translation = pose.translation;
    out.status = TrackingStatus::kCalibrating;
    out.pose_reinitialized = true;
    OfferCalibrationFrame(*input, start, out.frame_index);
    out.message = CalibrationProgress() + " (" + pose.message + "; not fitted yet)";
    if (CalibrationReady()) {
      Calibrate(*input, start, &out);
      if (out.status == TrackingStatus::kCalibrated) {
        have_fit_ = true;
        previous_ = out;
        last_good_ = out;
      }
    }
    return out;
  }

  // Warm start from the previous frame, or a re-initialisation from the landmarks.
  gpu::FaceParameters start;
  bool reinit = !have_fit_;
  std::string reinit_reason = have_fit_ ? "" : (last_good_.has_parameters ? "re-acquired the face" : "first face");
  if (have_fit_) {
    start = previous_.params;
    start.alpha = identity_.alpha;
    start.beta = identity_.beta;
    const double err = LandmarkReprojectionError(m, *input, start, options_.loss.min_landmark_confidence, inner_only);
    if (err > options_.loss.reinit_landmark_error_px) {
      reinit = true;
      reinit_reason = format("landmarks %.1f px from the previous fit", err);
    }
  } else {
    start = identity_;
    start.delta = neutral_.delta;
    start.gamma = last_good_.has_parameters ? last_good_.params.gamma : initial_lighting(m, *input);
  }

  Attempt a = Solve(*input, start, reinit, &out.times);
  // Energy jump: far above the recent level of this track.
  auto check_energy = [&](Attempt* at) {
    if (!at->failure.empty() || depth_dropped) return;
    if (static_cast<int>(energy_history_.size()) < std::min(5, options_.loss.energy_history)) return;
    const double ref = median(energy_history_);
    const double e = at->summary.final_energy.total();
    if (ref > options_.loss.min_reference_energy && !(e <= options_.loss.max_energy_ratio * ref)) {
      at->failure = format("energy %.4g is %.1fx the recent median %.4g", e, e / ref, ref);
    }
  };
  check_energy(&a);
  if (!a.failure.empty() && !reinit) {
    const std::string first_failure = a.failure;
    start.delta = neutral_.delta;
    Attempt b = Solve(*input, start, true, &out.times);
    check_energy(&b);
    reinit_reason = first_failure;
    if (b.failure.empty() || (b.landmark_error_px >= 0 && b.landmark_error_px < a.landmark_error_px)) a = std::move(b);
    reinit = a.reinit;
  }
  out.params = a.params;
  out.has_parameters = true;
  out.energy = a.summary.final_energy;
  out.residuals = a.summary.iterations.empty() ? 0 : a.summary.iterations.back().residuals;
  out.landmark_error_px = a.landmark_error_px;
  out.pose_reinitialized = a.reinit;
  out.solver_termination = a.summary.termination;
  out.gaze = a.gaze;
  const std::string depth_note = depth_dropped ? "; no valid depth at the face: fitted colour and landmarks only" : "";
  if (!a.failure.empty()) {
    have_fit_ = false;
    out.status = TrackingStatus::kLost;
    out.message = "lost: " + a.failure + depth_note;
    return out;
  }
  have_fit_ = true;
  out.message = format("E %.4g, landmarks %.1f px", out.energy.total(), out.landmark_error_px);
  if (reinit) {
    out.status = TrackingStatus::kRecovered;
    out.message = "recovered (" + reinit_reason + "; " + a.pose_message + "): " + out.message;
  } else {
    out.status = TrackingStatus::kTracking;
    out.message = "tracking: " + out.message;
  }
  out.message += depth_note;
  if (!depth_dropped) {
    energy_history_.push_back(out.energy.total());
    if (static_cast<int>(energy_history_.size()) > options_.loss.energy_history) energy_history_.erase(energy_history_.begin());
  }

  if (collecting_) {
    const std::string fit_message = out.message;
    out.status = TrackingStatus::kCalibrating;
    OfferCalibrationFrame(*input, out.params, out.frame_index);
    out.message = CalibrationProgress() + "; " + fit_message;
    if (CalibrationReady()) Calibrate(*input, out.params, &out);
  }
  previous_ = out;
  last_good_ = out;
  return out;
}

void FaceTracker::OfferCalibrationFrame(const InputFrame& input, const gpu::FaceParameters& start, int64_t frame_index) {
  ++calibration_frames_seen_;
  const int kept = static_cast<int>(calibration_inputs_.size());
  if (kept < options_.calibration_frames) {
    if (frame_index - last_calibration_pick_ < options_.calibration_frame_stride) return;
    calibration_inputs_.push_back(input);
    calibration_starts_.push_back(start);
    last_calibration_pick_ = frame_index;
    calibration_frame_indices_.push_back(frame_index);
    return;
  }
  // A full set takes no more frames, except within a window, where a frame that widens the
  // spread of head poses replaces one (a set kept after a stopped calibration counts as seen).
  if (options_.calibration_window_frames == 0 || calibration_frames_seen_ > options_.calibration_window_frames) return;
  std::vector<Eigen::Matrix3f> rotations;
  rotations.reserve(calibration_starts_.size());
  for (const auto& p : calibration_starts_) rotations.push_back(gpu::rotation_from_euler(p.euler));
  const int swap = calibration_pose_swap(rotations, gpu::rotation_from_euler(start.euler));
  if (swap < 0) return;
  calibration_inputs_[static_cast<size_t>(swap)] = input;
  calibration_starts_[static_cast<size_t>(swap)] = start;
  calibration_frame_indices_[static_cast<size_t>(swap)] = frame_index;
}

bool FaceTracker::CalibrationReady() const {
  return static_cast<int>(calibration_inputs_.size()) >= options_.calibration_frames &&
         calibration_frames_seen_ >= options_.calibration_window_frames;
}

void FaceTracker::ClearCalibrationFrames() {
  calibration_inputs_.clear();
  calibration_starts_.clear();
  calibration_frame_indices_.clear();
  last_calibration_pick_ = std::numeric_limits<int64_t>::min() / 2;
  calibration_frames_seen_ = 0;
}

std::string FaceTracker::CalibrationProgress() const {
  std::string m = "calibrating: " + std::to_string(calibration_inputs_.size()) + " of " +
                  std::to_string(options_.calibration_frames) + " frames";
  if (options_.calibration_window_frames > 0)
    m += " (watching " + std::to_string(std::min(calibration_frames_seen_, options_.calibration_window_frames)) + " of " +
         std::to_string(options_.calibration_window_frames) + ": turn your head slowly left and right)";
  return m;
}

SolverOptions FaceTracker::WithStop(SolverOptions options) const {
  if (options_.stop.stop_possible()) options.stop = options_.stop;
  return options;
}

void FaceTracker::Calibrate(const InputFrame& current, const gpu::FaceParameters& current_start, TrackedFrame* out) {
  const TrackerModel& m = solver_.model();
  const int n_id = options_.calibration_identity_components < 0 ? m.num_identity() : options_.calibration_identity_components;
  const int n_alb = options_.calibration_albedo_components < 0 ? m.num_albedo() : options_.calibration_albedo_components;
  const ParameterLayout layout = ParameterLayout::Calibration(n_id, n_alb, m.num_expression());
  // Take the collected frames out first, so that a solve that throws (caught in Track) starts a
  // fresh collection instead of retrying the same set on every frame.
  std::vector<InputFrame> inputs = std::move(calibration_inputs_);
  std::vector<gpu::FaceParameters> params = std::move(calibration_starts_);
  const std::vector<int64_t> frame_indices = std::move(calibration_frame_indices_);
  ClearCalibrationFrames();
  double face_width = std::numeric_limits<double>::infinity();
  for (const auto& f : inputs) face_width = std::min(face_width, LandmarkExtentPx(f, options_.loss.min_landmark_confidence));
  const SolverOptions so =
      WithStop(AdaptScheduleToFaceSize(options_.calibration_solver, face_width, options_.ResolvedCalibrationMinFaceWidth()));
  const std::vector<gpu::FaceParameters> starts = params;
  // One joint solve from the per-frame fits' expressions or from neutral, into `*p`.
  auto solve_from = [&](CalibrationStart start, std::vector<gpu::FaceParameters>* p) {
    *p = starts;
    if (start == CalibrationStart::kNeutral)
      for (auto& f : *p) f.delta.setZero();
    return calibration_solve_ ? calibration_solve_(inputs, layout, so, p) : solver_.SolveFrames(inputs, layout, so, p);
  };
  // A solve that found no valid residuals or went non-finite leaves no identity to keep.
  auto failed = [](const SolverSummary& s) {
    return s.termination == Termination::kNoValidResiduals || s.termination == Termination::kNonFinite;
  };
  auto usable = [&](const SolverSummary& s) { return s.termination != Termination::kStopped && !failed(s); };
  CalibrationStartReport report;
  report.kept = options_.calibration_start == CalibrationStart::kPerFrameFits ? CalibrationStart::kPerFrameFits
                                                                             : CalibrationStart::kNeutral;
  const auto t0 = Clock::now();
  SolverSummary summary = solve_from(report.kept, &params);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  (report.kept == CalibrationStart::kNeutral ? report.neutral_energy : report.per_frame_fits_energy) =
      usable(summary) ? summary.final_energy.total() : nan;
  // All-zero per-frame expressions are the neutral start again.
  const bool fits_start_differs =
      std::any_of(starts.begin(), starts.end(), [](const gpu::FaceParameters& p) { return !p.delta.isZero(0.f); });
  if (options_.calibration_start == CalibrationStart::kLowerEnergy && fits_start_differs &&
      summary.termination != Termination::kStopped) {
    std::vector<gpu::FaceParameters> other;
    SolverSummary other_summary = solve_from(CalibrationStart::kPerFrameFits, &other);
    report.per_frame_fits_energy = usable(other_summary) ? other_summary.final_energy.total() : nan;
    // The lower energy wins among the usable results (a tie keeps neutral); a stop in either
    // solve stops the calibration.
    const bool take_other =
        other_summary.termination == Termination::kStopped ||
        (usable(other_summary) && (!usable(summary) || other_summary.final_energy.total() < summary.final_energy.total()));
    if (take_other) {
      summary = std::move(other_summary);
      params = std::move(other);
      report.kept = CalibrationStart::kPerFrameFits;
    }
  }
  out->times.calibration_ms = ms_since(t0);
  const int frames = static_cast<int>(inputs.size());
  if (summary.termination == Termination::kStopped) {
    // Half a calibration is not an identity: keep the old one and the collected frames.
    out->message = "calibration over " + std::to_string(frames) + " frames stopped before it finished (" + summary.message + ")";
    calibration_inputs_ = std::move(inputs);
    calibration_starts_ = starts;
    calibration_frame_indices_ = frame_indices;
    calibration_frames_seen_ = options_.calibration_window_frames;
    calibration_summary_ = std::move(summary);
    return;
  }
  if (failed(summary)) {
    // Keep the previous identity and collect a fresh set of frames.
    out->message = "calibration over " + std::to_string(frames) + " frames failed (" + summary.message +
                   "); collecting new frames";
    calibration_summary_ = std::move(summary);
    return;
  }
  identity_.alpha = params[0].alpha;
  identity_.beta = params[0].beta;
  neutral_ = params[0];
  Eigen::VectorXf mean_delta = Eigen::VectorXf::Zero(m.num_expression());
  for (const auto& p : params) {
    Eigen::VectorXf d = Eigen::VectorXf::Zero(m.num_expression());
    d.head(std::min<Eigen::Index>(p.delta.size(), d.size())) = p.delta.head(std::min<Eigen::Index>(p.delta.size(), d.size()));
    mean_delta += d;
  }
  neutral_.delta = mean_delta / static_cast<float>(params.size());
  // A tracking solve of `input` (identity fixed at the new one), warm-started from `start`.
  auto track_with_new_identity = [&](const InputFrame& input, gpu::FaceParameters start) {
    start.alpha = identity_.alpha;
    start.beta = identity_.beta;
    return Solve(input, start, /*reinit=*/false, &out->times);
  };
  if (options_.neutral_from_tracking) {
    // Re-read each calibration frame the way tracking reads frames (identity fixed, tracking
    // prior, warm start from the joint solve), so Eq. 15 subtracts a neutral in the same terms
    // as the expressions it is subtracted from. Frames whose fit fails keep no say.
    Eigen::VectorXf sum = Eigen::VectorXf::Zero(m.num_expression());
    int fitted = 0;
    for (size_t f = 0; f < inputs.size(); ++f) {
      const Attempt a = track_with_new_identity(inputs[f], params[f]);
      if (!a.failure.empty() || a.summary.termination == Termination::kStopped) continue;
      const Eigen::Index k = std::min<Eigen::Index>(a.params.delta.size(), sum.size());
      sum.head(k) += a.params.delta.head(k);
      ++fitted;
    }
    if (fitted > 0) neutral_.delta = sum / static_cast<float>(fitted);
  }
  // Gaze is absolute: the rest of the eyes is looking straight ahead, whatever the actor looked at
  // while calibrating. Eq. 15 subtracts the neutral, so a neutral that kept a glance aside would
  // turn the reenacted eyes away whenever the source looked straight at the camera; and gaze does
  // not enter the identity, so it is no sign of a calibration not at rest either.
  if (gaze_.available() && neutral_.delta.size() >= m.num_expression()) {
    for (const GazeEstimator::Weight& w : gaze_.WeightsFor(0.f, 0.f)) neutral_.delta[w.index] = 0.f;
  }
  calibrated_ = true;
  collecting_ = false;
  calibration_start_report_ = report;
  energy_history_.clear();  // energies with the new identity are not comparable to the old
  // This frame's parameters: its joint fit when it is a calibration frame (always, without a
  // window: it completed the set), else a tracking solve with the new identity.
  const auto in_set = std::find(frame_indices.begin(), frame_indices.end(), out->frame_index);
  if (in_set != frame_indices.end()) {
    out->params = params[static_cast<size_t>(in_set - frame_indices.begin())];
  } else {
    const Attempt a = track_with_new_identity(current, current_start);
    out->params = a.failure.empty() ? a.params : current_start;
  }
  out->params.alpha = identity_.alpha;
  out->params.beta = identity_.beta;
  out->landmark_error_px = LandmarkReprojectionError(m, current, out->params, options_.loss.min_landmark_confidence,
                                                     options_.calibration_solver.energy.inner_landmarks_only);
  out->has_parameters = true;
  out->status = TrackingStatus::kCalibrated;
  std::string start_note = std::string("from the ") + (report.kept == CalibrationStart::kNeutral ? "neutral" : "per-frame fits'") +
                           " expressions";
  if (!std::isnan(report.neutral_energy) && !std::isnan(report.per_frame_fits_energy))
    start_note += format(", E %.4g against %.4g", summary.final_energy.total(),
                         report.kept == CalibrationStart::kNeutral ? report.per_frame_fits_energy : report.neutral_energy) +
                  (report.kept == CalibrationStart::kNeutral ? " from the per-frame fits'" : " from neutral");
  out->message = "calibrated over " + std::to_string(frames) + " frames " + start_note + " (" + summary.BriefReport() + ")";
  calibration_warning_ = NotAtRestWarning(m, neutral_.delta, options_.rest_warning_weight);
  if (!calibration_warning_.empty()) out->message += "; " + calibration_warning_;
  calibration_summary_ = std::move(summary);
}

}  // namespace face_reenact::tracker
