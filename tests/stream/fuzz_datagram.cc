// libFuzzer target: the datagram parser/verifier and the receiver's stream bookkeeping.
// Input byte 0 picks the mode:
//   even: the rest is a datagram as it would arrive from the network;
//   odd:  the rest is a 20-byte header + plaintext payload, encrypted here with the fuzz key so
//         inputs get past authentication and exercise value validation and stream state.
// Invariants checked (trap on violation): a datagram that decodes re-encodes to the same
// values; statistics always balance; nothing is applied that was rejected.
#include <sodium.h>

#include <cstdint>
#include <cstring>
#include <vector>

#include "face_reenact/stream/protocol.h"
#include "face_reenact/stream/stream_state.h"

using namespace face_reenact::stream;

namespace {

const StreamKey& fuzz_key() {
  static const StreamKey key = [] {
    std::array<uint8_t, kKeySize> b;
    for (size_t i = 0; i < b.size(); ++i) b[i] = static_cast<uint8_t>(i * 13 + 1);
    return StreamKey(b);
  }();
  return key;
}

void check(bool ok) {
  if (!ok) __builtin_trap();
}

void exercise(std::span<const uint8_t> d) {
  DatagramHeader h;
  ExpressionFrame f;
  const DatagramError e = decode_datagram(fuzz_key(), d, &h, &f);
  if (e == DatagramError::kNone) {
    std::string why;
    check(frame_values_valid(f, &why));
    std::array<uint8_t, kMaxDatagramSize> buf;
    const size_t n = encode_datagram(fuzz_key(), h.stream_id, h.sequence, f, buf);
    check(n == d.size());
    DatagramHeader h2;
    ExpressionFrame f2;
    check(decode_datagram(fuzz_key(), std::span<const uint8_t>(buf.data(), n), &h2, &f2) == DatagramError::kNone);
    check(h2.flags == h.flags && h2.stream_id == h.stream_id && h2.sequence == h.sequence);
    check(std::memcmp(f2.expression.data(), f.expression.data(), sizeof(f.expression)) == 0);
  }
  ExpressionStreamState state(fuzz_key(), {});
  const auto t = SteadyClock::now();
  const DatagramError first = state.process(d, t, 0);
  check(first == e);
  const DatagramError again = state.process(d, t, 0);
  if (e == DatagramError::kNone || e == DatagramError::kInvalidValues) check(again == DatagramError::kReplay);
  const ReceiverStatistics s = state.statistics(t);
  check(s.received == 2);
  check(s.received == s.applied + s.reordered + s.late + s.standby + s.rejected_total());
  check(state.sample(t).has_frame == (e == DatagramError::kNone));
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0 || sodium_init() < 0) return 0;
  const std::span<const uint8_t> rest(data + 1, size - 1);
  if ((data[0] & 1) == 0) {
    exercise(rest);
    return 0;
  }
  if (rest.size() < kHeaderSize || rest.size() > kHeaderSize + 4096) return 0;
  const size_t plain = rest.size() - kHeaderSize;
  std::vector<uint8_t> d(kCiphertextOffset + plain + kTagSize);
  std::memcpy(d.data(), rest.data(), kHeaderSize);
  std::memset(d.data() + kNonceOffset, 0x5A, kNonceSize);
  unsigned long long clen = 0;
  crypto_aead_xchacha20poly1305_ietf_encrypt(d.data() + kCiphertextOffset, &clen, rest.data() + kHeaderSize, plain,
                                             d.data(), kHeaderSize, nullptr, d.data() + kNonceOffset,
                                             fuzz_key().bytes().data());
  exercise(d);
  return 0;
}
