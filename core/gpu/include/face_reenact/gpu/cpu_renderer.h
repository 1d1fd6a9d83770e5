#pragma once
// The CPU twin of the Vulkan renderer (renderer.h): the same S(P) math, written plainly, used
// as the oracle in tests and as the CPU column of `face-reenact bench render`. It follows the
// conventions of image_formation.h and mirrors the GPU rasteriser's rules:
// - vertex screen positions are snapped to 1/256 pixel (8 sub-pixel bits, as GPUs do);
// - a pixel is covered when its centre is strictly inside the triangle, or exactly on a top or
//   left edge (the top-left fill rule);
// - barycentrics are perspective-correct; depth is tested with LESS on the same depth value the
//   GPU writes, d = far * (z - near) / ((far - near) * z), triangles in draw order.
#include <vector>

#include "face_reenact/gpu/image_formation.h"

namespace face_reenact::gpu {

struct CpuRenderTimes {
  double model_ms = 0;   // model evaluation (Eq. 1-2)
  double shade_ms = 0;   // normals, rigid transform, SH shading
  double raster_ms = 0;  // rasterisation into the G-buffer
};

// Indices (into the model's triangle list) of the triangles drawn with `options`.
std::vector<int32_t> drawn_triangles(const RenderModel& model, const RenderOptions& options);

class CpuRenderer {
 public:
  explicit CpuRenderer(RenderModel model);

  const RenderModel& model() const { return model_; }

  // Model evaluation, normals and shading. Throws face_reenact::Error on invalid parameters.
  VertexState evaluate(const FaceParameters& params, CpuRenderTimes* times = nullptr) const;
  GBuffer render(const FaceParameters& params, const PinholeCamera& camera, const RenderOptions& options = {},
                 CpuRenderTimes* times = nullptr) const;
  // Rasterises already evaluated vertices.
  GBuffer rasterize(const VertexState& state, const PinholeCamera& camera, const RenderOptions& options) const;
  // The same into `out`, reusing its buffers: a G-buffer holds 16 values per pixel (20 MB at
  // 640x480), and a per-frame caller that keeps one allocates and page-faults none of it again.
  void rasterize(const VertexState& state, const PinholeCamera& camera, const RenderOptions& options,
                 GBuffer* out) const;

 private:
  RenderModel model_;
};

}  // namespace face_reenact::gpu
