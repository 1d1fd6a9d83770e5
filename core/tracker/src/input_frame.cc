#include "face_reenact/tracker/input_frame.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cstdint>
#include <cmath>
#include <limits>

#include "face_reenact/common/error.h"
#include "face_reenact/common/parallel.h"
#include "face_reenact/common/srgb.h"
#include "tracker_internal.h"

namespace face_reenact::tracker {
namespace {
size_t pixel_count(const gpu::PinholeCamera& c) { return static_cast<size_t>(c.width) * static_cast<size_t>(c.height); }

// A depth sample inside the camera's near/far range: what makes a sample valid (depth_valid).
// NaN and infinity fail one of the comparisons; branch-free, so loops over rows vectorise.
bool depth_in_range(float d, float near, float far) { return d > near && d < far; }

// Taps of the [1 3 3 1] / 8 kernel around coarse sample k: fine indices 2k-1 .. 2k+2.
constexpr float kTap[4] = {1.f / 8, 3.f / 8, 3.f / 8, 1.f / 8};

// Coarse rows per work item: each coarse pixel reads only the fine frame, so rows are independent.
constexpr int kRowsPerItem = 8;

// The fine samples of coarse index k along an axis of n samples: 2k-1 .. 2k+2, clamped.
std::array<int, 4> taps_of(int k, int n) {
  return {std::max(2 * k - 1, 0), std::min(2 * k, n - 1), std::min(2 * k + 1, n - 1), std::min(2 * k + 2, n - 1)};
}

// The next coarser level's camera and landmarks (the pixel centres move with the camera
// convention), without pixels.
InputFrame coarser_level(const InputFrame& fine) {
  InputFrame c;
  c.camera = fine.camera.Downsampled(1);
  c.landmarks = fine.landmarks;
  for (auto& l : c.landmarks) l.position = (l.position.array() + 0.5f) * 0.5f - 0.5f;
  return c;
}

InputFrame downsample(const InputFrame& fine, const PyramidOptions& options, int threads) {
  InputFrame c = coarser_level(fine);
  const int fw = fine.width(), fh = fine.height(), w = c.width(), h = c.height();
  c.color.resize(3 * pixel_count(c.camera));  // every value is written below
  if (fine.has_depth()) c.depth.resize(pixel_count(c.camera));
  std::vector<std::array<int, 4>> columns(static_cast<size_t>(w));
  for (int i = 0; i < w; ++i) columns[static_cast<size_t>(i)] = taps_of(i, fw);
  const float inf = std::numeric_limits<float>::infinity();
  const float near = fine.camera.near_plane, far = fine.camera.far_plane, threshold = options.depth_edge_threshold;
  ParallelFor((h + kRowsPerItem - 1) / kRowsPerItem, threads, [&](int item) {
    const int j0 = item * kRowsPerItem, j1 = std::min(h, j0 + kRowsPerItem);
    // The fine rows these coarse rows read (2 j0 - 1 .. 2 j1, clamped), each filtered along the
    // row once: the kernel is separable, and its weights (eighths) sum to exactly 1.
    const int first = 2 * j0 - 1, rows = 2 * (j1 - j0) + 2;
    std::vector<float> filtered(static_cast<size_t>(rows) * w * 3);
    // Depth per fine sample of those rows, +inf where not valid: an invalid sample is then never
    // the nearest and never within the edge threshold of it.
    std::vector<float> valid_depth(fine.has_depth() ? static_cast<size_t>(rows) * fw : 0);
    for (int r = 0; r < rows; ++r) {
      const int fj = std::clamp(first + r, 0, fh - 1);
      const float* src = &fine.color[static_cast<size_t>(fj) * fw * 3];
      float* dst = &filtered[static_cast<size_t>(r) * w * 3];
      for (int i = 0; i < w; ++i) {
        const auto& t = columns[static_cast<size_t>(i)];
        for (int k = 0; k < 3; ++k) {
          dst[3 * i + k] = kTap[0] * src[3 * t[0] + k] + kTap[1] * src[3 * t[1] + k] + kTap[2] * src[3 * t[2] + k] +
                           kTap[3] * src[3 * t[3] + k];
        }
      }
      if (!fine.has_depth()) continue;
      // InputFrame::depth_valid without its bounds checks.
      const float* depth = &fine.depth[static_cast<size_t>(fj) * fw];
      float* vd = &valid_depth[static_cast<size_t>(r) * fw];
      for (int fi = 0; fi < fw; ++fi) vd[fi] = depth_in_range(depth[fi], near, far) ? depth[fi] : inf;
    }
    for (int j = j0; j < j1; ++j) {
      const size_t row0 = static_cast<size_t>(2 * (j - j0));  // fine row 2j - 1 (clamped) in `filtered`
      const float* f[4];
      for (int b = 0; b < 4; ++b) f[b] = &filtered[(row0 + static_cast<size_t>(b)) * w * 3];
      float* dst = &c.color[static_cast<size_t>(j) * w * 3];
      for (int k = 0; k < 3 * w; ++k) dst[k] = kTap[0] * f[0][k] + kTap[1] * f[1][k] + kTap[2] * f[2][k] + kTap[3] * f[3][k];
      if (!fine.has_depth()) continue;
      // Depth: the nearest valid sample of the inner 2x2 block is the reference; only samples
      // within depth_edge_threshold of it are averaged, so silhouettes do not blend with the
      // background into phantom surfaces.
      const float* d[4];
      for (int b = 0; b < 4; ++b) d[b] = &valid_depth[(row0 + static_cast<size_t>(b)) * fw];
      for (int i = 0; i < w; ++i) {
        const auto& t = columns[static_cast<size_t>(i)];
        const float nearest = std::min({d[1][t[1]], d[1][t[2]], d[2][t[1]], d[2][t[2]]});
        float dsum = 0, dw = 0;
        if (nearest < inf) {
          // A sample beyond the edge (or invalid: +inf) adds an exact 0, without a branch.
          for (int b = 0; b < 4; ++b) {
            for (int a = 0; a < 4; ++a) {
              const float v = d[b][t[static_cast<size_t>(a)]];
              const bool near_surface = std::abs(v - nearest) <= threshold;
              dsum += near_surface ? kTap[a] * kTap[b] * v : 0.f;
              dw += near_surface ? kTap[a] * kTap[b] : 0.f;
            }
          }
        }
        c.depth[static_cast<size_t>(j) * w + i] = dw > 0 ? dsum / dw : 0.f;
      }
    }
  });
  return c;
}

// Level 0 as BuildPyramid keeps it without its pixels: the frame's camera, landmarks, timestamp.
InputFrame level0_without_pixels(const InputFrame& frame) {
  InputFrame header;
  header.camera = frame.camera;
  header.landmarks = frame.landmarks;
  header.timestamp_s = frame.timestamp_s;
  header.new_face = frame.new_face;
  return header;
}

void check_level_size(const InputFrame& frame, const InputFrame& finer, const PyramidOptions& options) {
  if (finer.width() < 2 || finer.height() < 2) {
    throw Error("pyramid: a " + std::to_string(frame.width()) + "x" + std::to_string(frame.height()) +
                " frame is too small for " + std::to_string(options.levels) + " levels");
  }
}

}  // namespace

bool InputFrame::depth_valid(int i, int j) const {
  if (depth.empty() || i < 0 || j < 0 || i >= camera.width || j >= camera.height) return false;
  const float d = depth[static_cast<size_t>(j) * camera.width + i];
  return depth_in_range(d, camera.near_plane, camera.far_plane);
}

Eigen::Vector3d InputFrame::point(int i, int j) const {
  const double z = depth[static_cast<size_t>(j) * camera.width + i];
  return {(i - camera.cx) * z / camera.fx, (j - camera.cy) * z / camera.fy, z};
}

bool InputFrame::IsValid(std::string* why) const {
  if (!IsValidExceptColorValues(why)) return false;
  // NaN or infinity: all exponent bits set. An OR over the array vectorises; a loop that stops
  // at the first bad value does not (this check is a fifth of a 640x480 pyramid's time otherwise).
  uint32_t non_finite = 0;
  for (float v : color) non_finite |= static_cast<uint32_t>((std::bit_cast<uint32_t>(v) & 0x7f800000u) == 0x7f800000u);
  if (non_finite) return fail_why(why, kNonFiniteColorMessage);
  return true;
}

bool InputFrame::IsValidExceptColorValues(std::string* why) const {
  if (!camera.IsValid(why)) return false;
  const size_t n = pixel_count(camera);
  if (color.size() != 3 * n) {
    return fail_why(why, "input frame: colour has " + std::to_string(color.size()) + " values, " +
                         std::to_string(3 * n) + " expected (3 per pixel)");
  }
  if (!depth.empty() && depth.size() != n) {
    return fail_why(why, "input frame: depth has " + std::to_string(depth.size()) + " values, " + std::to_string(n) +
                         " expected (1 per pixel, or none)");
  }
  for (const auto& l : landmarks) {
    if (l.ibug_index < 0 || l.ibug_index > 67) return fail_why(why, "input frame: landmark index outside 0..67");
    if (!l.position.allFinite() || !std::isfinite(l.confidence) || l.confidence < 0.f) {
      return fail_why(why, "input frame: landmark " + std::to_string(l.ibug_index) + " has a non-finite position or bad confidence");
    }
  }
  return true;
}

void InputFrame::SetColorFromSrgb8(const uint8_t* rgb, size_t size_bytes) {
  const size_t n = pixel_count(camera);
  if (size_bytes != 3 * n) throw Error("input frame: sRGB image has the wrong size for the camera");
  const auto& table = srgb_decode_table();
  color.resize(3 * n);
  for (size_t k = 0; k < 3 * n; ++k) color[k] = table[rgb[k]];
}

bool PyramidOptions::IsValid(std::string* why) const {
  if (levels < 1 || levels > 8) return fail_why(why, "pyramid: levels must be 1..8");
  if (!(depth_edge_threshold > 0.f)) return fail_why(why, "pyramid: depth_edge_threshold must be positive");
  return true;
}

std::vector<InputFrame> BuildPyramid(const InputFrame& frame, const PyramidOptions& options, int threads,
                                     bool keep_level0) {
  std::string why;
  if (!options.IsValid(&why)) throw Error(why);
  if (!frame.IsValid(&why)) throw Error(why);
  std::vector<InputFrame> levels;
  levels.reserve(options.levels);
  levels.push_back(keep_level0 ? frame : level0_without_pixels(frame));
  for (int l = 1; l < options.levels; ++l) {
    const InputFrame& finer = l == 1 ? frame : levels.back();
    check_level_size(frame, finer, options);
    levels.push_back(downsample(finer, options, threads));
  }
  return levels;
}

std::vector<InputFrame> PyramidLevelsWithoutPixels(const InputFrame& frame, const PyramidOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw Error(why);
  if (!frame.IsValidExceptColorValues(&why)) throw Error(why);
  std::vector<InputFrame> levels;
  levels.reserve(options.levels);
  levels.push_back(level0_without_pixels(frame));
  for (int l = 1; l < options.levels; ++l) {
    check_level_size(frame, levels.back(), options);
    levels.push_back(coarser_level(levels.back()));
  }
  return levels;
}

bool InputNormal(const InputFrame& frame, int i, int j, float max_depth_jump, Eigen::Vector3d* normal) {
  if (!frame.depth_valid(i, j) || !frame.depth_valid(i - 1, j) || !frame.depth_valid(i + 1, j) ||
      !frame.depth_valid(i, j - 1) || !frame.depth_valid(i, j + 1)) {
    return false;
  }
  const size_t w = frame.camera.width;
  const float d = frame.depth[j * w + i];
  for (size_t k : {j * w + i - 1, j * w + i + 1, (j - 1) * w + i, (j + 1) * w + i}) {
    if (std::abs(frame.depth[k] - d) > max_depth_jump) return false;
  }
  const Eigen::Vector3d du = frame.point(i + 1, j) - frame.point(i - 1, j);
  const Eigen::Vector3d dv = frame.point(i, j + 1) - frame.point(i, j - 1);
  Eigen::Vector3d n = du.cross(dv);
  const double len = n.norm();
  if (!(len > 0)) return false;
  n /= len;
  if (n.dot(frame.point(i, j)) > 0) n = -n;  // towards the camera
  *normal = n;
  return true;
}

Eigen::Matrix<double, 3, 2> InputColorGradient(const InputFrame& frame, int i, int j) {
  const int w = frame.width(), h = frame.height();
  auto at = [&](int ii, int jj, int c) { return static_cast<double>(frame.color[3 * (static_cast<size_t>(jj) * w + ii) + c]); };
  const int i0 = std::max(i - 1, 0), i1 = std::min(i + 1, w - 1);
  const int j0 = std::max(j - 1, 0), j1 = std::min(j + 1, h - 1);
  Eigen::Matrix<double, 3, 2> g = Eigen::Matrix<double, 3, 2>::Zero();
  for (int c = 0; c < 3; ++c) {
    if (i1 > i0) g(c, 0) = (at(i1, j, c) - at(i0, j, c)) / (i1 - i0);
    if (j1 > j0) g(c, 1) = (at(i, j1, c) - at(i, j0, c)) / (j1 - j0);
  }
  return g;
}

}  // namespace face_reenact::tracker
