#pragma once
// Accuracy and stability measurements on real data: NME on 68-point annotated photos
// (.pts files, 300-W convention) and jitter / per-frame cost on videos. Used by the
// `face-reenact landmarks --eval/--video-report` command and by the tests.
#include <array>
#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "face_reenact/landmarks/landmark_detector.h"
#include "face_reenact/landmarks/landmark_tracker.h"

namespace face_reenact::landmarks {

// Reads a 68-point .pts file (`version: 1`, `n_points: 68`, `{`, 68 "x y" lines, `}`) and
// converts the 1-based coordinates to 0-based. Throws face_reenact::Error with path and line.
Shape68 read_pts(const std::string& path);
Shape68 parse_pts(const std::string& text, const std::string& what);

// Mean point error normalised by the outer-eye-corner distance (points 36, 45) of `truth`.
float nme_outer_eye(const Shape68& predicted, const Shape68& truth);
// The same over the points with `use[i]` (e.g. the ground-truth-visible ones); the
// normalisation still uses points 36 and 45 of `truth`. Infinity when no point is used.
float nme_outer_eye(const Shape68& predicted, const Shape68& truth, const std::array<bool, kNumLandmarks>& use);

nlohmann::json to_json(const LandmarkResult& result);

struct EvalImage {
  std::string path;
  int64_t index = -1;         // frame number when evaluating a recording
  DetectionStatus status = DetectionStatus::kNoFace;
  std::string reason;
  bool has_landmarks = false;
  float nme = 0;              // valid when has_landmarks
  float mean_confidence = 0;
  int faces_found = 0;
  double milliseconds = 0;
};

struct EvalReport {
  std::string folder;         // the annotated folder or the recording
  std::string unit = "image"; // what per_image holds: "image" (photos) or "frame" (a recording)
  int images = 0;
  int no_face = 0;            // images without landmarks
  int failures = 0;           // images with landmarks and NME > 0.1
  double mean_nme = 0;        // over images with landmarks
  double median_nme = 0;
  // Per-point errors (inter-ocular units) pooled over all images, split at the median
  // confidence: how well the confidence predicts the error.
  double point_error_high_confidence = 0;
  double point_error_low_confidence = 0;
  double confidence_error_correlation = 0;  // Spearman rank correlation (negative is good)
  std::vector<EvalImage> per_image;

  nlohmann::json ToJson() const;
};

// The images with a sibling .pts file under `folder` (recursive), sorted; the .pts path of each
// is the image's with the extension replaced. Throws face_reenact::Error when the folder is
// missing or holds no annotated image.
std::vector<std::string> list_annotated_images(const std::string& folder);
std::string annotation_path(const std::string& image_path);
// The 300-W protocol's choice among a photo's faces: the detection overlapping the annotated
// face (its points' bounding box). The annotation only picks among the detector's boxes; the
// landmarks are never started from it.
TrackingHint annotated_face_hint(const Shape68& truth);

// Every image with a sibling .pts file under `folder` (recursive). As in 300-W, where a photo
// shows several faces the detection overlapping the annotated face is scored (the annotation
// only chooses among detector boxes). Throws face_reenact::Error
// when the folder is missing or holds no annotated image.
EvalReport evaluate_annotated_folder(const std::string& folder, LandmarkDetector* detector);

// Builds an EvalReport from scored images/frames, so every evaluation (annotated photos,
// recordings with ground truth) shares one NME, failure and confidence statistic.
class EvalAccumulator {
 public:
  explicit EvalAccumulator(std::string folder, std::string unit = "image");
  // Adds one image/frame; `result` is scored against `truth` over the points with use[i]
  // (nullptr: all 68). `entry` carries path, timing; status and NME are filled in here.
  void Add(EvalImage entry, const LandmarkResult& result, const Shape68& truth,
           const std::array<bool, kNumLandmarks>* use = nullptr);
  // Adds an image/frame that could not be read (counts as no_face).
  void AddUnreadable(EvalImage entry);
  EvalReport Finish() const;

 private:
  EvalReport report_;
  std::vector<double> nmes_, point_conf_, point_err_;
};

struct VideoModeReport {
  std::string mode;
  int frames = 0;
  int frames_with_landmarks = 0;
  // Mean frame-to-frame displacement of the stable points (eye corners, nose), inter-ocular
  // units: raw, and after removing the head's similarity motion between the two frames.
  double jitter_raw = 0;
  double jitter_motion_compensated = 0;
  double ms_mean = 0, ms_p95 = 0, ms_max = 0;  // Track() per frame (wall clock), decode excluded
  // The same in CPU time of the calling thread: what a frame costs when the machine is busy
  // with other work (wall time then includes waiting for a core).
  double cpu_ms_mean = 0, cpu_ms_p95 = 0;
  TrackerSummary summary;
  // Box of the followed face per frame (x, y, w, h; w = 0 when none).
  std::vector<Box> boxes;
};

struct VideoReport {
  std::string path;
  int width = 0, height = 0;
  double fps = 0;
  std::vector<VideoModeReport> modes;

  nlohmann::json ToJson(bool include_boxes = false) const;
};

// Runs the tracker over the video in one mode. `max_frames` <= 0: all frames.
VideoModeReport run_video_mode(const std::string& path, const TrackerOptions& options, const std::string& mode,
                               int max_frames, int* width = nullptr, int* height = nullptr, double* fps = nullptr);
// tracking, tracking + One-Euro smoothing, detection on every frame.
VideoReport video_report(const std::string& path, const TrackerOptions& base, int max_frames);

// Jitter of a landmark sequence (entries without landmarks break the chain).
void measure_jitter(const std::vector<LandmarkResult>& sequence, double* raw, double* motion_compensated);

}  // namespace face_reenact::landmarks
