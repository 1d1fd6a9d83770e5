// BGR -> YUYV / I420 (BT.601 limited range) and letterboxing, against reference values.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <opencv2/core.hpp>
#include <random>

#include "face_reenact/common/error.h"
#include "face_reenact/output/pixel_conversion.h"

namespace face_reenact::output {
namespace {

// The BT.601 definition in floating point (ITU-R BT.601: Y' = 16 + 219 E'Y, C = 128 + 224 E'C).
void reference_ycbcr(double b, double g, double r, double* y, double* cb, double* cr) {
  double ey = (0.299 * r + 0.587 * g + 0.114 * b) / 255;
  *y = 16 + 219 * ey;
  *cb = 128 + 224 * (b / 255 - ey) / 1.772;
  *cr = 128 + 224 * (r / 255 - ey) / 1.402;
}

TEST(PixelConversion, BlackWhiteAndGreyAreExact) {
  EXPECT_EQ(bgr_to_ycbcr(0, 0, 0).y, 16);
  EXPECT_EQ(bgr_to_ycbcr(0, 0, 0).cb, 128);
  EXPECT_EQ(bgr_to_ycbcr(0, 0, 0).cr, 128);
  EXPECT_EQ(bgr_to_ycbcr(255, 255, 255).y, 235);
  EXPECT_EQ(bgr_to_ycbcr(255, 255, 255).cb, 128);
  EXPECT_EQ(bgr_to_ycbcr(255, 255, 255).cr, 128);
  for (int v = 0; v < 256; ++v) {
    Ycbcr c = bgr_to_ycbcr(uint8_t(v), uint8_t(v), uint8_t(v));
    EXPECT_EQ(c.cb, 128) << v;
    EXPECT_EQ(c.cr, 128) << v;
  }
}

TEST(PixelConversion, PureColoursMatchBt601Table) {
  // Standard 100% colour-bar values (8-bit, limited range), within 1 of the fixed-point form.
  struct Case {
    uint8_t b, g, r;
    int y, cb, cr;
  } cases[] = {{0, 0, 255, 81, 90, 240},    {0, 255, 0, 145, 54, 34},   {255, 0, 0, 41, 240, 110},
               {0, 255, 255, 210, 16, 146}, {255, 255, 0, 170, 166, 16}, {255, 0, 255, 106, 202, 222}};
  for (const auto& c : cases) {
    Ycbcr got = bgr_to_ycbcr(c.b, c.g, c.r);
    EXPECT_NEAR(got.y, c.y, 1) << int(c.b) << "," << int(c.g) << "," << int(c.r);
    EXPECT_NEAR(got.cb, c.cb, 1);
    EXPECT_NEAR(got.cr, c.cr, 1);
  }
}

TEST(PixelConversion, EveryColourWithinOneOfTheDefinition) {
  std::mt19937 rng(7);
  for (int i = 0; i < 20000; ++i) {
    uint8_t b = uint8_t(rng()), g = uint8_t(rng()), r = uint8_t(rng());
    double y, cb, cr;
    reference_ycbcr(b, g, r, &y, &cb, &cr);
    Ycbcr got = bgr_to_ycbcr(b, g, r);
    ASSERT_LE(std::abs(got.y - y), 1.0) << int(b) << "," << int(g) << "," << int(r);
    ASSERT_LE(std::abs(got.cb - cb), 1.0);
    ASSERT_LE(std::abs(got.cr - cr), 1.0);
    ASSERT_GE(got.y, 16);
    ASSERT_LE(got.y, 235);
    ASSERT_GE(got.cb, 16);
    ASSERT_LE(got.cb, 240);
    ASSERT_GE(got.cr, 16);
    ASSERT_LE(got.cr, 240);
  }
}

TEST(PixelConversion, PixelRoundTripWithinThree) {
  // 8-bit limited range has about 220 x 225 x 225 levels for 256^3 colours, so a round trip
  // cannot be exact; the fixed-point pair stays within 3 and is within 1 on average.
  int worst = 0;
  double sum = 0;
  int count = 0;
  for (int b = 0; b < 256; b += 3)
    for (int g = 0; g < 256; g += 3)
      for (int r = 0; r < 256; r += 3) {
        Ycbcr c = bgr_to_ycbcr(uint8_t(b), uint8_t(g), uint8_t(r));
        uint8_t b2, g2, r2;
        ycbcr_to_bgr(c.y, c.cb, c.cr, &b2, &g2, &r2);
        int e = std::max({std::abs(b2 - b), std::abs(g2 - g), std::abs(r2 - r)});
        worst = std::max(worst, e);
        sum += e;
        ++count;
      }
  EXPECT_LE(worst, 3);
  EXPECT_LT(sum / count, 1.0);
}

TEST(PixelConversion, YuyvLayoutAveragesChromaOfEachPair) {
  cv::Mat img(1, 4, CV_8UC3);
  img.at<cv::Vec3b>(0, 0) = {0, 0, 255};    // red
  img.at<cv::Vec3b>(0, 1) = {255, 0, 0};    // blue
  img.at<cv::Vec3b>(0, 2) = {255, 255, 255};
  img.at<cv::Vec3b>(0, 3) = {255, 255, 255};
  std::vector<uint8_t> out(frame_bytes(PixelFormat::kYuyv, 4, 1));
  ASSERT_EQ(out.size(), 8u);
  convert_bgr(img, PixelFormat::kYuyv, out);
  Ycbcr red = bgr_to_ycbcr(0, 0, 255), blue = bgr_to_ycbcr(255, 0, 0);
  EXPECT_EQ(out[0], red.y);
  EXPECT_EQ(out[1], (red.cb + blue.cb + 1) / 2);
  EXPECT_EQ(out[2], blue.y);
  EXPECT_EQ(out[3], (red.cr + blue.cr + 1) / 2);
  EXPECT_EQ(out[4], 235);
  EXPECT_EQ(out[5], 128);
  EXPECT_EQ(out[6], 235);
  EXPECT_EQ(out[7], 128);
}

TEST(PixelConversion, I420LayoutIsYPlaneThenCbThenCr) {
  // 4x2: left 2x2 block green, right 2x2 block magenta.
  cv::Mat img(2, 4, CV_8UC3);
  for (int y = 0; y < 2; ++y)
    for (int x = 0; x < 4; ++x) img.at<cv::Vec3b>(y, x) = x < 2 ? cv::Vec3b(0, 255, 0) : cv::Vec3b(255, 0, 255);
  std::vector<uint8_t> out(frame_bytes(PixelFormat::kI420, 4, 2));
  ASSERT_EQ(out.size(), 12u);
  convert_bgr(img, PixelFormat::kI420, out);
  Ycbcr green = bgr_to_ycbcr(0, 255, 0), magenta = bgr_to_ycbcr(255, 0, 255);
  for (int y = 0; y < 2; ++y)
    for (int x = 0; x < 4; ++x) EXPECT_EQ(out[y * 4 + x], x < 2 ? green.y : magenta.y);
  EXPECT_EQ(out[8], green.cb);
  EXPECT_EQ(out[9], magenta.cb);
  EXPECT_EQ(out[10], green.cr);
  EXPECT_EQ(out[11], magenta.cr);
}

TEST(PixelConversion, GreyGradientHasMonotonicLumaAndNeutralChroma) {
  cv::Mat img(4, 256, CV_8UC3);
  for (int y = 0; y < 4; ++y)
    for (int x = 0; x < 256; ++x) img.at<cv::Vec3b>(y, x) = cv::Vec3b(uint8_t(x), uint8_t(x), uint8_t(x));
  for (PixelFormat f : {PixelFormat::kYuyv, PixelFormat::kI420}) {
    std::vector<uint8_t> out(frame_bytes(f, 256, 4));
    convert_bgr(img, f, out);
    cv::Mat back = convert_to_bgr(out, f, 256, 4);
    int previous_y = -1;
    for (int x = 0; x < 256; ++x) {
      int y = f == PixelFormat::kYuyv ? out[2 * x] : out[x];
      EXPECT_GE(y, previous_y) << pixel_format_name(f) << " x=" << x;
      previous_y = y;
      cv::Vec3b px = back.at<cv::Vec3b>(1, x);
      EXPECT_NEAR(px[0], x, 2);
      EXPECT_NEAR(px[1], x, 2);
      EXPECT_NEAR(px[2], x, 2);
    }
    EXPECT_EQ(out[f == PixelFormat::kYuyv ? 0 : 0], 16);
    if (f == PixelFormat::kYuyv) {
      for (size_t i = 1; i < out.size(); i += 2) ASSERT_EQ(out[i], 128);
    } else {
      for (size_t i = 256 * 4; i < out.size(); ++i) ASSERT_EQ(out[i], 128);
    }
  }
}

TEST(PixelConversion, ImageRoundTripWithBlockConstantChroma) {
  // Images whose colour is constant on 2x2 blocks lose nothing to subsampling, so the round
  // trip is as exact as the per-pixel one.
  std::mt19937 rng(11);
  cv::Mat img(48, 64, CV_8UC3);
  for (int y = 0; y < img.rows; y += 2)
    for (int x = 0; x < img.cols; x += 2) {
      cv::Vec3b c{static_cast<uint8_t>(rng()), static_cast<uint8_t>(rng()), static_cast<uint8_t>(rng())};
      img(cv::Rect(x, y, 2, 2)).setTo(cv::Scalar(c[0], c[1], c[2]));
    }
  for (PixelFormat f : {PixelFormat::kYuyv, PixelFormat::kI420}) {
    std::vector<uint8_t> out(frame_bytes(f, img.cols, img.rows));
    convert_bgr(img, f, out);
    cv::Mat back = convert_to_bgr(out, f, img.cols, img.rows);
    cv::Mat diff;
    cv::absdiff(img, back, diff);
    double max_diff;
    cv::minMaxLoc(diff.reshape(1), nullptr, &max_diff);
    EXPECT_LE(max_diff, 3) << pixel_format_name(f);
  }
}

TEST(PixelConversion, RejectsOddSizesWrongTypesAndShortBuffers) {
  std::vector<uint8_t> out(1 << 16);
  EXPECT_THROW(convert_bgr(cv::Mat(4, 3, CV_8UC3), PixelFormat::kYuyv, out), Error);
  EXPECT_THROW(convert_bgr(cv::Mat(3, 4, CV_8UC3), PixelFormat::kI420, out), Error);
  EXPECT_NO_THROW(convert_bgr(cv::Mat(3, 4, CV_8UC3, cv::Scalar(1, 2, 3)), PixelFormat::kYuyv, out));
  EXPECT_THROW(convert_bgr(cv::Mat(4, 4, CV_8UC4), PixelFormat::kYuyv, out), Error);
  EXPECT_THROW(convert_bgr(cv::Mat(), PixelFormat::kYuyv, out), Error);
  std::vector<uint8_t> small(10);
  EXPECT_THROW(convert_bgr(cv::Mat(4, 4, CV_8UC3), PixelFormat::kYuyv, small), Error);
  EXPECT_THROW(convert_to_bgr(small, PixelFormat::kI420, 4, 4), Error);
  EXPECT_THROW(frame_bytes(PixelFormat::kYuyv, 0, 4), Error);
}

TEST(PixelConversion, FormatNamesAndFourccs) {
  EXPECT_EQ(parse_pixel_format("YUYV"), PixelFormat::kYuyv);
  EXPECT_EQ(parse_pixel_format("yuy2"), PixelFormat::kYuyv);
  EXPECT_EQ(parse_pixel_format("i420"), PixelFormat::kI420);
  EXPECT_EQ(parse_pixel_format("YU12"), PixelFormat::kI420);
  EXPECT_FALSE(parse_pixel_format("rgb24").has_value());
  EXPECT_FALSE(parse_pixel_format("").has_value());
  EXPECT_EQ(fourcc_to_string(pixel_format_fourcc(PixelFormat::kYuyv)), "YUYV");
  EXPECT_EQ(fourcc_to_string(pixel_format_fourcc(PixelFormat::kI420)), "YU12");
  EXPECT_EQ(frame_bytes(PixelFormat::kYuyv, 1280, 720), 1280u * 720 * 2);
  EXPECT_EQ(frame_bytes(PixelFormat::kI420, 1280, 720), 1280u * 720 * 3 / 2);
}

TEST(PixelConversion, BlackFrames) {
  for (PixelFormat f : {PixelFormat::kYuyv, PixelFormat::kI420}) {
    std::vector<uint8_t> out(frame_bytes(f, 8, 4), 0);
    fill_black(f, 8, 4, out);
    cv::Mat back = convert_to_bgr(out, f, 8, 4);
    EXPECT_EQ(cv::countNonZero(back.reshape(1)), 0) << pixel_format_name(f);
    std::vector<uint8_t> expected(out.size());
    convert_bgr(cv::Mat(4, 8, CV_8UC3, cv::Scalar(0, 0, 0)), f, expected);
    EXPECT_EQ(out, expected);
  }
}

TEST(Letterbox, PillarboxesFourThreeIntoSixteenNine) {
  cv::Rect r = letterbox_rect(640, 480, 1280, 720);
  EXPECT_EQ(r, cv::Rect(160, 0, 960, 720));
  cv::Mat img(480, 640, CV_8UC3, cv::Scalar(10, 200, 30));
  cv::Mat out = letterbox_bgr(img, 1280, 720);
  ASSERT_EQ(out.size(), cv::Size(1280, 720));
  EXPECT_EQ(out.at<cv::Vec3b>(360, 0), cv::Vec3b(0, 0, 0));
  EXPECT_EQ(out.at<cv::Vec3b>(360, 159), cv::Vec3b(0, 0, 0));
  EXPECT_EQ(out.at<cv::Vec3b>(360, 160), cv::Vec3b(10, 200, 30));
  EXPECT_EQ(out.at<cv::Vec3b>(0, 640), cv::Vec3b(10, 200, 30));
  EXPECT_EQ(out.at<cv::Vec3b>(719, 1119), cv::Vec3b(10, 200, 30));
  EXPECT_EQ(out.at<cv::Vec3b>(360, 1120), cv::Vec3b(0, 0, 0));
}

TEST(Letterbox, LetterboxesWideIntoFourThreeAndKeepsLayout) {
  EXPECT_EQ(letterbox_rect(1920, 1080, 640, 480), cv::Rect(0, 60, 640, 360));
  // Left half red, right half blue survives the shrink in the right places.
  cv::Mat img(1080, 1920, CV_8UC3, cv::Scalar(0, 0, 255));
  img(cv::Rect(960, 0, 960, 1080)).setTo(cv::Scalar(255, 0, 0));
  cv::Mat out = letterbox_bgr(img, 640, 480);
  EXPECT_EQ(out.at<cv::Vec3b>(30, 320), cv::Vec3b(0, 0, 0));
  EXPECT_EQ(out.at<cv::Vec3b>(240, 100), cv::Vec3b(0, 0, 255));
  EXPECT_EQ(out.at<cv::Vec3b>(240, 540), cv::Vec3b(255, 0, 0));
  EXPECT_EQ(out.at<cv::Vec3b>(450, 320), cv::Vec3b(0, 0, 0));
}

TEST(Letterbox, SameSizeIsNotCopiedAndOtherTypesAreConverted) {
  cv::Mat img(720, 1280, CV_8UC3, cv::Scalar(1, 2, 3));
  cv::Mat out = letterbox_bgr(img, 1280, 720);
  EXPECT_EQ(out.data, img.data);
  cv::Mat grey(240, 320, CV_8UC1, cv::Scalar(77));
  EXPECT_EQ(letterbox_bgr(grey, 320, 240).at<cv::Vec3b>(5, 5), cv::Vec3b(77, 77, 77));
  cv::Mat bgra(240, 320, CV_8UC4, cv::Scalar(9, 8, 7, 255));
  EXPECT_EQ(letterbox_bgr(bgra, 640, 480).at<cv::Vec3b>(240, 320), cv::Vec3b(9, 8, 7));
  EXPECT_THROW(letterbox_bgr(cv::Mat(), 640, 480), Error);
  EXPECT_THROW(letterbox_bgr(cv::Mat(4, 4, CV_32FC3), 640, 480), Error);
  EXPECT_THROW(letterbox_bgr(img, 0, 480), Error);
  // Extreme aspect ratios still give at least one pixel.
  EXPECT_EQ(letterbox_rect(10000, 1, 640, 480).height, 1);
}

}  // namespace
}  // namespace face_reenact::output
