#pragma once
// A thin recording API over a VkCommandBuffer (Granite-style): bind a pipeline, set storage
// buffers by binding number, push constants, dispatch or draw; barriers in sync2 terms.
// Descriptors are pushed at dispatch/draw time, so setting a buffer is just remembering it.
#include <vulkan/vulkan.h>

#include <array>
#include <cstdint>
#include <initializer_list>
#include <vector>

namespace face_reenact::gpu {

class Buffer;
class Context;
class Image;
class Pipeline;

class CommandRecorder {
 public:
  static constexpr uint32_t kMaxBindings = 16;

  CommandRecorder(const Context& context, VkCommandBuffer cmd) : context_(context), cmd_(cmd) {}
  VkCommandBuffer handle() const { return cmd_; }

  void bind(const Pipeline& pipeline);
  void set_storage_buffer(uint32_t binding, const Buffer& buffer);
  void push_constants(const void* data, uint32_t size);
  template <typename T>
  void push_constants(const T& value) {
    push_constants(&value, static_cast<uint32_t>(sizeof(T)));
  }
  // Dispatches enough groups of `local_size` threads to cover `threads` (1-D).
  void dispatch_1d(uint32_t threads, uint32_t local_size);
  void dispatch(uint32_t x, uint32_t y, uint32_t z);
  void draw(uint32_t vertex_count);
  // The same with the sizes read on the device from `args` at `offset` (a
  // VkDispatchIndirectCommand / VkDrawIndirectCommand written by an earlier pass; zero groups or
  // vertices skip the work): passes whose sizes a device pass decides, recorded ahead of it.
  void dispatch_indirect(const Buffer& args, VkDeviceSize offset);
  void draw_indirect(const Buffer& args, VkDeviceSize offset);

  // A global memory dependency (buffers), sync2 stage/access masks.
  void memory_barrier(VkPipelineStageFlags2 src_stage, VkAccessFlags2 src_access, VkPipelineStageFlags2 dst_stage,
                      VkAccessFlags2 dst_access);
  // Layout transition + dependency for one image; updates image.layout.
  void image_barrier(Image& image, VkImageLayout new_layout, VkPipelineStageFlags2 src_stage,
                     VkAccessFlags2 src_access, VkPipelineStageFlags2 dst_stage, VkAccessFlags2 dst_access);
  // The same transition for several images in one vkCmdPipelineBarrier2 (each barrier call can
  // cost a full pipeline drain on some drivers, lavapipe among them).
  void image_barriers(std::initializer_list<Image*> images, VkImageLayout new_layout, VkPipelineStageFlags2 src_stage,
                      VkAccessFlags2 src_access, VkPipelineStageFlags2 dst_stage, VkAccessFlags2 dst_access);

 private:
  void flush_descriptors();

  const Context& context_;
  VkCommandBuffer cmd_;
  const Pipeline* pipeline_ = nullptr;
  std::array<VkBuffer, kMaxBindings> buffers_{};
};

// Several barriers recorded as one vkCmdPipelineBarrier2: on some drivers (lavapipe) every
// barrier call drains the whole pipeline, so related transitions are batched.
class BarrierBatch {
 public:
  BarrierBatch& memory(VkPipelineStageFlags2 src_stage, VkAccessFlags2 src_access, VkPipelineStageFlags2 dst_stage,
                       VkAccessFlags2 dst_access);
  // Transition from image.layout (updated now) to new_layout.
  BarrierBatch& image(Image& image, VkImageLayout new_layout, VkPipelineStageFlags2 src_stage, VkAccessFlags2 src_access,
                      VkPipelineStageFlags2 dst_stage, VkAccessFlags2 dst_access);
  void record(VkCommandBuffer cmd);

 private:
  std::vector<VkMemoryBarrier2> memory_;
  std::vector<VkImageMemoryBarrier2> images_;
};

// Timestamp queries around stages. write(i) records a timestamp after all prior work; after
// the submission has finished, elapsed_ms(a, b) gives the GPU time between two marks. On a
// queue without timestamps every call is a no-op and elapsed_ms returns -1.
class TimestampQueries {
 public:
  TimestampQueries(const Context& context, uint32_t count, const char* name);
  ~TimestampQueries();
  TimestampQueries(const TimestampQueries&) = delete;
  TimestampQueries& operator=(const TimestampQueries&) = delete;

  bool supported() const { return pool_ != VK_NULL_HANDLE; }
  void reset(VkCommandBuffer cmd);
  void write(VkCommandBuffer cmd, uint32_t index);
  // Fetches the results of the last submission (waits for them): the queries written since the
  // last reset only (waiting on one never written would never end on a real GPU).
  void fetch();
  double elapsed_ms(uint32_t from, uint32_t to) const;

 private:
  const Context& context_;
  uint32_t count_;
  VkQueryPool pool_ = VK_NULL_HANDLE;
  std::array<uint64_t, 32> ticks_{};
  uint32_t written_ = 0;  // bit i: query i written since the last reset
  bool fetched_ = false;
};

}  // namespace face_reenact::gpu
