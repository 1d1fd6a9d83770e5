#include "face_reenact/gpu/pipeline.h"

#include <vector>

#include "face_reenact/common/error.h"
#include "face_reenact/gpu/context.h"
#include "face_reenact/gpu/vk_check.h"

namespace face_reenact::gpu {

ShaderModule::ShaderModule(const Context& context, const SpirvBlob& spirv) : context_(&context) {
  if (!spirv.words || spirv.word_count == 0) throw Error(std::string("shader '") + spirv.name + "' is empty");
  VkShaderModuleCreateInfo ci{VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO};
  ci.codeSize = spirv.word_count * sizeof(uint32_t);
  ci.pCode = spirv.words;
  FR_VK_CHECK(vkCreateShaderModule(context.device(), &ci, nullptr, &module_));
  context.set_name(VK_OBJECT_TYPE_SHADER_MODULE, module_, spirv.name);
}

ShaderModule::~ShaderModule() {
  if (module_) vkDestroyShaderModule(context_->device(), module_, nullptr);
}

Pipeline::Pipeline(const Context& context, VkPipelineBindPoint bind_point, uint32_t storage_buffers,
                   uint32_t push_constant_size, VkShaderStageFlags stages, const std::string& name)
    : context_(&context),
      bind_point_(bind_point),
      storage_buffers_(storage_buffers),
      push_constant_size_(push_constant_size),
      name_(name) {
  if (push_constant_size > context.properties().limits.maxPushConstantsSize) {
    throw Error("pipeline '" + name + "': " + std::to_string(push_constant_size) + " bytes of push constants exceed the device limit");
  }
  std::vector<VkDescriptorSetLayoutBinding> bindings(storage_buffers);
  for (uint32_t i = 0; i < storage_buffers; ++i) {
    bindings[i].binding = i;
    bindings[i].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
    bindings[i].descriptorCount = 1;
    bindings[i].stageFlags = stages;
  }
  VkDescriptorSetLayoutCreateInfo dci{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO};
  dci.flags = VK_DESCRIPTOR_SET_LAYOUT_CREATE_PUSH_DESCRIPTOR_BIT_KHR;
  dci.bindingCount = storage_buffers;
  dci.pBindings = bindings.data();
  FR_VK_CHECK(vkCreateDescriptorSetLayout(context.device(), &dci, nullptr, &set_layout_));
  VkPushConstantRange range{stages, 0, push_constant_size};
  VkPipelineLayoutCreateInfo lci{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
  lci.setLayoutCount = 1;
  lci.pSetLayouts = &set_layout_;
  lci.pushConstantRangeCount = push_constant_size ? 1 : 0;
  lci.pPushConstantRanges = &range;
  try {
    FR_VK_CHECK(vkCreatePipelineLayout(context.device(), &lci, nullptr, &layout_));
  } catch (...) {
    release();
    throw;
  }
  context.set_name(VK_OBJECT_TYPE_DESCRIPTOR_SET_LAYOUT, set_layout_, name + " set layout");
  context.set_name(VK_OBJECT_TYPE_PIPELINE_LAYOUT, layout_, name + " layout");
}

Pipeline::~Pipeline() { release(); }

void Pipeline::release() {
  VkDevice device = context_->device();
  if (pipeline_) vkDestroyPipeline(device, pipeline_, nullptr);
  if (layout_) vkDestroyPipelineLayout(device, layout_, nullptr);
  if (set_layout_) vkDestroyDescriptorSetLayout(device, set_layout_, nullptr);
  pipeline_ = VK_NULL_HANDLE;
  layout_ = VK_NULL_HANDLE;
  set_layout_ = VK_NULL_HANDLE;
}

ComputePipeline::ComputePipeline(const Context& context, const SpirvBlob& shader, uint32_t storage_buffers,
                                 uint32_t push_constant_size, const std::string& name)
    : Pipeline(context, VK_PIPELINE_BIND_POINT_COMPUTE, storage_buffers, push_constant_size,
               VK_SHADER_STAGE_COMPUTE_BIT, name) {
  try {
    ShaderModule module(context, shader);
    VkComputePipelineCreateInfo ci{VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO};
    ci.stage = {VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO};
    ci.stage.stage = VK_SHADER_STAGE_COMPUTE_BIT;
    ci.stage.module = module.handle();
    ci.stage.pName = "main";
    ci.layout = layout_;
    FR_VK_CHECK(vkCreateComputePipelines(context.device(), VK_NULL_HANDLE, 1, &ci, nullptr, &pipeline_));
    context.set_name(VK_OBJECT_TYPE_PIPELINE, pipeline_, name);
  } catch (...) {
    release();
    throw;
  }
}

GraphicsPipeline::GraphicsPipeline(const Context& context, const SpirvBlob& vertex, const SpirvBlob& fragment,
                                   uint32_t storage_buffers, uint32_t push_constant_size, const Options& options,
                                   const std::string& name)
    : Pipeline(context, VK_PIPELINE_BIND_POINT_GRAPHICS, storage_buffers, push_constant_size,
               VK_SHADER_STAGE_VERTEX_BIT | VK_SHADER_STAGE_FRAGMENT_BIT, name) {
  try {
    ShaderModule vs(context, vertex);
    ShaderModule fs(context, fragment);
    VkPipelineShaderStageCreateInfo stages[2] = {{VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO},
                                                 {VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO}};
    stages[0].stage = VK_SHADER_STAGE_VERTEX_BIT;
    stages[0].module = vs.handle();
    stages[0].pName = "main";
    stages[1].stage = VK_SHADER_STAGE_FRAGMENT_BIT;
    stages[1].module = fs.handle();
    stages[1].pName = "main";

    VkPipelineVertexInputStateCreateInfo vertex_input{VK_STRUCTURE_TYPE_PIPELINE_VERTEX_INPUT_STATE_CREATE_INFO};
    VkPipelineInputAssemblyStateCreateInfo assembly{VK_STRUCTURE_TYPE_PIPELINE_INPUT_ASSEMBLY_STATE_CREATE_INFO};
    assembly.topology = VK_PRIMITIVE_TOPOLOGY_TRIANGLE_LIST;
    VkPipelineViewportStateCreateInfo viewport{VK_STRUCTURE_TYPE_PIPELINE_VIEWPORT_STATE_CREATE_INFO};
    viewport.viewportCount = 1;
    viewport.scissorCount = 1;
    VkPipelineRasterizationStateCreateInfo raster{VK_STRUCTURE_TYPE_PIPELINE_RASTERIZATION_STATE_CREATE_INFO};
    raster.polygonMode = VK_POLYGON_MODE_FILL;
    raster.cullMode = options.cull_mode;
    raster.frontFace = options.front_face;
    raster.lineWidth = 1.0f;
    VkPipelineMultisampleStateCreateInfo multisample{VK_STRUCTURE_TYPE_PIPELINE_MULTISAMPLE_STATE_CREATE_INFO};
    multisample.rasterizationSamples = VK_SAMPLE_COUNT_1_BIT;
    VkPipelineDepthStencilStateCreateInfo depth{VK_STRUCTURE_TYPE_PIPELINE_DEPTH_STENCIL_STATE_CREATE_INFO};
    const bool has_depth = options.depth_format != VK_FORMAT_UNDEFINED;
    depth.depthTestEnable = has_depth;
    depth.depthWriteEnable = has_depth;
    depth.depthCompareOp = VK_COMPARE_OP_LESS;
    std::vector<VkPipelineColorBlendAttachmentState> blend(options.color_formats.size());
    for (auto& b : blend) {
      b.colorWriteMask = VK_COLOR_COMPONENT_R_BIT | VK_COLOR_COMPONENT_G_BIT | VK_COLOR_COMPONENT_B_BIT | VK_COLOR_COMPONENT_A_BIT;
    }
    VkPipelineColorBlendStateCreateInfo blend_state{VK_STRUCTURE_TYPE_PIPELINE_COLOR_BLEND_STATE_CREATE_INFO};
    blend_state.attachmentCount = static_cast<uint32_t>(blend.size());
    blend_state.pAttachments = blend.data();
    const VkDynamicState dynamic_states[] = {VK_DYNAMIC_STATE_VIEWPORT, VK_DYNAMIC_STATE_SCISSOR};
    VkPipelineDynamicStateCreateInfo dynamic{VK_STRUCTURE_TYPE_PIPELINE_DYNAMIC_STATE_CREATE_INFO};
    dynamic.dynamicStateCount = 2;
    dynamic.pDynamicStates = dynamic_states;
    VkPipelineRenderingCreateInfo rendering{VK_STRUCTURE_TYPE_PIPELINE_RENDERING_CREATE_INFO};
    rendering.colorAttachmentCount = static_cast<uint32_t>(options.color_formats.size());
    rendering.pColorAttachmentFormats = options.color_formats.data();
    rendering.depthAttachmentFormat = options.depth_format;

    VkGraphicsPipelineCreateInfo ci{VK_STRUCTURE_TYPE_GRAPHICS_PIPELINE_CREATE_INFO, &rendering};
    ci.stageCount = 2;
    ci.pStages = stages;
    ci.pVertexInputState = &vertex_input;
    ci.pInputAssemblyState = &assembly;
    ci.pViewportState = &viewport;
    ci.pRasterizationState = &raster;
    ci.pMultisampleState = &multisample;
    ci.pDepthStencilState = &depth;
    ci.pColorBlendState = &blend_state;
    ci.pDynamicState = &dynamic;
    ci.layout = layout_;
    FR_VK_CHECK(vkCreateGraphicsPipelines(context.device(), VK_NULL_HANDLE, 1, &ci, nullptr, &pipeline_));
    context.set_name(VK_OBJECT_TYPE_PIPELINE, pipeline_, name);
  } catch (...) {
    release();
    throw;
  }
}

}  // namespace face_reenact::gpu
