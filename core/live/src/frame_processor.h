#pragma once
// Internal to fr_live: what the session's worker runs on each target frame. The reenactment
// pipeline (core/reenact) is one implementation; the raw pass-through of the input (mode kRaw,
// and the fallback while the pipeline cannot be loaded) is the other.
#include <memory>
#include <stop_token>
#include <string>

#include "face_reenact/capture/recording.h"
#include "face_reenact/live/live_session.h"
#include "face_reenact/reenact/detail_transfer.h"
#include "face_reenact/stream/stream_state.h"

namespace face_reenact::live {

struct ExpressionInput {
  const stream::RemoteExpression* remote = nullptr;  // the UDP stream's sample, if a stream is configured
  const capture::RgbdFrame* actor_frame = nullptr;   // a NEW frame of the source actor, else nullptr
};

// What tracking the source actor's frame gave (the worker's half, ExpressionInput::actor_frame).
struct ActorOutcome {
  bool tracked = false;      // the actor frame given was tracked and now drives the expression
  bool calibrating = false;  // the actor frame given went to the actor's calibration
  std::string calibration_progress;  // then: its progress (CalibrationProgress::Brief())
  double ms = 0;             // time spent tracking it
};

struct ProcessedFrame {
  cv::Mat bgr;
  TrackingState tracking = TrackingState::kOff;
  std::string message;        // why the input passed unchanged, or ""
  std::string calibration_warning;  // LiveStatus::calibration_warning
  std::string calibration_progress;        // the target's, while calibrating (LiveStatus::calibration_progress)
  bool wants_open_mouth = false;  // LiveStatus::wants_open_mouth
  bool wants_head_turn = false;   // LiveStatus::wants_head_turn
  bool wants_relaxed_face = false;  // LiveStatus::wants_relaxed_face
  LiveStageTimes times;  // the pipeline's rows (the session adds worker_other_ms and total_ms)
};

// A frame between the two halves: whatever the processor's track() hands its render().
struct StagedFrame {
  virtual ~StagedFrame() = default;
};

// A target frame's first part, before track(): the frame checked and its landmarks detected
// (ReenactmentPipeline::Prepare). The session's landmark stage (Options::landmarks_ahead) makes it
// on a thread of its own for frame n+1 while the worker tracks frame n.
struct PreparedFrame {
  virtual ~PreparedFrame() = default;
};

// Each frame runs in two halves so that consecutive frames overlap on two threads: track() on the
// session's worker (the target's fit, and the source actor's), render() on its render thread (the
// re-rendered face composited into the frame), while the worker tracks the next frame. Each half
// is called from one thread at a time, in frame order.
class FrameProcessor {
 public:
  virtual ~FrameProcessor() = default;
  // Never throw for bad frame content; may throw face_reenact::Error for internal failures
  // (the session then passes the frame through and reports the message).
  virtual std::unique_ptr<StagedFrame> track(const capture::RgbdFrame& target, const ExpressionInput& input,
                                             ActorOutcome* actor) = 0;
  // The same with the target's first part made already by prepare() (nullptr: made here). prepare()
  // may run on another thread beside track() and render(), one frame ahead, in frame order.
  virtual std::unique_ptr<StagedFrame> track_prepared(const capture::RgbdFrame& target, const ExpressionInput& input,
                                                      ActorOutcome* actor, std::unique_ptr<PreparedFrame> prepared) {
    (void)prepared;
    return track(target, input, actor);
  }
  // nullptr where the processor has no first part worth a thread (the raw pass-through).
  virtual std::unique_ptr<PreparedFrame> prepare(const capture::RgbdFrame& target) {
    (void)target;
    return nullptr;
  }
  virtual ProcessedFrame render(std::unique_ptr<StagedFrame> staged) = 0;
  virtual void request_calibration() = 0;
  // The target tracker's solver in words (tracker::FaceTracker::solver_description), or "".
  virtual std::string tracking_solver() const { return ""; }
  // Whether that tracker solves on a GPU (tracker::FaceTracker::solves_on_gpu).
  virtual bool tracking_solves_on_gpu() const { return false; }
};

// Output = input. Used for OutputMode::kRaw.
std::shared_ptr<FrameProcessor> make_raw_processor();

// LiveSession::Options::mirror_* (mode kMirror).
struct MirrorSettings {
  std::string texture, at;
  float opacity = 1.0f;
  std::string light;
};

// What the reenactment pipeline is built with, from LiveSession::Options (already validated).
struct PipelineSettings {
  OutputMode mode = OutputMode::kReenact;
  bool use_vulkan = false;       // the Vulkan renderer instead of the CPU twin
  std::string solver = "auto";   // LiveSession::Options::solver
  bool with_actor = false;       // a second pipeline tracks the source actor (camera or recording)
  MirrorSettings mirror;         // kMirror: the texture and light
  reenact::DetailMode detail = reenact::DetailMode::kTransient;  // the source actor's folds (Sec. 7.3)
  std::string mouth = "auto";    // an opened mouth's interior (ReenactmentOptions::SetMouth)
};

// The reenactment pipeline on the model at `model_path` (mode kReenact, kPassThrough, kOverlay
// or kMirror), as `settings` say. Throws face_reenact::Error when the model cannot be loaded or
// this build has no reenactment pipeline. A requested `stop` ends a process() call in progress
// within one Gauss-Newton iteration (the session is shutting down).
std::shared_ptr<FrameProcessor> make_reenactment_processor(const std::string& model_path, const PipelineSettings& settings,
                                                           std::stop_token stop);

}  // namespace face_reenact::live
