#pragma once
// The live session that the OBS source and the virtual webcam share (docs/obs-source.md): a
// target input (camera, OpenNI device or looping recording), an expression source (the UDP
// stream, a second camera/recording tracked by its own pipeline, or none), the face model and
// an output mode. It owns three kinds of threads:
//   - a capture thread per picture input (FrameGrabber): keeps only the newest frame;
//   - the UDP receiver's thread (stream::ExpressionReceiver) when the source is a stream;
//   - the worker ("fr-live"), which loads the model, tracks the newest target frame, re-renders
//     and composites it and publishes the result; with Options::overlap_frames (or while it falls
//     behind the input, overlap_frames_when_behind) it hands the second half to
//   - a render thread ("fr-live-render"), which publishes while the worker already tracks the
//     next frame (docs/real-time.md);
//   - with Options::landmarks_ahead, a landmark stage ("fr-live-marks") between the capture thread
//     and the worker, which detects the next frame's landmarks while the worker fits this one.
// Front-ends never wait on any of it: latest_frame() and status() copy under a short lock, and
// Options::on_frame is called on the publishing thread with each output frame (OBS hands it to
// obs_source_output_video there). Inputs that fail (camera unplugged, recording missing,
// stream silent, model missing) are statuses, retried in the background, never exceptions.
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <stop_token>
#include <string>
#include <thread>
#include <vector>

#include <opencv2/core.hpp>

#include "face_reenact/live/frame_overlap.h"
#include "face_reenact/live/input_spec.h"
#include "face_reenact/output/frame_source.h"
#include "face_reenact/stream/stream_state.h"

namespace face_reenact::live {

enum class OutputMode {
  kReenact,      // the source's expression on the target (Eq. 15)
  kPassThrough,  // the target tracked and re-rendered with its own expression
  kRaw,          // the target's frames unchanged (tracking off): checks the camera set-up
  kOverlay,      // the target tracked, with the fit drawn over it (mesh, landmarks, agreement)
  kMirror,       // the virtual mirror: the target's own face re-textured / re-lit (Options::mirror_*)
};
const char* output_mode_name(OutputMode mode);                          // "reenact", ...
bool parse_output_mode(const std::string& text, OutputMode* mode);      // also "pass-through"

enum class TrackingState {
  kOff,          // no tracking (raw mode, or the pipeline is unavailable: see pipeline_message)
  kCalibrating,  // calibrating the target's identity (output = input, at the input's rate: the
                 // joint solve runs on a thread of its own, "fr-calibrate")
  kTracking,     // face tracked; output reenacted / re-rendered
  kLost,         // no face in the current frame (output = input)
};
const char* tracking_state_name(TrackingState state);

enum class SourceState {
  kNone,     // no expression source configured
  kWaiting,  // configured, nothing received / tracked yet (source_detail says what it waits for)
  kCalibrating,  // a source actor (camera / recording) is being calibrated: hold still
  kLive,     // delivering
  kLost,     // was delivering, now silent (the target's own expression fades back in)
  kError,    // cannot be set up (port in use, key file unreadable, input missing): see source_error
};
const char* source_state_name(SourceState state);

struct LiveStatus {
  bool running = false;           // the worker is running
  // Target input.
  bool target_open = false;       // delivering frames
  std::string target;             // what it is ("camera /dev/video0 640x480")
  std::string target_error;       // why not open (camera unplugged, recording missing), "" if open
  double target_fps = 0;
  // Pipeline.
  OutputMode mode = OutputMode::kReenact;
  TrackingState tracking = TrackingState::kOff;
  bool pipeline_ready = false;    // the reenactment pipeline is loaded
  std::string solver;             // the target tracker's solver once loaded ("vulkan on NVIDIA H200 (discrete, auto)")
  bool frames_overlapped = false; // each frame's render half runs on "fr-live-render" now (Options::overlap_frames*)
  bool landmarks_ahead = false;   // the landmark stage runs on "fr-live-marks" (Options::landmarks_ahead)
  std::string pipeline_message;   // why frames pass unchanged (model missing, no face), or ""
  bool calibration_pending = false;
  // Non-empty when the last calibration saw a face that was not at rest (smiling, talking): part
  // of that expression is in the fitted identity; a new calibration with a relaxed face fixes it.
  std::string calibration_warning;
  // While tracking == kCalibrating: "3 of 5 frames", "fitting the identity over 5 frames, 1.2 s"
  // (tracker::FaceTracker::CalibrationProgress::Brief()).
  std::string calibration_progress;
  // While tracking in the reenact mode: no still of the target's own open mouth yet
  // (reenact/mouth_interior.h), so an opened mouth shows the model's teeth and a dark cavity; the
  // status line asks the target to open the mouth wide once, facing the camera.
  bool wants_open_mouth = false;
  // While tracking in the reenact mode, once the mouth is seen: the target's albedo texture
  // (reenact/albedo_texture.h) has no view turned to one side or the other yet, so a turned head
  // shows the per-vertex colours on the far cheek; the status line asks the target to turn the
  // head slowly to each side once.
  bool wants_head_turn = false;
  // With a calibration_warning, while the target's tracker watches the next frames for a relaxed
  // face to calibrate again on (tracker::TrackerOptions::relaxed_recalibration_frames): the status
  // line asks for a relaxed face instead of a press of Calibrate.
  bool wants_relaxed_face = false;
  // Expression source.
  SourceState source = SourceState::kNone;
  std::string source_description;  // "udp port 9000", "recording 'actor'"
  bool stream_source = false;      // the source is a UDP expression stream (stream_statistics apply)
  std::string source_error;
  // A source actor not live yet: what it waits for ("loading the face model", "no face found
  // yet") or, while kCalibrating, the actor's calibration progress.
  std::string source_detail;
  double packets_per_second = 0;   // UDP: applied datagrams per second; actor: tracked frames per second
  double source_weight = 0;        // cross-fade weight of the remote expression in [0, 1]
  // UDP: the receiver's counters since the session opened it (received, lost, reordered, the
  // duplicates among the rejected): what the network did to the stream.
  stream::ReceiverStatistics stream_statistics;
  // Output.
  int64_t frames_out = 0;
  double output_fps = 0;
  double process_ms = 0;           // mean time of one pipeline call over the last second

  // One line for status bars: "Tracking | stream live 60 pkt/s | 29.8 fps",
  // "Calibrating: hold still (3 of 5 frames) | 30.0 fps" or
  // "No camera: camera /dev/video0: no such device (retrying)".
  std::string Headline() const;
  // The same line without what changes while nothing happens (rates, calibration progress): a
  // front-end logs the status when this changes, not every time a number moves.
  std::string StateLine() const;
};

// Where the worker's time goes, per stage (the rows of the paper's Table 1), summed over the
// frames it processed: `bench live` divides by `frames` and prints them. The tracker's rows come
// from tracker::StageTimes, the rest from reenact::StageTimes; `tracker_other_ms` is the tracker's
// time outside its named stages (the fit's agreement check, loss checks, the landmark pose), and
// `worker_other_ms` the rest of the frame's time from the worker taking it to its publication (the
// hand-off to the render thread, a wait for it, copies).
struct LiveStageTimes {
  double input_ms = 0;          // the frame turned into the tracker's input (sRGB decode, depth)
  double landmarks_ms = 0;      // dlib: detection, or tracking from the last frame's points
  double pose_init_ms = 0;      // the pose re-initialised from the landmarks
  double pyramid_ms = 0;
  double synthesis_ms = 0;      // renders inside the Gauss-Newton solve
  double analysis_ms = 0;       // linearisation, J, PCG, step control
  double calibration_ms = 0;    // a joint calibration solve run in the foreground
  double gaze_ms = 0;           // gaze and lids from the colour around the eyes
  double tracker_other_ms = 0;
  double transfer_ms = 0;       // Eq. 15
  double render_ms = 0;         // the face re-rendered (and the albedo observed)
  double detail_ms = 0;         // the source actor's folds carried over (Sec. 7.3; a camera/recording source)
  double mouth_ms = 0;
  double composite_ms = 0;      // masks, Laplacian blend, 8-bit output
  double actor_ms = 0;          // waiting for a source actor's frame (camera/recording source), tracked on a
                                // thread of its own beside the target's: what its tracking adds to the frame
  double worker_other_ms = 0;
  double total_ms = 0;          // from the worker taking the frame to its publication (the sum of the rows above)

  void Add(const LiveStageTimes& t);
};

// The rows of LiveStageTimes in pipeline order with their names, for sums and tables.
struct LiveStageRow {
  const char* name;
  double LiveStageTimes::*ms;
};
// Every row but total_ms; the last is worker_other_ms.
const std::vector<LiveStageRow>& LiveStageRows();

// The worker's counts and stage times since the session started or ResetTimings().
struct LiveTimings {
  int64_t frames = 0;          // target frames the worker processed (= output frames)
  int64_t tracked = 0;         // of which the target's face was tracked (reenacted / re-rendered)
  int64_t calibrating = 0;     // passed unchanged while calibrating
  int64_t unchanged = 0;       // passed unchanged otherwise (no face, loading, raw mode, a failure)
  int64_t input_frames = 0;    // frames the target input delivered in the same time
  // Frames the input delivered that the worker never took: the capture thread keeps only the
  // newest frame, so a worker slower than the input drops frames here instead of queueing them.
  int64_t dropped_at_input = 0;
  int64_t overlapped = 0;      // frames rendered on the render thread while the worker tracked the next
  int64_t overlap_changes = 0; // times the worker started or stopped that thread (overlap_frames_when_behind)
  LiveStageTimes sum;          // summed over `frames`
  double seconds = 0;          // wall time covered
};

struct LiveFrame {
  cv::Mat bgr;                    // CV_8UC3, the target's size
  uint64_t sequence = 0;          // 1, 2, ... in output order
  int source_index = 0;           // the target frame's index in its input
  // UDP source: the cross-fade weight of the streamed expression this frame was made with (1 while
  // the stream is live, ramping to 0 when it stops: the target's own expression); 0 otherwise.
  float source_weight = 0;
  std::chrono::steady_clock::time_point captured;  // when the capture thread had the target frame
  std::chrono::steady_clock::time_point started;   // when the worker took it (and read source_weight)
  std::chrono::steady_clock::time_point produced;  // when the pipeline finished it
};

class LiveSession : public output::FrameSource {
 public:
  struct Options {
    std::string target;              // camera / openni / recording (input_spec.h)
    std::string source = "none";     // none / udp://PORT / camera / openni / recording
    std::string key_file;            // the stream key (required for udp://)
    // udp://: how long a silent stream counts as live, and the cross-fade between the streamed
    // expression and the target's own when it stops and resumes (stream_state.h).
    stream::StreamStateOptions stream;
    std::string model_path;          // empty: resolve_model_path("") (FACE_REENACT_MODEL, next to the program, installed)
    OutputMode mode = OutputMode::kReenact;
    int camera_width = 640;          // requested from cameras
    int camera_height = 480;
    double camera_fps = 30;
    bool loop = true;                // recordings loop (else the session output ends with them)
    std::chrono::milliseconds reopen_interval{1000};  // retry period for inputs, port, model
    bool use_vulkan = false;         // render with the Vulkan renderer instead of the CPU twin
    // The trackers' Gauss-Newton solver: "auto" (the Vulkan solver on a real GPU, the CPU solver
    // where Vulkan runs on the CPU), "cpu" or "vulkan" (tracker::parse_solver_backend).
    std::string solver = "auto";
    // The worker's nice increment (0..19): the pipeline yields the CPU to the front-end's own
    // threads (OBS's render thread, the webcam's pacing thread) when the machine is saturated.
    int worker_nice = 5;
    // Render frame n on a thread of its own ("fr-live-render") while the worker tracks frame n+1,
    // always. Measured on 2 cores (docs/real-time.md): about a fifth more frames per second where
    // one thread cannot keep up with the input, but 7-20 ms more latency (the two halves slow each
    // other down), so by default only while one thread falls behind (below).
    bool overlap_frames = false;
    // ... and, with the tracker on the CPU, while one thread falls behind the input and two take
    // clearly more frames within the latency target (FrameOverlapPolicy: more than 5 % of the
    // input's frames dropped over 2 s; 10 % more frames, at most 70 ms; one thread tried again
    // after 20 s and more). Measured on 2 cores (docs/real-time.md, "Two threads when behind"):
    // from a 60 fps clip 38-42 fps at 56-61 ms instead of 27-33 fps at 39-46 ms; from a 30 fps
    // clip the same as one thread within the machine's noise.
    bool overlap_frames_when_behind = true;
    FrameOverlapPolicy::Options overlap_policy;  // what "behind" is, and how long two threads are held
    // ... and also whenever the tracker solves on a GPU (Options::solver picked Vulkan): there the
    // two halves do not compete for cores and the tracking half is short. Measured on an H200
    // (docs/real-time.md, "On a GPU"): 22.1 -> 28.7 fps on a 30 fps camera, latency 60 -> 44 ms.
    bool overlap_frames_on_gpu = true;
    // Detect frame n+1's landmarks on a thread of its own ("fr-live-marks", the landmark stage)
    // while the worker fits frame n; the detector then starts from the pose fitted one frame
    // earlier than one after the other. The stage prepares every frame the camera delivers (the
    // newest waits for the worker; one it has not taken is dropped). Off by default: measured
    // (docs/real-time.md, "The landmark stage"), it gains only where the worker's tracking half
    // is what holds the frame rate (passthrough from a 120 fps camera on an H200: 73 -> 88 fps);
    // with a 60 fps camera the GPU machine shows every frame either way, reenacting is held by
    // the render thread, and on 2 cores it gave about the same frames for 3 ms more latency.
    bool landmarks_ahead = false;
    // Called for each output frame on the thread that publishes it (the worker, or the render
    // thread with overlap_frames); must return quickly (no blocking).
    std::function<void(const LiveFrame&)> on_frame;
    // The virtual mirror (mode kMirror; reenact/virtual_mirror.h, MirrorOptionsFromSettings): an
    // image to paint on the face ("" for none) and where ("face", "left-cheek", ..., or
    // "uv:U0,V0,U1,V1"), its opacity, and a light ("" keeps the tracked one, a preset's name such
    // as "left", or a .json file with "gamma"). At least a texture or a light.
    std::string mirror_texture;
    std::string mirror_at = "face";
    float mirror_opacity = 1.0f;
    std::string mirror_light;
    // The source actor's folds and wrinkles on the re-rendered face (paper Sec. 7.3,
    // reenact/detail_transfer.h): "transient" (what the expression adds), "copy" or "off". Only a
    // local source actor (a camera or recording) has an image to take them from; a UDP stream
    // carries none. "off" also saves the copy of each source frame and the detail's share of the
    // render (about 5-15 ms per frame on two cores, docs/reenactment.md).
    std::string detail = "transient";
    // The interior of an opened mouth (ReenactmentOptions::SetMouth): "auto" (the target's own
    // open mouth once seen; until then the source actor's own where it is a camera or recording
    // here, else the model's teeth), "target" (the target's own only) or "model".
    std::string mouth = "auto";
    std::string thread_name = "fr-live";

    bool IsValid(std::string* why) const;
  };

  // Validates the options (throws face_reenact::Error when invalid) and starts the threads.
  // Nothing else throws: inputs that fail are reported by status() and retried.
  explicit LiveSession(Options options);
  ~LiveSession() override;  // stop()
  LiveSession(const LiveSession&) = delete;
  LiveSession& operator=(const LiveSession&) = delete;

  // For front-ends that want errors up front (the CLI): throws face_reenact::Error when a
  // recording path does not exist, the key file cannot be read or the model cannot be found
  // (reenact / pass-through). Cameras are not checked: they may be plugged in later.
  static void CheckInputs(const Options& options);

  // The newest output frame if its sequence is above `after` (never waits).
  bool latest_frame(uint64_t after, LiveFrame* frame) const;
  // Waits up to `timeout` for an output frame above `after`; false on timeout or stop.
  bool wait_frame(uint64_t after, std::chrono::nanoseconds timeout, LiveFrame* frame) const;
  LiveStatus status() const;
  // Counts and per-stage times since the start or the last ResetTimings() (bench live).
  LiveTimings timings() const;
  void ResetTimings();
  // The next pipeline call restarts the target's calibration. Any thread, never waits.
  void RequestCalibration();
  // Stops and joins every thread; idempotent. wait_frame/next() return at once afterwards.
  void stop();
  const Options& options() const { return options_; }

  // output::FrameSource (the virtual webcam): next() waits for the next output frame; kEnd
  // once stopped, or when a non-looping recording has ended.
  output::SourceStatus next(output::SourceFrame* frame, std::string* error) override;
  bool is_live() const override { return true; }
  std::string describe() const override;

 private:
  struct Worker;
  void run();

  const Options options_;
  InputSpec target_spec_, source_spec_;
  // The target is a photo (a still image looped as a recording): it never opens its mouth, so the
  // status does not ask it to (the model's teeth serve, or the photo's own open mouth).
  bool target_is_still_ = false;
  std::mutex stop_mu_;  // stop() may be called from several threads at once
  mutable std::mutex mu_;
  mutable std::condition_variable frame_cv_;
  bool stopping_ = false;
  // Requested by stop(): reaches the tracker's solves, so a worker inside a calibration returns
  // within one Gauss-Newton iteration instead of finishing it.
  std::stop_source stop_source_;
  bool ended_ = false;
  LiveFrame latest_;
  LiveStatus status_;
  LiveTimings timings_;                      // guarded by mu_
  std::chrono::steady_clock::time_point timings_start_;
  int64_t timings_input_base_ = 0;           // the target input's frame count at timings_start_
  int64_t input_frames_ = 0;                 // the target input's frame count, as last seen
  std::atomic<bool> calibration_requested_{false};
  uint64_t next_delivered_ = 0;  // FrameSource::next(): last sequence handed out
  std::chrono::steady_clock::time_point start_time_;
  std::thread worker_;
};

}  // namespace face_reenact::live
