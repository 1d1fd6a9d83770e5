#pragma once
// RGB-D cameras on USB, through libusb: which USB devices are the depth cameras OpenNI2 drives
// (PrimeSense PS1080-class: PrimeSense, Asus Xtion, Carmine; Microsoft Kinect), the list
// `face-reenact devices` prints, and their arrival, so that an OpenNI input waiting for its
// camera reopens when it is plugged in rather than at its next poll (FrameGrabber).
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace face_reenact::live {

struct UsbRgbdCamera {
  uint16_t vendor_id = 0;
  uint16_t product_id = 0;
  std::string model;  // "PrimeSense / Asus Xtion (PS1080)", "Microsoft Kinect"
  int bus = 0;
  int address = 0;
  std::string Describe() const;  // "Microsoft Kinect (045e:02ae) on bus 1, device 4"
};

// The model name of a known RGB-D camera's USB ids (the ids Debian's OpenNI2 grants access to in
// its udev rules, without the Kinect's audio and motor functions), or nullptr.
const char* rgbd_camera_model(uint16_t vendor_id, uint16_t product_id);

// The RGB-D cameras on the USB buses now. Never throws: where the buses cannot be read (no USB in
// a container, libusb failing) the list is empty and `error` says why.
std::vector<UsbRgbdCamera> list_usb_rgbd_cameras(std::string* error = nullptr);

// Arrivals and departures of RGB-D cameras for the whole process: one libusb context and one event
// thread ("fr-usb-hotplug"), started on first use, shared by every subscriber. Where libusb has no
// hotplug support (no udev or netlink, as in most containers) supported() is false, nothing is
// ever called, and callers keep polling.
class UsbRgbdHotplug {
 public:
  using Callback = std::function<void(bool arrived, const UsbRgbdCamera& camera)>;
  static UsbRgbdHotplug& Instance();
  ~UsbRgbdHotplug();
  UsbRgbdHotplug(const UsbRgbdHotplug&) = delete;
  UsbRgbdHotplug& operator=(const UsbRgbdHotplug&) = delete;

  bool supported() const;
  std::string why_unsupported() const;
  // Calls `callback` on the event thread for each arrival/departure until Unsubscribe(id), which
  // returns only when no call is running; keep it short (set a flag, notify) and do not call
  // Subscribe/Unsubscribe from it. Returns the subscription id.
  int Subscribe(Callback callback);
  void Unsubscribe(int id);
  // Delivers an event to the subscribers as libusb would (tests; a VM without the hardware).
  void SimulateForTesting(bool arrived, const UsbRgbdCamera& camera);

 private:
  UsbRgbdHotplug();
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace face_reenact::live
