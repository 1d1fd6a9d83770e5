#include "face_reenact/landmarks/frame_source.h"

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <mutex>

#include "face_reenact/common/error.h"

namespace face_reenact::landmarks {
namespace {

std::string lower_extension(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return ext;
}

Image from_mat(const cv::Mat& mat) {
  Image image;
  cv::Mat bgr;
  if (mat.channels() == 1) {
    cv::cvtColor(mat, bgr, cv::COLOR_GRAY2BGR);
  } else if (mat.channels() == 4) {
    cv::cvtColor(mat, bgr, cv::COLOR_BGRA2BGR);
  } else {
    bgr = mat;
  }
  if (bgr.depth() != CV_8U) bgr.convertTo(bgr, CV_8U);
  if (!bgr.isContinuous()) bgr = bgr.clone();
  image.width = bgr.cols;
  image.height = bgr.rows;
  image.format = PixelFormat::kBGR8;
  image.pixels.assign(bgr.data, bgr.data + size_t(bgr.cols) * size_t(bgr.rows) * 3);
  return image;
}

std::mutex& registry_mutex() {
  static std::mutex m;
  return m;
}
std::map<std::string, FrameSourceOpener>& registry() {
  static std::map<std::string, FrameSourceOpener> r;
  return r;
}

class StillImageSource : public FrameSource {
 public:
  explicit StillImageSource(const std::string& path) : path_(path), image_(load_image(path)) {}
  bool Next(Frame* frame) override {
    if (done_) return false;
    done_ = true;
    frame->image = std::move(image_);
    frame->index = 0;
    frame->timestamp_s = 0;
    return true;
  }
  std::string Describe() const override { return "image '" + path_ + "'"; }
  int64_t frame_count_hint() const override { return 1; }
  bool is_still_image() const override { return true; }

 private:
  std::string path_;
  Image image_;
  bool done_ = false;
};

class VideoFileSource : public FrameSource {
 public:
  explicit VideoFileSource(const std::string& path) : path_(path) {
    if (!capture_.open(path, cv::CAP_FFMPEG) || !capture_.isOpened()) {
      throw Error("video '" + path + "': cannot be opened (unknown container/codec or not a video)");
    }
    fps_ = capture_.get(cv::CAP_PROP_FPS);
    if (!(fps_ > 0 && fps_ < 1000)) fps_ = 30.0;
    const double count = capture_.get(cv::CAP_PROP_FRAME_COUNT);
    count_ = count > 0 && count < 1e9 ? int64_t(count) : -1;
  }
  bool Next(Frame* frame) override {
    cv::Mat mat;
    try {
      if (!capture_.read(mat) || mat.empty()) return false;
    } catch (const cv::Exception&) {
      return false;  // a damaged tail ends the video instead of the program
    }
    frame->image = from_mat(mat);
    frame->index = index_;
    frame->timestamp_s = double(index_) / fps_;
    ++index_;
    return true;
  }
  std::string Describe() const override { return "video '" + path_ + "'"; }
  double fps() const override { return fps_; }
  int64_t frame_count_hint() const override { return count_; }

 private:
  std::string path_;
  cv::VideoCapture capture_;
  double fps_ = 30;
  int64_t count_ = -1;
  int64_t index_ = 0;
};

}  // namespace

bool has_still_image_extension(const std::string& path) {
  static const char* const kExtensions[] = {".png", ".jpg", ".jpeg", ".ppm", ".pgm", ".pnm",
                                            ".bmp", ".tif", ".tiff", ".webp"};
  const std::string ext = lower_extension(path);
  return std::any_of(std::begin(kExtensions), std::end(kExtensions), [&](const char* e) { return ext == e; });
}

void register_frame_source(const std::string& extension, FrameSourceOpener opener) {
  std::lock_guard<std::mutex> lock(registry_mutex());
  registry()[extension] = std::move(opener);
}

std::unique_ptr<FrameSource> open_frame_source(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) throw Error("input '" + path + "': no such file");
  if (std::filesystem::is_directory(path, ec)) throw Error("input '" + path + "': is a folder, expected an image or a video");
  FrameSourceOpener opener;
  {
    std::lock_guard<std::mutex> lock(registry_mutex());
    if (auto it = registry().find(lower_extension(path)); it != registry().end()) opener = it->second;
  }
  if (opener) return opener(path);
  if (has_still_image_extension(path)) return std::make_unique<StillImageSource>(path);
  return std::make_unique<VideoFileSource>(path);
}

Image load_image(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) throw Error("image '" + path + "': no such file");
  cv::Mat mat;
  try {
    mat = cv::imread(path, cv::IMREAD_COLOR);
  } catch (const cv::Exception& e) {
    throw Error("image '" + path + "': cannot be decoded (" + std::string(e.what()).substr(0, 200) + ")");
  }
  if (mat.empty()) throw Error("image '" + path + "': cannot be decoded (corrupt or unsupported format)");
  return from_mat(mat);
}

void save_png(const std::string& path, const ImageView& image) {
  std::string error;
  if (!image.IsValid(&error)) throw Error("PNG '" + path + "': " + error);
  const int bpp = bytes_per_pixel(image.format);
  const cv::Mat src(image.height, image.width, bpp == 1 ? CV_8UC1 : (bpp == 3 ? CV_8UC3 : CV_8UC4),
                    const_cast<uint8_t*>(image.data), image.row_bytes());  // NOLINT: read only
  cv::Mat out = src;
  if (image.format == PixelFormat::kRGB8) cv::cvtColor(src, out, cv::COLOR_RGB2BGR);
  bool ok = false;
  try {
    ok = cv::imwrite(path, out);
  } catch (const cv::Exception&) {
    ok = false;
  }
  if (!ok) throw Error("PNG '" + path + "': cannot be written");
}

}  // namespace face_reenact::landmarks
