// ProjectToPlausibleLight (plausible_light.h): every light a real room gives is left exactly as it
// is; a light with negative light somewhere beyond the truncation's own ringing goes to the
// nearest one that has none.
#include "face_reenact/tracker/plausible_light.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

#include "face_reenact/capture/synth.h"

namespace face_reenact::tracker {
namespace {

ShLight from_light(Eigen::Vector3f direction, Eigen::Vector3f colour, float intensity, float ambient) {
  capture::LightState l;
  l.direction = direction;
  l.color = colour;
  l.intensity = intensity;
  l.ambient = ambient;
  return capture::sh_from_light(l);
}

double distance(const ShLight& a, const ShLight& b) {
  double s = 0;
  for (size_t k = 0; k < a.size(); ++k) s += double(a[k] - b[k]) * (a[k] - b[k]);
  return std::sqrt(s);
}

TEST(PlausibleLight, EveryRoomsLightIsLeftAsItIs) {
  // A single distant light with no ambient at all is the worst case (its truncated irradiance
  // rings down to -0.158 of its mean), then coloured lights with ambient, from all sides.
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(-1.f, 1.f), pos(0.f, 1.f);
  std::vector<ShLight> lights = {from_light({0, 0, -1}, {1, 1, 1}, 1.f, 0.f), from_light({1, 0, 0}, {1, 0.5f, 0.2f}, 2.f, 0.f)};
  for (int i = 0; i < 200; ++i) {
    Eigen::Vector3f d(u(rng), u(rng), u(rng));
    if (d.norm() < 0.1f) d = Eigen::Vector3f::UnitZ();
    lights.push_back(from_light(d, Eigen::Vector3f(pos(rng), pos(rng), pos(rng)), 3.f * pos(rng), pos(rng)));
  }
  // Two distant lights together (a key and a fill) are a room too.
  for (int i = 0; i < 50; ++i) {
    const ShLight a = from_light(Eigen::Vector3f(u(rng), u(rng), 1.f), {1, 0.7f, 0.4f}, 2.f * pos(rng), 0.f);
    const ShLight b = from_light(Eigen::Vector3f(u(rng), u(rng), -1.f), {0.3f, 0.6f, 1.f}, pos(rng), 0.f);
    ShLight sum;
    for (size_t k = 0; k < sum.size(); ++k) sum[k] = a[k] + b[k];
    lights.push_back(sum);
  }
  for (const ShLight& original : lights) {
    for (int c = 0; c < 3; ++c) EXPECT_GE(LowestRelativeIrradiance(original, c), -0.16f);
    ShLight l = original;
    EXPECT_FALSE(ProjectToPlausibleLight(&l).changed);
    EXPECT_EQ(l, original);
  }
}

TEST(PlausibleLight, ALightThatDriftedBelowZeroGoesToTheNearestPlausibleOne) {
  // The Breaking Bad still's light after 90 frames of tracking (before the projection): every
  // channel's ambient at or below zero, the directional parts fourfold.
  const ShLight drifted = {-0.06f, 2.12f, -1.28f, 1.41f, 0.35f, -0.20f, 0.41f, 0.12f, -0.30f,
                           -1.07f, 2.30f, -2.10f, 2.00f, 0.30f, -0.25f, 0.50f, 0.10f, -0.40f,
                           -1.98f, 2.17f, -3.73f, 2.73f, 0.25f, -0.30f, 0.60f, 0.05f, -0.50f};
  for (int c = 0; c < 3; ++c) EXPECT_LT(LowestRelativeIrradiance(drifted, c), -1.f);
  ShLight l = drifted;
  const LightProjection p = ProjectToPlausibleLight(&l);
  EXPECT_TRUE(p.changed);
  EXPECT_NEAR(p.moved, distance(l, drifted), 1e-3);
  for (int c = 0; c < 3; ++c) {
    EXPECT_GE(l[static_cast<size_t>(9 * c)], 0.f) << "channel " << c << ": a negative ambient";
    EXPECT_GE(LowestRelativeIrradiance(l, c), -kNegativeLobe - 0.01f) << "channel " << c;
  }
  // Projected again: nowhere to go.
  ShLight again = l;
  ProjectToPlausibleLight(&again);
  EXPECT_LT(distance(again, l), 1e-3);
  // The nearest: x is the projection of g onto the (convex) set of plausible lights exactly when
  // (g - x) . (y - x) <= 0 for every plausible y; checked against 300 rooms' lights, per channel
  // (a projection that only zeroed the directional part, or scaled the light down, fails here).
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(-1.f, 1.f), pos(0.f, 1.f);
  for (int i = 0; i < 300; ++i) {
    const ShLight y = from_light(Eigen::Vector3f(u(rng), u(rng), u(rng)) + Eigen::Vector3f(0, 0, 0.01f),
                                 Eigen::Vector3f(pos(rng), pos(rng), pos(rng)), 4.f * pos(rng), 2.f * pos(rng));
    for (int c = 0; c < 3; ++c) {
      double inner = 0;
      for (int k = 0; k < 9; ++k) {
        const size_t q = static_cast<size_t>(9 * c + k);
        inner += double(drifted[q] - l[q]) * (y[q] - l[q]);
      }
      EXPECT_LE(inner, 1e-3) << "room " << i << ", channel " << c << ": a plausible light nearer to the drifted one";
    }
  }
}

TEST(PlausibleLight, OnlyTheImplausibleChannelMovesAndNonFiniteValuesAreLeftAlone) {
  ShLight l = from_light({0, 0.3f, -1}, {1, 0.8f, 0.6f}, 1.5f, 0.3f);
  const ShLight original = l;
  for (int k = 0; k < 9; ++k) l[static_cast<size_t>(18 + k)] = -0.5f * original[static_cast<size_t>(k)];  // blue: negative light
  const LightProjection p = ProjectToPlausibleLight(&l);
  EXPECT_TRUE(p.changed);
  for (int k = 0; k < 18; ++k) EXPECT_EQ(l[static_cast<size_t>(k)], original[static_cast<size_t>(k)]);
  EXPECT_GE(LowestRelativeIrradiance(l, 2), -kNegativeLobe - 0.01f);
  ShLight bad = original;
  bad[3] = std::numeric_limits<float>::quiet_NaN();
  bad[18] = -5.f;  // blue implausible, but red is not finite: red is left, blue projected
  ProjectToPlausibleLight(&bad);
  EXPECT_TRUE(std::isnan(bad[3]));
  EXPECT_GE(bad[18], -1e-6f);
  ShLight zero{};
  EXPECT_FALSE(ProjectToPlausibleLight(&zero).changed);
  EXPECT_EQ(LowestRelativeIrradiance(zero, 0), 0.f);
}

}  // namespace
}  // namespace face_reenact::tracker
