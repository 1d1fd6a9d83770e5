#pragma once
// Files the commands write (reenact, demo, track --overlay): the checks before any work, one video
// writer and its codec choice, and the video-or-PNG-folder output.
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "face_reenact/common/error.h"

namespace face_reenact::cli {

// A file a command will write: its folder must exist and the path must not be a folder (checked
// before any work, so a typo costs nothing).
inline void check_output_file(const std::string& path, const char* what) {
  namespace fs = std::filesystem;
  const fs::path p = fs::path(path).lexically_normal();
  const fs::path parent = p.has_parent_path() ? p.parent_path() : fs::path(".");
  std::error_code ec;
  if (!fs::is_directory(parent, ec))
    throw face_reenact::Error(std::string(what) + " '" + path + "': folder '" + parent.string() + "' does not exist");
  if (fs::is_directory(p, ec)) throw face_reenact::Error(std::string(what) + " '" + path + "' is a folder");
}

// Writes an mp4 (H.264 by libx264, else FFmpeg's MPEG-4 part 2) through FFmpeg's own libraries:
// OpenCV's writer opens x264 at its "medium" preset with no say over it, and that encoder took
// a sixth of `reenact`'s CPU on two cores; "veryfast" at CRF 21 keeps the picture (PSNR against
// the frames as medium's CRF 23 does) for 15-20 % more bytes (docs/reenactment.md).
class Mp4Writer {
 public:
  Mp4Writer(const std::string& path, double fps, cv::Size size);
  ~Mp4Writer();
  Mp4Writer(const Mp4Writer&) = delete;
  Mp4Writer& operator=(const Mp4Writer&) = delete;
  // A BGR frame of the size given at construction.
  void write(const cv::Mat& bgr);
  // Flushes the encoder and finishes the file (also done, errors swallowed, on destruction).
  void close();
  // What encodes the video, for the reports: "h264 (libx264 veryfast, crf 21)" or "mpeg4".
  const std::string& codec() const { return codec_; }

 private:
  struct Impl;
  std::string path_, codec_;
  std::unique_ptr<Impl> impl_;
};

// An output named by the user as `OUT.mp4` (one video) or a folder (one PNG per frame,
// frame_NNNNNN.png by the frame's index): `track --overlay`.
class FrameOutput {
 public:
  FrameOutput(const std::string& path, double fps, cv::Size size) : path_(path) {
    std::error_code ec;
    if (std::filesystem::path(path).extension() == ".mp4") {
      video_ = std::make_unique<Mp4Writer>(path, fps, size);
    } else {
      std::filesystem::create_directories(path, ec);
      if (ec || !std::filesystem::is_directory(path))
        throw face_reenact::Error("cannot create the folder '" + path + "' (give a folder or a file ending in .mp4)");
    }
  }
  void write(const cv::Mat& bgr, int64_t index) {
    if (video_) {
      video_->write(bgr);
      return;
    }
    char name[32];
    std::snprintf(name, sizeof name, "frame_%06lld.png", static_cast<long long>(index));
    const std::string file = (std::filesystem::path(path_) / name).string();
    if (!cv::imwrite(file, bgr)) throw face_reenact::Error("cannot write '" + file + "' (disk full?)");
  }
  void close() {
    if (video_) video_->close();
  }

 private:
  std::string path_;
  std::unique_ptr<Mp4Writer> video_;
};

}  // namespace face_reenact::cli
