#pragma once
// Clean shutdown of the stream services on SIGINT/SIGTERM without doing anything in a signal
// handler: the signals are blocked and read from a signalfd by the main loop.
//
// Construct it before starting any thread: threads inherit the blocked mask, so the signal is
// never delivered to (and the process never killed through) a thread that does not expect it.
#include <chrono>

namespace face_reenact::stream {

class ShutdownSignals {
 public:
  ShutdownSignals();   // blocks SIGINT and SIGTERM in this thread, opens the signalfd
  ~ShutdownSignals();  // closes it and restores the previous mask
  ShutdownSignals(const ShutdownSignals&) = delete;
  ShutdownSignals& operator=(const ShutdownSignals&) = delete;

  int fd() const { return fd_; }
  // Waits up to `timeout` (0: just checks) and returns the signal received, or 0.
  int wait(std::chrono::milliseconds timeout);
  // The first signal seen so far, or 0.
  int received() const { return received_; }

 private:
  int fd_ = -1;
  int received_ = 0;
  unsigned char old_mask_[128];  // sigset_t, kept opaque here
};

}  // namespace face_reenact::stream
