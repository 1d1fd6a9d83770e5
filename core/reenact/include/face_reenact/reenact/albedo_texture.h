#pragma once
// The actor's albedo map of paper Sec. 6.3 (last paragraph): a high-resolution texture in the
// model's UV layout, made from three views of the actor (front, about 20 degrees to either side),
// each camera image divided by the estimated shading, combined with pyramid (multi-band) blending.
// The per-vertex AlbedoMap (face_compositor.h) holds no detail finer than the mesh; this holds the
// frame's own (pores, moles, the brows' hairs, the lips' edge) wherever the re-rendering cannot take
// the current frame's colour: a surface the frame does not show, and Appearance::kAlbedoMap.
//
// Three units, kept apart: the layout (which triangle each texel lies on: the model's alone),
// one view's unwrap (FaceCompositor::UnwrapAlbedo: it owns the shading the division must match),
// and the blend of the views (BlendAlbedoViews). AlbedoViewChooser picks the frames.
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

namespace face_reenact {
struct FaceModel;
}

namespace face_reenact::gpu {
struct FaceParameters;
}

namespace face_reenact::reenact {

struct AlbedoTextureOptions {
  // Side of the whole UV square in texels (the paper's 2048); only the face's island of it is
  // stored (about 430 x 490 texels at 2048). 0: no texture, the per-vertex map alone.
  int size = 2048;
  // The side views: a tracked frame turned this far (yaw, degrees) either way is the ideal one; a
  // frame turned less than min_side_yaw_deg is no side view, more than max_side_yaw_deg too far
  // (the far cheek hidden, the near one grazing).
  float side_yaw_deg = 20.0f;
  float min_side_yaw_deg = 8.0f;
  float max_side_yaw_deg = 35.0f;
  // A front view turned mostly up or down (the head pitched against the camera) is taken only
  // while no level one is, and only up to this turn (degrees).
  float max_front_pitch_deg = 30.0f;
  // A view shows the face at rest enough: jawOpen and each eyeBlink at most this (an open mouth
  // stretches the lips' skin, a blink shows the lid where the eye is usually seen).
  float max_expression = 0.35f;
  // The closed-eyes view: a frame facing the camera with both eyeBlinks at least this. A resting
  // eye folds its upper lid away under the brow, so the front and side views show that skin only
  // squeezed into a shadowed band; the view of a blink is where the lids a source's blink closes
  // over the target's eyes take their colour from (FaceCompositor::UnwrapAlbedo takes each view in
  // proportion to how far it unfolds the lids; this one only on them).
  float min_closed_eyes_blink = 0.45f;
  int blend_levels = 5;  // pyramid levels of the multi-band blend (>= 1)
  // Build on a thread of its own (the live session: a build of three views takes 0.1-0.2 s on two
  // cores, a stalled frame); the frames meanwhile keep the last texture. Off, the frame that
  // completes the views builds it, so a file's output does not depend on timing.
  bool background = false;
  bool IsValid(std::string* why) const;
};

// The model's UV layout rasterised at one texture size: for each texel of the face's island (the
// largest connected island of FacePart::Face triangles in UV), the triangle it lies on and its
// barycentric coordinates there. Texels within two texels outside the island's triangles take the
// nearest triangle with clamped coordinates (a gutter, so bilinear sampling at the island's edge
// never reads an unwritten texel). UV (u, v) lies at texel (u * size - x0, (1 - v) * size - y0),
// texel centres at +0.5.
struct AlbedoTextureLayout {
  int size = 0;
  int x0 = 0, y0 = 0, width = 0, height = 0;  // the island's rectangle in the full UV square
  std::vector<int32_t> triangle;              // width * height; -1: on no triangle
  std::vector<float> barycentric;             // 3 per texel
  std::vector<int32_t> vertices;              // 3 per texel: the triangle's vertices
  std::vector<char> textured;                 // per model triangle: all its corners in the island
  // Throws face_reenact::Error when the model has no UVs or size is outside 64..8192.
  static std::shared_ptr<const AlbedoTextureLayout> ForModel(const FaceModel& model, int size);
  Eigen::Vector2f ToTexel(const Eigen::Vector2f& uv) const {
    return {uv.x() * static_cast<float>(size) - static_cast<float>(x0) - 0.5f,
            (1.0f - uv.y()) * static_cast<float>(size) - static_cast<float>(y0) - 0.5f};
  }
  size_t texels() const { return static_cast<size_t>(width) * static_cast<size_t>(height); }
};

// One view's albedo over the layout's rectangle (FaceCompositor::UnwrapAlbedo).
struct AlbedoTextureView {
  cv::Mat albedo;  // CV_32FC3, linear RGB
  cv::Mat weight;  // CV_32FC1, 0 where the view does not show the surface clearly
  int64_t frame_index = -1;
  float yaw_deg = 0.f;
  int seen_texels = 0;
  bool closed_eyes = false;  // the closed-eyes view (AlbedoViewChooser::kClosedEyes): weighted on the lids alone
};

struct AlbedoTexture {
  std::shared_ptr<const AlbedoTextureLayout> layout;
  cv::Mat albedo;  // CV_32FC3 linear RGB over the layout's rectangle
  cv::Mat seen;    // CV_32FC1: the views' summed weight (0: the per-vertex map's colour)
  // The per-vertex albedo the views were blended over (3N): the re-rendering scales the texture
  // by the per-vertex map's change since (a camera's exposure drifting, later frames refining the
  // map), so the texture adds the detail and the map keeps the colour current.
  Eigen::VectorXf base;
  struct ViewInfo {
    int64_t frame_index = -1;
    float yaw_deg = 0.f;
    int seen_texels = 0;
    bool closed_eyes = false;
  };
  std::vector<ViewInfo> views;
  double build_ms = 0;  // the views' unwraps and the blend (FaceCompositor::BuildAlbedoTexture)
  bool empty() const { return albedo.empty(); }
  // Bilinear albedo at `uv` (linear RGB) and, when asked, the views' summed weight there (`seen`);
  // false outside the layout's rectangle.
  bool Sample(const Eigen::Vector2f& uv, Eigen::Vector3f* rgb, float* seen_weight = nullptr) const;
};

// The texture of `views` (each over `layout`) blended per pyramid level (Burt and Adelson):
// each level of each view's Laplacian pyramid weighted by its weight smoothed to that level, over
// `base_albedo` (3N per-vertex linear RGB, interpolated over each texel's triangle) with a weight
// that only shows where no view does. Seams between views and towards the unseen surface spread
// over the coarse levels, while the finest detail comes from the view that shows it best.
// Throws face_reenact::Error on a view or base of the wrong size.
AlbedoTexture BlendAlbedoViews(std::shared_ptr<const AlbedoTextureLayout> layout,
                               const std::vector<AlbedoTextureView>& views, const Eigen::VectorXf& base_albedo,
                               int levels);

// The signed head yaw relative to the camera, degrees: the angle, about the camera's vertical, from
// the face's ray to the camera to its forward axis (positive: the face turned towards +x of the
// image).
float head_yaw_deg(const gpu::FaceParameters& params);

// Which tracked frames become the texture's views: the one closest to facing the camera (one turned
// mostly up or down, up to options.max_front_pitch_deg, only while no level one is), and per
// side the one turned closest to options.side_yaw_deg (between min_ and max_side_yaw_deg), each
// with the mouth and eyes near rest (options.max_expression) and, among those, the nearest to
// rest overall (the expression's summed weights count as 4 degrees each); and the closed-eyes
// view: a blink (both eyeBlinks at least options.min_closed_eyes_blink, the mouth near rest)
// facing the camera, the more closed the better (each 0.1 of the less closed eye's blink short of
// 1 counts as 2 degrees). Consider() says which slot a frame would fill or improve (by 2 degrees
// or more); the caller keeps that frame.
class AlbedoViewChooser {
 public:
  enum Slot { kFront = 0, kLeft = 1, kRight = 2, kClosedEyes = 3, kNone = -1 };
  static constexpr int kSlots = 4;
  explicit AlbedoViewChooser(const AlbedoTextureOptions& options) : options_(options) {}
  // The slot this frame improves (kNone: none), and takes it.
  Slot Consider(const gpu::FaceParameters& params);
  bool filled(Slot s) const { return best_[s] >= 0.f; }
  int filled_count() const;
  void Reset();

 private:
  AlbedoTextureOptions options_;
  float best_[kSlots] = {-1.f, -1.f, -1.f, -1.f};  // the slot's distance from its ideal view; -1 = empty
};

}  // namespace face_reenact::reenact
