#include "face_reenact/capture/sensor_model.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "face_reenact/common/error.h"
#include "face_reenact/common/srgb.h"

namespace face_reenact::capture {
namespace {

uint64_t splitmix(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

// Random streams, so that effects never share draws.
enum SensorNoiseStream : uint64_t {
  kNoisePixel = 1,
  kNoiseBlock,
  kGrazing,
  kEdge,
  kHoles,
  kColorNoise,
  kExposure,
  kWhiteBalance,
};


}  // namespace

uint64_t hash_key(uint64_t a, uint64_t b, uint64_t c, uint64_t d) {
  uint64_t h = splitmix(a);
  h = splitmix(h ^ b);
  h = splitmix(h ^ (c * 0xD6E8FEB86659FD93ull));
  return splitmix(h ^ (d * 0xA0761D6478BD642Full));
}

double uniform01(uint64_t key) { return static_cast<double>(splitmix(key) >> 11) * 0x1.0p-53; }

double gaussian(uint64_t key) {
  const double u1 = 1.0 - uniform01(key ^ 0x5555555555555555ull);  // (0, 1]
  const double u2 = uniform01(key ^ 0xAAAAAAAAAAAAAAAAull);
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * M_PI * u2);
}

double smooth_noise(uint64_t key, double t, double period) {
  const double s = t / period;
  const double k = std::floor(s);
  const double f = s - k;
  const double a = gaussian(hash_key(key, static_cast<uint64_t>(static_cast<int64_t>(k))));
  const double b = gaussian(hash_key(key, static_cast<uint64_t>(static_cast<int64_t>(k) + 1)));
  const double w = 0.5 - 0.5 * std::cos(M_PI * f);
  // Renormalise: the blend of two independent unit Gaussians has variance (1-w)^2 + w^2.
  return ((1 - w) * a + w * b) / std::sqrt((1 - w) * (1 - w) + w * w);
}

bool SensorModelOptions::IsValid(std::string* why) const {
  auto finite = [](double v) { return std::isfinite(v); };
  if (!(finite(baseline_m) && baseline_m > 0 && baseline_m < 1)) return fail_why(why, "baseline_m must be in (0, 1)");
  if (!(min_range_m >= 0 && max_range_m > min_range_m && max_range_m < 100))
    return fail_why(why, "need 0 <= min_range_m < max_range_m < 100");
  if (!(depth_sigma_coefficient >= 0 && depth_sigma_coefficient < 0.1))
    return fail_why(why, "depth_sigma_coefficient must be in [0, 0.1)");
  if (disparity_subpixels < 1 || disparity_subpixels > 1024) return fail_why(why, "disparity_subpixels must be in 1..1024");
  if (!(grazing_onset_deg > 0 && grazing_limit_deg >= grazing_onset_deg && grazing_limit_deg <= 90))
    return fail_why(why, "need 0 < grazing_onset_deg <= grazing_limit_deg <= 90");
  if (!(edge_jump_m > 0 && finite(edge_jump_m))) return fail_why(why, "edge_jump_m must be > 0");
  if (!(edge_dropout >= 0 && edge_dropout <= 1)) return fail_why(why, "edge_dropout must be in [0, 1]");
  if (!(hole_rate >= 0 && hole_rate <= 1e5)) return fail_why(why, "hole_rate must be in [0, 1e5]");
  if (!(blur_sigma_px >= 0 && blur_sigma_px <= 10)) return fail_why(why, "blur_sigma_px must be in [0, 10]");
  if (!(read_noise >= 0 && read_noise <= 50 && shot_noise >= 0 && shot_noise <= 50))
    return fail_why(why, "read_noise and shot_noise must be in [0, 50]");
  if (!(exposure_drift >= 0 && exposure_drift <= 1 && white_balance_drift >= 0 && white_balance_drift <= 1))
    return fail_why(why, "exposure_drift and white_balance_drift must be in [0, 1]");
  if (!(vignetting >= 0 && vignetting < 1)) return fail_why(why, "vignetting must be in [0, 1)");
  return true;
}

SensorModel::SensorModel(const SensorModelOptions& options, uint64_t seed, double fps)
    : options_(options), seed_(seed), fps_(fps) {
  std::string why;
  if (!options.IsValid(&why)) throw Error("sensor model: " + why);
  if (!(fps > 0 && fps <= 1000)) throw Error("sensor model: fps must be in (0, 1000]");
}

SensorModel::ColorState SensorModel::color_state(int frame_index) const {
  const double t = frame_index / fps_;
  ColorState s;
  // Auto exposure hunts slowly (a few seconds); white balance wanders more slowly still.
  s.exposure = std::exp(options_.exposure_drift * 2.0 * smooth_noise(hash_key(seed_, kExposure), t, 2.5));
  const double wb = options_.white_balance_drift * 2.0;
  s.gain_r = std::exp(wb * smooth_noise(hash_key(seed_, kWhiteBalance, 0), t, 4.0));
  s.gain_g = 1.0;
  s.gain_b = std::exp(wb * smooth_noise(hash_key(seed_, kWhiteBalance, 2), t, 4.0));
  return s;
}

cv::Mat SensorModel::measure_depth(const IdealFrame& ideal, double fx, int frame_index) const {
  if (ideal.depth.type() != CV_32FC1) throw Error("sensor model: ideal depth must be CV_32FC1");
  if (!ideal.view_cosine.empty() && (ideal.view_cosine.type() != CV_32FC1 || ideal.view_cosine.size() != ideal.depth.size()))
    throw Error("sensor model: view cosine must be CV_32FC1 of the depth's size");
  if (!(fx > 0 && std::isfinite(fx))) throw Error("sensor model: fx must be positive");
  const int w = ideal.depth.cols, h = ideal.depth.rows;
  const SensorModelOptions& o = options_;
  const uint64_t fkey = hash_key(seed_, static_cast<uint64_t>(frame_index));
  cv::Mat out(h, w, CV_32FC1, cv::Scalar(0));
  std::vector<uint8_t> keep(static_cast<size_t>(w) * h, 0);
  const double fb = fx * o.baseline_m;
  const double onset = std::cos(o.grazing_onset_deg * M_PI / 180.0);
  const double limit = std::cos(o.grazing_limit_deg * M_PI / 180.0);

  for (int y = 0; y < h; ++y) {
    const float* z = ideal.depth.ptr<float>(y);
    const float* vc = ideal.view_cosine.empty() ? nullptr : ideal.view_cosine.ptr<float>(y);
    // 2. The projector, baseline_m to the right, sees a point at u_p = u - fb / z. Scanning
    // right to left, a point whose u_p lies right of the smallest u_p seen so far is hidden
    // from the projector by a nearer surface to its right: the shadow falls left of edges.
    double min_projector_u = 1e30;
    for (int x = w - 1; x >= 0; --x) {
      const double zi = z[x];
      if (!(zi > 0) || !std::isfinite(zi)) continue;
      const double up = x - fb / zi;
      const bool shadowed = o.projector_shadows && up > min_projector_u + 0.25;
      min_projector_u = std::min(min_projector_u, up);
      if (shadowed) continue;
      if (zi < o.min_range_m || zi > o.max_range_m) continue;  // 1.
      if (vc) {                                                // 3.
        const double c = vc[x];
        if (c < limit) continue;
        if (c < onset && uniform01(hash_key(fkey, kGrazing, static_cast<uint64_t>(y) * w + x)) < (onset - c) / (onset - limit))
          continue;
      }
      if (o.edge_dropout > 0) {  // 4.
        bool edge = false;
        const int nx[4] = {x - 1, x + 1, x, x};
        const int ny[4] = {y, y, y - 1, y + 1};
        for (int k = 0; k < 4 && !edge; ++k) {
          if (nx[k] < 0 || ny[k] < 0 || nx[k] >= w || ny[k] >= h) continue;
          const float zn = ideal.depth.at<float>(ny[k], nx[k]);
          edge = !(zn > 0) || std::abs(zn - zi) > o.edge_jump_m;
        }
        if (edge && uniform01(hash_key(fkey, kEdge, static_cast<uint64_t>(y) * w + x)) < o.edge_dropout) continue;
      }
      keep[static_cast<size_t>(y) * w + x] = 1;
    }
  }
  // 5. Small holes.
  const double expected = o.hole_rate * w * h / 1e6;
  const int holes = static_cast<int>(expected) + (uniform01(hash_key(fkey, kHoles)) < expected - std::floor(expected) ? 1 : 0);
  for (int i = 0; i < holes; ++i) {
    const int cx = static_cast<int>(uniform01(hash_key(fkey, kHoles, i, 1)) * w);
    const int cy = static_cast<int>(uniform01(hash_key(fkey, kHoles, i, 2)) * h);
    const int r = 1 + static_cast<int>(uniform01(hash_key(fkey, kHoles, i, 3)) * 3);
    for (int y = std::max(0, cy - r); y <= std::min(h - 1, cy + r); ++y)
      for (int x = std::max(0, cx - r); x <= std::min(w - 1, cx + r); ++x)
        if ((x - cx) * (x - cx) + (y - cy) * (y - cy) <= r * r) keep[static_cast<size_t>(y) * w + x] = 0;
  }
  // 6. Disparity noise and quantisation.
  const double sigma_d = o.depth_sigma_coefficient * fb;
  const double sub = o.disparity_subpixels;
  for (int y = 0; y < h; ++y) {
    const float* z = ideal.depth.ptr<float>(y);
    float* dst = out.ptr<float>(y);
    for (int x = 0; x < w; ++x) {
      if (!keep[static_cast<size_t>(y) * w + x]) continue;
      const double d = fb / z[x];
      const double n = sigma_d * (M_SQRT1_2 * gaussian(hash_key(fkey, kNoisePixel, static_cast<uint64_t>(y) * w + x)) +
                                  M_SQRT1_2 * gaussian(hash_key(fkey, kNoiseBlock, static_cast<uint64_t>(y / 4) * w + x / 4)));
      const double dq = std::round((d + n) * sub) / sub;
      if (dq <= 0) continue;
      const double zq = fb / dq;
      if (zq >= o.min_range_m && zq <= o.max_range_m) dst[x] = static_cast<float>(zq);
    }
  }
  return out;
}

cv::Mat SensorModel::measure_color(const IdealFrame& ideal, int frame_index) const {
  if (ideal.linear_rgb.type() != CV_32FC3) throw Error("sensor model: ideal colour must be CV_32FC3");
  const SensorModelOptions& o = options_;
  const int w = ideal.linear_rgb.cols, h = ideal.linear_rgb.rows;
  const ColorState s = color_state(frame_index);
  cv::Mat lin;
  if (o.blur_sigma_px > 0) cv::GaussianBlur(ideal.linear_rgb, lin, cv::Size(0, 0), o.blur_sigma_px);
  else lin = ideal.linear_rgb;
  const uint64_t fkey = hash_key(seed_, static_cast<uint64_t>(frame_index), kColorNoise);
  cv::Mat out(h, w, CV_8UC3);
  const double gains[3] = {s.exposure * s.gain_r, s.exposure * s.gain_g, s.exposure * s.gain_b};
  const double half_diag2 = 0.25 * (double(w) * w + double(h) * h);
  for (int y = 0; y < h; ++y) {
    const cv::Vec3f* src = lin.ptr<cv::Vec3f>(y);
    cv::Vec3b* dst = out.ptr<cv::Vec3b>(y);
    for (int x = 0; x < w; ++x) {
      const double dx = x - 0.5 * (w - 1), dy = y - 0.5 * (h - 1);
      const double vig = 1.0 - o.vignetting * (dx * dx + dy * dy) / half_diag2;
      for (int c = 0; c < 3; ++c) {
        const double v = 255.0 * srgb_encode(src[x][c] * gains[c] * vig);
        const double sigma = std::sqrt(o.read_noise * o.read_noise + o.shot_noise * v);
        const double noisy = v + sigma * gaussian(hash_key(fkey, static_cast<uint64_t>(y) * w + x, static_cast<uint64_t>(c)));
        dst[x][2 - c] = static_cast<uint8_t>(std::clamp(std::lround(noisy), 0L, 255L));  // RGB -> BGR
      }
    }
  }
  return out;
}

}  // namespace face_reenact::capture
