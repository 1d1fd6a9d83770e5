#include "face_reenact/tracker/input_frame.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "face_reenact/common/error.h"
#include "face_reenact/common/parallel.h"
#include "face_reenact/common/srgb.h"
#include "tracker_internal.h"

namespace face_reenact::tracker {
using internal::fail;
namespace {
size_t pixel_count(const gpu::PinholeCamera& c) { return static_cast<size_t>(c.width) * static_cast<size_t>(c.height); }

// Taps of the [1 3 3 1] / 8 kernel around coarse sample k: fine indices 2k-1 .. 2k+2.
constexpr float kTap[4] = {1.f / 8, 3.f / 8, 3.f / 8, 1.f / 8};

// Coarse rows per work item: each coarse pixel reads only the fine frame, so rows are independent.
constexpr int kRowsPerItem = 8;

InputFrame downsample(const InputFrame& fine, const PyramidOptions& options, int threads) {
  InputFrame c;
  c.camera = fine.camera.Downsampled(1);
  const int fw = fine.width(), fh = fine.height(), w = c.width(), h = c.height();
  c.color.assign(3 * pixel_count(c.camera), 0.f);
  if (fine.has_depth()) c.depth.assign(pixel_count(c.camera), 0.f);
  ParallelFor((h + kRowsPerItem - 1) / kRowsPerItem, threads, [&](int item) {
    for (int j = item * kRowsPerItem; j < std::min(h, (item + 1) * kRowsPerItem); ++j) {
      for (int i = 0; i < w; ++i) {
        float rgb[3] = {0, 0, 0};
        float weight_sum = 0;
        for (int b = 0; b < 4; ++b) {
          const int fj = std::clamp(2 * j - 1 + b, 0, fh - 1);
          for (int a = 0; a < 4; ++a) {
            const int fi = std::clamp(2 * i - 1 + a, 0, fw - 1);
            const float wgt = kTap[a] * kTap[b];
            const float* src = &fine.color[(static_cast<size_t>(fj) * fw + fi) * 3];
            for (int k = 0; k < 3; ++k) rgb[k] += wgt * src[k];
            weight_sum += wgt;
          }
        }
        float* dst = &c.color[(static_cast<size_t>(j) * w + i) * 3];
        for (int k = 0; k < 3; ++k) dst[k] = rgb[k] / weight_sum;
        if (!fine.has_depth()) continue;
        // Depth: the nearest valid sample of the inner 2x2 block is the reference; only samples
        // within depth_edge_threshold of it are averaged, so silhouettes do not blend with the
        // background into phantom surfaces.
        float nearest = std::numeric_limits<float>::infinity();
        for (int b = 1; b <= 2; ++b) {
          for (int a = 1; a <= 2; ++a) {
            const int fi = std::min(2 * i - 1 + a, fw - 1), fj = std::min(2 * j - 1 + b, fh - 1);
            if (fine.depth_valid(fi, fj)) nearest = std::min(nearest, fine.depth[static_cast<size_t>(fj) * fw + fi]);
          }
        }
        if (!std::isfinite(nearest)) continue;
        float dsum = 0, dw = 0;
        for (int b = 0; b < 4; ++b) {
          const int fj = std::clamp(2 * j - 1 + b, 0, fh - 1);
          for (int a = 0; a < 4; ++a) {
            const int fi = std::clamp(2 * i - 1 + a, 0, fw - 1);
            if (!fine.depth_valid(fi, fj)) continue;
            const float d = fine.depth[static_cast<size_t>(fj) * fw + fi];
            if (std::abs(d - nearest) > options.depth_edge_threshold) continue;
            dsum += kTap[a] * kTap[b] * d;
            dw += kTap[a] * kTap[b];
          }
        }
        c.depth[static_cast<size_t>(j) * w + i] = dsum / dw;
      }
    }
  });
  c.landmarks = fine.landmarks;
  for (auto& l : c.landmarks) l.position = (l.position.array() + 0.5f) * 0.5f - 0.5f;
  return c;
}

}  // namespace

bool InputFrame::depth_valid(int i, int j) const {
  if (depth.empty() || i < 0 || j < 0 || i >= camera.width || j >= camera.height) return false;
  const float d = depth[static_cast<size_t>(j) * camera.width + i];
  return std::isfinite(d) && d > camera.near_plane && d < camera.far_plane;
}

Eigen::Vector3d InputFrame::point(int i, int j) const {
  const double z = depth[static_cast<size_t>(j) * camera.width + i];
  return {(i - camera.cx) * z / camera.fx, (j - camera.cy) * z / camera.fy, z};
}

bool InputFrame::IsValid(std::string* why) const {
  if (!camera.IsValid(why)) return false;
  const size_t n = pixel_count(camera);
  if (color.size() != 3 * n) {
    return fail(why, "input frame: colour has " + std::to_string(color.size()) + " values, " +
                         std::to_string(3 * n) + " expected (3 per pixel)");
  }
  for (float v : color) {
    if (!std::isfinite(v)) return fail(why, "input frame: colour contains NaN or infinity");
  }
  if (!depth.empty() && depth.size() != n) {
    return fail(why, "input frame: depth has " + std::to_string(depth.size()) + " values, " + std::to_string(n) +
                         " expected (1 per pixel, or none)");
  }
  for (const auto& l : landmarks) {
    if (l.ibug_index < 0 || l.ibug_index > 67) return fail(why, "input frame: landmark index outside 0..67");
    if (!l.position.allFinite() || !std::isfinite(l.confidence) || l.confidence < 0.f) {
      return fail(why, "input frame: landmark " + std::to_string(l.ibug_index) + " has a non-finite position or bad confidence");
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
  if (levels < 1 || levels > 8) return fail(why, "pyramid: levels must be 1..8");
  if (!(depth_edge_threshold > 0.f)) return fail(why, "pyramid: depth_edge_threshold must be positive");
  return true;
}

std::vector<InputFrame> BuildPyramid(const InputFrame& frame, const PyramidOptions& options, int threads,
                                     bool keep_level0) {
  std::string why;
  if (!options.IsValid(&why)) throw Error(why);
  if (!frame.IsValid(&why)) throw Error(why);
  std::vector<InputFrame> levels;
  levels.reserve(options.levels);
  if (keep_level0) {
    levels.push_back(frame);
  } else {
    InputFrame header;
    header.camera = frame.camera;
    header.landmarks = frame.landmarks;
    header.timestamp_s = frame.timestamp_s;
    header.new_face = frame.new_face;
    levels.push_back(std::move(header));
  }
  for (int l = 1; l < options.levels; ++l) {
    const InputFrame& finer = l == 1 ? frame : levels.back();
    if (finer.width() < 2 || finer.height() < 2) {
      throw Error("pyramid: a " + std::to_string(frame.width()) + "x" + std::to_string(frame.height()) +
                  " frame is too small for " + std::to_string(options.levels) + " levels");
    }
    levels.push_back(downsample(finer, options, threads));
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
