// The mouth pass (core/reenact/src/mouth_pass.h) on a G-buffer drawn by hand, so that which
// surface lies where around the opening is known pixel by pixel.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "face_reenact/common/srgb.h"
#include "face_reenact/reenact/mouth_interior.h"
#include "mouth_pass.h"

namespace face_reenact::reenact::internal {
namespace {

// A 120 x 80 G-buffer: skin everywhere at the lip line's depth, an inner-lip octagon 50 px wide
// and 24 px high around (60, 34), and whatever `surface` paints on top.
struct Scene {
  static constexpr int kW = 120, kH = 80;
  static constexpr float kLipZ = 0.5f;
  // Vertices: 0 skin or lip, 1 lower teeth, 2 a face surface 9 cm behind the lip line, 3 the
  // tongue, tongue_depth_m behind it.
  std::vector<FacePart> parts{FacePart::Face, FacePart::LowerTeeth, FacePart::Face, FacePart::Tongue};
  std::vector<char> in_mouth{0, 0, 0, 0};
  float tongue_depth_m = 0.03f;
  gpu::GBuffer g;
  std::vector<Eigen::Vector2f> opening{{35.f, 34.f}, {45.f, 26.f}, {60.f, 22.f}, {75.f, 26.f},
                                       {85.f, 34.f}, {75.f, 42.f}, {60.f, 46.f}, {45.f, 42.f}};
  cv::Mat inside_polygon;  // 255 inside the octagon

  Scene() {
    g.Resize(kW, kH);
    std::vector<cv::Point> poly;
    for (const Eigen::Vector2f& p : opening) poly.emplace_back(static_cast<int>(p.x()), static_cast<int>(p.y()));
    inside_polygon = cv::Mat::zeros(kH, kW, CV_8UC1);
    cv::fillPoly(inside_polygon, std::vector<std::vector<cv::Point>>{poly}, cv::Scalar(255));
    for (int j = 0; j < kH; ++j)
      for (int i = 0; i < kW; ++i) paint(i, j, 0);
  }
  void paint(int i, int j, int vertex) {
    const size_t p = static_cast<size_t>(j) * kW + i;
    g.triangle[p] = 0;
    for (int k = 0; k < 3; ++k) g.vertices[3 * p + k] = vertex;
    const float z = vertex == 1 ? kLipZ + 0.01f : vertex == 2 ? kLipZ + 0.09f : vertex == 3 ? kLipZ + tongue_depth_m : kLipZ;
    g.position[3 * p + 2] = z;
    g.barycentric[3 * p] = 1.f;
    g.barycentric[3 * p + 1] = g.barycentric[3 * p + 2] = 0.f;
    const Eigen::Vector3f c = vertex == 1 ? Eigen::Vector3f(0.8f, 0.8f, 0.75f) : Eigen::Vector3f(0.5f, 0.2f, 0.2f);
    for (int k = 0; k < 3; ++k) g.color[3 * p + k] = c[k];
  }
  // Pixels outside the octagon within `reach` px of it (8-neighbour steps).
  cv::Mat within(int reach) const {
    cv::Mat near;
    cv::dilate(inside_polygon, near, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * reach + 1, 2 * reach + 1)));
    return near & ~inside_polygon;
  }

  struct Drawn {
    cv::Mat face_mask, rendered;
  };
  Drawn Draw(const cv::Mat* frame_shown = nullptr, const MouthPassInput* lighting = nullptr) const {
    MouthPassInput in;
    if (lighting) in = *lighting;
    in.gbuffer = &g;
    in.opening = opening;
    in.lip_z = kLipZ;
    in.vertex_part = &parts;
    in.in_mouth = &in_mouth;
    in.teeth_pattern = [](size_t) { return Eigen::Vector3f::Ones(); };
    in.frame_shown = frame_shown;
    Drawn d;
    d.rendered = cv::Mat(kH, kW, CV_32FC3, cv::Scalar(200, 200, 200));
    d.face_mask = cv::Mat::zeros(kH, kW, CV_8UC1);
    cv::Mat mouth_mask = cv::Mat::zeros(kH, kW, CV_8UC1), depth(kH, kW, CV_32FC1, cv::Scalar(1.f));
    EXPECT_TRUE(DrawMouth(in, &d.rendered, &d.face_mask, &mouth_mask, &depth).drawn);
    return d;
  }
};

// Issue #28: where the output pulls a lip far from the polygon (d6 baring her teeth onto d10, output
// frame 120: mouthLowerDown 0.67 over jawOpen 0.48), the model shows the inside of the mouth up to
// 14 px past the polygon. Only the first 6 px were the pass's; the rest kept the face's rendering,
// the albedo map's teeth, a grey-green stroke along each side of the lower lip. The pass follows
// the inside as far as it continues from the opening, but not across a lip, and not onto what the
// frame itself shows.
TEST(MouthPassTest, TakesTheInsideOfTheMouthAsFarAsItContinuesPastThePolygon) {
  Scene s;
  // A band of lower teeth below the polygon's lower edge, 12 px deep, then the lower lip.
  const cv::Mat band = s.within(12);
  for (int j = 34; j < Scene::kH; ++j)
    for (int i = 0; i < Scene::kW; ++i)
      if (band.at<uchar>(j, i)) s.paint(i, j, 1);
  // A face surface far behind the lip line at the right corner, 8-12 px past it (the inside seen
  // past the corner), joined to the band.
  for (int j = 33; j <= 37; ++j)
    for (int i = 85; i <= 97; ++i)
      if (band.at<uchar>(j, i)) s.paint(i, j, 2);
  // Teeth above the upper lip, cut off from the opening by 4 px of lip: not the mouth's inside.
  for (int j = 2; j <= 8; ++j)
    for (int i = 50; i <= 70; ++i) s.paint(i, j, 1);

  const Scene::Drawn d = s.Draw();
  int band_px = 0, band_taken = 0;
  for (int j = 34; j < Scene::kH; ++j)
    for (int i = 0; i < Scene::kW; ++i)
      if (band.at<uchar>(j, i)) {
        ++band_px;
        band_taken += d.face_mask.at<uchar>(j, i) != 0;
      }
  RecordProperty("band_pixels", band_px);
  RecordProperty("band_taken", band_taken);
  EXPECT_GT(band_px, 400);
  EXPECT_EQ(band_taken, band_px) << "inside of the mouth left to the face's rendering past the polygon";
  // Not the teeth above the lip, and nothing beyond the lip band.
  EXPECT_EQ(cv::countNonZero(d.face_mask(cv::Rect(50, 2, 21, 7))), 0);
  EXPECT_EQ(cv::countNonZero(d.face_mask & ~s.within(16) & ~s.inside_polygon), 0);

  // What the frame shows there is the frame's: with the band's lower half shown, only its upper half is taken.
  cv::Mat shown(Scene::kH, Scene::kW, CV_32FC1, cv::Scalar(0.f));
  shown.setTo(1.f, s.within(12) & ~s.within(6));
  const Scene::Drawn partly = s.Draw(&shown);
  EXPECT_EQ(cv::countNonZero(partly.face_mask & s.within(12) & ~s.within(8)), 0);
  EXPECT_GT(cv::countNonZero(partly.face_mask & s.within(4)), 100);
}


// The light reaching a surface inside the mouth is the share of the light from in front that the
// opening subtends: sin^2 of its half-angle seen from the surface, r^2 / (r^2 + d^2).
TEST(MouthPassTest, ApertureLightIsTheShareOfTheHemisphereTheOpeningSubtends) {
  EXPECT_FLOAT_EQ(MouthApertureLight(0.02f, 0.f), 1.f);
  EXPECT_FLOAT_EQ(MouthApertureLight(0.02f, -0.01f), 1.f) << "in front of the lip line";
  EXPECT_NEAR(MouthApertureLight(0.02f, 0.02f), 0.5f, 1e-6f) << "half-angle 45 degrees";
  const float angle = std::atan2(0.018f, 0.035f);
  EXPECT_NEAR(MouthApertureLight(0.018f, 0.035f), std::sin(angle) * std::sin(angle), 1e-6f);
  EXPECT_LT(MouthApertureLight(0.018f, 0.04f), MouthApertureLight(0.018f, 0.02f)) << "deeper is darker";
  EXPECT_LT(MouthApertureLight(0.005f, 0.02f), MouthApertureLight(0.018f, 0.02f)) << "a narrower opening is darker";
  EXPECT_EQ(MouthApertureLight(0.f, 0.01f), 0.f);
  EXPECT_EQ(MouthApertureLight(std::nanf(""), 0.01f), 0.f);
  EXPECT_EQ(MouthApertureLight(0.02f, std::numeric_limits<float>::infinity()), 0.f);
  // What the model's teeth and tongue are drawn with: the light the mouth's inside bounces, and the
  // aperture's share of the rest.
  EXPECT_FLOAT_EQ(MouthInteriorLight(0.02f, 0.f), 1.f) << "at the lip line";
  EXPECT_NEAR(MouthInteriorLight(0.02f, 0.02f), kMouthBounceLight + (1.f - kMouthBounceLight) * 0.5f, 1e-6f);
  EXPECT_FLOAT_EQ(MouthInteriorLight(0.f, 0.01f), kMouthBounceLight) << "no opening: the bounce alone";
}

// Issue #28: without an open-mouth image, the model's tongue was shaded at its own normal and
// darkened linearly to 0.15 beyond 2 cm: in a wide-open mouth, 2 % of the cheek's luminance, the
// cavity's own colour, so the opening was one flat dark gash (d6 onto the webcam clip, --mouth
// model, output frame 60). Now it takes its albedo lit from in front, times the share of that
// light its depth and the opening's size let in, over the light a mouth's inside bounces
// (MouthInteriorLight): a tongue 3 cm in, in an opening of 50 x 24 px at 1 mm per pixel, shows at
// that share of its albedo; at half the opening's size, or 5 cm in, darker, but not black.
TEST(MouthPassTest, TheTongueIsLitThroughTheOpeningByItsSizeAndDepth) {
  const Eigen::Vector3f tongue_albedo(0.55f, 0.2f, 0.19f);
  Eigen::VectorXf albedo = Eigen::VectorXf::Zero(12);
  albedo.segment<3>(9) = tongue_albedo;
  MouthPassInput lighting;
  lighting.vertex_albedo = &albedo;
  lighting.front_light = Eigen::Vector3f(2.f, 2.f, 2.f);
  lighting.entering_light = Eigen::Vector3f(0.2f, 0.2f, 0.2f);  // the cavity: 0.2 x its albedo, red 0.018
  lighting.focal_px = 500.f;  // at the lip line's 0.5 m: 1 mm per pixel
  // The drawn red at the opening's centre, in linear light, for an opening scaled by `scale`.
  auto red_at_centre = [&](float scale, float depth_m, double* expected) {
    Scene s;
    s.tongue_depth_m = depth_m;
    const Eigen::Vector2f centre(60.f, 34.f);
    for (Eigen::Vector2f& p : s.opening) p = centre + scale * (p - centre);
    for (int j = 0; j < Scene::kH; ++j)
      for (int i = 0; i < Scene::kW; ++i)
        if ((Eigen::Vector2f(static_cast<float>(i), static_cast<float>(j)) - centre).cwiseAbs().maxCoeff() < 30.f &&
            std::abs(j - 34) < 14)
          s.paint(i, j, 3);
    const double radius_m = std::sqrt(PolygonArea(s.opening) / M_PI) * Scene::kLipZ / lighting.focal_px;
    const double light = MouthInteriorLight(static_cast<float>(radius_m), depth_m);
    *expected = std::max(light * tongue_albedo[0] * 2.0, 0.018);  // the cavity's floor
    const Scene::Drawn d = s.Draw(nullptr, &lighting);
    return srgb_decode(d.rendered.at<cv::Vec3f>(34, 60)[2] / 255.f);
  };
  double wide_expected = 0, narrow_expected = 0, deep_expected = 0;
  const double wide = red_at_centre(1.f, 0.03f, &wide_expected);
  const double narrow = red_at_centre(0.5f, 0.03f, &narrow_expected);
  const double deep = red_at_centre(1.f, 0.05f, &deep_expected);
  EXPECT_NEAR(wide, wide_expected, 0.01 * wide_expected + 0.002);
  EXPECT_NEAR(narrow, narrow_expected, 0.01 * narrow_expected + 0.002);
  EXPECT_NEAR(deep, deep_expected, 0.01 * deep_expected + 0.002);
  EXPECT_GT(wide, 1.1 * narrow) << "less light enters a narrower opening";
  EXPECT_GT(wide, 1.1 * deep) << "less reaches deeper in";
  EXPECT_GT(wide, 0.1) << "a tongue in a wide-open mouth is not the cavity's dark";
  // Nor one deep in a narrow opening: the aperture alone let 0.07 of the front light reach it (a
  // black gash on real clips); what the mouth's inside bounces reaches it whatever its depth.
  EXPECT_GT(narrow, 0.25 * tongue_albedo[0] * 2.0) << "a flat dark gash";
}

// The teeth's biting edges face away from the opening: they take the light from in front only as
// far as the fit's light at their own normals reaches (lit from in front in full, the lower teeth of
// d14's parted smile on the webcam clip drew white dashes along the lip).
TEST(MouthPassTest, TeethTakeTheLightFromInFrontOnlyUpToTheirOwnShading) {
  Eigen::VectorXf albedo = Eigen::VectorXf::Zero(12);
  albedo.segment<3>(3) = Eigen::Vector3f(0.7f, 0.7f, 0.7f);  // the lower teeth (vertex 1)
  MouthPassInput lighting;
  lighting.vertex_albedo = &albedo;
  lighting.entering_light = Eigen::Vector3f(0.2f, 0.2f, 0.2f);
  lighting.focal_px = 500.f;
  auto green_at_centre = [&](float front) {
    Scene s;
    for (int j = 24; j < 45; ++j)
      for (int i = 40; i < 81; ++i) s.paint(i, j, 1);  // teeth 1 cm in, shaded (0.8, 0.8, 0.75)
    lighting.front_light = Eigen::Vector3f(front, front, front);
    const double radius_m = std::sqrt(PolygonArea(s.opening) / M_PI) * Scene::kLipZ / lighting.focal_px;
    const double share = MouthInteriorLight(static_cast<float>(radius_m), 0.01f);
    const double drawn = srgb_decode(s.Draw(nullptr, &lighting).rendered.at<cv::Vec3f>(34, 60)[1] / 255.f);
    return drawn / share;  // the light the teeth took, before the mouth's share (MouthInteriorLight)
  };
  EXPECT_NEAR(green_at_centre(0.5f), 0.35, 0.01) << "dimmer from in front than at their normals: the front";
  EXPECT_NEAR(green_at_centre(2.0f), 0.8, 0.02) << "brighter from in front: their own shading";
}

}  // namespace
}  // namespace face_reenact::reenact::internal
