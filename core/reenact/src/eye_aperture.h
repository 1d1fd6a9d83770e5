#pragma once
// An eye's opening as the frame shows it (internal to fr_reenact; the compositor's frame texture).
//
// The fit's lids are held on the eye's landmarks through a face prior, and on real faces their
// margins miss the real ones by a pixel or two (on the webcam clip, output frame 53, the fit's
// opening reaches about 2.5 px above his upper lid and stops short of his lower one). While the
// eyes do what the target's do, that never shows: every pixel samples its own. Once the output
// turns the gaze, every eyeball pixel is drawn anew, and what was drawn anew was the fit's opening:
// where it exceeds the real one, a drawn white covered his lids (the eyes looked wider than his,
// with hard grey edges), and where the real one exceeds it, the fit's lid sampled his iris where it
// had been (a dark crescent under the output's lower lid; d6 crossing her eyes onto the webcam
// clip, output frames 44-57). The landmark detector's six points on each lid margin say where the
// real opening is; the output's is that one, moved as the output moves the fit's own lid points (a
// blink or a widening the output adds).
#include <array>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

namespace face_reenact::reenact::internal {

class EyeAperture {
 public:
  // `frame_points`: the detector's six points of one eye's lid margins, in order around the eye
  // (iBUG 36-41 or 42-47), in the frame's pixels; `motion`: per point, how far the output moves
  // it (the output's lid vertex projected, minus the target's). The outline is a closed
  // Catmull-Rom curve through the points (the lids are curves; the six points' hexagon cut the
  // iris' top off).
  EyeAperture(const std::array<Eigen::Vector2f, 6>& frame_points, const std::array<Eigen::Vector2f, 6>& motion);

  enum class Which { kFrame, kOutput };
  // Signed distance in pixels of `p` from the frame's or the output's outline, positive inside;
  // `motion_at` (optional): the output's motion at the outline's nearest point.
  float SignedDistance(const Eigen::Vector2f& p, Which which, Eigen::Vector2f* motion_at = nullptr) const;
  // Where the frame shows the lid that covers output pixel `p` (outside the output's opening),
  // moved by `motion`: p - motion, or, where that lies inside the frame's opening (lids the
  // output shuts leave a pixel's seam of eyeball, which sampled his open eye: a light dotted line
  // along the shut lids; d14 with her eyes shut onto the webcam clip, output frame 95), the
  // frame's lid margin nearest it, a pixel outside the opening.
  Eigen::Vector2f FrameLidPoint(const Eigen::Vector2f& p, const Eigen::Vector2f& motion) const;
  // The pixels within `margin` of the outline's box, within a w x h image.
  cv::Rect Bounds(Which which, int margin, int w, int h) const;
  // The outline in whole pixels (for a polygon fill).
  std::vector<cv::Point> PixelOutline(Which which) const;

 private:
  std::vector<Eigen::Vector2f> frame_, output_, motion_;  // the curve's samples, in order
};

}  // namespace face_reenact::reenact::internal
