#pragma once
// Every Vulkan call that returns a VkResult goes through FR_VK_CHECK: a failure throws
// face_reenact::Error naming the call and the result ("vkAllocateMemory(...) failed:
// VK_ERROR_OUT_OF_DEVICE_MEMORY"), so the CLI can print it as is.
#include <vulkan/vulkan.h>

#include <string>

namespace face_reenact::gpu {

// "VK_ERROR_OUT_OF_DEVICE_MEMORY", or "VkResult(<n>)" for codes this build does not know.
std::string vk_result_name(VkResult result);

// Throws face_reenact::Error when `result` is negative (an error code). Non-negative codes
// (VK_SUCCESS, VK_INCOMPLETE, VK_TIMEOUT, ...) are returned for the caller to interpret.
VkResult vk_check(VkResult result, const char* call);

}  // namespace face_reenact::gpu

#define FR_VK_CHECK(call) ::face_reenact::gpu::vk_check((call), #call)
