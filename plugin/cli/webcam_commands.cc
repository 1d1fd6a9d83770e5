// `face-reenact webcam`: a virtual webcam on a v4l2loopback device that Zoom, Meet and Firefox
// list as a camera (docs/virtual-webcam.md), and `face-reenact bench webcam` (conversion cost).
//
// Pictures come from a FrameSource: the live reenactment session (--target, core/live), a
// video or image (--input), or colour bars. The writer, pacing and reconnect logic are the same
// for all of them.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <csignal>
#include <cstdio>
#include <fstream>
#include <functional>
#include <mutex>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "command_registry.h"
#include "frame_size.h"
#include "face_reenact/capture/media_file.h"
#include "face_reenact/common/error.h"
#include "face_reenact/common/process_resources.h"
#include "face_reenact/common/thread_cpu.h"
#include "face_reenact/live/live_session.h"
#include "face_reenact/output/frame_source.h"
#include "face_reenact/output/pixel_conversion.h"
#include "face_reenact/output/v4l2_loopback_writer.h"
#include "face_reenact/output/webcam_streamer.h"
#include <nlohmann/json.hpp>

namespace face_reenact::cli {
namespace {

using namespace face_reenact::output;

struct WebcamArgs {
  std::string device;
  std::string input;
  std::string size = "1280x720";
  double fps = 30;
  std::string format = "yuyv";
  bool loop = false;
  bool status = false;
  double seconds = 0;  // 0: until stopped
  double reconnect_s = 2;
  // Live reenactment (--target): the session's inputs.
  std::string target;
  std::string source = "none";
  std::string key_file;
  std::string mode = "reenact";
  std::string model;
  std::string camera_size = "640x480";
  std::string solver = "auto";    // the trackers' solver (LiveSession::Options::solver)
  std::string renderer = "cpu";   // cpu or vulkan: the re-rendered face's rasteriser
  // --mode mirror: the virtual mirror's texture, placement, opacity and light (LiveSession::Options::mirror_*).
  std::string mirror_texture, mirror_at = "face", mirror_light;
  float mirror_opacity = 1.0f;
  std::string detail = "transient";  // the source actor's folds (LiveSession::Options::detail)
  std::string mouth = "auto";        // an opened mouth's interior (LiveSession::Options::mouth)
  bool overlap_when_behind = true;   // LiveSession::Options::overlap_frames_when_behind
};

// The pipeline choices a live session takes from the command line (webcam --target, bench live).
void apply_pipeline_args(const WebcamArgs& args, live::LiveSession::Options* o) {
  o->solver = args.solver;
  if (args.renderer != "cpu" && args.renderer != "vulkan") throw Error("--renderer must be cpu or vulkan (got '" + args.renderer + "')");
  o->use_vulkan = args.renderer == "vulkan";
  o->mirror_texture = args.mirror_texture;
  o->mirror_at = args.mirror_at;
  o->mirror_opacity = args.mirror_opacity;
  o->mirror_light = args.mirror_light;
  o->detail = args.detail;
  o->mouth = args.mouth;
  o->overlap_frames_when_behind = args.overlap_when_behind;
}

void add_pipeline_options(CLI::App* cmd, WebcamArgs* args) {
  cmd->add_option("--solver", args->solver,
                  "the tracker's solver: auto (the Vulkan solver on a GPU, the CPU solver where Vulkan runs on the CPU), cpu or vulkan")
      ->capture_default_str();
  cmd->add_option("--renderer", args->renderer, "cpu or vulkan: the rasteriser of the re-rendered face")->capture_default_str();
  cmd->add_option("--texture", args->mirror_texture, "with --mode mirror: an image to paint on the face (PNG with alpha)");
  cmd->add_option("--at", args->mirror_at,
                  "with --mode mirror: face, forehead, nose, left-cheek, right-cheek, chin, or uv:U0,V0,U1,V1")
      ->capture_default_str();
  cmd->add_option("--opacity", args->mirror_opacity, "with --mode mirror: the texture's opacity")->check(CLI::Range(0.0f, 1.0f));
  cmd->add_option("--light", args->mirror_light,
                  "with --mode mirror: re-light: front, left, right, top, bottom, warm, cool, or a .json with \"gamma\"");
  cmd->add_option("--detail", args->detail,
                  "the source actor's folds and wrinkles on the target (a camera or recording source): transient, copy or off")
      ->capture_default_str();
  cmd->add_option("--mouth", args->mouth,
                  "an opened mouth's interior: auto (the target's own open mouth once seen; until then the source actor's own "
                  "where it is a camera or recording here, else the model's teeth), target (the target's own only) or model")
      ->capture_default_str();
  cmd->add_flag("--overlap-when-behind,!--no-overlap-when-behind", args->overlap_when_behind,
                "render each frame on a second thread while the tracker works on the CPU and one thread falls "
                "behind the camera (the default: more frames for 10-20 ms more latency, only where that gains "
                "frames); --no-overlap-when-behind keeps one thread");
}

// What `bench soak` adds to a webcam run: the frames may go nowhere (every frame is still
// converted as for the device, so no loopback module is needed), and it hears the statistics and
// the live session's headline about once a second.
struct WebcamRunHooks {
  bool discard_frames = false;
  std::function<void(const StreamStatistics&, const std::string& live_headline)> on_status;
};

// A FrameSink that drops every frame (bench soak without --device).
class DiscardSink final : public FrameSink {
 public:
  WriteOutcome write_frame(std::span<const uint8_t>, std::string*) override { return WriteOutcome::kWritten; }
  bool reopen(std::string*) override { return true; }
  void close() override {}
};

void run_webcam(const WebcamArgs& args, const WebcamRunHooks& hooks = {}) {
  V4l2LoopbackWriter::Options writer_options;
  writer_options.device = args.device;
  parse_frame_size(args.size, &writer_options.width, &writer_options.height);
  std::optional<PixelFormat> format = parse_pixel_format(args.format);
  if (!format) throw Error("--format '" + args.format + "' is not one of yuyv, i420");
  writer_options.format = *format;
  std::optional<FrameRate> rate = FrameRate::from_double(args.fps);
  if (!rate) throw Error("--fps must be in (0, 240]");
  writer_options.rate = *rate;
  if (!(args.reconnect_s > 0) || args.reconnect_s > 3600) throw Error("--reconnect must be in (0, 3600] seconds");
  std::string why;
  V4l2LoopbackWriter::Options checked = writer_options;
  if (hooks.discard_frames) checked.device = "(none)";  // no device; size, format and rate still apply
  if (!checked.IsValid(&why)) throw Error(why);

  // The source first: a bad input file is reported before the device is touched.
  std::unique_ptr<FrameSource> source;
  live::LiveSession* session = nullptr;
  bool hold = false;
  if (!args.target.empty()) {
    if (!args.input.empty()) throw Error("--input and --target exclude each other (a clip, or the live session)");
    live::LiveSession::Options live_options;
    live_options.target = args.target;
    live_options.source = args.source;
    live_options.key_file = args.key_file;
    live_options.model_path = args.model;
    if (!live::parse_output_mode(args.mode, &live_options.mode))
      throw Error("--mode '" + args.mode + "' is not one of reenact, passthrough, overlay, mirror, raw");
    parse_frame_size(args.camera_size, &live_options.camera_width, &live_options.camera_height);
    live_options.camera_fps = rate->fps();
    apply_pipeline_args(args, &live_options);
    live::LiveSession::CheckInputs(live_options);  // a missing recording / key / model: exit 1 now
    auto live_session = std::make_unique<live::LiveSession>(std::move(live_options));
    session = live_session.get();
    source = std::move(live_session);
    hold = true;  // a camera unplugged or a stream lost keeps the last picture on the webcam
  } else if (args.input.empty()) {
    source = make_test_pattern_source(writer_options.width, writer_options.height, rate->fps());
  } else {
    source = open_media_source({.path = args.input, .loop = args.loop});
    hold = capture::is_still_image(args.input);  // a picture stays up until stopped
  }

  std::optional<V4l2LoopbackWriter> writer;
  DiscardSink discard;
  FrameSink* sink = &discard;
  if (hooks.discard_frames) {
    std::fprintf(stderr, "webcam: no device: %dx%d %s at %.2f fps from %s, converted and dropped\n", writer_options.width,
                 writer_options.height, pixel_format_name(writer_options.format), rate->fps(), source->describe().c_str());
  } else {
    writer.emplace(writer_options);
    writer->open();
    sink = &*writer;
    const auto& info = writer->device_info();
    std::fprintf(stderr, "webcam: %s (%s, %s): %dx%d %s at %.2f fps from %s\n", args.device.c_str(), info.card.c_str(),
                 info.bus_info.c_str(), writer_options.width, writer_options.height, pixel_format_name(writer_options.format),
                 rate->fps(), source->describe().c_str());
    for (const auto& w : info.warnings) std::fprintf(stderr, "webcam: warning: %s\n", w.c_str());
  }

  WebcamStreamer::Options options;
  options.width = writer_options.width;
  options.height = writer_options.height;
  options.format = writer_options.format;
  options.rate = *rate;
  options.reconnect_interval = std::chrono::nanoseconds(static_cast<int64_t>(args.reconnect_s * 1e9));
  options.hold_last_frame = hold;
  // An expression stream's counters go on the status line: what the network lost, reordered or
  // duplicated is what a user checks when the target's face falls back to its own.
  if (args.status || hooks.on_status)
    options.on_status = [session, status = args.status, hook = hooks.on_status](const StreamStatistics& s) {
      const live::LiveStatus st = session ? session->status() : live::LiveStatus{};
      const std::string headline = session ? st.Headline() : "";
      if (status)
        std::fprintf(stderr, "webcam: status: source frames %lld, %s%s%s\n", static_cast<long long>(s.source_frames),
                     s.BriefReport().c_str(), session ? (" | live: " + headline).c_str() : "",
                     st.stream_source ? (" | stream: " + st.stream_statistics.Counts()).c_str() : "");
      if (hook) hook(s, headline);
    };

  StopSignalGuard signals;
  // --seconds: stop on a timer too (tests, scripted captures). A helper thread sets a flag the
  // streamer polls together with the signal flag.
  std::atomic<bool> stop{false};
  std::atomic<bool> done{false};
  std::thread watcher([&] {
    auto deadline = std::chrono::steady_clock::now() + std::chrono::nanoseconds(static_cast<int64_t>(args.seconds * 1e9));
    while (!done.load()) {
      if (signals.flag().load() || (args.seconds > 0 && std::chrono::steady_clock::now() >= deadline)) {
        stop.store(true);
        // The streamer's producer may be waiting in the live session's next(): end it.
        if (session) session->stop();
        return;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
  });
  WebcamStreamer streamer(source.get(), sink, options);
  WebcamStreamer::Summary summary;
  try {
    summary = streamer.run(stop);
  } catch (...) {
    done.store(true);
    watcher.join();
    if (session) session->stop();
    throw;
  }
  done.store(true);
  watcher.join();
  if (session) {
    std::fprintf(stderr, "webcam: live session: %s\n", session->status().Headline().c_str());
    session->stop();
  }
  if (summary.stop_reason == "stop requested")
    summary.stop_reason = signals.signal_number() == SIGINT    ? "stopped by SIGINT"
                          : signals.signal_number() == SIGTERM ? "stopped by SIGTERM"
                                                               : "time limit reached";
  std::fprintf(stderr, "webcam: %s\n", summary.BriefReport().c_str());
  if (summary.source_failed) throw Error("webcam: " + summary.stop_reason);
}

// bench soak: the live session run as the virtual webcam runs it (through the writer, or with
// every frame converted and dropped when no --device is given) for a long time, with what the
// process holds sampled at intervals; the end says whether memory, open files or threads grew
// after the warm-up (issue #29, "an hour of faults"). Exit status 1 when they did.
struct SoakArgs {
  WebcamArgs webcam;
  double minutes = 60;
  double every_s = 60;
  double warmup_s = 120;
  double rss_bound_percent = 2;
  std::string json;
};

void run_soak(const SoakArgs& a) {
  if (!(a.minutes > 0) || a.minutes > 24 * 60) throw Error("--minutes must be in (0, 1440]");
  if (!(a.every_s >= 0.2) || a.every_s > 3600) throw Error("--every must be in [0.2, 3600] seconds");
  ResourceTrendOptions trend_options;
  trend_options.warmup_seconds = a.warmup_s;
  trend_options.rss_bound = a.rss_bound_percent / 100;
  std::string why;
  if (!trend_options.IsValid(&why)) throw Error("bench soak: " + why);
  if (a.warmup_s + 2 * a.every_s > a.minutes * 60)
    throw Error("bench soak: --warmup plus two --every intervals must fit in --minutes (nothing would be judged)");
  std::ofstream json_file;
  if (!a.json.empty()) {
    json_file.open(a.json, std::ios::binary | std::ios::trunc);
    if (!json_file) throw Error("--json '" + a.json + "': cannot write");
  }

  WebcamArgs webcam = a.webcam;
  webcam.seconds = a.minutes * 60;
  std::mutex mu;
  std::condition_variable wake;
  bool finished = false;
  StreamStatistics last_stats;
  std::string last_headline;
  WebcamRunHooks hooks;
  hooks.discard_frames = webcam.device.empty();
  hooks.on_status = [&](const StreamStatistics& s, const std::string& headline) {
    std::lock_guard lock(mu);
    last_stats = s;
    last_headline = headline;
  };

  std::vector<ResourceSample> samples;
  const auto start = std::chrono::steady_clock::now();
  auto take_sample = [&] {
    ResourceSample sample;
    sample.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::string error;
    if (!ReadProcessResources(&sample.resources, &error)) throw Error("bench soak: " + error);
    // The live session's render thread comes and goes with the load (a second thread while one
    // falls behind the input: LiveSession::Options::overlap_frames_when_behind), so one such
    // thread is not counted: a run that starts on one thread and ends on two has not grown. A
    // second one would count.
    int render_threads = 0;
    for (const ThreadInfo& t : ProcessThreads()) render_threads += t.name == "fr-live-render";
    sample.resources.threads -= std::min(1, render_threads);
    {
      std::lock_guard lock(mu);
      sample.frames = last_stats.frames_written;
      sample.note = last_headline;
    }
    const double fps = samples.empty() || sample.seconds <= samples.back().seconds
                           ? 0
                           : double(sample.frames - samples.back().frames) / (sample.seconds - samples.back().seconds);
    char heap[64] = "";
    if (sample.resources.heap_in_use_bytes >= 0)
      std::snprintf(heap, sizeof heap, ", heap in use %8.1f MB (%6.1f free)",
                    static_cast<double>(sample.resources.heap_in_use_bytes) / 1e6,
                    static_cast<double>(sample.resources.heap_free_bytes) / 1e6);
    std::printf("soak %7.1f s: resident %8.1f MB%s, open files %4d, threads %3d, frames out %8lld (%5.1f fps)%s%s\n",
                sample.seconds, static_cast<double>(sample.resources.rss_bytes) / 1e6, heap, sample.resources.open_files,
                sample.resources.threads, static_cast<long long>(sample.frames), fps, sample.note.empty() ? "" : " | ",
                sample.note.c_str());
    std::fflush(stdout);
    samples.push_back(std::move(sample));
  };

  // The sampler runs beside the webcam loop; a failure to read /proc ends the run with the error.
  std::exception_ptr sampler_error;
  std::thread sampler([&] {
    try {
      const auto period = std::chrono::nanoseconds(static_cast<int64_t>(a.every_s * 1e9));
      auto next = start;
      std::unique_lock lock(mu);
      while (!finished) {
        lock.unlock();
        take_sample();
        lock.lock();
        next += period;
        wake.wait_until(lock, next, [&] { return finished; });
      }
    } catch (...) {
      sampler_error = std::current_exception();
    }
  });
  std::exception_ptr run_error;
  try {
    run_webcam(webcam, hooks);
  } catch (...) {
    run_error = std::current_exception();
  }
  {
    std::lock_guard lock(mu);
    finished = true;
  }
  wake.notify_all();
  sampler.join();
  if (run_error) std::rethrow_exception(run_error);
  if (sampler_error) std::rethrow_exception(sampler_error);
  // No sample after the run: the session is gone by then, and its teardown is not the trend.

  const ResourceTrend trend = AnalyseResourceTrend(samples, trend_options);
  if (!trend.grows) std::printf("bench soak: %s\n", trend.verdict.c_str());  // growth: the error says it
  if (json_file.is_open()) {
    nlohmann::json doc;
    doc["target"] = webcam.target;
    doc["mode"] = webcam.mode;
    doc["device"] = webcam.device.empty() ? nlohmann::json(nullptr) : nlohmann::json(webcam.device);
    doc["minutes"] = a.minutes;
    doc["warmup_s"] = a.warmup_s;
    doc["rss_bound"] = trend_options.rss_bound;
    doc["measured"] = trend.measured;
    doc["grows"] = trend.grows;
    doc["verdict"] = trend.verdict;
    doc["leaks"] = trend.leaks;
    doc["rss_growth"] = trend.rss_growth;
    doc["heap_growth"] = trend.heap_measured ? nlohmann::json(trend.heap_growth) : nlohmann::json(nullptr);
    doc["samples"] = nlohmann::json::array();
    for (const ResourceSample& s : samples)
      doc["samples"].push_back({{"seconds", s.seconds},
                                {"rss_bytes", s.resources.rss_bytes},
                                {"heap_in_use_bytes", s.resources.heap_in_use_bytes},
                                {"heap_free_bytes", s.resources.heap_free_bytes},
                                {"open_files", s.resources.open_files},
                                {"threads", s.resources.threads},
                                {"frames", s.frames},
                                {"status", s.note}});
    json_file << doc.dump(2) << "\n";
    if (!json_file.flush()) throw Error("--json '" + a.json + "': write failed");
  }
  if (trend.grows) throw Error("bench soak: " + trend.verdict);
}

void add_bench_soak(CLI::App* bench) {
  auto args = std::make_shared<SoakArgs>();
  CLI::App* soak = bench->add_subcommand(
      "soak", "Run the live session as the virtual webcam does for a long time and report whether memory, open files or "
              "threads grow (exit 1 when they do)");
  soak->add_option("--target", args->webcam.target, "camera or recording/video (looped)")->required();
  soak->add_option("--source", args->webcam.source, "expression source (none, udp://PORT, camera, recording)")
      ->capture_default_str();
  soak->add_option("--key", args->webcam.key_file, "stream key file for udp://");
  soak->add_option("--mode", args->webcam.mode, "reenact, passthrough, overlay, mirror or raw")->capture_default_str();
  soak->add_option("--model", args->webcam.model, "face model file");
  add_pipeline_options(soak, &args->webcam);
  soak->add_option("--device", args->webcam.device,
                   "v4l2loopback device to write to (default: none; every frame is converted as for a device and dropped)");
  soak->add_option("--size", args->webcam.size, "output size WIDTHxHEIGHT")->capture_default_str();
  soak->add_option("--fps", args->webcam.fps, "output frame rate")->capture_default_str();
  soak->add_option("--minutes", args->minutes, "length of the run")->capture_default_str();
  soak->add_option("--every", args->every_s, "seconds between samples")->capture_default_str();
  soak->add_option("--warmup", args->warmup_s, "seconds at the start that are not judged (model load, calibration)")
      ->capture_default_str();
  soak->add_option("--rss-bound", args->rss_bound_percent,
                   "resident-memory growth allowed after the warm-up, percent (open files and threads: none)")
      ->capture_default_str();
  soak->add_option("--json", args->json, "also write the samples and the verdict to this JSON file");
  soak->callback([args] { run_soak(*args); });
}

void add_webcam_command(CLI::App& app) {
  auto args = std::make_shared<WebcamArgs>();
  CLI::App* cmd = app.add_subcommand(
      "webcam",
      "Send frames to a v4l2loopback virtual webcam (Zoom/Meet/Firefox see it as a camera): the live reenactment "
      "(--target), a video, an image, or colour bars when neither --target nor --input is given");
  cmd->add_option("--device", args->device, "v4l2loopback device node, e.g. /dev/video10")->required();
  cmd->add_option("--input", args->input, "video or image file to send (default: a colour-bar test pattern)");
  cmd->add_option("--target", args->target,
                  "live reenactment: the target actor, a camera (/dev/video0), 'openni[:URI]' or a recording/video (looped)");
  cmd->add_option("--source", args->source,
                  "with --target: the expression source, udp://PORT (needs --key), a camera/recording actor, or none")
      ->capture_default_str();
  cmd->add_option("--key", args->key_file, "with --source udp://PORT: the stream key file (face-reenact keygen)");
  cmd->add_option("--mode", args->mode, "with --target: reenact, passthrough (target re-rendered), overlay (the fit drawn over the target), mirror (the target's face re-textured / re-lit: --texture, --at, --light) or raw (unchanged)")
      ->capture_default_str();
  cmd->add_option("--model", args->model, "with --target: face model file (default: the installed/generated one)");
  cmd->add_option("--camera-size", args->camera_size, "with a camera --target: capture size WIDTHxHEIGHT")
      ->capture_default_str();
  add_pipeline_options(cmd, args.get());
  cmd->add_option("--size", args->size, "output size WIDTHxHEIGHT (input is letterboxed into it)")
      ->capture_default_str();
  cmd->add_option("--fps", args->fps, "output frame rate")->capture_default_str();
  cmd->add_option("--format", args->format, "pixel format: yuyv (what OBS sends; safest) or i420")
      ->capture_default_str();
  cmd->add_flag("--loop", args->loop, "start the video again at its end");
  cmd->add_flag("--status", args->status, "print statistics once a second");
  cmd->add_option("--seconds", args->seconds, "stop after this many seconds (default: run until Ctrl-C)");
  cmd->add_option("--reconnect", args->reconnect_s, "seconds between attempts to reopen a lost device")
      ->capture_default_str();
  cmd->callback([args] { run_webcam(*args); });

  CLI::App* bench = get_or_add_subcommand(app, "bench", "Measure the speed of pipeline stages");
  auto bench_args = std::make_shared<WebcamArgs>();
  auto iterations = std::make_shared<int>(200);
  CLI::App* bench_webcam =
      bench->add_subcommand("webcam", "Time letterboxing + BGR->YUYV/I420 conversion per output frame");
  bench_webcam->add_option("--size", bench_args->size, "output size")->capture_default_str();
  bench_webcam->add_option("--iterations", *iterations, "frames per measurement")->capture_default_str();
  bench_webcam->callback([bench_args, iterations] {
    int w, h;
    parse_frame_size(bench_args->size, &w, &h);
    if (*iterations <= 0) throw Error("--iterations must be positive");
    auto source = make_test_pattern_source(640, 480, 30);
    SourceFrame frame;
    std::string error;
    source->next(&frame, &error);
    for (PixelFormat format : {PixelFormat::kYuyv, PixelFormat::kI420}) {
      std::vector<uint8_t> out(frame_bytes(format, w, h));
      cv::Mat same_size = letterbox_bgr(frame.bgr, w, h);
      auto time_ms = [&](auto&& fn) {
        fn();  // warm-up
        auto t0 = std::chrono::steady_clock::now();
        for (int i = 0; i < *iterations; ++i) fn();
        return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() / *iterations;
      };
      double convert_ms = time_ms([&] { convert_bgr(same_size, format, out); });
      double fit_convert_ms = time_ms([&] { convert_bgr(letterbox_bgr(frame.bgr, w, h), format, out); });
      std::printf("%s %dx%d: convert %.3f ms/frame, letterbox 640x480 + convert %.3f ms/frame (%d frames)\n",
                  pixel_format_name(format), w, h, convert_ms, fit_convert_ms, *iterations);
    }
  });

  // bench live: the live session's throughput, capture-to-output latency and where the time
  // goes (per stage, per thread), as the OBS source and the webcam run it.
  auto live_args = std::make_shared<WebcamArgs>();
  auto live_seconds = std::make_shared<double>(5);
  auto live_warmup = std::make_shared<double>(0);
  CLI::App* bench_live = bench->add_subcommand(
      "live", "Run the live session (as OBS and the webcam do) on a target and report fps, latency and the time per stage and thread");
  bench_live->add_option("--target", live_args->target, "camera or recording/video (looped)")->required();
  bench_live->add_option("--source", live_args->source, "expression source (none, udp://PORT, camera, recording)")
      ->capture_default_str();
  bench_live->add_option("--key", live_args->key_file, "stream key file for udp://");
  bench_live->add_option("--mode", live_args->mode, "reenact, passthrough, overlay, mirror or raw")->capture_default_str();
  bench_live->add_option("--model", live_args->model, "face model file");
  add_pipeline_options(bench_live, live_args.get());
  bench_live->add_option("--seconds", *live_seconds, "measurement time after the first frame (and the warm-up)")
      ->capture_default_str();
  auto live_overlap = std::make_shared<bool>(false);
  bench_live->add_flag("--overlap", *live_overlap,
                       "Render frame n on a second thread while the worker tracks frame n+1 (LiveSession::Options::overlap_frames)");
  auto live_marks = std::make_shared<bool>(false);
  bench_live->add_flag("--landmarks-ahead", *live_marks,
                       "Detect frame n+1's landmarks on a thread of their own while frame n is fitted "
                       "(LiveSession::Options::landmarks_ahead)");
  bench_live->add_option("--warmup", *live_warmup,
                         "seconds after the first frame left out of the measurement (model load, calibration)")
      ->capture_default_str();
  bench_live->callback([live_args, live_seconds, live_warmup, live_overlap, live_marks] {
    if (!(*live_seconds > 0) || *live_seconds > 3600) throw Error("--seconds must be in (0, 3600]");
    if (!(*live_warmup >= 0) || *live_warmup > 600) throw Error("--warmup must be in [0, 600]");
    live::LiveSession::Options o;
    o.target = live_args->target;
    o.source = live_args->source;
    o.key_file = live_args->key_file;
    o.model_path = live_args->model;
    o.overlap_frames = *live_overlap;
    o.landmarks_ahead = *live_marks;
    apply_pipeline_args(*live_args, &o);
    if (!live::parse_output_mode(live_args->mode, &o.mode))
      throw Error("--mode '" + live_args->mode + "' is not one of reenact, passthrough, overlay, mirror, raw");
    live::LiveSession::CheckInputs(o);
    live::LiveSession session(o);
    live::LiveFrame frame;
    if (!session.wait_frame(0, std::chrono::seconds(60), &frame))
      throw Error("bench live: no frame within 60 s: " + session.status().Headline());
    uint64_t last = frame.sequence;
    const auto warm_end = std::chrono::steady_clock::now() + std::chrono::nanoseconds(static_cast<int64_t>(*live_warmup * 1e9));
    while (std::chrono::steady_clock::now() < warm_end)
      if (session.wait_frame(last, std::chrono::milliseconds(200), &frame)) last = frame.sequence;

    // The measurement: the session's stage times and counts, each thread's CPU time, and the
    // output conversion the virtual webcam does on every frame (BGR -> YUYV).
    session.ResetTimings();
    const std::vector<ThreadInfo> threads_before = ProcessThreads();
    const double cpu_before = ProcessCpuSeconds();
    std::vector<double> latency_ms;
    double convert_ms = 0;
    std::vector<uint8_t> yuyv;
    const auto start = std::chrono::steady_clock::now();
    const auto end = start + std::chrono::nanoseconds(static_cast<int64_t>(*live_seconds * 1e9));
    const uint64_t first = last;
    while (std::chrono::steady_clock::now() < end) {
      if (!session.wait_frame(last, std::chrono::milliseconds(200), &frame)) continue;
      last = frame.sequence;
      latency_ms.push_back(std::chrono::duration<double, std::milli>(frame.produced - frame.captured).count());
      const auto tc = std::chrono::steady_clock::now();
      yuyv.resize(frame_bytes(PixelFormat::kYuyv, frame.bgr.cols, frame.bgr.rows));
      convert_bgr(frame.bgr, PixelFormat::kYuyv, yuyv);
      convert_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - tc).count();
    }
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    const double cpu_s = ProcessCpuSeconds() - cpu_before;
    const std::vector<ThreadInfo> threads_after = ProcessThreads();
    const live::LiveTimings t = session.timings();
    live::LiveStatus status = session.status();
    session.stop();

    std::sort(latency_ms.begin(), latency_ms.end());
    double mean = 0;
    for (double v : latency_ms) mean += v;
    mean = latency_ms.empty() ? 0 : mean / latency_ms.size();
    double p95 = latency_ms.empty() ? 0 : latency_ms[std::min(latency_ms.size() - 1, latency_ms.size() * 95 / 100)];
    std::printf("bench live: %s\n", session.describe().c_str());
    std::printf("  target: %s\n", status.target.c_str());
    std::printf("  %s\n", status.Headline().c_str());
    if (status.stream_source)
      std::printf("  stream: %s\n", status.stream_statistics.Counts().c_str());
    // Where each frame was rendered: on the worker, on the render thread, or some of each (two
    // threads while one fell behind the input).
    std::string where_rendered = "track and render on the worker";
    if (t.overlapped > 0 && t.overlapped == t.frames) where_rendered = "render on its own thread";
    else if (t.overlapped > 0)
      where_rendered = "render on its own thread for " + std::to_string(t.overlapped) + " of " +
                       std::to_string(t.frames) + " frames (while behind)";
    if (t.overlap_changes > 0)
      where_rendered += ", " + std::to_string(t.overlap_changes) + " change" + (t.overlap_changes > 1 ? "s" : "") +
                        " between one thread and two";
    std::printf("  tracker solver: %s; renderer: %s; %s%s\n",
                status.solver.empty() ? "(pipeline not loaded)" : status.solver.c_str(), o.use_vulkan ? "vulkan" : "cpu",
                where_rendered.c_str(), status.landmarks_ahead ? "; landmarks on their own thread, a frame ahead" : "");
    std::printf("  output %.1f fps (%llu frames in %.1f s; target delivers %.1f fps), pipeline %.2f ms/frame, "
                "capture-to-output latency mean %.2f ms, p95 %.2f ms\n",
                double(last - first) / seconds, static_cast<unsigned long long>(last - first), seconds, status.target_fps,
                status.process_ms, mean, p95);
    const double n = static_cast<double>(std::max<int64_t>(1, t.frames));
    std::printf("  frames: %lld processed, %lld tracked (%.1f tracked fps), %lld calibrating, %lld unchanged; "
                "input delivered %lld, dropped at the input %lld (only the newest frame is kept)\n",
                static_cast<long long>(t.frames), static_cast<long long>(t.tracked), t.tracked / seconds,
                static_cast<long long>(t.calibrating), static_cast<long long>(t.unchanged),
                static_cast<long long>(t.input_frames), static_cast<long long>(t.dropped_at_input));
    std::printf("  per frame, mean ms from the worker taking it to its output (the paper's Table 1 rows):\n");
    for (const live::LiveStageRow& row : live::LiveStageRows())
      std::printf("    %-26s %8.2f\n", row.name, t.sum.*row.ms / n);
    std::printf("    %-26s %8.2f\n", "total", t.sum.total_ms / n);
    std::printf("    %-26s %8.2f   (BGR -> YUYV, as the virtual webcam does per frame)\n", "output conversion",
                latency_ms.empty() ? 0.0 : convert_ms / latency_ms.size());
    // CPU per thread, summed over threads of one name (the pool's helpers share theirs).
    std::vector<std::pair<std::string, double>> per_name;
    double listed = 0;
    for (const ThreadInfo& a : threads_after) {
      double before = 0;
      for (const ThreadInfo& b : threads_before)
        if (b.tid == a.tid) before = b.cpu_s;
      const double used = std::max(0.0, a.cpu_s - before);
      listed += used;
      auto it = std::find_if(per_name.begin(), per_name.end(), [&](const auto& p) { return p.first == a.name; });
      if (it == per_name.end()) per_name.emplace_back(a.name, used);
      else it->second += used;
    }
    if (cpu_s - listed > 0.02) per_name.emplace_back("(threads that ended)", cpu_s - listed);
    std::sort(per_name.begin(), per_name.end(), [](const auto& a, const auto& b) { return a.second > b.second; });
    const unsigned cores = std::max(1u, std::thread::hardware_concurrency());
    std::printf("  CPU: %.2f of %u cores busy on average (%.1f CPU-s in %.1f s)\n", cpu_s / seconds, cores, cpu_s, seconds);
    for (const auto& [name, used] : per_name)
      if (used >= 0.005) std::printf("    %-22s %5.1f %% of a core\n", name.c_str(), 100.0 * used / seconds);
  });

  add_bench_soak(bench);
}

}  // namespace

FR_REGISTER_COMMANDS(webcam, add_webcam_command);

}  // namespace face_reenact::cli
