#pragma once
// Where the virtual webcam's pictures come from. The reenactment pipeline implements this
// interface (a live source); so do a video file or still image (read by core/capture) and a test
// pattern, which exist for testing a set-up and for users who want to pipe a clip through.
#include <chrono>
#include <memory>
#include <opencv2/core/mat.hpp>
#include <string>

namespace face_reenact::output {

struct SourceFrame {
  cv::Mat bgr;                          // 8-bit BGR (grey or BGRA are accepted and converted)
  std::chrono::nanoseconds timestamp{}; // presentation time from the start of the source
};

enum class SourceStatus {
  kFrame,  // *frame holds the next picture
  kEnd,    // no more frames (end of a clip without looping, a still image already delivered)
  kError,  // the source failed; *error says why
};

class FrameSource {
 public:
  virtual ~FrameSource() = default;

  // Blocks until the next frame is available (a live source waits for its producer; a file
  // source decodes the next frame). Never throws: failures are kError with a message.
  virtual SourceStatus next(SourceFrame* frame, std::string* error) = 0;

  // A live source's frames are due the moment next() returns them; a recorded source's frames
  // are due at their timestamps, so the streamer holds each one back until then.
  virtual bool is_live() const = 0;

  // What it is, for status lines ("video 'talk.mp4' 640x480 @ 25 fps, looping").
  virtual std::string describe() const = 0;
};

struct MediaSourceOptions {
  std::string path;   // a video (anything OpenCV/ffmpeg reads) or an image (png, jpg, ...)
  bool loop = false;  // start a clip again at its end (timestamps keep increasing)
  // Used when the container does not say its frame rate (or says something absurd).
  double fallback_fps = 30;
};

// Opens a video (capture::VideoFileReader) or, when capture::is_still_image says so, an image
// (capture::read_still_image). Throws face_reenact::Error when the file is missing,
// unreadable, or holds no decodable frame. A still image yields one frame, then kEnd.
std::unique_ptr<FrameSource> open_media_source(const MediaSourceOptions& options);

// Colour bars (white, yellow, cyan, green, magenta, red, blue, black; 100% intensity) over the
// top 3/4 and a grey strip with a white marker that moves one step per frame at the bottom, so
// a viewer sees at a glance that frames are live and the colours are right. Frames at `rate`.
std::unique_ptr<FrameSource> make_test_pattern_source(int width, int height, double fps);

// The BGR colours of the bars, left to right (tests check received frames against them).
inline constexpr int kTestPatternBars = 8;
extern const unsigned char kTestPatternBarBgr[kTestPatternBars][3];

}  // namespace face_reenact::output
