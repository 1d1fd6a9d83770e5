#pragma once
// A consumer structured-light RGB-D sensor (Kinect v1 / PrimeSense Carmine class) applied to
// ideal renderings: what turns a synthetic G-buffer into frames that look like real data.
// docs/recording-format.md (section "Sensor model") lists every effect and parameter.
//
// Depth, in order:
//   1. range: no data nearer than min_range_m or farther than max_range_m;
//   2. projector shadows: the IR projector sits baseline_m to the right of the depth camera
//      (+x); surfaces it cannot light (left of foreground edges) get no data;
//   3. grazing angles: no data where the surface is seen at more than grazing_limit_deg from
//      its normal, randomly thinning from grazing_onset_deg;
//   4. edge dropout: pixels next to a depth jump above edge_jump_m lose data with probability
//      edge_dropout;
//   5. small holes: hole_rate holes per megapixel, 1-3 px radius;
//   6. disparity noise and quantisation: d = fx b / z gets Gaussian noise with
//      sigma_d = depth_sigma_coefficient * fx * b (so sigma_z ~ depth_sigma_coefficient * z^2,
//      half of it shared by 4x4 pixel blocks as in the real sensor's correlation window) and is
//      rounded to 1 / disparity_subpixels pixel before converting back to depth.
// Colour: per-frame exposure and white-balance gains (slow random walks), a slight Gaussian
// blur, vignetting, sRGB encoding, signal-dependent (shot) and constant (read) noise, 8 bits.
// Every random draw comes from (seed, frame, stream) through a counter-based generator, so a
// frame's output depends only on its inputs, the seed and its index.
#include <algorithm>
#include <cstdint>
#include <string>

#include <opencv2/core.hpp>

namespace face_reenact::capture {

struct SensorModelOptions {
  // depth
  double baseline_m = 0.075;
  double min_range_m = 0.5;
  double max_range_m = 4.0;
  double depth_sigma_coefficient = 1.4e-3;  // sigma_z ~ k z^2 (m)
  int disparity_subpixels = 8;              // disparity steps per pixel (Kinect v1: 1/8 px)
  double grazing_onset_deg = 68.0;
  double grazing_limit_deg = 80.0;
  double edge_jump_m = 0.04;
  double edge_dropout = 0.5;
  double hole_rate = 60.0;                  // holes per megapixel per frame
  bool projector_shadows = true;
  // colour
  double blur_sigma_px = 0.6;
  double read_noise = 1.2;        // 8-bit units
  double shot_noise = 0.35;       // variance per unit of signal (8-bit units)
  double exposure_drift = 0.04;   // per-second standard deviation of log exposure
  double white_balance_drift = 0.02;
  double vignetting = 0.25;       // brightness lost at the image corners

  bool IsValid(std::string* why) const;
};

// Ideal inputs of one frame at the output resolution.
struct IdealFrame {
  cv::Mat linear_rgb;   // CV_32FC3, linear RGB (R, G, B order), 1 = white
  cv::Mat depth;        // CV_32FC1, metres along the optical axis, 0 = nothing (sky)
  cv::Mat view_cosine;  // CV_32FC1, |cos| of the angle between surface normal and viewing ray
};

class SensorModel {
 public:
  SensorModel(const SensorModelOptions& options, uint64_t seed, double fps);
  const SensorModelOptions& options() const { return options_; }

  // Depth as the sensor would measure it (metres, 0 = no data). fx is the depth camera's focal
  // length in pixels (the disparity scale).
  cv::Mat measure_depth(const IdealFrame& ideal, double fx, int frame_index) const;
  // 8-bit BGR colour as the sensor's RGB camera would deliver it.
  cv::Mat measure_color(const IdealFrame& ideal, int frame_index) const;

  // The slowly varying per-frame camera state (exposure and white-balance gains).
  struct ColorState {
    double exposure = 1.0;
    double gain_r = 1.0, gain_g = 1.0, gain_b = 1.0;
  };
  ColorState color_state(int frame_index) const;

 private:
  SensorModelOptions options_;
  uint64_t seed_;
  double fps_;
};

// Counter-based random numbers (SplitMix64 of a key), the same on every platform.
uint64_t hash_key(uint64_t a, uint64_t b = 0, uint64_t c = 0, uint64_t d = 0);
double uniform01(uint64_t key);  // [0, 1)
double gaussian(uint64_t key);   // standard normal (Box-Muller of two derived uniforms)
// Smooth noise of unit variance over time t: cosine interpolation of Gaussian knots `period` apart.
double smooth_noise(uint64_t key, double t, double period);
// 0 below 0, 1 above 1, Hermite-eased in between (the synthetic actor's fades and turns).
inline double smoothstep01(double x) {
  x = std::clamp(x, 0.0, 1.0);
  return x * x * (3 - 2 * x);
}

}  // namespace face_reenact::capture
