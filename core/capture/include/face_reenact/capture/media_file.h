#pragma once
// Ordinary media files as 8-bit BGR frames: video files (mp4, avi, wmv, ... anything OpenCV's
// FFmpeg back-end decodes) frame by frame, and still images. The one place that opens, decodes
// and normalises such files: the RGB-only recordings (VideoReader, and with them the live
// session's video inputs), the landmark tool's inputs and the virtual webcam's media sources
// all read through it. Recordings and the live camera share its pixel normalisation, to_bgr8.
//
// Frames are BGR, OpenCV's own channel order, because every consumer (capture::RgbdFrame,
// landmarks::Image, output::SourceFrame) holds BGR: decoding to RGB would only be undone.
#include <cstdint>
#include <memory>
#include <string>
#include <utility>

#include <opencv2/core.hpp>

namespace face_reenact::capture {

// A container's frame rate outside [kMinPlausibleFps, kMaxPlausibleFps] is taken as unknown:
// containers with a millisecond time base report 1000, broken headers 0 or NaN, and no camera a
// user records with delivers less than one or more than 240 frames per second.
inline constexpr double kMinPlausibleFps = 1;
inline constexpr double kMaxPlausibleFps = 240;

// Brings a decoded 8-bit image to 3-channel BGR in place: grey is expanded, an alpha channel
// dropped, BGR kept as it is. False (the image untouched) when it is not 8-bit or has another
// channel count.
bool to_bgr8(cv::Mat* image);

// Reads a video file front to back. Not thread-safe; one reader per thread.
class VideoFileReader {
 public:
  struct Options {
    // The frame rate fps() reports when the container says none or an implausible one.
    double fallback_fps = 30;
  };

  // Opens `path` and decodes its first frame, so a file that opens but holds nothing
  // decodable fails here instead of looking like an empty video. Throws face_reenact::Error
  // naming the path when it is missing, a folder or another non-regular file, not a video
  // FFmpeg can open, without a decodable frame, or of an invalid frame size.
  VideoFileReader(std::string path, const Options& options);
  explicit VideoFileReader(std::string path) : VideoFileReader(std::move(path), Options()) {}
  ~VideoFileReader();
  VideoFileReader(VideoFileReader&&) noexcept;
  VideoFileReader& operator=(VideoFileReader&&) noexcept;

  const std::string& path() const { return path_; }
  // The first frame's size (later frames normally have it too; the reader does not enforce it).
  int width() const { return width_; }
  int height() const { return height_; }
  // The container's frame rate when plausible, else Options::fallback_fps.
  double fps() const { return fps_; }
  // The container's frame count, an estimate for some formats; -1 when it says none.
  int64_t frame_count() const { return frame_count_; }
  // Frames read() has delivered since opening or the last rewind(): the next frame's index.
  int64_t frames_read() const { return frames_read_; }

  // The next frame as 8-bit BGR (grey and BGRA frames converted). *bgr's buffer is written
  // into when it fits, so pass a cv::Mat that shares its pixels with nothing else. False at
  // the end of the file: the decoder has no further frame, which for a truncated file is where
  // its data stops. Throws face_reenact::Error naming the path and frame when the decoder
  // fails or delivers a frame that is not 8-bit grey, BGR or BGRA.
  bool read(cv::Mat* bgr);

  // Starts again at the first frame: reopens the file rather than seeking, because seeking is
  // unreliable in some containers (wmv, streams), and decodes the first frame again, so the
  // next read() delivers it. Throws face_reenact::Error like the constructor; after that read()
  // delivers nothing more.
  void rewind();

 private:
  void open();  // (re)opens and decodes the first frame; on failure leaves nothing to read

  struct Decoder;  // cv::VideoCapture: keeps opencv2/videoio.hpp out of this header
  std::unique_ptr<Decoder> decoder_;
  std::string path_;
  Options options_;
  cv::Mat first_;  // decoded by open(), handed out by the next read()
  int width_ = 0, height_ = 0;
  double fps_ = 30;
  int64_t frame_count_ = -1;
  int64_t frames_read_ = 0;
};

// True when `path` ends in a still-image extension (png, jpg, jpeg, ppm, pgm, pnm, bmp, tif,
// tiff, webp; any case). Looks at the name only.
bool has_still_image_extension(const std::string& path);

// True when `path` is to be read as a still image rather than a video: its name has a
// still-image extension (so a damaged photo is reported as a damaged image) or its content is
// an image format OpenCV decodes (so a picture without the usual extension works too).
bool is_still_image(const std::string& path);

// Decodes a still image as 8-bit BGR (grey expanded, alpha dropped, 16-bit scaled down).
// Throws face_reenact::Error naming the path when it is missing or cannot be decoded.
cv::Mat read_still_image(const std::string& path);

}  // namespace face_reenact::capture
