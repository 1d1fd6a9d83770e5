#pragma once
// A device-local 2D image with one view (colour or depth aspect by format). Layout transitions
// are the user's business (see CommandRecorder::image_barrier); Image only remembers the
// layout its owner last recorded, to keep the bookkeeping next to the image.
#include <vulkan/vulkan.h>

#include <cstdint>
#include <string>

namespace face_reenact::gpu {

class Context;

class Image {
 public:
  Image() = default;
  Image(const Context& context, uint32_t width, uint32_t height, VkFormat format, VkImageUsageFlags usage,
        const std::string& name);
  ~Image();
  Image(Image&& other) noexcept;
  Image& operator=(Image&& other) noexcept;
  Image(const Image&) = delete;
  Image& operator=(const Image&) = delete;

  VkImage handle() const { return image_; }
  VkImageView view() const { return view_; }
  VkFormat format() const { return format_; }
  uint32_t width() const { return width_; }
  uint32_t height() const { return height_; }
  VkImageAspectFlags aspect() const;
  // Bytes per texel of the formats this project uses (R32/RG32/RGBA32 float/uint, D32).
  uint32_t texel_size() const;

  VkImageLayout layout = VK_IMAGE_LAYOUT_UNDEFINED;  // as last recorded by the owner

 private:
  void release();

  const Context* context_ = nullptr;
  VkImage image_ = VK_NULL_HANDLE;
  VkImageView view_ = VK_NULL_HANDLE;
  VkDeviceMemory memory_ = VK_NULL_HANDLE;
  VkFormat format_ = VK_FORMAT_UNDEFINED;
  uint32_t width_ = 0;
  uint32_t height_ = 0;
};

}  // namespace face_reenact::gpu
