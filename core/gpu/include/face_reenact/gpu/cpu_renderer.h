#pragma once
// The CPU twin of the Vulkan renderer (renderer.h): the same S(P) math, written plainly, used
// as the oracle in tests and as the CPU column of `face-reenact bench render`. It follows the
// conventions of image_formation.h and mirrors the GPU rasteriser's rules:
// - vertex screen positions are snapped to 1/256 pixel (8 sub-pixel bits, as GPUs do);
// - a pixel is covered when its centre is strictly inside the triangle, or exactly on a top or
//   left edge (the top-left fill rule);
// - barycentrics are perspective-correct; depth is tested with LESS on the same depth value the
//   GPU writes, d = far * (z - near) / ((far - near) * z), triangles in draw order.
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <vector>

#include "face_reenact/gpu/image_formation.h"

namespace face_reenact::gpu {

struct CpuRenderTimes {
  double model_ms = 0;   // model evaluation (Eq. 1-2)
  double shade_ms = 0;   // normals, rigid transform, SH shading
  double raster_ms = 0;  // rasterisation into the G-buffer
};

// Whether CpuRenderer::evaluate shades the vertices (VertexState::colors). A caller that reads
// only the geometry (the tracker's synthesis on RGB video, the gaze's eye renders) saves each
// vertex its SH basis and irradiance, most of the shading pass; its colours are then zero.
enum class VertexColors { kShaded, kNone };

// Indices (into the model's triangle list) of the triangles drawn with `options`.
std::vector<int32_t> drawn_triangles(const RenderModel& model, const RenderOptions& options);

// Safe to use from several threads at once.
class CpuRenderer {
 public:
  explicit CpuRenderer(RenderModel model);
  CpuRenderer(const CpuRenderer& other);  // the model; not the identity kept from other's renders
  CpuRenderer& operator=(const CpuRenderer&) = delete;

  const RenderModel& model() const { return model_; }

  // Model evaluation, normals and shading, on up to `threads` threads (bit-identical for any
  // count). Throws face_reenact::Error on invalid parameters.
  VertexState evaluate(const FaceParameters& params, CpuRenderTimes* times = nullptr, int threads = 1,
                       VertexColors colors = VertexColors::kShaded) const;
  GBuffer render(const FaceParameters& params, const PinholeCamera& camera, const RenderOptions& options = {},
                 CpuRenderTimes* times = nullptr) const;
  // Rasterises already evaluated vertices.
  GBuffer rasterize(const VertexState& state, const PinholeCamera& camera, const RenderOptions& options) const;
  // The same into `out`, reusing its buffers: a G-buffer holds 16 values per pixel (20 MB at
  // 640x480), and a per-frame caller that keeps one allocates and page-faults none of it again.
  // Up to `threads` threads share the work (triangle set-up, then bands of rows); the result is
  // bit-identical for any count.
  void rasterize(const VertexState& state, const PinholeCamera& camera, const RenderOptions& options, GBuffer* out,
                 int threads = 1) const;

 private:
  // a_id + E_id alpha and a_alb + E_alb beta for one alpha/beta.
  struct IdentityParts {
    Eigen::VectorXf alpha, beta;
    Eigen::VectorXf shape, albedo;
  };
  std::shared_ptr<const IdentityParts> identity_parts(const FaceParameters& params) const;

  // drawn_triangles(model_, {parts}), listed once per part mask: every draw listed them from all
  // the model's triangles (a tracked frame draws 6-10 times, the compositor 3-4).
  const std::vector<int32_t>& drawn_triangles_for(PartMask parts) const;

  RenderModel model_;
  std::vector<int32_t> incident_begin_, incident_;  // each vertex's triangles, ascending
  mutable std::mutex identity_mutex_;
  mutable std::shared_ptr<const IdentityParts> identity_;  // of the last evaluate
  mutable std::mutex drawn_mutex_;
  mutable std::map<PartMask, std::vector<int32_t>> drawn_;  // by part mask; entries stay where they are
};

}  // namespace face_reenact::gpu
