#pragma once
// Laplacian-pyramid compositing (paper Sec. 7.4.2, after Burt and Adelson): the rendered face
// and the target frame are split into band-pass levels, each level is blended with the mask
// smoothed to that level's scale (its Gaussian pyramid), and the levels are summed back. Coarse
// bands cross the seam over a wide region, fine bands over a narrow one, so neither a colour
// step nor a blurred edge shows at the mask boundary.
//
// Exactness outside the blend region: the blend is done on the difference D = rendered - target
// (the blend of two images with one mask equals target + blend of D), and the collapsed result
// is applied only inside the *blend region*: the pixels within `support_radius()` of a nonzero
// mask pixel, faded to zero across its outer band. Everywhere else the output is the target,
// bit for bit.
#include <string>

#include <opencv2/core.hpp>

namespace face_reenact::reenact {

struct LaplacianBlendOptions {
  int levels = 5;  // >= 1; 1 = a plain per-pixel alpha blend
  int threads = 1;  // the pool's threads for its passes (face_reenact::ParallelFor); the same result for any count
  bool IsValid(std::string* why) const;
};

struct LaplacianBlendSummary {
  int levels_used = 0;     // fewer than asked when the image is too small to halve again
  cv::Rect blend_region;   // bounding box of the pixels that may differ from the target (empty: none)
};

// Blends `rendered` over `target` with `mask` (1 = rendered, 0 = target). target and rendered:
// CV_8UC3 or CV_32FC3 of the same size; mask: CV_32FC1 in [0, 1] (or CV_8UC1, 255 = 1) of that
// size. Returns the type of `target`. Work is restricted to a padded bounding box of the mask,
// so cost follows the face's size, not the frame's. Throws face_reenact::Error on mismatched or
// empty inputs or invalid options.
cv::Mat LaplacianBlend(const cv::Mat& target, const cv::Mat& rendered, const cv::Mat& mask,
                       const LaplacianBlendOptions& options, LaplacianBlendSummary* summary = nullptr);

// How far (pixels) the blend can reach beyond the mask with `levels` levels.
int blend_support_radius(int levels);

}  // namespace face_reenact::reenact
