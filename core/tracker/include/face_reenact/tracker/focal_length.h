#pragma once
// The focal length of a camera that does not say (a video file, a V4L2 webcam), estimated from
// the tracker's calibration frames (issue #26 §5). Videos carry no intrinsics, and the 60 degrees
// assumed until now put the face at the wrong distance whenever the camera was wider or narrower:
// the fitted head then had to be a different shape to project the same, and the reenacted face
// was rendered with the wrong perspective.
//
// How: for each horizontal field of view of a search (a grid, then a golden-section refinement
// around the grid's best), the calibration frames' landmarks are fitted by one shared identity and
// a pose per frame (Gauss-Newton, no rendering), and the field of view whose fit leaves the lowest
// energy (E_lan plus the identity prior, the calibration's weights) wins. A head of the model's
// metric size seen through the right lens explains the landmarks' perspective (the nose against the
// brows and the mouth, changing with the head's turn); through a wider lens the head has to be
// nearer and shows more perspective than the image does, through a narrower one less. The identity
// prior keeps the head at a plausible size and depth, so it cannot absorb the difference for free.
// docs/tracking-pipeline.md ("Camera intrinsics for video") has the measurements.
#include <string>
#include <utility>
#include <vector>

#include "face_reenact/gpu/image_formation.h"
#include "face_reenact/tracker/input_frame.h"
#include "face_reenact/tracker/tracker_model.h"

namespace face_reenact::tracker {

struct FocalLengthOptions {
  // Off by default: only the front-ends know that a camera is an assumption (a video file or a
  // webcam without --fov / --intrinsics). Frames with depth are never searched (their intrinsics
  // are the sensor's).
  bool estimate = false;
  // The search range (horizontal field of view, degrees): webcams and phones are 50-80, wide
  // conference cameras up to 90-100, a zoomed camera 30.
  double min_fov_deg = 30.0;
  double max_fov_deg = 100.0;
  int grid_points = 15;         // fields of view tried over the range, evenly spaced
  int refine_iterations = 10;   // golden-section steps between the grid's best and its neighbours
  int threads = 0;              // grid points fitted side by side (0: one per hardware thread, at most 8)
  // The landmark fit per field of view.
  int gauss_newton_iterations = 20;
  // Leading identity components fitted (the rest stay at the mean). Measured on synthetic renders
  // (docs): with 40 of the model's 80, the part of the head the fit could not shape was read as
  // perspective (85 degrees read 92).
  int identity_components = 80;
  // Weight of the identity prior sum (alpha_i / sigma_i)^2 against E_lan (0.125 x the mean squared
  // landmark offset in pixels of a 640-wide image, summed over frames): the calibration's w_reg.
  // 10x stronger held the actors' identity near the mean face and read the wrong lens (errors up to
  // 9.5 % against 2.7 %).
  double w_identity = 0.005;
  double w_landmarks = 0.125;
  // When the search cannot decide (no usable landmarks, the best at an end of the range, an energy
  // that leaves the lens uncertain): this field of view, the common webcam's.
  double fallback_fov_deg = 60.0;
  // How well the landmarks pin the lens down: the fields of view whose fit ends within the
  // landmarks' own noise of the best (energy below the best's + confidence_chi2 x the best fit's
  // landmark energy per degree of freedom, the residuals less the unknowns; 3.84: a profile
  // likelihood's 95 % for one parameter) form an interval, and the grid must have one valley
  // (SecondEnergyValley below, with the same bound). The interval must not reach an end of the
  // range and must be at most max_relative_uncertainty x the estimate wide on either side. Renders
  // with exact landmarks give intervals of +-2-7 %; with 1 px of landmark noise they span most of
  // the range, where the checks before this one passed estimates 4-15 % off, and stretches of one
  // real clip read 32-96 degrees (docs/tracking-pipeline.md, "Camera intrinsics for video").
  double confidence_chi2 = 3.84;
  double max_relative_uncertainty = 0.15;
  // Landmarks further from the best fit than this (RMS, pixels of a 640-wide image) are too noisy
  // to read the lens: the perspective the search reads is below a pixel (synthetic renders fit to
  // 0.07 px; dlib on the real clips to ~3 px, where the energy over the field of view had several
  // minima).
  double max_landmark_rms_px = 1.5;
  float min_landmark_confidence = 0.05f;
  bool IsValid(std::string* why) const;
};

struct FocalLengthEstimate {
  // True when the search ran and found an interior minimum; false: horizontal_fov_deg is the
  // fallback (message says why) or, when nothing was done, NaN.
  bool estimated = false;
  double horizontal_fov_deg = 0;
  double energy = 0;               // the landmark fit's energy at horizontal_fov_deg
  double landmark_error_px = -1;   // its RMS landmark offset, pixels of a 640-wide image
  // The fields of view the landmarks cannot tell from the best (FocalLengthOptions::confidence_chi2);
  // an end of the search range where the energy never rose above the bound on that side.
  double fov_low_deg = 0, fov_high_deg = 0;
  int frames = 0;                  // calibration frames with enough landmarks
  std::vector<std::pair<double, double>> energy_by_fov;  // the grid: (fov deg, energy)
  std::string message;
  double ms = 0;                   // wall time of the search
};

// The search above over `frames` (their cameras' principal points and image sizes are kept; fx and
// fy are replaced per field of view). Never throws for frame content: bad or too few landmarks give
// estimated false with the fallback and a message.
FocalLengthEstimate EstimateFocalLength(const TrackerModel& model, const std::vector<InputFrame>& frames,
                                        const FocalLengthOptions& options);

// How EstimateFocalLength reads its energy over the field of view (samples: (fov deg, energy)).
//
// The fields of view whose energy is at most `bound`: from the lowest such sample to the highest
// (several valleys make one wide interval), each end where the line to its outer neighbour crosses
// the bound; `bounded` false when a sample at an end of the range is within (that end is then the
// interval's).
struct FovInterval {
  double low = 0, high = 0;
  bool bounded = false;
};
FovInterval FieldsOfViewWithin(std::vector<std::pair<double, double>> samples, double bound);
// A valley of the grid (ordered by fov) other than the one at `best`: walking from each end
// towards `best`, the energy rises more than `bound` above the lowest point passed, a hump between
// that point and the best. Returns that point's index, or -1 when the grid has one valley
// (non-finite energies count as the highest). Renders with exact landmarks give one smooth valley;
// on real clips fits that ended in different minima at neighbouring fields of view made steps of
// 1-20 %, and a narrow dip between two of them passed for an estimate (68.5 degrees from one
// stretch of a clip, 95.6 from the next).
int SecondEnergyValley(const std::vector<std::pair<double, double>>& grid, int best, double bound);

// `camera` with fx = fy set for the horizontal field of view `fov_deg` (principal point and size kept).
gpu::PinholeCamera WithHorizontalFov(const gpu::PinholeCamera& camera, double fov_deg);
// 2 atan(width / (2 fx)) in degrees.
double HorizontalFovDeg(const gpu::PinholeCamera& camera);

}  // namespace face_reenact::tracker
