#pragma once
// A VkBuffer with its own memory, chosen by what the buffer is for (Granite's BufferDomain):
//   Device    device-local; written through a staging copy (model data, per-vertex results)
//   Upload    host-visible + coherent, persistently mapped; the host writes, the GPU reads
//             (per-frame parameters)
//   Readback  host-visible, preferably cached, persistently mapped; the GPU writes, the host
//             reads (G-buffer readback)
// Buffers free themselves; the owner must not destroy one the GPU still uses (the synchronous
// submit path waits for the queue, so this holds by construction).
#include <vulkan/vulkan.h>

#include <cstddef>
#include <string>

namespace face_reenact::gpu {

class Context;

enum class BufferDomain { Device, Upload, Readback };

class Buffer {
 public:
  Buffer() = default;
  Buffer(const Context& context, VkDeviceSize size, VkBufferUsageFlags usage, BufferDomain domain,
         const std::string& name);
  ~Buffer();
  Buffer(Buffer&& other) noexcept;
  Buffer& operator=(Buffer&& other) noexcept;
  Buffer(const Buffer&) = delete;
  Buffer& operator=(const Buffer&) = delete;

  VkBuffer handle() const { return buffer_; }
  VkDeviceSize size() const { return size_; }
  BufferDomain domain() const { return domain_; }
  bool valid() const { return buffer_ != VK_NULL_HANDLE; }
  // Host pointer for Upload/Readback buffers, nullptr for Device buffers.
  void* mapped() const { return mapped_; }
  // The mapped pointer of a Readback buffer for reading what the GPU wrote, in place (no copy
  // of a large readback; non-coherent memory is invalidated first). Throws for Device buffers.
  const void* mapped_for_read() const;

  // Copies host data in at `offset` (bounds-checked). Device buffers go through a temporary
  // staging buffer and a synchronous transfer.
  void write(const void* data, VkDeviceSize bytes, VkDeviceSize offset = 0);
  // Copies `bytes` at `offset` out to the host (bounds-checked; synchronous for Device buffers).
  void read(void* data, VkDeviceSize bytes, VkDeviceSize offset = 0) const;

 private:
  void release();

  const Context* context_ = nullptr;
  VkBuffer buffer_ = VK_NULL_HANDLE;
  VkDeviceMemory memory_ = VK_NULL_HANDLE;
  VkDeviceSize size_ = 0;
  BufferDomain domain_ = BufferDomain::Device;
  void* mapped_ = nullptr;
  bool coherent_ = true;
  std::string name_;
};

}  // namespace face_reenact::gpu
