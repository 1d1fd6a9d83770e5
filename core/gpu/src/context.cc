#include "face_reenact/gpu/context.h"

#include <chrono>

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <dlfcn.h>

#include "face_reenact/common/paths.h"
#include "face_reenact/common/sanitizers.h"
#include "face_reenact/common/error.h"
#include "face_reenact/gpu/vk_check.h"

namespace face_reenact::gpu {
namespace {

// Sanitizer builds only: the Vulkan loader unloads the driver (and its layers) when the last
// instance is destroyed, so LeakSanitizer later sees the driver's process-lifetime allocations
// with "<unknown module>" stacks that no suppression can name. Keeping those libraries loaded
// lets tests/lsan.supp suppress them by name while our own leaks stay visible.
void pin_drivers_for_leak_checks() {
#ifdef FR_ADDRESS_SANITIZER
  for (const char* lib : {"libvulkan_lvp.so", "libVkLayer_khronos_validation.so"})
    dlopen(lib, RTLD_NOW | RTLD_NODELETE | RTLD_GLOBAL);
#endif
}

constexpr const char* kValidationLayer = "VK_LAYER_KHRONOS_validation";

std::string version_string(uint32_t v) {
  return std::to_string(VK_API_VERSION_MAJOR(v)) + "." + std::to_string(VK_API_VERSION_MINOR(v)) + "." +
         std::to_string(VK_API_VERSION_PATCH(v));
}

std::string type_name(VkPhysicalDeviceType type) {
  switch (type) {
    case VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU: return "discrete";
    case VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU: return "integrated";
    case VK_PHYSICAL_DEVICE_TYPE_VIRTUAL_GPU: return "virtual";
    case VK_PHYSICAL_DEVICE_TYPE_CPU: return "cpu";
    default: return "other";
  }
}

// Lower is preferred: real GPUs first, the CPU rasteriser (lavapipe) as the fallback.
int type_rank(const std::string& type) {
  if (type == "discrete") return 0;
  if (type == "integrated") return 1;
  if (type == "virtual") return 2;
  if (type == "cpu") return 3;
  return 4;
}

// The graphics+compute queue family of `pd`, or -1.
int find_queue_family(VkPhysicalDevice pd) {
  uint32_t count = 0;
  vkGetPhysicalDeviceQueueFamilyProperties(pd, &count, nullptr);
  std::vector<VkQueueFamilyProperties> families(count);
  vkGetPhysicalDeviceQueueFamilyProperties(pd, &count, families.data());
  for (uint32_t i = 0; i < count; ++i) {
    const VkQueueFlags need = VK_QUEUE_GRAPHICS_BIT | VK_QUEUE_COMPUTE_BIT;
    if ((families[i].queueFlags & need) == need) return static_cast<int>(i);
  }
  return -1;
}

bool has_device_extension(VkPhysicalDevice pd, const char* name) {
  uint32_t count = 0;
  FR_VK_CHECK(vkEnumerateDeviceExtensionProperties(pd, nullptr, &count, nullptr));
  std::vector<VkExtensionProperties> exts(count);
  FR_VK_CHECK(vkEnumerateDeviceExtensionProperties(pd, nullptr, &count, exts.data()));
  for (const auto& e : exts) {
    if (std::strcmp(e.extensionName, name) == 0) return true;
  }
  return false;
}

DeviceInfo describe(VkPhysicalDevice pd, uint32_t index) {
  DeviceInfo info;
  info.index = index;
  VkPhysicalDeviceDriverProperties driver{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_DRIVER_PROPERTIES};
  VkPhysicalDeviceProperties2 props{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, &driver};
  vkGetPhysicalDeviceProperties2(pd, &props);
  info.name = props.properties.deviceName;
  info.type = type_name(props.properties.deviceType);
  info.api_version = version_string(props.properties.apiVersion);
  info.driver_name = driver.driverName;
  info.driver_info = driver.driverInfo;
  VkPhysicalDeviceMemoryProperties mem{};
  vkGetPhysicalDeviceMemoryProperties(pd, &mem);
  for (uint32_t h = 0; h < mem.memoryHeapCount; ++h) {
    info.heaps.push_back({mem.memoryHeaps[h].size, (mem.memoryHeaps[h].flags & VK_MEMORY_HEAP_DEVICE_LOCAL_BIT) != 0});
  }
  info.has_graphics_compute_queue = find_queue_family(pd) >= 0;
  info.supports_vulkan_1_3 = props.properties.apiVersion >= VK_API_VERSION_1_3;

  VkPhysicalDeviceVulkan13Features f13{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_3_FEATURES};
  VkPhysicalDeviceFeatures2 f2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2, &f13};
  if (info.supports_vulkan_1_3) vkGetPhysicalDeviceFeatures2(pd, &f2);

  if (!info.supports_vulkan_1_3) {
    info.why_unusable = "needs Vulkan 1.3, device has " + info.api_version;
  } else if (!info.has_graphics_compute_queue) {
    info.why_unusable = "no queue family with graphics and compute";
  } else if (!f13.dynamicRendering || !f13.synchronization2 || !f13.maintenance4) {
    info.why_unusable = "no dynamicRendering/synchronization2/maintenance4";
  } else if (!has_device_extension(pd, VK_KHR_PUSH_DESCRIPTOR_EXTENSION_NAME)) {
    info.why_unusable = "no VK_KHR_push_descriptor";
  } else {
    info.usable = true;
  }
  return info;
}

// Index into `infos` of the device `selector` picks; throws with the list when nothing fits.
size_t pick_device(const std::vector<DeviceInfo>& infos, const std::string& selector) {
  auto list = [&] {
    std::string s;
    for (const auto& d : infos) {
      s += "\n  [" + std::to_string(d.index) + "] " + d.name + " (" + d.type + ")" +
           (d.usable ? "" : " unusable: " + d.why_unusable);
    }
    return s.empty() ? std::string(" (none)") : s;
  };
  if (infos.empty()) throw Error("no Vulkan device found (install mesa-vulkan-drivers for the CPU device lavapipe)");
  if (!selector.empty()) {
    const bool numeric = std::all_of(selector.begin(), selector.end(), [](unsigned char c) { return std::isdigit(c); });
    for (size_t i = 0; i < infos.size(); ++i) {
      const bool match = numeric ? std::to_string(infos[i].index) == selector
                                 : ascii_lower(infos[i].name).find(ascii_lower(selector)) != std::string::npos;
      if (!match) continue;
      if (!infos[i].usable) {
        throw Error("Vulkan device '" + infos[i].name + "' matches '" + selector + "' but is unusable: " + infos[i].why_unusable);
      }
      return i;
    }
    throw Error("no Vulkan device matches '" + selector + "'; devices:" + list());
  }
  size_t best = infos.size();
  for (size_t i = 0; i < infos.size(); ++i) {
    if (!infos[i].usable) continue;
    if (best == infos.size() || type_rank(infos[i].type) < type_rank(infos[best].type)) best = i;
  }
  if (best == infos.size()) throw Error("no usable Vulkan 1.3 device; devices:" + list());
  return best;
}

std::string effective_selector(const std::string& selector) {
  if (!selector.empty()) return selector;
  const char* env = std::getenv("FR_VULKAN_DEVICE");
  return env ? std::string(env) : std::string();
}

bool has_instance_layer(const char* name) {
  uint32_t count = 0;
  FR_VK_CHECK(vkEnumerateInstanceLayerProperties(&count, nullptr));
  std::vector<VkLayerProperties> layers(count);
  FR_VK_CHECK(vkEnumerateInstanceLayerProperties(&count, layers.data()));
  for (const auto& l : layers) {
    if (std::strcmp(l.layerName, name) == 0) return true;
  }
  return false;
}

bool has_instance_extension(const char* name) {
  uint32_t count = 0;
  FR_VK_CHECK(vkEnumerateInstanceExtensionProperties(nullptr, &count, nullptr));
  std::vector<VkExtensionProperties> exts(count);
  FR_VK_CHECK(vkEnumerateInstanceExtensionProperties(nullptr, &count, exts.data()));
  for (const auto& e : exts) {
    if (std::strcmp(e.extensionName, name) == 0) return true;
  }
  return false;
}

// A bare instance, owned; used by enumerate_devices.
struct InstanceHolder {
  VkInstance instance = VK_NULL_HANDLE;
  ~InstanceHolder() {
    if (instance) vkDestroyInstance(instance, nullptr);
  }
};

VkInstance create_instance(const std::string& app_name, bool validation, bool debug_utils, bool sync_validation = false) {
  uint32_t loader_version = VK_API_VERSION_1_0;
  FR_VK_CHECK(vkEnumerateInstanceVersion(&loader_version));
  if (loader_version < VK_API_VERSION_1_3) {
    throw Error("the Vulkan loader supports only " + version_string(loader_version) + "; face-reenact needs 1.3");
  }
  VkApplicationInfo app{VK_STRUCTURE_TYPE_APPLICATION_INFO};
  app.pApplicationName = app_name.c_str();
  app.pEngineName = "face-reenact";
  app.apiVersion = VK_API_VERSION_1_3;
  std::vector<const char*> layers;
  std::vector<const char*> extensions;
  if (validation) layers.push_back(kValidationLayer);
  if (debug_utils) extensions.push_back(VK_EXT_DEBUG_UTILS_EXTENSION_NAME);
  VkInstanceCreateInfo ci{VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO};
  ci.pApplicationInfo = &app;
  ci.enabledLayerCount = static_cast<uint32_t>(layers.size());
  ci.ppEnabledLayerNames = layers.data();
  ci.enabledExtensionCount = static_cast<uint32_t>(extensions.size());
  ci.ppEnabledExtensionNames = extensions.data();
  const VkValidationFeatureEnableEXT sync_feature = VK_VALIDATION_FEATURE_ENABLE_SYNCHRONIZATION_VALIDATION_EXT;
  VkValidationFeaturesEXT features{VK_STRUCTURE_TYPE_VALIDATION_FEATURES_EXT};
  features.enabledValidationFeatureCount = 1;
  features.pEnabledValidationFeatures = &sync_feature;
  if (validation && sync_validation) ci.pNext = &features;
  pin_drivers_for_leak_checks();
  VkInstance instance = VK_NULL_HANDLE;
  const VkResult created = vkCreateInstance(&ci, nullptr, &instance);
  // The loader answers this when it finds no driver at all: Debian's libvulkan1 only recommends
  // one, so a machine installed without recommends has none. Say which package fixes it.
  if (created == VK_ERROR_INCOMPATIBLE_DRIVER) {
    throw Error("no Vulkan driver is installed (vkCreateInstance: VK_ERROR_INCOMPATIBLE_DRIVER); install one, "
                "e.g. sudo apt-get install mesa-vulkan-drivers (Mesa's drivers, with lavapipe for any CPU)");
  }
  FR_VK_CHECK(created);
  return instance;
}

std::vector<VkPhysicalDevice> physical_devices(VkInstance instance) {
  uint32_t count = 0;
  FR_VK_CHECK(vkEnumeratePhysicalDevices(instance, &count, nullptr));
  std::vector<VkPhysicalDevice> devices(count);
  FR_VK_CHECK(vkEnumeratePhysicalDevices(instance, &count, devices.data()));
  devices.resize(count);
  return devices;
}

VKAPI_ATTR VkBool32 VKAPI_CALL debug_callback(VkDebugUtilsMessageSeverityFlagBitsEXT severity,
                                              VkDebugUtilsMessageTypeFlagsEXT /*types*/,
                                              const VkDebugUtilsMessengerCallbackDataEXT* data, void* user) {
  static_cast<Context*>(user)->on_debug_message(severity, data && data->pMessage ? data->pMessage : "(no message)");
  return VK_FALSE;
}

}  // namespace

bool Context::Options::IsValid(std::string* why) const {
  if (application_name.empty()) {
    if (why) *why = "application_name is empty";
    return false;
  }
  return true;
}

std::vector<DeviceInfo> Context::enumerate_devices(const std::string& selector) {
  InstanceHolder holder;
  holder.instance = create_instance("face-reenact devices", false, false);
  std::vector<DeviceInfo> infos;
  const auto devices = physical_devices(holder.instance);
  for (uint32_t i = 0; i < devices.size(); ++i) infos.push_back(describe(devices[i], i));
  try {
    infos[pick_device(infos, effective_selector(selector))].would_pick = true;
  } catch (const Error&) {
    // Listing still works when nothing would be picked; the caller sees would_pick == false.
  }
  return infos;
}

Context::Context(const Options& options) {
  std::string why;
  if (!options.IsValid(&why)) throw Error("invalid Vulkan context options: " + why);
  bool validation = options.enable_validation;
  if (options.validation_from_env) {
    const char* env = std::getenv("FR_VULKAN_VALIDATION");
    if (env && std::strcmp(env, "1") == 0) validation = true;
  }
  if (validation && !has_instance_layer(kValidationLayer)) {
    throw Error(std::string("Vulkan validation requested but ") + kValidationLayer +
                " is not installed (Debian package vulkan-validationlayers)");
  }
  debug_utils_ = has_instance_extension(VK_EXT_DEBUG_UTILS_EXTENSION_NAME);
  if (validation && !debug_utils_) throw Error("Vulkan validation requested but VK_EXT_debug_utils is missing");
  validation_enabled_ = validation;

  try {
    instance_ = create_instance(options.application_name, validation, debug_utils_, options.synchronization_validation);
    if (debug_utils_) {
      set_object_name_ = reinterpret_cast<PFN_vkSetDebugUtilsObjectNameEXT>(
          vkGetInstanceProcAddr(instance_, "vkSetDebugUtilsObjectNameEXT"));
    }
    if (validation) {
      auto create = reinterpret_cast<PFN_vkCreateDebugUtilsMessengerEXT>(
          vkGetInstanceProcAddr(instance_, "vkCreateDebugUtilsMessengerEXT"));
      if (!create) throw Error("vkCreateDebugUtilsMessengerEXT is not available");
      VkDebugUtilsMessengerCreateInfoEXT mci{VK_STRUCTURE_TYPE_DEBUG_UTILS_MESSENGER_CREATE_INFO_EXT};
      mci.messageSeverity = VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT | VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT;
      mci.messageType = VK_DEBUG_UTILS_MESSAGE_TYPE_GENERAL_BIT_EXT | VK_DEBUG_UTILS_MESSAGE_TYPE_VALIDATION_BIT_EXT |
                        VK_DEBUG_UTILS_MESSAGE_TYPE_PERFORMANCE_BIT_EXT;
      mci.pfnUserCallback = debug_callback;
      mci.pUserData = this;
      FR_VK_CHECK(create(instance_, &mci, nullptr, &messenger_));
    }

    const auto devices = physical_devices(instance_);
    std::vector<DeviceInfo> infos;
    for (uint32_t i = 0; i < devices.size(); ++i) infos.push_back(describe(devices[i], i));
    const size_t chosen = pick_device(infos, effective_selector(options.device));
    physical_device_ = devices[chosen];
    device_info_ = infos[chosen];
    device_info_.would_pick = true;
    vkGetPhysicalDeviceProperties(physical_device_, &properties_);
    vkGetPhysicalDeviceMemoryProperties(physical_device_, &memory_properties_);
    queue_family_ = static_cast<uint32_t>(find_queue_family(physical_device_));
    {
      uint32_t count = 0;
      vkGetPhysicalDeviceQueueFamilyProperties(physical_device_, &count, nullptr);
      std::vector<VkQueueFamilyProperties> families(count);
      vkGetPhysicalDeviceQueueFamilyProperties(physical_device_, &count, families.data());
      timestamp_valid_bits_ = properties_.limits.timestampComputeAndGraphics ? families[queue_family_].timestampValidBits : 0;
    }

    const float priority = 1.0f;
    VkDeviceQueueCreateInfo qci{VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO};
    qci.queueFamilyIndex = queue_family_;
    qci.queueCount = 1;
    qci.pQueuePriorities = &priority;
    VkPhysicalDeviceVulkan13Features f13{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_3_FEATURES};
    f13.dynamicRendering = VK_TRUE;
    f13.synchronization2 = VK_TRUE;
    f13.maintenance4 = VK_TRUE;  // SPIR-V 1.6 (Vulkan 1.3 target) declares LocalSizeId
    VkPhysicalDeviceFeatures2 f2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2, &f13};
    const char* device_extensions[] = {VK_KHR_PUSH_DESCRIPTOR_EXTENSION_NAME};
    VkDeviceCreateInfo dci{VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO, &f2};
    dci.queueCreateInfoCount = 1;
    dci.pQueueCreateInfos = &qci;
    dci.enabledExtensionCount = 1;
    dci.ppEnabledExtensionNames = device_extensions;
    FR_VK_CHECK(vkCreateDevice(physical_device_, &dci, nullptr, &device_));
    vkGetDeviceQueue(device_, queue_family_, 0, &queue_);
    cmd_push_descriptor_set =
        reinterpret_cast<PFN_vkCmdPushDescriptorSetKHR>(vkGetDeviceProcAddr(device_, "vkCmdPushDescriptorSetKHR"));
    if (!cmd_push_descriptor_set) throw Error("vkCmdPushDescriptorSetKHR is not available");

    VkCommandPoolCreateInfo pci{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
    pci.flags = VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT;
    pci.queueFamilyIndex = queue_family_;
    FR_VK_CHECK(vkCreateCommandPool(device_, &pci, nullptr, &command_pool_));
    set_name(VK_OBJECT_TYPE_DEVICE, device_, "face-reenact device");
    set_name(VK_OBJECT_TYPE_QUEUE, queue_, "face-reenact graphics+compute queue");
    set_name(VK_OBJECT_TYPE_COMMAND_POOL, command_pool_, "face-reenact command pool");
  } catch (...) {
    destroy();
    throw;
  }
}

Context::~Context() { destroy(); }

void Context::destroy() {
  if (device_) {
    vkDeviceWaitIdle(device_);
    if (kept_fence_) vkDestroyFence(device_, kept_fence_, nullptr);
    kept_fence_ = VK_NULL_HANDLE;
    kept_command_buffer_ = VK_NULL_HANDLE;  // freed with its pool
    if (command_pool_) vkDestroyCommandPool(device_, command_pool_, nullptr);
    vkDestroyDevice(device_, nullptr);
    device_ = VK_NULL_HANDLE;
    command_pool_ = VK_NULL_HANDLE;
  }
  if (messenger_) {
    auto destroy = reinterpret_cast<PFN_vkDestroyDebugUtilsMessengerEXT>(
        vkGetInstanceProcAddr(instance_, "vkDestroyDebugUtilsMessengerEXT"));
    if (destroy) destroy(instance_, messenger_, nullptr);
    messenger_ = VK_NULL_HANDLE;
  }
  if (instance_) {
    vkDestroyInstance(instance_, nullptr);
    instance_ = VK_NULL_HANDLE;
  }
}

void Context::on_debug_message(VkDebugUtilsMessageSeverityFlagBitsEXT severity, const char* message) {
  const bool error = (severity & VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT) != 0;
  if (error) {
    ++validation_errors_;
  } else {
    ++validation_warnings_;
  }
  std::fprintf(stderr, "face-reenact [vulkan %s] %s\n", error ? "error" : "warning", message);
  std::lock_guard<std::mutex> lock(message_mutex_);
  last_message_ = message;
}

ValidationStats Context::validation_stats() const {
  ValidationStats s;
  s.errors = validation_errors_.load();
  s.warnings = validation_warnings_.load();
  std::lock_guard<std::mutex> lock(message_mutex_);
  s.last_message = last_message_;
  return s;
}

void Context::reset_validation_stats() {
  validation_errors_ = 0;
  validation_warnings_ = 0;
  std::lock_guard<std::mutex> lock(message_mutex_);
  last_message_.clear();
}

void Context::set_name(VkObjectType type, uint64_t handle, const std::string& name) const {
  if (!set_object_name_ || !device_ || handle == 0) return;
  VkDebugUtilsObjectNameInfoEXT info{VK_STRUCTURE_TYPE_DEBUG_UTILS_OBJECT_NAME_INFO_EXT};
  info.objectType = type;
  info.objectHandle = handle;
  info.pObjectName = name.c_str();
  FR_VK_CHECK(set_object_name_(device_, &info));
}

void Context::submit_and_wait(const std::function<void(VkCommandBuffer)>& record, const char* what) const {
  const auto start = std::chrono::steady_clock::now();
  struct AddTime {  // on every way out, errors included
    const std::chrono::steady_clock::time_point start;
    std::atomic<uint64_t>& total;
    ~AddTime() {
      total.fetch_add(static_cast<uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                                std::chrono::steady_clock::now() - start).count()),
                      std::memory_order_relaxed);
    }
  } add_time{start, submission_ns_};
  // The kept command buffer and fence, unless another submission holds them: allocating and
  // destroying them for every submission cost a real GPU's driver a large part of a tracked
  // frame's time (bench track on an H200, 2026-11-26: docs/real-time.md, "On a GPU").
  bool kept = false;
  {
    std::lock_guard<std::mutex> lock(submit_mutex_);
    if (!submit_in_use_) submit_in_use_ = kept = true;
  }
  VkCommandBuffer cmd = kept ? kept_command_buffer_ : VK_NULL_HANDLE;
  VkFence fence = kept ? kept_fence_ : VK_NULL_HANDLE;
  auto release = [&](bool failed) {
    if (!kept) {
      if (fence) vkDestroyFence(device_, fence, nullptr);
      if (cmd) vkFreeCommandBuffers(device_, command_pool_, 1, &cmd);
      return;
    }
    if (failed) {  // after an error the pair's state is unknown: make new ones next time
      if (fence) vkDestroyFence(device_, fence, nullptr);
      if (cmd) vkFreeCommandBuffers(device_, command_pool_, 1, &cmd);
      cmd = VK_NULL_HANDLE;
      fence = VK_NULL_HANDLE;
    }
    std::lock_guard<std::mutex> lock(submit_mutex_);
    kept_command_buffer_ = cmd;
    kept_fence_ = fence;
    submit_in_use_ = false;
  };
  try {
    if (!cmd) {
      VkCommandBufferAllocateInfo ai{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
      ai.commandPool = command_pool_;
      ai.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
      ai.commandBufferCount = 1;
      FR_VK_CHECK(vkAllocateCommandBuffers(device_, &ai, &cmd));
    }
    if (!fence) {
      VkFenceCreateInfo fci{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
      FR_VK_CHECK(vkCreateFence(device_, &fci, nullptr, &fence));
    } else {
      FR_VK_CHECK(vkResetFences(device_, 1, &fence));
    }
    set_name(VK_OBJECT_TYPE_COMMAND_BUFFER, cmd, what);
    VkCommandBufferBeginInfo bi{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
    bi.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
    const auto record_start = std::chrono::steady_clock::now();
    FR_VK_CHECK(vkBeginCommandBuffer(cmd, &bi));  // the pool resets a recorded buffer implicitly
    record(cmd);
    FR_VK_CHECK(vkEndCommandBuffer(cmd));
    recording_ns_.fetch_add(static_cast<uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                                      std::chrono::steady_clock::now() - record_start).count()),
                            std::memory_order_relaxed);
    VkCommandBufferSubmitInfo cbsi{VK_STRUCTURE_TYPE_COMMAND_BUFFER_SUBMIT_INFO};
    cbsi.commandBuffer = cmd;
    VkSubmitInfo2 si{VK_STRUCTURE_TYPE_SUBMIT_INFO_2};
    si.commandBufferInfoCount = 1;
    si.pCommandBufferInfos = &cbsi;
    FR_VK_CHECK(vkQueueSubmit2(queue_, 1, &si, fence));
    submissions_.fetch_add(1, std::memory_order_relaxed);
    // On a real GPU the host polls the fence for a while before it sleeps on it: the tracker's
    // submissions take a fraction of a millisecond, less than a sleeping thread takes to be woken
    // in a virtual machine. Not on a CPU implementation (lavapipe), whose own worker threads
    // need the cores that polling would take.
    constexpr auto kPoll = std::chrono::milliseconds(20);
    VkResult r = VK_NOT_READY;
    if (device_info_.type != "cpu") {
      const auto poll_end = std::chrono::steady_clock::now() + kPoll;
      while ((r = vkGetFenceStatus(device_, fence)) == VK_NOT_READY && std::chrono::steady_clock::now() < poll_end) {
      }
      if (r != VK_SUCCESS && r != VK_NOT_READY) FR_VK_CHECK(r);
    }
    if (r != VK_SUCCESS) {
      // A generous bound so a hung device becomes an error instead of a hang (60 s).
      r = FR_VK_CHECK(vkWaitForFences(device_, 1, &fence, VK_TRUE, 60ull * 1000 * 1000 * 1000));
      if (r == VK_TIMEOUT) throw Error(std::string("GPU work '") + what + "' did not finish within 60 s");
    }
  } catch (...) {
    vkDeviceWaitIdle(device_);
    release(true);
    throw;
  }
  release(false);
}

uint32_t Context::find_memory_type(uint32_t type_bits, VkMemoryPropertyFlags required,
                                   VkMemoryPropertyFlags preferred) const {
  int fallback = -1;
  for (uint32_t i = 0; i < memory_properties_.memoryTypeCount; ++i) {
    if (!(type_bits & (1u << i))) continue;
    const VkMemoryPropertyFlags flags = memory_properties_.memoryTypes[i].propertyFlags;
    if ((flags & required) != required) continue;
    if ((flags & preferred) == preferred) return i;
    if (fallback < 0) fallback = static_cast<int>(i);
  }
  if (fallback < 0) throw Error("no Vulkan memory type with the required properties");
  return static_cast<uint32_t>(fallback);
}

}  // namespace face_reenact::gpu
