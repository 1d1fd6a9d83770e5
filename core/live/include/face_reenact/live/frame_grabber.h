#pragma once
// A capture thread for one live input (camera, OpenNI device, looping recording): it opens the
// input, reads frames as fast as the input delivers them (a recording at its own frame rate),
// and keeps only the newest one, so a slow consumer never builds up latency. An input that
// fails to open or stops delivering (a camera unplugged, a recording deleted) is reported in the
// status and reopened every reopen_interval until it comes back or the grabber stops.
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include "face_reenact/capture/recording.h"
#include "face_reenact/live/input_spec.h"

namespace face_reenact::live {

struct GrabberOptions {
  InputSpec input;                   // kCamera, kOpenNi or kRecording
  int camera_width = 640;            // requested from cameras (they may pick another size)
  int camera_height = 480;
  double camera_fps = 30;
  double camera_fov_deg = 60;        // horizontal field of view assumed for V4L2 cameras
  bool loop = true;                  // recordings: start again at the end (else: end of input)
  // Files read by an offline command (`track`, `reenact`): every frame in order, as fast as they
  // are asked for, instead of at the file's own speed (an .oni's driver would skip the frames a
  // slow reader misses, as a camera does).
  bool every_frame = false;
  // How often an input that cannot be opened is tried again. An OpenNI camera is also tried the
  // moment one arrives on USB (UsbRgbdHotplug, where libusb can see arrivals).
  std::chrono::milliseconds reopen_interval{1000};
  std::string thread_name = "fr-live-grab";  // at most 15 characters (Linux limit)

  bool IsValid(std::string* why) const;
};

struct GrabberStatus {
  bool open = false;          // the input is open and delivering
  bool ended = false;         // a recording without loop reached its end
  std::string description;    // what the input is, once opened ("recording 'x' 160x120 @ 30 fps")
  std::string error;          // why it is not open / the last failure (empty while delivering)
  int64_t frames = 0;         // frames read since start
  int64_t open_attempts = 0;  // opens tried (the first included)
  int64_t losses = 0;         // times an open input stopped delivering
  double fps = 0;             // frames per second over the last second or so
  int64_t usb_arrivals = 0;   // RGB-D cameras plugged in while this (OpenNI) input was watching
};

// An opened input: reads frames one at a time. Implementations throw face_reenact::Error when
// the input fails (the grabber closes it and retries).
class InputDevice {
 public:
  virtual ~InputDevice() = default;
  // The next frame; false at the end of a recording (not looping). Blocks for at most about a
  // frame period (cameras) or not at all (recordings: the grabber paces by timestamp_s).
  virtual bool read(capture::RgbdFrame* frame) = 0;
  virtual bool paced_by_timestamps() const = 0;  // recordings: frames are due at timestamp_s
  virtual std::string describe() const = 0;
};

// Opens the input (throws face_reenact::Error saying what failed).
std::unique_ptr<InputDevice> open_input_device(const GrabberOptions& options);

// Any input as a capture::FrameSource for the offline commands (`track`, `reenact`): a recording
// folder or a video file (capture::open_frame_source, videos with `video`'s intrinsics), an
// OpenNI device or `.oni` file (`openni`, `openni:URI`, or a path ending in .oni: depth registered
// to colour by the driver, every frame of a file in order), or a camera (`/dev/videoN`: it never
// ends; give the command a frame count). Throws face_reenact::Error saying what failed.
std::unique_ptr<capture::FrameSource> open_offline_source(const std::string& text, const std::string& what,
                                                          const capture::VideoReader::Options& video = {});

class FrameGrabber {
 public:
  // Starts the thread. Throws face_reenact::Error on invalid options only; an input that
  // cannot be opened is a status, not an exception.
  explicit FrameGrabber(GrabberOptions options);
  ~FrameGrabber();  // stop()
  FrameGrabber(const FrameGrabber&) = delete;
  FrameGrabber& operator=(const FrameGrabber&) = delete;

  // Waits up to `timeout` for a frame with a sequence number above `after` and copies it
  // (shares the pixel buffers: the grabber never writes into a frame it has handed out).
  // False on timeout or once stopping.
  // `published` (optional) receives when the grabber made the frame available (latency).
  bool wait_newer(uint64_t after, std::chrono::nanoseconds timeout, capture::RgbdFrame* frame, uint64_t* sequence,
                  std::chrono::steady_clock::time_point* published = nullptr);
  // The same without waiting.
  bool take_newer(uint64_t after, capture::RgbdFrame* frame, uint64_t* sequence) {
    return wait_newer(after, std::chrono::nanoseconds(0), frame, sequence);
  }
  GrabberStatus status() const;
  const GrabberOptions& options() const { return options_; }

  // Wakes and joins the thread; idempotent.
  void stop();

 private:
  void run();
  // Sleeps until `until` or stop; false when stopping.
  bool sleep_until(std::chrono::steady_clock::time_point until);

  const GrabberOptions options_;
  mutable std::mutex mu_;
  std::condition_variable frame_cv_;  // a new frame, or stopping
  std::condition_variable stop_cv_;   // stopping (wakes the grabber's own sleeps)
  bool stopping_ = false;
  bool usb_arrival_ = false;          // an RGB-D camera arrived: end the wait before the next open
  int hotplug_subscription_ = 0;      // UsbRgbdHotplug, for OpenNI devices (0: none)
  capture::RgbdFrame latest_;
  std::chrono::steady_clock::time_point latest_published_{};
  uint64_t sequence_ = 0;
  GrabberStatus status_;
  std::thread thread_;
};

}  // namespace face_reenact::live
