#include "face_reenact/tracker/depth_alignment.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "face_reenact/common/srgb.h"
#include "tracker_internal.h"


namespace face_reenact::tracker {
using internal::format;

bool DepthAlignmentOptions::IsValid(std::string* why) const {
  auto fail = [&](const char* m) {
    if (why) *why = std::string("depth alignment options: ") + m;
    return false;
  };
  if (!(max_shift_px >= 1.0 && max_shift_px <= 64.0)) return fail("max_shift_px must be in [1, 64]");
  if (!(min_shift_px > 0.0 && min_shift_px <= max_shift_px)) return fail("min_shift_px must be in (0, max_shift_px]");
  if (!(min_gain >= 1.0)) return fail("min_gain must be >= 1");
  if (!(depth_jump_m > 0.f)) return fail("depth_jump_m must be > 0");
  if (min_edge_pixels < 1) return fail("min_edge_pixels must be >= 1");
  return true;
}

DepthAlignment MeasureDepthAlignment(const InputFrame& frame, const DepthAlignmentOptions& options) {
  DepthAlignment r;
  std::string why;
  if (!options.IsValid(&why)) {
    r.message = why;
    return r;
  }
  if (!frame.has_depth()) {
    r.message = "no depth";
    return r;
  }
  const int w = frame.width(), h = frame.height();
  if (w < 8 || h < 8 || frame.depth.size() != size_t(w) * size_t(h) || frame.color.size() != 3 * size_t(w) * size_t(h)) {
    r.message = "the frame's colour and depth do not match its size";
    return r;
  }
  // The region: around the confident landmarks, or the whole frame.
  float x0 = float(w), y0 = float(h), x1 = -1.f, y1 = -1.f;
  for (const InputLandmark& l : frame.landmarks) {
    if (!(l.confidence > 0.f) || !l.position.allFinite()) continue;
    x0 = std::min(x0, l.position.x());
    y0 = std::min(y0, l.position.y());
    x1 = std::max(x1, l.position.x());
    y1 = std::max(y1, l.position.y());
  }
  int rx0 = 0, ry0 = 0, rx1 = w, ry1 = h;
  if (x1 > x0 && y1 > y0) {
    const float mx = 0.5f * (x1 - x0), my = 0.5f * (y1 - y0);
    rx0 = std::max(0, int(std::floor(x0 - mx)));
    ry0 = std::max(0, int(std::floor(y0 - my)));
    rx1 = std::min(w, int(std::ceil(x1 + mx)) + 1);
    ry1 = std::min(h, int(std::ceil(y1 + my)) + 1);
  }
  const int s = std::max(1, int(std::lround(options.max_shift_px * w / 640.0)));
  // The colour's gradient magnitude (luminance, central differences) over the region and the
  // shifts around it.
  const int gx0 = std::max(1, rx0 - s), gy0 = std::max(1, ry0 - s), gx1 = std::min(w - 1, rx1 + s),
            gy1 = std::min(h - 1, ry1 + s);
  std::vector<float> grad(size_t(w) * size_t(h), 0.f);
  auto luminance = [&](int i, int j) {
    const float* c = &frame.color[3 * (size_t(j) * w + i)];
    const float l = linear_luminance(c[0], c[1], c[2]);
    return std::isfinite(l) ? std::sqrt(std::max(l, 0.f)) : 0.f;  // a perceptual scale: shadows count too
  };
  for (int j = gy0; j < gy1; ++j)
    for (int i = gx0; i < gx1; ++i) {
      const float dx = luminance(i + 1, j) - luminance(i - 1, j), dy = luminance(i, j + 1) - luminance(i, j - 1);
      grad[size_t(j) * w + i] = std::sqrt(dx * dx + dy * dy);
    }
  // The depth's foreground edges.
  std::vector<int> edges;
  for (int j = std::max(1, ry0); j < std::min(h - 1, ry1); ++j)
    for (int i = std::max(1, rx0); i < std::min(w - 1, rx1); ++i) {
      if (!frame.depth_valid(i, j)) continue;
      const float d = frame.depth[size_t(j) * w + i];
      bool edge = false;
      for (const auto& [di, dj] : {std::pair{1, 0}, std::pair{-1, 0}, std::pair{0, 1}, std::pair{0, -1}}) {
        if (!frame.depth_valid(i + di, j + dj) || frame.depth[size_t(j + dj) * w + i + di] > d + options.depth_jump_m) {
          edge = true;
          break;
        }
      }
      if (edge) edges.push_back(j * w + i);
    }
  r.edge_pixels = int(edges.size());
  if (r.edge_pixels < options.min_edge_pixels) {
    r.message = format("too few depth edges (%d) to measure", r.edge_pixels);
    return r;
  }
  auto agreement = [&](int sx, int sy) {
    double sum = 0;
    int n = 0;
    for (int p : edges) {
      const int i = p % w + sx, j = p / w + sy;
      if (i < 0 || j < 0 || i >= w || j >= h) continue;
      sum += grad[size_t(j) * w + i];
      ++n;
    }
    return n > 0 ? sum / n : 0.0;
  };
  r.agreement_unshifted = agreement(0, 0);
  r.agreement_best = r.agreement_unshifted;
  for (int sy = -s; sy <= s; ++sy)
    for (int sx = -s; sx <= s; ++sx) {
      const double a = agreement(sx, sy);
      if (a > r.agreement_best) {
        r.agreement_best = a;
        r.shift_x = sx;
        r.shift_y = sy;
      }
    }
  r.measured = true;
  const double shift_640 = std::hypot(double(r.shift_x), double(r.shift_y)) * 640.0 / w;
  r.misaligned = shift_640 >= options.min_shift_px && r.agreement_best >= options.min_gain * r.agreement_unshifted;
  r.message = r.misaligned ? format("the depth looks %d px %s and %d px %s of the colour (its edges match the colour's %.1fx better "
                                    "shifted): is the depth registered to the colour?",
                                    std::abs(r.shift_x), r.shift_x > 0 ? "left" : "right", std::abs(r.shift_y),
                                    r.shift_y > 0 ? "up" : "down",
                                    r.agreement_unshifted > 0 ? r.agreement_best / r.agreement_unshifted : 0.0)
                           : format("depth and colour edges agree (best shift %d, %d px)", r.shift_x, r.shift_y);
  return r;
}

}  // namespace face_reenact::tracker
