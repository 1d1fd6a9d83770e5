#include "face_reenact/live/live_session.h"

#include <pthread.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <deque>
#include <functional>
#include <future>
#include <optional>

#include <opencv2/core/utility.hpp>

#include "face_reenact/capture/media_file.h"
#include "face_reenact/common/error.h"
#include "face_reenact/common/paths.h"
#include "face_reenact/common/timing.h"
#include "face_reenact/live/frame_grabber.h"
#include "face_reenact/live/frame_overlap.h"
#include "face_reenact/stream/receiver.h"
#include "face_reenact/stream/stream_key.h"
#include "face_reenact/stream/udp.h"
#include "face_reenact/tracker/solver_choice.h"
#include "face_reenact/reenact/reenactment_pipeline.h"
#include "face_reenact/reenact/virtual_mirror.h"
#include "frame_processor.h"

namespace face_reenact::live {
namespace {

using Clock = std::chrono::steady_clock;

std::string fixed(double v, int digits) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", digits, v);
  return buf;
}

bool is_picture_input(InputKind kind) {
  return kind == InputKind::kCamera || kind == InputKind::kOpenNi || kind == InputKind::kRecording;
}

}  // namespace

const std::vector<LiveStageRow>& LiveStageRows() {
  static const std::vector<LiveStageRow> rows = {
      {"input conversion", &LiveStageTimes::input_ms},
      {"landmarks", &LiveStageTimes::landmarks_ms},
      {"pose initialisation", &LiveStageTimes::pose_init_ms},
      {"pyramid", &LiveStageTimes::pyramid_ms},
      {"synthesis", &LiveStageTimes::synthesis_ms},
      {"analysis", &LiveStageTimes::analysis_ms},
      {"calibration (foreground)", &LiveStageTimes::calibration_ms},
      {"gaze/lids", &LiveStageTimes::gaze_ms},
      {"tracker checks", &LiveStageTimes::tracker_other_ms},
      {"transfer", &LiveStageTimes::transfer_ms},
      {"render", &LiveStageTimes::render_ms},
      {"detail", &LiveStageTimes::detail_ms},
      {"mouth", &LiveStageTimes::mouth_ms},
      {"composite", &LiveStageTimes::composite_ms},
      {"source actor (waited)", &LiveStageTimes::actor_ms},
      {"hand-off and other", &LiveStageTimes::worker_other_ms},
  };
  return rows;
}

void LiveStageTimes::Add(const LiveStageTimes& t) {
  for (const LiveStageRow& row : LiveStageRows()) this->*row.ms += t.*row.ms;
  total_ms += t.total_ms;
}

const char* output_mode_name(OutputMode mode) {
  switch (mode) {
    case OutputMode::kReenact: return "reenact";
    case OutputMode::kPassThrough: return "passthrough";
    case OutputMode::kRaw: return "raw";
    case OutputMode::kOverlay: return "overlay";
    case OutputMode::kMirror: return "mirror";
  }
  return "?";
}

bool parse_output_mode(const std::string& text, OutputMode* mode) {
  if (text == "reenact") *mode = OutputMode::kReenact;
  else if (text == "passthrough" || text == "pass-through") *mode = OutputMode::kPassThrough;
  else if (text == "raw" || text == "off") *mode = OutputMode::kRaw;
  else if (text == "overlay") *mode = OutputMode::kOverlay;
  else if (text == "mirror") *mode = OutputMode::kMirror;
  else return false;
  return true;
}

const char* tracking_state_name(TrackingState state) {
  switch (state) {
    case TrackingState::kOff: return "off";
    case TrackingState::kCalibrating: return "calibrating";
    case TrackingState::kTracking: return "tracking";
    case TrackingState::kLost: return "no face";
  }
  return "?";
}

const char* source_state_name(SourceState state) {
  switch (state) {
    case SourceState::kNone: return "none";
    case SourceState::kWaiting: return "waiting";
    case SourceState::kCalibrating: return "calibrating";
    case SourceState::kLive: return "live";
    case SourceState::kLost: return "lost";
    case SourceState::kError: return "error";
  }
  return "?";
}

namespace {

// Below this share of the input's frame rate, the status line says the output is behind (the
// two rates are each counted over a second, so a frame more or less moves them by 3 % at 30 fps).
constexpr double kShownBehindShare = 0.9;

// LiveStatus::Headline (numbers true) and StateLine (false): one wording in one place.
std::string status_line(const LiveStatus& s, bool numbers) {
  if (!s.target_open) {
    bool camera = s.target.rfind("camera", 0) == 0 || s.target.rfind("OpenNI", 0) == 0;
    if (s.target_error == "end of recording") return "Recording ended";
    if (s.target_error.empty() || s.target_error == "opening") return "Starting: opening " + s.target;
    return std::string(camera ? "No camera: " : "No input: ") + s.target_error + " (retrying)";
  }
  std::string line;
  if (s.mode == OutputMode::kRaw) {
    line = "Raw input (tracking off)";
  } else if (!s.pipeline_ready) {
    line = "Unchanged: " + (s.pipeline_message.empty() ? std::string("loading the face model") : s.pipeline_message);
  } else {
    switch (s.tracking) {
      case TrackingState::kCalibrating: line = "Calibrating: hold still"; break;
      case TrackingState::kTracking: line = "Tracking"; break;
      case TrackingState::kLost: line = "No face"; break;
      case TrackingState::kOff: line = "Starting"; break;
    }
    if (s.tracking == TrackingState::kCalibrating) {
      if (numbers && !s.calibration_progress.empty()) line += " (" + s.calibration_progress + ")";
    } else if (s.tracking != TrackingState::kTracking && numbers && !s.pipeline_message.empty()) {
      line += " (" + s.pipeline_message + ")";  // a per-frame reason, with its measurements
    }
    // One request at a time, each gone by itself once done: the open mouth first (the teeth),
    // then a warning of the calibration (it shows in every frame until acted on), then a turn to
    // each side (the skin's texture; a person who never turns keeps a fine picture).
    if (s.tracking == TrackingState::kTracking && s.wants_open_mouth)
      line += ": open your mouth wide once, facing the camera (for the teeth)";
    else if (s.tracking == TrackingState::kTracking && !s.calibration_warning.empty() && s.wants_relaxed_face)
      line += ": relax your face for a few seconds, mouth closed (calibrated while it was not at rest; it calibrates again then)";
    else if (s.tracking == TrackingState::kTracking && !s.calibration_warning.empty())
      line += " (calibrated while the face was not at rest: calibrate again with a relaxed face)";
    else if (s.tracking == TrackingState::kTracking && s.wants_head_turn)
      line += ": turn your head slowly to each side once (for the skin's texture)";
  }
  const bool stream = s.stream_source;
  std::string what = stream ? "stream" : "source actor";
  switch (s.source) {
    case SourceState::kNone: break;
    case SourceState::kWaiting:
      if (stream) line += " | waiting for stream on " + s.source_description;
      else if (!s.source_detail.empty()) line += " | source actor: " + s.source_detail;
      else line += " | waiting for " + s.source_description;
      break;
    case SourceState::kCalibrating:
      line += " | source actor calibrating: hold still";
      if (numbers && !s.source_detail.empty()) line += " (" + s.source_detail + ")";
      break;
    case SourceState::kLive:
      line += " | " + what + " live";
      if (numbers) line += " " + fixed(s.packets_per_second, 0) + (stream ? " pkt/s" : " fps");
      break;
    case SourceState::kLost: line += " | " + what + " lost" + (s.source_error.empty() ? "" : ": " + s.source_error); break;
    case SourceState::kError: line += " | " + what + " error: " + s.source_error; break;
  }
  if (numbers) {
    // A machine too busy for every frame the camera delivers drops the rest (never queues them):
    // said, so that the lower rate is not taken for the camera's own.
    const bool behind = s.pipeline_ready && s.tracking == TrackingState::kTracking && s.target_fps > 0 &&
                        s.output_fps > 0 && s.output_fps < kShownBehindShare * s.target_fps;
    line += " | " + fixed(s.output_fps, 1) +
            (behind ? " of " + fixed(s.target_fps, 0) + " fps (the machine cannot keep up: frames dropped)" : " fps");
  }
  return line;
}

}  // namespace

std::string LiveStatus::Headline() const { return status_line(*this, true); }
std::string LiveStatus::StateLine() const { return status_line(*this, false); }

bool LiveSession::Options::IsValid(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  InputSpec t, s;
  try {
    t = parse_target_spec(target, "target");
    s = parse_source_spec(source, "source");
  } catch (const Error& e) {
    return fail(e.what());
  }
  if (s.kind == InputKind::kUdp) {
    if (key_file.empty()) return fail("source " + s.text + ": a UDP stream needs its key file");
    try {
      (void)stream::parse_listen_spec(s.listen, "source");
    } catch (const Error& e) {
      return fail(e.what());
    }
    std::string stream_why;
    if (!stream.IsValid(&stream_why)) return fail("source " + s.text + ": " + stream_why);
  }
  if (camera_width <= 0 || camera_height <= 0 || camera_width > 8192 || camera_height > 8192)
    return fail("camera size must be within 1..8192");
  if (!(camera_fps > 0 && camera_fps <= 240)) return fail("camera fps must be in (0, 240]");
  if (reopen_interval.count() <= 0 || reopen_interval > std::chrono::minutes(10))
    return fail("reopen interval must be in (0, 10 min]");
  if (thread_name.empty() || thread_name.size() > 15) return fail("thread name must have 1..15 characters");
  if (worker_nice < 0 || worker_nice > 19) return fail("worker nice increment must be in 0..19");
  std::string overlap_why;
  if (!overlap_policy.IsValid(&overlap_why)) return fail("overlap policy: " + overlap_why);
  tracker::SolverBackend backend;
  if (!tracker::parse_solver_backend(solver, &backend)) return fail("solver must be auto, cpu or vulkan (got '" + solver + "')");
  if (mode == OutputMode::kMirror && mirror_texture.empty() && mirror_light.empty())
    return fail("the mirror mode needs a texture to paint on the face or a light");
  if (!(mirror_opacity >= 0.f && mirror_opacity <= 1.f)) return fail("the mirror's opacity must be within [0, 1]");
  reenact::DetailMode detail_mode;
  if (!reenact::ParseDetailMode(detail, &detail_mode))
    return fail("the detail transfer must be transient, copy or off (got '" + detail + "')");
  if (reenact::ReenactmentOptions probe; !probe.SetMouth(mouth))
    return fail("the mouth must be auto, target or model (got '" + mouth + "')");
  return true;
}

void LiveSession::CheckInputs(const Options& options) {
  std::string why;
  if (!options.IsValid(&why)) throw Error(why);
  InputSpec t = parse_target_spec(options.target, "target");
  InputSpec s = parse_source_spec(options.source, "source");
  for (const InputSpec& spec : {t, s}) CheckRecordingOpens(spec);
  if (s.kind == InputKind::kUdp) (void)stream::load_key_file(options.key_file);
  if (options.mode != OutputMode::kRaw) (void)resolve_model_path(options.model_path);
  // The texture, its placement and the light, read now (a front-end says what is wrong at once).
  if (options.mode == OutputMode::kMirror)
    (void)reenact::MirrorOptionsFromSettings(options.mirror_texture, options.mirror_at, options.mirror_opacity,
                                             options.mirror_light);
}

LiveSession::LiveSession(Options options) : options_(std::move(options)) {
  std::string why;
  if (!options_.IsValid(&why)) throw Error("live session: " + why);
  target_spec_ = parse_target_spec(options_.target, "target");
  source_spec_ = parse_source_spec(options_.source, "source");
  target_is_still_ = target_spec_.kind == InputKind::kRecording && capture::is_still_image(target_spec_.path);
  status_.running = true;
  status_.mode = options_.mode;
  status_.target = target_spec_.describe();
  status_.target_error = "opening";
  status_.source = source_spec_.kind == InputKind::kNone ? SourceState::kNone : SourceState::kWaiting;
  status_.source_description = source_spec_.describe();
  status_.stream_source = source_spec_.kind == InputKind::kUdp;
  start_time_ = Clock::now();
  timings_start_ = start_time_;
  worker_ = std::thread([this] {
    try {
      run();
    } catch (const std::exception& e) {
      std::lock_guard lock(mu_);
      status_.pipeline_message = std::string("live worker failed: ") + e.what();
    }
    {
      std::lock_guard lock(mu_);
      status_.running = false;
      ended_ = true;
    }
    frame_cv_.notify_all();
  });
  // Named here as well as in run(): once the constructor returns, the worker carries its name, so
  // whoever counts the session's threads (a front-end's shutdown check, `top -H`) never misses one
  // that has not reached its first line yet.
  pthread_setname_np(worker_.native_handle(), options_.thread_name.c_str());
}

LiveSession::~LiveSession() { stop(); }

void LiveSession::stop() {
  {
    std::lock_guard lock(mu_);
    stopping_ = true;
  }
  stop_source_.request_stop();
  frame_cv_.notify_all();
  std::lock_guard join_lock(stop_mu_);
  if (worker_.joinable()) worker_.join();
}

void LiveSession::RequestCalibration() {
  calibration_requested_.store(true);
  std::lock_guard lock(mu_);
  status_.calibration_pending = true;
}

bool LiveSession::latest_frame(uint64_t after, LiveFrame* frame) const {
  std::lock_guard lock(mu_);
  if (latest_.sequence <= after) return false;
  *frame = latest_;
  return true;
}

bool LiveSession::wait_frame(uint64_t after, std::chrono::nanoseconds timeout, LiveFrame* frame) const {
  std::unique_lock lock(mu_);
  frame_cv_.wait_for(lock, timeout, [&] { return stopping_ || ended_ || latest_.sequence > after; });
  if (latest_.sequence <= after) return false;
  *frame = latest_;
  return true;
}

LiveStatus LiveSession::status() const {
  std::lock_guard lock(mu_);
  return status_;
}

LiveTimings LiveSession::timings() const {
  std::lock_guard lock(mu_);
  LiveTimings t = timings_;
  t.seconds = std::chrono::duration<double>(Clock::now() - timings_start_).count();
  t.input_frames = std::max<int64_t>(0, input_frames_ - timings_input_base_);
  t.dropped_at_input = std::max<int64_t>(0, t.input_frames - t.frames);
  return t;
}

void LiveSession::ResetTimings() {
  std::lock_guard lock(mu_);
  timings_ = LiveTimings();
  timings_start_ = Clock::now();
  timings_input_base_ = input_frames_;
}

std::string LiveSession::describe() const {
  return std::string("live session: target ") + target_spec_.describe() + ", source " + source_spec_.describe() +
         ", mode " + output_mode_name(options_.mode);
}

output::SourceStatus LiveSession::next(output::SourceFrame* frame, std::string* error) {
  std::unique_lock lock(mu_);
  frame_cv_.wait(lock, [&] { return stopping_ || ended_ || latest_.sequence > next_delivered_; });
  if (stopping_ || latest_.sequence <= next_delivered_) {
    if (!status_.running && !status_.pipeline_message.empty() && error) *error = status_.pipeline_message;
    return output::SourceStatus::kEnd;
  }
  next_delivered_ = latest_.sequence;
  frame->bgr = latest_.bgr;
  frame->timestamp = std::chrono::duration_cast<std::chrono::nanoseconds>(latest_.produced - start_time_);
  return output::SourceStatus::kFrame;
}

namespace {

// One frame between the worker's half (track) and the render half.
struct RenderJob {
  std::shared_ptr<FrameProcessor> processor;  // the one that tracked it (a pipeline loaded meanwhile replaces it)
  std::unique_ptr<StagedFrame> staged;        // null when the worker's half failed: `failure` says why
  std::string failure;
  cv::Mat input_bgr;                          // the target frame's colour: the output when nothing else is
  int source_index = 0;
  int64_t input_sequence = 0;                 // the target input's count when it delivered this frame
  float source_weight = 0;                    // the streamed expression's cross-fade weight (LiveFrame)
  bool overlapped = false;                    // rendered on the render thread
  Clock::time_point captured, started;        // the capture thread had it / the worker took it
};

// The render half of each frame on a thread of its own ("fr-live-render", Options::overlap_frames),
// so that the worker tracks frame n+1 while frame n is re-rendered, composited and published. One
// slot, not a queue: a worker that is ahead waits for the slot, so frames never pile up.
class RenderThread {
 public:
  using Publish = std::function<void(RenderJob&, ProcessedFrame&)>;
  explicit RenderThread(Publish publish) : publish_(std::move(publish)), thread_([this] { run(); }) {}
  ~RenderThread() {
    {
      std::lock_guard lock(mu_);
      stopping_ = true;
    }
    cv_.notify_all();
    thread_.join();
  }
  RenderThread(const RenderThread&) = delete;
  RenderThread& operator=(const RenderThread&) = delete;

  // The render half of `job` (on whichever thread runs it), or why there is none.
  static ProcessedFrame Finish(RenderJob& job) {
    ProcessedFrame out;
    if (!job.staged) {
      out.message = job.failure;
      return out;
    }
    try {
      out = job.processor->render(std::move(job.staged));
    } catch (const std::exception& e) {
      out = ProcessedFrame();
      out.message = e.what();
    }
    return out;
  }

  // Hands a job over once the slot is free; false (the job dropped) when `stopping()` turns true
  // first (it is polled every 50 ms).
  bool Submit(RenderJob job, const std::function<bool()>& stopping) {
    std::unique_lock lock(mu_);
    while (slot_) {
      if (stopping()) return false;
      cv_.wait_for(lock, std::chrono::milliseconds(50));
    }
    slot_ = std::make_unique<RenderJob>(std::move(job));
    cv_.notify_all();
    return true;
  }

 private:
  void run() {
    pthread_setname_np(pthread_self(), "fr-live-render");
    for (;;) {
      std::unique_ptr<RenderJob> job;
      {
        std::unique_lock lock(mu_);
        cv_.wait(lock, [&] { return stopping_ || slot_; });
        if (!slot_) return;  // stopping, nothing in hand
        job = std::move(slot_);
      }
      cv_.notify_all();  // the slot is free: the worker may hand over the next frame
      ProcessedFrame out = Finish(*job);
      publish_(*job, out);
    }
  }

  Publish publish_;
  std::mutex mu_;
  std::condition_variable cv_;
  bool stopping_ = false;
  std::unique_ptr<RenderJob> slot_;
  std::thread thread_;  // last: started once the rest is constructed
};

// OpenCV's own helper threads (its cv::parallel_for_ pool, which a frame's conversion uses) start
// on the first call that needs them, carry the name of the thread that made it and live as long
// as the process. Started from the landmark stage they would still show as "fr-live-marks" once
// the session has ended (the per-thread CPU tables, `top -H`), so the worker starts them first.
void StartOpenCvThreads() {
  cv::parallel_for_(cv::Range(0, std::max(2, cv::getNumThreads())), [](const cv::Range&) {});
}

// The landmark stage (Options::landmarks_ahead): a thread of its own ("fr-live-marks") takes each
// newest target frame from the capture thread and runs the processor's first part on it (the frame
// checked, the landmark detector) while the worker tracks the frame before. One slot, newest
// first: a prepared frame the worker has not taken when the next is ready is dropped, as the
// capture thread drops frames the pipeline is too slow for, so nothing queues and the latency
// does not grow.
class LandmarkStage {
 public:
  struct Job {
    capture::RgbdFrame frame;
    uint64_t sequence = 0;                 // the capture thread's
    Clock::time_point captured, started;   // the capture thread had it / the stage took it
    std::unique_ptr<PreparedFrame> prepared;
    std::string failure;                   // why prepare() threw, or ""
  };

  LandmarkStage(FrameGrabber& target, std::shared_ptr<FrameProcessor> processor, uint64_t after)
      : target_(target), processor_(std::move(processor)), after_(after), thread_([this] { run(); }) {}
  ~LandmarkStage() {
    {
      std::lock_guard lock(mu_);
      stopping_ = true;
    }
    cv_.notify_all();
    thread_.join();
  }
  LandmarkStage(const LandmarkStage&) = delete;
  LandmarkStage& operator=(const LandmarkStage&) = delete;

  // The newest prepared frame not taken yet, waiting up to `timeout`; false when there is none.
  bool Take(std::chrono::milliseconds timeout, Job* job) {
    std::unique_lock lock(mu_);
    if (!cv_.wait_for(lock, timeout, [&] { return slot_ != nullptr || stopping_; }) || !slot_) return false;
    *job = std::move(*slot_);
    slot_.reset();
    return true;
  }

 private:
  void run() {
    pthread_setname_np(pthread_self(), "fr-live-marks");
    uint64_t sequence = after_;
    for (;;) {
      {
        std::lock_guard lock(mu_);
        if (stopping_) return;
      }
      auto job = std::make_unique<Job>();
      if (!target_.wait_newer(sequence, std::chrono::milliseconds(50), &job->frame, &sequence, &job->captured))
        continue;
      job->sequence = sequence;
      job->started = Clock::now();
      try {
        job->prepared = processor_->prepare(job->frame);
      } catch (const std::exception& e) {
        job->failure = e.what();
      }
      {
        std::lock_guard lock(mu_);
        slot_ = std::move(job);  // a frame still there is dropped: this one is newer
      }
      cv_.notify_all();
    }
  }

  FrameGrabber& target_;
  std::shared_ptr<FrameProcessor> processor_;
  const uint64_t after_;
  std::mutex mu_;
  std::condition_variable cv_;
  bool stopping_ = false;
  std::unique_ptr<Job> slot_;
  std::thread thread_;  // last: started once the rest is constructed
};

}  // namespace

void LiveSession::run() {
  pthread_setname_np(pthread_self(), options_.thread_name.c_str());
  if (options_.worker_nice > 0) {
    // On Linux the nice value is per thread; the capture and receiver threads the worker starts
    // below inherit it, so the whole session yields to the front-end's threads.
    const id_t tid = static_cast<id_t>(::syscall(SYS_gettid));
    errno = 0;
    int current = ::getpriority(PRIO_PROCESS, tid);
    if (errno == 0) ::setpriority(PRIO_PROCESS, tid, std::min(19, current + options_.worker_nice));
  }
  auto stopping = [&] {
    std::lock_guard lock(mu_);
    return stopping_;
  };

  GrabberOptions target_options;
  target_options.input = target_spec_;
  target_options.camera_width = options_.camera_width;
  target_options.camera_height = options_.camera_height;
  target_options.camera_fps = options_.camera_fps;
  target_options.loop = options_.loop;
  target_options.reopen_interval = options_.reopen_interval;
  target_options.thread_name = "fr-live-target";
  FrameGrabber target(target_options);

  std::unique_ptr<FrameGrabber> actor;
  if (is_picture_input(source_spec_.kind)) {
    GrabberOptions actor_options = target_options;
    actor_options.input = source_spec_;
    actor_options.loop = true;  // the source actor keeps playing whatever the target does
    actor_options.thread_name = "fr-live-actor";
    actor = std::make_unique<FrameGrabber>(actor_options);
  }

  // The pipeline loads on a thread of its own (seconds: the face model and dlib's 100 MB shape
  // predictor), never on a front-end's thread; meanwhile the target's frames pass unchanged, so
  // a front-end shows the camera at once ("Unchanged: loading the face model").
  std::shared_ptr<FrameProcessor> processor = make_raw_processor();
  bool pipeline_ready = false;
  std::string pipeline_error;
  Clock::time_point next_pipeline_try = Clock::now();
  std::future<std::shared_ptr<FrameProcessor>> loading;  // its destructor waits for a load under way
  auto start_loading = [&] {
    try {
      PipelineSettings settings;
      settings.mode = options_.mode;
      settings.use_vulkan = options_.use_vulkan;
      settings.solver = options_.solver;
      settings.with_actor = actor != nullptr;
      settings.mirror = MirrorSettings{options_.mirror_texture, options_.mirror_at, options_.mirror_opacity,
                                       options_.mirror_light};
      reenact::ParseDetailMode(options_.detail, &settings.detail);  // validated by Options::IsValid
      settings.mouth = options_.mouth;
      loading = std::async(std::launch::async, [model_path = options_.model_path, settings = std::move(settings),
                                                stop = stop_source_.get_token()] {
        pthread_setname_np(pthread_self(), "fr-live-load");  // niced like the worker that starts it
        return make_reenactment_processor(resolve_model_path(model_path), settings, stop);
      });
    } catch (const std::exception& e) {  // no thread could be started
      pipeline_error = e.what();
      next_pipeline_try = Clock::now() + 5 * options_.reopen_interval;
    }
  };
  auto poll_loading = [&] {
    if (!loading.valid() || loading.wait_for(std::chrono::seconds(0)) != std::future_status::ready) return;
    try {
      processor = loading.get();
      pipeline_ready = true;
      pipeline_error.clear();
    } catch (const std::exception& e) {
      pipeline_error = e.what();
      next_pipeline_try = Clock::now() + 5 * options_.reopen_interval;
    }
  };

  std::unique_ptr<stream::ExpressionReceiver> receiver;
  std::string receiver_error;
  Clock::time_point next_receiver_try = Clock::now();
  auto try_receiver = [&] {
    try {
      stream::StreamKey key = stream::load_key_file(options_.key_file);
      stream::ExpressionReceiver::Options ro;
      ro.listen = stream::parse_listen_spec(source_spec_.listen, "source");
      ro.thread_name = "fr-live-udp";
      ro.stream = options_.stream;
      receiver = std::make_unique<stream::ExpressionReceiver>(key, ro);
      receiver_error.clear();
    } catch (const std::exception& e) {
      receiver_error = e.what();
      next_receiver_try = Clock::now() + options_.reopen_interval;
    }
  };

  uint64_t target_seq = 0, actor_seq = 0;
  capture::RgbdFrame frame, actor_frame;
  bool actor_ever_tracked = false, actor_calibrating = false;
  Clock::time_point actor_last_tracked{};
  std::deque<Clock::time_point> actor_tracked_times;  // the last second's, for the actor's rate
  std::string actor_progress;

  // What the render thread published last (guarded by mu_): the status reads it.
  struct Published {
    uint64_t sequence = 0;
    TrackingState tracking = TrackingState::kOff;
    std::string message, calibration_warning, calibration_progress;
    bool wants_open_mouth = false, wants_head_turn = false, wants_relaxed_face = false;
    Clock::time_point window_start = Clock::now();
    int64_t window_frames = 0;
    double window_ms = 0;
    double output_fps = 0, process_ms = 0;
  } shown;
  auto publish = [&](RenderJob& job, ProcessedFrame& out) {
    // Whatever went wrong, the front-end gets a picture of the right kind.
    if (out.bgr.empty() || out.bgr.type() != CV_8UC3) out.bgr = job.input_bgr;
    LiveFrame published;
    published.bgr = out.bgr;
    published.source_index = job.source_index;
    published.source_weight = job.source_weight;
    published.captured = job.captured;
    published.started = job.started;
    LiveStageTimes rows = out.times;
    {
      std::lock_guard lock(mu_);
      published.sequence = ++shown.sequence;
      published.produced = Clock::now();
      shown.tracking = out.tracking;
      shown.message = out.message;
      shown.calibration_warning = out.calibration_warning;
      shown.calibration_progress = out.calibration_progress;
      shown.wants_open_mouth = out.wants_open_mouth;
      shown.wants_head_turn = out.wants_head_turn;
      shown.wants_relaxed_face = out.wants_relaxed_face;
      ++shown.window_frames;
      shown.window_ms += ms_since(job.started, published.produced);
      latest_ = published;
      status_.frames_out = static_cast<int64_t>(published.sequence);
      status_.calibration_pending = calibration_requested_.load();
      // The frame's time from the worker taking it to its publication, both halves and the
      // hand-off between them; a frame a reader has seen is counted.
      rows.total_ms = ms_since(job.started, published.produced);
      double named = 0;
      for (const LiveStageRow& row : LiveStageRows()) named += rows.*row.ms;
      rows.worker_other_ms = std::max(0.0, rows.total_ms - named);
      // A frame the input delivered before ResetTimings (still in flight then) belongs to the
      // measurement before it: counting it after made more frames than inputs.
      if (job.input_sequence > timings_input_base_) {
        ++timings_.frames;
        timings_.overlapped += job.overlapped;
        timings_.tracked += out.tracking == TrackingState::kTracking;
        timings_.calibrating += out.tracking == TrackingState::kCalibrating;
        timings_.unchanged +=
            out.tracking != TrackingState::kTracking && out.tracking != TrackingState::kCalibrating;
        timings_.sum.Add(rows);
      }
    }
    frame_cv_.notify_all();
    if (options_.on_frame) {
      try {
        options_.on_frame(published);
      } catch (...) {
        // A front-end's callback must not take the session down; it sees the next frame.
      }
    }
  };
  // Declared after everything `publish` uses, so it is joined (its job in hand finished) first.
  std::optional<RenderThread> render;
  if (options_.overlap_frames) render.emplace(publish);
  // After the capture thread (it reads from it) and the pipeline (it runs its first part).
  std::optional<LandmarkStage> marks;
  bool solver_checked = false;  // overlap_frames_on_gpu: decided once the pipeline has loaded
  std::string solver;           // the tracker's solver in words, read then
  // overlap_frames_when_behind: whether `render` runs, decided frame by frame (CPU solver only).
  std::optional<FrameOverlapPolicy> overlap_policy;

  while (!stopping()) {
    Clock::time_point now = Clock::now();
    if (!pipeline_ready && options_.mode != OutputMode::kRaw) {
      poll_loading();
      if (!pipeline_ready && !loading.valid() && now >= next_pipeline_try) start_loading();
    }
    if (pipeline_ready && !solver_checked) {
      solver_checked = true;
      solver = processor->tracking_solver();
      if (!render && options_.overlap_frames_on_gpu && processor->tracking_solves_on_gpu()) render.emplace(publish);
      if (!render && options_.overlap_frames_when_behind && !processor->tracking_solves_on_gpu())
        overlap_policy.emplace(options_.overlap_policy);
      if (options_.landmarks_ahead) {
        StartOpenCvThreads();
        marks.emplace(target, processor, target_seq);
      }
    }
    if (source_spec_.kind == InputKind::kUdp && !receiver && now >= next_receiver_try) try_receiver();
    if (calibration_requested_.exchange(false)) processor->request_calibration();

    Clock::time_point captured{};
    LandmarkStage::Job marked;  // with the landmark stage: the frame and its first part
    bool got = marks ? marks->Take(std::chrono::milliseconds(50), &marked)
                     : target.wait_newer(target_seq, std::chrono::milliseconds(50), &frame, &target_seq, &captured);
    if (got && marks) {
      frame = std::move(marked.frame);
      target_seq = marked.sequence;
      captured = marked.captured;
    }
    stream::RemoteExpression remote;
    if (receiver) remote = receiver->sample();
    if (got) {
      ExpressionInput input;
      if (receiver) input.remote = &remote;
      if (actor && actor->take_newer(actor_seq, &actor_frame, &actor_seq)) input.actor_frame = &actor_frame;
      RenderJob job;
      job.processor = processor;
      job.input_bgr = frame.color;
      job.source_index = frame.index;
      job.input_sequence = static_cast<int64_t>(target_seq);
      job.source_weight = receiver ? remote.weight : 0.0f;
      job.captured = captured;
      {
        // Seen before the frame can be counted, so that no measurement has more frames than inputs.
        std::lock_guard lock(mu_);
        input_frames_ = std::max(input_frames_, job.input_sequence);
      }
      job.started = marks ? marked.started : Clock::now();
      ActorOutcome actor_outcome;
      try {
        if (!marked.failure.empty()) throw Error(marked.failure);
        job.staged = processor->track_prepared(frame, input, &actor_outcome, std::move(marked.prepared));
      } catch (const std::exception& e) {
        job.failure = e.what();
      }
      if (input.actor_frame) {
        actor_calibrating = actor_outcome.calibrating;
        actor_progress = actor_outcome.calibration_progress;
      }
      if (actor_outcome.tracked) {
        actor_ever_tracked = true;
        actor_last_tracked = Clock::now();
        actor_tracked_times.push_back(actor_last_tracked);
      }
      const int64_t input_sequence = job.input_sequence;
      if (render) {
        job.overlapped = true;
        render->Submit(std::move(job), stopping);
      } else {
        ProcessedFrame out = RenderThread::Finish(job);
        publish(job, out);
      }
      if (overlap_policy) {
        bool tracked;
        double latency_ms = std::nan("");
        {
          std::lock_guard lock(mu_);
          tracked = shown.tracking == TrackingState::kTracking;
          if (latest_.sequence > 0) latency_ms = ms_since(latest_.captured, latest_.produced);
        }
        // Stopping the render thread finishes the frame in its hands first, so frames stay in order.
        if (overlap_policy->Update(Clock::now(), input_sequence, tracked, latency_ms) != render.has_value()) {
          if (render) render.reset();
          else render.emplace(publish);
          std::lock_guard lock(mu_);
          ++timings_.overlap_changes;
        }
      }
    }

    // Status, refreshed every pass (a few copies of small strings).
    now = Clock::now();
    TrackingState tracking;
    std::string frame_message, calibration_warning, calibration_progress;
    bool wants_open_mouth = false, wants_head_turn = false, wants_relaxed_face = false;
    double output_fps, process_ms;
    {
      std::lock_guard lock(mu_);
      const double window_s = std::chrono::duration<double>(now - shown.window_start).count();
      if (window_s >= 1.0) {
        shown.output_fps = shown.window_frames / window_s;
        shown.process_ms = shown.window_frames > 0 ? shown.window_ms / shown.window_frames : 0;
        shown.window_frames = 0;
        shown.window_ms = 0;
        shown.window_start = now;
      }
      tracking = shown.tracking;
      frame_message = shown.message;
      calibration_warning = shown.calibration_warning;
      calibration_progress = shown.calibration_progress;
      wants_open_mouth = shown.wants_open_mouth;
      wants_head_turn = shown.wants_head_turn;
      wants_relaxed_face = shown.wants_relaxed_face;
      output_fps = shown.output_fps;
      process_ms = shown.process_ms;
    }
    GrabberStatus ts = target.status();
    LiveStatus s;
    {
      std::lock_guard lock(mu_);
      s = status_;
    }
    s.running = true;
    s.target_open = ts.open;
    s.target = ts.description;
    s.target_error = ts.error;
    s.target_fps = ts.fps;
    s.pipeline_ready = pipeline_ready;
    s.solver = pipeline_ready ? solver : "";
    s.frames_overlapped = render.has_value();
    s.landmarks_ahead = marks.has_value();
    s.tracking = pipeline_ready ? tracking : TrackingState::kOff;
    s.pipeline_message = pipeline_ready ? frame_message : pipeline_error;
    s.calibration_warning = pipeline_ready ? calibration_warning : "";
    s.calibration_progress = pipeline_ready && tracking == TrackingState::kCalibrating ? calibration_progress : "";
    s.wants_open_mouth = pipeline_ready && tracking == TrackingState::kTracking && wants_open_mouth && !target_is_still_;
    s.wants_head_turn = pipeline_ready && tracking == TrackingState::kTracking && wants_head_turn && !target_is_still_;
    s.wants_relaxed_face = pipeline_ready && tracking == TrackingState::kTracking && wants_relaxed_face;
    s.output_fps = ts.open ? output_fps : 0;
    s.process_ms = process_ms;
    if (source_spec_.kind == InputKind::kUdp) {
      if (!receiver) {
        s.source = SourceState::kError;
        s.source_error = receiver_error;
        s.packets_per_second = 0;
      } else {
        stream::ReceiverStatistics rs = receiver->statistics();
        std::string thread_error = receiver->thread_error();
        s.packets_per_second = rs.rate_hz;
        s.stream_statistics = rs;
        s.source_weight = remote.weight;
        s.source_error = thread_error;
        s.source = !thread_error.empty() ? SourceState::kError
                   : !remote.has_frame   ? SourceState::kWaiting
                   : remote.live         ? SourceState::kLive
                                         : SourceState::kLost;
        if (!remote.live) s.packets_per_second = 0;
      }
    } else if (actor) {
      GrabberStatus as = actor->status();
      // The rate is the tracked frames of the last second, so "live" never shows 0 fps.
      while (!actor_tracked_times.empty() && now - actor_tracked_times.front() > std::chrono::seconds(1))
        actor_tracked_times.pop_front();
      bool recent = actor_ever_tracked && now - actor_last_tracked < std::chrono::milliseconds(500);
      s.packets_per_second = recent ? static_cast<double>(actor_tracked_times.size()) : 0;
      s.source_weight = recent ? 1 : 0;
      s.source_error.clear();
      s.source_detail.clear();
      if (!as.open) {
        s.source = actor_ever_tracked ? SourceState::kLost : (as.error == "opening" ? SourceState::kWaiting : SourceState::kError);
        s.source_error = as.error;
      } else if (recent) {
        s.source = SourceState::kLive;
      } else if (!pipeline_ready) {
        // The actor's frames are there; what they wait for is the pipeline (its error, if any,
        // is the target's line).
        s.source = SourceState::kWaiting;
        s.source_detail = "waiting for the face model";
      } else if (actor_calibrating) {
        s.source = SourceState::kCalibrating;
        s.source_detail = actor_progress;
      } else if (actor_ever_tracked) {
        s.source = SourceState::kLost;
        s.source_error = "no face";
      } else {
        s.source = SourceState::kWaiting;
        s.source_detail = "no face found yet";
      }
    }
    bool ended = ts.ended && !options_.loop;
    {
      std::lock_guard lock(mu_);
      input_frames_ = std::max(input_frames_, ts.frames);
      s.calibration_pending = status_.calibration_pending;
      s.frames_out = status_.frames_out;
      status_ = s;
      if (ended) ended_ = true;
    }
    if (ended) frame_cv_.notify_all();
  }
}

}  // namespace face_reenact::live
