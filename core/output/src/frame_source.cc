#include "face_reenact/output/frame_source.h"

#include <cmath>
#include <filesystem>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "face_reenact/common/error.h"

namespace face_reenact::output {

const unsigned char kTestPatternBarBgr[kTestPatternBars][3] = {
    {255, 255, 255}, {0, 255, 255}, {255, 255, 0}, {0, 255, 0},
    {255, 0, 255},   {0, 0, 255},   {255, 0, 0},   {0, 0, 0}};

namespace {

std::chrono::nanoseconds frame_time(int64_t index, double fps) {
  return std::chrono::nanoseconds(static_cast<int64_t>(std::llround(double(index) * 1e9 / fps)));
}

class StillImageSource : public FrameSource {
 public:
  StillImageSource(std::string path, cv::Mat image) : path_(std::move(path)), image_(std::move(image)) {}
  SourceStatus next(SourceFrame* frame, std::string*) override {
    if (delivered_) return SourceStatus::kEnd;
    delivered_ = true;
    frame->bgr = image_;
    frame->timestamp = std::chrono::nanoseconds(0);
    return SourceStatus::kFrame;
  }
  bool is_live() const override { return false; }
  std::string describe() const override {
    return "image '" + path_ + "' " + std::to_string(image_.cols) + "x" + std::to_string(image_.rows);
  }

 private:
  std::string path_;
  cv::Mat image_;
  bool delivered_ = false;
};

class VideoFileSource : public FrameSource {
 public:
  explicit VideoFileSource(const MediaSourceOptions& options) : options_(options) {
    try {
      // Files are decoded by FFmpeg only: CAP_ANY would also probe GStreamer and camera
      // back-ends for a bad path, slowly and with their own leaks.
      if (!capture_.open(options.path, cv::CAP_FFMPEG) || !capture_.isOpened())
        throw Error("cannot open input '" + options.path + "': not a video or image that OpenCV/ffmpeg can read");
      double fps = capture_.get(cv::CAP_PROP_FPS);
      fps_ = (std::isfinite(fps) && fps >= 1 && fps <= 240) ? fps : options.fallback_fps;
      // Read the first frame now, so a file that opens but decodes nothing fails at start-up.
      if (!capture_.read(first_) || first_.empty())
        throw Error("input '" + options.path + "' holds no decodable video frame");
    } catch (const cv::Exception& e) {
      throw Error("cannot read input '" + options.path + "': " + e.what());
    }
    width_ = first_.cols;
    height_ = first_.rows;
  }

  SourceStatus next(SourceFrame* frame, std::string* error) override {
    cv::Mat image;
    if (!first_.empty()) {
      image = std::move(first_);
      first_.release();
    } else {
      try {
        if (!capture_.read(image) || image.empty()) {
          if (!options_.loop) return SourceStatus::kEnd;
          if (frames_in_pass_ == 0) {
            if (error) *error = "input '" + options_.path + "' stopped delivering frames";
            return SourceStatus::kError;
          }
          // Rewind by reopening: seeking is unreliable for some containers (wmv, streams).
          capture_.release();
          if (!capture_.open(options_.path, cv::CAP_FFMPEG) || !capture_.read(image) || image.empty()) {
            if (error) *error = "input '" + options_.path + "' could not be read again for looping";
            return SourceStatus::kError;
          }
          frames_in_pass_ = 0;
        }
      } catch (const cv::Exception& e) {
        if (error) *error = "decoding '" + options_.path + "' failed: " + e.what();
        return SourceStatus::kError;
      }
    }
    ++frames_in_pass_;
    frame->bgr = std::move(image);
    frame->timestamp = frame_time(index_++, fps_);
    return SourceStatus::kFrame;
  }

  bool is_live() const override { return false; }
  std::string describe() const override {
    char fps[32];
    std::snprintf(fps, sizeof fps, "%.2f", fps_);
    return "video '" + options_.path + "' " + std::to_string(width_) + "x" + std::to_string(height_) + " @ " +
           fps + " fps" + (options_.loop ? ", looping" : "");
  }

 private:
  MediaSourceOptions options_;
  cv::VideoCapture capture_;
  cv::Mat first_;
  double fps_ = 30;
  int width_ = 0, height_ = 0;
  int64_t index_ = 0;
  int64_t frames_in_pass_ = 0;
};

class TestPatternSource : public FrameSource {
 public:
  TestPatternSource(int width, int height, double fps) : fps_(fps) {
    if (width <= 0 || height <= 0) throw Error("test pattern: size must be positive");
    if (!(fps > 0)) throw Error("test pattern: frame rate must be positive");
    base_ = cv::Mat(height, width, CV_8UC3, cv::Scalar(0, 0, 0));
    bars_height_ = std::max(1, height * 3 / 4);
    for (int i = 0; i < kTestPatternBars; ++i) {
      int x0 = i * width / kTestPatternBars, x1 = (i + 1) * width / kTestPatternBars;
      const unsigned char* c = kTestPatternBarBgr[i];
      base_(cv::Rect(x0, 0, x1 - x0, bars_height_)).setTo(cv::Scalar(c[0], c[1], c[2]));
    }
    if (bars_height_ < height)
      base_(cv::Rect(0, bars_height_, width, height - bars_height_)).setTo(cv::Scalar(128, 128, 128));
  }

  SourceStatus next(SourceFrame* frame, std::string*) override {
    cv::Mat image = base_.clone();
    const int strip = image.rows - bars_height_;
    if (strip > 0) {
      // The marker crosses the frame in two seconds, so motion shows that frames are live.
      int marker_w = std::max(2, image.cols / 32);
      int steps = std::max(1, static_cast<int>(std::lround(2 * fps_)));
      int x = static_cast<int>((index_ % steps) * (image.cols - marker_w) / steps);
      image(cv::Rect(x, bars_height_, marker_w, strip)).setTo(cv::Scalar(255, 255, 255));
    }
    frame->bgr = std::move(image);
    frame->timestamp = frame_time(index_++, fps_);
    return SourceStatus::kFrame;
  }
  bool is_live() const override { return false; }
  std::string describe() const override {
    return "test pattern " + std::to_string(base_.cols) + "x" + std::to_string(base_.rows);
  }

 private:
  double fps_;
  cv::Mat base_;
  int bars_height_ = 0;
  int64_t index_ = 0;
};

}  // namespace

bool is_still_image(const std::string& path) {
  try {
    return cv::haveImageReader(path);
  } catch (const cv::Exception&) {
    return false;
  }
}

std::unique_ptr<FrameSource> open_media_source(const MediaSourceOptions& options) {
  std::error_code ec;
  if (options.path.empty()) throw Error("no input file given");
  if (!std::filesystem::exists(options.path, ec)) throw Error("input '" + options.path + "' does not exist");
  if (std::filesystem::is_directory(options.path, ec))
    throw Error("input '" + options.path + "' is a directory, not a video or image");
  if (is_still_image(options.path)) {
    cv::Mat image;
    try {
      image = cv::imread(options.path, cv::IMREAD_COLOR);
    } catch (const cv::Exception& e) {
      throw Error("cannot read image '" + options.path + "': " + e.what());
    }
    if (image.empty()) throw Error("cannot read image '" + options.path + "' (damaged or unsupported)");
    return std::make_unique<StillImageSource>(options.path, std::move(image));
  }
  return std::make_unique<VideoFileSource>(options);
}

std::unique_ptr<FrameSource> make_test_pattern_source(int width, int height, double fps) {
  return std::make_unique<TestPatternSource>(width, height, fps);
}

}  // namespace face_reenact::output
