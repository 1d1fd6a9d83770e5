#pragma once
// Where frames come from: a still image, a video file, and later the project's RGB-D
// recordings. The landmark command reads through this interface only, so a new container is
// one FrameSource subclass plus register_frame_source() for its file extension.
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "face_reenact/landmarks/image.h"

namespace face_reenact::landmarks {

struct Frame {
  Image image;             // BGR8 (or what the source delivers)
  int64_t index = 0;       // 0-based position in the source
  double timestamp_s = 0;  // presentation time; index / fps when the container has none
};

class FrameSource {
 public:
  virtual ~FrameSource() = default;
  // Fills the next frame; false at the end (or when the rest of the file is unreadable).
  virtual bool Next(Frame* frame) = 0;
  virtual std::string Describe() const = 0;
  virtual double fps() const { return 0; }
  // Frames in the source if the container says so, else -1.
  virtual int64_t frame_count_hint() const { return -1; }
  virtual bool is_still_image() const { return false; }
};

using FrameSourceOpener = std::function<std::unique_ptr<FrameSource>(const std::string& path)>;

// Registers an opener for files ending in `extension` (lower case, with the dot: ".frec").
void register_frame_source(const std::string& extension, FrameSourceOpener opener);
// Opens `path`: registered extensions first, then still images (capture::is_still_image: png,
// jpg, ... by name or content), then anything the video decoder accepts
// (capture::VideoFileReader). Throws face_reenact::Error with the path when the file is missing
// or cannot be decoded.
std::unique_ptr<FrameSource> open_frame_source(const std::string& path);

// Decodes a still image as BGR8 (capture::read_still_image); throws face_reenact::Error.
Image load_image(const std::string& path);
// Writes a PNG (grey, BGR or BGRA; RGB is converted); throws face_reenact::Error.
void save_png(const std::string& path, const ImageView& image);

}  // namespace face_reenact::landmarks
