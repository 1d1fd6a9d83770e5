#pragma once
// The puppeteer's side of the live link (paper Sec. 7.1): the source actor filmed by a camera
// (or played from a recording) is tracked frame by frame and each fit becomes an expression
// datagram payload, so `face-reenact send --input` streams what the actor does right now.
//
// A camera runs on a FrameGrabber thread that keeps only the newest frame; tracking runs on the
// caller's thread inside next(). When tracking is slower than the camera, frames are dropped
// rather than queued, so the stream's latency stays one tracking step. A recording is a
// performance to be sent whole: every frame is tracked, sent no earlier than its timestamp
// (so never faster than it was recorded) and later when tracking is slower than real time. Frames are sent only
// once the actor is calibrated (the neutral expression is what the target subtracts) and only
// while the fit is trustworthy; a lost face simply stops the datagrams, which is what the
// receiver's smooth fallback to the target's own expression is built for.
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>

#include "face_reenact/live/frame_grabber.h"
#include "face_reenact/stream/sender.h"
#include "face_reenact/tracker/face_tracker.h"
#include "face_reenact/tracker/rgbd_input.h"

namespace face_reenact {
struct FaceModel;
}

namespace face_reenact::live {

struct TrackedSourceOptions {
  GrabberOptions grabber;  // the input (camera, OpenNI device, recording); loop = false by default
  tracker::TrackerOptions tracker;
  tracker::RgbdInputOptions input;
  bool send_pose = true;  // include the head rotation and translation in each frame
  bool IsValid(std::string* why) const;
};

struct TrackedSourceStatistics {
  int64_t frames_tracked = 0;
  int64_t frames_sent = 0;         // frames handed to the sender (calibrated, trustworthy fit)
  int64_t frames_calibrating = 0;  // tracked before the calibration completed
  int64_t frames_without_fit = 0;  // no face, lost fit or bad input
  std::string last_status;         // tracker status name and message of the last frame
  double tracking_ms_mean = 0;     // mean wall time of one tracked frame
};

class TrackedExpressionSource : public stream::ExpressionFrameSource {
 public:
  // Starts the capture thread. Throws face_reenact::Error for invalid options or a model the
  // tracker rejects; an input that cannot be opened is reported through input_errors() and
  // retried by the grabber.
  TrackedExpressionSource(const FaceModel& model, TrackedSourceOptions options);
  ~TrackedExpressionSource() override;

  Status next(stream::ExpressionFrame* frame, std::chrono::milliseconds max_wait) override;
  std::string description() const override;
  uint64_t input_errors() const override { return input_errors_; }
  std::string last_input_error() const override { return last_input_error_; }

  const TrackedSourceStatistics& statistics() const { return stats_; }
  const tracker::FaceTracker& tracker() const { return tracker_; }

 private:
  // The next recording frame once it is due; false when not due within max_wait (or *ended).
  bool NextRecordingFrame(capture::RgbdFrame* frame, std::chrono::milliseconds max_wait, bool* ended);

  TrackedSourceOptions options_;
  tracker::FaceTracker tracker_;
  tracker::RgbdInput input_;
  std::unique_ptr<FrameGrabber> grabber_;    // cameras and OpenNI devices
  std::unique_ptr<InputDevice> recording_;   // recordings: read in order, every frame
  std::chrono::steady_clock::time_point recording_start_{};
  double recording_first_timestamp_s_ = 0;
  bool recording_started_ = false;
  bool pending_ = false;  // pending_frame_ was read but is not due yet
  capture::RgbdFrame pending_frame_;
  uint64_t last_sequence_ = 0;
  std::string last_grabber_error_;
  uint64_t input_errors_ = 0;
  std::string last_input_error_;
  TrackedSourceStatistics stats_;
  double tracking_ms_total_ = 0;
};

// An ExpressionFrame from a tracked fit: the expression and the actor's neutral (not
// subtracted: the receiver does that, Eq. 15), optionally the head pose.
stream::ExpressionFrame expression_frame_from_fit(const gpu::FaceParameters& fit, const gpu::FaceParameters& neutral,
                                                  bool with_pose, uint64_t capture_time_us);

}  // namespace face_reenact::live
