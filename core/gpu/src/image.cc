#include "face_reenact/gpu/image.h"

#include <utility>

#include "face_reenact/common/error.h"
#include "face_reenact/gpu/context.h"
#include "face_reenact/gpu/vk_check.h"

namespace face_reenact::gpu {

Image::Image(const Context& context, uint32_t width, uint32_t height, VkFormat format, VkImageUsageFlags usage,
             const std::string& name)
    : context_(&context), format_(format), width_(width), height_(height) {
  if (width == 0 || height == 0) throw Error("GPU image '" + name + "': empty size");
  VkDevice device = context.device();
  VkImageCreateInfo ci{VK_STRUCTURE_TYPE_IMAGE_CREATE_INFO};
  ci.imageType = VK_IMAGE_TYPE_2D;
  ci.format = format;
  ci.extent = {width, height, 1};
  ci.mipLevels = 1;
  ci.arrayLayers = 1;
  ci.samples = VK_SAMPLE_COUNT_1_BIT;
  ci.tiling = VK_IMAGE_TILING_OPTIMAL;
  ci.usage = usage;
  ci.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
  ci.initialLayout = VK_IMAGE_LAYOUT_UNDEFINED;
  try {
    FR_VK_CHECK(vkCreateImage(device, &ci, nullptr, &image_));
    VkMemoryRequirements req{};
    vkGetImageMemoryRequirements(device, image_, &req);
    VkMemoryAllocateInfo ai{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO};
    ai.allocationSize = req.size;
    ai.memoryTypeIndex = context.find_memory_type(req.memoryTypeBits, 0, VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT);
    FR_VK_CHECK(vkAllocateMemory(device, &ai, nullptr, &memory_));
    FR_VK_CHECK(vkBindImageMemory(device, image_, memory_, 0));
    VkImageViewCreateInfo vci{VK_STRUCTURE_TYPE_IMAGE_VIEW_CREATE_INFO};
    vci.image = image_;
    vci.viewType = VK_IMAGE_VIEW_TYPE_2D;
    vci.format = format;
    vci.subresourceRange = {aspect(), 0, 1, 0, 1};
    FR_VK_CHECK(vkCreateImageView(device, &vci, nullptr, &view_));
    context.set_name(VK_OBJECT_TYPE_IMAGE, image_, name);
    context.set_name(VK_OBJECT_TYPE_IMAGE_VIEW, view_, name + " view");
    context.set_name(VK_OBJECT_TYPE_DEVICE_MEMORY, memory_, name + " memory");
  } catch (const Error& e) {
    release();
    throw Error("GPU image '" + name + "' (" + std::to_string(width) + "x" + std::to_string(height) + "): " + e.what());
  }
}

Image::~Image() { release(); }

Image::Image(Image&& other) noexcept { *this = std::move(other); }

Image& Image::operator=(Image&& other) noexcept {
  if (this != &other) {
    release();
    context_ = std::exchange(other.context_, nullptr);
    image_ = std::exchange(other.image_, VK_NULL_HANDLE);
    view_ = std::exchange(other.view_, VK_NULL_HANDLE);
    memory_ = std::exchange(other.memory_, VK_NULL_HANDLE);
    format_ = other.format_;
    width_ = other.width_;
    height_ = other.height_;
    layout = other.layout;
  }
  return *this;
}

void Image::release() {
  if (!context_) return;
  VkDevice device = context_->device();
  if (view_) vkDestroyImageView(device, view_, nullptr);
  if (image_) vkDestroyImage(device, image_, nullptr);
  if (memory_) vkFreeMemory(device, memory_, nullptr);
  view_ = VK_NULL_HANDLE;
  image_ = VK_NULL_HANDLE;
  memory_ = VK_NULL_HANDLE;
}

VkImageAspectFlags Image::aspect() const {
  switch (format_) {
    case VK_FORMAT_D32_SFLOAT:
    case VK_FORMAT_D16_UNORM:
      return VK_IMAGE_ASPECT_DEPTH_BIT;
    default:
      return VK_IMAGE_ASPECT_COLOR_BIT;
  }
}

uint32_t Image::texel_size() const {
  switch (format_) {
    case VK_FORMAT_R32_SFLOAT:
    case VK_FORMAT_R32_UINT:
    case VK_FORMAT_D32_SFLOAT:
    case VK_FORMAT_R8G8B8A8_UNORM:
      return 4;
    case VK_FORMAT_R32G32_SFLOAT:
    case VK_FORMAT_R32G32_UINT:
      return 8;
    case VK_FORMAT_R32G32B32A32_SFLOAT:
    case VK_FORMAT_R32G32B32A32_UINT:
      return 16;
    default:
      throw Error("Image::texel_size: unsupported format " + std::to_string(static_cast<int>(format_)));
  }
}

}  // namespace face_reenact::gpu
