#pragma once
// The tracker's input: one RGB-D frame with optional 2D landmarks, as plain data. Recording
// formats (core/capture) convert into this; the tracker never reads files itself.
#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <limits>
#include <vector>

#include "face_reenact/gpu/image_formation.h"

namespace face_reenact::tracker {

struct InputLandmark {
  int32_t ibug_index = 0;              // 0..67, iBUG 300-W order
  Eigen::Vector2f position{0.f, 0.f};  // pixels of this frame (OpenCV centre convention)
  float confidence = 1.0f;             // >= 0; 0 ignores the point
  // The model vertex this point is matched to in E_lan, when it is not the model's binding for
  // ibug_index (-1): a correspondence that moves with the view, like a jaw-line point on the
  // face's occluding contour (ContourLandmarks, fit_agreement.h).
  int32_t model_vertex = -1;
};

struct InputFrame {
  gpu::PinholeCamera camera;         // intrinsics; width x height is the image size
  std::vector<float> color;          // 3 per pixel, linear RGB in [0, 1], row-major (j * w + i)
  std::vector<float> depth;          // 1 per pixel, metres along +z; 0 or NaN = no measurement;
                                     // empty = the frame has no depth at all (colour-only)
  std::vector<InputLandmark> landmarks;
  // When the frame was captured (seconds, any origin); NaN = unknown. The tracker's rotation
  // speed check (FitAgreementOptions::max_rotation_speed_deg_s) needs it.
  double timestamp_s = std::numeric_limits<double>::quiet_NaN();
  // The landmarks belong to another face than the previous frame's (the landmark tracker left a
  // small face for a more prominent one): the tracker learns this person's identity anew.
  bool new_face = false;

  int width() const { return camera.width; }
  int height() const { return camera.height; }
  bool has_depth() const { return !depth.empty(); }
  // Valid depth sample at (i, j): finite, > 0 and inside the camera's near/far range.
  bool depth_valid(int i, int j) const;
  // Back-projected point X_I(p) (camera frame, metres); only meaningful where depth_valid.
  Eigen::Vector3d point(int i, int j) const;

  bool IsValid(std::string* why) const;
  // IsValid without reading the colour values (their number is checked): for a caller that reads
  // every value anyway and checks them as it goes (VulkanSolver::Solve, while uploading them).
  bool IsValidExceptColorValues(std::string* why) const;

  // Fills `color` from 8-bit sRGB (3 bytes per pixel, row-major) with the sRGB transfer
  // function undone, so that C_I is linear like the renderer's C_S.
  void SetColorFromSrgb8(const uint8_t* rgb, size_t size_bytes);
};

// What IsValid says of a frame whose colour has a NaN or an infinity.
inline constexpr const char* kNonFiniteColorMessage = "input frame: colour contains NaN or infinity";

struct PyramidOptions {
  int levels = 3;                     // level 0 = the input itself
  float depth_edge_threshold = 0.03f; // metres: depth samples farther than this from the block's
                                      // nearest sample are not averaged across (silhouettes)
  bool IsValid(std::string* why) const;
};

// Gaussian pyramid (Sec. 6.1): each level blurs with the separable [1 3 3 1] / 8 kernel centred
// on the 2x2 block it replaces and takes one sample per block, so coarse pixel centres sit where
// PinholeCamera::Downsampled puts them. Depth averages only valid samples near the block's
// nearest depth; landmarks move with the camera convention. Throws face_reenact::Error on an
// invalid frame or options. Up to `threads` threads share each level's rows (the same result for
// any count). `keep_level0` false: level 0 has the frame's camera, timestamp and landmarks but no
// pixels, for a solve whose schedule starts on a coarser level (the paper's never reads level 0,
// and copying a 640x480 frame into it was a third of the pyramid's time).
std::vector<InputFrame> BuildPyramid(const InputFrame& frame, const PyramidOptions& options, int threads = 1,
                                     bool keep_level0 = true);

// The levels BuildPyramid makes, without their pixels: each level's camera and landmarks (level
// 0 also the frame's timestamp), for a solver that makes the pixels itself (VulkanSolver builds
// them on the device with the same kernel). Throws like BuildPyramid, except that the colour
// values are not read (InputFrame::IsValidExceptColorValues): the caller that reads them checks
// them.
std::vector<InputFrame> PyramidLevelsWithoutPixels(const InputFrame& frame, const PyramidOptions& options);

// The input normal N_I(p): the cross product of the central differences of X_I along i and j,
// oriented towards the camera. False where a neighbour is missing or across a depth jump larger
// than `max_depth_jump` metres.
bool InputNormal(const InputFrame& frame, int i, int j, float max_depth_jump, Eigen::Vector3d* normal);

// The gradient of the input colour at pixel (i, j): column 0 is d/du (along i), column 1 d/dv
// (along j), one row per channel, per pixel. Central differences, one-sided at the image border.
// The colour term's derivative through the projection (energy.h) reads it.
Eigen::Matrix<double, 3, 2> InputColorGradient(const InputFrame& frame, int i, int j);

}  // namespace face_reenact::tracker
