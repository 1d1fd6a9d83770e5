#include "face_reenact/stream/livelink.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <limits>

namespace face_reenact::stream {
namespace {

LiveLinkPacket sample_packet() {
  LiveLinkPacket p;
  p.device_id = "6B0B6D3E-1D5F-4C49-9E5A-6A1C2C3D4E5F";
  p.subject_name = "iPhone";
  p.frame_number = 123456;
  p.subframe = 0.25f;
  p.rate_numerator = 60;
  p.rate_denominator = 1;
  for (int i = 0; i < kLiveLinkValues; ++i) p.values[i] = 0.01f * static_cast<float>(i % 50);
  p.values[52] = 0.2f;    // head yaw
  p.values[53] = -0.1f;   // pitch
  p.values[54] = 0.05f;   // roll
  return p;
}

void set_be32(std::vector<uint8_t>& b, size_t at, uint32_t v) {
  for (int k = 0; k < 4; ++k) b[at + k] = static_cast<uint8_t>(v >> (24 - 8 * k));
}

TEST(LiveLink, ParsesAWellFormedPacket) {
  const LiveLinkPacket p = sample_packet();
  const auto bytes = encode_livelink_packet(p);
  // 1 + 4+36 + 4+6 + 16 + 1 + 61*4
  EXPECT_EQ(bytes.size(), 1u + 40 + 10 + 16 + 1 + 244);
  EXPECT_EQ(bytes[0], 6);
  EXPECT_EQ(bytes[1], 0);  // big-endian length 36
  EXPECT_EQ(bytes[4], 36);
  LiveLinkPacket q;
  std::string why;
  ASSERT_TRUE(parse_livelink_packet(bytes, &q, &why)) << why;
  EXPECT_EQ(q.device_id, p.device_id);
  EXPECT_EQ(q.subject_name, "iPhone");
  EXPECT_EQ(q.frame_number, 123456);
  EXPECT_EQ(q.subframe, 0.25f);
  EXPECT_EQ(q.rate_numerator, 60);
  EXPECT_EQ(q.num_values, 61);
  EXPECT_EQ(q.values, p.values);
  EXPECT_TRUE(q.has_head_rotation());
}

TEST(LiveLink, BlendshapesOnlyPacketHasNoHeadPose) {
  LiveLinkPacket p = sample_packet();
  p.num_values = 52;
  LiveLinkPacket q;
  std::string why;
  ASSERT_TRUE(parse_livelink_packet(encode_livelink_packet(p), &q, &why)) << why;
  EXPECT_FALSE(q.has_head_rotation());
  EXPECT_FALSE(livelink_to_frame(q, 1).has_rotation);
}

TEST(LiveLink, EveryTruncationIsRejected) {
  const auto bytes = encode_livelink_packet(sample_packet());
  for (size_t n = 0; n < bytes.size(); ++n) {
    LiveLinkPacket q;
    std::string why;
    EXPECT_FALSE(parse_livelink_packet(std::span<const uint8_t>(bytes.data(), n), &q, &why)) << n;
    EXPECT_FALSE(why.empty());
  }
}

TEST(LiveLink, MalformedPacketsAreRejectedWithReasons) {
  const auto good = encode_livelink_packet(sample_packet());
  struct Case {
    const char* name;
    std::function<void(std::vector<uint8_t>&)> spoil;
    const char* reason;
  };
  const size_t count_at = 1 + 40 + 10 + 16;
  const std::vector<Case> cases = {
      {"version", [](auto& b) { b[0] = 5; }, "unsupported version"},
      {"negative length", [](auto& b) { set_be32(b, 1, 0xFFFFFFFFu); }, "outside"},
      {"huge length", [](auto& b) { set_be32(b, 1, 0x7FFFFFFFu); }, "outside"},
      {"length past end", [](auto& b) { set_be32(b, 1, 256); b.resize(100); }, "truncated"},
      {"count too big", [&](auto& b) { b[count_at] = 62; }, "value count"},
      {"count too small", [&](auto& b) { b[count_at] = 10; }, "value count"},
      {"count says more than sent", [&](auto& b) { b[count_at] = 61; b.resize(b.size() - 4); }, "values need"},
      {"trailing", [](auto& b) { b.push_back(0); }, "trailing"},
      {"nan value", [&](auto& b) { set_be32(b, count_at + 1 + 4 * 17, 0x7FC00000u); }, "not finite"},
      {"inf subframe", [&](auto& b) { set_be32(b, 1 + 40 + 10 + 4, 0x7F800000u); }, "subframe"},
  };
  for (const Case& c : cases) {
    auto b = good;
    c.spoil(b);
    LiveLinkPacket q;
    std::string why;
    EXPECT_FALSE(parse_livelink_packet(b, &q, &why)) << c.name;
    EXPECT_NE(why.find(c.reason), std::string::npos) << c.name << ": " << why;
  }
}

TEST(LiveLink, ConvertsToAFrameWithHeadRotation) {
  LiveLinkPacket p = sample_packet();
  const ExpressionFrame f = livelink_to_frame(p, 77);
  EXPECT_EQ(f.capture_time_us, 77u);
  EXPECT_TRUE(f.neutral_subtracted);
  for (int i = 0; i < kNumCoefficients; ++i) EXPECT_EQ(f.expression[i], p.values[i]);
  ASSERT_TRUE(f.has_rotation);
  EXPECT_FALSE(f.has_translation);
  // The axis-angle vector reproduces R = Ry(yaw) Rx(pitch) Rz(roll).
  const Eigen::Vector3f v(f.rotation[0], f.rotation[1], f.rotation[2]);
  const Eigen::Matrix3f got = Eigen::AngleAxisf(v.norm(), v.normalized()).toRotationMatrix();
  const Eigen::Matrix3f want = (Eigen::AngleAxisf(0.2f, Eigen::Vector3f::UnitY()) *
                                Eigen::AngleAxisf(-0.1f, Eigen::Vector3f::UnitX()) *
                                Eigen::AngleAxisf(0.05f, Eigen::Vector3f::UnitZ())).toRotationMatrix();
  EXPECT_LT((got - want).norm(), 1e-5f);
  // Pure yaw is a rotation about +y.
  p.values[53] = p.values[54] = 0;
  const ExpressionFrame y = livelink_to_frame(p, 0);
  EXPECT_NEAR(y.rotation[0], 0, 1e-6);
  EXPECT_NEAR(y.rotation[1], 0.2f, 1e-6);
  EXPECT_NEAR(y.rotation[2], 0, 1e-6);
  // Zero rotation stays finite.
  p.values[52] = 0;
  const ExpressionFrame z = livelink_to_frame(p, 0);
  for (float r : z.rotation) EXPECT_TRUE(std::isfinite(r));
  std::string why;
  EXPECT_TRUE(frame_values_valid(z, &why)) << why;
}

}  // namespace
}  // namespace face_reenact::stream
