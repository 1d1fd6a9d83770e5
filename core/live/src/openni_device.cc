// OpenNI2 input: colour + depth registered to colour (the paper's PrimeSense camera, Asus Xtion)
// or a .oni recording through OpenNI's file driver.
#include <OpenNI.h>

#include <cmath>
#include <mutex>
#include <string>
#include <opencv2/imgproc.hpp>

#include "face_reenact/common/error.h"
#include "live_internal.h"

namespace face_reenact::live {
namespace {

// OpenNI::initialize is process-wide and reference-counted here, so devices can come and go.
std::mutex g_openni_mu;
int g_openni_users = 0;

// OpenNI2's last error as one line (it comes with tabs and a trailing newline).
std::string extended_error() {
  std::string e = openni::OpenNI::getExtendedError();
  for (char& c : e)
    if (c == '\n' || c == '\t' || c == '\r') c = ' ';
  const size_t b = e.find_first_not_of(' '), t = e.find_last_not_of(' ');
  return b == std::string::npos ? std::string("no detail") : e.substr(b, t - b + 1);
}

void acquire_openni() {
  std::lock_guard lock(g_openni_mu);
  if (g_openni_users == 0 && openni::OpenNI::initialize() != openni::STATUS_OK)
    throw Error(std::string("OpenNI2 failed to initialise: ") + extended_error());
  ++g_openni_users;
}

void release_openni() {
  std::lock_guard lock(g_openni_mu);
  if (--g_openni_users == 0) openni::OpenNI::shutdown();
}

class OpenNiDevice : public InputDevice {
 public:
  explicit OpenNiDevice(const GrabberOptions& options)
      : uri_(options.input.device_path), loop_(options.loop), every_frame_(options.every_frame) {
    acquire_openni();
    try {
      open();
    } catch (...) {
      close();
      release_openni();
      throw;
    }
  }
  ~OpenNiDevice() override {
    close();
    release_openni();
  }

  bool read(capture::RgbdFrame* frame) override {
    openni::VideoStream* streams[] = {&color_};
    int ready = -1;
    if (openni::OpenNI::waitForAnyStream(streams, 1, &ready, 2000) != openni::STATUS_OK) {
      if (playback_ && !loop_ && index_ > 0) return false;  // a file played to its end
      throw Error(what() + ": no colour frame within 2 s (unplugged?)");
    }
    openni::VideoFrameRef color_frame;
    if (color_.readFrame(&color_frame) != openni::STATUS_OK || !color_frame.isValid())
      throw Error(what() + ": reading a colour frame failed: " + extended_error());
    if (playback_ && !loop_ && color_frame.getFrameIndex() < last_index_) return false;  // wrapped
    last_index_ = color_frame.getFrameIndex();
    const int w = color_frame.getWidth(), h = color_frame.getHeight();
    cv::Mat rgb(h, w, CV_8UC3, const_cast<void*>(color_frame.getData()), color_frame.getStrideInBytes());
    cv::Mat bgr;
    cv::cvtColor(rgb, bgr, cv::COLOR_RGB2BGR);
    frame->color = bgr;
    frame->depth = cv::Mat();
    if (depth_.isValid()) {
      openni::VideoFrameRef depth_frame;
      // The depth stream runs at the same rate; take its newest frame without waiting long.
      openni::VideoStream* dstreams[] = {&depth_};
      if (openni::OpenNI::waitForAnyStream(dstreams, 1, &ready, 100) == openni::STATUS_OK &&
          depth_.readFrame(&depth_frame) == openni::STATUS_OK && depth_frame.isValid()) {
        cv::Mat raw(depth_frame.getHeight(), depth_frame.getWidth(), CV_16UC1, const_cast<void*>(depth_frame.getData()),
                    depth_frame.getStrideInBytes());
        cv::Mat metres;
        raw.convertTo(metres, CV_32F, depth_scale_);
        if (metres.size() != bgr.size()) cv::resize(metres, metres, bgr.size(), 0, 0, cv::INTER_NEAREST);
        frame->depth = metres;
      }
    }
    float fov = color_.getHorizontalFieldOfView();
    double fov_deg = std::isfinite(fov) && fov > 0.1f && fov < 3.0f ? fov * 180.0 / M_PI : 62.0;
    frame->camera = capture::camera_from_fov(w, h, fov_deg);
    frame->index = index_++;
    frame->timestamp_s = double(color_frame.getTimestamp()) * 1e-6;
    frame->ground_truth = {};
    return true;
  }
  bool paced_by_timestamps() const override { return false; }  // the driver paces (files too, speed 1)
  std::string describe() const override { return description_; }

 private:
  std::string what() const { return uri_.empty() ? "OpenNI device" : "OpenNI '" + uri_ + "'"; }

  void open() {
    const char* uri = uri_.empty() ? openni::ANY_DEVICE : uri_.c_str();
    if (device_.open(uri) != openni::STATUS_OK)
      throw Error(what() + ": cannot open (" + std::string(extended_error()) +
                  "); is an RGB-D camera plugged in, or is the .oni path right?");
    if (color_.create(device_, openni::SENSOR_COLOR) != openni::STATUS_OK || color_.start() != openni::STATUS_OK)
      throw Error(what() + ": no colour stream: " + extended_error());
    if (color_.getVideoMode().getPixelFormat() != openni::PIXEL_FORMAT_RGB888)
      throw Error(what() + ": the colour stream is not RGB888");
    if (device_.hasSensor(openni::SENSOR_DEPTH) && depth_.create(device_, openni::SENSOR_DEPTH) == openni::STATUS_OK) {
      if (device_.isImageRegistrationModeSupported(openni::IMAGE_REGISTRATION_DEPTH_TO_COLOR))
        device_.setImageRegistrationMode(openni::IMAGE_REGISTRATION_DEPTH_TO_COLOR);
      openni::PixelFormat pf = depth_.getVideoMode().getPixelFormat();
      depth_scale_ = pf == openni::PIXEL_FORMAT_DEPTH_100_UM ? 1e-4 : 1e-3;
      if (depth_.start() != openni::STATUS_OK) depth_.destroy();
    }
    playback_ = device_.getPlaybackControl();
    if (playback_) {
      playback_->setRepeatEnabled(loop_);
      // -1: the driver hands out the next frame when it is asked for one (OpenNI2's manual mode).
      playback_->setSpeed(every_frame_ ? -1.0f : 1.0f);
    }
    const openni::VideoMode mode = color_.getVideoMode();
    description_ = what() + " " + std::to_string(mode.getResolutionX()) + "x" + std::to_string(mode.getResolutionY()) +
                   (depth_.isValid() ? " RGB-D" : " RGB") + " @ " + std::to_string(mode.getFps()) + " fps";
  }
  void close() {
    if (depth_.isValid()) {
      depth_.stop();
      depth_.destroy();
    }
    if (color_.isValid()) {
      color_.stop();
      color_.destroy();
    }
    if (device_.isValid()) device_.close();
  }

  std::string uri_;
  bool loop_;
  bool every_frame_;
  openni::Device device_;
  openni::VideoStream color_, depth_;
  openni::PlaybackControl* playback_ = nullptr;
  double depth_scale_ = 1e-3;
  std::string description_;
  int index_ = 0;
  int last_index_ = -1;
};

}  // namespace

std::unique_ptr<InputDevice> open_openni_device(const GrabberOptions& options) {
  return std::make_unique<OpenNiDevice>(options);
}

}  // namespace face_reenact::live
