#include "face_reenact/landmarks/landmark_detector.h"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>

#include "dlib_backend.h"
#include "face_reenact/common/error.h"
#include "face_reenact/common/parallel.h"
#include "landmark_internal.h"

namespace face_reenact::landmarks {

// ---------------------------------------------------------------- small value types

int bytes_per_pixel(PixelFormat format) {
  switch (format) {
    case PixelFormat::kGray8: return 1;
    case PixelFormat::kBGR8:
    case PixelFormat::kRGB8: return 3;
    case PixelFormat::kBGRA8: return 4;
  }
  return 1;
}

const char* pixel_format_name(PixelFormat format) {
  switch (format) {
    case PixelFormat::kGray8: return "gray8";
    case PixelFormat::kBGR8: return "bgr8";
    case PixelFormat::kRGB8: return "rgb8";
    case PixelFormat::kBGRA8: return "bgra8";
  }
  return "unknown";
}

bool ImageView::IsValid(std::string* error) const {
  auto fail = [&](const std::string& m) {
    if (error) *error = m;
    return false;
  };
  const int bpp = bytes_per_pixel(format);
  if (bpp != 1 && bpp != 3 && bpp != 4) return fail("unknown pixel format");
  if (data == nullptr) return fail("image has no pixel data");
  if (width <= 0 || height <= 0) {
    return fail("image size " + std::to_string(width) + "x" + std::to_string(height) + " is empty");
  }
  if (width > 32768 || height > 32768) return fail("image larger than 32768 px on a side");
  if (stride_bytes != 0 && stride_bytes < size_t(width) * size_t(bpp)) {
    return fail("row stride " + std::to_string(stride_bytes) + " is shorter than a row of " +
                std::to_string(width) + " " + pixel_format_name(format) + " pixels");
  }
  return true;
}

Image to_gray_image(const ImageView& view) {
  Image out;
  if (!view.IsValid(nullptr)) return out;
  const cv::Mat gray = internal::to_gray(view);
  out.width = gray.cols;
  out.height = gray.rows;
  out.format = PixelFormat::kGray8;
  out.pixels.resize(size_t(gray.cols) * size_t(gray.rows));
  for (int y = 0; y < gray.rows; ++y) {
    std::memcpy(out.pixels.data() + size_t(y) * size_t(gray.cols), gray.ptr(y), size_t(gray.cols));
  }
  return out;
}

float Box::iou(const Box& o) const {
  const float ix = std::max(0.f, std::min(x + width, o.x + o.width) - std::max(x, o.x));
  const float iy = std::max(0.f, std::min(y + height, o.y + o.height) - std::max(y, o.y));
  const float inter = ix * iy;
  const float uni = area() + o.area() - inter;
  return uni > 0 ? inter / uni : 0.f;
}

float Box::fraction_outside(int w, int h) const {
  if (area() <= 0) return 1.f;
  const float ix = std::max(0.f, std::min(x + width, float(w)) - std::max(x, 0.f));
  const float iy = std::max(0.f, std::min(y + height, float(h)) - std::max(y, 0.f));
  return 1.f - (ix * iy) / area();
}

const char* status_name(DetectionStatus s) {
  switch (s) {
    case DetectionStatus::kOk: return "ok";
    case DetectionStatus::kNoFace: return "no_face";
    case DetectionStatus::kFaceTooSmall: return "face_too_small";
    case DetectionStatus::kBlurred: return "blurred";
    case DetectionStatus::kPartiallyOutside: return "partially_outside";
    case DetectionStatus::kInvalidInput: return "invalid_input";
  }
  return "unknown";
}

const char* source_name(LandmarkSource s) {
  switch (s) {
    case LandmarkSource::kNone: return "none";
    case LandmarkSource::kDetected: return "detected";
    case LandmarkSource::kTracked: return "tracked";
  }
  return "unknown";
}

float outer_eye_distance(const Shape68& p) { return (p[36] - p[45]).norm(); }

bool DetectorOptions::IsValid(std::string* error) const {
  auto fail = [&](const std::string& m) {
    if (error) *error = "landmark detector options: " + m;
    return false;
  };
  if (detection_width != 0 && detection_width < 80) return fail("detection_width must be 0 or >= 80");
  if (max_upsample < 0 || max_upsample > 3) return fail("max_upsample must be in [0, 3]");
  if (max_search_pixels < 80 * 80) return fail("max_search_pixels too small");
  if (!std::isfinite(detector_threshold) || std::abs(detector_threshold) > 10) {
    return fail("detector_threshold must be in [-10, 10]");
  }
  if (min_face_size < 1) return fail("min_face_size must be >= 1");
  if (confidence_samples < 1 || confidence_samples > internal::kMaxSamples) {
    return fail("confidence_samples must be in [1, " + std::to_string(internal::kMaxSamples) + "]");
  }
  if (!(jitter_fraction > 0.f && jitter_fraction <= 0.25f)) return fail("jitter_fraction must be in (0, 0.25]");
  if (!(confidence_sigma > 0.f)) return fail("confidence_sigma must be > 0");
  if (!(min_sharpness >= 0.f)) return fail("min_sharpness must be >= 0");
  if (!(max_outside_fraction >= 0.f && max_outside_fraction <= 1.f)) {
    return fail("max_outside_fraction must be in [0, 1]");
  }
  if (!(max_shape_residual > 0.f)) return fail("max_shape_residual must be > 0");
  if (!(prune_start_deg >= 0.f && prune_full_deg > prune_start_deg && prune_full_deg <= 90.f)) {
    return fail("need 0 <= prune_start_deg < prune_full_deg <= 90");
  }
  return true;
}

// ---------------------------------------------------------------- internal helpers

namespace internal {

std::string default_shape_predictor_path() {
  if (const char* env = std::getenv("FACE_REENACT_SHAPE_PREDICTOR"); env != nullptr && *env != '\0') {
    return env;
  }
  return "/usr/share/dlib/shape_predictor_68_face_landmarks.dat";
}

cv::Mat to_gray(const ImageView& image) {
  const int bpp = bytes_per_pixel(image.format);
  const int type = bpp == 1 ? CV_8UC1 : (bpp == 3 ? CV_8UC3 : CV_8UC4);
  const cv::Mat src(image.height, image.width, type, const_cast<uint8_t*>(image.data),  // NOLINT: read only
                    image.row_bytes());
  if (image.format == PixelFormat::kGray8) return src;  // zero-copy view
  cv::Mat gray;
  switch (image.format) {
    case PixelFormat::kBGR8: cv::cvtColor(src, gray, cv::COLOR_BGR2GRAY); break;
    case PixelFormat::kRGB8: cv::cvtColor(src, gray, cv::COLOR_RGB2GRAY); break;
    case PixelFormat::kBGRA8: cv::cvtColor(src, gray, cv::COLOR_BGRA2GRAY); break;
    case PixelFormat::kGray8: break;
  }
  return gray;
}

float shape_residual(const Shape68& mean_unit, const Shape68& points) {
  // 2D similarity Procrustes: centre both, closed-form scale*rotation.
  Eigen::Vector2f ca = Eigen::Vector2f::Zero(), cb = Eigen::Vector2f::Zero();
  for (int i = 0; i < kNumLandmarks; ++i) {
    ca += mean_unit[i];
    cb += points[i];
  }
  ca /= float(kNumLandmarks);
  cb /= float(kNumLandmarks);
  double saa = 0, sdot = 0, scross = 0;
  for (int i = 0; i < kNumLandmarks; ++i) {
    const Eigen::Vector2f a = mean_unit[i] - ca, b = points[i] - cb;
    saa += a.squaredNorm();
    sdot += a.dot(b);
    scross += a.x() * b.y() - a.y() * b.x();
  }
  if (saa <= 0) return 1e3f;
  const double c = sdot / saa, s = scross / saa;  // scale*cos, scale*sin
  double sum = 0;
  for (int i = 0; i < kNumLandmarks; ++i) {
    const Eigen::Vector2f a = mean_unit[i] - ca, b = points[i] - cb;
    const double rx = c * a.x() - s * a.y() - b.x();
    const double ry = s * a.x() + c * a.y() - b.y();
    sum += rx * rx + ry * ry;
  }
  // Normalise by the inter-ocular distance of the aligned mean (robust to a collapsed target).
  const double scale = std::sqrt(c * c + s * s);
  const double iod = scale * (mean_unit[36] - mean_unit[45]).norm();
  if (!(iod > 1e-3)) return 1e3f;
  return float(std::sqrt(sum / kNumLandmarks) / iod);
}

float sharpness(const cv::Mat& gray, const Box& box) {
  const cv::Rect full(0, 0, gray.cols, gray.rows);
  const cv::Rect r = cv::Rect(int(std::floor(box.x)), int(std::floor(box.y)), int(std::ceil(box.width)),
                              int(std::ceil(box.height))) & full;
  if (r.width < 4 || r.height < 4) return 0.f;
  // Normalised 64x64 crop: the measure is independent of face size and exposure.
  cv::Mat crop;
  cv::resize(gray(r), crop, cv::Size(64, 64), 0, 0, r.width >= 64 ? cv::INTER_AREA : cv::INTER_LINEAR);
  cv::Mat lap;
  cv::Laplacian(crop, lap, CV_32F, 1);
  cv::Scalar mean, stddev;
  cv::meanStdDev(crop, mean, stddev);
  const double mean_abs_lap = cv::mean(cv::abs(lap))[0];
  return float(mean_abs_lap / (stddev[0] + 4.0));
}

// Jittered start boxes: (dx, dy, dscale) in units of jitter_fraction; sample 0 is the box.
static constexpr int kJitter[kMaxSamples][3] = {{0, 0, 0},  {1, 1, 1},   {-1, -1, -1},
                                                {1, -1, -1}, {-1, 1, 1}, {1, 1, -1},
                                                {-1, -1, 1}, {1, -1, 1}, {-1, 1, -1}};

Box jittered_box(const Box& box, int sample, float jitter) {
  const float size = std::max(box.width, box.height);
  const float scale = 1.f + jitter * float(kJitter[sample][2]);
  Box b;
  b.width = box.width * scale;
  b.height = box.height * scale;
  const Eigen::Vector2f c = box.center() + jitter * size * Eigen::Vector2f(float(kJitter[sample][0]), float(kJitter[sample][1]));
  b.x = c.x() - 0.5f * b.width;
  b.y = c.y() - 0.5f * b.height;
  return b;
}

}  // namespace internal

// ---------------------------------------------------------------- detector

// Overlap above which a detection is taken to be the face we follow.
constexpr float kMinFollowIou = 0.2f;

struct LandmarkDetector::Impl {
  DetectorOptions options;
  std::shared_ptr<const detail::ShapeModel> model;
  detail::HogFaceDetector hog;

  // Searches gray scaled by `scale` (< 1 shrinks, > 1 enlarges) and maps boxes back.
  std::vector<FaceCandidate> search_scaled(const cv::Mat& gray, double scale) {
    cv::Mat scaled;
    if (std::abs(scale - 1.0) < 1e-6) {
      scaled = gray;
    } else {
      const cv::Size size(std::max(1, int(std::lround(gray.cols * scale))),
                          std::max(1, int(std::lround(gray.rows * scale))));
      cv::resize(gray, scaled, size, 0, 0, scale < 1 ? cv::INTER_AREA : cv::INTER_LINEAR);
    }
    std::vector<FaceCandidate> faces = hog.Detect(scaled, options.detector_threshold);
    const float inv_x = float(gray.cols) / float(scaled.cols), inv_y = float(gray.rows) / float(scaled.rows);
    for (auto& f : faces) {
      f.box.x *= inv_x;
      f.box.y *= inv_y;
      f.box.width *= inv_x;
      f.box.height *= inv_y;
    }
    return faces;
  }

  // Searches scale after scale and stops at the first that finds a face (overlapping `wanted`
  // when given: a tracked or annotated face is worth a harder search than "any face").
  std::vector<FaceCandidate> find_faces(const cv::Mat& gray, bool harder, std::string* how,
                                        const std::optional<Box>& wanted = std::nullopt) {
    std::vector<double> scales;
    if (options.detection_width > 0 && gray.cols > options.detection_width) {
      scales.push_back(double(options.detection_width) / gray.cols);
      if (harder) scales.push_back(1.0);
    } else {
      scales.push_back(1.0);
    }
    if (harder) {
      double s = 1.0;
      for (int i = 0; i < options.max_upsample; ++i) {
        s *= 2.0;
        if (double(gray.cols) * gray.rows * s * s > double(options.max_search_pixels)) break;
        scales.push_back(s);
      }
    }
    std::vector<FaceCandidate> first_found;
    std::string tried;
    for (double s : scales) {
      std::vector<FaceCandidate> faces = search_scaled(gray, s);
      if (!tried.empty()) tried += ", ";
      tried += std::to_string(std::lround(gray.cols * s)) + " px";
      if (faces.empty()) continue;
      if (!wanted) {
        first_found = std::move(faces);
        break;
      }
      const bool overlaps = std::any_of(faces.begin(), faces.end(),
                                        [&](const FaceCandidate& f) { return f.box.iou(*wanted) > kMinFollowIou; });
      if (overlaps) {
        first_found = std::move(faces);
        break;
      }
      if (first_found.empty()) first_found = std::move(faces);
    }
    if (how) *how = "searched at " + tried + " wide";
    return first_found;
  }

  LandmarkResult fit(const cv::Mat& gray, const Box& box, int samples) {
    LandmarkResult r;
    // Boxes come from callers and from previous frames: reject what dlib's integer rectangles
    // cannot hold instead of overflowing.
    const float limit = 4.f * float(std::max(gray.cols, gray.rows)) + 1e4f;
    if (!std::isfinite(box.x) || !std::isfinite(box.y) || !std::isfinite(box.width) || !std::isfinite(box.height) ||
        !(box.width > 1.f && box.height > 1.f) || box.width > limit || box.height > limit ||
        std::abs(box.x) > limit || std::abs(box.y) > limit) {
      r.status = DetectionStatus::kNoFace;
      r.reason = "start box is empty or far outside the image";
      return r;
    }
    if (samples <= 0) samples = options.confidence_samples;
    samples = std::clamp(samples, 1, internal::kMaxSamples);
    std::array<Shape68, internal::kMaxSamples> runs;
    // The jittered runs are independent (dlib's predictor may be used from several threads at
    // once): on the pool's threads, each into its own slot, so the mean is the same for any count.
    // On the live worker the second core was otherwise idle for these 3.5 ms.
    ParallelFor(samples, ResolvedThreadCount(0), [&](int k) {
      model->Predict(gray, internal::jittered_box(box, k, options.jitter_fraction), &runs[size_t(k)]);
    });
    Shape68 mean;
    for (int i = 0; i < kNumLandmarks; ++i) {
      Eigen::Vector2f m = Eigen::Vector2f::Zero();
      for (int k = 0; k < samples; ++k) m += runs[size_t(k)][i];
      mean[i] = m / float(samples);
    }
    float iod = outer_eye_distance(mean);
    if (!(iod > 1.f)) iod = std::max(1.f, 0.4f * box.width);
    r.points = mean;
    r.face_box = box;
    r.has_landmarks = true;
    r.shape_residual = internal::shape_residual(model->mean_shape(), mean);
    const float sigma = options.confidence_sigma * iod;
    for (int i = 0; i < kNumLandmarks; ++i) {
      float conf = 1.f;
      if (samples > 1) {
        double spread2 = 0;
        for (int k = 0; k < samples; ++k) spread2 += (runs[size_t(k)][i] - mean[i]).squaredNorm();
        spread2 /= samples;
        conf = float(std::exp(-0.5 * spread2 / (double(sigma) * sigma)));
      }
      const Eigen::Vector2f& p = mean[i];
      const bool inside = p.x() >= 0 && p.y() >= 0 && p.x() <= gray.cols - 1 && p.y() <= gray.rows - 1;
      r.visible[size_t(i)] = inside;
      r.confidence[size_t(i)] = inside ? conf : 0.f;
    }
    // An implausible shape lowers every point: the predictor always returns 68 points, even on
    // a wall, and only their arrangement tells.
    // Real faces sit at 0.05-0.12 (expressions, moderate yaw): full weight up to half the
    // limit, 0.5 at the limit, 0 at 1.5 times it.
    const float plausibility =
        std::clamp((1.5f * options.max_shape_residual - r.shape_residual) / options.max_shape_residual, 0.f, 1.f);
    float sum = 0;
    for (float c : r.confidence) sum += c;
    r.score = (sum / kNumLandmarks) * plausibility;
    classify(gray, &r);
    return r;
  }

  void classify(const cv::Mat& gray, LandmarkResult* r) const {
    const Box& box = r->face_box;
    const float outside = box.fraction_outside(gray.cols, gray.rows);
    char buf[160];
    if (box.width < float(options.min_face_size)) {
      r->status = DetectionStatus::kFaceTooSmall;
      std::snprintf(buf, sizeof(buf), "face is %.0f px wide, below the minimum of %d px", double(box.width),
                    options.min_face_size);
      r->reason = buf;
      return;
    }
    if (outside > options.max_outside_fraction) {
      r->status = DetectionStatus::kPartiallyOutside;
      std::snprintf(buf, sizeof(buf), "%.0f%% of the face box is outside the frame", 100.0 * outside);
      r->reason = buf;
      return;
    }
    const float sharp = internal::sharpness(gray, box);
    if (sharp < options.min_sharpness) {
      r->status = DetectionStatus::kBlurred;
      std::snprintf(buf, sizeof(buf), "face is blurred (sharpness %.3f < %.3f)", double(sharp),
                    double(options.min_sharpness));
      r->reason = buf;
      return;
    }
    r->status = DetectionStatus::kOk;
    r->reason = "ok";
  }
};

void PreloadShapeModel(const DetectorOptions& options) {
  std::string error;
  if (!options.IsValid(&error)) return;  // the detector's constructor says why
  detail::preload_shape_model(options.shape_predictor_path.empty() ? internal::default_shape_predictor_path()
                                                                   : options.shape_predictor_path);
}

LandmarkDetector::LandmarkDetector(const DetectorOptions& options) {
  std::string error;
  if (!options.IsValid(&error)) throw Error(error);
  impl_ = std::make_unique<Impl>();
  impl_->options = options;
  const std::string path =
      options.shape_predictor_path.empty() ? internal::default_shape_predictor_path() : options.shape_predictor_path;
  impl_->model = detail::load_shape_model(path);
}

LandmarkDetector::~LandmarkDetector() = default;
LandmarkDetector::LandmarkDetector(LandmarkDetector&&) noexcept = default;
LandmarkDetector& LandmarkDetector::operator=(LandmarkDetector&&) noexcept = default;

const DetectorOptions& LandmarkDetector::options() const { return impl_->options; }
const Shape68& LandmarkDetector::mean_shape() const { return impl_->model->mean_shape(); }

Box LandmarkDetector::BoxFromPoints(const Shape68& points) const {
  // Least-squares scale + translation (no rotation: detector boxes are axis-aligned) of the
  // mean shape onto the points, over the rigid part of the face (brows, nose, eyes), so an
  // open mouth does not move the box.
  const Shape68& m = impl_->model->mean_shape();
  Eigen::Vector2f cm = Eigen::Vector2f::Zero(), cp = Eigen::Vector2f::Zero();
  int n = 0;
  for (int i = 17; i <= 47; ++i, ++n) {
    cm += m[i];
    cp += points[i];
  }
  cm /= float(n);
  cp /= float(n);
  double num = 0, den = 0;
  for (int i = 17; i <= 47; ++i) {
    num += (m[i] - cm).dot(points[i] - cp);
    den += (m[i] - cm).squaredNorm();
  }
  const float s = den > 0 ? float(std::max(1.0, num / den)) : 1.f;
  const Eigen::Vector2f t = cp - s * cm;
  // dlib maps the unit square to [left, right] where right = left + width - 1.
  return Box{t.x(), t.y(), s + 1.f, s + 1.f};
}

std::vector<FaceCandidate> LandmarkDetector::FindFaces(const ImageView& image, bool harder,
                                                       const std::optional<Box>& wanted) {
  if (!image.IsValid(nullptr)) return {};
  return impl_->find_faces(internal::to_gray(image), harder, nullptr, wanted);
}

std::vector<FaceCandidate> LandmarkDetector::FindFacesInRegion(const ImageView& image, const Box& region,
                                                               float expected_face_width) {
  if (!image.IsValid(nullptr)) return {};
  const cv::Mat gray = internal::to_gray(image);
  const cv::Rect r = cv::Rect(int(std::floor(region.x)), int(std::floor(region.y)), int(std::ceil(region.width)),
                              int(std::ceil(region.height))) & cv::Rect(0, 0, gray.cols, gray.rows);
  if (r.width <= 0 || r.height <= 0) return {};
  // About 100 px for the face: above HOG's 80 px window with some margin, and cheap.
  double scale = expected_face_width > 0 ? 100.0 / expected_face_width : 1.0;
  scale = std::clamp(scale, 0.1, 2.0);
  std::vector<FaceCandidate> faces = impl_->search_scaled(gray(r), scale);
  for (auto& f : faces) {
    f.box.x += float(r.x);
    f.box.y += float(r.y);
  }
  return faces;
}

LandmarkResult LandmarkDetector::FitFromBox(const ImageView& image, const Box& box, int samples) {
  LandmarkResult r;
  std::string error;
  if (!image.IsValid(&error)) {
    r.status = DetectionStatus::kInvalidInput;
    r.reason = error;
    return r;
  }
  r = impl_->fit(internal::to_gray(image), box, samples);
  if (r.has_landmarks) r.source = LandmarkSource::kTracked;
  return r;
}

LandmarkResult LandmarkDetector::Detect(const ImageView& image, const TrackingHint& hint) {
  LandmarkResult r;
  std::string error;
  if (!image.IsValid(&error)) {
    r.status = DetectionStatus::kInvalidInput;
    r.reason = error;
    return r;
  }
  const cv::Mat gray = internal::to_gray(image);
  const DetectorOptions& o = impl_->options;
  if (gray.cols < o.min_face_size || gray.rows < o.min_face_size) {
    r.status = DetectionStatus::kFaceTooSmall;
    r.reason = "image " + std::to_string(gray.cols) + "x" + std::to_string(gray.rows) +
               " is smaller than the smallest usable face (" + std::to_string(o.min_face_size) + " px)";
    return r;
  }
  if (hint.previous_points) {
    const Box start = BoxFromPoints(*hint.previous_points);
    if (start.fraction_outside(gray.cols, gray.rows) < 0.5f) {
      LandmarkResult tracked = impl_->fit(gray, start, 0);
      if (tracked.shape_residual <= o.max_shape_residual) {
        tracked.source = LandmarkSource::kTracked;
        if (hint.pose) apply_pose_pruning(*hint.pose, o, &tracked);
        return tracked;
      }
    }
  }
  std::string how;
  const std::vector<FaceCandidate> faces = impl_->find_faces(gray, /*harder=*/true, &how, hint.previous_box);
  if (faces.empty()) {
    r.status = DetectionStatus::kNoFace;
    r.reason = "no face found (" + how + ")";
    return r;
  }
  // Follow the tracked face when there is one, else take the largest.
  size_t best = 0;
  float best_iou = 0.f;
  if (hint.previous_box) {
    for (size_t i = 0; i < faces.size(); ++i) {
      const float iou = faces[i].box.iou(*hint.previous_box);
      if (iou > best_iou) {
        best_iou = iou;
        best = i;
      }
    }
  }
  if (best_iou < kMinFollowIou) {
    best = 0;
    for (size_t i = 1; i < faces.size(); ++i) {
      if (faces[i].box.area() > faces[best].box.area()) best = i;
    }
  }
  r = impl_->fit(gray, faces[best].box, 0);
  r.source = LandmarkSource::kDetected;
  r.detector_score = faces[best].score;
  r.faces_found = int(faces.size());
  if (hint.pose) apply_pose_pruning(*hint.pose, o, &r);
  return r;
}

// ---------------------------------------------------------------- pose pruning

int apply_pose_pruning(const HeadPose& pose, const DetectorOptions& options, LandmarkResult* result) {
  if (result == nullptr || !result->has_landmarks || !std::isfinite(pose.yaw_deg)) return 0;
  const float yaw = std::abs(pose.yaw_deg);
  if (yaw <= options.prune_start_deg) return 0;
  const float weight =
      std::clamp(1.f - (yaw - options.prune_start_deg) / (options.prune_full_deg - options.prune_start_deg), 0.f, 1.f);
  // Which iBUG half lies toward +x in this image (mirrored cameras swap them).
  float left_x = 0, right_x = 0;
  int nl = 0, nr = 0;
  for (int i = 0; i < kNumLandmarks; ++i) {
    const int side = internal::face_side(i);
    if (side > 0) {
      left_x += result->points[size_t(i)].x();
      ++nl;
    } else if (side < 0) {
      right_x += result->points[size_t(i)].x();
      ++nr;
    }
  }
  const bool subject_left_at_plus_x = left_x / float(nl) > right_x / float(nr);
  // yaw > 0 turns the +x half away from the camera.
  const int far_side = (pose.yaw_deg > 0) == subject_left_at_plus_x ? +1 : -1;
  int hidden = 0;
  for (int i = 0; i < kNumLandmarks; ++i) {
    if (internal::face_side(i) != far_side) continue;
    result->confidence[size_t(i)] *= weight;
    if (yaw >= options.prune_full_deg && result->visible[size_t(i)]) {
      result->visible[size_t(i)] = false;
      ++hidden;
    }
  }
  return hidden;
}

}  // namespace face_reenact::landmarks
