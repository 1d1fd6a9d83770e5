#include "face_reenact/stream/livelink.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstring>

namespace face_reenact::stream {
namespace {

// Big-endian cursor that reports failure instead of reading past the end.
class BigEndianReader {
 public:
  explicit BigEndianReader(std::span<const uint8_t> b) : b_(b) {}
  bool u8(uint8_t* v) {
    if (left() < 1) return false;
    *v = b_[pos_++];
    return true;
  }
  bool u32(uint32_t* v) {
    if (left() < 4) return false;
    *v = (uint32_t(b_[pos_]) << 24) | (uint32_t(b_[pos_ + 1]) << 16) | (uint32_t(b_[pos_ + 2]) << 8) |
         uint32_t(b_[pos_ + 3]);
    pos_ += 4;
    return true;
  }
  bool i32(int32_t* v) {
    uint32_t u;
    if (!u32(&u)) return false;
    *v = static_cast<int32_t>(u);
    return true;
  }
  bool f32(float* v) {
    uint32_t u;
    if (!u32(&u)) return false;
    std::memcpy(v, &u, 4);
    return true;
  }
  bool bytes(size_t n, std::string* out) {
    if (left() < n) return false;
    out->assign(reinterpret_cast<const char*>(b_.data() + pos_), n);
    pos_ += n;
    return true;
  }
  size_t left() const { return b_.size() - pos_; }
  size_t pos() const { return pos_; }

 private:
  std::span<const uint8_t> b_;
  size_t pos_ = 0;
};

void put_u32(std::vector<uint8_t>& out, uint32_t v) {
  for (int s = 24; s >= 0; s -= 8) out.push_back(static_cast<uint8_t>(v >> s));
}
void put_f32(std::vector<uint8_t>& out, float f) {
  uint32_t u;
  std::memcpy(&u, &f, 4);
  put_u32(out, u);
}

}  // namespace

bool parse_livelink_packet(std::span<const uint8_t> bytes, LiveLinkPacket* packet, std::string* why) {
  auto fail = [&](const std::string& m, size_t at) {
    if (why) *why = "Live Link packet: " + m + " (at byte " + std::to_string(at) + " of " + std::to_string(bytes.size()) + ")";
    return false;
  };
  BigEndianReader r(bytes);
  LiveLinkPacket p;
  if (!r.u8(&p.version)) return fail("empty packet", 0);
  if (p.version != kLiveLinkVersion)
    return fail("unsupported version " + std::to_string(p.version) + " (expected " +
                    std::to_string(kLiveLinkVersion) + ")", 0);
  for (std::string* s : {&p.device_id, &p.subject_name}) {
    const char* what = s == &p.device_id ? "device id" : "subject name";
    int32_t len;
    const size_t at = r.pos();
    if (!r.i32(&len)) return fail(std::string("truncated before the ") + what + " length", at);
    if (len < 0 || static_cast<size_t>(len) > kMaxLiveLinkString)
      return fail(std::string(what) + " length " + std::to_string(len) + " outside 0.." +
                      std::to_string(kMaxLiveLinkString), at);
    if (!r.bytes(static_cast<size_t>(len), s))
      return fail(std::string(what) + " of " + std::to_string(len) + " bytes is truncated", r.pos());
  }
  if (!r.i32(&p.frame_number) || !r.f32(&p.subframe) || !r.i32(&p.rate_numerator) ||
      !r.i32(&p.rate_denominator))
    return fail("truncated frame time", r.pos());
  if (!std::isfinite(p.subframe)) return fail("subframe is not finite", r.pos());
  uint8_t count;
  if (!r.u8(&count)) return fail("truncated before the value count", r.pos());
  if (count < kMinLiveLinkValues || count > kLiveLinkValues)
    return fail("value count " + std::to_string(count) + " outside " + std::to_string(kMinLiveLinkValues) +
                    ".." + std::to_string(kLiveLinkValues), r.pos() - 1);
  p.num_values = count;
  if (r.left() < 4u * count)
    return fail(std::to_string(count) + " values need " + std::to_string(4 * count) + " bytes, " +
                    std::to_string(r.left()) + " left", r.pos());
  for (int i = 0; i < count; ++i) {
    r.f32(&p.values[i]);
    if (!std::isfinite(p.values[i])) return fail("value " + std::to_string(i) + " is not finite", r.pos() - 4);
  }
  if (r.left() != 0) return fail(std::to_string(r.left()) + " unexpected trailing bytes", r.pos());
  *packet = std::move(p);
  return true;
}

std::vector<uint8_t> encode_livelink_packet(const LiveLinkPacket& p) {
  std::vector<uint8_t> out;
  out.push_back(p.version);
  put_u32(out, static_cast<uint32_t>(p.device_id.size()));
  out.insert(out.end(), p.device_id.begin(), p.device_id.end());
  put_u32(out, static_cast<uint32_t>(p.subject_name.size()));
  out.insert(out.end(), p.subject_name.begin(), p.subject_name.end());
  put_u32(out, static_cast<uint32_t>(p.frame_number));
  put_f32(out, p.subframe);
  put_u32(out, static_cast<uint32_t>(p.rate_numerator));
  put_u32(out, static_cast<uint32_t>(p.rate_denominator));
  const int n = std::clamp(p.num_values, 0, kLiveLinkValues);
  out.push_back(static_cast<uint8_t>(n));
  for (int i = 0; i < n; ++i) put_f32(out, p.values[i]);
  return out;
}

ExpressionFrame livelink_to_frame(const LiveLinkPacket& packet, uint64_t capture_time_us) {
  ExpressionFrame f;
  f.capture_time_us = capture_time_us;
  for (int i = 0; i < kNumCoefficients; ++i) f.expression[i] = packet.values[i];
  f.neutral_subtracted = true;
  if (packet.has_head_rotation()) {
    const Eigen::Matrix3f rot = (Eigen::AngleAxisf(packet.head_yaw(), Eigen::Vector3f::UnitY()) *
                                 Eigen::AngleAxisf(packet.head_pitch(), Eigen::Vector3f::UnitX()) *
                                 Eigen::AngleAxisf(packet.head_roll(), Eigen::Vector3f::UnitZ()))
                                    .toRotationMatrix();
    const Eigen::AngleAxisf aa(rot);
    const Eigen::Vector3f v = aa.axis() * aa.angle();
    f.has_rotation = true;
    for (int k = 0; k < 3; ++k) f.rotation[k] = std::isfinite(v[k]) ? v[k] : 0.f;
  }
  return f;
}

}  // namespace face_reenact::stream
