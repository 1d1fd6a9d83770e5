#include "face_reenact/landmarks/frame_source.h"

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <filesystem>
#include <map>
#include <mutex>

#include "face_reenact/capture/media_file.h"
#include "face_reenact/common/error.h"
#include "face_reenact/common/paths.h"

namespace face_reenact::landmarks {
namespace {

// A decoded 8-bit BGR picture (what capture's readers deliver) as an Image.
Image from_bgr8(const cv::Mat& bgr) {
  const cv::Mat packed = bgr.isContinuous() ? bgr : bgr.clone();
  Image image;
  image.width = packed.cols;
  image.height = packed.rows;
  image.format = PixelFormat::kBGR8;
  image.pixels.assign(packed.data, packed.data + size_t(packed.cols) * size_t(packed.rows) * 3);
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
  explicit VideoFileSource(const std::string& path) : video_(path) {}
  bool Next(Frame* frame) override {
    const int64_t index = video_.frames_read();
    cv::Mat bgr;
    try {
      if (!video_.read(&bgr)) return false;
    } catch (const Error&) {
      return false;  // a damaged tail ends the video instead of the program
    }
    frame->image = from_bgr8(bgr);
    frame->index = index;
    frame->timestamp_s = double(index) / video_.fps();
    return true;
  }
  std::string Describe() const override { return "video '" + video_.path() + "'"; }
  double fps() const override { return video_.fps(); }
  int64_t frame_count_hint() const override { return video_.frame_count(); }

 private:
  capture::VideoFileReader video_;
};

}  // namespace

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
    if (auto it = registry().find(lower_case_extension(path)); it != registry().end()) opener = it->second;
  }
  if (opener) return opener(path);
  if (capture::is_still_image(path)) return std::make_unique<StillImageSource>(path);
  return std::make_unique<VideoFileSource>(path);
}

Image load_image(const std::string& path) { return from_bgr8(capture::read_still_image(path)); }

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
