#pragma once
// The headless Vulkan 1.3 context: instance, physical device, one graphics+compute queue, a
// command pool, and (on request) the Khronos validation layer with a debug messenger that counts
// and logs every warning and error. Everything else in face_reenact::gpu hangs off a Context.
//
// Device choice (Context::Options::device, else env FR_VULKAN_DEVICE, else automatic):
//   ""           discrete GPU, else integrated, else virtual, else CPU (lavapipe), else any;
//   "3"          the device with that index in enumerate order (see `face-reenact devices`);
//   "llvmpipe"   the first device whose name contains the text (case-insensitive).
#include <vulkan/vulkan.h>

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

namespace face_reenact::gpu {

// What `face-reenact devices` prints about one physical device.
struct DeviceInfo {
  uint32_t index = 0;
  std::string name;
  std::string type;            // "discrete", "integrated", "virtual", "cpu", "other"
  std::string api_version;     // "1.3.230"
  std::string driver_name;     // VkPhysicalDeviceDriverProperties::driverName
  std::string driver_info;
  struct Heap {
    uint64_t size_bytes = 0;
    bool device_local = false;
  };
  std::vector<Heap> heaps;
  bool has_graphics_compute_queue = false;
  bool supports_vulkan_1_3 = false;
  bool usable = false;         // meets every requirement of Context (see why_unusable)
  std::string why_unusable;
  bool would_pick = false;     // the device Context would choose with the given selector
};

struct ValidationStats {
  uint64_t errors = 0;
  uint64_t warnings = 0;
  std::string last_message;
};

class Context {
 public:
  struct Options {
    std::string device;              // selector, see above; empty: env FR_VULKAN_DEVICE or automatic
    bool enable_validation = false;  // VK_LAYER_KHRONOS_validation + debug messenger
    // With validation: also the layer's synchronization validation (hazards between GPU
    // accesses: missing or wrong barriers). Slower; the tests turn it on.
    bool synchronization_validation = false;
    // Also read env FR_VULKAN_VALIDATION=1 to turn validation on without code changes.
    bool validation_from_env = true;
    std::string application_name = "face-reenact";
    bool IsValid(std::string* why) const;
  };

  explicit Context(const Options& options);
  ~Context();
  Context(const Context&) = delete;
  Context& operator=(const Context&) = delete;

  // Lists the devices the loader sees, marking the one `selector` would pick (validation off).
  static std::vector<DeviceInfo> enumerate_devices(const std::string& selector = "");

  VkInstance instance() const { return instance_; }
  VkPhysicalDevice physical_device() const { return physical_device_; }
  VkDevice device() const { return device_; }
  VkQueue queue() const { return queue_; }
  uint32_t queue_family() const { return queue_family_; }
  VkCommandPool command_pool() const { return command_pool_; }
  const DeviceInfo& device_info() const { return device_info_; }
  const VkPhysicalDeviceProperties& properties() const { return properties_; }
  const VkPhysicalDeviceMemoryProperties& memory_properties() const { return memory_properties_; }
  bool validation_enabled() const { return validation_enabled_; }
  // Nanoseconds per timestamp tick, and whether the queue supports timestamps at all.
  double timestamp_period_ns() const { return properties_.limits.timestampPeriod; }
  bool timestamps_supported() const { return timestamp_valid_bits_ != 0; }
  uint32_t timestamp_valid_bits() const { return timestamp_valid_bits_; }

  ValidationStats validation_stats() const;
  void reset_validation_stats();

  // Debug-utils object name (no-op without VK_EXT_debug_utils).
  void set_name(VkObjectType type, uint64_t handle, const std::string& name) const;
  template <typename Handle>
  void set_name(VkObjectType type, Handle handle, const std::string& name) const {
    set_name(type, reinterpret_cast<uint64_t>(handle), name);
  }

  // Records with `record`, submits, and waits for completion (fenced). For uploads, readbacks
  // and the synchronous render path.
  void submit_and_wait(const std::function<void(VkCommandBuffer)>& record, const char* what) const;
  // Queue submissions made so far through submit_and_wait; each one is also a host wait for the
  // device, which is what a solver's per-frame cost on a real GPU is made of (bench track).
  uint64_t submissions() const { return submissions_.load(std::memory_order_relaxed); }
  // Wall time spent inside submit_and_wait so far (recording, submission, the wait), in ms: what
  // a frame's time outside it is, is host work between submissions.
  double submission_ms() const { return submission_ns_.load(std::memory_order_relaxed) * 1e-6; }
  // Of that, the time spent recording the command buffers (the host's share of a submission).
  double recording_ms() const { return recording_ns_.load(std::memory_order_relaxed) * 1e-6; }

  // Memory type index that has all `required` flags (and preferably `preferred`), or throws.
  uint32_t find_memory_type(uint32_t type_bits, VkMemoryPropertyFlags required,
                            VkMemoryPropertyFlags preferred = 0) const;

  // Extension entry points loaded at device creation.
  PFN_vkCmdPushDescriptorSetKHR cmd_push_descriptor_set = nullptr;

 public:
  // Called by the debug messenger; public only for the C callback.
  void on_debug_message(VkDebugUtilsMessageSeverityFlagBitsEXT severity, const char* message);

 private:
  void destroy();  // releases everything created so far (also on a failed constructor)

  VkInstance instance_ = VK_NULL_HANDLE;
  VkDebugUtilsMessengerEXT messenger_ = VK_NULL_HANDLE;
  VkPhysicalDevice physical_device_ = VK_NULL_HANDLE;
  VkDevice device_ = VK_NULL_HANDLE;
  VkQueue queue_ = VK_NULL_HANDLE;
  uint32_t queue_family_ = 0;
  VkCommandPool command_pool_ = VK_NULL_HANDLE;
  VkPhysicalDeviceProperties properties_{};
  VkPhysicalDeviceMemoryProperties memory_properties_{};
  uint32_t timestamp_valid_bits_ = 0;
  DeviceInfo device_info_;
  bool validation_enabled_ = false;
  bool debug_utils_ = false;
  PFN_vkSetDebugUtilsObjectNameEXT set_object_name_ = nullptr;

  mutable std::atomic<uint64_t> submissions_{0};
  mutable std::atomic<uint64_t> submission_ns_{0};
  mutable std::atomic<uint64_t> recording_ns_{0};
  // submit_and_wait's command buffer and fence, kept from one submission to the next (a nested
  // or concurrent call makes its own).
  mutable std::mutex submit_mutex_;
  mutable bool submit_in_use_ = false;  // guarded by submit_mutex_
  mutable VkCommandBuffer kept_command_buffer_ = VK_NULL_HANDLE;
  mutable VkFence kept_fence_ = VK_NULL_HANDLE;
  std::atomic<uint64_t> validation_errors_{0};
  std::atomic<uint64_t> validation_warnings_{0};
  mutable std::mutex message_mutex_;
  std::string last_message_;  // guarded by message_mutex_
};

}  // namespace face_reenact::gpu
