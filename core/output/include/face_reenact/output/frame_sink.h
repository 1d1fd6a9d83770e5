#pragma once
// Where paced frames go: the V4L2 loopback writer, or a test double.
#include <cstdint>
#include <span>
#include <string>

namespace face_reenact::output {

enum class WriteOutcome {
  kWritten,
  kTransientError,  // EAGAIN, EINTR, EPIPE, EBUSY, a short write: try again at the next frame
  kDeviceLost,      // ENODEV, ENXIO, EIO, EBADF, EINVAL (format gone): close and reopen later
};

class FrameSink {
 public:
  virtual ~FrameSink() = default;
  // Writes one whole frame. Never throws; on failure *error says why.
  virtual WriteOutcome write_frame(std::span<const uint8_t> frame, std::string* error) = 0;
  // Closes (if open) and sets the device up again. Never throws; false with *error on failure.
  virtual bool reopen(std::string* error) = 0;
  virtual void close() = 0;
};

}  // namespace face_reenact::output
