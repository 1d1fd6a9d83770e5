// The virtual mirror (reenact/virtual_mirror.h) on faces rendered with known parameters: where a
// texture lands, that it follows the face, what re-lighting changes (only the coarsest pyramid
// level), and its errors.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>

#include <opencv2/imgproc.hpp>

#include "face_reenact/common/error.h"
#include "face_reenact/reenact/virtual_mirror.h"
#include "reenact_test_support.h"
#include "support/temp_dir.h"

namespace face_reenact::reenact {
namespace {

using testing::render_target;
using testing::test_camera;
using testing::test_face;
using testing::test_model;

// The pixel a model landmark projects to.
Eigen::Vector2f landmark_pixel(const gpu::FaceParameters& p, const gpu::PinholeCamera& cam, int ibug) {
  const std::vector<cv::Point> px =
      testing::project_vertices(testing::test_renderer().evaluate(p), cam, testing::landmark_vertices(*test_model(), ibug, ibug));
  return px.empty() ? Eigen::Vector2f(-1.f, -1.f) : Eigen::Vector2f(static_cast<float>(px[0].x), static_cast<float>(px[0].y));
}

// The centroid and count of the pixels where `out` is strongly green and `in` is not.
struct Painted {
  Eigen::Vector2f centroid = Eigen::Vector2f::Zero();
  int count = 0;
};
Painted green_paint(const cv::Mat& in, const cv::Mat& out) {
  Painted p;
  for (int j = 0; j < out.rows; ++j)
    for (int i = 0; i < out.cols; ++i) {
      const cv::Vec3b o = out.at<cv::Vec3b>(j, i), t = in.at<cv::Vec3b>(j, i);
      if (o[1] - std::max(o[0], o[2]) > 40 && !(t[1] - std::max(t[0], t[2]) > 40)) {
        p.centroid += Eigen::Vector2f(static_cast<float>(i), static_cast<float>(j));
        ++p.count;
      }
    }
  if (p.count > 0) p.centroid /= static_cast<float>(p.count);
  return p;
}

cv::Mat green_texture() { return cv::Mat(64, 64, CV_8UC4, cv::Scalar(0, 255, 0, 255)); }

// A named region lands on that part of the face, on the person's side, and moves with the head.
TEST(VirtualMirrorTest, ATextureLandsOnItsRegionAndFollowsTheHead) {
  FR_REQUIRE_MODEL();
  const gpu::PinholeCamera cam = test_camera(320, 240);
  for (const float yaw : {0.0f, 0.3f}) {
    gpu::FaceParameters p = test_face(0.5f);
    p.euler.y() += yaw;
    const cv::Mat frame = render_target(p, cam);
    const Eigen::Vector2f nose = landmark_pixel(p, cam, 30), left_eye = landmark_pixel(p, cam, 45),
                          right_eye = landmark_pixel(p, cam, 36), chin = landmark_pixel(p, cam, 8);
    const float eyes = (left_eye - right_eye).norm();
    ASSERT_GT(eyes, 20.f);
    auto paint = [&](const char* region) {
      MirrorOptions o;
      o.texture = green_texture();
      FaceRegion r;
      EXPECT_TRUE(ParseFaceRegion(region, &r)) << region;
      o.placement.region = r;
      const VirtualMirror mirror(*test_model(), o);
      const MirrorResult res = mirror.Apply(frame, cam, p);
      EXPECT_TRUE(res.drawn);
      EXPECT_GT(res.textured_pixels, 0) << region;
      return green_paint(frame, res.bgr);
    };
    const Painted nose_paint = paint("nose"), left = paint("left-cheek"), right = paint("right-cheek"),
                  chin_paint = paint("chin"), forehead = paint("forehead");
    for (const Painted* q : {&nose_paint, &left, &right, &chin_paint, &forehead}) ASSERT_GT(q->count, 20) << "yaw " << yaw;
    RecordProperty("nose_paint_off_nose_eyes_" + std::to_string(yaw), std::to_string((nose_paint.centroid - nose).norm() / eyes));
    // The nose's paint around the nose tip's height and across it; the cheeks on either side (the
    // person's left is the image's right for a face towards the camera), the chin below the
    // mouth, the forehead above the eyes.
    EXPECT_LT((nose_paint.centroid - nose).norm(), 0.3f * eyes) << "yaw " << yaw;
    EXPECT_GT(left.centroid.x(), nose.x() + 0.15f * eyes) << "yaw " << yaw;
    EXPECT_LT(right.centroid.x(), nose.x() - 0.15f * eyes) << "yaw " << yaw;
    EXPECT_GT(chin_paint.centroid.y(), nose.y() + 0.5f * eyes) << "yaw " << yaw;
    EXPECT_LT((chin_paint.centroid - chin).norm(), 0.5f * eyes) << "yaw " << yaw;
    EXPECT_LT(forehead.centroid.y(), 0.5f * (left_eye.y() + right_eye.y()) - 0.3f * eyes) << "yaw " << yaw;
  }
}

// A transparent texture changes nothing; and nothing outside the face and its feather ever changes.
TEST(VirtualMirrorTest, TransparentPartsLeaveTheFrameAndOnlyTheFaceChanges) {
  FR_REQUIRE_MODEL();
  const gpu::PinholeCamera cam = test_camera(320, 240);
  const gpu::FaceParameters p = test_face(0.5f);
  const cv::Mat frame = render_target(p, cam);
  MirrorOptions o;
  o.texture = cv::Mat(32, 32, CV_8UC4, cv::Scalar(0, 0, 255, 0));
  const MirrorResult clear = VirtualMirror(*test_model(), o).Apply(frame, cam, p);
  EXPECT_EQ(cv::norm(clear.bgr, frame, cv::NORM_INF), 0.0) << "a fully transparent texture changed the frame";
  EXPECT_EQ(clear.textured_pixels, 0);
  o.texture = green_texture();
  const MirrorResult painted = VirtualMirror(*test_model(), o).Apply(frame, cam, p);
  EXPECT_GT(painted.textured_pixels, 1000);
  // Changed pixels lie on the face's rendering (skin and eyes), never beyond it.
  const gpu::CpuRenderer& renderer = testing::test_renderer();
  gpu::RenderOptions ro;
  ro.parts = gpu::PartMask{1} << static_cast<int>(FacePart::Face);
  const gpu::GBuffer g = renderer.render(p, cam, ro);
  int outside = 0, inside = 0;
  for (int j = 0; j < cam.height; ++j)
    for (int i = 0; i < cam.width; ++i) {
      if (painted.bgr.at<cv::Vec3b>(j, i) == frame.at<cv::Vec3b>(j, i)) continue;
      (g.covered(i, j) ? inside : outside)++;
    }
  EXPECT_GT(inside, 1000);
  EXPECT_EQ(outside, 0) << "the texture reached pixels off the face";
}

// A texture made for the model's UV layout: uv:U0,V0,U1,V1 maps its corners to the rectangle's.
TEST(VirtualMirrorTest, AUvRectangleMapsTheTexturesCorners) {
  FR_REQUIRE_MODEL();
  MirrorOptions o;
  o.texture = cv::Mat(100, 200, CV_8UC3, cv::Scalar(10, 20, 30));
  o.placement.region.reset();
  o.placement.uv = UvRect{0.2f, 0.3f, 0.6f, 0.5f};
  const VirtualMirror mirror(*test_model(), o);
  EXPECT_TRUE(mirror.TexturePixelToUv(0.f, 0.f).isApprox(Eigen::Vector2f(0.2f, 0.5f), 1e-5f));  // top-left: v1
  EXPECT_TRUE(mirror.TexturePixelToUv(200.f, 100.f).isApprox(Eigen::Vector2f(0.6f, 0.3f), 1e-5f));
  EXPECT_TRUE(mirror.TexturePixelToUv(100.f, 50.f).isApprox(Eigen::Vector2f(0.4f, 0.4f), 1e-5f));
}

// Re-lighting changes the face at the scale of the coarsest pyramid level only: a light from the
// image's left brightens the face's left half and darkens its right, and the change is smooth:
// the part of it finer than a few pixels (the change minus its own blur, in linear light) is
// 2 % of it with the default 4 levels, 12 % with 1 level (failed). The tracked light itself
// changes nothing.
TEST(VirtualMirrorTest, ReLightingChangesOnlyTheCoarsestLevel) {
  FR_REQUIRE_MODEL();
  const gpu::PinholeCamera cam = test_camera(320, 240);
  const gpu::FaceParameters p = test_face(0.5f);
  cv::Mat frame = render_target(p, cam);
  // Detail on the face: squares of 4 px at 0.6 of the brightness, which the SH light cannot have made.
  for (int j = 0; j < frame.rows; ++j)
    for (int i = 0; i < frame.cols; ++i)
      if (((i / 4) + (j / 4)) % 2 == 0) frame.at<cv::Vec3b>(j, i) = frame.at<cv::Vec3b>(j, i) * 0.6;
  MirrorOptions same;
  same.light.kind = MirrorLight::Kind::kCoefficients;
  same.light.gamma = p.gamma;
  const MirrorResult unchanged = VirtualMirror(*test_model(), same).Apply(frame, cam, p);
  EXPECT_LE(cv::norm(unchanged.bgr, frame, cv::NORM_INF), 1.0) << "re-lit with the tracked light";

  MirrorOptions o;
  o.light = ParseLightPreset("left");
  const MirrorResult lit = VirtualMirror(*test_model(), o).Apply(frame, cam, p);
  ASSERT_TRUE(lit.drawn);
  const float nose_x = landmark_pixel(p, cam, 30).x();
  const gpu::CpuRenderer& renderer = testing::test_renderer();
  gpu::RenderOptions ro;
  ro.parts = gpu::PartMask{1} << static_cast<int>(FacePart::Face);
  const gpu::GBuffer g = renderer.render(p, cam, ro);
  // Brightness in linear light x 255 (the light adds in linear light: in sRGB the same change
  // is larger on darker squares).
  auto linear_gray = [](const cv::Mat& bgr) {
    cv::Mat out(bgr.size(), CV_32F);
    const auto& lut = srgb_decode_table();
    for (int j = 0; j < bgr.rows; ++j)
      for (int i = 0; i < bgr.cols; ++i) {
        const cv::Vec3b px = bgr.at<cv::Vec3b>(j, i);
        out.at<float>(j, i) = 255.f * (lut[px[0]] + lut[px[1]] + lut[px[2]]) / 3.f;
      }
    return out;
  };
  const cv::Mat in_gray = linear_gray(frame), out_gray = linear_gray(lit.bgr);
  // The change and its part finer than a few pixels: with only the coarsest level changed, the
  // change is smooth (the frame's squares are not in it).
  const cv::Mat change = out_gray - in_gray;
  cv::Mat smooth_change;
  cv::GaussianBlur(change, smooth_change, cv::Size(0, 0), 2.0);
  double left_change = 0, right_change = 0, fine_change = 0, total_change = 0;
  int left_n = 0, right_n = 0, n = 0;
  for (int j = 6; j < cam.height - 6; ++j)
    for (int i = 6; i < cam.width - 6; ++i) {
      if (!g.covered(i, j) || !g.covered(i - 6, j) || !g.covered(i + 6, j) || !g.covered(i, j - 6) || !g.covered(i, j + 6)) continue;
      const double d = change.at<float>(j, i);
      if (i < nose_x - 10) left_change += d, ++left_n;
      if (i > nose_x + 10) right_change += d, ++right_n;
      // Where the output is not clipped (the brighter side may reach 255).
      if (out_gray.at<float>(j, i) < 250.f) {
        fine_change += std::abs(d - smooth_change.at<float>(j, i));
        total_change += std::abs(d);
        ++n;
      }
    }
  ASSERT_GT(left_n, 200);
  ASSERT_GT(right_n, 200);
  ASSERT_GT(n, 500);
  left_change /= left_n;
  right_change /= right_n;
  RecordProperty("left_half_change", std::to_string(left_change));
  RecordProperty("right_half_change", std::to_string(right_change));
  RecordProperty("fine_share_of_the_change", std::to_string(fine_change / total_change));
  EXPECT_GT(left_change, right_change + 8.0) << "a light from the left should brighten the left half over the right";
  EXPECT_LT(fine_change / total_change, 0.06) << "the change should be smooth: the fine detail stays the frame's";
}

// Something in front of the face (a hand over the cheek) keeps its own look on a frame with
// depth: neither the texture nor the new light lands on the pixels whose depth lies in front of
// the fitted face; without the depth (or with the test off) the texture covers them as well.
TEST(VirtualMirrorTest, WhatStandsInFrontOfTheFaceKeepsItsLookOnFramesWithDepth) {
  FR_REQUIRE_MODEL();
  const gpu::PinholeCamera cam = test_camera(320, 240);
  const gpu::FaceParameters p = test_face(0.5f);
  const cv::Mat frame = render_target(p, cam);
  gpu::RenderOptions ro;
  ro.parts = gpu::PartMask{1} << static_cast<int>(FacePart::Face);
  const gpu::GBuffer g = testing::test_renderer().render(p, cam, ro);
  // The face's own depth, and a "hand" 8 cm in front of it over the person's left cheek.
  cv::Mat depth = cv::Mat::zeros(cam.height, cam.width, CV_32FC1);
  for (int j = 0; j < cam.height; ++j)
    for (int i = 0; i < cam.width; ++i)
      if (g.covered(i, j)) depth.at<float>(j, i) = g.depth(i, j);
  const Eigen::Vector2f nose = landmark_pixel(p, cam, 30), left_eye = landmark_pixel(p, cam, 45);
  const float eyes = (left_eye - landmark_pixel(p, cam, 36)).norm();
  const cv::Rect hand(static_cast<int>(nose.x() + 0.25f * eyes), static_cast<int>(nose.y() - 0.2f * eyes),
                      static_cast<int>(0.5f * eyes), static_cast<int>(0.5f * eyes));
  int hand_on_face = 0;
  for (int j = hand.y; j < hand.y + hand.height; ++j)
    for (int i = hand.x; i < hand.x + hand.width; ++i)
      if (g.covered(i, j)) depth.at<float>(j, i) -= 0.08f, ++hand_on_face;
  ASSERT_GT(hand_on_face, 100) << "the hand should lie on the face";
  // The hand's inside, away from the fade around its edge.
  const cv::Rect inside(hand.x + 4, hand.y + 4, hand.width - 8, hand.height - 8);
  auto changed_inside = [&](const cv::Mat& out) {
    int n = 0;
    for (int j = inside.y; j < inside.y + inside.height; ++j)
      for (int i = inside.x; i < inside.x + inside.width; ++i) n += out.at<cv::Vec3b>(j, i) != frame.at<cv::Vec3b>(j, i);
    return n;
  };

  MirrorOptions o;
  o.texture = green_texture();
  const VirtualMirror mirror(*test_model(), o);
  const MirrorResult with_depth = mirror.Apply(frame, cam, p, &depth);
  EXPECT_GE(with_depth.occluded_pixels, hand_on_face - 5);
  EXPECT_GT(green_paint(frame, with_depth.bgr).count, 1000) << "the rest of the face is painted";
  EXPECT_EQ(changed_inside(with_depth.bgr), 0) << "the texture landed on the hand";
  const MirrorResult without = mirror.Apply(frame, cam, p);
  EXPECT_EQ(without.occluded_pixels, 0);
  EXPECT_GT(changed_inside(without.bgr), inside.area() / 2) << "without depth the cheek under the hand is painted";
  MirrorOptions off = o;
  off.depth_occluder_m = 0.f;
  EXPECT_GT(changed_inside(VirtualMirror(*test_model(), off).Apply(frame, cam, p, &depth).bgr), inside.area() / 2);

  MirrorOptions relit;
  relit.light = ParseLightPreset("left");
  const VirtualMirror relight(*test_model(), relit);
  EXPECT_EQ(changed_inside(relight.Apply(frame, cam, p, &depth).bgr), 0) << "the new light landed on the hand";
  EXPECT_GT(changed_inside(relight.Apply(frame, cam, p).bgr), 0);

  // Depth of another size or type is refused.
  const cv::Mat small = cv::Mat::zeros(10, 10, CV_32FC1), wrong = cv::Mat::zeros(cam.height, cam.width, CV_16UC1);
  EXPECT_THROW(mirror.Apply(frame, cam, p, &small), Error);
  EXPECT_THROW(mirror.Apply(frame, cam, p, &wrong), Error);
  MirrorOptions bad = o;
  bad.depth_occluder_m = -1.f;
  EXPECT_FALSE(bad.IsValid(nullptr));
}

TEST(VirtualMirrorTest, BadOptionsLightsAndFramesAreClearErrors) {
  FR_REQUIRE_MODEL();
  const FaceModel& model = *test_model();
  FaceRegion r;
  EXPECT_FALSE(ParseFaceRegion("ear", &r));
  EXPECT_THROW(ParseLightPreset("disco"), Error);
  try {
    ParseLightPreset("disco");
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("front"), std::string::npos) << "should list the presets: " << e.what();
  }
  MirrorOptions o;
  o.texture = cv::Mat(8, 8, CV_16UC3, cv::Scalar(0, 0, 0));
  EXPECT_THROW(VirtualMirror(model, o), Error);
  o.texture = cv::Mat(8, 8, CV_8UC3, cv::Scalar(0, 0, 0));
  o.opacity = 1.5f;
  EXPECT_THROW(VirtualMirror(model, o), Error);
  o.opacity = 1.0f;
  o.placement.region.reset();
  o.placement.uv = UvRect{0.5f, 0.f, 0.4f, 1.f};
  EXPECT_THROW(VirtualMirror(model, o), Error) << "u0 > u1";
  o.placement.uv = UvRect{0.f, 0.f, 1.f, 1.2f};
  EXPECT_THROW(VirtualMirror(model, o), Error) << "outside [0, 1]";
  o.placement.uv = UvRect{};
  // Light files: not JSON, no gamma, the wrong count, a value that is not a number, an ambient
  // that is not positive.
  const face_reenact::testing::TempDir scratch("fr-mirror-light");
  auto light_file = [&](const std::string& text) {
    const std::string path = (std::filesystem::path(scratch.path()) / "light.json").string();
    std::ofstream(path) << text;
    return path;
  };
  EXPECT_THROW(ReadLightFile(light_file("{not json")), Error);
  EXPECT_THROW(ReadLightFile(light_file("{\"light\": 1}")), Error);
  EXPECT_THROW(ReadLightFile(light_file("{\"gamma\": [1, 2, 3]}")), Error);
  std::string g27 = "{\"gamma\": [";
  for (int k = 0; k < 27; ++k) g27 += (k ? ", " : "") + std::string(k == 5 ? "null" : (k % 9 == 0 ? "2" : "0"));
  EXPECT_THROW(ReadLightFile(light_file(g27 + "]}")), Error);
  std::string dark = "{\"gamma\": [";
  for (int k = 0; k < 27; ++k) dark += (k ? ", " : "") + std::string(k % 9 == 0 ? "-1" : "0");
  EXPECT_THROW(ReadLightFile(light_file(dark + "]}")), Error);
  EXPECT_THROW(ReadLightFile((std::filesystem::path(scratch.path()) / "missing.json").string()), Error);
  std::string ok = "{\"frame\": 3, \"gamma\": [";
  for (int k = 0; k < 27; ++k) ok += (k ? ", " : "") + std::string(k % 9 == 0 ? "2.5" : "0.1");
  const MirrorLight l = ReadLightFile(light_file(ok + "]}"));
  EXPECT_EQ(l.kind, MirrorLight::Kind::kCoefficients);
  EXPECT_FLOAT_EQ(l.gamma[9], 2.5f);
  // Frames of another size, and parameters that are not finite.
  const gpu::PinholeCamera cam = test_camera(320, 240);
  const VirtualMirror mirror(model, o);
  gpu::FaceParameters p = test_face(0.5f);
  EXPECT_THROW(mirror.Apply(cv::Mat(100, 100, CV_8UC3), cam, p), Error);
  p.translation.z() = std::nanf("");
  EXPECT_THROW(mirror.Apply(cv::Mat(240, 320, CV_8UC3, cv::Scalar(0, 0, 0)), cam, p), Error);
  // A face entirely outside the frame: nothing drawn, the frame returned as it was.
  gpu::FaceParameters away = test_face(0.5f);
  away.translation.x() = 5.0f;
  const cv::Mat frame(240, 320, CV_8UC3, cv::Scalar(40, 80, 120));
  const MirrorResult none = mirror.Apply(frame, cam, away);
  EXPECT_FALSE(none.drawn);
  EXPECT_EQ(cv::norm(none.bgr, frame, cv::NORM_INF), 0.0);
}

}  // namespace
}  // namespace face_reenact::reenact
