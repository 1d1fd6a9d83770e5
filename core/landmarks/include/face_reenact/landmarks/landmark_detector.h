#pragma once
// 68-point facial landmarks (iBUG 300-W order) for the tracker's feature term E_lan
// (Thies et al. 2015, Sec. 5.3): a still-image detector and a video tracker, both with a
// per-point confidence and visibility so the energy can weight or prune each feature.
//
// The detector is dlib's HOG face detector plus its ensemble-of-regression-trees shape
// predictor; dlib stays behind this interface (only src/dlib_backend.cc includes it).
#include <Eigen/Core>
#include <array>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "face_reenact/landmarks/image.h"

namespace face_reenact::landmarks {

constexpr int kNumLandmarks = 68;
using Shape68 = std::array<Eigen::Vector2f, kNumLandmarks>;

// Axis-aligned box in pixel coordinates of the input image (x, y = top-left corner).
struct Box {
  float x = 0, y = 0, width = 0, height = 0;

  Eigen::Vector2f center() const { return {x + 0.5f * width, y + 0.5f * height}; }
  float area() const { return width > 0 && height > 0 ? width * height : 0.f; }
  // Intersection over union; 0 when either box is empty.
  float iou(const Box& other) const;
  // Fraction of this box's area that lies outside [0,w) x [0,h).
  float fraction_outside(int image_width, int image_height) const;
};

// Head rotation from the tracker, degrees. Convention (image terms, so it holds for mirrored
// cameras too): yaw > 0 turns the nose toward +x in the image, so the half of the face at
// larger x turns away from the camera; pitch > 0 tilts the chin down; roll > 0 rotates the
// face clockwise in the image.
struct HeadPose {
  float yaw_deg = 0, pitch_deg = 0, roll_deg = 0;
};

enum class DetectionStatus {
  kOk,                // landmarks usable
  kNoFace,            // no face found (landmarks empty)
  kFaceTooSmall,      // face (or whole image) smaller than Options::min_face_size
  kBlurred,           // face found but too little image detail for reliable points
  kPartiallyOutside,  // face box reaches out of the frame; outside points are marked invisible
  kInvalidInput,      // null/empty image, bad stride
};
const char* status_name(DetectionStatus status);

// How the landmarks of a result were obtained.
enum class LandmarkSource { kNone, kDetected, kTracked };
const char* source_name(LandmarkSource source);

struct LandmarkResult {
  DetectionStatus status = DetectionStatus::kNoFace;
  std::string reason;                 // human-readable, e.g. "no face found (searched at 320 px ...)"
  LandmarkSource source = LandmarkSource::kNone;
  bool has_landmarks = false;         // true whenever points/confidence below are filled
  Box face_box;                       // the box the shape predictor started from
  Shape68 points{};                   // pixel coordinates, iBUG order, 0-based
  std::array<float, kNumLandmarks> confidence{};  // in [0,1]; see docs/landmarks.md
  std::array<bool, kNumLandmarks> visible{};      // false: outside the frame or pose-pruned
  float score = 0;                    // overall quality in [0,1]
  float detector_score = 0;           // dlib HOG score when detected this call (0 otherwise)
  float shape_residual = 0;           // RMS distance to the mean shape after similarity alignment,
                                      // in inter-ocular units (implausible shapes are large)
  int faces_found = 0;                // faces the detector saw in this call (0 when tracked)
  // The tracker left the face it followed for a more prominent one elsewhere in the frame
  // (TrackerOptions::prominent_face_*): another person, whose identity must be learned anew.
  bool switched_face = false;

  bool ok() const { return status == DetectionStatus::kOk; }
};

// Jawline points (0-16) lie on the face silhouette: their 3D correspondence slides along the
// contour with pose, so the tracker must treat them differently from fixed features.
constexpr bool is_silhouette_point(int index) { return index >= 0 && index <= 16; }

// Which half of the face an iBUG point belongs to: +1 the subject's left (larger x in an
// unmirrored frontal image), -1 the subject's right, 0 the midline.
constexpr int face_side(int i) {
  if (i <= 7) return -1;
  if (i == 8) return 0;
  if (i <= 16) return +1;
  if (i <= 21) return -1;
  if (i <= 26) return +1;
  if (i <= 30) return 0;
  if (i <= 32) return -1;
  if (i == 33) return 0;
  if (i <= 35) return +1;
  if (i <= 41) return -1;
  if (i <= 47) return +1;
  if (i <= 50) return -1;
  if (i == 51) return 0;
  if (i <= 56) return +1;
  if (i == 57) return 0;
  if (i <= 61) return -1;
  if (i == 62) return 0;
  if (i <= 65) return +1;
  if (i == 66) return 0;
  return -1;  // 67
}

// Optional information from the previous frame / the tracker.
struct TrackingHint {
  std::optional<Box> previous_box;        // prefer the face overlapping this box
  std::optional<Shape68> previous_points; // start the predictor from these (re-centred)
  std::optional<HeadPose> pose;           // prune far-side points under large rotation
};

struct DetectorOptions {
  // The dlib 68-point model; empty: $FACE_REENACT_SHAPE_PREDICTOR, then
  // /usr/share/dlib/shape_predictor_68_face_landmarks.dat.
  std::string shape_predictor_path;
  // The HOG search runs on a copy scaled to this width (0: full resolution) and is mapped back.
  int detection_width = 320;
  // Still images: when the scaled search finds nothing, search again at full resolution and
  // then upsampled 2x, up to this many times (0 disables), while the image stays under
  // max_search_pixels.
  int max_upsample = 1;
  int max_search_pixels = 4000 * 3000;
  // dlib's adjust_threshold (lower finds more faces and more false positives).
  double detector_threshold = 0.0;
  // Faces whose box is narrower than this (pixels) get kFaceTooSmall.
  int min_face_size = 40;
  // Shape-predictor runs from jittered start boxes; their mean is the output and their spread
  // the confidence. 1 disables the ensemble (confidence from evidence only).
  int confidence_samples = 5;
  float jitter_fraction = 0.05f;       // box shift/scale of the jittered starts
  float confidence_sigma = 0.03f;      // spread (inter-ocular units) where confidence = e^-0.5
  // Sharpness (mean |Laplacian| / contrast on the normalised face crop) below which a face is
  // kBlurred.
  float min_sharpness = 0.06f;
  // Box fraction outside the frame above which the status is kPartiallyOutside.
  float max_outside_fraction = 0.2f;
  // Shapes farther than this from the mean shape (inter-ocular units) count as implausible.
  float max_shape_residual = 0.2f;
  // Pose pruning: far-side points lose weight from prune_start_deg of |yaw| and are invisible
  // beyond prune_full_deg (the paper prunes features under rotations > 30 degrees).
  float prune_start_deg = 15.f;
  float prune_full_deg = 30.f;

  bool IsValid(std::string* error) const;
};

struct FaceCandidate {
  Box box;
  float score = 0;
};

// Starts reading the shape predictor a LandmarkDetector with `options` loads, on a thread of its
// own ("fr-shape-load"), and returns at once. The read takes 0.1-0.2 s (67 MB of tables, a start's
// largest single wait); a caller with other set-up to do first (the tracker, the compositor) does
// it meanwhile, and the detector made next takes the model, waiting for the read if it still runs.
// A read that fails throws there, as it would have without this. Does nothing for a model in
// memory or being read already.
void PreloadShapeModel(const DetectorOptions& options = {});

// One instance per thread (the HOG scanner keeps state); instances share the loaded model.
class LandmarkDetector {
 public:
  // Loads (or shares an already loaded) shape predictor; throws face_reenact::Error for bad
  // options or a missing/corrupt model file.
  explicit LandmarkDetector(const DetectorOptions& options = {});
  ~LandmarkDetector();
  LandmarkDetector(LandmarkDetector&&) noexcept;
  LandmarkDetector& operator=(LandmarkDetector&&) noexcept;

  // Landmarks of one face. With hint.previous_points the predictor starts from those (no
  // search) and a full search only happens when that fit is implausible; otherwise the whole
  // image is searched (scaled, then harder) and the face overlapping hint.previous_box, else
  // the largest, is taken. Never throws for image content; kInvalidInput for bad views.
  LandmarkResult Detect(const ImageView& image, const TrackingHint& hint = {});

  // All faces found by the HOG search. `harder`: retry at full resolution / upsampled.
  // With `wanted`, the search goes on to harder scales until a face overlapping it turns up
  // (the faces of the first scale that found any are returned otherwise).
  std::vector<FaceCandidate> FindFaces(const ImageView& image, bool harder,
                                       const std::optional<Box>& wanted = std::nullopt);
  // Searches only inside `region` (e.g. a band around the tracked box), scaled so that a face
  // of `expected_face_width` is about 100 px wide.
  std::vector<FaceCandidate> FindFacesInRegion(const ImageView& image, const Box& region,
                                               float expected_face_width);
  // Fits the landmarks starting from `box` (detector convention), with `samples` jittered
  // runs (0: options().confidence_samples).
  LandmarkResult FitFromBox(const ImageView& image, const Box& box, int samples = 0);
  // The start box whose mean shape best explains `points` (used to re-centre on a track).
  Box BoxFromPoints(const Shape68& points) const;

  const DetectorOptions& options() const;
  // The predictor's mean shape in unit-box coordinates ([0,1]^2 maps to the start box).
  const Shape68& mean_shape() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Down-weights / hides the points on the far side of the face under large yaw. The far side
// is found from the points themselves (which iBUG half lies toward +x), so mirrored images
// work. Midline points keep their weight. Returns the number of points made invisible.
int apply_pose_pruning(const HeadPose& pose, const DetectorOptions& options, LandmarkResult* result);

// Inter-ocular distance used for normalisation: outer eye corners 36 and 45.
float outer_eye_distance(const Shape68& points);

}  // namespace face_reenact::landmarks
