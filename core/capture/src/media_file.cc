#include "face_reenact/capture/media_file.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <iterator>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "face_reenact/common/paths.h"
#include "face_reenact/common/error.h"

namespace face_reenact::capture {
namespace fs = std::filesystem;

namespace {

// Larger frames are a corrupt header rather than a picture (16K is beyond any camera).
constexpr int kMaxFrameSide = 16384;

// OpenCV's what() spans several lines with its own source location; err is the reason alone.
std::string reason(const cv::Exception& e) { return e.err.empty() ? std::string(e.what()) : e.err; }

}  // namespace

bool to_bgr8(cv::Mat* image) {
  if (image->depth() != CV_8U) return false;
  switch (image->channels()) {
    case 1: cv::cvtColor(*image, *image, cv::COLOR_GRAY2BGR); return true;
    case 3: return true;
    case 4: cv::cvtColor(*image, *image, cv::COLOR_BGRA2BGR); return true;
    default: return false;
  }
}

// --- video files -----------------------------------------------------------------------------

struct VideoFileReader::Decoder {
  cv::VideoCapture capture;
};

VideoFileReader::VideoFileReader(std::string path, const Options& options)
    : decoder_(std::make_unique<Decoder>()), path_(std::move(path)), options_(options) {
  open();
}

VideoFileReader::~VideoFileReader() = default;
VideoFileReader::VideoFileReader(VideoFileReader&&) noexcept = default;
VideoFileReader& VideoFileReader::operator=(VideoFileReader&&) noexcept = default;

void VideoFileReader::open() {
  const std::string what = "video '" + path_ + "'";
  std::error_code ec;
  cv::VideoCapture& capture = decoder_->capture;
  // A reader that failed to (re)open delivers nothing rather than the rest of an old pass.
  capture.release();
  first_.release();
  if (!fs::exists(path_, ec)) throw Error(what + ": no such file");
  if (fs::is_directory(path_, ec)) throw Error(what + ": is a folder, not a video file");
  // A device or pipe would make FFmpeg block or probe a camera.
  if (!fs::is_regular_file(path_, ec)) throw Error(what + ": not a regular file");
  cv::Mat first;
  std::string failure;
  try {
    // Files are decoded by FFmpeg only: CAP_ANY would also probe GStreamer and camera
    // back-ends for a bad path, slowly and with their own leaks.
    if (!capture.open(path_, cv::CAP_FFMPEG) || !capture.isOpened())
      failure = "cannot open (not a video file OpenCV/FFmpeg can decode)";
    else if (!capture.read(first) || first.empty())
      failure = "holds no decodable video frame";
    else if (!to_bgr8(&first))
      failure = "frame 0 is not 8-bit grey, BGR or BGRA";
    else if (first.cols > kMaxFrameSide || first.rows > kMaxFrameSide)
      failure = "invalid frame size " + std::to_string(first.cols) + "x" + std::to_string(first.rows);
  } catch (const cv::Exception& e) {
    failure = "cannot be decoded (" + reason(e) + ")";
  }
  if (!failure.empty()) {
    capture.release();
    throw Error(what + ": " + failure);
  }
  width_ = first.cols;
  height_ = first.rows;
  first_ = std::move(first);
  frames_read_ = 0;

  const double fps = capture.get(cv::CAP_PROP_FPS);
  fps_ = std::isfinite(fps) && fps >= kMinPlausibleFps && fps <= kMaxPlausibleFps ? fps : options_.fallback_fps;
  const double count = capture.get(cv::CAP_PROP_FRAME_COUNT);
  frame_count_ = std::isfinite(count) && count > 0 && count < 1e9 ? static_cast<int64_t>(count) : -1;
}

bool VideoFileReader::read(cv::Mat* bgr) {
  if (!first_.empty()) {
    *bgr = std::move(first_);  // leaves first_ empty
    ++frames_read_;
    return true;
  }
  auto failure = [&](const std::string& why) {
    return Error("video '" + path_ + "': frame " + std::to_string(frames_read_) + " " + why);
  };
  try {
    if (!decoder_->capture.read(*bgr) || bgr->empty()) return false;
  } catch (const cv::Exception& e) {
    throw failure("cannot be decoded (" + reason(e) + ")");
  }
  if (!to_bgr8(bgr)) throw failure("is not 8-bit grey, BGR or BGRA");
  ++frames_read_;
  return true;
}

void VideoFileReader::rewind() { open(); }

// --- still images ----------------------------------------------------------------------------

bool has_still_image_extension(const std::string& path) {
  static const char* const kExtensions[] = {".png", ".jpg", ".jpeg", ".ppm", ".pgm", ".pnm",
                                            ".bmp", ".tif", ".tiff", ".webp"};
  const std::string ext = lower_case_extension(path);
  return std::any_of(std::begin(kExtensions), std::end(kExtensions), [&](const char* e) { return ext == e; });
}

bool is_still_image(const std::string& path) {
  if (has_still_image_extension(path)) return true;
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) return false;  // nothing to sniff (and OpenCV would log it)
  try {
    return cv::haveImageReader(path);  // sniffs the file's first bytes
  } catch (const cv::Exception&) {
    return false;
  }
}

cv::Mat read_still_image(const std::string& path) {
  const std::string what = "image '" + path + "'";
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) throw Error(what + ": no such file");
  cv::Mat image;
  try {
    image = cv::imread(path, cv::IMREAD_COLOR);
  } catch (const cv::Exception& e) {
    throw Error(what + ": cannot be decoded (" + reason(e) + ")");
  }
  if (image.empty()) throw Error(what + ": cannot be decoded (corrupt or unsupported format)");
  return image;
}

}  // namespace face_reenact::capture
