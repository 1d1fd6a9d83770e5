#pragma once
// Accuracy of a fit against ground truth (synthetic recordings): the error measures of
// `face-reenact track --report` and of the tracker tests (docs/tracker.md, "Accuracy").
#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <vector>

#include "face_reenact/gpu/cpu_renderer.h"
#include "face_reenact/gpu/image_formation.h"
#include "face_reenact/tracker/tracker_model.h"

namespace face_reenact::tracker {

struct FitErrors {
  // Closest-point distance from each vertex of the true face region to the fitted surface,
  // camera frame, millimetres (the paper's measure, Sec. 8.1: the true face against the
  // reconstruction, whatever its mesh). The face region: the vertices of the face-part
  // triangles (all three vertices in model part Face) that are visible in the true render at
  // the frame's camera (every part drawn, so eyes, teeth and ears occlude) and in the render of
  // the same face at rest (expression 0), which leaves out the mouth cavity an open mouth shows
  // (the part holds it; the paper's ground truth, scans of the face, has none); the fitted surface:
  // the fit's skin (kFittedSurfaceParts), the continuous surface the tracker fits. Against the
  // fit's face part alone, a face border that slides along the skin (onto the fitted ear or
  // scalp) counted as a surface error although the fitted surface was there: seed 5151's
  // 20 mm max was such a slide, 1.4-2.2 mm from the fitted skin (docs/tracking-pipeline.md,
  // "What the surface error measures"). The vertex figures below count the slide.
  double geometric_mm_mean = 0;
  double geometric_mm_max = 0;
  // Distance between corresponding vertices of the true and the fitted face region, mm: the
  // surface error plus any sliding along the surface, which no depth or image term observes
  // on smooth skin.
  double vertex_mm_mean = 0;
  double vertex_mm_max = 0;
  // Mean image distance (pixels of the frame) between the projections of corresponding
  // face-region vertices of the true and the fitted face.
  double alignment_px_mean = 0;
  double rotation_deg = 0;    // angle of R_fit^T R_true
  double translation_mm = 0;  // |t_fit - t_true|
  // Mean |delta_fit - delta_true| over the model's blendshapes (weights in [0, 1]).
  double expression_mean_abs = 0;
  int region_vertices = 0;  // vertices the surface and 2D errors average over
  int geometric_max_vertex = -1;  // the model vertex where geometric_mm_max was found
};

// What CompareToGroundTruth and CompareIdentities measure against: the fit's skin (face, scalp,
// ears, neck), without the eyeballs, teeth and tongue, which are separate surfaces.
inline constexpr gpu::PartMask kFittedSurfaceParts = gpu::kSkinParts;

// Closest points on a triangle mesh (uniform grid over the triangles' bounding boxes).
class TriangleSurface {
 public:
  // `positions` 3N, `triangles` indices into them. `cell` is the grid spacing (metres).
  TriangleSurface(const Eigen::VectorXf& positions, const std::vector<std::array<int32_t, 3>>& triangles, float cell = 0.01f);
  // Distance from p to the nearest point of any triangle (infinity for an empty surface).
  double Distance(const Eigen::Vector3d& p) const;

 private:
  std::vector<Eigen::Vector3d> a_, b_, c_;
  Eigen::Vector3d origin_ = Eigen::Vector3d::Zero();
  Eigen::Vector3i dims_ = Eigen::Vector3i::Zero();
  double cell_ = 0.01;
  std::vector<std::vector<int32_t>> cells_;
  int cell_index(const Eigen::Vector3i& c) const { return (c.z() * dims_.y() + c.y()) * dims_.x() + c.x(); }
};

// Closest point to p on triangle (a, b, c).
Eigen::Vector3d ClosestPointOnTriangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                                       const Eigen::Vector3d& c);

// The face region FitErrors measures over, per vertex (the definition at FitErrors).
std::vector<bool> GroundTruthFaceRegion(const gpu::CpuRenderer& renderer, const TrackerModel& model,
                                        const gpu::FaceParameters& truth, const gpu::PinholeCamera& camera);

// Compares `fit` with `truth` on the model (which must contain the Face part); `renderer`
// renders `model.render` (visibility of the face region) and `camera` is the frame's camera.
// Throws face_reenact::Error when the model has no face part or the renderer another model.
FitErrors CompareToGroundTruth(const gpu::CpuRenderer& renderer, const TrackerModel& model,
                               const gpu::FaceParameters& fit, const gpu::FaceParameters& truth,
                               const gpu::PinholeCamera& camera);

// How far a fitted identity is from the true one, independent of pose and expression: both
// neutral faces (delta = 0) seen from the front at `distance_m` on `camera`, the fitted one
// rigidly aligned to the true one (corresponding face-region vertices, Kabsch), then the same
// surface measure as FitErrors::geometric_mm_* (the true face region visible from the front
// against the aligned fitted skin).
struct IdentityErrors {
  double surface_mm_mean = 0;  // closest-point distance, true region -> aligned fitted surface
  double surface_mm_max = 0;
  double vertex_mm_mean = 0;   // distance between corresponding vertices (also counts sliding
                               // along the surface, which no depth or image term observes)
  int region_vertices = 0;
};

IdentityErrors CompareIdentities(const gpu::CpuRenderer& renderer, const TrackerModel& model,
                                 const Eigen::VectorXf& alpha_fit, const Eigen::VectorXf& alpha_truth,
                                 const gpu::PinholeCamera& camera, float distance_m);

}  // namespace face_reenact::tracker
