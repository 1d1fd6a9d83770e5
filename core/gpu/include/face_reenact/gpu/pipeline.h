#pragma once
// Pipelines built from embedded SPIR-V (embedded_shaders.h). Resources are bound with push
// descriptors (VK_KHR_push_descriptor): every binding is a storage buffer at set 0, binding i,
// so recording stays a thin "set buffer i, push constants, dispatch/draw" API (command.h) and
// no descriptor pools exist. Pipelines are created once by their owner and reused every frame.
#include <vulkan/vulkan.h>

#include <cstdint>
#include <string>
#include <vector>

#include "face_reenact/gpu/embedded_shaders.h"

namespace face_reenact::gpu {

class Context;

// A VkShaderModule that frees itself.
class ShaderModule {
 public:
  ShaderModule(const Context& context, const SpirvBlob& spirv);
  ~ShaderModule();
  ShaderModule(const ShaderModule&) = delete;
  ShaderModule& operator=(const ShaderModule&) = delete;
  VkShaderModule handle() const { return module_; }

 private:
  const Context* context_;
  VkShaderModule module_ = VK_NULL_HANDLE;
};

// Layout shared by compute and graphics pipelines: N storage buffers + push constants.
class Pipeline {
 public:
  ~Pipeline();
  Pipeline(const Pipeline&) = delete;
  Pipeline& operator=(const Pipeline&) = delete;

  VkPipeline handle() const { return pipeline_; }
  VkPipelineLayout layout() const { return layout_; }
  VkPipelineBindPoint bind_point() const { return bind_point_; }
  uint32_t storage_buffer_count() const { return storage_buffers_; }
  uint32_t push_constant_size() const { return push_constant_size_; }
  const std::string& name() const { return name_; }

 protected:
  Pipeline(const Context& context, VkPipelineBindPoint bind_point, uint32_t storage_buffers,
           uint32_t push_constant_size, VkShaderStageFlags stages, const std::string& name);
  void release();

  const Context* context_;
  VkPipelineBindPoint bind_point_;
  uint32_t storage_buffers_;
  uint32_t push_constant_size_;
  std::string name_;
  VkDescriptorSetLayout set_layout_ = VK_NULL_HANDLE;
  VkPipelineLayout layout_ = VK_NULL_HANDLE;
  VkPipeline pipeline_ = VK_NULL_HANDLE;
};

class ComputePipeline : public Pipeline {
 public:
  ComputePipeline(const Context& context, const SpirvBlob& shader, uint32_t storage_buffers,
                  uint32_t push_constant_size, const std::string& name);
};

// A triangle-list pipeline with dynamic viewport/scissor, rendering with dynamic rendering into
// `color_formats` (+ optional depth, test LESS, write on).
class GraphicsPipeline : public Pipeline {
 public:
  struct Options {
    std::vector<VkFormat> color_formats;
    VkFormat depth_format = VK_FORMAT_UNDEFINED;
    VkCullModeFlags cull_mode = VK_CULL_MODE_NONE;
    VkFrontFace front_face = VK_FRONT_FACE_COUNTER_CLOCKWISE;
  };
  GraphicsPipeline(const Context& context, const SpirvBlob& vertex, const SpirvBlob& fragment,
                   uint32_t storage_buffers, uint32_t push_constant_size, const Options& options,
                   const std::string& name);
};

}  // namespace face_reenact::gpu
