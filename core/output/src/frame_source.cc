#include "face_reenact/output/frame_source.h"

#include <cmath>
#include <filesystem>

#include "face_reenact/capture/media_file.h"
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
  explicit VideoFileSource(const MediaSourceOptions& options)
      : options_(options), video_(options.path, {.fallback_fps = options.fallback_fps}) {}

  SourceStatus next(SourceFrame* frame, std::string* error) override {
    cv::Mat image;
    try {
      if (!video_.read(&image)) {
        if (!options_.loop) return SourceStatus::kEnd;
        try {
          video_.rewind();
        } catch (const Error& e) {
          if (error) *error = "input '" + options_.path + "' could not be read again for looping: " + e.what();
          return SourceStatus::kError;
        }
        video_.read(&image);  // the first frame, which rewind() has decoded already
      }
    } catch (const Error& e) {
      if (error) *error = e.what();
      return SourceStatus::kError;
    }
    frame->bgr = std::move(image);
    frame->timestamp = frame_time(index_++, video_.fps());
    return SourceStatus::kFrame;
  }

  bool is_live() const override { return false; }
  std::string describe() const override {
    char fps[32];
    std::snprintf(fps, sizeof fps, "%.2f", video_.fps());
    return "video '" + options_.path + "' " + std::to_string(video_.width()) + "x" + std::to_string(video_.height()) +
           " @ " + fps + " fps" + (options_.loop ? ", looping" : "");
  }

 private:
  MediaSourceOptions options_;
  capture::VideoFileReader video_;
  int64_t index_ = 0;  // frames delivered over all passes: timestamps keep increasing when looping
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

std::unique_ptr<FrameSource> open_media_source(const MediaSourceOptions& options) {
  std::error_code ec;
  if (options.path.empty()) throw Error("no input file given");
  if (!std::filesystem::exists(options.path, ec)) throw Error("input '" + options.path + "' does not exist");
  if (std::filesystem::is_directory(options.path, ec))
    throw Error("input '" + options.path + "' is a directory, not a video or image");
  if (capture::is_still_image(options.path))
    return std::make_unique<StillImageSource>(options.path, capture::read_still_image(options.path));
  return std::make_unique<VideoFileSource>(options);
}

std::unique_ptr<FrameSource> make_test_pattern_source(int width, int height, double fps) {
  return std::make_unique<TestPatternSource>(width, height, fps);
}

}  // namespace face_reenact::output
