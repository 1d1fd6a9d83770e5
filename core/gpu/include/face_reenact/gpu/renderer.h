#pragma once
// The Vulkan image formation model S(P) (paper Sec. 5.2): per frame
//   1. identity_eval.comp a_id + E_id alpha and the albedo, only when alpha/beta change,
//      model_eval.comp    + E_exp delta                                              [model]
//   2. vertex_shade.comp  area-weighted normals, R v + t, SH shading per vertex    [shade]
//   3. gbuffer.vert/.frag rasterisation into the G-buffer (5 colour targets + depth) [raster]
// each bracketed by timestamp queries. The G-buffer stays on the GPU (targets()) for the
// tracker's compute passes; read_gbuffer() copies it to the host for tests and tools.
// Conventions and formats: image_formation.h and docs/renderer.md. The CPU twin is
// cpu_renderer.h.
#include <functional>
#include <map>
#include <memory>
#include <utility>
#include <vector>

#include "face_reenact/gpu/buffer.h"
#include "face_reenact/gpu/command.h"
#include "face_reenact/gpu/image.h"
#include "face_reenact/gpu/image_formation.h"
#include "face_reenact/gpu/pipeline.h"

namespace face_reenact::gpu {

class Context;

// The G-buffer images of one resolution. After render() they are in VK_IMAGE_LAYOUT_GENERAL
// and visible to any later shader read or transfer.
struct GBufferTargets {
  Image color;        // RGBA32F: C_S, a = 1 where covered
  Image position;     // RGBA32F: X_S (camera space, m), w = 1 where covered
  Image normal;       // RGBA32F: N_S (unit, camera space), w = 0
  Image barycentric;  // RGBA32F: b0, b1, b2 (perspective-correct), w = 0
  Image ids;          // RGBA32UI: model triangle + 1 (0 = not covered), v0, v1, v2
  Image depth;        // D32: d = far (z - near) / ((far - near) z), 1 where empty
};

inline constexpr VkFormat kGBufferFloatFormat = VK_FORMAT_R32G32B32A32_SFLOAT;
inline constexpr VkFormat kGBufferIdFormat = VK_FORMAT_R32G32B32A32_UINT;
inline constexpr VkFormat kGBufferDepthFormat = VK_FORMAT_D32_SFLOAT;

struct RenderTimings {
  double model_ms = -1;   // GPU time per stage from timestamp queries (-1: not supported)
  double shade_ms = -1;
  double raster_ms = -1;
  double gpu_total_ms = -1;
  double wall_ms = 0;     // host time from recording to completion
  size_t drawn_triangles = 0;
  bool identity_updated = false;  // this render re-evaluated a_id + E_id alpha and the albedo
};

class Renderer {
 public:
  struct Options {
    // Timestamp queries around the stages. Cheap on GPUs; on lavapipe each one flushes the
    // rasteriser, so a tracker loop may turn them off (RenderTimings then has -1 stage times).
    bool timestamps = true;
  };

  Renderer(const Context& context, const RenderModel& model) : Renderer(context, model, Options{}) {}
  Renderer(const Context& context, const RenderModel& model, const Options& options);
  ~Renderer();
  Renderer(const Renderer&) = delete;
  Renderer& operator=(const Renderer&) = delete;

  const RenderModel& model() const { return model_; }

  // Renders S(P) at `camera`'s resolution and waits for the GPU. Invalid parameters (NaN,
  // infinity, too many coefficients), cameras or options throw face_reenact::Error before any
  // GPU work is recorded. `then`, when given, records more work into the same submission after
  // the render, with the G-buffer it wrote (images in GENERAL layout, writes made available to
  // ALL_COMMANDS reads): a solver linearising the render saves a submission and a host wait.
  using RecordAfterRender = std::function<void(VkCommandBuffer, const GBufferTargets&)>;
  RenderTimings render(const FaceParameters& params, const PinholeCamera& camera, const RenderOptions& options = {},
                       const RecordAfterRender& then = {});

  // Device-driven rendering, for a solver whose parameters live on the device (the Vulkan
  // tracker records a frame's whole Gauss-Newton schedule into one submission): the caller's
  // passes write device_coefficients() (alpha | delta | beta, the model's counts, floats) and
  // device_frame() (FrameBlock of shaders/common.glsl: rotation rows, translation, SH) before
  // the recorded render reads them, and `args` holds each stage's VkDispatchIndirectCommand /
  // VkDrawIndirectCommand, so that a pass can skip a render (zero groups and vertices) that a
  // converged iteration does not need. prepare_device_render does the host work (validation,
  // draw list, targets, pipelines) before recording; record_device_render records the stages
  // into `cmd` without waiting. The identity pass runs where its arguments say, from the device
  // coefficients; the next render() re-evaluates the identity.
  struct IndirectStages {
    const Buffer* args = nullptr;  // VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT
    VkDeviceSize identity = 0, model = 0, shade = 0, draw = 0;  // byte offsets into args
  };
  const Buffer& device_coefficients() const { return coefficients_; }
  const Buffer& device_frame() const { return frame_; }
  struct DeviceRenderSizes {
    uint32_t model_groups = 0, shade_groups = 0;  // full-size dispatches (the identity pass: model_groups)
    uint32_t draw_vertices = 0;                                          // 3 per drawn triangle
  };
  DeviceRenderSizes prepare_device_render(const PinholeCamera& camera, const RenderOptions& options);
  void record_device_render(VkCommandBuffer cmd, const PinholeCamera& camera, const RenderOptions& options,
                            const IndirectStages& stages);

  // The G-buffer of the last render() (throws if nothing was rendered yet).
  const GBufferTargets& targets() const;
  const PinholeCamera& last_camera() const { return last_camera_; }
  GBuffer read_gbuffer() const;
  // The same into `out`, reusing its storage (per-frame callers: no fresh 20 MB per 640x480 frame).
  // With `box` (every pixel the last render covered, e.g. ProjectedBox of its vertices), only that
  // rectangle is copied and unpacked, `out` is as Resize leaves it outside, and its `drawn` trace
  // says so; at 640x480 a face's box is a fifth of the frame (docs/renderer.md).
  void read_gbuffer(GBuffer* out, const PixelBox* box = nullptr) const;
  // Per-vertex results of the last render().
  VertexState read_vertex_state() const;

  // Device buffers of the last render() for later GPU passes.
  const Buffer& camera_positions() const { return camera_positions_; }  // vec4 per vertex
  const Buffer& camera_normals() const { return camera_normals_; }      // vec4 per vertex
  const Buffer& vertex_colors() const { return colors_; }               // vec4 per vertex
  const Buffer& model_positions() const { return shape_; }              // float 3N
  const Buffer& albedo() const { return albedo_; }                      // float 3N

 private:
  GBufferTargets& targets_for(int width, int height);
  void check_camera(const PinholeCamera& camera, const RenderOptions& options) const;
  // Records stages 1-3 (sizes from `stages->args` when given) and leaves the targets in GENERAL.
  void record_stages(VkCommandBuffer cmd, GBufferTargets& targets, const PinholeCamera& camera,
                     const GraphicsPipeline& raster, bool run_identity, const IndirectStages* stages);
  void update_draw_list(const RenderOptions& options);
  const GraphicsPipeline& raster_pipeline(bool cull);

  const Context& context_;
  Options options_;
  RenderModel model_;
  uint32_t num_vertices_ = 0;
  uint32_t coefficient_count_ = 0;

  Buffer mean_shape_, identity_basis_, expression_basis_, mean_albedo_, albedo_basis_;
  Buffer triangles_, adjacency_offsets_, adjacency_;
  Buffer coefficients_, frame_;  // host-written per frame
  Buffer base_shape_, shape_, albedo_, camera_positions_, camera_normals_, colors_;
  // alpha | beta (padded) of the last identity pass, valid after the first render.
  std::vector<float> identity_key_;
  bool identity_valid_ = false;
  Buffer draw_list_;
  // Reused by read_gbuffer: allocating ~25 MB of host-visible memory per read cost a real GPU's
  // driver more than the render itself (bench reenact, 2026-11-24).
  mutable Buffer readback_;
  uint32_t draw_count_ = 0;
  PartMask draw_list_parts_ = ~0u;

  std::unique_ptr<ComputePipeline> identity_pipeline_;
  std::unique_ptr<ComputePipeline> model_pipeline_;
  std::unique_ptr<ComputePipeline> shade_pipeline_;
  std::unique_ptr<GraphicsPipeline> raster_pipelines_[2];  // [cull back faces]
  std::unique_ptr<TimestampQueries> timestamps_;

  std::map<std::pair<int, int>, std::unique_ptr<GBufferTargets>> targets_;
  GBufferTargets* last_targets_ = nullptr;
  PinholeCamera last_camera_;
};

}  // namespace face_reenact::gpu
