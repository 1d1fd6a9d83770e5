#pragma once
// Live Link Face (Epic's iPhone app) UDP packets, so an iPhone can be the puppeteer. The app
// has no published spec; the layout below is the reverse-engineered one (design notes §8),
// big-endian throughout:
//
//   u8   version (6)
//   i32  device id length L1 (0..kMaxLiveLinkString), then L1 bytes
//   i32  subject name length L2 (0..kMaxLiveLinkString), then L2 bytes
//   i32  frame number, f32 subframe, i32 frame-rate numerator, i32 denominator
//   u8   value count N (kMinLiveLinkValues..kLiveLinkValues; the app sends 61)
//   N x f32: 52 ARKit blendshapes (ARKit order), head yaw/pitch/roll, left eye yaw/pitch/roll,
//            right eye yaw/pitch/roll
//
// The parser reads nothing it has not bounds-checked, allocates at most the two bounded
// strings, and rejects trailing bytes, unknown versions and non-finite values.
#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "face_reenact/stream/protocol.h"

namespace face_reenact::stream {

inline constexpr uint8_t kLiveLinkVersion = 6;
inline constexpr size_t kMaxLiveLinkString = 256;
inline constexpr int kLiveLinkValues = 61;
inline constexpr int kMinLiveLinkValues = 52;  // blendshapes only, no head angles
inline constexpr uint16_t kLiveLinkDefaultPort = 11111;

struct LiveLinkPacket {
  uint8_t version = kLiveLinkVersion;
  std::string device_id;
  std::string subject_name;
  int32_t frame_number = 0;
  float subframe = 0;
  int32_t rate_numerator = 60;
  int32_t rate_denominator = 1;
  int num_values = kLiveLinkValues;
  std::array<float, kLiveLinkValues> values{};  // the first num_values are meaningful

  bool has_head_rotation() const { return num_values >= kMinLiveLinkValues + 3; }
  float head_yaw() const { return values[52]; }
  float head_pitch() const { return values[53]; }
  float head_roll() const { return values[54]; }
};

// Parses one packet. On failure returns false and says why in *why (never throws).
bool parse_livelink_packet(std::span<const uint8_t> bytes, LiveLinkPacket* packet, std::string* why);

// The packet's bytes (tests, fuzz seeds, and a simulator of the app).
std::vector<uint8_t> encode_livelink_packet(const LiveLinkPacket& packet);

// The 52 blendshapes (already relative to the neutral face in ARKit) and, when present, the
// head rotation: yaw about +y, pitch about +x, roll about +z of the model frame (radians,
// R = Ry(yaw) Rx(pitch) Rz(roll)), as an axis-angle vector. No translation (the app sends none).
ExpressionFrame livelink_to_frame(const LiveLinkPacket& packet, uint64_t capture_time_us);

}  // namespace face_reenact::stream
