#include "face_reenact/tracker/evaluation.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>

#include "face_reenact/common/error.h"
#include "face_reenact/model/face_model.h"
#include "tracker_internal.h"

namespace face_reenact::tracker {
using internal::kRadToDeg;
namespace {

// Camera-frame vertex positions of `p` (3N), double precision.
Eigen::VectorXd camera_positions(const TrackerModel& model, const gpu::FaceParameters& p) {
  const auto& r = model.render;
  Eigen::VectorXd v = r.mean_shape.cast<double>();
  const Eigen::Index n_id = std::min<Eigen::Index>(p.alpha.size(), r.identity_basis.cols());
  if (n_id > 0) v += (r.identity_basis.leftCols(n_id) * p.alpha.head(n_id)).cast<double>();
  const Eigen::Index n_exp = std::min<Eigen::Index>(p.delta.size(), r.expression_basis.cols());
  if (n_exp > 0) v += (r.expression_basis.leftCols(n_exp) * p.delta.head(n_exp)).cast<double>();
  const Eigen::Matrix3d rot = gpu::rotation_from_euler(p.euler).cast<double>();
  const Eigen::Vector3d t = p.translation.cast<double>();
  for (Eigen::Index k = 0; k < v.size() / 3; ++k) v.segment<3>(3 * k) = rot * v.segment<3>(3 * k) + t;
  return v;
}

}  // namespace

Eigen::Vector3d ClosestPointOnTriangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                                       const Eigen::Vector3d& c) {
  // Voronoi regions of the triangle: vertices, then edges, then the face.
  const Eigen::Vector3d ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return a;
  const Eigen::Vector3d bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return b;
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return a + ab * (d1 / (d1 - d3));
  const Eigen::Vector3d cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return c;
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return a + ac * (d2 / (d2 - d6));
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
  const double denom = va + vb + vc;
  if (!(std::abs(denom) > 0)) return a;  // degenerate triangle
  return a + ab * (vb / denom) + ac * (vc / denom);
}

TriangleSurface::TriangleSurface(const Eigen::VectorXf& positions, const std::vector<std::array<int32_t, 3>>& triangles,
                                 float cell)
    : cell_(cell) {
  if (!(cell > 0)) throw Error("triangle surface: the grid cell must be positive");
  const Eigen::Index nv = positions.size() / 3;
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
  for (const auto& t : triangles) {
    bool ok = true;
    for (int k = 0; k < 3; ++k) ok = ok && t[k] >= 0 && t[k] < nv;
    if (!ok) throw Error("triangle surface: triangle vertex index out of range");
    const Eigen::Vector3d a = positions.segment<3>(3 * t[0]).cast<double>();
    const Eigen::Vector3d b = positions.segment<3>(3 * t[1]).cast<double>();
    const Eigen::Vector3d c = positions.segment<3>(3 * t[2]).cast<double>();
    if (!a.allFinite() || !b.allFinite() || !c.allFinite()) continue;
    a_.push_back(a);
    b_.push_back(b);
    c_.push_back(c);
    lo = lo.cwiseMin(a).cwiseMin(b).cwiseMin(c);
    hi = hi.cwiseMax(a).cwiseMax(b).cwiseMax(c);
  }
  if (a_.empty()) return;
  // Keep the grid small for any input: grow the cell until it has at most ~2 M cells.
  Eigen::Vector3d extent = hi - lo;
  while ((extent / cell_).array().floor().prod() > 2e6) cell_ *= 2;
  origin_ = lo;
  dims_ = ((extent / cell_).array().floor() + 1).cast<int>().matrix();
  cells_.assign(static_cast<size_t>(dims_.prod()), {});
  for (size_t k = 0; k < a_.size(); ++k) {
    const Eigen::Vector3d tlo = a_[k].cwiseMin(b_[k]).cwiseMin(c_[k]), thi = a_[k].cwiseMax(b_[k]).cwiseMax(c_[k]);
    const Eigen::Vector3i c0 = ((tlo - origin_) / cell_).array().floor().cast<int>().matrix().cwiseMax(0).cwiseMin(dims_ - Eigen::Vector3i::Ones());
    const Eigen::Vector3i c1 = ((thi - origin_) / cell_).array().floor().cast<int>().matrix().cwiseMax(0).cwiseMin(dims_ - Eigen::Vector3i::Ones());
    for (int z = c0.z(); z <= c1.z(); ++z) {
      for (int y = c0.y(); y <= c1.y(); ++y) {
        for (int x = c0.x(); x <= c1.x(); ++x) cells_[cell_index({x, y, z})].push_back(static_cast<int32_t>(k));
      }
    }
  }
}

double TriangleSurface::Distance(const Eigen::Vector3d& p) const {
  if (a_.empty() || !p.allFinite()) return std::numeric_limits<double>::infinity();
  // Search shells of cells around p's (clamped) cell. Every point in the shell at Chebyshev
  // radius r is at least max(distance to the grid box, (r - 1) cells) from p, so the search
  // stops once the best distance found is within that bound.
  // Clamp in floating point before converting: p may lie arbitrarily far from the grid.
  const Eigen::Vector3d rel = ((p - origin_) / cell_).array().floor().matrix().cwiseMax(0.0).cwiseMin(
      (dims_ - Eigen::Vector3i::Ones()).cast<double>());
  const Eigen::Vector3i pc = rel.cast<int>();
  // Distance from p to the grid box (p may lie outside it).
  const Eigen::Vector3d box_hi = origin_ + dims_.cast<double>() * cell_;
  const double outside = (p.cwiseMax(origin_).cwiseMin(box_hi) - p).norm();
  double best = std::numeric_limits<double>::infinity();
  const int max_r = dims_.maxCoeff();
  for (int r = 0; r <= max_r; ++r) {
    if (std::isfinite(best) && best <= std::max(outside, (r - 1) * cell_)) break;
    for (int z = pc.z() - r; z <= pc.z() + r; ++z) {
      if (z < 0 || z >= dims_.z()) continue;
      for (int y = pc.y() - r; y <= pc.y() + r; ++y) {
        if (y < 0 || y >= dims_.y()) continue;
        for (int x = pc.x() - r; x <= pc.x() + r; ++x) {
          if (x < 0 || x >= dims_.x()) continue;
          if (std::max({std::abs(x - pc.x()), std::abs(y - pc.y()), std::abs(z - pc.z())}) != r) continue;
          for (int32_t t : cells_[cell_index({x, y, z})]) {
            best = std::min(best, (ClosestPointOnTriangle(p, a_[t], b_[t], c_[t]) - p).norm());
          }
        }
      }
    }
  }
  return best;
}

namespace {

// The triangles of the fitted surface: all three vertices in kFittedSurfaceParts.
std::vector<std::array<int32_t, 3>> FittedSurfaceTriangles(const TrackerModel& model) {
  const auto& r = model.render;
  auto in_surface = [&](int32_t v) { return (kFittedSurfaceParts >> r.vertex_part[static_cast<size_t>(v)]) & 1u; };
  std::vector<std::array<int32_t, 3>> triangles;
  for (const auto& t : r.triangles) {
    if (in_surface(t[0]) && in_surface(t[1]) && in_surface(t[2])) triangles.push_back(t);
  }
  return triangles;
}

}  // namespace

// The face region of `truth`, per vertex: the vertices of the face-part triangles that the
// camera sees on the true face (every part drawn, so eyes, teeth and ears occlude) and would see
// on the same face at rest (expression 0, the mouth closed). The part also holds surfaces inside
// the head: the mouth cavity, about 8 cm deep behind the lips, and the eye sockets. No camera sees
// them on a face at rest, and the paper's ground truth (stereo scans of the face) has no such
// surface, but an open mouth shows the cavity's back wall through the lips' gap: seed 5151's
// largest surface errors (10 mm, the sensor's depth of a 5-pixel gap) were all there.
std::vector<bool> GroundTruthFaceRegion(const gpu::CpuRenderer& renderer, const TrackerModel& model,
                                        const gpu::FaceParameters& truth, const gpu::PinholeCamera& camera) {
  const auto face = static_cast<uint8_t>(FacePart::Face);
  const auto& r = model.render;
  if (renderer.model().num_vertices() != model.num_vertices()) {
    throw Error("evaluation: the renderer and the tracker model differ");
  }
  std::vector<bool> is_face_triangle(r.triangles.size(), false);
  bool any = false;
  for (size_t k = 0; k < r.triangles.size(); ++k) {
    const auto& t = r.triangles[k];
    is_face_triangle[k] = r.vertex_part[t[0]] == face && r.vertex_part[t[1]] == face && r.vertex_part[t[2]] == face;
    any = any || is_face_triangle[k];
  }
  if (!any) throw Error("evaluation: the model has no face-region triangles");
  gpu::RenderOptions all;
  all.parts = gpu::kAllParts;
  auto seen = [&](const gpu::FaceParameters& p) {
    const gpu::GBuffer g = renderer.render(p, camera, all);
    std::vector<bool> visible(static_cast<size_t>(model.num_vertices()), false);
    for (const int32_t tri : g.triangle) {
      if (tri < 0 || !is_face_triangle[tri]) continue;
      for (int k = 0; k < 3; ++k) visible[static_cast<size_t>(r.triangles[tri][k])] = true;
    }
    return visible;
  };
  std::vector<bool> visible = seen(truth);
  gpu::FaceParameters at_rest = truth;
  at_rest.delta = Eigen::VectorXf::Zero(model.num_expression());
  const std::vector<bool> visible_at_rest = seen(at_rest);
  for (size_t v = 0; v < visible.size(); ++v) visible[v] = visible[v] && visible_at_rest[v];
  return visible;
}

FitErrors CompareToGroundTruth(const gpu::CpuRenderer& renderer, const TrackerModel& model,
                               const gpu::FaceParameters& fit, const gpu::FaceParameters& truth,
                               const gpu::PinholeCamera& camera) {
  const std::vector<bool> in_region = GroundTruthFaceRegion(renderer, model, truth, camera);
  const Eigen::VectorXd xf = camera_positions(model, fit);
  const Eigen::VectorXd xt = camera_positions(model, truth);
  const TriangleSurface surface(xf.cast<float>(), FittedSurfaceTriangles(model), 0.01f);
  FitErrors e;
  int n = 0, n_2d = 0;
  for (int v = 0; v < model.num_vertices(); ++v) {
    if (!in_region[v]) continue;
    const Eigen::Vector3d pt = xt.segment<3>(3 * v), pf = xf.segment<3>(3 * v);
    const double d = surface.Distance(pt) * 1000.0;
    e.geometric_mm_mean += d;
    if (d > e.geometric_mm_max) {
      e.geometric_mm_max = d;
      e.geometric_max_vertex = v;
    }
    const double dv = (pf - pt).norm() * 1000.0;
    e.vertex_mm_mean += dv;
    e.vertex_mm_max = std::max(e.vertex_mm_max, dv);
    ++n;
    if (pt.z() > camera.near_plane && pf.z() > camera.near_plane) {
      const Eigen::Vector2d ut(camera.fx * pt.x() / pt.z() + camera.cx, camera.fy * pt.y() / pt.z() + camera.cy);
      const Eigen::Vector2d uf(camera.fx * pf.x() / pf.z() + camera.cx, camera.fy * pf.y() / pf.z() + camera.cy);
      e.alignment_px_mean += (ut - uf).norm();
      ++n_2d;
    }
  }
  e.region_vertices = n;
  if (n > 0) {
    e.geometric_mm_mean /= n;
    e.vertex_mm_mean /= n;
  }
  if (n_2d > 0) e.alignment_px_mean /= n_2d;
  const Eigen::Matrix3d rf = gpu::rotation_from_euler(fit.euler).cast<double>();
  const Eigen::Matrix3d rt = gpu::rotation_from_euler(truth.euler).cast<double>();
  e.rotation_deg = Eigen::AngleAxisd(rf.transpose() * rt).angle() * kRadToDeg;
  e.translation_mm = (fit.translation - truth.translation).cast<double>().norm() * 1000.0;
  const int k_exp = model.num_expression();
  double sum = 0;
  for (int k = 0; k < k_exp; ++k) {
    const double a = k < fit.delta.size() ? fit.delta[k] : 0.0;
    const double b = k < truth.delta.size() ? truth.delta[k] : 0.0;
    sum += std::abs(a - b);
  }
  e.expression_mean_abs = k_exp > 0 ? sum / k_exp : 0.0;
  return e;
}

IdentityErrors CompareIdentities(const gpu::CpuRenderer& renderer, const TrackerModel& model,
                                 const Eigen::VectorXf& alpha_fit, const Eigen::VectorXf& alpha_truth,
                                 const gpu::PinholeCamera& camera, float distance_m) {
  gpu::FaceParameters truth = gpu::frontal_pose(distance_m);
  truth.alpha = alpha_truth;
  truth.beta = Eigen::VectorXf::Zero(model.num_albedo());
  truth.delta = Eigen::VectorXf::Zero(model.num_expression());
  gpu::FaceParameters fit = truth;
  fit.alpha = alpha_fit;
  const std::vector<bool> in_region = GroundTruthFaceRegion(renderer, model, truth, camera);
  const Eigen::VectorXd xf = camera_positions(model, fit);
  const Eigen::VectorXd xt = camera_positions(model, truth);
  std::vector<int> vertices;
  for (int v = 0; v < model.num_vertices(); ++v)
    if (in_region[static_cast<size_t>(v)]) vertices.push_back(v);
  IdentityErrors e;
  e.region_vertices = static_cast<int>(vertices.size());
  if (vertices.size() < 3) return e;
  // The rigid motion that best maps the fitted region onto the true one (corresponding
  // vertices): where the model origin sits inside the head is not observable.
  Eigen::Matrix3Xd p(3, vertices.size()), q(3, vertices.size());
  for (size_t k = 0; k < vertices.size(); ++k) {
    p.col(static_cast<Eigen::Index>(k)) = xf.segment<3>(3 * vertices[k]);
    q.col(static_cast<Eigen::Index>(k)) = xt.segment<3>(3 * vertices[k]);
  }
  const Eigen::Matrix4d m = Eigen::umeyama(p, q, /*with_scaling=*/false);
  Eigen::VectorXf aligned(xf.size());
  for (int v = 0; v < model.num_vertices(); ++v) {
    aligned.segment<3>(3 * v) = (m.topLeftCorner<3, 3>() * xf.segment<3>(3 * v) + m.topRightCorner<3, 1>()).cast<float>();
  }
  const TriangleSurface surface(aligned, FittedSurfaceTriangles(model), 0.01f);
  for (size_t k = 0; k < vertices.size(); ++k) {
    const Eigen::Vector3d pt = q.col(static_cast<Eigen::Index>(k));
    const double d = surface.Distance(pt) * 1000.0;
    e.surface_mm_mean += d;
    e.surface_mm_max = std::max(e.surface_mm_max, d);
    e.vertex_mm_mean += (aligned.segment<3>(3 * vertices[k]).cast<double>() - pt).norm() * 1000.0;
  }
  e.surface_mm_mean /= static_cast<double>(vertices.size());
  e.vertex_mm_mean /= static_cast<double>(vertices.size());
  return e;
}

}  // namespace face_reenact::tracker
