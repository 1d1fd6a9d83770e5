#pragma once
// Geometric test meshes for the renderer tests: an icosphere (analytic silhouette, normals and
// depth) and linear "models" on it with smooth random bases, so that model evaluation, normals,
// shading and rasterisation can be checked without the face model.
#include <cstdint>

#include "face_reenact/gpu/image_formation.h"

namespace face_reenact::gpu::testing {

// Unit-direction icosphere of `radius` (metres) centred at the model origin, counter-clockwise
// from outside, `subdivisions` times subdivided (4: 2562 vertices, 5120 triangles). Constant
// albedo `albedo`, no bases, every vertex in part 0 (Face).
RenderModel make_icosphere(float radius, int subdivisions, float albedo = 0.5f);

// The same sphere with `k_id` identity, `k_exp` expression and `k_alb` albedo columns of smooth
// random displacement / colour fields (seeded), and the vertices with y > 0.5 * radius in part 6
// (Tongue) so part masks have something to select.
RenderModel make_deformable_sphere(float radius, int subdivisions, int k_id, int k_exp, int k_alb, uint32_t seed);

// `a` followed by `b` moved by `offset` (model frame), as one mesh (bases must be empty).
RenderModel concatenate(const RenderModel& a, const RenderModel& b, const Eigen::Vector3f& offset);

}  // namespace face_reenact::gpu::testing
