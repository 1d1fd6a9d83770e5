// Statistics of the structured-light sensor model: noise growing with z^2, quantisation on the
// disparity grid, shadows left of foreground edges, range and grazing-angle dropouts, and
// determinism per seed.
#include <cmath>
#include <cstdio>
#include <vector>

#include "capture_test_support.h"
#include "face_reenact/capture/sensor_model.h"
#include "face_reenact/common/error.h"

namespace face_reenact::capture {
namespace {

constexpr double kFx = 525.0;

IdealFrame flat(int w, int h, float z) {
  IdealFrame f;
  f.depth = cv::Mat(h, w, CV_32FC1, cv::Scalar(z));
  f.view_cosine = cv::Mat(h, w, CV_32FC1, cv::Scalar(1.0));
  f.linear_rgb = cv::Mat(h, w, CV_32FC3, cv::Scalar(0.2, 0.2, 0.2));
  return f;
}

SensorModelOptions no_dropouts() {
  SensorModelOptions o;
  o.hole_rate = 0;
  o.edge_dropout = 0;
  return o;
}

struct Stats {
  double mean = 0, sd = 0;
  int valid = 0;
};

Stats error_stats(const cv::Mat& measured, float truth) {
  Stats s;
  double sum = 0, sum2 = 0;
  for (int y = 0; y < measured.rows; ++y)
    for (int x = 0; x < measured.cols; ++x) {
      const float z = measured.at<float>(y, x);
      if (!(z > 0)) continue;
      const double e = z - truth;
      sum += e;
      sum2 += e * e;
      ++s.valid;
    }
  s.mean = sum / s.valid;
  s.sd = std::sqrt(sum2 / s.valid - s.mean * s.mean);
  return s;
}

TEST(CaptureSensorModelTest, DepthNoiseGrowsWithDistanceSquared) {
  const SensorModel sensor(no_dropouts(), 7, 30);
  std::vector<double> sd;
  for (float z : {1.0f, 2.0f, 3.0f}) {
    const Stats s = error_stats(sensor.measure_depth(flat(200, 160, z), kFx, 0), z);
    EXPECT_EQ(s.valid, 200 * 160) << "no dropouts configured, yet pixels missing at " << z << " m";
    // Disparity rounding may bias by at most half a quantisation step; noise averages out.
    const double step = z * z / (kFx * 0.075 * 8);
    EXPECT_LT(std::abs(s.mean), 0.5 * step + 0.001) << "at " << z << " m";
    sd.push_back(s.sd);
  }
  std::printf("depth error sd: %.2f mm at 1 m, %.2f mm at 2 m, %.2f mm at 3 m\n", 1e3 * sd[0], 1e3 * sd[1], 1e3 * sd[2]);
  // sigma_z = 1.4e-3 z^2 plus quantisation (step z^2 / (8 fx b)): both scale with z^2.
  EXPECT_NEAR(sd[0], 1.4e-3, 0.8e-3);
  EXPECT_GT(sd[1] / sd[0], 3.0);
  EXPECT_LT(sd[1] / sd[0], 5.5);
  EXPECT_GT(sd[2] / sd[0], 6.5);
  EXPECT_LT(sd[2] / sd[0], 12.0);
}

TEST(CaptureSensorModelTest, DepthLiesOnTheDisparityGrid) {
  const SensorModel sensor(no_dropouts(), 3, 30);
  const cv::Mat d = sensor.measure_depth(flat(64, 48, 2.5f), kFx, 4);
  const double fb = kFx * 0.075;
  for (int y = 0; y < d.rows; ++y)
    for (int x = 0; x < d.cols; ++x) {
      const double sub = fb / d.at<float>(y, x) * 8.0;
      ASSERT_NEAR(sub, std::round(sub), 2e-3) << "depth " << d.at<float>(y, x) << " is not on the 1/8 px disparity grid";
    }
}

TEST(CaptureSensorModelTest, ShadowsAndHolesAtSilhouettes) {
  // A 1 m square in front of a 2.5 m wall.
  IdealFrame f = flat(320, 120, 2.5f);
  const int left = 120, right = 220;
  f.depth(cv::Rect(left, 20, right - left, 80)).setTo(1.0f);
  SensorModelOptions o;
  o.hole_rate = 0;
  const SensorModel sensor(o, 11, 30);
  const cv::Mat d = sensor.measure_depth(f, kFx, 0);
  // Shadow width fb (1/z_fg - 1/z_bg) = 23.6 px, left of the square, on every covered row.
  const double width = kFx * 0.075 * (1.0 / 1.0 - 1.0 / 2.5);
  for (int y = 25; y < 95; ++y) {
    for (int x = left - static_cast<int>(width) + 2; x < left - 1; ++x)
      ASSERT_EQ(d.at<float>(y, x), 0.0f) << "expected projector shadow at " << x << "," << y;
    EXPECT_GT(d.at<float>(y, left - static_cast<int>(width) - 3), 0.0f) << "shadow too wide on row " << y;
    // The far side of the square (the projector side) casts no shadow.
    EXPECT_GT(d.at<float>(y, right + 3), 0.0f);
    EXPECT_GT(d.at<float>(y, (left + right) / 2), 0.0f);
  }
  // Edge dropout thins the silhouette: some, not all, pixels along the right edge are missing.
  int missing = 0;
  for (int y = 25; y < 95; ++y) missing += d.at<float>(y, right - 1) == 0.0f;
  EXPECT_GT(missing, 10);
  EXPECT_LT(missing, 60);
  // Switching shadows off restores the wall.
  o.projector_shadows = false;
  o.edge_dropout = 0;
  const cv::Mat d2 = SensorModel(o, 11, 30).measure_depth(f, kFx, 0);
  EXPECT_EQ(cv::countNonZero(d2), d2.rows * d2.cols);
}

TEST(CaptureSensorModelTest, RangeGrazingAndHoles) {
  SensorModelOptions o = no_dropouts();
  const SensorModel sensor(o, 1, 30);
  EXPECT_EQ(cv::countNonZero(sensor.measure_depth(flat(40, 30, 4.5f), kFx, 0)), 0);
  EXPECT_EQ(cv::countNonZero(sensor.measure_depth(flat(40, 30, 0.3f), kFx, 0)), 0);
  IdealFrame graze = flat(40, 30, 1.5f);
  graze.view_cosine.setTo(0.1);  // 84 degrees
  EXPECT_EQ(cv::countNonZero(sensor.measure_depth(graze, kFx, 0)), 0);
  graze.view_cosine.setTo(std::cos(74.0 * M_PI / 180.0));  // between onset and limit: thinned
  const int kept = cv::countNonZero(sensor.measure_depth(graze, kFx, 0));
  EXPECT_GT(kept, 40 * 30 / 10);
  EXPECT_LT(kept, 40 * 30 * 9 / 10);
  IdealFrame sky = flat(40, 30, 1.5f);
  sky.depth(cv::Rect(0, 0, 10, 10)).setTo(0.0f);
  EXPECT_EQ(cv::countNonZero(sensor.measure_depth(sky, kFx, 0)(cv::Rect(0, 0, 10, 10))), 0);
  o.hole_rate = 2000;  // holes per megapixel
  const cv::Mat holes = SensorModel(o, 1, 30).measure_depth(flat(400, 300, 1.5f), kFx, 0);
  const int missing = 400 * 300 - cv::countNonZero(holes);
  EXPECT_GT(missing, 240 * 3);   // 240 holes of at least 5 px (some overlap)
  EXPECT_LT(missing, 240 * 30);
}

TEST(CaptureSensorModelTest, DeterministicPerSeedAndFrame) {
  SensorModelOptions o;
  IdealFrame f = flat(80, 60, 1.2f);
  f.depth(cv::Rect(30, 20, 20, 20)).setTo(0.8f);
  const SensorModel a(o, 42, 30), b(o, 42, 30), c(o, 43, 30);
  EXPECT_EQ(cv::norm(a.measure_depth(f, kFx, 5), b.measure_depth(f, kFx, 5), cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(a.measure_color(f, 5), b.measure_color(f, 5), cv::NORM_INF), 0.0);
  EXPECT_GT(cv::norm(a.measure_depth(f, kFx, 5), a.measure_depth(f, kFx, 6), cv::NORM_L1), 0.0);
  EXPECT_GT(cv::norm(a.measure_depth(f, kFx, 5), c.measure_depth(f, kFx, 5), cv::NORM_L1), 0.0);
  EXPECT_GT(cv::norm(a.measure_color(f, 5), c.measure_color(f, 5), cv::NORM_L1), 0.0);
}

TEST(CaptureSensorModelTest, ColourNoiseExposureAndWhiteBalance) {
  SensorModelOptions o;
  o.vignetting = 0;
  o.exposure_drift = 0;
  o.white_balance_drift = 0;
  o.blur_sigma_px = 0;
  const SensorModel sensor(o, 9, 30);
  IdealFrame f = flat(100, 100, 1.0f);
  f.linear_rgb.setTo(cv::Scalar(0.2140, 0.2140, 0.2140));  // sRGB 0.5 -> 127.5
  const cv::Mat c = sensor.measure_color(f, 0);
  cv::Scalar mean, sd;
  cv::meanStdDev(c, mean, sd);
  for (int ch = 0; ch < 3; ++ch) {
    EXPECT_NEAR(mean[ch], 127.5, 1.0);
    const double expected = std::sqrt(o.read_noise * o.read_noise + o.shot_noise * 127.5);
    EXPECT_NEAR(sd[ch], expected, 0.25 * expected);
  }
  // With drift on, the gains move smoothly and stay within a few standard deviations.
  const SensorModel drifting(SensorModelOptions(), 9, 30);
  double previous = drifting.color_state(0).exposure, max_step = 0, lo = 10, hi = 0;
  for (int i = 1; i < 600; ++i) {
    const auto s = drifting.color_state(i);
    max_step = std::max(max_step, std::abs(s.exposure - previous));
    previous = s.exposure;
    lo = std::min(lo, s.exposure);
    hi = std::max(hi, s.exposure);
    EXPECT_GT(s.gain_r, 0.8);
    EXPECT_LT(s.gain_b, 1.25);
  }
  EXPECT_LT(max_step, 0.01);  // no jumps between frames
  EXPECT_GT(hi - lo, 0.01);   // but it does change over 20 s
  EXPECT_LT(hi, 1.5);
  EXPECT_GT(lo, 0.66);
}

TEST(CaptureSensorModelTest, InvalidOptionsAndInputs) {
  SensorModelOptions o;
  std::string why;
  EXPECT_TRUE(o.IsValid(&why)) << why;
  o.max_range_m = 0.2;
  EXPECT_FALSE(o.IsValid(&why));
  EXPECT_THROW_WITH(SensorModel(o, 1, 30), "max_range_m");
  o = SensorModelOptions();
  o.depth_sigma_coefficient = std::nan("");
  EXPECT_FALSE(o.IsValid(&why));
  o = SensorModelOptions();
  o.disparity_subpixels = 0;
  EXPECT_FALSE(o.IsValid(&why));
  EXPECT_THROW(SensorModel(SensorModelOptions(), 1, 0), Error);
  const SensorModel sensor(SensorModelOptions(), 1, 30);
  IdealFrame f = flat(8, 8, 1.0f);
  f.depth.convertTo(f.depth, CV_16UC1);
  EXPECT_THROW(sensor.measure_depth(f, kFx, 0), Error);
  f = flat(8, 8, 1.0f);
  f.view_cosine = cv::Mat(4, 4, CV_32FC1, cv::Scalar(1));
  EXPECT_THROW(sensor.measure_depth(f, kFx, 0), Error);
  EXPECT_THROW(sensor.measure_depth(flat(8, 8, 1.0f), -1.0, 0), Error);
  f = flat(8, 8, 1.0f);
  f.linear_rgb.convertTo(f.linear_rgb, CV_8UC3);
  EXPECT_THROW(sensor.measure_color(f, 0), Error);
}

}  // namespace
}  // namespace face_reenact::capture
