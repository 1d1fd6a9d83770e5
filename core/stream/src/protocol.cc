#include "face_reenact/stream/protocol.h"

#include <sodium.h>

#include <cmath>
#include <cstring>

#include "face_reenact/common/error.h"

namespace face_reenact::stream {
namespace {

static_assert(kMaxDatagramSize <= 508, "a datagram must fit the smallest guaranteed IPv4 UDP payload");
static_assert(kNonceSize == crypto_aead_xchacha20poly1305_ietf_NPUBBYTES);
static_assert(kTagSize == crypto_aead_xchacha20poly1305_ietf_ABYTES);
static_assert(kKeySize == crypto_aead_xchacha20poly1305_ietf_KEYBYTES);

// Field offsets inside the header.
constexpr size_t kMagicOffset = 0;
constexpr size_t kVersionOffset = 4;
constexpr size_t kFlagsOffset = 5;
constexpr size_t kReservedOffset = 6;
constexpr size_t kStreamIdOffset = 8;
constexpr size_t kSequenceOffset = 12;
static_assert(kSequenceOffset + 8 == kHeaderSize);

void store_u32(uint8_t* p, uint32_t v) {
  for (int i = 0; i < 4; ++i) p[i] = static_cast<uint8_t>(v >> (8 * i));
}
void store_u64(uint8_t* p, uint64_t v) {
  for (int i = 0; i < 8; ++i) p[i] = static_cast<uint8_t>(v >> (8 * i));
}
void store_f32(uint8_t* p, float f) {
  uint32_t u;
  std::memcpy(&u, &f, 4);
  store_u32(p, u);
}
uint32_t load_u32(const uint8_t* p) {
  uint32_t v = 0;
  for (int i = 0; i < 4; ++i) v |= static_cast<uint32_t>(p[i]) << (8 * i);
  return v;
}
uint64_t load_u64(const uint8_t* p) {
  uint64_t v = 0;
  for (int i = 0; i < 8; ++i) v |= static_cast<uint64_t>(p[i]) << (8 * i);
  return v;
}
float load_f32(const uint8_t* p) {
  uint32_t u = load_u32(p);
  float f;
  std::memcpy(&f, &u, 4);
  return f;
}

bool coefficients_valid(const std::array<float, kNumCoefficients>& c, const char* what, std::string* why) {
  for (int i = 0; i < kNumCoefficients; ++i) {
    if (!std::isfinite(c[i]) || std::fabs(c[i]) > kMaxAbsCoefficient) {
      if (why)
        *why = std::string(what) + " coefficient " + std::to_string(i) + " is " + std::to_string(c[i]) +
               " (must be finite, |x| <= " + std::to_string(kMaxAbsCoefficient) + ")";
      return false;
    }
  }
  return true;
}

uint8_t flags_for_frame(const ExpressionFrame& frame) {
  uint8_t flags = frame.neutral_subtracted ? kNeutralSubtracted : kHasNeutral;
  if (frame.has_rotation) flags |= kHasRotation;
  if (frame.has_translation) flags |= kHasTranslation;
  return flags;
}

}  // namespace

std::array<float, kNumCoefficients> ExpressionFrame::relative_expression() const {
  std::array<float, kNumCoefficients> r = expression;
  if (!neutral_subtracted)
    for (int i = 0; i < kNumCoefficients; ++i) r[i] -= neutral[i];
  return r;
}

const char* datagram_error_name(DatagramError e) {
  switch (e) {
    case DatagramError::kNone: return "none";
    case DatagramError::kTruncated: return "truncated";
    case DatagramError::kOversized: return "oversized";
    case DatagramError::kBadMagic: return "bad_magic";
    case DatagramError::kBadVersion: return "bad_version";
    case DatagramError::kBadFlags: return "bad_flags";
    case DatagramError::kUnknownStream: return "unknown_stream";
    case DatagramError::kReplay: return "replay";
    case DatagramError::kTooOld: return "too_old";
    case DatagramError::kAuthFailed: return "auth_failed";
    case DatagramError::kInvalidValues: return "invalid_values";
    case DatagramError::kCount: break;
  }
  return "unknown";
}

size_t payload_size_for_flags(uint8_t flags) {
  size_t n = kPayloadBaseSize;
  if (flags & kHasNeutral) n += kNeutralSize;
  if (flags & kHasRotation) n += kVectorSize;
  if (flags & kHasTranslation) n += kVectorSize;
  return n;
}

size_t datagram_size_for_flags(uint8_t flags) {
  return kCiphertextOffset + payload_size_for_flags(flags) + kTagSize;
}

bool frame_values_valid(const ExpressionFrame& frame, std::string* why) {
  if (!coefficients_valid(frame.expression, "expression", why)) return false;
  if (!frame.neutral_subtracted && !coefficients_valid(frame.neutral, "neutral", why)) return false;
  if (frame.has_rotation) {
    double n2 = 0;
    for (float r : frame.rotation) {
      if (!std::isfinite(r)) {
        if (why) *why = "head rotation is not finite";
        return false;
      }
      n2 += double(r) * r;
    }
    if (std::sqrt(n2) > kMaxRotationAngle) {
      if (why) *why = "head rotation angle " + std::to_string(std::sqrt(n2)) + " rad exceeds 2*pi";
      return false;
    }
  }
  if (frame.has_translation) {
    for (float t : frame.translation) {
      if (!std::isfinite(t) || std::fabs(t) > kMaxAbsTranslation) {
        if (why) *why = "head translation " + std::to_string(t) + " m is not finite or exceeds 100 m";
        return false;
      }
    }
  }
  return true;
}

size_t encode_datagram(const StreamKey& key, uint32_t stream_id, uint64_t sequence,
                       const ExpressionFrame& frame, std::span<uint8_t, kMaxDatagramSize> out) {
  std::string why;
  if (!frame_values_valid(frame, &why)) throw Error("cannot send expression frame: " + why);
  if (sodium_init() < 0) throw Error("libsodium failed to initialise");
  const uint8_t flags = flags_for_frame(frame);
  uint8_t* d = out.data();
  std::memcpy(d + kMagicOffset, kDatagramMagic.data(), kDatagramMagic.size());
  d[kVersionOffset] = kProtocolVersion;
  d[kFlagsOffset] = flags;
  d[kReservedOffset] = 0;
  d[kReservedOffset + 1] = 0;
  store_u32(d + kStreamIdOffset, stream_id);
  store_u64(d + kSequenceOffset, sequence);
  randombytes_buf(d + kNonceOffset, kNonceSize);

  // Serialise the payload in place, then encrypt it in place (libsodium allows m == c).
  uint8_t* p = d + kCiphertextOffset;
  size_t off = 0;
  store_u64(p + off, frame.capture_time_us);
  off += 8;
  for (float c : frame.expression) store_f32(p + off, c), off += 4;
  if (flags & kHasNeutral)
    for (float c : frame.neutral) store_f32(p + off, c), off += 4;
  if (flags & kHasRotation)
    for (float c : frame.rotation) store_f32(p + off, c), off += 4;
  if (flags & kHasTranslation)
    for (float c : frame.translation) store_f32(p + off, c), off += 4;

  unsigned long long clen = 0;
  crypto_aead_xchacha20poly1305_ietf_encrypt(p, &clen, p, off, d, kHeaderSize, nullptr,
                                             d + kNonceOffset, key.bytes().data());
  return kCiphertextOffset + static_cast<size_t>(clen);
}

DatagramError parse_datagram_header(std::span<const uint8_t> datagram, DatagramHeader* header) {
  if (datagram.size() < kMinDatagramSize) return DatagramError::kTruncated;
  if (datagram.size() > kMaxDatagramSize) return DatagramError::kOversized;
  const uint8_t* d = datagram.data();
  if (std::memcmp(d + kMagicOffset, kDatagramMagic.data(), kDatagramMagic.size()) != 0)
    return DatagramError::kBadMagic;
  if (d[kVersionOffset] != kProtocolVersion) return DatagramError::kBadVersion;
  const uint8_t flags = d[kFlagsOffset];
  const bool subtracted = flags & kNeutralSubtracted, has_neutral = flags & kHasNeutral;
  if ((flags & ~kKnownFlags) != 0 || subtracted == has_neutral || d[kReservedOffset] != 0 ||
      d[kReservedOffset + 1] != 0)
    return DatagramError::kBadFlags;
  const size_t expected = datagram_size_for_flags(flags);
  if (datagram.size() < expected) return DatagramError::kTruncated;
  if (datagram.size() > expected) return DatagramError::kOversized;
  header->version = d[kVersionOffset];
  header->flags = flags;
  header->stream_id = load_u32(d + kStreamIdOffset);
  header->sequence = load_u64(d + kSequenceOffset);
  return DatagramError::kNone;
}

DatagramError open_datagram(const StreamKey& key, std::span<const uint8_t> datagram,
                            const DatagramHeader& header, ExpressionFrame* frame) {
  *frame = ExpressionFrame{};
  const size_t plen = payload_size_for_flags(header.flags);
  if (datagram.size() != kCiphertextOffset + plen + kTagSize) return DatagramError::kTruncated;
  const uint8_t* d = datagram.data();
  uint8_t plain[kMaxPayloadSize];
  unsigned long long mlen = 0;
  if (crypto_aead_xchacha20poly1305_ietf_decrypt(plain, &mlen, nullptr, d + kCiphertextOffset,
                                                 plen + kTagSize, d, kHeaderSize, d + kNonceOffset,
                                                 key.bytes().data()) != 0 ||
      mlen != plen)
    return DatagramError::kAuthFailed;

  size_t off = 0;
  frame->capture_time_us = load_u64(plain + off);
  off += 8;
  for (float& c : frame->expression) c = load_f32(plain + off), off += 4;
  frame->neutral_subtracted = (header.flags & kNeutralSubtracted) != 0;
  if (header.flags & kHasNeutral)
    for (float& c : frame->neutral) c = load_f32(plain + off), off += 4;
  frame->has_rotation = (header.flags & kHasRotation) != 0;
  if (frame->has_rotation)
    for (float& c : frame->rotation) c = load_f32(plain + off), off += 4;
  frame->has_translation = (header.flags & kHasTranslation) != 0;
  if (frame->has_translation)
    for (float& c : frame->translation) c = load_f32(plain + off), off += 4;
  sodium_memzero(plain, sizeof(plain));
  if (!frame_values_valid(*frame, nullptr)) {
    *frame = ExpressionFrame{};
    return DatagramError::kInvalidValues;
  }
  return DatagramError::kNone;
}

DatagramError decode_datagram(const StreamKey& key, std::span<const uint8_t> datagram,
                              DatagramHeader* header, ExpressionFrame* frame) {
  *frame = ExpressionFrame{};
  DatagramError e = parse_datagram_header(datagram, header);
  if (e != DatagramError::kNone) return e;
  return open_datagram(key, datagram, *header, frame);
}

}  // namespace face_reenact::stream
