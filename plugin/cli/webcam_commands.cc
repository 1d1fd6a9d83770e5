// `face-reenact webcam`: a virtual webcam on a v4l2loopback device that Zoom, Meet and Firefox
// list as a camera (docs/virtual-webcam.md), and `face-reenact bench webcam` (conversion cost).
//
// Extension point: the reenactment pipeline becomes one more FrameSource (a live one) chosen
// by an input option here; the writer, pacing and reconnect logic below stay as they are.
// Until that pipeline exists the command sends a video, an image or a test pattern.
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "command_registry.h"
#include "face_reenact/common/error.h"
#include "face_reenact/output/frame_source.h"
#include "face_reenact/output/pixel_conversion.h"
#include "face_reenact/output/v4l2_loopback_writer.h"
#include "face_reenact/output/webcam_streamer.h"

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
};

void parse_size(const std::string& text, int* width, int* height) {
  int w = 0, h = 0;
  char tail = 0;
  if (std::sscanf(text.c_str(), "%dx%d%c", &w, &h, &tail) != 2 || w <= 0 || h <= 0)
    throw Error("--size '" + text + "' is not WIDTHxHEIGHT (e.g. 1280x720)");
  *width = w;
  *height = h;
}

void run_webcam(const WebcamArgs& args) {
  V4l2LoopbackWriter::Options writer_options;
  writer_options.device = args.device;
  parse_size(args.size, &writer_options.width, &writer_options.height);
  std::optional<PixelFormat> format = parse_pixel_format(args.format);
  if (!format) throw Error("--format '" + args.format + "' is not one of yuyv, i420");
  writer_options.format = *format;
  std::optional<FrameRate> rate = FrameRate::from_double(args.fps);
  if (!rate) throw Error("--fps must be in (0, 240]");
  writer_options.rate = *rate;
  if (!(args.reconnect_s > 0) || args.reconnect_s > 3600) throw Error("--reconnect must be in (0, 3600] seconds");
  std::string why;
  if (!writer_options.IsValid(&why)) throw Error(why);

  // The source first: a bad input file is reported before the device is touched.
  std::unique_ptr<FrameSource> source;
  bool hold = false;
  if (args.input.empty()) {
    source = make_test_pattern_source(writer_options.width, writer_options.height, rate->fps());
  } else {
    source = open_media_source({.path = args.input, .loop = args.loop});
    hold = is_still_image(args.input);  // a picture stays up until stopped
  }

  V4l2LoopbackWriter writer(writer_options);
  writer.open();
  const auto& info = writer.device_info();
  std::fprintf(stderr, "webcam: %s (%s, %s): %dx%d %s at %.2f fps from %s\n", args.device.c_str(), info.card.c_str(),
               info.bus_info.c_str(), writer_options.width, writer_options.height, pixel_format_name(writer_options.format),
               rate->fps(), source->describe().c_str());
  for (const auto& w : info.warnings) std::fprintf(stderr, "webcam: warning: %s\n", w.c_str());

  WebcamStreamer::Options options;
  options.width = writer_options.width;
  options.height = writer_options.height;
  options.format = writer_options.format;
  options.rate = *rate;
  options.reconnect_interval = std::chrono::nanoseconds(static_cast<int64_t>(args.reconnect_s * 1e9));
  options.hold_last_frame = hold;
  if (args.status)
    options.on_status = [](const StreamStatistics& s) {
      std::fprintf(stderr, "webcam: status: source frames %lld, %s\n", static_cast<long long>(s.source_frames),
                   s.BriefReport().c_str());
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
        return;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
  });
  WebcamStreamer streamer(source.get(), &writer, options);
  WebcamStreamer::Summary summary;
  try {
    summary = streamer.run(stop);
  } catch (...) {
    done.store(true);
    watcher.join();
    throw;
  }
  done.store(true);
  watcher.join();
  if (summary.stop_reason == "stop requested")
    summary.stop_reason = signals.signal_number() == SIGINT    ? "stopped by SIGINT"
                          : signals.signal_number() == SIGTERM ? "stopped by SIGTERM"
                                                               : "time limit reached";
  std::fprintf(stderr, "webcam: %s\n", summary.BriefReport().c_str());
  if (summary.source_failed) throw Error("webcam: " + summary.stop_reason);
}

void add_webcam_command(CLI::App& app) {
  auto args = std::make_shared<WebcamArgs>();
  CLI::App* cmd = app.add_subcommand(
      "webcam",
      "Send frames to a v4l2loopback virtual webcam (Zoom/Meet/Firefox see it as a camera): a video, an image, "
      "or colour bars when no --input is given");
  cmd->add_option("--device", args->device, "v4l2loopback device node, e.g. /dev/video10")->required();
  cmd->add_option("--input", args->input, "video or image file to send (default: a colour-bar test pattern)");
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
    parse_size(bench_args->size, &w, &h);
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
}

}  // namespace

FR_REGISTER_COMMANDS(webcam, add_webcam_command);

}  // namespace face_reenact::cli
