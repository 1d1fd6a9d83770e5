// The Laplacian-pyramid blend (Sec. 7.4.2): exactness outside the blend region, no seam.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include <opencv2/imgproc.hpp>

#include "face_reenact/common/error.h"
#include "face_reenact/reenact/laplacian_blend.h"

namespace face_reenact::reenact {
namespace {

cv::Mat noise_image(int w, int h, uint32_t seed) {
  cv::Mat m(h, w, CV_8UC3);
  cv::RNG rng(seed);
  rng.fill(m, cv::RNG::UNIFORM, 0, 256);
  return m;
}

TEST(ReenactLaplacianBlendTest, ZeroMaskReturnsTheTargetExactly) {
  const cv::Mat target = noise_image(160, 120, 1), rendered = noise_image(160, 120, 2);
  LaplacianBlendSummary s;
  const cv::Mat out = LaplacianBlend(target, rendered, cv::Mat::zeros(120, 160, CV_32FC1), {}, &s);
  EXPECT_EQ(cv::norm(out, target, cv::NORM_INF), 0.0);
  EXPECT_TRUE(s.blend_region.empty());
}

TEST(ReenactLaplacianBlendTest, FullMaskReturnsTheRendered) {
  const cv::Mat target = noise_image(96, 64, 3), rendered = noise_image(96, 64, 4);
  const cv::Mat out = LaplacianBlend(target, rendered, cv::Mat(64, 96, CV_32FC1, cv::Scalar(1.0f)), {});
  EXPECT_LE(cv::norm(out, rendered, cv::NORM_INF), 1.0);  // 8-bit rounding
}

TEST(ReenactLaplacianBlendTest, OutsideTheBlendRegionTheOutputIsTheTarget) {
  const cv::Mat target = noise_image(320, 240, 5), rendered = noise_image(320, 240, 6);
  cv::Mat mask = cv::Mat::zeros(240, 320, CV_8UC1);
  cv::ellipse(mask, cv::Point(150, 110), cv::Size(30, 40), 0, 0, 360, cv::Scalar(255), cv::FILLED);
  LaplacianBlendOptions o;
  o.levels = 4;
  LaplacianBlendSummary s;
  const cv::Mat out = LaplacianBlend(target, rendered, mask, o, &s);
  ASSERT_FALSE(s.blend_region.empty());
  const int r = blend_support_radius(o.levels);
  EXPECT_LE(s.blend_region.width, 60 + 2 * r + 2);
  cv::Mat differs;
  cv::Mat diff;
  cv::absdiff(out, target, diff);
  cv::cvtColor(diff, diff, cv::COLOR_BGR2GRAY);
  differs = diff > 0;
  // Every changed pixel lies within the support radius of the mask.
  cv::Mat dist;
  cv::distanceTransform(mask == 0, dist, cv::DIST_L2, cv::DIST_MASK_PRECISE);
  for (int y = 0; y < 240; ++y)
    for (int x = 0; x < 320; ++x)
      if (differs.at<uchar>(y, x)) ASSERT_LE(dist.at<float>(y, x), static_cast<float>(r) + 0.5f) << x << "," << y;
  // Far away nothing changed at all, and inside the mask's core the rendered image shows.
  EXPECT_EQ(cv::norm(out(cv::Rect(250, 0, 70, 240)), target(cv::Rect(250, 0, 70, 240)), cv::NORM_INF), 0.0);
}

TEST(ReenactLaplacianBlendTest, NoStepAtTheMaskBoundary) {
  // Flat dark target, flat bright render, hard vertical mask edge: the blended profile must
  // climb gradually, never jumping by a large fraction of the contrast between two pixels.
  const int w = 256, h = 64;
  const cv::Mat target(h, w, CV_8UC3, cv::Scalar(40, 50, 60));
  const cv::Mat rendered(h, w, CV_8UC3, cv::Scalar(200, 190, 180));
  cv::Mat mask = cv::Mat::zeros(h, w, CV_32FC1);
  mask(cv::Rect(128, 0, 128, h)).setTo(1.0f);
  LaplacianBlendOptions o;
  o.levels = 5;
  const cv::Mat out = LaplacianBlend(target, rendered, mask, o);
  const cv::Mat plain = LaplacianBlend(target, rendered, mask, LaplacianBlendOptions{1});
  int max_step = 0, plain_step = 0;
  for (int x = 1; x < w; ++x) {
    max_step = std::max(max_step, std::abs(out.at<cv::Vec3b>(h / 2, x)[0] - out.at<cv::Vec3b>(h / 2, x - 1)[0]));
    plain_step = std::max(plain_step, std::abs(plain.at<cv::Vec3b>(h / 2, x)[0] - plain.at<cv::Vec3b>(h / 2, x - 1)[0]));
  }
  EXPECT_EQ(plain_step, 160);   // one level = a hard cut
  EXPECT_LE(max_step, 40);      // the pyramid spreads the 160-level step over many pixels
  // Monotonic (no ringing) and reaching both ends.
  for (int x = 1; x < w; ++x) EXPECT_GE(out.at<cv::Vec3b>(h / 2, x)[0] + 1, out.at<cv::Vec3b>(h / 2, x - 1)[0]);
  EXPECT_EQ(out.at<cv::Vec3b>(h / 2, 0)[0], 40);
  EXPECT_NEAR(out.at<cv::Vec3b>(h / 2, w - 1)[0], 200, 1);
}

// The blend's passes run on the pool (LaplacianBlendOptions::threads): the same bits for any
// thread count, on a face-sized mask whose rows and levels split unevenly into the pool's items.
TEST(ReenactLaplacianBlendTest, TheSameBitsOnAnyThreadCount) {
  const cv::Mat target = noise_image(333, 257, 11), rendered = noise_image(333, 257, 12);
  cv::Mat mask = cv::Mat::zeros(257, 333, CV_32FC1);
  cv::ellipse(mask, cv::Point(170, 121), cv::Size(61, 83), 0, 0, 360, cv::Scalar(1.0), cv::FILLED);
  cv::GaussianBlur(mask, mask, cv::Size(0, 0), 3.0);
  LaplacianBlendOptions one;
  one.threads = 1;
  LaplacianBlendSummary s1;
  const cv::Mat reference = LaplacianBlend(target, rendered, mask, one, &s1);
  cv::Mat float_target, float_rendered;
  target.convertTo(float_target, CV_32FC3);
  rendered.convertTo(float_rendered, CV_32FC3);
  const cv::Mat float_reference = LaplacianBlend(float_target, float_rendered, mask, one);
  for (int threads : {2, 3, 8}) {
    LaplacianBlendOptions o;
    o.threads = threads;
    LaplacianBlendSummary s;
    EXPECT_EQ(cv::norm(LaplacianBlend(target, rendered, mask, o, &s), reference, cv::NORM_INF), 0.0) << threads;
    EXPECT_EQ(s.blend_region, s1.blend_region);
    const cv::Mat f = LaplacianBlend(float_target, float_rendered, mask, o);
    EXPECT_EQ(cv::countNonZero(f.reshape(1) != float_reference.reshape(1)), 0) << threads;
  }
  EXPECT_THROW(LaplacianBlend(target, rendered, mask, LaplacianBlendOptions{5, 0}), Error);
}

TEST(ReenactLaplacianBlendTest, FloatImagesAndTinyImages) {
  cv::Mat t(5, 7, CV_32FC3, cv::Scalar(10, 10, 10)), r(5, 7, CV_32FC3, cv::Scalar(20, 20, 20));
  cv::Mat m = cv::Mat::zeros(5, 7, CV_32FC1);
  m.at<float>(2, 3) = 1.0f;
  LaplacianBlendSummary s;
  const cv::Mat out = LaplacianBlend(t, r, m, {}, &s);
  EXPECT_EQ(out.type(), CV_32FC3);
  EXPECT_GE(s.levels_used, 1);
  EXPECT_GT(out.at<cv::Vec3f>(2, 3)[0], 10.0f);
}

TEST(ReenactLaplacianBlendTest, RejectsMismatchedInputs) {
  const cv::Mat t = noise_image(32, 32, 7);
  EXPECT_THROW(LaplacianBlend(cv::Mat(), t, cv::Mat::zeros(32, 32, CV_8UC1), {}), Error);
  EXPECT_THROW(LaplacianBlend(t, noise_image(16, 32, 8), cv::Mat::zeros(32, 32, CV_8UC1), {}), Error);
  EXPECT_THROW(LaplacianBlend(t, t, cv::Mat::zeros(32, 32, CV_16UC1), {}), Error);
  EXPECT_THROW(LaplacianBlend(t, t, cv::Mat::zeros(32, 32, CV_8UC1), LaplacianBlendOptions{0}), Error);
  cv::Mat nan_mask(32, 32, CV_32FC1, cv::Scalar(std::nanf("")));
  EXPECT_EQ(cv::norm(LaplacianBlend(t, noise_image(32, 32, 9), nan_mask, {}), t, cv::NORM_INF), 0.0);
}

}  // namespace
}  // namespace face_reenact::reenact
