#pragma once
// Whether a frame's depth is registered to its colour, from their edges.
//
// The tracker's depth terms compare the model with the depth at the colour's pixels (Eq. 6-7):
// a depth map that is not registered to the colour (a sensor's depth-to-colour registration off,
// a recording made with another camera's calibration) puts the face's depth a few pixels beside
// its colour, and the fit compromises between the two without saying so. The head's silhouette
// is an edge in both: where the depth jumps (or ends) the colour changes too. So the colour's
// gradient is summed along the depth's foreground edges, for every shift of the colour within a
// few pixels; registered, the sum peaks at (or next to) no shift. A clear peak elsewhere is the
// offset, and the tracker warns with it (FaceTracker::calibration_warning).
#include <string>

#include "face_reenact/tracker/input_frame.h"

namespace face_reenact::tracker {

struct DepthAlignmentOptions {
  // Shifts searched, each way, in pixels of a 640-wide frame (scaled with the frame's width).
  double max_shift_px = 12.0;
  // A best shift at least this far from none (640-wide pixels), whose edge agreement beats the
  // unshifted one by at least min_gain, is a misalignment. A few pixels are within the sensors'
  // and the edges' own blur: the synthetic recordings' Kinect-like sensor (registered, with its
  // edge noise and shadows) reads best shifts of 2-4 px at gains of 1.06-1.24, a depth map moved
  // by 6-9 px reads its shift at gains above 1.5.
  double min_shift_px = 4.0;
  double min_gain = 1.5;
  // A depth edge: a valid sample whose 4-neighbour is this much farther away, or has no depth.
  float depth_jump_m = 0.02f;
  // Fewer depth edge pixels than this measure nothing.
  int min_edge_pixels = 50;

  bool IsValid(std::string* why) const;
};

struct DepthAlignment {
  bool measured = false;
  std::string message;  // why nothing was measured, or what was found
  // The shift s (pixels of this frame) at which the colour's edges, colour(p + s), best match
  // the depth's, depth(p).
  int shift_x = 0, shift_y = 0;
  double agreement_unshifted = 0;  // mean colour gradient along the depth edges, unshifted
  double agreement_best = 0;       // the same at the best shift
  int edge_pixels = 0;
  bool misaligned = false;
};

// Measures `frame` (with depth) around its landmarks (the box of the confident ones, widened by
// half its size each way, so that it holds the head's silhouette), or over the whole frame
// without landmarks.
DepthAlignment MeasureDepthAlignment(const InputFrame& frame, const DepthAlignmentOptions& options = {});

}  // namespace face_reenact::tracker
