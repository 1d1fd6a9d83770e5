#include "face_reenact/stream/replay_window.h"

namespace face_reenact::stream {

bool ReplayWindow::test_bit(uint64_t s) const {
  const uint64_t i = s % kSize;
  return (bits_[i / 64] >> (i % 64)) & 1u;
}

void ReplayWindow::set_bit(uint64_t s) {
  const uint64_t i = s % kSize;
  bits_[i / 64] |= uint64_t(1) << (i % 64);
}

void ReplayWindow::clear_bit(uint64_t s) {
  const uint64_t i = s % kSize;
  bits_[i / 64] &= ~(uint64_t(1) << (i % 64));
}

ReplayWindow::Verdict ReplayWindow::check(uint64_t s) const {
  if (empty_ || s > highest_) return Verdict::kNew;
  if (highest_ - s >= kSize) return Verdict::kTooOld;
  return test_bit(s) ? Verdict::kDuplicate : Verdict::kNew;
}

void ReplayWindow::mark(uint64_t s) {
  if (empty_) {
    bits_.fill(0);
    empty_ = false;
    highest_ = s;
    set_bit(s);
    return;
  }
  if (s > highest_) {
    const uint64_t advance = s - highest_;
    if (advance >= kSize) {
      bits_.fill(0);
    } else {
      // Forget the slots that now fall out of the window (they are reused by the new numbers).
      for (uint64_t k = highest_ + 1; k <= s; ++k) clear_bit(k);
    }
    highest_ = s;
  } else if (highest_ - s >= kSize) {
    return;  // too old: check() refuses these; nothing to record
  }
  set_bit(s);
}

void ReplayWindow::reset() {
  empty_ = true;
  highest_ = 0;
  bits_.fill(0);
}

}  // namespace face_reenact::stream
