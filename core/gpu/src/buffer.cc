#include "face_reenact/gpu/buffer.h"

#include <cstring>
#include <utility>

#include "face_reenact/common/error.h"
#include "face_reenact/gpu/context.h"
#include "face_reenact/gpu/vk_check.h"

namespace face_reenact::gpu {

Buffer::Buffer(const Context& context, VkDeviceSize size, VkBufferUsageFlags usage, BufferDomain domain,
               const std::string& name)
    : context_(&context), size_(size), domain_(domain), name_(name) {
  if (size == 0) throw Error("GPU buffer '" + name + "': size must be positive");
  VkDevice device = context.device();
  VkBufferCreateInfo ci{VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO};
  ci.size = size;
  ci.usage = usage | VK_BUFFER_USAGE_TRANSFER_SRC_BIT | VK_BUFFER_USAGE_TRANSFER_DST_BIT;
  ci.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
  try {
    FR_VK_CHECK(vkCreateBuffer(device, &ci, nullptr, &buffer_));
    VkMemoryRequirements req{};
    vkGetBufferMemoryRequirements(device, buffer_, &req);
    VkMemoryPropertyFlags required = 0;
    VkMemoryPropertyFlags preferred = 0;
    switch (domain) {
      case BufferDomain::Device:
        preferred = VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT;
        break;
      case BufferDomain::Upload:
        required = VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
        break;
      case BufferDomain::Readback:
        required = VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT;
        preferred = VK_MEMORY_PROPERTY_HOST_CACHED_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
        break;
    }
    const uint32_t type = context.find_memory_type(req.memoryTypeBits, required, preferred);
    coherent_ = (context.memory_properties().memoryTypes[type].propertyFlags & VK_MEMORY_PROPERTY_HOST_COHERENT_BIT) != 0;
    VkMemoryAllocateInfo ai{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO};
    ai.allocationSize = req.size;
    ai.memoryTypeIndex = type;
    FR_VK_CHECK(vkAllocateMemory(device, &ai, nullptr, &memory_));
    FR_VK_CHECK(vkBindBufferMemory(device, buffer_, memory_, 0));
    if (domain != BufferDomain::Device) FR_VK_CHECK(vkMapMemory(device, memory_, 0, VK_WHOLE_SIZE, 0, &mapped_));
    context.set_name(VK_OBJECT_TYPE_BUFFER, buffer_, name);
    context.set_name(VK_OBJECT_TYPE_DEVICE_MEMORY, memory_, name + " memory");
  } catch (const Error& e) {
    release();
    throw Error("GPU buffer '" + name + "' (" + std::to_string(size) + " bytes): " + e.what());
  }
}

Buffer::~Buffer() { release(); }

Buffer::Buffer(Buffer&& other) noexcept { *this = std::move(other); }

Buffer& Buffer::operator=(Buffer&& other) noexcept {
  if (this != &other) {
    release();
    context_ = std::exchange(other.context_, nullptr);
    buffer_ = std::exchange(other.buffer_, VK_NULL_HANDLE);
    memory_ = std::exchange(other.memory_, VK_NULL_HANDLE);
    size_ = std::exchange(other.size_, 0);
    domain_ = other.domain_;
    mapped_ = std::exchange(other.mapped_, nullptr);
    coherent_ = other.coherent_;
    name_ = std::move(other.name_);
  }
  return *this;
}

void Buffer::release() {
  if (!context_) return;
  VkDevice device = context_->device();
  if (mapped_) vkUnmapMemory(device, memory_);
  if (buffer_) vkDestroyBuffer(device, buffer_, nullptr);
  if (memory_) vkFreeMemory(device, memory_, nullptr);
  mapped_ = nullptr;
  buffer_ = VK_NULL_HANDLE;
  memory_ = VK_NULL_HANDLE;
}

void Buffer::write(const void* data, VkDeviceSize bytes, VkDeviceSize offset) {
  if (!buffer_) throw Error("write to an empty GPU buffer");
  if (offset > size_ || bytes > size_ - offset) {
    throw Error("GPU buffer '" + name_ + "': write of " + std::to_string(bytes) + " bytes at " + std::to_string(offset) +
                " exceeds its " + std::to_string(size_) + " bytes");
  }
  if (bytes == 0) return;
  if (mapped_) {
    std::memcpy(static_cast<char*>(mapped_) + offset, data, bytes);
    if (!coherent_) {
      VkMappedMemoryRange range{VK_STRUCTURE_TYPE_MAPPED_MEMORY_RANGE};
      range.memory = memory_;
      range.size = VK_WHOLE_SIZE;
      FR_VK_CHECK(vkFlushMappedMemoryRanges(context_->device(), 1, &range));
    }
    return;
  }
  Buffer staging(*context_, bytes, VK_BUFFER_USAGE_TRANSFER_SRC_BIT, BufferDomain::Upload, name_ + " staging");
  staging.write(data, bytes);
  context_->submit_and_wait(
      [&](VkCommandBuffer cmd) {
        VkBufferCopy region{0, offset, bytes};
        vkCmdCopyBuffer(cmd, staging.handle(), buffer_, 1, &region);
      },
      "buffer upload");
}

const void* Buffer::mapped_for_read() const {
  if (!mapped_) throw Error("GPU buffer '" + name_ + "' is not host-visible");
  if (!coherent_) {
    VkMappedMemoryRange range{VK_STRUCTURE_TYPE_MAPPED_MEMORY_RANGE};
    range.memory = memory_;
    range.size = VK_WHOLE_SIZE;
    FR_VK_CHECK(vkInvalidateMappedMemoryRanges(context_->device(), 1, &range));
  }
  return mapped_;
}

void Buffer::read(void* data, VkDeviceSize bytes, VkDeviceSize offset) const {
  if (!buffer_) throw Error("read from an empty GPU buffer");
  if (offset > size_ || bytes > size_ - offset) {
    throw Error("GPU buffer '" + name_ + "': read of " + std::to_string(bytes) + " bytes at " + std::to_string(offset) +
                " exceeds its " + std::to_string(size_) + " bytes");
  }
  if (bytes == 0) return;
  if (mapped_) {
    std::memcpy(data, static_cast<const char*>(mapped_for_read()) + offset, bytes);
    return;
  }
  Buffer staging(*context_, bytes, VK_BUFFER_USAGE_TRANSFER_DST_BIT, BufferDomain::Readback, name_ + " readback");
  context_->submit_and_wait(
      [&](VkCommandBuffer cmd) {
        VkBufferCopy region{offset, 0, bytes};
        vkCmdCopyBuffer(cmd, buffer_, staging.handle(), 1, &region);
      },
      "buffer readback");
  staging.read(data, bytes);
}

}  // namespace face_reenact::gpu
