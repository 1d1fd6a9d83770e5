#pragma once
// RGB-D recordings on disk (docs/recording-format.md is the spec): a folder with one 8-bit
// colour PNG and one 16-bit depth PNG (millimetres, 0 = no data) per frame, recording.json
// (camera, frame rate, provenance) and frames.jsonl (one JSON object per frame: timestamp,
// file names and, for synthetic data, the ground-truth parameters P and 68 landmarks).
// The same format holds real recordings (no ground truth). Ordinary video files (mp4, avi,
// wmv, ...) open as RGB-only recordings through VideoFileReader (media_file.h).
#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "face_reenact/gpu/image_formation.h"

namespace face_reenact::capture {

inline constexpr int kNumLandmarks = 68;
inline constexpr const char* kRecordingFormatName = "face-reenact-rgbd";
inline constexpr int kRecordingFormatVersion = 1;

struct LandmarkObservation {
  Eigen::Vector2f pixel = Eigen::Vector2f::Zero();  // (u, v), pixel centres at integers
  bool visible = false;  // not occluded (by the head itself or anything else) and inside the image
};

struct GroundTruth {
  std::optional<gpu::FaceParameters> params;  // P of the face model (image_formation.h conventions)
  std::optional<std::array<LandmarkObservation, kNumLandmarks>> landmarks;  // iBUG 68 order
};

struct RgbdFrame {
  int index = 0;             // 0-based frame number in the recording
  double timestamp_s = 0;    // seconds since the first frame
  cv::Mat color;             // CV_8UC3, BGR
  cv::Mat depth;             // CV_32FC1, metres, registered to colour; 0 or NaN = no data; empty = RGB only
  gpu::PinholeCamera camera; // intrinsics of colour and depth (registered)
  GroundTruth ground_truth;  // empty for real recordings
};

// Recording-wide metadata (recording.json).
struct RecordingInfo {
  gpu::PinholeCamera camera;
  double fps = 30;
  double depth_scale = 0.001;  // metres per depth PNG unit
  bool has_depth = true;
  std::string source;          // free text: "synthetic", "kinect", the video file...
  std::string generator;       // free text: the program and options that made it
  int frame_count = 0;         // frames in the recording (-1: unknown, e.g. a live video stream)

  bool IsValid(std::string* why) const;
};

class VideoFileReader;  // media_file.h

// Something that yields frames in order: a recording folder, a video file.
class FrameSource {
 public:
  virtual ~FrameSource() = default;
  virtual const RecordingInfo& info() const = 0;
  // Fills *frame with the next frame; false at the end. Throws face_reenact::Error on bad data.
  virtual bool read_next(RgbdFrame* frame) = 0;
};

// One frame shown for a while: a still photo as a target held for the length of a performance
// (`reenact --target photo.jpg`). Yields `frames` copies of `frame` at `fps`, its index and
// timestamp counting up from 0 as a video's would. Throws face_reenact::Error when frames < 1,
// fps is not in (0, 1000] or the frame has no colour.
class HeldFrameSource : public FrameSource {
 public:
  HeldFrameSource(RgbdFrame frame, RecordingInfo info, int frames, double fps);
  const RecordingInfo& info() const override { return info_; }
  bool read_next(RgbdFrame* frame) override;

 private:
  RgbdFrame frame_;
  RecordingInfo info_;
  int next_ = 0;
};

// Writes a recording folder. Frames go into "<dir>.partial-<pid>" next to `dir`; finish()
// writes recording.json (last) and renames the folder to `dir`, so a folder named `dir` always
// holds a complete recording. Without finish() (an exception, a crash) the partial folder is
// removed by the destructor when possible and never looks complete.
class RecordingWriter {
 public:
  struct Options {
    bool overwrite = false;      // replace an existing `dir` (only once the new one is complete)
    int png_compression = 1;     // zlib level 0-9 for the PNGs (1: fast, still lossless)
    bool IsValid(std::string* why) const;
  };

  // Throws face_reenact::Error when `dir` exists (and !overwrite), its parent is missing or not
  // writable, or `info` is invalid.
  RecordingWriter(const std::string& dir, const RecordingInfo& info, const Options& options);
  RecordingWriter(const std::string& dir, const RecordingInfo& info) : RecordingWriter(dir, info, Options()) {}
  ~RecordingWriter();
  RecordingWriter(const RecordingWriter&) = delete;
  RecordingWriter& operator=(const RecordingWriter&) = delete;

  // Appends a frame (its index must be the number of frames written so far). Colour must be
  // CV_8UC3 of the camera's size; depth CV_32FC1 of the same size (metres) unless the recording
  // has no depth. Depth beyond 65535 units, negative or NaN is written as 0 (no data).
  void write(const RgbdFrame& frame);
  // Completes the recording; returns the final folder.
  std::string finish();
  int frames_written() const { return static_cast<int>(frame_lines_.size()); }
  const std::string& partial_dir() const { return partial_dir_; }

 private:
  std::string dir_, partial_dir_;
  RecordingInfo info_;
  Options options_;
  std::vector<std::string> frame_lines_;
  bool finished_ = false;
};

// Reads a recording folder. The constructor validates recording.json and every line of
// frames.jsonl and checks that every referenced file exists; read() validates each PNG (type,
// size, decodability). All errors name the file (and frame) at fault.
class RecordingReader : public FrameSource {
 public:
  explicit RecordingReader(const std::string& dir);
  const RecordingInfo& info() const override { return info_; }
  int frame_count() const { return static_cast<int>(frames_.size()); }
  RgbdFrame read(int index) const;
  bool read_next(RgbdFrame* frame) override;
  const std::string& dir() const { return dir_; }

 private:
  struct FrameEntry {
    double timestamp_s = 0;
    std::string color_file, depth_file;
    GroundTruth ground_truth;
  };
  std::string dir_;
  RecordingInfo info_;
  std::vector<FrameEntry> frames_;
  int next_ = 0;
};

// An ordinary video file as an RGB-only recording. Video files carry no intrinsics, so the
// camera is a pinhole with the principal point at the image centre and the horizontal field of
// view `horizontal_fov_deg` (default 60 degrees, typical of webcams), or the given `intrinsics`.
// (The tracker can estimate the focal length from the face: TrackerOptions::focal_length.)
class VideoReader : public FrameSource {
 public:
  struct Intrinsics {
    double fx = 0, fy = 0, cx = 0, cy = 0;  // pixels (OpenCV pixel-centre convention)
  };
  struct Options {
    double horizontal_fov_deg = 60.0;
    std::optional<Intrinsics> intrinsics;  // when set, replaces horizontal_fov_deg
    bool IsValid(std::string* why) const;
  };
  // Throws face_reenact::Error for invalid options and for everything VideoFileReader rejects.
  VideoReader(const std::string& path, const Options& options);
  explicit VideoReader(const std::string& path) : VideoReader(path, Options()) {}
  ~VideoReader() override;
  const RecordingInfo& info() const override { return info_; }
  // Throws face_reenact::Error also when a frame's size differs from the first frame's.
  bool read_next(RgbdFrame* frame) override;

 private:
  std::unique_ptr<VideoFileReader> video_;
  RecordingInfo info_;
  std::string path_;
};

// A camera with the principal point at the image centre and the given horizontal field of view.
gpu::PinholeCamera camera_from_fov(int width, int height, double horizontal_fov_deg);

// Opens a recording folder, or a video file, by what `path` is; a video file with
// `video_options` (its assumed intrinsics).
std::unique_ptr<FrameSource> open_frame_source(const std::string& path,
                                               const VideoReader::Options& video_options = VideoReader::Options());

// JSON helpers shared by the recording, script and identity readers (exposed for tests).
// Ground truth to/from the JSON object stored per frame. `what` names the place in errors.
std::string ground_truth_to_json(const GroundTruth& truth);
GroundTruth ground_truth_from_json(const std::string& json_text, const std::string& what);

}  // namespace face_reenact::capture
