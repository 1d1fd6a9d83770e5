#include "face_reenact/live/frame_grabber.h"
#include "face_reenact/live/usb_cameras.h"

#include <pthread.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <mutex>
#include <opencv2/videoio.hpp>

#include "face_reenact/capture/media_file.h"
#include "face_reenact/common/error.h"
#include "live_internal.h"

namespace face_reenact::live {
namespace {

using Clock = std::chrono::steady_clock;

std::string size_text(const cv::Mat& m) { return std::to_string(m.cols) + "x" + std::to_string(m.rows); }

// A recording folder or video file, started again at its end when looping. Timestamps keep
// increasing across loops so consumers (and the pacing below) never see time run backwards.
class RecordingDevice : public InputDevice {
 public:
  RecordingDevice(std::string path, bool loop) : path_(std::move(path)), loop_(loop) {
    if (!std::filesystem::exists(path_)) throw Error("recording '" + path_ + "': no such file or folder");
    source_ = capture::open_frame_source(path_);
    const capture::RecordingInfo& info = source_->info();
    period_s_ = info.fps > 0 ? 1.0 / info.fps : 1.0 / 30;
    description_ = "recording '" + path_ + "' " + std::to_string(info.camera.width) + "x" +
                   std::to_string(info.camera.height) + (info.has_depth ? " RGB-D" : " RGB") + " @ " +
                   std::to_string(static_cast<int>(std::lround(info.fps))) + " fps" + (loop_ ? ", looping" : "");
  }

  bool read(capture::RgbdFrame* frame) override {
    if (!source_->read_next(frame)) {
      if (!loop_) return false;
      if (frames_this_loop_ == 0) throw Error("recording '" + path_ + "' holds no frames");
      // Start again: the new loop begins one frame period after the last frame of this one.
      loop_offset_s_ += last_timestamp_s_ + period_s_;
      frames_this_loop_ = 0;
      source_ = capture::open_frame_source(path_);
      if (!source_->read_next(frame)) throw Error("recording '" + path_ + "' holds no frames");
    }
    if (frame->color.empty()) throw Error("recording '" + path_ + "': frame " + std::to_string(frame->index) + " has no colour image");
    ++frames_this_loop_;
    last_timestamp_s_ = frame->timestamp_s;
    frame->timestamp_s += loop_offset_s_;
    return true;
  }
  bool paced_by_timestamps() const override { return true; }
  std::string describe() const override { return description_; }

 private:
  std::string path_;
  bool loop_;
  std::unique_ptr<capture::FrameSource> source_;
  std::string description_;
  double period_s_ = 1.0 / 30;
  double loop_offset_s_ = 0;
  double last_timestamp_s_ = 0;
  int64_t frames_this_loop_ = 0;
};

// How long OpenCV's V4L2 backend waits for a camera's next frame before read() fails, in whole
// seconds. Its default, 10 s, left the picture frozen that long before "No camera" when a camera
// stalled without vanishing (a v4l2loopback camera whose writer died, a USB hiccup); a device that
// is unplugged fails at once anyway. 2 s is over ten frame periods of the slowest webcam mode
// (5 fps in poor light). OpenCV reads the setting from the environment once per process, at the
// first frame of the first camera; a value the user set is kept.
constexpr const char* kCameraStallSeconds = "2";

void shorten_opencv_camera_stall_timeout() {
  static std::once_flag once;
  std::call_once(once, [] { ::setenv("OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT", kCameraStallSeconds, /*overwrite=*/0); });
}

// A V4L2 camera through OpenCV. RGB only; the intrinsics come from an assumed field of view.
class CameraDevice : public InputDevice {
 public:
  explicit CameraDevice(const GrabberOptions& options) : path_(options.input.device_path), fov_(options.camera_fov_deg) {
    shorten_opencv_camera_stall_timeout();
    std::error_code ec;
    if (!std::filesystem::exists(path_, ec))
      throw Error("camera " + path_ + ": no such device (unplugged, or another number?)");
    if (!capture_.open(path_, cv::CAP_V4L2) || !capture_.isOpened())
      throw Error("camera " + path_ + ": cannot open it (busy in another program, no permission - group 'video' - or not a capture device)");
    capture_.set(cv::CAP_PROP_FRAME_WIDTH, options.camera_width);
    capture_.set(cv::CAP_PROP_FRAME_HEIGHT, options.camera_height);
    capture_.set(cv::CAP_PROP_FPS, options.camera_fps);
  }
  bool read(capture::RgbdFrame* frame) override {
    cv::Mat image;
    if (!capture_.read(image) || image.empty())
      throw Error("camera " + path_ + ": stopped delivering frames (unplugged?)");
    if (!capture::to_bgr8(&image)) throw Error("camera " + path_ + ": unsupported pixel type from the driver");
    if (description_.empty()) description_ = "camera " + path_ + " " + size_text(image);
    frame->index = index_++;
    frame->color = image;
    frame->depth = cv::Mat();
    frame->camera = capture::camera_from_fov(image.cols, image.rows, fov_);
    frame->ground_truth = {};
    frame->timestamp_s = std::chrono::duration<double>(Clock::now().time_since_epoch()).count();
    return true;
  }
  bool paced_by_timestamps() const override { return false; }
  std::string describe() const override { return description_.empty() ? "camera " + path_ : description_; }

 private:
  std::string path_;
  double fov_;
  cv::VideoCapture capture_;
  std::string description_;
  int index_ = 0;
};

void set_thread_name(const std::string& name) {
  std::string n = name.substr(0, 15);
  pthread_setname_np(pthread_self(), n.c_str());
}

}  // namespace

bool GrabberOptions::IsValid(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (input.kind != InputKind::kCamera && input.kind != InputKind::kOpenNi && input.kind != InputKind::kRecording)
    return fail(std::string("a frame grabber needs a camera, OpenNI device or recording, not ") + input_kind_name(input.kind));
  if (input.kind == InputKind::kRecording && input.path.empty()) return fail("the recording path is empty");
  if (camera_width <= 0 || camera_height <= 0 || camera_width > 8192 || camera_height > 8192)
    return fail("camera size must be within 1..8192");
  if (!(camera_fps > 0 && camera_fps <= 240)) return fail("camera fps must be in (0, 240]");
  if (!(camera_fov_deg > 1 && camera_fov_deg < 179)) return fail("camera field of view must be in (1, 179) degrees");
  if (reopen_interval.count() <= 0) return fail("reopen interval must be positive");
  if (thread_name.empty() || thread_name.size() > 15) return fail("thread name must have 1..15 characters");
  return true;
}

std::unique_ptr<InputDevice> open_input_device(const GrabberOptions& options) {
  switch (options.input.kind) {
    case InputKind::kRecording: return std::make_unique<RecordingDevice>(options.input.path, options.loop);
    case InputKind::kCamera: return std::make_unique<CameraDevice>(options);
    case InputKind::kOpenNi: return open_openni_device(options);
    default: break;
  }
  throw Error(options.input.describe() + " is not a picture input");
}

FrameGrabber::FrameGrabber(GrabberOptions options) : options_(std::move(options)) {
  std::string why;
  if (!options_.IsValid(&why)) throw Error("frame grabber: " + why);
  status_.description = options_.input.describe();
  status_.error = "opening";
  // An OpenNI camera (not a .oni file) that is not there yet or was unplugged is opened again the
  // moment an RGB-D camera arrives on USB, instead of at the next reopen_interval.
  if (options_.input.kind == InputKind::kOpenNi && !has_oni_extension(options_.input.device_path)) {
    hotplug_subscription_ = UsbRgbdHotplug::Instance().Subscribe([this](bool arrived, const UsbRgbdCamera&) {
      if (!arrived) return;
      {
        std::lock_guard lock(mu_);
        usb_arrival_ = true;
        ++status_.usb_arrivals;
      }
      stop_cv_.notify_all();
    });
  }
  thread_ = std::thread([this] {
    // Nothing may escape the thread (std::terminate); a failure becomes the status.
    try {
      run();
    } catch (const std::exception& e) {
      std::lock_guard lock(mu_);
      status_.open = false;
      status_.error = std::string("capture thread failed: ") + e.what();
    }
  });
}

FrameGrabber::~FrameGrabber() { stop(); }

void FrameGrabber::stop() {
  if (hotplug_subscription_) {
    UsbRgbdHotplug::Instance().Unsubscribe(hotplug_subscription_);  // no callback after this returns
    hotplug_subscription_ = 0;
  }
  {
    std::lock_guard lock(mu_);
    stopping_ = true;
  }
  frame_cv_.notify_all();
  stop_cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

bool FrameGrabber::sleep_until(Clock::time_point until) {
  std::unique_lock lock(mu_);
  stop_cv_.wait_until(lock, until, [&] { return stopping_ || usb_arrival_; });
  usb_arrival_ = false;
  return !stopping_;
}

bool FrameGrabber::wait_newer(uint64_t after, std::chrono::nanoseconds timeout, capture::RgbdFrame* frame,
                              uint64_t* sequence, Clock::time_point* published) {
  std::unique_lock lock(mu_);
  auto ready = [&] { return stopping_ || sequence_ > after; };
  if (timeout.count() > 0) frame_cv_.wait_for(lock, timeout, ready);
  if (stopping_ || sequence_ <= after) return false;
  *frame = latest_;
  *sequence = sequence_;
  if (published) *published = latest_published_;
  return true;
}

GrabberStatus FrameGrabber::status() const {
  std::lock_guard lock(mu_);
  return status_;
}

void FrameGrabber::run() {
  set_thread_name(options_.thread_name);
  auto update = [&](auto&& fn) {
    std::lock_guard lock(mu_);
    fn(status_);
  };
  auto stopping = [&] {
    std::lock_guard lock(mu_);
    return stopping_;
  };
  while (!stopping()) {
    std::unique_ptr<InputDevice> device;
    update([](GrabberStatus& s) { ++s.open_attempts; });
    try {
      device = open_input_device(options_);
    } catch (const std::exception& e) {
      std::string message = e.what();
      update([&](GrabberStatus& s) {
        s.open = false;
        s.error = message;
      });
      if (!sleep_until(Clock::now() + options_.reopen_interval)) return;
      continue;
    }
    update([&](GrabberStatus& s) {
      s.description = device->describe();
      s.error.clear();
      s.ended = false;
    });
    Clock::time_point start = Clock::now();
    double first_timestamp = NAN;
    Clock::time_point window_start = Clock::now();
    int64_t window_frames = 0;
    bool lost = false;
    bool described = false;  // cameras know their size only after the first frame
    while (!stopping()) {
      capture::RgbdFrame frame;
      bool got = false;
      try {
        got = device->read(&frame);
      } catch (const std::exception& e) {
        std::string message = e.what();
        update([&](GrabberStatus& s) {
          s.open = false;
          s.error = message;
          s.fps = 0;
          ++s.losses;
        });
        lost = true;
        break;
      }
      if (!got) {
        update([](GrabberStatus& s) {
          s.open = false;
          s.ended = true;
          s.error = "end of recording";
        });
        std::unique_lock lock(mu_);
        stop_cv_.wait(lock, [&] { return stopping_; });
        return;
      }
      if (device->paced_by_timestamps()) {
        if (std::isnan(first_timestamp)) first_timestamp = frame.timestamp_s;
        Clock::time_point due =
            start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(frame.timestamp_s - first_timestamp));
        // More than a second behind (a stalled machine): re-anchor instead of bursting.
        if (Clock::now() - due > std::chrono::seconds(1)) {
          start = Clock::now();
          first_timestamp = frame.timestamp_s;
          due = start;
        }
        if (!sleep_until(due)) return;
      }
      Clock::time_point now = Clock::now();
      ++window_frames;
      double window_s = std::chrono::duration<double>(now - window_start).count();
      {
        std::lock_guard lock(mu_);
        latest_ = std::move(frame);
        latest_published_ = now;
        ++sequence_;
        ++status_.frames;
        if (!described) status_.description = device->describe();
        status_.open = true;
        status_.error.clear();
        if (window_s >= 1.0) {
          status_.fps = double(window_frames) / window_s;
          window_frames = 0;
          window_start = now;
        }
      }
      described = true;
      frame_cv_.notify_all();
    }
    device.reset();  // release the camera before waiting
    if (lost && !sleep_until(Clock::now() + options_.reopen_interval)) return;
  }
}

namespace {

// A live input device read in order (InputDevice::read) as a capture::FrameSource.
class DeviceFrameSource : public capture::FrameSource {
 public:
  DeviceFrameSource(std::unique_ptr<InputDevice> device, const std::string& what) : device_(std::move(device)) {
    // The first frame says what the input is (size, intrinsics, depth).
    if (!device_->read(&first_)) throw Error(what + ": " + device_->describe() + " delivered no frame");
    have_first_ = true;
    info_.camera = first_.camera;
    info_.has_depth = !first_.depth.empty();
    info_.fps = 30;
    info_.frame_count = -1;  // unknown until the end
    info_.source = device_->describe();
  }
  const capture::RecordingInfo& info() const override { return info_; }
  bool read_next(capture::RgbdFrame* frame) override {
    if (have_first_) {
      *frame = std::move(first_);
      have_first_ = false;
      return true;
    }
    return device_->read(frame);
  }

 private:
  std::unique_ptr<InputDevice> device_;
  capture::RgbdFrame first_;
  bool have_first_ = false;
  capture::RecordingInfo info_;
};

}  // namespace

std::unique_ptr<capture::FrameSource> open_offline_source(const std::string& text, const std::string& what,
                                                          const capture::VideoReader::Options& video) {
  const InputSpec spec = parse_target_spec(text, what);
  if (spec.kind == InputKind::kRecording) return capture::open_frame_source(spec.path, video);
  GrabberOptions o;
  o.input = spec;
  o.loop = false;
  o.every_frame = true;
  o.camera_fov_deg = video.horizontal_fov_deg;
  std::string why;
  if (!o.IsValid(&why)) throw Error(what + " '" + text + "': " + why);
  return std::make_unique<DeviceFrameSource>(open_input_device(o), what + " '" + text + "'");
}

}  // namespace face_reenact::live
