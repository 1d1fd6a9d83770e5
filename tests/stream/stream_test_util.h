#pragma once
// Helpers shared by the stream tests: deterministic frames and keys, and an encoder written
// independently from docs/stream-protocol.md (so tests can build datagrams the library's own
// encoder refuses to produce: NaN values, bad flags, wrong versions).
#include <sodium.h>

#include <array>
#include <chrono>
#include <cstdint>
#include <cstring>
#include <functional>
#include <random>
#include <thread>
#include <vector>

#include "face_reenact/stream/protocol.h"
#include "face_reenact/stream/stream_key.h"

namespace face_reenact::stream::testing {

inline StreamKey test_key(uint8_t seed = 7) {
  std::array<uint8_t, kKeySize> b;
  for (size_t i = 0; i < b.size(); ++i) b[i] = static_cast<uint8_t>(seed * 31 + i * 7);
  return StreamKey(b);
}

inline ExpressionFrame make_frame(uint32_t seed, bool with_neutral = false, bool with_pose = false) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  ExpressionFrame f;
  f.capture_time_us = 1'700'000'000'000'000ull + seed;
  for (float& c : f.expression) c = u(rng);
  f.neutral_subtracted = !with_neutral;
  if (with_neutral)
    for (float& c : f.neutral) c = 0.1f * u(rng);
  if (with_pose) {
    f.has_rotation = true;
    f.rotation = {0.1f * u(rng), -0.2f * u(rng), 0.05f};
    f.has_translation = true;
    f.translation = {0.01f, -0.02f, 0.6f};
  }
  return f;
}

// Spec-level encoder: header fields as given, payload as given (already serialised), encrypted
// with XChaCha20-Poly1305-IETF over the 20-byte header.
struct RawDatagram {
  std::array<uint8_t, 4> magic = {'F', 'R', 'E', 'X'};
  uint8_t version = 1;
  uint8_t flags = kNeutralSubtracted;
  uint16_t reserved = 0;
  uint32_t stream_id = 1;
  uint64_t sequence = 1;
  std::vector<uint8_t> payload;  // plaintext
};

inline void put_le(std::vector<uint8_t>& v, uint64_t x, int bytes) {
  for (int i = 0; i < bytes; ++i) v.push_back(static_cast<uint8_t>(x >> (8 * i)));
}
inline void put_f32(std::vector<uint8_t>& v, float f) {
  uint32_t u;
  std::memcpy(&u, &f, 4);
  put_le(v, u, 4);
}

// Serialises a frame's payload per the spec (the flags must match the frame).
inline std::vector<uint8_t> spec_payload(const ExpressionFrame& f) {
  std::vector<uint8_t> p;
  put_le(p, f.capture_time_us, 8);
  for (float c : f.expression) put_f32(p, c);
  if (!f.neutral_subtracted)
    for (float c : f.neutral) put_f32(p, c);
  if (f.has_rotation)
    for (float c : f.rotation) put_f32(p, c);
  if (f.has_translation)
    for (float c : f.translation) put_f32(p, c);
  return p;
}
inline uint8_t spec_flags(const ExpressionFrame& f) {
  uint8_t fl = f.neutral_subtracted ? 1 : 2;
  if (f.has_rotation) fl |= 4;
  if (f.has_translation) fl |= 8;
  return fl;
}

inline std::vector<uint8_t> spec_encode(const StreamKey& key, const RawDatagram& r) {
  if (sodium_init() < 0) return {};
  std::vector<uint8_t> d;
  d.insert(d.end(), r.magic.begin(), r.magic.end());
  d.push_back(r.version);
  d.push_back(r.flags);
  put_le(d, r.reserved, 2);
  put_le(d, r.stream_id, 4);
  put_le(d, r.sequence, 8);
  std::array<uint8_t, 24> nonce;
  randombytes_buf(nonce.data(), nonce.size());
  d.insert(d.end(), nonce.begin(), nonce.end());
  std::vector<uint8_t> c(r.payload.size() + 16);
  unsigned long long clen = 0;
  crypto_aead_xchacha20poly1305_ietf_encrypt(c.data(), &clen, r.payload.data(), r.payload.size(), d.data(), 20,
                                             nullptr, nonce.data(), key.bytes().data());
  d.insert(d.end(), c.begin(), c.begin() + static_cast<long>(clen));
  return d;
}

inline std::vector<uint8_t> encode(const StreamKey& key, uint32_t stream, uint64_t seq, const ExpressionFrame& f) {
  std::array<uint8_t, kMaxDatagramSize> buf;
  const size_t n = encode_datagram(key, stream, seq, f, buf);
  return std::vector<uint8_t>(buf.begin(), buf.begin() + static_cast<long>(n));
}

// Polls `done` every 5 ms until it holds or `limit` passes (for events on other threads).
inline bool wait_for(const std::function<bool()>& done, std::chrono::milliseconds limit = std::chrono::seconds(10)) {
  const auto end = std::chrono::steady_clock::now() + limit;
  while (std::chrono::steady_clock::now() < end) {
    if (done()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return done();
}

}  // namespace face_reenact::stream::testing
