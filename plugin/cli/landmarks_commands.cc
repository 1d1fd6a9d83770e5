// `face-reenact landmarks`: 68-point landmarks on an image, a video or an RGB-D recording
// folder (JSON + drawings), the accuracy evaluation on annotated photos or on a recording's
// ground truth (--eval) and the video stability/cost report (--video-report);
// `face-reenact bench landmarks`: per-stage costs.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <numeric>
#include <time.h>

#include "command_registry.h"
#include "face_reenact/capture/recording.h"
#include "face_reenact/common/byte_io.h"
#include "face_reenact/common/error.h"
#include "face_reenact/landmarks/drawing.h"
#include "face_reenact/landmarks/evaluation.h"
#include "face_reenact/landmarks/frame_source.h"
#include "face_reenact/landmarks/landmark_detector.h"
#include "face_reenact/landmarks/landmark_tracker.h"

namespace face_reenact::cli {
namespace {
namespace lm = face_reenact::landmarks;
namespace fs = std::filesystem;

struct LandmarkArgs {
  std::string input, out, draw, eval, video_report, shape_predictor;
  bool detect_every_frame = false, json = false, smooth = false;
  int max_frames = 0;
  int samples = 0;
  int detection_width = -1;
  int upsample = -1;
  int sheet_tiles = 48;
};

void write_text(const std::string& path, const std::string& text) {
  write_file_atomic(path, std::span<const uint8_t>(reinterpret_cast<const uint8_t*>(text.data()), text.size()));
}

lm::DetectorOptions detector_options(const LandmarkArgs& a, lm::DetectorOptions o) {
  o.shape_predictor_path = a.shape_predictor;
  if (a.samples > 0) o.confidence_samples = a.samples;
  if (a.detection_width >= 0) o.detection_width = a.detection_width;
  if (a.upsample >= 0) o.max_upsample = a.upsample;
  std::string error;
  if (!o.IsValid(&error)) throw Error(error);
  return o;
}

lm::TrackerOptions tracker_options(const LandmarkArgs& a) {
  lm::TrackerOptions t;
  t.detector = detector_options(a, t.detector);
  t.detect_every_frame = a.detect_every_frame;
  t.smoothing.enabled = a.smooth;
  return t;
}

// A recording folder (docs/recording-format.md) as a landmarks::FrameSource, so fr_landmarks
// needs no dependency on fr_capture. Keeps the last frame's ground truth for --eval. Bad data
// (a corrupt PNG, a missing file) throws face_reenact::Error naming the file: a recording is
// a data set, so a damaged frame is an error rather than an early end as in a video.
class RecordingLandmarkSource : public lm::FrameSource {
 public:
  explicit RecordingLandmarkSource(const std::string& dir) : reader_(dir) {}
  bool Next(lm::Frame* frame) override {
    capture::RgbdFrame rgbd;
    if (!reader_.read_next(&rgbd)) return false;
    const cv::Mat& color = rgbd.color;  // CV_8UC3 BGR, checked by the reader
    if (color.type() != CV_8UC3) throw Error(Describe() + ": frame " + std::to_string(rgbd.index) + " is not 8-bit BGR");
    frame->image.width = color.cols;
    frame->image.height = color.rows;
    frame->image.format = lm::PixelFormat::kBGR8;
    frame->image.pixels.resize(size_t(color.cols) * size_t(color.rows) * 3);
    for (int y = 0; y < color.rows; ++y) {
      std::copy_n(color.ptr<uint8_t>(y), size_t(color.cols) * 3,
                  frame->image.pixels.data() + size_t(y) * size_t(color.cols) * 3);
    }
    frame->index = rgbd.index;
    frame->timestamp_s = rgbd.timestamp_s;
    ground_truth_ = std::move(rgbd.ground_truth);
    return true;
  }
  std::string Describe() const override { return "recording '" + reader_.dir() + "'"; }
  double fps() const override { return reader_.info().fps; }
  int64_t frame_count_hint() const override { return reader_.frame_count(); }
  const capture::GroundTruth& ground_truth() const { return ground_truth_; }

 private:
  capture::RecordingReader reader_;
  capture::GroundTruth ground_truth_;
};

bool is_directory(const std::string& path) {
  std::error_code ec;
  return fs::is_directory(path, ec);
}

// A folder is taken as a recording when it has the recording's own files (a damaged one
// without recording.json still gets the recording reader's error naming that file).
bool looks_like_recording(const std::string& dir) {
  std::error_code ec;
  return is_directory(dir) &&
         (fs::exists(fs::path(dir) / "recording.json", ec) || fs::exists(fs::path(dir) / "frames.jsonl", ec));
}

// Input files go through landmarks::open_frame_source; folders are recordings.
std::unique_ptr<lm::FrameSource> open_input(const std::string& path) {
  if (is_directory(path)) return std::make_unique<RecordingLandmarkSource>(path);
  return lm::open_frame_source(path);
}

void print_result_line(const std::string& label, const lm::LandmarkResult& r) {
  if (r.has_landmarks) {
    float mc = 0;
    for (float c : r.confidence) mc += c;
    std::printf("%s: %s (%s), box %.0f,%.0f %.0fx%.0f, score %.2f, mean confidence %.2f%s%s\n", label.c_str(),
                lm::status_name(r.status), lm::source_name(r.source), double(r.face_box.x), double(r.face_box.y),
                double(r.face_box.width), double(r.face_box.height), double(r.score), double(mc / lm::kNumLandmarks),
                r.ok() ? "" : " - ", r.ok() ? "" : r.reason.c_str());
  } else {
    std::printf("%s: %s - %s\n", label.c_str(), lm::status_name(r.status), r.reason.c_str());
  }
}

void run_input(const LandmarkArgs& a) {
  std::unique_ptr<lm::FrameSource> source = open_input(a.input);
  nlohmann::json doc;
  doc["input"] = a.input;
  doc["format"] = "face-reenact-landmarks";
  doc["version"] = 1;
  doc["layout"] = "ibug68";
  nlohmann::json frames = nlohmann::json::array();
  const bool still = source->is_still_image();
  doc["kind"] = still ? "image" : is_directory(a.input) ? "recording" : "video";
  const bool sheet = !a.draw.empty() && !still && fs::path(a.draw).extension() == ".png";
  if (!a.draw.empty() && !still && !sheet) {
    std::error_code ec;
    fs::create_directories(a.draw, ec);
    if (ec) throw Error("--draw '" + a.draw + "': cannot create folder (" + ec.message() + ")");
  }
  std::vector<lm::Image> tiles;
  int64_t hint = source->frame_count_hint();
  if (a.max_frames > 0 && (hint < 0 || hint > a.max_frames)) hint = a.max_frames;
  const int64_t tile_every = hint > 0 ? std::max<int64_t>(1, (hint + a.sheet_tiles - 1) / a.sheet_tiles) : 10;

  lm::Frame frame;
  if (still) {
    lm::LandmarkDetector detector(detector_options(a, {}));
    if (!source->Next(&frame)) throw Error(source->Describe() + ": no image");
    const lm::LandmarkResult r = detector.Detect(frame.image.view());
    print_result_line(a.input, r);
    nlohmann::json j = lm::to_json(r);
    j["index"] = 0;
    j["width"] = frame.image.width;
    j["height"] = frame.image.height;
    frames.push_back(std::move(j));
    if (!a.draw.empty()) {
      lm::save_png(a.draw, lm::draw_landmarks(frame.image.view(), r).view());
      std::printf("drawing written to %s\n", a.draw.c_str());
    }
  } else {
    lm::LandmarkTracker tracker(tracker_options(a));
    int n = 0;
    std::map<std::string, int> statuses;
    while ((a.max_frames <= 0 || n < a.max_frames) && source->Next(&frame)) {
      const lm::LandmarkResult r = tracker.Track(frame.image.view(), frame.timestamp_s);
      ++statuses[lm::status_name(r.status)];
      nlohmann::json j = lm::to_json(r);
      j["index"] = frame.index;
      j["timestamp_s"] = frame.timestamp_s;
      frames.push_back(std::move(j));
      if (!a.draw.empty()) {
        char caption[32];
        std::snprintf(caption, sizeof(caption), "#%lld", static_cast<long long>(frame.index));
        if (sheet) {
          if (frame.index % tile_every == 0 && int(tiles.size()) < a.sheet_tiles) {
            tiles.push_back(lm::draw_landmarks(frame.image.view(), r, caption));
          }
        } else {
          char name[32];
          std::snprintf(name, sizeof(name), "frame_%06lld.png", static_cast<long long>(frame.index));
          lm::save_png((fs::path(a.draw) / name).string(), lm::draw_landmarks(frame.image.view(), r, caption).view());
        }
      }
      ++n;
    }
    if (n == 0) throw Error(source->Describe() + ": no frame could be decoded");
    std::printf("%s: %d frames (%s)\n", a.input.c_str(), n, tracker.summary().BriefReport().c_str());
    for (const auto& [status, count] : statuses) std::printf("  %-18s %d\n", status.c_str(), count);
    doc["tracker"] = tracker.summary().BriefReport();
    if (sheet) {
      const int columns = int(std::ceil(std::sqrt(double(tiles.size()))));
      lm::save_png(a.draw, lm::contact_sheet(tiles, columns, 240).view());
      std::printf("contact sheet of %zu frames written to %s\n", tiles.size(), a.draw.c_str());
    } else if (!a.draw.empty()) {
      std::printf("%d drawings written to %s/\n", n, a.draw.c_str());
    }
  }
  doc["frames"] = std::move(frames);
  if (!a.out.empty()) {
    write_text(a.out, doc.dump(1) + "\n");
    std::printf("landmarks written to %s\n", a.out.c_str());
  }
}

// --eval on a recording with ground truth: the frames are tracked as a video (the mode the
// product runs in) and each frame is scored over its ground-truth-visible points.
lm::EvalReport evaluate_recording(const LandmarkArgs& a) {
  RecordingLandmarkSource source(a.eval);
  lm::LandmarkTracker tracker(tracker_options(a));
  lm::EvalAccumulator accumulator(a.eval, "frame");
  lm::Frame frame;
  int n = 0, without_truth = 0;
  while ((a.max_frames <= 0 || n < a.max_frames) && source.Next(&frame)) {
    ++n;
    const auto t0 = std::chrono::steady_clock::now();
    const lm::LandmarkResult r = tracker.Track(frame.image.view(), frame.timestamp_s);
    const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    const auto& truth_points = source.ground_truth().landmarks;
    if (!truth_points) {
      ++without_truth;  // tracked (the next frames depend on it) but not scored
      continue;
    }
    lm::Shape68 truth{};
    std::array<bool, lm::kNumLandmarks> visible{};
    for (size_t i = 0; i < size_t(lm::kNumLandmarks); ++i) {
      truth[i] = (*truth_points)[i].pixel;
      visible[i] = (*truth_points)[i].visible;
    }
    lm::EvalImage e;
    char name[32];
    std::snprintf(name, sizeof(name), "frame %06lld", static_cast<long long>(frame.index));
    e.path = name;
    e.index = frame.index;
    e.milliseconds = ms;
    accumulator.Add(std::move(e), r, truth, &visible);
  }
  if (n == 0) throw Error(source.Describe() + ": has no frames");
  if (without_truth == n) {
    throw Error(source.Describe() + ": no frame has ground-truth landmarks (a real recording?); "
                "--eval needs a synthetic recording (face-reenact synth)");
  }
  lm::EvalReport report = accumulator.Finish();
  if (without_truth > 0) {
    std::fprintf(stderr, "%s: %d of %d frames have no ground-truth landmarks and were not scored\n",
                 source.Describe().c_str(), without_truth, n);
  }
  return report;
}

void run_eval(const LandmarkArgs& a) {
  lm::EvalReport report;
  if (looks_like_recording(a.eval)) {
    report = evaluate_recording(a);
  } else {
    lm::LandmarkDetector detector(detector_options(a, {}));
    report = lm::evaluate_annotated_folder(a.eval, &detector);
  }
  if (a.json) {
    std::printf("%s\n", report.ToJson().dump(1).c_str());
    return;
  }
  for (const lm::EvalImage& e : report.per_image) {
    if (e.has_landmarks) {
      std::printf("%-60s NME %.4f  conf %.2f  %-17s %6.1f ms%s\n", e.path.c_str(), double(e.nme),
                  double(e.mean_confidence), lm::status_name(e.status), e.milliseconds, e.nme > 0.1f ? "  FAILURE" : "");
    } else {
      std::printf("%-60s %s - %s\n", e.path.c_str(), lm::status_name(e.status), e.reason.c_str());
    }
  }
  std::printf("\n%d %ss: mean NME %.4f (median %.4f) over %d with landmarks; no face %d; failures (NME > 0.1) %d\n",
              report.images, report.unit.c_str(), report.mean_nme, report.median_nme, report.images - report.no_face, report.no_face,
              report.failures);
  std::printf("point error (inter-ocular units): high-confidence half %.4f, low-confidence half %.4f; "
              "Spearman(confidence, error) %.3f\n",
              report.point_error_high_confidence, report.point_error_low_confidence,
              report.confidence_error_correlation);
}

void run_video_report(const LandmarkArgs& a) {
  const lm::VideoReport report = lm::video_report(a.video_report, tracker_options(a), a.max_frames);
  if (a.json) {
    std::printf("%s\n", report.ToJson().dump(1).c_str());
    return;
  }
  std::printf("%s: %dx%d at %.1f fps\n", report.path.c_str(), report.width, report.height, report.fps);
  std::printf("%-20s %7s %7s %12s %12s %9s %9s %9s %9s %9s\n", "mode", "frames", "w/face", "jitter", "jitter-comp",
              "ms mean", "ms p95", "ms max", "cpu mean", "cpu p95");
  for (const lm::VideoModeReport& m : report.modes) {
    std::printf("%-20s %7d %7d %12.5f %12.5f %9.2f %9.2f %9.2f %9.2f %9.2f\n", m.mode.c_str(), m.frames,
                m.frames_with_landmarks, m.jitter_raw, m.jitter_motion_compensated, m.ms_mean, m.ms_p95, m.ms_max,
                m.cpu_ms_mean, m.cpu_ms_p95);
  }
  for (const lm::VideoModeReport& m : report.modes) std::printf("  %s: %s\n", m.mode.c_str(), m.summary.BriefReport().c_str());
  std::printf("jitter: mean frame-to-frame motion of eye corners and nose over the outer-eye distance; "
              "'comp' after removing the head's similarity motion\n");
}

void add_landmarks(CLI::App& app) {
  auto args = std::make_shared<LandmarkArgs>();
  CLI::App* cmd = app.add_subcommand("landmarks", "68-point facial landmarks on an image or video (dlib)");
  auto* in = cmd->add_option("--input", args->input, "image or video file, or an RGB-D recording folder");
  auto* ev = cmd->add_option("--eval", args->eval,
                             "folder of images with .pts annotations (recursive), or a recording with ground truth "
                             "(tracked): NME report");
  auto* vr = cmd->add_option("--video-report", args->video_report,
                             "video: jitter and per-frame cost of tracking vs detection on every frame");
  in->excludes(ev)->excludes(vr);
  ev->excludes(vr);
  cmd->add_option("--out", args->out, "JSON file with points, confidence and status per image/frame");
  cmd->add_option("--draw", args->draw,
                  "PNG with the points drawn; for a video a folder (one PNG per frame) or a .png contact sheet");
  cmd->add_flag("--detect-every-frame", args->detect_every_frame, "search the whole frame every frame (no tracking)");
  cmd->add_flag("--smooth", args->smooth, "One-Euro temporal smoothing of the tracked points");
  cmd->add_option("--max-frames", args->max_frames, "videos, recordings: stop after N frames (0: all)")->check(CLI::NonNegativeNumber);
  cmd->add_flag("--json", args->json, "--eval/--video-report: print JSON instead of a table");
  cmd->add_option("--samples", args->samples, "shape-predictor runs per face for the confidence (1-9)")
      ->check(CLI::Range(1, 9));
  cmd->add_option("--detection-width", args->detection_width, "width of the face search image (0: full size)")
      ->check(CLI::NonNegativeNumber);
  cmd->add_option("--upsample", args->upsample, "still images: 2x upsampled searches when no face is found (0-3)")
      ->check(CLI::Range(0, 3));
  cmd->add_option("--shape-predictor", args->shape_predictor, "dlib 68-point model (default: libdlib-data's)");
  cmd->add_option("--sheet-tiles", args->sheet_tiles, "frames on a video contact sheet")->check(CLI::Range(1, 400));
  cmd->callback([args] {
    if (!args->eval.empty()) return run_eval(*args);
    if (!args->video_report.empty()) return run_video_report(*args);
    if (!args->input.empty()) return run_input(*args);
    throw Error("landmarks: give --input FILE|RECORDING, --eval DIR|RECORDING or --video-report VIDEO");
  });

  struct BenchArgs {
    std::string video, image;
    int frames = 150;
    bool json = false;
  };
  auto bench_args = std::make_shared<BenchArgs>();
  CLI::App* bench = get_or_add_subcommand(app, "bench", "measure the speed of pipeline stages");
  CLI::App* b = bench->add_subcommand("landmarks", "landmark stages: grey conversion, face search, shape fit, tracking");
  b->add_option("--video", bench_args->video, "640x480 video (default: $FR_SHARED_DATA/videos/webcam_talking_640x480.wmv)");
  b->add_option("--frames", bench_args->frames, "frames per mode")->check(CLI::PositiveNumber);
  b->add_flag("--json", bench_args->json, "print JSON");
  b->callback([bench_args] {
    std::string video = bench_args->video;
    if (video.empty()) {
      const char* shared = std::getenv("FR_SHARED_DATA");
      video = std::string(shared ? shared : "../shared/data") + "/videos/webcam_talking_640x480.wmv";
    }
    std::unique_ptr<lm::FrameSource> source = lm::open_frame_source(video);
    lm::Frame frame;
    std::vector<lm::Image> frames;
    while (int(frames.size()) < 30 && source->Next(&frame)) frames.push_back(frame.image);
    if (frames.empty()) throw Error("bench: no frame in '" + video + "'");
    lm::LandmarkDetector detector;
    using clock = std::chrono::steady_clock;
    auto thread_cpu_ms = [] {
      timespec ts{};
      clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
      return double(ts.tv_sec) * 1e3 + double(ts.tv_nsec) * 1e-6;
    };
    struct Timing {
      double mean, p95, cpu_mean;
    };
    auto time_ms = [&](auto&& fn, int reps) {
      std::vector<double> ms;
      double cpu = 0;
      for (int i = 0; i < reps; ++i) {
        const double c0 = thread_cpu_ms();
        const auto t0 = clock::now();
        fn(i);
        ms.push_back(std::chrono::duration<double, std::milli>(clock::now() - t0).count());
        cpu += thread_cpu_ms() - c0;
      }
      std::sort(ms.begin(), ms.end());
      return Timing{std::accumulate(ms.begin(), ms.end(), 0.0) / double(ms.size()),
                    ms[std::min(ms.size() - 1, size_t(0.95 * double(ms.size())))], cpu / reps};
    };
    nlohmann::json j;
    j["video"] = video;
    j["width"] = frames[0].width;
    j["height"] = frames[0].height;
    const auto n = frames.size();
    lm::DetectorOptions full_opts;
    full_opts.detection_width = 0;
    lm::LandmarkDetector full_res(full_opts);
    auto stage = [&](const char* name, Timing t) {
      j["stages"][name] = {{"ms_mean", t.mean}, {"ms_p95", t.p95}, {"cpu_ms_mean", t.cpu_mean}};
    };
    stage("grey_conversion", time_ms([&](int i) { lm::to_gray_image(frames[size_t(i) % n].view()); }, 100));
    stage("face_search_320", time_ms([&](int i) { detector.FindFaces(frames[size_t(i) % n].view(), false); }, 30));
    stage("face_search_full", time_ms([&](int i) { full_res.FindFaces(frames[size_t(i) % n].view(), false); }, 10));
    const auto faces = detector.FindFaces(frames[0].view(), true);
    if (!faces.empty()) {
      for (int s : {1, 3, 5}) {
        const std::string name = "shape_fit_" + std::to_string(s) + "_samples";
        stage(name.c_str(), time_ms([&](int) { detector.FitFromBox(frames[0].view(), faces[0].box, s); }, 50));
      }
    }
    lm::TrackerOptions tracking;
    for (const bool every : {false, true}) {
      tracking.detect_every_frame = every;
      const lm::VideoModeReport m =
          lm::run_video_mode(video, tracking, every ? "detect_every_frame" : "tracking", bench_args->frames);
      j["modes"][m.mode] = {{"frames", m.frames},         {"ms_mean", m.ms_mean},         {"ms_p95", m.ms_p95},
                            {"ms_max", m.ms_max},         {"cpu_ms_mean", m.cpu_ms_mean}, {"cpu_ms_p95", m.cpu_ms_p95},
                            {"frames_with_landmarks", m.frames_with_landmarks}};
    }
    if (bench_args->json) {
      std::printf("%s\n", j.dump(1).c_str());
      return;
    }
    std::printf("bench landmarks on %s (%dx%d)\n", video.c_str(), frames[0].width, frames[0].height);
    for (auto& [name, v] : j["stages"].items()) {
      std::printf("  %-26s mean %7.2f ms  p95 %7.2f ms  cpu mean %7.2f ms\n", name.c_str(),
                  v["ms_mean"].get<double>(), v["ms_p95"].get<double>(), v["cpu_ms_mean"].get<double>());
    }
    for (auto& [name, v] : j["modes"].items()) {
      std::printf("  per frame, %-18s mean %7.2f ms  p95 %7.2f ms  max %7.2f ms  cpu mean %6.2f ms  cpu p95 %6.2f ms"
                  "  (%d/%d frames with landmarks)\n",
                  name.c_str(), v["ms_mean"].get<double>(), v["ms_p95"].get<double>(), v["ms_max"].get<double>(),
                  v["cpu_ms_mean"].get<double>(), v["cpu_ms_p95"].get<double>(), v["frames_with_landmarks"].get<int>(),
                  v["frames"].get<int>());
    }
  });
}

}  // namespace

FR_REGISTER_COMMANDS(landmarks, add_landmarks);

}  // namespace face_reenact::cli
