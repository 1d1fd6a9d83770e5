#pragma once
// The expression-stream datagram (spec: docs/stream-protocol.md). This header is the ONE
// definition of the layout: every offset and size below is used by both the encoder and the
// decoder, and the spec document is written from it.
//
// A datagram is a fixed, little-endian layout (no variable-length fields, so no length is ever
// read from the wire):
//
//   offset size  field
//   0      4     magic "FREX" (0x46 0x52 0x45 0x58)
//   4      1     version (1)
//   5      1     flags (DatagramFlag bits; unknown bits must be 0)
//   6      2     reserved, must be 0
//   8      4     stream id (u32)
//   12     8     sequence number (u64)
//   20     24    nonce (random per datagram, XChaCha20-Poly1305-IETF)
//   44     P     ciphertext of the payload below
//   44+P   16    Poly1305 tag
//
// Bytes 0..19 (the header) are the AEAD's associated data, so a receiver can route and
// replay-check on them before decrypting, yet any change to them fails authentication.
//
// Payload (plaintext, P bytes, size fixed by the flags):
//   0      8     capture time, microseconds since the Unix epoch on the sender's clock (u64)
//   8      208   52 expression coefficients (f32), ARKit order (arkit_blendshape_names())
//   [208         52 neutral-expression coefficients (f32)     if kHasNeutral]
//   [12          head rotation, axis-angle radians (3 x f32)   if kHasRotation]
//   [12          head translation, metres (3 x f32)            if kHasTranslation]
#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>

#include "face_reenact/stream/stream_key.h"

namespace face_reenact::stream {

inline constexpr int kNumCoefficients = 52;
inline constexpr std::array<uint8_t, 4> kDatagramMagic = {'F', 'R', 'E', 'X'};
inline constexpr uint8_t kProtocolVersion = 1;

enum DatagramFlag : uint8_t {
  kNeutralSubtracted = 1 << 0,  // coefficients are already relative to the sender's neutral face
  kHasNeutral = 1 << 1,         // the payload carries the sender's neutral coefficients
  kHasRotation = 1 << 2,
  kHasTranslation = 1 << 3,
};
inline constexpr uint8_t kKnownFlags = kNeutralSubtracted | kHasNeutral | kHasRotation | kHasTranslation;

// Layout constants (bytes).
inline constexpr size_t kHeaderSize = 20;  // the associated data
inline constexpr size_t kNonceOffset = 20;
inline constexpr size_t kNonceSize = 24;
inline constexpr size_t kCiphertextOffset = kNonceOffset + kNonceSize;  // 44
inline constexpr size_t kTagSize = 16;
inline constexpr size_t kPayloadBaseSize = 8 + 4 * kNumCoefficients;    // 216
inline constexpr size_t kNeutralSize = 4 * kNumCoefficients;            // 208
inline constexpr size_t kVectorSize = 12;
inline constexpr size_t kMaxPayloadSize = kPayloadBaseSize + kNeutralSize + 2 * kVectorSize;  // 448
inline constexpr size_t kMinDatagramSize = kCiphertextOffset + kPayloadBaseSize + kTagSize;   // 276
inline constexpr size_t kMaxDatagramSize = kCiphertextOffset + kMaxPayloadSize + kTagSize;    // 508

// Value limits a receiver enforces (and a sender checks before sending). ARKit coefficients
// live in [0, 1]; a relative expression (minus neutral) in [-1, 1]; trackers overshoot a little.
inline constexpr float kMaxAbsCoefficient = 2.0f;
inline constexpr float kMaxRotationAngle = 6.2831855f;  // radians, norm of the axis-angle vector
inline constexpr float kMaxAbsTranslation = 100.0f;     // metres, per component

// One frame of expression parameters as it travels.
struct ExpressionFrame {
  uint64_t capture_time_us = 0;  // sender's CLOCK_REALTIME when the frame was captured
  std::array<float, kNumCoefficients> expression{};
  // True: `expression` is already relative to the sender's neutral face and `neutral` is unused.
  // False: `neutral` holds the sender's neutral-expression coefficients (paper Sec. 7.2).
  bool neutral_subtracted = true;
  std::array<float, kNumCoefficients> neutral{};
  bool has_rotation = false;
  std::array<float, 3> rotation{};  // axis-angle, radians, model frame (docs/face-model.md)
  bool has_translation = false;
  std::array<float, 3> translation{};  // metres

  // The expression relative to the sender's neutral face (what a target applies).
  std::array<float, kNumCoefficients> relative_expression() const;
};

struct DatagramHeader {
  uint8_t version = 0;
  uint8_t flags = 0;
  uint32_t stream_id = 0;
  uint64_t sequence = 0;
};

// Why a datagram was not used. Stable names (datagram_error_name) appear in statistics output.
enum class DatagramError : uint8_t {
  kNone = 0,
  kTruncated,      // shorter than the smallest datagram or than its flags require
  kOversized,      // longer than the largest datagram or than its flags require
  kBadMagic,
  kBadVersion,
  kBadFlags,       // unknown flag bits, nonzero reserved bytes, or neutral flags not exactly one
  kUnknownStream,  // stream id not allowed (or not the locked-on stream)
  kReplay,         // sequence number already seen (duplicate or replay)
  kTooOld,         // sequence number older than the replay window
  kAuthFailed,     // tag did not verify (forged, corrupted, or wrong key)
  kInvalidValues,  // authenticated, but NaN/inf/out-of-range values
  kCount
};
inline constexpr int kNumDatagramErrors = static_cast<int>(DatagramError::kCount);
const char* datagram_error_name(DatagramError e);

// Payload size that `flags` imply (assumes the flags are valid).
size_t payload_size_for_flags(uint8_t flags);
size_t datagram_size_for_flags(uint8_t flags);

// Checks a frame's values against the limits above; says which value is wrong in *why.
bool frame_values_valid(const ExpressionFrame& frame, std::string* why);

// Encrypts `frame` into `out` (kMaxDatagramSize bytes available) and returns the datagram
// length. The nonce is 24 random bytes from libsodium, so it never repeats under one key even
// across sender restarts. Throws face_reenact::Error if the frame's values are invalid.
size_t encode_datagram(const StreamKey& key, uint32_t stream_id, uint64_t sequence,
                       const ExpressionFrame& frame, std::span<uint8_t, kMaxDatagramSize> out);

// Parses and checks the cleartext header only (sizes, magic, version, flags): cheap, no crypto.
DatagramError parse_datagram_header(std::span<const uint8_t> datagram, DatagramHeader* header);

// Verifies and decrypts a datagram whose header parse_datagram_header accepted, then validates
// the values. Never allocates; on failure *frame is left zeroed.
DatagramError open_datagram(const StreamKey& key, std::span<const uint8_t> datagram,
                            const DatagramHeader& header, ExpressionFrame* frame);

// Both steps in one (for tests and tools that do no stream bookkeeping).
DatagramError decode_datagram(const StreamKey& key, std::span<const uint8_t> datagram,
                              DatagramHeader* header, ExpressionFrame* frame);

}  // namespace face_reenact::stream
