// The fill by place on the eyeball (core/reenact/src/eyeball_fill.h): an eyeball of radius 20 px
// seen from the front, sampled once per pixel where the "frame" shows it.
#include <gtest/gtest.h>

#include <cmath>

#include "eyeball_fill.h"

namespace face_reenact::reenact::internal {
namespace {

constexpr float kRadiusPx = 20.f;
const Eigen::Vector3f kIris(0.1f, 0.2f, 0.6f), kWhite(0.7f, 0.7f, 0.65f), kFallback(1.f, 0.f, 0.f);

// The place seen at pixel (i, j) from the eyeball's centre (the front, +z, at (0, 0); +y up).
Eigen::Vector3f place(int i, int j) {
  const float x = static_cast<float>(i) / kRadiusPx, y = static_cast<float>(j) / kRadiusPx;
  return Eigen::Vector3f(x, y, std::sqrt(std::max(0.f, 1.f - x * x - y * y)));
}
// The pattern: an iris within 30 degrees of the axis, white beyond.
Eigen::Vector3f pattern(const Eigen::Vector3f& d) { return d.z() > std::cos(30.f * static_cast<float>(M_PI) / 180.f) ? kIris : kWhite; }

// Samples of the pixels within 16 px of the front for which `shown(i, j)` holds.
template <typename Shown>
EyeballFill sampled(Shown shown) {
  EyeballFill fill(kRadiusPx);
  for (int j = -16; j <= 16; ++j)
    for (int i = -16; i <= 16; ++i)
      if (i * i + j * j <= 16 * 16 && shown(i, j)) fill.Add(place(i, j), pattern(place(i, j)), 1.f);
  return fill;
}

bool near(const Eigen::Vector3f& a, const Eigen::Vector3f& b, float tolerance) { return (a - b).cwiseAbs().maxCoeff() <= tolerance; }

// An eye opened wider than the frame's: the frame shows the eyeball up to 2 px above the axis (its
// upper lid there), the output bares the rest. Above the lid the iris continues as an iris and the
// white as white (the mirror places below), not a mix of the two.
TEST(EyeballFill, ContinuesTheIrisAndTheWhiteUnderALid) {
  const EyeballFill fill = sampled([](int, int j) { return j <= 2; });
  int wrong = 0, bared = 0;
  for (int j = 6; j <= 14; ++j)
    for (int i = -14; i <= 14; ++i) {
      if (i * i + j * j > 14 * 14) continue;
      const Eigen::Vector3f d = place(i, j);
      const float degrees = std::acos(d.z()) * 180.f / static_cast<float>(M_PI);
      if (std::abs(degrees - 30.f) < 4.f) continue;  // the iris' edge is soft (the kernels are 1.5 px)
      ++bared;
      const Eigen::Vector3f other = pattern(d) == kIris ? kWhite : kIris;
      const Eigen::Vector3f got = fill.At(d, kFallback);
      wrong += (got - pattern(d)).norm() > 0.25f * (other - pattern(d)).norm();
    }
  ASSERT_GT(bared, 100);
  EXPECT_EQ(wrong, 0) << wrong << " of " << bared << " bared pixels neither the iris nor the white";
}

// A place neither it nor its mirror shown (a gaze turned hard aside bares the far side of a squinting
// eye): the same angle from the axis anywhere, here the white on the other side.
TEST(EyeballFill, TakesTheSameAngleFromTheAxisWhereNeitherSideIsShown) {
  const EyeballFill fill = sampled([](int i, int j) { return i <= 4 && std::abs(j) <= 5; });
  EXPECT_TRUE(near(fill.At(place(12, 0), kFallback), kWhite, 0.02f));
  EXPECT_TRUE(near(fill.At(place(12, 3), kFallback), kWhite, 0.02f));
  // Nothing at that angle: the fallback.
  const EyeballFill iris_only = sampled([](int i, int j) { return i * i + j * j <= 25; });
  EXPECT_TRUE(near(iris_only.At(place(15, 0), kFallback), kFallback, 1e-4f));
  EXPECT_TRUE(near(EyeballFill(kRadiusPx).At(place(0, 0), kFallback), kFallback, 0.f));
}

// A place the frame shows nearby keeps the frame's colour there, even where its mirror differs
// (a glint, a shadowed top): the same place comes first.
TEST(EyeballFill, TheSamePlaceComesBeforeItsMirror) {
  EyeballFill fill(kRadiusPx);
  const Eigen::Vector3f shadow(0.2f, 0.2f, 0.2f);
  for (int j = -16; j <= 16; ++j)
    for (int i = -16; i <= 16; ++i)
      if (i * i + j * j <= 256 && (i + j) % 7 != 0) fill.Add(place(i, j), j > 0 ? shadow : kWhite, 1.f);
  EXPECT_TRUE(near(fill.At(place(10, 8), kFallback), shadow, 0.02f));  // its neighbours, not the mirror's white
  // Untrusted and non-finite samples count for nothing.
  EyeballFill none(kRadiusPx);
  none.Add(place(0, 0), kWhite, 0.f);
  none.Add(Eigen::Vector3f(std::nanf(""), 0.f, 1.f), kWhite, 1.f);
  none.Add(place(0, 0), Eigen::Vector3f(std::nanf(""), 0.f, 0.f), 1.f);
  EXPECT_TRUE(none.empty());
}

}  // namespace
}  // namespace face_reenact::reenact::internal
