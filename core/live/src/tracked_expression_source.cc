#include "face_reenact/live/tracked_expression_source.h"

#include <algorithm>
#include <cmath>
#include <thread>

#include "face_reenact/common/error.h"
#include "face_reenact/stream/stream_state.h"

namespace face_reenact::live {

bool TrackedSourceOptions::IsValid(std::string* why) const {
  std::string reason;
  if (grabber.input.kind != InputKind::kCamera && grabber.input.kind != InputKind::kOpenNi &&
      grabber.input.kind != InputKind::kRecording) {
    reason = "the input must be a camera, an OpenNI device or a recording (got " + grabber.input.describe() + ")";
  } else if (!grabber.IsValid(&reason)) {
    reason = "capture: " + reason;
  } else if (!tracker.IsValid(&reason)) {
    reason = "tracker: " + reason;
  } else if (!input.IsValid(&reason)) {
    reason = "input conversion: " + reason;
  } else {
    return true;
  }
  if (why) *why = reason;
  return false;
}

namespace {
// The options, checked, with the landmark model's read started: it runs while the tracker is made.
const TrackedSourceOptions& validated_and_preloading(const TrackedSourceOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw Error("tracked expression source: " + why);
  tracker::PreloadLandmarkModel(options.input);
  return options;
}
}  // namespace

TrackedExpressionSource::TrackedExpressionSource(const FaceModel& model, TrackedSourceOptions options)
    : options_(validated_and_preloading(options)),
      tracker_(model, options_.tracker),
      input_(options_.input) {
  if (options_.grabber.input.kind == InputKind::kRecording) {
    recording_ = open_input_device(options_.grabber);  // throws with the reason (missing, unreadable)
  } else {
    grabber_ = std::make_unique<FrameGrabber>(options_.grabber);
  }
}

TrackedExpressionSource::~TrackedExpressionSource() {
  if (grabber_) grabber_->stop();
}

std::string TrackedExpressionSource::description() const {
  const std::string solver = " (solver: " + tracker_.solver_description() + ")";
  if (recording_) return "tracked " + recording_->describe() + solver;
  const GrabberStatus s = grabber_->status();
  return "tracked " + (s.description.empty() ? options_.grabber.input.describe() : s.description) + solver;
}

bool TrackedExpressionSource::NextRecordingFrame(capture::RgbdFrame* frame, std::chrono::milliseconds max_wait,
                                                 bool* ended) {
  *ended = false;
  if (!pending_) {
    capture::RgbdFrame next;
    // The device itself starts a looping recording again, with timestamps still increasing.
    if (!recording_->read(&next)) {
      *ended = true;
      return false;
    }
    if (!recording_started_) {
      recording_started_ = true;
      recording_first_timestamp_s_ = next.timestamp_s;
      recording_start_ = std::chrono::steady_clock::now();
    }
    pending_frame_ = std::move(next);
    pending_ = true;
  }
  const double t = pending_frame_.timestamp_s - recording_first_timestamp_s_;
  const auto due = recording_start_ + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                          std::chrono::duration<double>(std::max(0.0, t)));
  const auto now = std::chrono::steady_clock::now();
  if (due > now) {
    if (due - now > max_wait) {
      std::this_thread::sleep_for(max_wait);
      return false;  // not due yet: idle, so the caller can check for shutdown
    }
    std::this_thread::sleep_until(due);
  }
  *frame = std::move(pending_frame_);
  pending_ = false;
  return true;
}

stream::ExpressionFrameSource::Status TrackedExpressionSource::next(stream::ExpressionFrame* frame,
                                                                    std::chrono::milliseconds max_wait) {
  capture::RgbdFrame rgbd;
  uint64_t sequence = 0;
  if (recording_) {
    bool ended = false;
    try {
      if (!NextRecordingFrame(&rgbd, max_wait, &ended)) return ended ? Status::kEnd : Status::kIdle;
    } catch (const Error& e) {
      // A recording that turns unreadable mid-way ends the stream with the reason counted.
      ++input_errors_;
      last_input_error_ = e.what();
      return Status::kEnd;
    }
  } else if (!grabber_->wait_newer(last_sequence_, max_wait, &rgbd, &sequence)) {
    const GrabberStatus s = grabber_->status();
    if (s.ended) return Status::kEnd;
    // A failing input (camera unplugged, recording unreadable) is counted once per new reason;
    // the grabber keeps reopening it.
    if (!s.open && !s.error.empty() && s.error != "opening" && s.error != last_grabber_error_) {
      ++input_errors_;
      last_input_error_ = s.error;
    }
    last_grabber_error_ = s.open ? std::string() : s.error;
    return Status::kIdle;
  }
  if (!recording_) last_sequence_ = sequence;
  const uint64_t capture_time_us = stream::realtime_now_us();
  const auto t0 = std::chrono::steady_clock::now();

  tracker::TrackedFrame tracked;
  try {
    tracker::RgbdInputInfo info;
    tracker::InputFrame input = input_.Convert(rgbd, &info);
    tracked = tracker_.Track(input, info.landmarks_ms);
    input_.Recycle(std::move(input));
    input_.SetTrackedPose(tracked.params, tracker::tracking_status_has_fit(tracked.status));
  } catch (const Error& e) {
    // A frame the adapter cannot convert (a source delivering broken images) is an input
    // error, not a reason to stop the stream.
    ++input_errors_;
    last_input_error_ = e.what();
    ++stats_.frames_without_fit;
    stats_.last_status = std::string("bad input: ") + e.what();
    return Status::kIdle;
  }
  tracking_ms_total_ += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  ++stats_.frames_tracked;
  stats_.tracking_ms_mean = tracking_ms_total_ / static_cast<double>(stats_.frames_tracked);
  stats_.last_status = std::string(tracker::tracking_status_name(tracked.status)) +
                       (tracked.message.empty() ? "" : ": " + tracked.message);

  if (!tracker_.calibrated()) {
    ++stats_.frames_calibrating;
    return Status::kIdle;
  }
  if (!tracker::tracking_status_has_fit(tracked.status)) {
    ++stats_.frames_without_fit;
    return Status::kIdle;
  }
  *frame = expression_frame_from_fit(tracked.params, tracker_.neutral(), options_.send_pose, capture_time_us);
  ++stats_.frames_sent;
  return Status::kFrame;
}

stream::ExpressionFrame expression_frame_from_fit(const gpu::FaceParameters& fit, const gpu::FaceParameters& neutral,
                                                  bool with_pose, uint64_t capture_time_us) {
  stream::ExpressionFrame f;
  f.capture_time_us = capture_time_us;
  f.neutral_subtracted = false;
  for (int k = 0; k < stream::kNumCoefficients; ++k) {
    // The model's blendshape weights live in [0, 1]; the protocol carries them as they are.
    f.expression[k] = k < fit.delta.size() ? std::clamp(fit.delta[k], 0.f, 1.f) : 0.f;
    f.neutral[k] = k < neutral.delta.size() ? std::clamp(neutral.delta[k], 0.f, 1.f) : 0.f;
  }
  if (with_pose) {
    const Eigen::Vector3f r = gpu::head_rotation_axis_angle(fit.euler);
    f.has_rotation = true;
    f.rotation = {r.x(), r.y(), r.z()};
    f.has_translation = true;
    f.translation = {fit.translation.x(), fit.translation.y(), fit.translation.z()};
  }
  return f;
}

}  // namespace face_reenact::live
