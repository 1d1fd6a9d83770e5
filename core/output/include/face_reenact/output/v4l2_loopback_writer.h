#pragma once
// Writes raw frames into a v4l2loopback device: the producer side of a virtual webcam that
// Zoom, Meet (Chrome) and Firefox read as a camera. See docs/virtual-webcam.md.
//
// Set-up, in the order the driver needs it:
//   1. open the node and VIDIOC_QUERYCAP: it must be the v4l2loopback driver and announce
//      video *output* (with exclusive_caps=1 a device that another program is already
//      writing to announces only capture: that is reported as busy);
//   2. VIDIOC_S_FMT on the output queue (YUYV or I420, width x height), then read back what
//      the driver kept: v4l2loopback silently substitutes a format it does not know and keeps
//      the old one while readers hold the device, so a mismatch is an error that says so;
//   3. VIDIOC_S_PARM on the output queue: the frame rate readers see in VIDIOC_G_PARM;
//   4. VIDIOC_STREAMON on the output queue, the equivalent of OBS's start/stop: it registers
//      this file as *the writer*, which flips an exclusive_caps device to announce capture
//      (only then do Chrome/WebRTC list it) and makes the driver announce output again when we
//      close (a writer that only write()s leaves the device without output capability);
//   5. one priming frame (black) with write(), so a reader that opens the device right away
//      (apps probe cameras) gets a valid picture instead of a stall.
// Frames then go out with write(): one syscall and one copy per frame, no buffer queue to
// manage, and v4l2loopback 0.12 supports it on every kernel; a frame is a few MB at most, so
// the copy costs well under a millisecond.
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "face_reenact/output/frame_sink.h"
#include "face_reenact/output/frame_pacer.h"
#include "face_reenact/output/pixel_conversion.h"

namespace face_reenact::output {

class V4l2LoopbackWriter : public FrameSink {
 public:
  struct Options {
    std::string device = "/dev/video0";
    int width = 1280;
    int height = 720;
    FrameRate rate{30, 1};
    PixelFormat format = PixelFormat::kYuyv;
    bool prime = true;  // write a black frame right after set-up (see step 5)

    bool IsValid(std::string* error) const;
  };

  // What the device said during set-up (the command prints it).
  struct DeviceInfo {
    std::string driver, card, bus_info;
    uint32_t device_caps_before = 0;  // as found
    uint32_t device_caps_after = 0;   // after STREAMON + priming frame
    bool frame_rate_set = false;
    bool streamon_ok = false;
    std::vector<std::string> warnings;  // non-fatal set-up problems, in plain words
  };

  explicit V4l2LoopbackWriter(Options options);
  ~V4l2LoopbackWriter() override;
  V4l2LoopbackWriter(const V4l2LoopbackWriter&) = delete;
  V4l2LoopbackWriter& operator=(const V4l2LoopbackWriter&) = delete;

  // Opens and sets up the device (steps 1-5). Throws face_reenact::Error with what went wrong
  // and what to do (load the module, fix permissions, pick another device, ...).
  void open();
  bool is_open() const { return fd_ >= 0; }
  const DeviceInfo& device_info() const { return info_; }
  const Options& options() const { return options_; }
  size_t frame_size() const { return frame_size_; }

  // FrameSink: writes one frame of frame_size() bytes.
  WriteOutcome write_frame(std::span<const uint8_t> frame, std::string* error) override;
  bool reopen(std::string* error) override;
  void close() override;

 private:
  Options options_;
  size_t frame_size_;
  int fd_ = -1;
  DeviceInfo info_;
};

// Whether device_caps announce capture / output (single- or multi-planar).
bool caps_have_capture(uint32_t caps);
bool caps_have_output(uint32_t caps);

}  // namespace face_reenact::output
