// RGB-D cameras on USB through libusb (usb_cameras.h).
#include "face_reenact/live/usb_cameras.h"

#include <libusb.h>

#include <atomic>
#include <cstdio>
#include <map>
#include <mutex>
#include <thread>

#include <pthread.h>

namespace face_reenact::live {

namespace {

constexpr uint16_t kPrimeSense = 0x1d27;
constexpr uint16_t kMicrosoft = 0x045e;

UsbRgbdCamera camera_of(libusb_device* device, const libusb_device_descriptor& d, const char* model) {
  UsbRgbdCamera c;
  c.vendor_id = d.idVendor;
  c.product_id = d.idProduct;
  c.model = model;
  c.bus = libusb_get_bus_number(device);
  c.address = libusb_get_device_address(device);
  return c;
}

}  // namespace

std::string UsbRgbdCamera::Describe() const {
  char buf[160];
  std::snprintf(buf, sizeof buf, "%s (%04x:%04x) on bus %d, device %d", model.c_str(), vendor_id, product_id, bus, address);
  return buf;
}

const char* rgbd_camera_model(uint16_t vendor_id, uint16_t product_id) {
  if (vendor_id == kPrimeSense) {
    switch (product_id) {
      case 0x0200: case 0x0300: case 0x0400: case 0x0401: case 0x0500: case 0x0600: case 0x0601:
      case 0x0609: case 0x1280: case 0x2100: case 0x2200: case 0xf9db:
        return "PrimeSense / Asus Xtion (PS1080)";
      default:
        return nullptr;
    }
  }
  if (vendor_id == kMicrosoft && (product_id == 0x02ae || product_id == 0x02bf)) return "Microsoft Kinect";
  return nullptr;
}

std::vector<UsbRgbdCamera> list_usb_rgbd_cameras(std::string* error) {
  std::vector<UsbRgbdCamera> out;
  libusb_context* ctx = nullptr;
  if (const int r = libusb_init(&ctx); r != 0) {
    if (error) *error = std::string("cannot read the USB buses (libusb: ") + libusb_error_name(r) + ")";
    return out;
  }
  libusb_device** list = nullptr;
  const ssize_t n = libusb_get_device_list(ctx, &list);
  if (n < 0) {
    if (error) *error = std::string("cannot list the USB devices (libusb: ") + libusb_error_name(static_cast<int>(n)) + ")";
  } else {
    for (ssize_t i = 0; i < n; ++i) {
      libusb_device_descriptor d{};
      if (libusb_get_device_descriptor(list[i], &d) != 0) continue;
      if (const char* model = rgbd_camera_model(d.idVendor, d.idProduct)) out.push_back(camera_of(list[i], d, model));
    }
    libusb_free_device_list(list, 1);
    if (error) error->clear();
  }
  libusb_exit(ctx);
  return out;
}

struct UsbRgbdHotplug::Impl {
  libusb_context* ctx = nullptr;
  std::vector<libusb_hotplug_callback_handle> handles;
  std::string unsupported;
  std::atomic<bool> stop{false};
  std::thread events;
  std::mutex mu;
  std::map<int, Callback> subscribers;
  int next_id = 1;

  // Under the lock, so that once Unsubscribe returns its callback is not running and never will
  // (the subscriber may be destroyed right after); callbacks only set a flag and notify.
  void Deliver(bool arrived, const UsbRgbdCamera& camera) {
    std::lock_guard lock(mu);
    for (auto& [id, cb] : subscribers) cb(arrived, camera);
  }

  static int LIBUSB_CALL OnEvent(libusb_context*, libusb_device* device, libusb_hotplug_event event, void* self) {
    libusb_device_descriptor d{};
    if (libusb_get_device_descriptor(device, &d) != 0) return 0;
    const char* model = rgbd_camera_model(d.idVendor, d.idProduct);
    if (!model) return 0;
    static_cast<Impl*>(self)->Deliver(event == LIBUSB_HOTPLUG_EVENT_DEVICE_ARRIVED, camera_of(device, d, model));
    return 0;  // stay registered
  }
};

UsbRgbdHotplug& UsbRgbdHotplug::Instance() {
  static UsbRgbdHotplug instance;
  return instance;
}

UsbRgbdHotplug::UsbRgbdHotplug() : impl_(std::make_unique<Impl>()) {
  Impl& m = *impl_;
  if (const int r = libusb_init(&m.ctx); r != 0) {
    m.ctx = nullptr;
    m.unsupported = std::string("libusb cannot start (") + libusb_error_name(r) + ")";
    return;
  }
  if (!libusb_has_capability(LIBUSB_CAP_HAS_HOTPLUG)) {
    m.unsupported = "this libusb has no hotplug support";
    return;
  }
  // One registration per vendor; the callback keeps the known cameras of each.
  for (const uint16_t vendor : {kPrimeSense, kMicrosoft}) {
    libusb_hotplug_callback_handle h = 0;
    const int r = libusb_hotplug_register_callback(
        m.ctx, static_cast<libusb_hotplug_event>(LIBUSB_HOTPLUG_EVENT_DEVICE_ARRIVED | LIBUSB_HOTPLUG_EVENT_DEVICE_LEFT),
        LIBUSB_HOTPLUG_NO_FLAGS, vendor, LIBUSB_HOTPLUG_MATCH_ANY, LIBUSB_HOTPLUG_MATCH_ANY, &Impl::OnEvent, &m, &h);
    if (r != LIBUSB_SUCCESS) {
      m.unsupported = std::string("libusb hotplug registration failed (") + libusb_error_name(r) + ")";
      for (auto handle : m.handles) libusb_hotplug_deregister_callback(m.ctx, handle);
      m.handles.clear();
      return;
    }
    m.handles.push_back(h);
  }
  m.events = std::thread([&m] {
    pthread_setname_np(pthread_self(), "fr-usb-hotplug");
    while (!m.stop.load()) {
      timeval tv{0, 200000};  // wake now and then to see the stop flag
      libusb_handle_events_timeout_completed(m.ctx, &tv, nullptr);
    }
  });
}

UsbRgbdHotplug::~UsbRgbdHotplug() {
  Impl& m = *impl_;
  m.stop.store(true);
  // Deregistering wakes a blocked libusb_handle_events (libusb's documented way to end the loop).
  for (auto handle : m.handles) libusb_hotplug_deregister_callback(m.ctx, handle);
  if (m.events.joinable()) m.events.join();
  if (m.ctx) libusb_exit(m.ctx);
}

bool UsbRgbdHotplug::supported() const { return impl_->unsupported.empty(); }
std::string UsbRgbdHotplug::why_unsupported() const { return impl_->unsupported; }

int UsbRgbdHotplug::Subscribe(Callback callback) {
  std::lock_guard lock(impl_->mu);
  const int id = impl_->next_id++;
  impl_->subscribers[id] = std::move(callback);
  return id;
}

void UsbRgbdHotplug::Unsubscribe(int id) {
  std::lock_guard lock(impl_->mu);
  impl_->subscribers.erase(id);
}

void UsbRgbdHotplug::SimulateForTesting(bool arrived, const UsbRgbdCamera& camera) { impl_->Deliver(arrived, camera); }

}  // namespace face_reenact::live
