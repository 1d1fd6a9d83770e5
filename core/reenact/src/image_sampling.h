#pragma once
// Pixel-level helpers of the re-rendering (internal to fr_reenact): sub-pixel sampling, shared by
// the compositor's frame texture and the mouth interior's warp, and the composite's pixel encoding.
#include <algorithm>
#include <cmath>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "face_reenact/common/srgb.h"
#include "face_reenact/gpu/image_formation.h"

namespace face_reenact::reenact::internal {

// The four pixels around the sub-pixel position (x, y) of a cols x rows image (x, y within
// [0, cols-1] x [0, rows-1]) and their bilinear weights: value = mix(mix(a, b, fx), mix(c, d, fx), fy).
struct Bilinear {
  int i0, j0, i1, j1;
  float fx, fy;
  Bilinear(int cols, int rows, float x, float y) {
    i0 = std::min(static_cast<int>(x), std::max(cols - 2, 0));
    j0 = std::min(static_cast<int>(y), std::max(rows - 2, 0));
    i1 = std::min(i0 + 1, cols - 1);
    j1 = std::min(j0 + 1, rows - 1);
    fx = std::clamp(x - static_cast<float>(i0), 0.0f, 1.0f);
    fy = std::clamp(y - static_cast<float>(j0), 0.0f, 1.0f);
  }
  float mix(float a, float b, float c, float d) const { return (1 - fy) * ((1 - fx) * a + fx * b) + fy * ((1 - fx) * c + fx * d); }
};

// A projected coordinate as a pixel index, rounded down or to the nearest: clamped to +-2^24 first,
// so a point projecting far outside any image (a fit far off, just in front of the near plane)
// cannot overflow the int (a NaN takes the low end). Such a pixel lies outside every image.
inline float within_pixel_range(float v) {
  constexpr float kFar = 16777216.f;
  return v >= -kFar ? (v <= kFar ? v : kFar) : -kFar;
}
inline int pixel_floor(float v) { return static_cast<int>(std::floor(within_pixel_range(v))); }
inline int pixel_round(float v) { return static_cast<int>(std::lround(within_pixel_range(v))); }

// `m` (CV_32FC1) at the sub-pixel position (x, y), bilinear, clamped to its border.
inline float sample_float(const cv::Mat& m, float x, float y) {
  const Bilinear s(m.cols, m.rows, std::clamp(x, 0.0f, static_cast<float>(m.cols - 1)),
                   std::clamp(y, 0.0f, static_cast<float>(m.rows - 1)));
  return s.mix(m.at<float>(s.j0, s.i0), m.at<float>(s.j0, s.i1), m.at<float>(s.j1, s.i0), m.at<float>(s.j1, s.i1));
}

// Linear colour of `bgr` (CV_8UC3, sRGB) at the sub-pixel position (x, y), bilinear in linear
// light (0 <= x <= w-1, 0 <= y <= h-1).
inline Eigen::Vector3f sample_linear(const cv::Mat& bgr, float x, float y) {
  const auto& lut = srgb_decode_table();
  const Bilinear s(bgr.cols, bgr.rows, x, y);
  const cv::Vec3b a = bgr.at<cv::Vec3b>(s.j0, s.i0), b = bgr.at<cv::Vec3b>(s.j0, s.i1), c = bgr.at<cv::Vec3b>(s.j1, s.i0),
                  d = bgr.at<cv::Vec3b>(s.j1, s.i1);
  Eigen::Vector3f out;
  for (int ch = 0; ch < 3; ++ch) {
    const int k = 2 - ch;  // BGR -> RGB
    out[ch] = s.mix(lut[a[k]], lut[b[k]], lut[c[k]], lut[d[k]]);
  }
  return out;
}

// Linear RGB as the composite's pixels hold it: sRGB-encoded BGR, 0..255 as float.
inline cv::Vec3f display_bgr(float r, float g, float b) {
  return cv::Vec3f(255.0f * srgb_encode(b), 255.0f * srgb_encode(g), 255.0f * srgb_encode(r));
}
inline cv::Vec3f display_bgr(const Eigen::Vector3f& rgb) { return display_bgr(rgb[0], rgb[1], rgb[2]); }

// Pixel p of `from` written into `to` (a G-buffer of the same size): a surface another draw put
// there replaces the one `to` had (skin over a stray tooth, an eyeball behind a lid).
inline void copy_pixel(const gpu::GBuffer& from, size_t p, gpu::GBuffer* to) {
  to->triangle[p] = from.triangle[p];
  for (size_t k = 0; k < 3; ++k) {
    to->vertices[3 * p + k] = from.vertices[3 * p + k];
    to->color[3 * p + k] = from.color[3 * p + k];
    to->position[3 * p + k] = from.position[3 * p + k];
    to->normal[3 * p + k] = from.normal[3 * p + k];
    to->barycentric[3 * p + k] = from.barycentric[3 * p + k];
  }
}

// `rect` grown by `margin` on every side and kept inside a w x h image.
inline cv::Rect grown_within(const cv::Rect& rect, int margin, int w, int h) {
  return (rect + cv::Size(2 * margin, 2 * margin) - cv::Point(margin, margin)) & cv::Rect(0, 0, w, h);
}

// The rectangle around a G-buffer's covered pixels, grown by `margin` on every side and kept
// inside the image; empty when nothing is covered. Each row is scanned from both ends to its
// first covered pixel (uniting a rectangle per pixel cost a tenth of a millisecond at 640x480),
// and only within the rectangle the last draw wrote when the buffer says it (outside it
// nothing is covered: GBuffer::drawn).
inline cv::Rect covered_rect(const gpu::GBuffer& g, int margin) {
  int scan_i0 = 0, scan_i1 = g.width - 1, scan_j0 = 0, scan_j1 = g.height - 1;
  if (g.DrawnIsKnown(g.width, g.height)) {
    scan_i0 = std::max(scan_i0, g.drawn.i0), scan_i1 = std::min(scan_i1, g.drawn.i1);
    scan_j0 = std::max(scan_j0, g.drawn.j0), scan_j1 = std::min(scan_j1, g.drawn.j1);
  }
  int i0 = g.width, i1 = -1, j0 = g.height, j1 = -1;
  for (int j = scan_j0; j <= scan_j1 && scan_i0 <= scan_i1; ++j) {
    const int32_t* row = g.triangle.data() + static_cast<size_t>(j) * g.width;
    int first = scan_i0;
    while (first <= scan_i1 && row[first] < 0) ++first;
    if (first > scan_i1) continue;
    int last = scan_i1;
    while (row[last] < 0) --last;
    i0 = std::min(i0, first), i1 = std::max(i1, last), j0 = std::min(j0, j), j1 = j;
  }
  if (i1 < 0) return cv::Rect();
  return grown_within(cv::Rect(i0, j0, i1 - i0 + 1, j1 - j0 + 1), margin, g.width, g.height);
}

}  // namespace face_reenact::reenact::internal
