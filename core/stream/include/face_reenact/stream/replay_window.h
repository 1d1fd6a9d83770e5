#pragma once
// Anti-replay sliding window over 64-bit sequence numbers (the scheme of IPsec ESP, RFC 4303
// Appendix A, and WireGuard): the highest sequence accepted so far plus a bitmap of which of the
// kSize sequence numbers below it were seen. Fixed size, no allocation.
//
// Usage: check() before the (expensive) authentication, mark() only after it succeeded, so a
// forged datagram can never advance the window.
#include <array>
#include <cstddef>
#include <cstdint>

namespace face_reenact::stream {

class ReplayWindow {
 public:
  static constexpr uint64_t kSize = 1024;  // sequence numbers remembered below the highest

  enum class Verdict { kNew, kDuplicate, kTooOld };

  Verdict check(uint64_t sequence) const;
  // Records `sequence` as seen (call only for authenticated datagrams that check() accepted).
  void mark(uint64_t sequence);
  void reset();

  bool empty() const { return empty_; }
  uint64_t highest() const { return highest_; }

 private:
  static constexpr std::size_t kWords = kSize / 64;
  bool test_bit(uint64_t sequence) const;
  void set_bit(uint64_t sequence);
  void clear_bit(uint64_t sequence);

  bool empty_ = true;
  uint64_t highest_ = 0;
  // Bit (s mod kSize) is set when s was seen, for s in (highest - kSize, highest].
  std::array<uint64_t, kWords> bits_{};
};

}  // namespace face_reenact::stream
