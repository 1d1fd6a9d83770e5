#pragma once
// The mouth interior of paper Sec. 7.4.1: a still image of the target actor's own open mouth
// (teeth, tongue, the dark of the cavity as the camera saw them), taken from one of the target's
// tracked frames, and warped into the opening of every re-rendered frame with generalized
// barycentric coordinates (Floater's mean-value coordinates) over the inner-lip polygon.
// FaceCompositor draws it (docs/reenactment.md, "Mouth"); ReenactmentPipeline chooses the frame.
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

namespace face_reenact::reenact {

// Mean-value coordinates (Floater 2003; Hormann and Floater 2006 for any simple polygon, convex
// or not) of `p` with respect to the closed polygon `polygon` (at least 3 vertices, either
// orientation): weights that sum to 1 and reproduce p = sum_i w_i polygon_i, so any affine map
// of the polygon's vertices carries p along exactly. At a vertex the weights are that vertex's
// indicator, on an edge the linear interpolation of its two ends. Returns false (w untouched)
// for fewer than 3 vertices, non-finite input, or a polygon of zero area.
bool MeanValueCoordinates(const std::vector<Eigen::Vector2f>& polygon, const Eigen::Vector2f& p, std::vector<float>* w);

// Area of a simple polygon (absolute value of the shoelace sum), square pixels.
double PolygonArea(const std::vector<Eigen::Vector2f>& polygon);

// One open-mouth image of the target actor.
struct MouthExemplar {
  cv::Mat bgr;                           // CV_8UC3: the frame cropped around the opening
  std::vector<Eigen::Vector2f> opening;  // the inner-lip polygon (iBUG 60-67 order), crop pixels
  double area_px = 0;                    // the opening's area
  float jaw_open = 0;                    // the tracked jawOpen of that frame
  int64_t frame_index = -1;              // the frame it was taken from
  bool empty() const { return bgr.empty(); }
};

struct MouthExemplarOptions {
  // A frame is a candidate when its tracked jawOpen is at least this, its opening at least
  // min_area_px (a barely parted mouth shows lips, not an interior) and its head within
  // max_turn_deg of facing the camera (any turn: a turned mouth shows one side's teeth).
  float min_jaw_open = 0.2f;
  double min_area_px = 60.0;
  float max_turn_deg = 20.0f;
  // A later candidate replaces the exemplar when its opening is this much larger (the interior is
  // a still image: swapping it on every slightly wider frame would make the teeth flicker).
  double replace_area_ratio = 1.3;
  // The crop keeps this much of the frame around the opening (bilinear sampling near the rim).
  int margin_px = 3;
  bool IsValid(std::string* why) const;
};

// Whether a frame whose opening is `opening` (full-frame pixels), with tracked `jaw_open` and
// head turn `turn_deg` (the angle between the face's forward axis and its ray to the camera),
// should become the exemplar in place of `current` (empty: none yet).
bool IsBetterMouthExemplar(const MouthExemplar& current, const std::vector<Eigen::Vector2f>& opening, float jaw_open,
                           float turn_deg, const MouthExemplarOptions& options);

// The exemplar from `frame_bgr` (CV_8UC3) and its inner-lip polygon in frame pixels. Empty when
// the polygon is degenerate, not finite or not inside the frame.
MouthExemplar CaptureMouthExemplar(const cv::Mat& frame_bgr, const std::vector<Eigen::Vector2f>& opening, float jaw_open,
                                   int64_t frame_index, const MouthExemplarOptions& options = {});

// The exemplar's interior at the output pixel `p` inside the output opening `polygon` (the same
// vertex count and order as exemplar.opening): p's mean-value coordinates in `polygon` applied to
// the exemplar's polygon give the point sampled (bilinear). The colour is linear RGB in [0, 1].
// False where it cannot be sampled (mismatched polygons, p's coordinates undefined).
bool SampleMouthExemplar(const MouthExemplar& exemplar, const std::vector<Eigen::Vector2f>& polygon,
                         const Eigen::Vector2f& p, Eigen::Vector3f* linear_rgb, Eigen::Vector2f* exemplar_point = nullptr);

// How much light the interior gets in an opening of `area_px` against the exemplar's (Sec.
// 7.4.1: teeth and cavity darken as the mouth closes, since less light enters it). 1 when the
// opening is at least the exemplar's, falling with the square root of the area ratio, floored at
// 0.35 (a slit).
float MouthInteriorBrightness(double area_px, double exemplar_area_px);

}  // namespace face_reenact::reenact
