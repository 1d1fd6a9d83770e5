#include "test_meshes.h"

#include <cmath>
#include <map>
#include <random>
#include <utility>

namespace face_reenact::gpu::testing {

RenderModel make_icosphere(float radius, int subdivisions, float albedo) {
  const float t = (1.0f + std::sqrt(5.0f)) / 2.0f;
  std::vector<Eigen::Vector3f> v = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0}, {0, -1, t}, {0, 1, t},
                                    {0, -1, -t}, {0, 1, -t}, {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
  for (auto& p : v) p.normalize();
  std::vector<std::array<int32_t, 3>> f = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                                           {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                                           {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                                           {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
  for (int s = 0; s < subdivisions; ++s) {
    std::map<std::pair<int, int>, int> mid;
    auto midpoint = [&](int a, int b) {
      const auto key = std::minmax(a, b);
      auto it = mid.find(key);
      if (it != mid.end()) return it->second;
      v.push_back((v[a] + v[b]).normalized());
      const int id = static_cast<int>(v.size()) - 1;
      mid[key] = id;
      return id;
    };
    std::vector<std::array<int32_t, 3>> next;
    for (const auto& tri : f) {
      const int a = midpoint(tri[0], tri[1]), b = midpoint(tri[1], tri[2]), c = midpoint(tri[2], tri[0]);
      next.push_back({tri[0], a, c});
      next.push_back({tri[1], b, a});
      next.push_back({tri[2], c, b});
      next.push_back({a, b, c});
    }
    f = std::move(next);
  }
  RenderModel m;
  m.triangles = f;
  // The icosahedron table above is counter-clockwise from outside; check and fix per triangle
  // so the convention holds by construction.
  for (auto& tri : m.triangles) {
    const Eigen::Vector3f n = (v[tri[1]] - v[tri[0]]).cross(v[tri[2]] - v[tri[0]]);
    if (n.dot(v[tri[0]] + v[tri[1]] + v[tri[2]]) < 0) std::swap(tri[1], tri[2]);
  }
  const Eigen::Index n = static_cast<Eigen::Index>(v.size());
  m.vertex_part.assign(v.size(), 0);
  m.mean_shape.resize(3 * n);
  for (Eigen::Index i = 0; i < n; ++i) m.mean_shape.segment<3>(3 * i) = radius * v[i];
  m.mean_albedo = Eigen::VectorXf::Constant(3 * n, albedo);
  m.identity_basis.resize(3 * n, 0);
  m.expression_basis.resize(3 * n, 0);
  m.albedo_basis.resize(3 * n, 0);
  m.IndexExpression();
  return m;
}

RenderModel make_deformable_sphere(float radius, int subdivisions, int k_id, int k_exp, int k_alb, uint32_t seed) {
  RenderModel m = make_icosphere(radius, subdivisions);
  const Eigen::Index n = m.num_vertices();
  std::mt19937 rng(seed);
  std::normal_distribution<float> gauss(0.f, 1.f);
  // Each column: a smooth field, a random quadratic form in the unit direction.
  auto smooth_field = [&](float scale, bool radial) {
    Eigen::Matrix3f q;
    Eigen::Vector3f l;
    for (int i = 0; i < 9; ++i) q.data()[i] = gauss(rng);
    for (int i = 0; i < 3; ++i) l[i] = gauss(rng);
    Eigen::Vector3f dir_mix(gauss(rng), gauss(rng), gauss(rng));
    Eigen::VectorXf col(3 * n);
    for (Eigen::Index i = 0; i < n; ++i) {
      const Eigen::Vector3f d = m.mean_shape.segment<3>(3 * i).normalized();
      const float s = scale * (d.dot(q * d) + l.dot(d));
      col.segment<3>(3 * i) = radial ? Eigen::Vector3f(s * d) : Eigen::Vector3f(s * dir_mix.normalized());
    }
    return col;
  };
  m.identity_basis.resize(3 * n, k_id);
  for (int k = 0; k < k_id; ++k) m.identity_basis.col(k) = smooth_field(0.01f * radius, true);
  m.expression_basis.resize(3 * n, k_exp);
  for (int k = 0; k < k_exp; ++k) m.expression_basis.col(k) = smooth_field(0.02f * radius, false);
  m.albedo_basis.resize(3 * n, k_alb);
  for (int k = 0; k < k_alb; ++k) m.albedo_basis.col(k) = smooth_field(0.05f, false);
  for (Eigen::Index i = 0; i < n; ++i) {
    if (m.mean_shape[3 * i + 1] > 0.5f * radius) m.vertex_part[i] = 6;
  }
  m.IndexExpression();
  return m;
}

RenderModel concatenate(const RenderModel& a, const RenderModel& b, const Eigen::Vector3f& offset) {
  RenderModel m;
  const int na = a.num_vertices(), nb = b.num_vertices();
  m.triangles = a.triangles;
  for (auto t : b.triangles) m.triangles.push_back({t[0] + na, t[1] + na, t[2] + na});
  m.vertex_part = a.vertex_part;
  m.vertex_part.insert(m.vertex_part.end(), b.vertex_part.begin(), b.vertex_part.end());
  m.mean_shape.resize(3 * (na + nb));
  m.mean_shape.head(3 * na) = a.mean_shape;
  for (int i = 0; i < nb; ++i) m.mean_shape.segment<3>(3 * (na + i)) = b.mean_shape.segment<3>(3 * i) + offset;
  m.mean_albedo.resize(3 * (na + nb));
  m.mean_albedo << a.mean_albedo, b.mean_albedo;
  m.identity_basis.resize(3 * (na + nb), 0);
  m.expression_basis.resize(3 * (na + nb), 0);
  m.albedo_basis.resize(3 * (na + nb), 0);
  m.IndexExpression();
  return m;
}

}  // namespace face_reenact::gpu::testing
