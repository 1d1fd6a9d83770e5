#include "face_reenact/output/v4l2_loopback_writer.h"

#include <fcntl.h>
#include <linux/videodev2.h>
#include <sys/ioctl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "face_reenact/common/error.h"

namespace face_reenact::output {
namespace {

constexpr const char* kLoopbackDriver = "v4l2 loopback";
// The options the face-reenact package installs in /etc/modprobe.d/face-reenact.conf
// (packaging/modprobe.conf) and the docs use: one device, /dev/video10.
constexpr const char* kModprobeHint =
    "sudo modprobe v4l2loopback devices=1 video_nr=10 card_label=\"Face Reenact\" exclusive_caps=1";

int xioctl(int fd, unsigned long request, void* arg) {
  int r;
  do {
    r = ::ioctl(fd, request, arg);
  } while (r < 0 && errno == EINTR);
  return r;
}


std::string caps_text(uint32_t caps) {
  std::string s;
  auto add = [&](bool on, const char* name) {
    if (on) s += std::string(s.empty() ? "" : ", ") + name;
  };
  add(caps_have_capture(caps), "capture");
  add(caps_have_output(caps), "output");
  add(caps & V4L2_CAP_STREAMING, "streaming");
  add(caps & V4L2_CAP_READWRITE, "read/write");
  return s.empty() ? "none" : s;
}

std::string field(const __u8* bytes, size_t n) {
  size_t len = strnlen(reinterpret_cast<const char*>(bytes), n);
  return std::string(reinterpret_cast<const char*>(bytes), len);
}

uint32_t device_caps_of(const v4l2_capability& cap) {
  return (cap.capabilities & V4L2_CAP_DEVICE_CAPS) ? cap.device_caps : cap.capabilities;
}

}  // namespace

bool caps_have_capture(uint32_t caps) {
  return caps & (V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_VIDEO_CAPTURE_MPLANE);
}
bool caps_have_output(uint32_t caps) { return caps & (V4L2_CAP_VIDEO_OUTPUT | V4L2_CAP_VIDEO_OUTPUT_MPLANE); }

bool V4l2LoopbackWriter::Options::IsValid(std::string* error) const {
  auto fail = [&](const std::string& why) {
    if (error) *error = why;
    return false;
  };
  if (device.empty()) return fail("no device given (e.g. --device /dev/video10)");
  if (width < 2 || height < 2 || width > 8192 || height > 8192)
    return fail("frame size " + std::to_string(width) + "x" + std::to_string(height) +
                " must be between 2x2 and 8192x8192");
  if (width % 2 != 0) return fail("frame width must be even (4:2:x chroma pairs pixels), got " + std::to_string(width));
  if (format == PixelFormat::kI420 && height % 2 != 0)
    return fail("i420 needs an even frame height, got " + std::to_string(height));
  return rate.IsValid(error);
}

V4l2LoopbackWriter::V4l2LoopbackWriter(Options options) : options_(std::move(options)), frame_size_(0) {
  std::string why;
  if (!options_.IsValid(&why)) throw Error("virtual webcam: " + why);
  frame_size_ = frame_bytes(options_.format, options_.width, options_.height);
}

V4l2LoopbackWriter::~V4l2LoopbackWriter() { close(); }

void V4l2LoopbackWriter::open() {
  close();
  info_ = DeviceInfo{};
  const std::string& dev = options_.device;

  struct stat st {};
  if (::stat(dev.c_str(), &st) != 0) {
    int err = errno;
    if (err == ENOENT)
      throw Error("device '" + dev + "' does not exist. Load the loopback module (package v4l2loopback-dkms): " +
                  kModprobeHint + ", then list devices with 'v4l2-ctl --list-devices'");
    if (err == EACCES)
      throw Error("cannot access '" + dev + "': permission denied");
    throw Error("cannot access '" + dev + "': " + errno_text(err));
  }
  if (!S_ISCHR(st.st_mode))
    throw Error("'" + dev + "' is not a video device (" + (S_ISDIR(st.st_mode) ? "a directory" : S_ISREG(st.st_mode) ? "a regular file" : "not a character device") +
                "); give a v4l2loopback node such as /dev/video10");

  int fd = ::open(dev.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    int err = errno;
    if (err == EACCES || err == EPERM)
      throw Error("permission denied opening '" + dev +
                  "': add your user to the device's group (usually 'video': sudo usermod -aG video $USER, then log "
                  "in again) or run as a user that may write to it");
    if (err == EBUSY)
      throw Error("device '" + dev + "' is busy: it accepts no more openers (v4l2loopback's max_openers limit, 10 by "
                  "default, or a program holding it exclusively). Close programs that use it, or use another loopback "
                  "device (sudo modprobe v4l2loopback devices=2 video_nr=10,11 exclusive_caps=1,1)");
    if (err == ENODEV || err == ENXIO)
      throw Error("device '" + dev + "' exists but has no driver behind it (" + errno_text(err) +
                  "); reload the module: " + kModprobeHint);
    throw Error("cannot open '" + dev + "': " + errno_text(err));
  }
  fd_ = fd;
  try {
    // 1. Is it a v4l2loopback device that accepts a writer now?
    v4l2_capability cap{};
    if (xioctl(fd_, VIDIOC_QUERYCAP, &cap) < 0) {
      int err = errno;
      if (err == ENOTTY || err == EINVAL)
        throw Error("'" + dev + "' is not a V4L2 video device (VIDIOC_QUERYCAP: " + errno_text(err) +
                    "); give a v4l2loopback node such as /dev/video10");
      throw Error("VIDIOC_QUERYCAP on '" + dev + "' failed: " + errno_text(err));
    }
    info_.driver = field(cap.driver, sizeof cap.driver);
    info_.card = field(cap.card, sizeof cap.card);
    info_.bus_info = field(cap.bus_info, sizeof cap.bus_info);
    info_.device_caps_before = device_caps_of(cap);
    const uint32_t caps = info_.device_caps_before;
    if (info_.driver != kLoopbackDriver) {
      if (!caps_have_output(caps))
        throw Error("'" + dev + "' is a capture device (driver '" + info_.driver + "', card '" + info_.card +
                    "'), i.e. a camera, not a v4l2loopback output. Load the loopback module (" + kModprobeHint +
                    ") and give its node (v4l2-ctl --list-devices shows it)");
      throw Error("'" + dev + "' is a video output of driver '" + info_.driver + "', not v4l2loopback; apps would not "
                  "see it as a camera. Load the loopback module (" + kModprobeHint + ") and give its node");
    }
    if (!caps_have_output(caps)) {
      if (caps_have_capture(caps))
        throw Error("device '" + dev + "' is busy: another program is already writing to it (with exclusive_caps=1 "
                    "it then announces capture only). Stop that program or use another loopback device");
      throw Error("device '" + dev + "' announces neither output nor capture (caps: " + caps_text(caps) +
                  "): v4l2loopback 0.12 is left in this state by a writer that used write() without streaming. "
                  "Close every program using it, or reload the module: sudo modprobe -r v4l2loopback && " +
                  kModprobeHint);
    }

    // 2. The format. The driver substitutes its first format for unknown ones and keeps the
    // current one while readers hold the device, so what it kept is checked.
    v4l2_format fmt{};
    fmt.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    fmt.fmt.pix.width = static_cast<uint32_t>(options_.width);
    fmt.fmt.pix.height = static_cast<uint32_t>(options_.height);
    fmt.fmt.pix.pixelformat = pixel_format_fourcc(options_.format);
    fmt.fmt.pix.field = V4L2_FIELD_NONE;
    fmt.fmt.pix.bytesperline = static_cast<uint32_t>(bytes_per_line(options_.format, options_.width));
    fmt.fmt.pix.sizeimage = static_cast<uint32_t>(frame_size_);
    fmt.fmt.pix.colorspace = V4L2_COLORSPACE_SMPTE170M;
    const std::string requested = std::to_string(options_.width) + "x" + std::to_string(options_.height) + " " +
                                  fourcc_to_string(pixel_format_fourcc(options_.format));
    if (xioctl(fd_, VIDIOC_S_FMT, &fmt) < 0) {
      int err = errno;
      if (err == EINVAL)
        throw Error("device '" + dev + "' rejected the format " + requested +
                    " (VIDIOC_S_FMT: invalid argument). Try --format yuyv or --size 640x480; if the device was set "
                    "up with a fixed format (v4l2loopback-ctl set-caps), match it");
      if (err == EBUSY)
        throw Error("device '" + dev + "' is busy: its format cannot change while it is streaming (" + requested + ")");
      throw Error("VIDIOC_S_FMT " + requested + " on '" + dev + "' failed: " + errno_text(err));
    }
    if (fmt.fmt.pix.width != uint32_t(options_.width) || fmt.fmt.pix.height != uint32_t(options_.height) ||
        fmt.fmt.pix.pixelformat != pixel_format_fourcc(options_.format)) {
      throw Error("device '" + dev + "' keeps the format " + std::to_string(fmt.fmt.pix.width) + "x" +
                  std::to_string(fmt.fmt.pix.height) + " " + fourcc_to_string(fmt.fmt.pix.pixelformat) + " instead of " +
                  requested + " (programs still reading it fix the format, or keep_format is set). Close the readers, "
                  "or ask for that size and format");
    }
    if (fmt.fmt.pix.sizeimage != 0 && fmt.fmt.pix.sizeimage < frame_size_)
      throw Error("device '" + dev + "' reports " + std::to_string(fmt.fmt.pix.sizeimage) + "-byte frames, " +
                  std::to_string(frame_size_) + " needed for " + requested);

    // 3. The frame rate readers see (VIDIOC_G_PARM on the capture side).
    v4l2_streamparm parm{};
    parm.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    parm.parm.output.capability = V4L2_CAP_TIMEPERFRAME;
    parm.parm.output.timeperframe.numerator = static_cast<uint32_t>(options_.rate.den);
    parm.parm.output.timeperframe.denominator = static_cast<uint32_t>(options_.rate.num);
    if (xioctl(fd_, VIDIOC_S_PARM, &parm) == 0) {
      info_.frame_rate_set = true;
    } else {
      info_.warnings.push_back("the device did not take the frame rate (VIDIOC_S_PARM: " + errno_text(errno) +
                               "); readers may see the driver's default rate");
    }

    // 4. Register as the writer (see the header): flips exclusive_caps to capture.
    int type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    if (xioctl(fd_, VIDIOC_STREAMON, &type) == 0) {
      info_.streamon_ok = true;
    } else {
      info_.warnings.push_back("VIDIOC_STREAMON on the output failed (" + errno_text(errno) +
                               "); the device turns into a camera with the first frame instead");
    }

    // 5. Priming frame.
    if (options_.prime) {
      std::vector<uint8_t> black(frame_size_);
      fill_black(options_.format, options_.width, options_.height, black);
      std::string why;
      if (write_frame(black, &why) != WriteOutcome::kWritten)
        throw Error("writing the first frame to '" + dev + "' failed: " + why);
    }
    v4l2_capability after{};
    if (xioctl(fd_, VIDIOC_QUERYCAP, &after) == 0) info_.device_caps_after = device_caps_of(after);
    if (!caps_have_capture(info_.device_caps_after))
      info_.warnings.push_back("the device does not announce capture yet (caps: " + caps_text(info_.device_caps_after) +
                               "); apps may not list it until frames flow");
  } catch (...) {
    close();
    throw;
  }
}

WriteOutcome V4l2LoopbackWriter::write_frame(std::span<const uint8_t> frame, std::string* error) {
  if (fd_ < 0) {
    if (error) *error = "device '" + options_.device + "' is not open";
    return WriteOutcome::kDeviceLost;
  }
  if (frame.size() != frame_size_) {
    if (error)
      *error = "frame of " + std::to_string(frame.size()) + " bytes, the device expects " + std::to_string(frame_size_);
    return WriteOutcome::kTransientError;
  }
  ssize_t n;
  do {
    n = ::write(fd_, frame.data(), frame.size());
  } while (n < 0 && errno == EINTR);
  if (n == static_cast<ssize_t>(frame.size())) return WriteOutcome::kWritten;
  if (n >= 0) {
    if (error)
      *error = "short write to '" + options_.device + "' (" + std::to_string(n) + " of " + std::to_string(frame.size()) +
               " bytes)";
    return WriteOutcome::kTransientError;
  }
  int err = errno;
  if (error) *error = "write to '" + options_.device + "' failed: " + errno_text(err);
  switch (err) {
    case EAGAIN:
    case EPIPE:
    case EBUSY:
    case ENOMEM:
    case ENOBUFS:
      return WriteOutcome::kTransientError;
    default:
      // ENODEV / ENXIO / EIO (device gone), EBADF, EINVAL (the driver lost its buffers),
      // EFAULT and anything unknown: start over with a fresh open.
      return WriteOutcome::kDeviceLost;
  }
}

bool V4l2LoopbackWriter::reopen(std::string* error) {
  try {
    open();
    return true;
  } catch (const std::exception& e) {
    if (error) *error = e.what();
    return false;
  }
}

void V4l2LoopbackWriter::close() {
  if (fd_ < 0) return;
  int type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
  if (info_.streamon_ok) xioctl(fd_, VIDIOC_STREAMOFF, &type);
  ::close(fd_);
  fd_ = -1;
}

}  // namespace face_reenact::output
