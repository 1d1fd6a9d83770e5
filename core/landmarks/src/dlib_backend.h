#pragma once
// The only bridge to dlib. Nothing here includes dlib, so only dlib_backend.cc pays for its
// heavy headers. Images cross as OpenCV grey matrices (CV_8UC1, any step), wrapped without a
// copy on the dlib side.
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "face_reenact/landmarks/landmark_detector.h"

namespace face_reenact::landmarks::detail {

// How read_shape_model() reads the model.
struct ShapeModelReadOptions {
  // Where the raw copy of the model is kept (read when it is current, written after reading
  // dlib's file); "" for none.
  std::string cache_dir;
  // dlib's own reader end to end, no copy: what the copy is checked against in the tests.
  bool dlib_reader_only = false;
};

// dlib's 68-point shape predictor plus its mean shape. Immutable once loaded, so one instance
// is shared by every detector and thread of the process.
class ShapeModel {
 public:
  ~ShapeModel();
  // Predicts the 68 points starting from `box` (pixel coordinates of `gray`).
  void Predict(const cv::Mat& gray, const Box& box, Shape68* points) const;
  // Mean shape in unit-box coordinates.
  const Shape68& mean_shape() const { return mean_shape_; }
  const std::string& path() const { return path_; }
  // Whether it was read from the cache copy (shape_predictor_cache.h), and where it was not, why
  // (and why no copy was written where that failed); "" when a copy was used.
  bool from_cache() const { return from_cache_; }
  const std::string& cache_note() const { return cache_note_; }

  struct Predictor;  // dlib_backend.cc

 private:
  friend std::shared_ptr<const ShapeModel> read_shape_model(const std::string& path,
                                                            const ShapeModelReadOptions& options);
  ShapeModel() = default;
  std::unique_ptr<Predictor> predictor_;
  Shape68 mean_shape_{};
  std::string path_;
  bool from_cache_ = false;
  std::string cache_note_;
};

// Reads the model from `path`, through the copy in `options.cache_dir` where that copy is of this
// very file (path, size, modification time) and dlib version. Throws face_reenact::Error with the
// path for a missing, unreadable or wrong model file; a bad or stale copy is not an error (the
// model is read from its file and the copy written again).
std::shared_ptr<const ShapeModel> read_shape_model(const std::string& path, const ShapeModelReadOptions& options);

// read_shape_model() with the user's cache folder (user_cache_dir()), once per model path: a
// model already in memory is shared, one preload_shape_model() is reading is waited for.
std::shared_ptr<const ShapeModel> load_shape_model(const std::string& path);
// Starts that read on a thread of its own ("fr-shape-load") and returns; nothing where the model
// is in memory or being read already. The next load_shape_model() of the path takes it.
void preload_shape_model(const std::string& path);
// The model of `path` some detector of this process holds; null where none does (the tests).
std::shared_ptr<const ShapeModel> shape_model_in_memory(const std::string& path);

// dlib's frontal face detector in dlib's serialisation: as embedded at build time
// (tools/embed_face_detector.cc), and as dlib's get_frontal_face_detector() decodes it at run time
// (about 350 ms), for the test that they are the same.
std::string EmbeddedFaceDetectorSerialization();
std::string DecodedFaceDetectorSerialization();

// dlib's HOG frontal face detector (5 view-specific filters, no model file; the one embedded at
// build time, above). Not thread-safe: one per LandmarkDetector.
class HogFaceDetector {
 public:
  HogFaceDetector();
  ~HogFaceDetector();
  // Faces in `gray` with their SVM scores; boxes in `gray`'s pixel coordinates.
  std::vector<FaceCandidate> Detect(const cv::Mat& gray, double adjust_threshold);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace face_reenact::landmarks::detail
