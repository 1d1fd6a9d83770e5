// The mouth pass (core/reenact/src/mouth_pass.h) on a G-buffer drawn by hand, so that which
// surface lies where around the opening is known pixel by pixel.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "mouth_pass.h"

namespace face_reenact::reenact::internal {
namespace {

// A 120 x 80 G-buffer: skin everywhere at the lip line's depth, an inner-lip octagon 50 px wide
// and 24 px high around (60, 34), and whatever `surface` paints on top.
struct Scene {
  static constexpr int kW = 120, kH = 80;
  static constexpr float kLipZ = 0.5f;
  // Vertices: 0 skin or lip, 1 lower teeth, 2 a face surface 9 cm behind the lip line.
  std::vector<FacePart> parts{FacePart::Face, FacePart::LowerTeeth, FacePart::Face};
  std::vector<char> in_mouth{0, 0, 0};
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
    const float z = vertex == 1 ? kLipZ + 0.01f : vertex == 2 ? kLipZ + 0.09f : kLipZ;
    g.position[3 * p + 2] = z;
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
  Drawn Draw(const cv::Mat* frame_shown = nullptr) const {
    MouthPassInput in;
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

}  // namespace
}  // namespace face_reenact::reenact::internal
