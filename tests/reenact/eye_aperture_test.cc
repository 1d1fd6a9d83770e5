// An eye's real opening (core/reenact/src/eye_aperture.h): the curve through the detector's six
// lid points, the output's moved with the lids, and the openings read from detected landmarks.
#include <gtest/gtest.h>

#include <cmath>

#include "eye_aperture.h"
#include "face_reenact/reenact/reenactment_pipeline.h"

namespace face_reenact::reenact::internal {
namespace {

// Six points around an eye 40 px wide and 16 px tall centred at (100, 50), in iBUG order: the
// outer corner, two on the upper lid, the inner corner, two on the lower lid.
std::array<Eigen::Vector2f, 6> eye_points() {
  return {Eigen::Vector2f(80.f, 50.f), Eigen::Vector2f(93.f, 42.f), Eigen::Vector2f(107.f, 42.f),
          Eigen::Vector2f(120.f, 50.f), Eigen::Vector2f(107.f, 58.f), Eigen::Vector2f(93.f, 58.f)};
}
std::array<Eigen::Vector2f, 6> no_motion() {
  std::array<Eigen::Vector2f, 6> m;
  m.fill(Eigen::Vector2f::Zero());
  return m;
}
using Which = EyeAperture::Which;

TEST(EyeAperture, TheOutlinePassesThroughTheLidPointsAndBulgesLikeALid) {
  const EyeAperture a(eye_points(), no_motion());
  for (const Eigen::Vector2f& p : eye_points()) EXPECT_NEAR(a.SignedDistance(p, Which::kFrame), 0.f, 0.05f);
  EXPECT_NEAR(a.SignedDistance(Eigen::Vector2f(100.f, 50.f), Which::kFrame), 8.f, 1.0f) << "the centre, half the height in";
  EXPECT_LT(a.SignedDistance(Eigen::Vector2f(100.f, 30.f), Which::kFrame), -10.f) << "above the upper lid";
  EXPECT_LT(a.SignedDistance(Eigen::Vector2f(125.f, 50.f), Which::kFrame), -4.f) << "beyond the inner corner";
  // Between the two upper points the lid curves above their chord (the hexagon would cut it flat).
  EXPECT_GT(a.SignedDistance(Eigen::Vector2f(100.f, 41.8f), Which::kFrame), 0.f);
}

TEST(EyeAperture, TheOutputsOpeningMovesWithTheLidsAndSaysHowFar) {
  std::array<Eigen::Vector2f, 6> motion = no_motion();
  motion[1] = motion[2] = Eigen::Vector2f(0.f, -3.f);  // the upper lid raised by 3 px
  const EyeAperture a(eye_points(), motion);
  const Eigen::Vector2f above(100.f, 40.f);  // between the frame's upper lid and the output's
  EXPECT_LT(a.SignedDistance(above, Which::kFrame), 0.f);
  Eigen::Vector2f at;
  EXPECT_GT(a.SignedDistance(above, Which::kOutput, &at), 0.f);
  EXPECT_NEAR(at.y(), -3.f, 0.01f) << "the nearest outline point moves with the upper lid";
  a.SignedDistance(Eigen::Vector2f(100.f, 62.f), Which::kOutput, &at);
  EXPECT_NEAR(at.norm(), 0.f, 0.01f) << "the lower lid stays";
  const cv::Rect frame_box = a.Bounds(Which::kFrame, 0, 640, 480), output_box = a.Bounds(Which::kOutput, 0, 640, 480);
  EXPECT_LT(output_box.y, frame_box.y);
  EXPECT_EQ(a.Bounds(Which::kFrame, 100, 150, 120), cv::Rect(0, 0, 150, 120)) << "kept within the image";
}

TEST(EyeAperture, ALidIsNeverSampledInsideTheFramesOpening) {
  std::array<Eigen::Vector2f, 6> motion = no_motion();
  motion[1] = motion[2] = Eigen::Vector2f(0.f, 20.f);  // the upper lid shut past the lower one
  const EyeAperture a(eye_points(), motion);
  // A pixel above the frame's opening whose lid motion maps it further up: that pixel as it is.
  const Eigen::Vector2f above = a.FrameLidPoint(Eigen::Vector2f(100.f, 35.f), Eigen::Vector2f(0.f, 2.f));
  EXPECT_NEAR((above - Eigen::Vector2f(100.f, 33.f)).norm(), 0.f, 1e-4f);
  // The seam of shut lids inside the frame's open eye, with the unmoved lower lid's motion: not
  // the eye there, the lid margin nearest it, a pixel outside the opening.
  const Eigen::Vector2f seam = a.FrameLidPoint(Eigen::Vector2f(100.f, 55.f), Eigen::Vector2f::Zero());
  EXPECT_LT(a.SignedDistance(seam, Which::kFrame), -0.5f);
  EXPECT_GT(seam.y(), 57.5f) << "the lower lid's margin, the nearest";
  EXPECT_LT(std::abs(seam.x() - 100.f), 3.f);
}

TEST(EyeAperture, OpeningsAreReadOnlyFromEyesWithAllSixPoints) {
  std::vector<tracker::InputLandmark> landmarks;
  for (int i = 0; i < 68; ++i) {
    tracker::InputLandmark l;
    l.ibug_index = i;
    l.position = Eigen::Vector2f(static_cast<float>(i), static_cast<float>(2 * i));
    landmarks.push_back(l);
  }
  EyeOpenings o = EyeOpeningsFromLandmarks(landmarks);
  ASSERT_TRUE(o.known[0] && o.known[1]);
  EXPECT_EQ(o.points[0][0], Eigen::Vector2f(36.f, 72.f));
  EXPECT_EQ(o.points[1][5], Eigen::Vector2f(47.f, 94.f));
  landmarks[44].confidence = 0.f;  // a point the detector does not vouch for
  landmarks[38].position.x() = std::nanf("");
  o = EyeOpeningsFromLandmarks(landmarks);
  EXPECT_FALSE(o.known[0]);
  EXPECT_FALSE(o.known[1]);
  EXPECT_TRUE(o.empty());
  landmarks.resize(40);  // a detector that gave fewer points
  landmarks[38].position.x() = 38.f;
  EXPECT_TRUE(EyeOpeningsFromLandmarks(landmarks).empty());
}

}  // namespace
}  // namespace face_reenact::reenact::internal
