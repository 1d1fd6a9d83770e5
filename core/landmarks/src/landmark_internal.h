#pragma once
// Helpers shared by the detector and tracker sources (not installed).
#include <opencv2/core.hpp>
#include <string>

#include "face_reenact/landmarks/landmark_detector.h"

namespace face_reenact::landmarks::internal {

constexpr int kMaxSamples = 9;

std::string default_shape_predictor_path();
// Grey view of any supported image (zero-copy for kGray8). The view must be valid.
cv::Mat to_gray(const ImageView& image);
// RMS distance of `points` to the similarity-aligned mean shape, in inter-ocular units.
float shape_residual(const Shape68& mean_unit, const Shape68& points);
// Mean |Laplacian| over contrast on a 64x64 crop of `box`: about 0.15-0.4 on sharp faces.
float sharpness(const cv::Mat& gray, const Box& box);
Box jittered_box(const Box& box, int sample, float jitter);

using landmarks::face_side;

}  // namespace face_reenact::landmarks::internal
