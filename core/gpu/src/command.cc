#include "face_reenact/gpu/command.h"

#include <vector>

#include "face_reenact/common/error.h"
#include "face_reenact/gpu/buffer.h"
#include "face_reenact/gpu/context.h"
#include "face_reenact/gpu/image.h"
#include "face_reenact/gpu/pipeline.h"
#include "face_reenact/gpu/vk_check.h"

namespace face_reenact::gpu {

void CommandRecorder::bind(const Pipeline& pipeline) {
  pipeline_ = &pipeline;
  buffers_.fill(VK_NULL_HANDLE);
  vkCmdBindPipeline(cmd_, pipeline.bind_point(), pipeline.handle());
}

void CommandRecorder::set_storage_buffer(uint32_t binding, const Buffer& buffer) {
  if (binding >= kMaxBindings) throw Error("storage buffer binding " + std::to_string(binding) + " out of range");
  if (!buffer.valid()) throw Error("storage buffer binding " + std::to_string(binding) + ": empty buffer");
  buffers_[binding] = buffer.handle();
}

void CommandRecorder::push_constants(const void* data, uint32_t size) {
  if (!pipeline_) throw Error("push_constants before bind");
  if (size != pipeline_->push_constant_size()) {
    throw Error("pipeline '" + pipeline_->name() + "' expects " + std::to_string(pipeline_->push_constant_size()) +
                " bytes of push constants, got " + std::to_string(size));
  }
  VkShaderStageFlags stages = pipeline_->bind_point() == VK_PIPELINE_BIND_POINT_COMPUTE
                                  ? VK_SHADER_STAGE_COMPUTE_BIT
                                  : (VK_SHADER_STAGE_VERTEX_BIT | VK_SHADER_STAGE_FRAGMENT_BIT);
  vkCmdPushConstants(cmd_, pipeline_->layout(), stages, 0, size, data);
}

void CommandRecorder::flush_descriptors() {
  if (!pipeline_) throw Error("dispatch/draw before bind");
  const uint32_t n = pipeline_->storage_buffer_count();
  if (n == 0) return;
  std::vector<VkDescriptorBufferInfo> infos(n);
  std::vector<VkWriteDescriptorSet> writes(n);
  for (uint32_t i = 0; i < n; ++i) {
    if (!buffers_[i]) throw Error("pipeline '" + pipeline_->name() + "': storage buffer " + std::to_string(i) + " not set");
    infos[i] = {buffers_[i], 0, VK_WHOLE_SIZE};
    writes[i] = {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET};
    writes[i].dstBinding = i;
    writes[i].descriptorCount = 1;
    writes[i].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
    writes[i].pBufferInfo = &infos[i];
  }
  context_.cmd_push_descriptor_set(cmd_, pipeline_->bind_point(), pipeline_->layout(), 0, n, writes.data());
}

void CommandRecorder::dispatch_1d(uint32_t threads, uint32_t local_size) {
  if (threads == 0) return;
  dispatch((threads + local_size - 1) / local_size, 1, 1);
}

void CommandRecorder::dispatch(uint32_t x, uint32_t y, uint32_t z) {
  if (x == 0 || y == 0 || z == 0) return;
  flush_descriptors();
  vkCmdDispatch(cmd_, x, y, z);
}

void CommandRecorder::draw(uint32_t vertex_count) {
  if (vertex_count == 0) return;
  flush_descriptors();
  vkCmdDraw(cmd_, vertex_count, 1, 0, 0);
}

void CommandRecorder::dispatch_indirect(const Buffer& args, VkDeviceSize offset) {
  flush_descriptors();
  vkCmdDispatchIndirect(cmd_, args.handle(), offset);
}

void CommandRecorder::draw_indirect(const Buffer& args, VkDeviceSize offset) {
  flush_descriptors();
  vkCmdDrawIndirect(cmd_, args.handle(), offset, 1, 0);
}

void CommandRecorder::memory_barrier(VkPipelineStageFlags2 src_stage, VkAccessFlags2 src_access,
                                     VkPipelineStageFlags2 dst_stage, VkAccessFlags2 dst_access) {
  VkMemoryBarrier2 barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER_2};
  barrier.srcStageMask = src_stage;
  barrier.srcAccessMask = src_access;
  barrier.dstStageMask = dst_stage;
  barrier.dstAccessMask = dst_access;
  VkDependencyInfo dep{VK_STRUCTURE_TYPE_DEPENDENCY_INFO};
  dep.memoryBarrierCount = 1;
  dep.pMemoryBarriers = &barrier;
  vkCmdPipelineBarrier2(cmd_, &dep);
}

void CommandRecorder::image_barrier(Image& image, VkImageLayout new_layout, VkPipelineStageFlags2 src_stage,
                                    VkAccessFlags2 src_access, VkPipelineStageFlags2 dst_stage,
                                    VkAccessFlags2 dst_access) {
  image_barriers({&image}, new_layout, src_stage, src_access, dst_stage, dst_access);
}

void CommandRecorder::image_barriers(std::initializer_list<Image*> images, VkImageLayout new_layout,
                                     VkPipelineStageFlags2 src_stage, VkAccessFlags2 src_access,
                                     VkPipelineStageFlags2 dst_stage, VkAccessFlags2 dst_access) {
  std::vector<VkImageMemoryBarrier2> barriers;
  barriers.reserve(images.size());
  for (Image* image : images) {
    VkImageMemoryBarrier2 barrier{VK_STRUCTURE_TYPE_IMAGE_MEMORY_BARRIER_2};
    barrier.srcStageMask = src_stage;
    barrier.srcAccessMask = src_access;
    barrier.dstStageMask = dst_stage;
    barrier.dstAccessMask = dst_access;
    barrier.oldLayout = image->layout;
    barrier.newLayout = new_layout;
    barrier.srcQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
    barrier.dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
    barrier.image = image->handle();
    barrier.subresourceRange = {image->aspect(), 0, 1, 0, 1};
    barriers.push_back(barrier);
    image->layout = new_layout;
  }
  VkDependencyInfo dep{VK_STRUCTURE_TYPE_DEPENDENCY_INFO};
  dep.imageMemoryBarrierCount = static_cast<uint32_t>(barriers.size());
  dep.pImageMemoryBarriers = barriers.data();
  vkCmdPipelineBarrier2(cmd_, &dep);
}

BarrierBatch& BarrierBatch::memory(VkPipelineStageFlags2 src_stage, VkAccessFlags2 src_access,
                                   VkPipelineStageFlags2 dst_stage, VkAccessFlags2 dst_access) {
  VkMemoryBarrier2 barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER_2};
  barrier.srcStageMask = src_stage;
  barrier.srcAccessMask = src_access;
  barrier.dstStageMask = dst_stage;
  barrier.dstAccessMask = dst_access;
  memory_.push_back(barrier);
  return *this;
}

BarrierBatch& BarrierBatch::image(Image& image, VkImageLayout new_layout, VkPipelineStageFlags2 src_stage,
                                  VkAccessFlags2 src_access, VkPipelineStageFlags2 dst_stage, VkAccessFlags2 dst_access) {
  VkImageMemoryBarrier2 barrier{VK_STRUCTURE_TYPE_IMAGE_MEMORY_BARRIER_2};
  barrier.srcStageMask = src_stage;
  barrier.srcAccessMask = src_access;
  barrier.dstStageMask = dst_stage;
  barrier.dstAccessMask = dst_access;
  barrier.oldLayout = image.layout;
  barrier.newLayout = new_layout;
  barrier.srcQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
  barrier.dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
  barrier.image = image.handle();
  barrier.subresourceRange = {image.aspect(), 0, 1, 0, 1};
  images_.push_back(barrier);
  image.layout = new_layout;
  return *this;
}

void BarrierBatch::record(VkCommandBuffer cmd) {
  if (memory_.empty() && images_.empty()) return;
  VkDependencyInfo dep{VK_STRUCTURE_TYPE_DEPENDENCY_INFO};
  dep.memoryBarrierCount = static_cast<uint32_t>(memory_.size());
  dep.pMemoryBarriers = memory_.data();
  dep.imageMemoryBarrierCount = static_cast<uint32_t>(images_.size());
  dep.pImageMemoryBarriers = images_.data();
  vkCmdPipelineBarrier2(cmd, &dep);
  memory_.clear();
  images_.clear();
}

TimestampQueries::TimestampQueries(const Context& context, uint32_t count, const char* name)
    : context_(context), count_(count) {
  if (count > ticks_.size()) throw Error("too many timestamp queries");
  if (!context.timestamps_supported()) return;
  VkQueryPoolCreateInfo ci{VK_STRUCTURE_TYPE_QUERY_POOL_CREATE_INFO};
  ci.queryType = VK_QUERY_TYPE_TIMESTAMP;
  ci.queryCount = count;
  FR_VK_CHECK(vkCreateQueryPool(context.device(), &ci, nullptr, &pool_));
  context.set_name(VK_OBJECT_TYPE_QUERY_POOL, pool_, name);
}

TimestampQueries::~TimestampQueries() {
  if (pool_) vkDestroyQueryPool(context_.device(), pool_, nullptr);
}

void TimestampQueries::reset(VkCommandBuffer cmd) {
  fetched_ = false;
  written_ = 0;
  if (pool_) vkCmdResetQueryPool(cmd, pool_, 0, count_);
}

void TimestampQueries::write(VkCommandBuffer cmd, uint32_t index) {
  if (!pool_ || index >= count_) return;
  vkCmdWriteTimestamp2(cmd, VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT, pool_, index);
  written_ |= 1u << index;
}

void TimestampQueries::fetch() {
  if (!pool_) return;
  for (uint32_t i = 0; i < count_; ++i) {
    if (!(written_ & (1u << i))) continue;
    FR_VK_CHECK(vkGetQueryPoolResults(context_.device(), pool_, i, 1, sizeof(uint64_t), &ticks_[i], sizeof(uint64_t),
                                      VK_QUERY_RESULT_64_BIT | VK_QUERY_RESULT_WAIT_BIT));
  }
  fetched_ = true;
}

double TimestampQueries::elapsed_ms(uint32_t from, uint32_t to) const {
  if (!pool_ || !fetched_ || from >= count_ || to >= count_ || !(written_ & (1u << from)) || !(written_ & (1u << to)))
    return -1.0;
  const uint32_t bits = context_.timestamp_valid_bits();
  const uint64_t mask = bits >= 64 ? ~0ull : ((1ull << bits) - 1);
  const uint64_t delta = (ticks_[to] - ticks_[from]) & mask;
  return static_cast<double>(delta) * context_.timestamp_period_ns() * 1e-6;
}

}  // namespace face_reenact::gpu
