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

 private:
  friend std::shared_ptr<const ShapeModel> load_shape_model(const std::string& path);
  ShapeModel() = default;
  struct Predictor;
  std::unique_ptr<Predictor> predictor_;
  Shape68 mean_shape_{};
  std::string path_;
};

// Loads the model or returns the copy already in memory; throws face_reenact::Error with the
// path for a missing, unreadable or wrong model file.
std::shared_ptr<const ShapeModel> load_shape_model(const std::string& path);

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
