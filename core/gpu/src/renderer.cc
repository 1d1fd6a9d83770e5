#include "face_reenact/gpu/renderer.h"

#include <chrono>
#include <cstddef>
#include <cstring>

#include "face_reenact/common/error.h"
#include "face_reenact/common/parallel.h"
#include "face_reenact/gpu/context.h"
#include "face_reenact/gpu/cpu_renderer.h"
#include "face_reenact/gpu/embedded_shaders.h"
#include "face_reenact/gpu/shader_layout.h"
#include "face_reenact/gpu/vk_check.h"

namespace face_reenact::gpu {
namespace {

constexpr uint32_t kLocalSize = 64;

// Host mirrors of the shaders' blocks (std430; types and rules: shader_layout.h).

// shaders/common.glsl, struct FrameBlock: vertex_shade.comp's Frame buffer. std430 rounds a
// struct's size up to its alignment (16, from the vec4s): 172 bytes of members, 176 in all.
struct alignas(16) FrameBlock {
  glm::vec4 rotation_rows[3];     // R, row-major, xyz used
  glm::vec4 translation;          // t, xyz used
  float gamma[kNumShParameters];  // SH lighting, gamma[channel * 9 + k]
};
static_assert(offsetof(FrameBlock, rotation_rows) == 0);
static_assert(offsetof(FrameBlock, translation) == 48);
static_assert(offsetof(FrameBlock, gamma) == 64);
static_assert(sizeof(FrameBlock::gamma) == 27 * sizeof(float));  // float gamma[27]: the rounding hides its length
static_assert(sizeof(FrameBlock) == 176);

// identity_eval.comp, push constant block Push.
struct IdentityEvalPush {
  glm::uint rows;  // 3N
  glm::uint num_identity;
  glm::uint num_albedo;
  glm::uint albedo_offset;  // index of beta_0 in coeffs
};
static_assert(offsetof(IdentityEvalPush, rows) == 0);
static_assert(offsetof(IdentityEvalPush, num_identity) == 4);
static_assert(offsetof(IdentityEvalPush, num_albedo) == 8);
static_assert(offsetof(IdentityEvalPush, albedo_offset) == 12);
static_assert(sizeof(IdentityEvalPush) == 16);

// model_eval.comp, push constant block Push.
struct ModelEvalPush {
  glm::uint rows;  // 3N
  glm::uint num_expression;
  glm::uint expression_offset;  // index of delta_0 in coeffs
  glm::uint pad;
};
static_assert(offsetof(ModelEvalPush, rows) == 0);
static_assert(offsetof(ModelEvalPush, num_expression) == 4);
static_assert(offsetof(ModelEvalPush, expression_offset) == 8);
static_assert(offsetof(ModelEvalPush, pad) == 12);
static_assert(sizeof(ModelEvalPush) == 16);

// vertex_shade.comp, push constant block Push.
struct ShadePush {
  glm::uint num_vertices;
};
static_assert(offsetof(ShadePush, num_vertices) == 0);
static_assert(sizeof(ShadePush) == 4);

// gbuffer.vert, push constant block Push.
struct RasterPush {
  float fx, fy, cx, cy;
  float width, height, near_plane, far_plane;
};
static_assert(offsetof(RasterPush, fx) == 0);
static_assert(offsetof(RasterPush, fy) == 4);
static_assert(offsetof(RasterPush, cx) == 8);
static_assert(offsetof(RasterPush, cy) == 12);
static_assert(offsetof(RasterPush, width) == 16);
static_assert(offsetof(RasterPush, height) == 20);
static_assert(offsetof(RasterPush, near_plane) == 24);
static_assert(offsetof(RasterPush, far_plane) == 28);
static_assert(sizeof(RasterPush) == 32);

// gbuffer.vert, element of the DrawList buffer (uvec4 draw_list[]): v0, v1, v2, model triangle.
using DrawListEntry = glm::uvec4;

constexpr VkBufferUsageFlags kStorage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;

// A storage buffer holding `data` (at least 16 bytes, so empty bases still bind).
Buffer device_buffer_with(const Context& context, const void* data, size_t bytes, const std::string& name) {
  Buffer b(context, std::max<size_t>(bytes, 16), kStorage, BufferDomain::Device, name);
  if (bytes) b.write(data, bytes);
  return b;
}

// Column-major on the device: the evaluation shader gives each invocation one row of E c, so a
// column's rows are read by neighbouring invocations together.
Buffer matrix_buffer(const Context& context, const Eigen::MatrixXf& column_major, const std::string& name) {
  return device_buffer_with(context, column_major.data(), static_cast<size_t>(column_major.size()) * sizeof(float), name);
}

void copy_padded(float* out, const Eigen::VectorXf& v, Eigen::Index n) {
  for (Eigen::Index i = 0; i < n; ++i) out[i] = i < v.size() ? v[i] : 0.f;
}

}  // namespace

Renderer::Renderer(const Context& context, const RenderModel& model, const Options& options)
    : context_(context), options_(options), model_(model) {
  std::string why;
  if (!model_.IsValid(&why)) throw Error("GPU renderer: " + why);
  num_vertices_ = static_cast<uint32_t>(model_.num_vertices());
  const size_t rows = 3 * static_cast<size_t>(num_vertices_);
  coefficient_count_ = static_cast<uint32_t>(model_.identity_basis.cols() + model_.expression_basis.cols() +
                                             model_.albedo_basis.cols());
  const VkDeviceSize max_range = context.properties().limits.maxStorageBufferRange;
  for (const BasisMatrix* m : {&model_.identity_basis, &model_.expression_basis, &model_.albedo_basis}) {
    if (static_cast<VkDeviceSize>(m->size()) * sizeof(float) > max_range) {
      throw Error("GPU renderer: a model basis of " + std::to_string(m->size() * sizeof(float)) +
                  " bytes exceeds the device's storage buffer range of " + std::to_string(max_range));
    }
  }

  // The G-buffer formats must be renderable (and storage-capable for the tracker's passes).
  auto require_format = [&](VkFormat format, VkFormatFeatureFlags features, const char* what) {
    VkFormatProperties props{};
    vkGetPhysicalDeviceFormatProperties(context.physical_device(), format, &props);
    if ((props.optimalTilingFeatures & features) != features) {
      throw Error(std::string("GPU renderer: device '") + context.device_info().name + "' cannot use " + what +
                  " for the G-buffer");
    }
  };
  require_format(kGBufferFloatFormat,
                 VK_FORMAT_FEATURE_COLOR_ATTACHMENT_BIT | VK_FORMAT_FEATURE_STORAGE_IMAGE_BIT | VK_FORMAT_FEATURE_TRANSFER_SRC_BIT,
                 "RGBA32F colour/storage images");
  require_format(kGBufferIdFormat,
                 VK_FORMAT_FEATURE_COLOR_ATTACHMENT_BIT | VK_FORMAT_FEATURE_STORAGE_IMAGE_BIT | VK_FORMAT_FEATURE_TRANSFER_SRC_BIT,
                 "RGBA32UI colour/storage images");
  require_format(kGBufferDepthFormat, VK_FORMAT_FEATURE_DEPTH_STENCIL_ATTACHMENT_BIT, "D32 depth");

  mean_shape_ = matrix_buffer(context, model_.mean_shape, "mean shape a_id");
  identity_basis_ = matrix_buffer(context, Eigen::MatrixXf(model_.identity_basis), "identity basis E_id");
  expression_basis_ = matrix_buffer(context, Eigen::MatrixXf(model_.expression_basis), "expression basis E_exp");
  mean_albedo_ = matrix_buffer(context, model_.mean_albedo, "mean albedo a_alb");
  albedo_basis_ = matrix_buffer(context, Eigen::MatrixXf(model_.albedo_basis), "albedo basis E_alb");

  // Triangles flat, and the vertex -> incident triangle adjacency as CSR.
  std::vector<uint32_t> flat;
  flat.reserve(model_.triangles.size() * 3);
  std::vector<uint32_t> offsets(num_vertices_ + 1, 0);
  for (const auto& t : model_.triangles) {
    for (int k = 0; k < 3; ++k) {
      flat.push_back(static_cast<uint32_t>(t[k]));
      ++offsets[t[k] + 1];
    }
  }
  for (uint32_t v = 0; v < num_vertices_; ++v) offsets[v + 1] += offsets[v];
  std::vector<uint32_t> adjacency(offsets.back());
  std::vector<uint32_t> fill(offsets.begin(), offsets.end() - 1);
  for (size_t t = 0; t < model_.triangles.size(); ++t) {
    for (int k = 0; k < 3; ++k) adjacency[fill[model_.triangles[t][k]]++] = static_cast<uint32_t>(t);
  }
  triangles_ = device_buffer_with(context, flat.data(), flat.size() * sizeof(uint32_t), "triangles");
  adjacency_offsets_ = device_buffer_with(context, offsets.data(), offsets.size() * sizeof(uint32_t), "adjacency offsets");
  adjacency_ = device_buffer_with(context, adjacency.data(), adjacency.size() * sizeof(uint32_t), "vertex-triangle adjacency");

  coefficients_ = Buffer(context, std::max<size_t>(coefficient_count_ * sizeof(float), 16), kStorage, BufferDomain::Upload,
                         "coefficients alpha|delta|beta");
  frame_ = Buffer(context, sizeof(FrameBlock), kStorage, BufferDomain::Upload, "frame pose + lighting");
  base_shape_ = Buffer(context, rows * sizeof(float), kStorage, BufferDomain::Device, "identity shape a_id + E_id alpha");
  shape_ = Buffer(context, rows * sizeof(float), kStorage, BufferDomain::Device, "model positions");
  albedo_ = Buffer(context, rows * sizeof(float), kStorage, BufferDomain::Device, "vertex albedo");
  camera_positions_ = Buffer(context, num_vertices_ * sizeof(glm::vec4), kStorage, BufferDomain::Device, "camera positions");
  camera_normals_ = Buffer(context, num_vertices_ * sizeof(glm::vec4), kStorage, BufferDomain::Device, "camera normals");
  colors_ = Buffer(context, num_vertices_ * sizeof(glm::vec4), kStorage, BufferDomain::Device, "shaded vertex colours");
  draw_list_ = Buffer(context, std::max<size_t>(model_.triangles.size(), 1) * sizeof(DrawListEntry), kStorage,
                      BufferDomain::Device, "draw list");

  identity_pipeline_ = std::make_unique<ComputePipeline>(context, shaders::identity_eval_comp, 7,
                                                         sizeof(IdentityEvalPush), "identity + albedo evaluation");
  model_pipeline_ = std::make_unique<ComputePipeline>(context, shaders::model_eval_comp, 4, sizeof(ModelEvalPush),
                                                      "expression evaluation");
  shade_pipeline_ = std::make_unique<ComputePipeline>(context, shaders::vertex_shade_comp, 9, sizeof(ShadePush),
                                                      "vertex normals + shading");
  if (options_.timestamps) timestamps_ = std::make_unique<TimestampQueries>(context, 4, "render timestamps");
}

Renderer::~Renderer() = default;

const GraphicsPipeline& Renderer::raster_pipeline(bool cull) {
  auto& slot = raster_pipelines_[cull ? 1 : 0];
  if (!slot) {
    GraphicsPipeline::Options o;
    o.color_formats = {kGBufferFloatFormat, kGBufferFloatFormat, kGBufferFloatFormat, kGBufferFloatFormat,
                       kGBufferIdFormat};
    o.depth_format = kGBufferDepthFormat;
    o.cull_mode = cull ? VK_CULL_MODE_BACK_BIT : VK_CULL_MODE_NONE;
    // Counter-clockwise from outside in the model becomes Vulkan's counter-clockwise (positive
    // area in framebuffer coordinates) under our y-down camera; see docs/renderer.md.
    o.front_face = VK_FRONT_FACE_COUNTER_CLOCKWISE;
    slot = std::make_unique<GraphicsPipeline>(context_, shaders::gbuffer_vert, shaders::gbuffer_frag, 4,
                                              static_cast<uint32_t>(sizeof(RasterPush)), o,
                                              cull ? "G-buffer raster (cull back)" : "G-buffer raster");
  }
  return *slot;
}

GBufferTargets& Renderer::targets_for(int width, int height) {
  auto& slot = targets_[{width, height}];
  if (!slot) {
    const uint32_t w = static_cast<uint32_t>(width), h = static_cast<uint32_t>(height);
    const VkImageUsageFlags color_usage = VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT | VK_IMAGE_USAGE_TRANSFER_SRC_BIT |
                                          VK_IMAGE_USAGE_STORAGE_BIT | VK_IMAGE_USAGE_SAMPLED_BIT;
    const std::string suffix = " " + std::to_string(width) + "x" + std::to_string(height);
    auto t = std::make_unique<GBufferTargets>();
    t->color = Image(context_, w, h, kGBufferFloatFormat, color_usage, "G-buffer colour" + suffix);
    t->position = Image(context_, w, h, kGBufferFloatFormat, color_usage, "G-buffer position" + suffix);
    t->normal = Image(context_, w, h, kGBufferFloatFormat, color_usage, "G-buffer normal" + suffix);
    t->barycentric = Image(context_, w, h, kGBufferFloatFormat, color_usage, "G-buffer barycentric" + suffix);
    t->ids = Image(context_, w, h, kGBufferIdFormat, color_usage, "G-buffer ids" + suffix);
    t->depth = Image(context_, w, h, kGBufferDepthFormat,
                     VK_IMAGE_USAGE_DEPTH_STENCIL_ATTACHMENT_BIT | VK_IMAGE_USAGE_TRANSFER_SRC_BIT,
                     "G-buffer depth" + suffix);
    slot = std::move(t);
  }
  return *slot;
}

void Renderer::update_draw_list(const RenderOptions& options) {
  if (options.parts == draw_list_parts_) return;
  std::vector<DrawListEntry> list;
  for (int32_t t : drawn_triangles(model_, options)) {
    const auto& tri = model_.triangles[t];
    list.emplace_back(static_cast<glm::uint>(tri[0]), static_cast<glm::uint>(tri[1]), static_cast<glm::uint>(tri[2]),
                      static_cast<glm::uint>(t));
  }
  if (!list.empty()) draw_list_.write(list.data(), list.size() * sizeof(DrawListEntry));
  draw_count_ = static_cast<uint32_t>(list.size());
  draw_list_parts_ = options.parts;
}

void Renderer::check_camera(const PinholeCamera& camera, const RenderOptions& options) const {
  std::string why;
  if (!camera.IsValid(&why)) throw Error("invalid camera: " + why);
  if (!options.IsValid(&why)) throw Error("invalid render options: " + why);
  const VkPhysicalDeviceLimits& limits = context_.properties().limits;
  const uint32_t max_w = std::min(limits.maxFramebufferWidth, limits.maxImageDimension2D);
  const uint32_t max_h = std::min(limits.maxFramebufferHeight, limits.maxImageDimension2D);
  if (static_cast<uint32_t>(camera.width) > max_w || static_cast<uint32_t>(camera.height) > max_h) {
    throw Error("camera size " + std::to_string(camera.width) + "x" + std::to_string(camera.height) +
                " exceeds the device's framebuffer limit " + std::to_string(max_w) + "x" + std::to_string(max_h));
  }
}

Renderer::DeviceRenderSizes Renderer::prepare_device_render(const PinholeCamera& camera, const RenderOptions& options) {
  check_camera(camera, options);
  update_draw_list(options);
  targets_for(camera.width, camera.height);
  raster_pipeline(options.cull_back_faces);
  const uint32_t rows = 3 * num_vertices_;
  return {(rows + kLocalSize - 1) / kLocalSize, (num_vertices_ + kLocalSize - 1) / kLocalSize, 3 * draw_count_};
}

void Renderer::record_device_render(VkCommandBuffer cmd, const PinholeCamera& camera, const RenderOptions& options,
                                    const IndirectStages& stages) {
  if (!stages.args) throw Error("GPU renderer: a device-driven render needs its indirect arguments");
  if (options.parts != draw_list_parts_) throw Error("GPU renderer: prepare_device_render was not called for these options");
  GBufferTargets& targets = targets_for(camera.width, camera.height);
  record_stages(cmd, targets, camera, raster_pipeline(options.cull_back_faces), true, &stages);
  identity_valid_ = false;  // the identity pass (if its arguments ran it) used the device's coefficients
  last_targets_ = &targets;
  last_camera_ = camera;
}

RenderTimings Renderer::render(const FaceParameters& params, const PinholeCamera& camera, const RenderOptions& options,
                              const RecordAfterRender& then) {
  std::string why;
  if (!params.IsValid(&why, static_cast<int>(model_.identity_basis.cols()), static_cast<int>(model_.expression_basis.cols()),
                      static_cast<int>(model_.albedo_basis.cols()))) {
    throw Error("invalid face parameters: " + why);
  }
  check_camera(camera, options);
  const auto start = std::chrono::steady_clock::now();

  // Per-frame data: coefficients and pose + lighting (host-visible, read by the shaders).
  std::vector<float> coeffs(std::max<uint32_t>(coefficient_count_, 1), 0.f);
  const Eigen::Index kid = model_.identity_basis.cols(), kexp = model_.expression_basis.cols();
  copy_padded(coeffs.data(), params.alpha, kid);
  copy_padded(coeffs.data() + kid, params.delta, kexp);
  copy_padded(coeffs.data() + kid + kexp, params.beta, model_.albedo_basis.cols());
  if (coefficient_count_) coefficients_.write(coeffs.data(), coefficient_count_ * sizeof(float));
  // The identity pass runs only when alpha or beta differ from the last one it ran for.
  std::vector<float> identity_key(coeffs.begin(), coeffs.begin() + kid);
  identity_key.insert(identity_key.end(), coeffs.begin() + kid + kexp, coeffs.begin() + coefficient_count_);
  const bool run_identity = !identity_valid_ || identity_key != identity_key_;
  FrameBlock frame{};
  const Eigen::Matrix3f r = rotation_from_euler(params.euler);
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) frame.rotation_rows[i][j] = r(i, j);
    frame.translation[i] = params.translation[i];
  }
  std::memcpy(frame.gamma, params.gamma.data(), sizeof(frame.gamma));
  frame_.write(&frame, sizeof(frame));

  update_draw_list(options);
  GBufferTargets& targets = targets_for(camera.width, camera.height);
  const GraphicsPipeline& raster = raster_pipeline(options.cull_back_faces);

  context_.submit_and_wait(
      [&](VkCommandBuffer cmd) {
        record_stages(cmd, targets, camera, raster, run_identity, nullptr);
        if (then) then(cmd, targets);
      },
      then ? "render G-buffer + follow-up" : "render G-buffer");

  identity_key_ = std::move(identity_key);
  identity_valid_ = true;
  RenderTimings timings;
  timings.identity_updated = run_identity;
  timings.wall_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  timings.drawn_triangles = draw_count_;
  if (timestamps_) {
    timestamps_->fetch();
    timings.model_ms = timestamps_->elapsed_ms(0, 1);
    timings.shade_ms = timestamps_->elapsed_ms(1, 2);
    timings.raster_ms = timestamps_->elapsed_ms(2, 3);
    timings.gpu_total_ms = timestamps_->elapsed_ms(0, 3);
  }
  last_targets_ = &targets;
  last_camera_ = camera;
  return timings;
}

void Renderer::record_stages(VkCommandBuffer cmd, GBufferTargets& targets, const PinholeCamera& camera,
                             const GraphicsPipeline& raster, bool run_identity, const IndirectStages* stages) {
  CommandRecorder rec(context_, cmd);
  const Eigen::Index kid = model_.identity_basis.cols(), kexp = model_.expression_basis.cols();
  // A device-driven render is one part of its caller's submission: the caller times it.
  TimestampQueries* stamps = stages ? nullptr : timestamps_.get();
  if (stamps) {
    stamps->reset(cmd);
    stamps->write(cmd, 0);
  }
  auto dispatch = [&](uint32_t threads, VkDeviceSize Renderer::IndirectStages::*offset) {
    if (stages) {
      rec.dispatch_indirect(*stages->args, stages->*offset);
    } else {
      rec.dispatch_1d(threads, kLocalSize);
    }
  };

  if (run_identity) {
    rec.bind(*identity_pipeline_);
    const Buffer* identity_buffers[] = {&mean_shape_, &identity_basis_, &mean_albedo_, &albedo_basis_,
                                        &coefficients_, &base_shape_, &albedo_};
    for (uint32_t i = 0; i < 7; ++i) rec.set_storage_buffer(i, *identity_buffers[i]);
    rec.push_constants(IdentityEvalPush{3 * num_vertices_, static_cast<uint32_t>(kid),
                                        static_cast<uint32_t>(model_.albedo_basis.cols()),
                                        static_cast<uint32_t>(kid + kexp)});
    dispatch(3 * num_vertices_, &IndirectStages::identity);
    rec.memory_barrier(VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT,
                       VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_READ_BIT);
  }
  rec.bind(*model_pipeline_);
  const Buffer* model_buffers[] = {&base_shape_, &expression_basis_, &coefficients_, &shape_};
  for (uint32_t i = 0; i < 4; ++i) rec.set_storage_buffer(i, *model_buffers[i]);
  rec.push_constants(ModelEvalPush{3 * num_vertices_, static_cast<uint32_t>(kexp), static_cast<uint32_t>(kid), 0});
  dispatch(3 * num_vertices_, &IndirectStages::model);
  rec.memory_barrier(VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT,
                     VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_READ_BIT);
  if (stamps) stamps->write(cmd, 1);

  rec.bind(*shade_pipeline_);
  const Buffer* shade_buffers[] = {&shape_, &albedo_, &triangles_, &adjacency_offsets_, &adjacency_,
                                   &frame_, &camera_positions_, &camera_normals_, &colors_};
  for (uint32_t i = 0; i < 9; ++i) rec.set_storage_buffer(i, *shade_buffers[i]);
  rec.push_constants(ShadePush{num_vertices_});
  dispatch(num_vertices_, &IndirectStages::shade);
  if (stamps) stamps->write(cmd, 2);

  // One barrier: vertex results -> vertex shader, and every target -> attachment. The
  // targets are cleared, so their old contents need not survive (UNDEFINED); the source
  // scope covers readers of the previous frame's G-buffer (write-after-read).
  Image* colour_targets[] = {&targets.color, &targets.position, &targets.normal, &targets.barycentric, &targets.ids};
  BarrierBatch pre;
  pre.memory(VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT,
             VK_PIPELINE_STAGE_2_VERTEX_SHADER_BIT | VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
             VK_ACCESS_2_SHADER_STORAGE_READ_BIT);
  for (Image* image : colour_targets) {
    image->layout = VK_IMAGE_LAYOUT_UNDEFINED;
    pre.image(*image, VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL, VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT,
              VK_ACCESS_2_NONE, VK_PIPELINE_STAGE_2_COLOR_ATTACHMENT_OUTPUT_BIT,
              VK_ACCESS_2_COLOR_ATTACHMENT_WRITE_BIT);
  }
  targets.depth.layout = VK_IMAGE_LAYOUT_UNDEFINED;
  pre.image(targets.depth, VK_IMAGE_LAYOUT_DEPTH_ATTACHMENT_OPTIMAL, VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT,
            VK_ACCESS_2_NONE, VK_PIPELINE_STAGE_2_EARLY_FRAGMENT_TESTS_BIT | VK_PIPELINE_STAGE_2_LATE_FRAGMENT_TESTS_BIT,
            VK_ACCESS_2_DEPTH_STENCIL_ATTACHMENT_READ_BIT | VK_ACCESS_2_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT);
  pre.record(cmd);

  VkRenderingAttachmentInfo colour_attachments[5];
  for (int i = 0; i < 5; ++i) {
    colour_attachments[i] = {VK_STRUCTURE_TYPE_RENDERING_ATTACHMENT_INFO};
    colour_attachments[i].imageView = colour_targets[i]->view();
    colour_attachments[i].imageLayout = VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL;
    colour_attachments[i].loadOp = VK_ATTACHMENT_LOAD_OP_CLEAR;
    colour_attachments[i].storeOp = VK_ATTACHMENT_STORE_OP_STORE;
    colour_attachments[i].clearValue = {};  // zeros (float and uint alike)
  }
  VkRenderingAttachmentInfo depth_attachment{VK_STRUCTURE_TYPE_RENDERING_ATTACHMENT_INFO};
  depth_attachment.imageView = targets.depth.view();
  depth_attachment.imageLayout = VK_IMAGE_LAYOUT_DEPTH_ATTACHMENT_OPTIMAL;
  depth_attachment.loadOp = VK_ATTACHMENT_LOAD_OP_CLEAR;
  depth_attachment.storeOp = VK_ATTACHMENT_STORE_OP_STORE;
  depth_attachment.clearValue.depthStencil = {1.0f, 0};
  VkRenderingInfo rendering{VK_STRUCTURE_TYPE_RENDERING_INFO};
  rendering.renderArea = {{0, 0}, {static_cast<uint32_t>(camera.width), static_cast<uint32_t>(camera.height)}};
  rendering.layerCount = 1;
  rendering.colorAttachmentCount = 5;
  rendering.pColorAttachments = colour_attachments;
  rendering.pDepthAttachment = &depth_attachment;
  vkCmdBeginRendering(cmd, &rendering);
  VkViewport viewport{0.f, 0.f, static_cast<float>(camera.width), static_cast<float>(camera.height), 0.f, 1.f};
  VkRect2D scissor = rendering.renderArea;
  vkCmdSetViewport(cmd, 0, 1, &viewport);
  vkCmdSetScissor(cmd, 0, 1, &scissor);
  rec.bind(raster);
  rec.set_storage_buffer(0, camera_positions_);
  rec.set_storage_buffer(1, camera_normals_);
  rec.set_storage_buffer(2, colors_);
  rec.set_storage_buffer(3, draw_list_);
  rec.push_constants(RasterPush{camera.fx, camera.fy, camera.cx, camera.cy, static_cast<float>(camera.width),
                                static_cast<float>(camera.height), camera.near_plane, camera.far_plane});
  if (stages) {
    rec.draw_indirect(*stages->args, stages->draw);
  } else {
    rec.draw(3 * draw_count_);
  }
  vkCmdEndRendering(cmd);

  BarrierBatch post;
  for (Image* image : colour_targets) {
    post.image(*image, VK_IMAGE_LAYOUT_GENERAL, VK_PIPELINE_STAGE_2_COLOR_ATTACHMENT_OUTPUT_BIT,
               VK_ACCESS_2_COLOR_ATTACHMENT_WRITE_BIT, VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT,
               VK_ACCESS_2_MEMORY_READ_BIT);
  }
  post.image(targets.depth, VK_IMAGE_LAYOUT_GENERAL, VK_PIPELINE_STAGE_2_LATE_FRAGMENT_TESTS_BIT,
             VK_ACCESS_2_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT, VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT,
             VK_ACCESS_2_MEMORY_READ_BIT);
  post.record(cmd);
  if (stamps) stamps->write(cmd, 3);
}

const GBufferTargets& Renderer::targets() const {
  if (!last_targets_) throw Error("GPU renderer: no G-buffer yet (call render first)");
  return *last_targets_;
}

GBuffer Renderer::read_gbuffer() const {
  GBuffer g;
  read_gbuffer(&g);
  return g;
}

void Renderer::read_gbuffer(GBuffer* out, const PixelBox* box) const {
  if (!out) throw Error("GPU renderer: read_gbuffer needs an output");
  targets();  // throws when nothing was rendered
  GBufferTargets& t = *last_targets_;
  const int w = static_cast<int>(t.color.width()), h = static_cast<int>(t.color.height());
  PixelBox b{0, w - 1, 0, h - 1};
  if (box) b = PixelBox{std::max(0, box->i0), std::min(w - 1, box->i1), std::max(0, box->j0), std::min(h - 1, box->j1)};
  GBuffer& g = *out;
  const int threads = ResolvedThreadCount(0);
  const bool whole = b.i0 == 0 && b.j0 == 0 && b.i1 == w - 1 && b.j1 == h - 1;
  if (whole) {
    // Every pixel is written below: sized, not cleared.
    const size_t n = static_cast<size_t>(w) * h;
    g.width = w;
    g.height = h;
    for (auto* v : {&g.color, &g.position, &g.normal, &g.barycentric}) v->resize(3 * n);
    g.vertices.resize(3 * n);
    g.triangle.resize(n);
  } else {
    g.ClearForDraw(w, h, threads);
  }
  g.drawn = GBuffer::DrawnTrace{g.triangle.data(), b.i0, b.i1, b.j0, b.j1};
  if (b.empty()) return;  // nothing the render covered: nothing to read
  const uint32_t bw = static_cast<uint32_t>(b.i1 - b.i0 + 1), bh = static_cast<uint32_t>(b.j1 - b.j0 + 1);
  const VkDeviceSize plane = static_cast<VkDeviceSize>(bw) * bh * 16;
  Image* images[] = {&t.color, &t.position, &t.normal, &t.barycentric, &t.ids};
  if (!readback_.valid() || readback_.size() < plane * 5)
    readback_ = Buffer(context_, static_cast<VkDeviceSize>(w) * h * 16 * 5, VK_BUFFER_USAGE_TRANSFER_DST_BIT,
                       BufferDomain::Readback, "G-buffer readback");
  context_.submit_and_wait(
      [&](VkCommandBuffer cmd) {
        CommandRecorder rec(context_, cmd);
        rec.image_barriers({images[0], images[1], images[2], images[3], images[4]}, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL,
                           VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT, VK_ACCESS_2_MEMORY_WRITE_BIT, VK_PIPELINE_STAGE_2_COPY_BIT,
                           VK_ACCESS_2_TRANSFER_READ_BIT);
        for (int i = 0; i < 5; ++i) {
          VkBufferImageCopy region{};
          region.bufferOffset = plane * i;
          region.imageSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1};
          region.imageOffset = {b.i0, b.j0, 0};
          region.imageExtent = {bw, bh, 1};
          vkCmdCopyImageToBuffer(cmd, images[i]->handle(), VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, readback_.handle(), 1,
                                 &region);
        }
        // Back to GENERAL, where the tracker's compute passes expect the G-buffer.
        rec.image_barriers({images[0], images[1], images[2], images[3], images[4]}, VK_IMAGE_LAYOUT_GENERAL,
                           VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_NONE, VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT,
                           VK_ACCESS_2_MEMORY_READ_BIT);
        rec.memory_barrier(VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT, VK_PIPELINE_STAGE_2_HOST_BIT,
                           VK_ACCESS_2_HOST_READ_BIT);
      },
      "G-buffer readback");
  // Unpacked straight from the mapped readback (cached host memory where the device offers it).
  const size_t stride = static_cast<size_t>(bw) * bh * 4;  // floats per plane
  const auto* floats = static_cast<const float*>(readback_.mapped_for_read());
  const auto* ids = reinterpret_cast<const uint32_t*>(floats + 4 * stride);  // the fifth plane
  // Rows in parallel: one core does not keep up with reading ~25 MB per 640x480 frame.
  ParallelFor(static_cast<int>(bh), threads, [&](int row) {
    for (uint32_t col = 0; col < bw; ++col) {
      const size_t q = static_cast<size_t>(row) * bw + col;  // in the box
      const size_t p = static_cast<size_t>(b.j0 + row) * w + static_cast<size_t>(b.i0) + col;  // in the image
      for (int c = 0; c < 3; ++c) {
        g.color[3 * p + c] = floats[0 * stride + 4 * q + c];
        g.position[3 * p + c] = floats[1 * stride + 4 * q + c];
        g.normal[3 * p + c] = floats[2 * stride + 4 * q + c];
        g.barycentric[3 * p + c] = floats[3 * stride + 4 * q + c];
      }
      const uint32_t tri = ids[4 * q];
      g.triangle[p] = tri == 0 ? -1 : static_cast<int32_t>(tri - 1);
      for (int c = 0; c < 3; ++c) g.vertices[3 * p + c] = tri == 0 ? -1 : static_cast<int32_t>(ids[4 * q + 1 + c]);
    }
  });
}

VertexState Renderer::read_vertex_state() const {
  const Eigen::Index n = num_vertices_;
  VertexState s;
  s.model_positions.resize(3 * n);
  s.albedo.resize(3 * n);
  shape_.read(s.model_positions.data(), 3 * n * sizeof(float));
  albedo_.read(s.albedo.data(), 3 * n * sizeof(float));
  auto read_vec4 = [&](const Buffer& b, Eigen::VectorXf& out) {
    std::vector<glm::vec4> tmp(n);
    b.read(tmp.data(), tmp.size() * sizeof(glm::vec4));
    out.resize(3 * n);
    for (Eigen::Index v = 0; v < n; ++v) {
      for (int c = 0; c < 3; ++c) out[3 * v + c] = tmp[v][c];
    }
  };
  read_vec4(camera_positions_, s.camera_positions);
  read_vec4(camera_normals_, s.camera_normals);
  read_vec4(colors_, s.colors);
  return s;
}

}  // namespace face_reenact::gpu
