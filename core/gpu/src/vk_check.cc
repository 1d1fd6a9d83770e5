#include "face_reenact/gpu/vk_check.h"

#include "face_reenact/common/error.h"

namespace face_reenact::gpu {

std::string vk_result_name(VkResult result) {
  switch (result) {
#define FR_CASE(x) \
  case x:          \
    return #x;
    FR_CASE(VK_SUCCESS)
    FR_CASE(VK_NOT_READY)
    FR_CASE(VK_TIMEOUT)
    FR_CASE(VK_EVENT_SET)
    FR_CASE(VK_EVENT_RESET)
    FR_CASE(VK_INCOMPLETE)
    FR_CASE(VK_ERROR_OUT_OF_HOST_MEMORY)
    FR_CASE(VK_ERROR_OUT_OF_DEVICE_MEMORY)
    FR_CASE(VK_ERROR_INITIALIZATION_FAILED)
    FR_CASE(VK_ERROR_DEVICE_LOST)
    FR_CASE(VK_ERROR_MEMORY_MAP_FAILED)
    FR_CASE(VK_ERROR_LAYER_NOT_PRESENT)
    FR_CASE(VK_ERROR_EXTENSION_NOT_PRESENT)
    FR_CASE(VK_ERROR_FEATURE_NOT_PRESENT)
    FR_CASE(VK_ERROR_INCOMPATIBLE_DRIVER)
    FR_CASE(VK_ERROR_TOO_MANY_OBJECTS)
    FR_CASE(VK_ERROR_FORMAT_NOT_SUPPORTED)
    FR_CASE(VK_ERROR_FRAGMENTED_POOL)
    FR_CASE(VK_ERROR_UNKNOWN)
    FR_CASE(VK_ERROR_OUT_OF_POOL_MEMORY)
    FR_CASE(VK_ERROR_INVALID_EXTERNAL_HANDLE)
    FR_CASE(VK_ERROR_FRAGMENTATION)
    FR_CASE(VK_ERROR_INVALID_OPAQUE_CAPTURE_ADDRESS)
    FR_CASE(VK_PIPELINE_COMPILE_REQUIRED)
    FR_CASE(VK_ERROR_SURFACE_LOST_KHR)
    FR_CASE(VK_ERROR_NATIVE_WINDOW_IN_USE_KHR)
    FR_CASE(VK_SUBOPTIMAL_KHR)
    FR_CASE(VK_ERROR_OUT_OF_DATE_KHR)
    FR_CASE(VK_ERROR_VALIDATION_FAILED_EXT)
#undef FR_CASE
    default:
      return "VkResult(" + std::to_string(static_cast<int>(result)) + ")";
  }
}

VkResult vk_check(VkResult result, const char* call) {
  if (result < 0) {
    throw Error(std::string("Vulkan call ") + call + " failed: " + vk_result_name(result));
  }
  return result;
}

}  // namespace face_reenact::gpu
