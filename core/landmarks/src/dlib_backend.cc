#include "dlib_backend.h"

#include <dlib/image_processing.h>
#include <dlib/image_processing/frontal_face_detector.h>
#include <dlib/opencv/cv_image.h>

#include <cstddef>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <sstream>
#include <string>

#include "face_reenact/common/error.h"

namespace face_reenact::landmarks::detail {
namespace {

dlib::rectangle to_dlib(const Box& box) {
  const long left = std::lround(box.x);
  const long top = std::lround(box.y);
  const long right = std::lround(box.x + box.width) - 1;
  const long bottom = std::lround(box.y + box.height) - 1;
  return dlib::rectangle(left, top, std::max(left, right), std::max(top, bottom));
}

Box from_dlib(const dlib::rectangle& r) {
  return Box{float(r.left()), float(r.top()), float(r.width()), float(r.height())};
}

// dlib wraps a cv::Mat without copying; cv_image needs a non-const Mat header.
dlib::cv_image<unsigned char> wrap(const cv::Mat& gray) {
  return dlib::cv_image<unsigned char>(const_cast<cv::Mat&>(gray));  // NOLINT: read-only use
}

}  // namespace

struct ShapeModel::Predictor {
  dlib::shape_predictor sp;
};

ShapeModel::~ShapeModel() = default;

void ShapeModel::Predict(const cv::Mat& gray, const Box& box, Shape68* points) const {
  const dlib::full_object_detection det = predictor_->sp(wrap(gray), to_dlib(box));
  for (int i = 0; i < kNumLandmarks; ++i) {
    const dlib::point& p = det.part(static_cast<unsigned long>(i));
    (*points)[i] = Eigen::Vector2f(float(p.x()), float(p.y()));
  }
}

std::shared_ptr<const ShapeModel> load_shape_model(const std::string& path) {
  static std::mutex mutex;
  static std::map<std::string, std::weak_ptr<const ShapeModel>> cache;
  std::error_code ec;
  const std::string key = std::filesystem::weakly_canonical(path, ec).string();
  std::lock_guard<std::mutex> lock(mutex);
  if (auto it = cache.find(key); it != cache.end()) {
    if (auto model = it->second.lock()) return model;
  }
  if (!std::filesystem::is_regular_file(path, ec)) {
    throw Error("shape predictor '" + path +
                "': file not found (install libdlib-data or set FACE_REENACT_SHAPE_PREDICTOR)");
  }
  std::shared_ptr<ShapeModel> model(new ShapeModel());
  model->predictor_ = std::make_unique<ShapeModel::Predictor>();
  model->path_ = path;
  try {
    dlib::deserialize(path) >> model->predictor_->sp;
    // The file starts with a version and the mean shape in unit-box coordinates
    // (dlib's shape_predictor serialisation); read it once more for plausibility checks.
    std::ifstream in(path, std::ios::binary);
    int version = 0;
    dlib::matrix<float, 0, 1> initial_shape;
    dlib::deserialize(version, in);
    dlib::deserialize(initial_shape, in);
    if (model->predictor_->sp.num_parts() != kNumLandmarks || initial_shape.size() != 2 * kNumLandmarks) {
      throw Error("shape predictor '" + path + "': has " +
                  std::to_string(model->predictor_->sp.num_parts()) + " points, expected 68 (iBUG layout)");
    }
    for (int i = 0; i < kNumLandmarks; ++i) {
      model->mean_shape_[i] = Eigen::Vector2f(initial_shape(2 * i), initial_shape(2 * i + 1));
    }
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    throw Error("shape predictor '" + path + "': not a dlib shape predictor (" +
                std::string(e.what()).substr(0, 200) + ")");
  }
  cache[key] = model;
  return model;
}

// Written at build time by fr_embed_face_detector (embedded_face_detector.cc in the build tree).
extern const unsigned char kFrontalFaceDetector[];
extern const std::size_t kFrontalFaceDetectorSize;

std::string EmbeddedFaceDetectorSerialization() {
  return std::string(reinterpret_cast<const char*>(kFrontalFaceDetector), kFrontalFaceDetectorSize);
}

std::string DecodedFaceDetectorSerialization() {
  std::ostringstream out;
  dlib::serialize(dlib::get_frontal_face_detector(), out);
  return out.str();
}

struct HogFaceDetector::Impl {
  // Read once from the serialisation embedded at build time (2 ms; dlib's own decoding of its
  // built-in model took about 350 ms of every process start), and copied for each detector.
  static const dlib::frontal_face_detector& prototype() {
    static const dlib::frontal_face_detector d = [] {
      dlib::frontal_face_detector detector;
      std::istringstream in(EmbeddedFaceDetectorSerialization());
      dlib::deserialize(detector, in);
      return detector;
    }();
    return d;
  }
  dlib::frontal_face_detector detector = prototype();
};

HogFaceDetector::HogFaceDetector() : impl_(std::make_unique<Impl>()) {}
HogFaceDetector::~HogFaceDetector() = default;

std::vector<FaceCandidate> HogFaceDetector::Detect(const cv::Mat& gray, double adjust_threshold) {
  std::vector<FaceCandidate> faces;
  // The HOG scanner needs at least its 80x80 window.
  if (gray.empty() || gray.cols < 80 || gray.rows < 80) return faces;
  std::vector<dlib::rect_detection> detections;
  impl_->detector(wrap(gray), detections, adjust_threshold);
  faces.reserve(detections.size());
  for (const auto& d : detections) {
    faces.push_back(FaceCandidate{from_dlib(d.rect), float(d.detection_confidence)});
  }
  return faces;
}

}  // namespace face_reenact::landmarks::detail
