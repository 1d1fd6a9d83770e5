#include "face_reenact/tracker/face_tracker.h"

#include <pthread.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <functional>
#include <limits>
#include <thread>

#include "face_reenact/common/error.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/tracker/plausible_light.h"
#include "face_reenact/tracker/solver_choice.h"
#include "tracker_internal.h"

namespace face_reenact::tracker {
using internal::Clock;
using internal::format;
using internal::median;
namespace {

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

// Blendshape k's ARKit name, for messages ("blendshape k" on a model with other blendshapes).
std::string BlendshapeName(const TrackerModel& model, Eigen::Index k) {
  const auto& names = arkit_blendshape_names();
  if (model.num_expression() == static_cast<int>(names.size()) && k >= 0 && k < static_cast<Eigen::Index>(names.size()))
    return names[static_cast<size_t>(k)];
  return "blendshape " + std::to_string(k);
}

// The calibration's neutral expression against TrackerOptions::rest_warning_weight: "" when the
// actor looked at rest, else the strongest weights (ARKit names) and what to do about them.
// `neutral` holds no gaze and no brows the brow reader reads (ApplyCalibration clears them), so
// its strongest weight is FaceTracker::RestWeight's.
std::string NotAtRestWarning(const TrackerModel& model, const Eigen::VectorXf& neutral, float threshold) {
  if (threshold <= 0.f) return "";
  std::vector<std::pair<float, int>> strong;
  for (Eigen::Index k = 0; k < neutral.size(); ++k)
    if (neutral[k] > threshold) strong.emplace_back(neutral[k], static_cast<int>(k));
  if (strong.empty()) return "";
  std::sort(strong.rbegin(), strong.rend());
  std::string list;
  for (size_t i = 0; i < std::min<size_t>(strong.size(), 3); ++i)
    list += (i ? ", " : "") + BlendshapeName(model, strong[i].second) + format(" %.2f", strong[i].first);
  return "the face was not at rest while calibrating (" + list +
         "): part of that expression is now in the identity; calibrate again with a relaxed face and closed mouth";
}

// `frame` seen through `camera` (a copy: used on the calibration frames, not per tracked frame).
InputFrame WithCamera(const InputFrame& frame, const gpu::PinholeCamera& camera) {
  InputFrame f = frame;
  f.camera = camera;
  return f;
}


}  // namespace

struct FaceTracker::CalibrationOutcome {
  // The set, as collected.
  std::vector<InputFrame> inputs;
  std::vector<gpu::FaceParameters> starts;  // the joint solve's starts (per-frame fits or landmark poses)
  std::vector<int64_t> frame_indices;
  // What the solve found.
  std::vector<gpu::FaceParameters> params;  // the joint fit of each frame
  SolverSummary summary;
  CalibrationStartReport report;
  Eigen::VectorXf neutral_delta;  // the neutral expression (TrackerOptions::neutral_from_tracking)
  // The focal length search (TrackerOptions::focal_length), decided on the tracking thread.
  bool search_focal_length = false;
  FocalLengthEstimate focal_length;
  // The set's first frame with depth against its colour (depth_alignment.h), measured beside the
  // solve (on the calibration's thread when it runs in the background).
  DepthAlignment depth_alignment;
  double solve_ms = 0;            // the joint solve(s)
  // A calibration on the most relaxed frames after one not at rest: that one's strongest weight,
  // which this one's neutral has to beat to be kept (NaN: an ordinary calibration).
  float relaxed_of = std::numeric_limits<float>::quiet_NaN();
  StageTimes reread_times;        // the neutral's re-reads
};

// One calibration on a thread of its own. The tracking thread polls done() at each Track() and
// then takes the outcome; destroying it (a new request, Reset, the tracker going away) stops the
// solve within one Gauss-Newton iteration and joins the thread.
class FaceTracker::BackgroundCalibration {
 public:
  BackgroundCalibration(const FaceTracker& tracker, CalibrationOutcome outcome, const std::stop_token& owner_stop)
      : outcome_(std::move(outcome)),
        frames_(static_cast<int>(outcome_.inputs.size())),
        started_(Clock::now()),
        owner_link_(owner_stop, [this] { stop_.request_stop(); }) {
    thread_ = std::thread([this, &tracker] {
      pthread_setname_np(pthread_self(), "fr-calibrate");
      try {
        tracker.SolveCalibration(&outcome_, stop_.get_token());
      } catch (const std::exception& e) {
        error_ = e.what();
      }
      done_.store(true, std::memory_order_release);
    });
  }
  ~BackgroundCalibration() {
    stop_.request_stop();
    if (thread_.joinable()) thread_.join();
  }
  BackgroundCalibration(const BackgroundCalibration&) = delete;
  BackgroundCalibration& operator=(const BackgroundCalibration&) = delete;

  bool done() const { return done_.load(std::memory_order_acquire); }
  int frames() const { return frames_; }
  double seconds() const { return std::chrono::duration<double>(Clock::now() - started_).count(); }
  // Once done(): the outcome, or the solve's exception as an Error.
  CalibrationOutcome Take() {
    thread_.join();
    if (!error_.empty()) throw Error(error_);
    return std::move(outcome_);
  }

 private:
  CalibrationOutcome outcome_;
  const int frames_;
  const Clock::time_point started_;
  std::string error_;
  std::atomic<bool> done_{false};
  std::stop_source stop_;
  std::stop_callback<std::function<void()>> owner_link_;  // the owner's stop stops the solve too
  std::thread thread_;  // last: starts once everything above exists
};

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

SolverOptions SparserSamplingForLargeFace(const SolverOptions& options, double face_width_px,
                                          int sparse_face_width_px) {
  if (sparse_face_width_px <= 0 || !(face_width_px > 0) || options.schedule.empty() ||
      options.energy.pixel_sampling != 2)
    return options;
  if (face_width_px / static_cast<double>(1 << FinestScheduledLevel(options)) <= sparse_face_width_px) return options;
  SolverOptions out = options;
  out.energy.pixel_sampling = 4;
  return out;
}

int FinestScheduledLevel(const SolverOptions& options) {
  if (options.schedule.empty()) return 0;
  int finest = options.schedule.front().level;
  for (const auto& l : options.schedule) finest = std::min(finest, l.level);
  return finest;
}

SolverOptions CalibrationSolverForFace(const TrackerOptions& options, double face_width_px) {
  const int min_width = options.ResolvedCalibrationMinFaceWidth();
  const SolverOptions sized = AdaptScheduleToFaceSize(options.calibration_solver, face_width_px, min_width);
  const int coarser = LargeFaceCoarsening(sized, face_width_px, options.calibration_max_face_width_px, min_width, 0);
  return SparserSamplingForLargeFace(CoarsenSchedule(sized, coarser), face_width_px,
                                     options.calibration_sparse_face_width_px);
}

int LargeFaceCoarsening(const SolverOptions& options, double face_width_px, int max_face_width_px,
                        int min_face_width_px, int current) {
  if (max_face_width_px <= 0 || !(face_width_px > 0) || options.schedule.empty()) return 0;
  const int finest = FinestScheduledLevel(options);
  int coarsest = finest;
  for (const auto& l : options.schedule) coarsest = std::max(coarsest, l.level);
  // Level k holds the face at face_width_px / 2^k. Never so coarse that the coarsest solved level
  // holds it under min_face_width_px (nor more than 8 levels: a 256x smaller frame).
  int limit = 0;
  while (limit < 8 && face_width_px / static_cast<double>(1 << (coarsest + limit + 1)) >= min_face_width_px) ++limit;
  const auto width_at = [&](int shift) { return face_width_px / static_cast<double>(1 << (finest + shift)); };
  int shift = std::clamp(current, 0, limit);
  while (shift < limit && width_at(shift) > max_face_width_px) ++shift;
  while (shift > 0 && width_at(shift - 1) <= 0.8 * max_face_width_px) --shift;
  return shift;
}

SolverOptions CoarsenSchedule(const SolverOptions& options, int levels) {
  if (levels <= 0) return options;
  SolverOptions out = options;
  int coarsest = 0;
  for (auto& l : out.schedule) {
    l.level += levels;
    coarsest = std::max(coarsest, l.level);
  }
  out.pyramid.levels = std::max(out.pyramid.levels, coarsest + 1);
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
  if (min_landmarks < 3 || min_landmarks > 68) return fail_why(why, "tracker: loss.min_landmarks must be 3..68");
  if (!(min_landmark_confidence >= 0.f && min_landmark_confidence < 1.f)) {
    return fail_why(why, "tracker: loss.min_landmark_confidence must be in [0, 1)");
  }
  if (!(reinit_landmark_error_px > 0) || !std::isfinite(reinit_landmark_error_px)) {
    return fail_why(why, "tracker: loss.reinit_landmark_error_px must be positive");
  }
  if (!(lost_landmark_error_px > 0) || !std::isfinite(lost_landmark_error_px)) {
    return fail_why(why, "tracker: loss.lost_landmark_error_px must be positive");
  }
  if (!(max_energy_ratio > 1) || !std::isfinite(max_energy_ratio)) return fail_why(why, "tracker: loss.max_energy_ratio must be > 1");
  if (energy_history < 1 || energy_history > 10000) return fail_why(why, "tracker: loss.energy_history must be 1..10000");
  if (!(min_reference_energy >= 0) || !std::isfinite(min_reference_energy)) {
    return fail_why(why, "tracker: loss.min_reference_energy must be finite and non-negative");
  }
  if (min_dense_pixels < 0) return fail_why(why, "tracker: loss.min_dense_pixels must be non-negative");
  std::string inner;
  if (!agreement.IsValid(&inner)) return fail_why(why, "tracker: loss." + inner);
  return true;
}

bool TrackerOptions::IsValid(std::string* why) const {
  if (calibration_frames < 1 || calibration_frames > 64) return fail_why(why, "tracker: calibration_frames must be 1..64");
  if (!focal_length.IsValid(why)) return false;
  if (std::string(calibration_start_name(calibration_start)) == "?")
    return fail_why(why, "tracker: calibration_start is not one of neutral, per-frame-fits, lower-energy");
  if (calibration_frame_stride < 1 || calibration_frame_stride > 10000) {
    return fail_why(why, "tracker: calibration_frame_stride must be 1..10000");
  }
  if (calibration_window_frames < 0 || calibration_window_frames > 100000)
    return fail_why(why, "tracker: calibration_window_frames must be 0..100000 (0: the first usable frames)");
  if (calibration_window_frames > 0 && calibration_window_frames < calibration_frames)
    return fail_why(why, "tracker: calibration_window_frames must be at least calibration_frames");
  if (calibration_window_frames > 0 && calibration_frame_stride != 1)
    return fail_why(why, "tracker: calibration_window_frames chooses the frames itself: leave calibration_frame_stride at 1");
  if (relaxed_recalibration_frames < 0 || relaxed_recalibration_frames > 100000)
    return fail_why(why, "tracker: relaxed_recalibration_frames must be 0..100000 (0: off)");
  if (relaxed_recalibration_frames > 0 && relaxed_recalibration_frames < calibration_frames)
    return fail_why(why, "tracker: relaxed_recalibration_frames must be at least calibration_frames (or 0: off)");
  if (!(relaxed_margin >= 0.f && relaxed_margin <= 1.f)) return fail_why(why, "tracker: relaxed_margin must be 0..1");
  if (!(relaxed_recalibration_above >= 0.f && relaxed_recalibration_above <= 1.f))
    return fail_why(why, "tracker: relaxed_recalibration_above must be 0..1");
  if (calibration_identity_components < -1 || calibration_albedo_components < -1) {
    return fail_why(why, "tracker: calibration component counts must be -1 (all) or >= 0");
  }
  std::string inner;
  if (!calibration_solver.IsValid(&inner)) return fail_why(why, "tracker: calibration_solver: " + inner);
  if (!tracking_solver.IsValid(&inner)) return fail_why(why, "tracker: tracking_solver: " + inner);
  if (!recovery_solver.IsValid(&inner)) return fail_why(why, "tracker: recovery_solver: " + inner);
  if (!loss.IsValid(why)) return false;
  if (!gaze.IsValid(&inner)) return fail_why(why, "tracker: " + inner);
  if (!eye_openness.IsValid(&inner)) return fail_why(why, "tracker: " + inner);
  if (!brows.IsValid(&inner)) return fail_why(why, "tracker: " + inner);
  if (!depth_alignment.IsValid(&inner)) return fail_why(why, "tracker: " + inner);
  if (min_face_width_px < 0 || min_face_width_px > 4096) return fail_why(why, "tracker: min_face_width_px must be 0..4096");
  if (max_face_width_px < 0 || max_face_width_px > 4096) return fail_why(why, "tracker: max_face_width_px must be 0..4096");
  if (calibration_min_face_width_px < -1 || calibration_min_face_width_px > 4096)
    return fail_why(why, "tracker: calibration_min_face_width_px must be -1..4096 (-1: min_face_width_px)");
  if (calibration_sparse_face_width_px < 0 || calibration_sparse_face_width_px > 4096)
    return fail_why(why, "tracker: calibration_sparse_face_width_px must be 0..4096 (0: never sparser)");
  if (calibration_max_face_width_px < 0 || calibration_max_face_width_px > 4096)
    return fail_why(why, "tracker: calibration_max_face_width_px must be 0..4096 (0: never coarser)");
  if (!(rest_warning_weight >= 0.f && rest_warning_weight <= 1.f))
    return fail_why(why, "tracker: rest_warning_weight must be in [0, 1] (0: no check)");
  if (!(default_face_distance_m > 0.1f && default_face_distance_m < 20.f)) {
    return fail_why(why, "tracker: default_face_distance_m must be in (0.1, 20) m");
  }
  return true;
}

// ------------------------------------------------------------------------------------ tracker

FaceTracker::FaceTracker(const FaceModel& model, const TrackerOptions& options)
    : FaceTracker(TrackerModel::FromFaceModel(model), options) {}

FaceTracker::FaceTracker(TrackerModel model, const TrackerOptions& options)
    : options_(options), solver_(std::move(model)), gaze_(solver_.model()),
      eye_openness_(options_.eye_openness, &solver_.model()),
      brows_(solver_.model(), options_.brows) {
  std::string why;
  if (!options_.IsValid(&why)) throw Error(why);
  const TrackerModel& m = solver_.model();
  if (options_.calibration_identity_components > m.num_identity() ||
      options_.calibration_albedo_components > m.num_albedo()) {
    throw Error("tracker: calibration solves " + std::to_string(options_.calibration_identity_components) + " identity / " +
                std::to_string(options_.calibration_albedo_components) + " albedo components but the model has " +
                std::to_string(m.num_identity()) + " / " + std::to_string(m.num_albedo()));
  }
  {
    // Throws for a forced Vulkan solver without a usable device; kAuto falls back and says why;
    // kCpu opens no device.
    TrackingSolverChoice choice = ChooseTrackingSolver(options_.solver, m, options_.solver_device);
    tracking_solve_ = std::move(choice.solve);
    calibration_solve_ = std::move(choice.calibrate);
    solver_description_ = std::move(choice.description);
    solves_on_gpu_ = choice.backend == SolverBackend::kVulkan;
  }
  Reset();
}

FaceTracker::~FaceTracker() = default;

void FaceTracker::Reset() {
  CancelBackgroundCalibration();
  const TrackerModel& m = solver_.model();
  neutral_ = gpu::frontal_pose(options_.default_face_distance_m);
  neutral_.alpha = Eigen::VectorXf::Zero(m.num_identity());
  neutral_.beta = Eigen::VectorXf::Zero(m.num_albedo());
  neutral_.delta = Eigen::VectorXf::Zero(m.num_expression());
  identity_ = neutral_;
  calibrated_ = false;
  large_face_levels_ = 0;
  collecting_ = true;
  calibration_requested_.store(false);
  calibration_summary_ = SolverSummary();
  calibration_start_report_ = CalibrationStartReport();
  calibration_warning_.clear();
  StopWatchingForRelaxedFrames();
  relaxed_report_ = RelaxedRecalibration();
  depth_alignment_ = DepthAlignment();
  focal_length_ = FocalLengthReport();
  ClearCalibrationFrames();
  ForgetTrack();
  frames_seen_ = 0;
}

void FaceTracker::ForgetTrack() {
  previous_ = TrackedFrame();
  last_good_ = TrackedFrame();
  have_fit_ = false;
  energy_history_.clear();
  unresolved_disagreement_deg_ = std::numeric_limits<double>::quiet_NaN();
  unresolved_landmark_nme_ = std::numeric_limits<double>::quiet_NaN();
  eye_openness_.Reset();
  brows_.Reset();
}

void FaceTracker::RequestCalibration() { calibration_requested_.store(true); }

// A background calibration reads both solvers: it is ended (not applied) before either changes;
// its set was taken out when it started, so the collection starts afresh.
void FaceTracker::SetTrackingSolver(FrameSolveFunction solve) {
  CancelBackgroundCalibration();
  tracking_solve_ = std::move(solve);
  solver_description_ = tracking_solve_ ? "set by the program" : "cpu";
  solves_on_gpu_ = false;
}

void FaceTracker::SetCalibrationSolver(FramesSolveFunction solve) {
  CancelBackgroundCalibration();
  calibration_solve_ = std::move(solve);
}

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
                                        StageTimes* times, const std::stop_token& stop,
                                        const EyeOpennessReading* lids, int* large_face_levels) const {
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
  const SolverOptions& base = reinit ? options_.recovery_solver : options_.tracking_solver;
  const double face_width = LandmarkExtentPx(input, options_.loss.min_landmark_confidence);
  const int coarser =
      LargeFaceCoarsening(base, face_width, options_.max_face_width_px, options_.min_face_width_px,
                          large_face_levels ? *large_face_levels : 0);
  if (large_face_levels) *large_face_levels = coarser;
  const SolverOptions so = WithStop(coarser > 0 ? CoarsenSchedule(base, coarser)
                                                : AdaptScheduleToFaceSize(base, face_width, options_.min_face_width_px),
                                    stop);
  const ParameterLayout layout = ParameterLayout::Tracking(m.num_expression());
  a.params = start;
  a.summary = tracking_solve_ ? tracking_solve_(input, layout, so, &a.params) : solver_.Solve(input, layout, so, &a.params);
  // A light no room gives (a negative ambient, a shadow side lit by negative light) goes to the
  // nearest one it could (plausible_light.h); the next frame starts from there.
  a.light = ProjectToPlausibleLight(&a.params.gamma);
  times->pyramid_ms += a.summary.pyramid_ms;
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
  if (a.failure.empty()) a.gaze = ReadEyes(input, lids, so.energy.use_point || so.energy.use_plane, &a.params, times);
  return a;
}

GazeReading FaceTracker::ReadEyes(const InputFrame& input, const EyeOpennessReading* lids, bool use_depth,
                                  gpu::FaceParameters* params, StageTimes* times) const {
  if (!options_.gaze.enabled) return {};
  // The lids only on fits that place the eyes well: with depth and the calibrated identity
  // (before the calibration, on the mean face, open eyes read 0.5-1.0 on synthetic actors).
  // TrackImpl reads `lids` only on frames without depth and with the lids on.
  const bool landmark_lids = lids && lids->ok;
  if (landmark_lids) eye_openness_.WriteBlink(*lids, &params->delta);
  GazeReading gaze = gaze_.Read(solver_.renderer(), input, params, options_.gaze, calibrated_ && use_depth);
  if (landmark_lids) {
    gaze.lids_read = true;
    gaze.blink = lids->blink;
    const double nan = std::numeric_limits<double>::quiet_NaN();
    gaze.open_fraction = {nan, nan};  // a colour reading's; the eye points have none
    gaze.lids_message = "read from the eye points";
  }
  times->gaze_ms += gaze.ms;
  return gaze;
}

TrackedFrame FaceTracker::TrackImpl(const InputFrame& frame, double /*landmarks_ms*/) {
  TrackedFrame out;
  out.frame_index = frames_seen_++;
  out.camera = FittingCamera(frame.camera, frame.has_depth());
  const bool recalibrate = calibration_requested_.exchange(false);
  if (recalibrate || frame.new_face) {
    CancelBackgroundCalibration();
    collecting_ = true;
    ClearCalibrationFrames();
    StopWatchingForRelaxedFrames();
    relaxed_report_ = RelaxedRecalibration();
  }
  if (frame.new_face) {
    // Another person: neither the last fit's pose nor its lighting is theirs, and their identity
    // is calibrated from their own frames (the old one serves until then, as after Calibrate).
    out.new_face = true;
    ForgetTrack();
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
  // The eye points of every frame with a face and no depth teach the reader the actor's open eyes
  // (eye_openness.h); Solve writes its reading into the fit.
  EyeOpennessReading lids;
  if (options_.gaze.enabled && options_.gaze.read_lids && !input->has_depth()) lids = eye_openness_.Read(*input);

  // A calibration in the background: frames are held until it has finished, then the first one
  // applies it and is tracked with the new identity from the last calibration frame's fit.
  std::string calibration_note =
      frame.new_face ? "a more prominent face appeared: following it, calibrating its identity" : "";
  bool just_calibrated = false;
  if (background_) {
    if (!background_->done())
      return hold(TrackingStatus::kCalibrating, CalibrationProgressMessage() + "; hold still");
    try {
      CalibrationOutcome o = background_->Take();
      background_.reset();
      just_calibrated = ApplyCalibration(&o, &calibration_note);
      // A calibration on relaxed frames ran on frames up to seconds old: this frame starts from
      // the last tracked one (with the new identity), not from the newest of those.
      if (just_calibrated && std::isnan(o.relaxed_of)) {
        // This frame starts from the set's newest frame's joint fit (the frame that completed the
        // set; with a window, the last one kept).
        const auto newest = std::max_element(o.frame_indices.begin(), o.frame_indices.end());
        previous_.params = o.params[static_cast<size_t>(newest - o.frame_indices.begin())];
        previous_.params.alpha = identity_.alpha;
        previous_.params.beta = identity_.beta;
      }
    } catch (const std::exception& e) {
      background_.reset();
      calibration_note = std::string("calibration failed (") + e.what() + "); collecting new frames";
    }
  }
  // The estimated focal length (TrackerOptions::focal_length), from the calibration that applied it
  // on: the frame is fitted through that camera.
  InputFrame recameraed;
  out.camera = FittingCamera(frame.camera, frame.has_depth());
  if (out.camera.fx != input->camera.fx || out.camera.fy != input->camera.fy) {
    recameraed = *input;
    recameraed.camera = out.camera;
    input = &recameraed;
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
    out.message = CalibrationProgressMessage() + " (" + pose.message + "; not fitted yet)";
    if (CalibrationReady() && options_.background_calibration) {
      StartBackgroundCalibration();
      out.message = CalibrationProgressMessage() + " (started; hold still)";
    } else if (CalibrationReady()) {
      Calibrate(*input, start, &lids, &out);
      if (out.status == TrackingStatus::kCalibrated) {
        have_fit_ = true;
        out.agreement = MeasureFitAgreement(m, WithCamera(*input, out.camera), out.params, options_.loss.agreement);
        previous_timestamp_s_ = frame.timestamp_s;
        previous_ = out;
        last_good_ = out;
      }
    }
    if (!calibration_note.empty()) out.message = calibration_note + "; " + out.message;
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

  Attempt a = Solve(*input, start, reinit, &out.times, options_.stop, &lids, &large_face_levels_);
  out.gauss_newton_iterations = static_cast<int>(a.summary.iterations.size());
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
  // The fit against the landmarks: its pose, its inner points, and (warm-started) how fast the
  // head would have turned since the previous fit. Only this check's failures are marked
  // `disagrees`: the others (energy, landmark distance, the solve) stay failures whatever happens.
  auto check_agreement = [&](Attempt* at) {
    const bool warm = !at->reinit && have_fit_;
    const double dt = warm && frame.timestamp_s > previous_timestamp_s_ ? frame.timestamp_s - previous_timestamp_s_ : 0.0;
    at->agreement = MeasureFitAgreement(m, *input, at->params, options_.loss.agreement, warm ? &previous_.params : nullptr, dt);
    if (at->failure.empty() && !at->agreement.agrees()) {
      at->failure = at->agreement.failure;
      at->disagrees = true;
    }
  };
  check_energy(&a);
  check_agreement(&a);
  const std::string first_disagreement = !a.agreement.agrees() ? a.agreement.failure : a.agreement.landmark_warning;
  if (!first_disagreement.empty()) out.disagreement = first_disagreement;
  // A disagreement that the last frames could not resolve (below) and that has not grown since is
  // the same one: no new re-solve for it (each costs about three tracking solves; on a small face
  // with noisy points every frame would pay it).
  const bool same_as_before = a.disagrees && std::isfinite(unresolved_disagreement_deg_) &&
                              std::abs(a.agreement.pose_disagreement_deg - unresolved_disagreement_deg_) < 5.0;
  const bool points_as_before = a.failure.empty() && !a.agreement.landmark_warning.empty() &&
                                a.agreement.landmark_nme < unresolved_landmark_nme_ + 0.01;
  std::string kept_note;
  bool landmark_pose_left = false;  // a solve from the landmarks' pose ended away from it too
  if ((!a.failure.empty() || !a.agreement.landmark_warning.empty()) && !reinit && !same_as_before && !points_as_before) {
    // A failed fit, or one whose pose or points stray from the landmarks (a drift the warm start
    // keeps): solved again from the landmarks' pose; a failure keeps whichever passes or sits
    // closer to the landmarks, a stray fit the re-solve only when that passes and strays less.
    const std::string first_failure = a.failure.empty() ? a.agreement.landmark_warning : a.failure;
    start.delta = neutral_.delta;
    Attempt b = Solve(*input, start, true, &out.times, options_.stop, &lids, &large_face_levels_);
    out.gauss_newton_iterations += static_cast<int>(b.summary.iterations.size());
    check_energy(&b);
    check_agreement(&b);
    reinit_reason = first_failure;
    landmark_pose_left = b.disagrees;
    const bool take_b = !a.failure.empty()
                            ? (b.failure.empty() || (b.landmark_error_px >= 0 && b.landmark_error_px < a.landmark_error_px))
                            : (b.failure.empty() && b.agreement.landmark_nme < a.agreement.landmark_nme);
    if (take_b) a = std::move(b);
    else if (a.failure.empty()) out.disagreement.clear();  // the warm fit stays: nothing was refused
    reinit = a.reinit;
  }
  if (a.disagrees && (a.reinit || same_as_before || landmark_pose_left) &&
      a.agreement.explains_landmarks_as_well(options_.loss.agreement.pose_tie_nme)) {
    // Solved from the landmarks' own pose, the fit still left it (or it is the disagreement the
    // last re-solve could not resolve), and it explains the landmarks almost as well as that pose
    // does (FitAgreementOptions::pose_tie_nme): the landmarks do not fix the pose (a small face,
    // noisy points), so the fit is kept and flagged rather than lost.
    kept_note = "; " + a.agreement.failure + (same_as_before ? ", as on the previous frames" : ", and from the landmarks' pose too") +
                ": kept (the landmarks do not fix the pose)";
    a.failure.clear();
    a.disagrees = false;
    unresolved_disagreement_deg_ = a.agreement.pose_disagreement_deg;
  } else if (a.failure.empty()) {
    unresolved_disagreement_deg_ = std::numeric_limits<double>::quiet_NaN();
  }
  // The points' stray that this frame leaves (NaN when none): the next frames re-solve only when it
  // grows by more than 1 % of the eye distance.
  unresolved_landmark_nme_ = a.failure.empty() && !a.agreement.landmark_warning.empty()
                                 ? a.agreement.landmark_nme
                                 : std::numeric_limits<double>::quiet_NaN();
  if (a.failure.empty() && options_.brows.enabled) {
    // After the checks: a fit the frame refuses teaches the reader nothing.
    const auto t0 = Clock::now();
    a.brows = brows_.Read(*input, a.params, input->camera);
    if (a.brows.ok) brows_.Write(a.brows, &a.params.delta);
    out.times.gaze_ms += ms_since(t0);
  }
  out.params = a.params;
  out.has_parameters = true;
  out.brows = a.brows;
  out.energy = a.summary.final_energy;
  out.residuals = a.summary.iterations.empty() ? 0 : a.summary.iterations.back().residuals;
  out.landmark_error_px = a.landmark_error_px;
  out.pose_reinitialized = a.reinit;
  out.solver_termination = a.summary.termination;
  out.gaze = a.gaze;
  out.agreement = a.agreement;
  out.light = a.light;
  const std::string depth_note = depth_dropped ? "; no valid depth at the face: fitted colour and landmarks only" : "";
  const std::string note_prefix = calibration_note.empty() ? "" : calibration_note + "; ";
  if (!a.failure.empty()) {
    have_fit_ = false;
    out.status = TrackingStatus::kLost;
    out.message = note_prefix + "lost: " + a.failure + depth_note;
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
  out.message += depth_note + kept_note;
  if (!a.agreement.landmark_warning.empty()) out.message += "; " + a.agreement.landmark_warning;
  if (!depth_dropped) {
    energy_history_.push_back(out.energy.total());
    if (static_cast<int>(energy_history_.size()) > options_.loss.energy_history) energy_history_.erase(energy_history_.begin());
  }

  previous_timestamp_s_ = frame.timestamp_s;
  if (just_calibrated) {
    out.status = TrackingStatus::kCalibrated;
  } else if (collecting_) {
    const std::string fit_message = out.message;
    out.status = TrackingStatus::kCalibrating;
    OfferCalibrationFrame(*input, out.params, out.frame_index);
    out.message = CalibrationProgressMessage() + "; " + fit_message;
    if (CalibrationReady() && options_.background_calibration) {
      StartBackgroundCalibration();
      out.message = CalibrationProgressMessage() + " (started; hold still); " + fit_message;
    } else if (CalibrationReady()) {
      Calibrate(*input, out.params, &lids, &out);
      // The frame's parameters are now the joint fit's (or a solve with the new identity).
      if (out.status == TrackingStatus::kCalibrated)
        out.agreement = MeasureFitAgreement(m, WithCamera(*input, out.camera), out.params, options_.loss.agreement);
    }
  } else if (relaxed_watching_) {
    WatchForRelaxedFrame(*input, &lids, &out);
    if (out.status == TrackingStatus::kCalibrated)
      out.agreement = MeasureFitAgreement(m, WithCamera(*input, out.camera), out.params, options_.loss.agreement);
  }
  out.message = note_prefix + out.message;  // a background calibration that ended on this frame
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

std::string FaceTracker::CalibrationProgressMessage() const {
  std::string m = "calibrating: " + calibration_progress().Brief();
  if (options_.calibration_window_frames > 0 && !background_)
    m += " (watching " + std::to_string(std::min(calibration_frames_seen_, options_.calibration_window_frames)) + " of " +
         std::to_string(options_.calibration_window_frames) + ": turn your head slowly left and right)";
  return m;
}

gpu::PinholeCamera FaceTracker::FittingCamera(const gpu::PinholeCamera& camera, bool has_depth) const {
  if (!focal_length_.searched || has_depth || camera.width <= 0) return camera;
  return WithHorizontalFov(camera, focal_length_.estimate.horizontal_fov_deg);
}

SolverOptions FaceTracker::WithStop(SolverOptions options, const std::stop_token& stop) const {
  if (stop.stop_possible()) options.stop = stop;
  return options;
}

std::string FaceTracker::CalibrationProgress::Brief() const {
  if (solving) return "fitting the identity over " + std::to_string(frames_collected) + " frames, " + format("%.1f s", solving_s);
  if (!collecting) return "";
  return std::to_string(frames_collected) + " of " + std::to_string(frames_needed) + " frames";
}

FaceTracker::CalibrationProgress FaceTracker::calibration_progress() const {
  CalibrationProgress p;
  p.collecting = collecting_;
  p.frames_needed = options_.calibration_frames;
  p.frames_collected = static_cast<int>(calibration_inputs_.size());
  if (background_) {
    p.solving = true;
    p.frames_collected = background_->frames();
    p.solving_s = background_->seconds();
  }
  return p;
}

FaceTracker::CalibrationOutcome FaceTracker::TakeCalibrationFrames(float relaxed_of) {
  // Taken out first, so that a solve that throws (caught in Track) starts a fresh collection
  // instead of retrying the same set on every frame.
  CalibrationOutcome o;
  o.inputs = std::move(calibration_inputs_);
  o.starts = std::move(calibration_starts_);
  o.frame_indices = std::move(calibration_frame_indices_);
  ClearCalibrationFrames();
  o.relaxed_of = relaxed_of;
  // The focal length is searched once per input (the first calibration), and only on frames
  // without depth: a depth camera's intrinsics are its own.
  o.search_focal_length = options_.focal_length.estimate && !focal_length_.searched && !o.inputs.empty() &&
                          std::none_of(o.inputs.begin(), o.inputs.end(), [](const InputFrame& f) { return f.has_depth(); });
  return o;
}

void FaceTracker::StartBackgroundCalibration(float relaxed_of) {
  background_ = std::make_unique<BackgroundCalibration>(*this, TakeCalibrationFrames(relaxed_of), options_.stop);
}

void FaceTracker::CancelBackgroundCalibration() { background_.reset(); }

void FaceTracker::SolveCalibration(CalibrationOutcome* o, const std::stop_token& stop) const {
  const TrackerModel& m = solver_.model();
  const auto with_depth = std::find_if(o->inputs.begin(), o->inputs.end(), [](const InputFrame& f) { return f.has_depth(); });
  if (with_depth != o->inputs.end()) o->depth_alignment = MeasureDepthAlignment(*with_depth, options_.depth_alignment);
  if (o->search_focal_length) {
    // Before the joint solve, which then fits the identity through the found camera. The starts
    // (fitted through the assumed camera) keep their image: the same x, y, the depth scaled
    // with the focal length.
    o->focal_length = EstimateFocalLength(m, o->inputs, options_.focal_length);
    for (size_t f = 0; f < o->inputs.size(); ++f) {
      InputFrame& in = o->inputs[f];
      const gpu::PinholeCamera c = WithHorizontalFov(in.camera, o->focal_length.horizontal_fov_deg);
      o->starts[f].translation.z() *= c.fx / in.camera.fx;
      in.camera = c;
    }
  }
  const int n_id = options_.calibration_identity_components < 0 ? m.num_identity() : options_.calibration_identity_components;
  const int n_alb = options_.calibration_albedo_components < 0 ? m.num_albedo() : options_.calibration_albedo_components;
  const ParameterLayout layout = ParameterLayout::Calibration(n_id, n_alb, m.num_expression());
  const std::vector<InputFrame>& inputs = o->inputs;
  const std::vector<gpu::FaceParameters>& starts = o->starts;
  double face_width = std::numeric_limits<double>::infinity();
  for (const auto& f : inputs) face_width = std::min(face_width, LandmarkExtentPx(f, options_.loss.min_landmark_confidence));
  const SolverOptions so = WithStop(CalibrationSolverForFace(options_, face_width), stop);
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
  CalibrationStartReport& report = o->report;
  report.kept = options_.calibration_start == CalibrationStart::kPerFrameFits ? CalibrationStart::kPerFrameFits
                                                                             : CalibrationStart::kNeutral;
  report.pixel_sampling = so.energy.pixel_sampling;
  report.level = so.schedule.empty() ? -1 : FinestScheduledLevel(so);
  std::vector<gpu::FaceParameters>& params = o->params;
  const auto t0 = Clock::now();
  SolverSummary& summary = o->summary;
  summary = solve_from(report.kept, &params);
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
  o->solve_ms = ms_since(t0);
  if (!usable(summary)) return;  // ApplyCalibration says why
  for (auto& p : params) ProjectToPlausibleLight(&p.gamma);  // as after every solve (plausible_light.h)

  Eigen::VectorXf& neutral = o->neutral_delta;
  neutral = Eigen::VectorXf::Zero(m.num_expression());
  for (const auto& p : params) {
    const Eigen::Index k = std::min<Eigen::Index>(p.delta.size(), neutral.size());
    neutral.head(k) += p.delta.head(k);
  }
  neutral /= static_cast<float>(params.size());
  if (options_.neutral_from_tracking) {
    // Re-read each calibration frame the way tracking reads frames (identity fixed at the new
    // one, tracking prior, warm start from the joint solve), so Eq. 15 subtracts a neutral in the
    // same terms as the expressions it is subtracted from. Frames whose fit fails keep no say.
    Eigen::VectorXf sum = Eigen::VectorXf::Zero(m.num_expression());
    int fitted = 0;
    for (size_t f = 0; f < inputs.size(); ++f) {
      gpu::FaceParameters start = params[f];
      start.alpha = params[0].alpha;
      start.beta = params[0].beta;
      const Attempt a = Solve(inputs[f], start, /*reinit=*/false, &o->reread_times, stop);
      if (!a.failure.empty() || a.summary.termination == Termination::kStopped) continue;
      const Eigen::Index k = std::min<Eigen::Index>(a.params.delta.size(), sum.size());
      sum.head(k) += a.params.delta.head(k);
      ++fitted;
    }
    if (fitted > 0) neutral = sum / static_cast<float>(fitted);
  }
  // Gaze is absolute: the rest of the eyes is looking straight ahead, whatever the actor looked at
  // while calibrating. Eq. 15 subtracts the neutral, so a neutral that kept a glance aside would
  // turn the reenacted eyes away whenever the source looked straight at the camera; and gaze does
  // not enter the identity, so it is no sign of a calibration not at rest either.
  if (gaze_.available() && neutral.size() >= m.num_expression()) {
    for (const GazeEstimator::Weight& w : gaze_.WeightsFor(0.f, 0.f)) neutral[w.index] = 0.f;
  }
}

bool FaceTracker::ApplyCalibration(CalibrationOutcome* o, std::string* message) {
  const TrackerModel& m = solver_.model();
  const int frames = static_cast<int>(o->inputs.size());
  const Termination termination = o->summary.termination;
  const bool relaxed = !std::isnan(o->relaxed_of);
  if (termination == Termination::kStopped) {
    // Half a calibration is not an identity: keep the old one and the collected frames.
    *message = "calibration over " + std::to_string(frames) + " frames stopped before it finished (" + o->summary.message + ")";
    calibration_inputs_ = std::move(o->inputs);
    calibration_starts_ = std::move(o->starts);
    calibration_frame_indices_ = std::move(o->frame_indices);
    calibration_frames_seen_ = options_.calibration_window_frames;
    calibration_summary_ = std::move(o->summary);
    return false;
  }
  if (termination == Termination::kNoValidResiduals || termination == Termination::kNonFinite) {
    // Keep the previous identity and collect a fresh set of frames.
    *message = "calibration over " + std::to_string(frames) + " frames failed (" + o->summary.message +
               (relaxed ? "); the first calibration stays" : "); collecting new frames");
    calibration_summary_ = std::move(o->summary);
    return false;
  }
  std::string relaxed_note;
  if (relaxed) {
    // Kept only when its neutral is more at rest than the first calibration's.
    int k = -1;
    const float w = RestWeight(o->neutral_delta, &k);
    relaxed_report_.relaxed_weight = w;
    relaxed_report_.frame_indices = o->frame_indices;
    const std::string name = BlendshapeName(m, k);
    if (!(w < o->relaxed_of)) {
      relaxed_report_.message = format(
          "calibrated again on the %d most relaxed frames after it: their neutral is no more at rest (%s %.2f against "
          "%.2f), so the first calibration stays",
          frames, name.c_str(), w, o->relaxed_of);
      *message = relaxed_report_.message;
      return false;
    }
    relaxed_report_.recalibrated = true;
    relaxed_note = format(
        "calibrated again on the %d most relaxed frames since the first calibration, which was not at rest (strongest "
        "neutral weight %.2f -> %.2f, %s): ",
        frames, o->relaxed_of, w, name.c_str());
    relaxed_report_.message = relaxed_note.substr(0, relaxed_note.size() - 2);
  }
  identity_.alpha = o->params[0].alpha;
  identity_.beta = o->params[0].beta;
  neutral_ = o->params[0];
  neutral_.delta = o->neutral_delta;
  if (options_.brows.enabled && brows_.usable()) {
    // The brows are read against the rest the reader learns, with the new identity from here on.
    // Not after a calibration on relaxed frames: the reader has learned the actor's resting brows
    // over the seconds watched, which the new identity moves by a millimetre or so; learned
    // afresh, a frown 20 frames later was read as half its depth (d14, frames 114-121: browDown
    // 0.63 against 0.7 and more).
    brows_.ClearBrows(&neutral_.delta);
    if (!relaxed) brows_.Reset();
  }
  calibrated_ = true;
  collecting_ = false;
  calibration_start_report_ = o->report;
  energy_history_.clear();  // energies with the new identity are not comparable to the old
  const CalibrationStartReport& report = o->report;
  std::string start_note = std::string("from the ") + (report.kept == CalibrationStart::kNeutral ? "neutral" : "per-frame fits'") +
                           " expressions";
  if (!std::isnan(report.neutral_energy) && !std::isnan(report.per_frame_fits_energy))
    start_note += format(", E %.4g against %.4g", o->summary.final_energy.total(),
                         report.kept == CalibrationStart::kNeutral ? report.per_frame_fits_energy : report.neutral_energy) +
                  (report.kept == CalibrationStart::kNeutral ? " from the per-frame fits'" : " from neutral");
  *message = relaxed_note + "calibrated over " + std::to_string(frames) + " frames " + start_note + " (" + o->summary.BriefReport() + ")";
  if (o->search_focal_length) {
    focal_length_.searched = true;
    focal_length_.estimate = o->focal_length;
    *message += "; camera: " + o->focal_length.message;
  }
  calibration_warning_ = NotAtRestWarning(m, neutral_.delta, options_.rest_warning_weight);
  depth_alignment_ = o->depth_alignment;
  if (depth_alignment_.misaligned)
    calibration_warning_ += (calibration_warning_.empty() ? "" : "; ") + depth_alignment_.message +
                            " The depth terms fit the face worse for it";
  if (!calibration_warning_.empty()) *message += "; " + calibration_warning_;
  calibration_summary_ = o->summary;
  // A first calibration not at rest: the next frames are watched for more relaxed ones.
  StopWatchingForRelaxedFrames();
  const float rest_weight = RestWeight(neutral_.delta);
  if (!relaxed && options_.relaxed_recalibration_frames > 0 && rest_weight > options_.relaxed_recalibration_above) {
    relaxed_watching_ = true;
    relaxed_report_ = RelaxedRecalibration();
    relaxed_report_.searched = true;
    relaxed_report_.first_weight = rest_weight;
    *message += format("; watching the next %d frames for a more relaxed face to calibrate on", options_.relaxed_recalibration_frames);
  }
  return true;
}

float FaceTracker::RestWeight(Eigen::VectorXf delta, int* index) const {
  if (gaze_.available() && delta.size() >= solver_.model().num_expression())
    for (const GazeEstimator::Weight& w : gaze_.WeightsFor(0.f, 0.f)) delta[w.index] = 0.f;
  if (options_.brows.enabled && brows_.usable()) brows_.ClearBrows(&delta);
  Eigen::Index k = -1;
  const float w = delta.size() > 0 ? delta.maxCoeff(&k) : 0.f;
  if (index) *index = static_cast<int>(k);
  return std::max(w, 0.f);
}

void FaceTracker::StopWatchingForRelaxedFrames() {
  relaxed_watching_ = false;
  relaxed_frames_seen_ = 0;
  relaxed_kept_.clear();
}

void FaceTracker::WatchForRelaxedFrame(const InputFrame& input, const EyeOpennessReading* lids, TrackedFrame* out) {
  ++relaxed_frames_seen_;
  // A fit whose points stray from the landmarks says little about the face's expression.
  if (out->agreement.landmark_warning.empty()) {
    const float w = RestWeight(out->params.delta);
    if (w <= relaxed_report_.first_weight - options_.relaxed_margin) {
      RelaxedCandidate c{input, out->params, out->frame_index, w};
      if (static_cast<int>(relaxed_kept_.size()) < options_.calibration_frames) {
        relaxed_kept_.push_back(std::move(c));
      } else {
        auto worst = std::max_element(relaxed_kept_.begin(), relaxed_kept_.end(),
                                      [](const RelaxedCandidate& a, const RelaxedCandidate& b) { return a.weight < b.weight; });
        if (w < worst->weight) *worst = std::move(c);
      }
    }
  }
  if (relaxed_frames_seen_ < options_.relaxed_recalibration_frames) return;
  const int watched = relaxed_frames_seen_;
  if (static_cast<int>(relaxed_kept_.size()) < options_.calibration_frames) {
    relaxed_report_.message =
        format("%d of the %d frames after the calibration were more relaxed (strongest weight %.2f or less; %d needed): the calibration stays",
               static_cast<int>(relaxed_kept_.size()), watched, relaxed_report_.first_weight - options_.relaxed_margin,
               options_.calibration_frames);
    out->message += "; " + relaxed_report_.message;
    StopWatchingForRelaxedFrames();
    return;
  }
  std::sort(relaxed_kept_.begin(), relaxed_kept_.end(),
            [](const RelaxedCandidate& a, const RelaxedCandidate& b) { return a.frame_index < b.frame_index; });
  ClearCalibrationFrames();
  for (RelaxedCandidate& c : relaxed_kept_) {
    calibration_inputs_.push_back(std::move(c.input));
    calibration_starts_.push_back(c.params);
    calibration_frame_indices_.push_back(c.frame_index);
  }
  StopWatchingForRelaxedFrames();
  const float relaxed_of = relaxed_report_.first_weight;
  const std::string fit_message = out->message;
  if (options_.background_calibration) {
    StartBackgroundCalibration(relaxed_of);
    out->message = "calibrating again on the " + std::to_string(options_.calibration_frames) + " most relaxed of the " +
                   std::to_string(watched) + " frames since the first calibration (started); " + fit_message;
    return;
  }
  Calibrate(input, out->params, lids, out, relaxed_of);
  out->message += "; " + fit_message;
}

void FaceTracker::Calibrate(const InputFrame& current, const gpu::FaceParameters& current_start,
                            const EyeOpennessReading* lids, TrackedFrame* out, float relaxed_of) {
  CalibrationOutcome o = TakeCalibrationFrames(relaxed_of);
  SolveCalibration(&o, options_.stop);
  out->times.calibration_ms = o.solve_ms;
  for (double StageTimes::*t : {&StageTimes::pyramid_ms, &StageTimes::synthesis_ms, &StageTimes::analysis_ms,
                                &StageTimes::pose_init_ms, &StageTimes::gaze_ms})
    out->times.*t += o.reread_times.*t;
  if (!ApplyCalibration(&o, &out->message)) return;
  // With a focal length just estimated, this frame too is fitted through the new camera; a start
  // fitted through the old one keeps its image (depth scaled with the focal length).
  out->camera = FittingCamera(current.camera, current.has_depth());
  const InputFrame current_now = WithCamera(current, out->camera);
  gpu::FaceParameters start_now = current_start;
  start_now.translation.z() *= out->camera.fx / current.camera.fx;
  // This frame's parameters: its joint fit when it is a calibration frame (always, without a
  // window: it completed the set), else a tracking solve with the new identity.
  // Either way its eyes and brows are read as on every tracked frame (the joint solve reads none;
  // without them a stream's closed eyes opened for this one frame: d14 onto the webcam clip, output
  // frame 94, after the calibration on relaxed frames).
  const bool use_depth = options_.tracking_solver.energy.use_point || options_.tracking_solver.energy.use_plane;
  start_now.alpha = identity_.alpha;
  start_now.beta = identity_.beta;
  const auto in_set = std::find(o.frame_indices.begin(), o.frame_indices.end(), out->frame_index);
  if (in_set != o.frame_indices.end()) {
    out->params = o.params[static_cast<size_t>(in_set - o.frame_indices.begin())];
    out->params.alpha = identity_.alpha;
    out->params.beta = identity_.beta;
    out->gaze = ReadEyes(current_now, lids, use_depth, &out->params, &out->times);
  } else {
    const Attempt a = Solve(current_now, start_now, /*reinit=*/false, &out->times, options_.stop, lids, &large_face_levels_);
    out->params = a.failure.empty() ? a.params : start_now;
    out->gaze = a.gaze;
  }
  // The brows TrackImpl read on this frame (the reader, learning the actor's rest, reads a frame once).
  if (options_.brows.enabled && out->brows.ok) brows_.Write(out->brows, &out->params.delta);
  out->landmark_error_px = LandmarkReprojectionError(solver_.model(), current_now, out->params, options_.loss.min_landmark_confidence,
                                                     options_.calibration_solver.energy.inner_landmarks_only);
  out->has_parameters = true;
  out->status = TrackingStatus::kCalibrated;
}

}  // namespace face_reenact::tracker
