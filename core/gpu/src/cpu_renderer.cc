#include "face_reenact/gpu/cpu_renderer.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>

#include "face_reenact/common/error.h"
#include "face_reenact/common/timing.h"

namespace face_reenact::gpu {
namespace {

using Clock = std::chrono::steady_clock;

// Sub-pixel snapping of the rasteriser (1/256 pixel).
constexpr double kSubpixel = 256.0;

double snap(double v) { return std::round(v * kSubpixel) / kSubpixel; }

Eigen::VectorXf padded(const Eigen::VectorXf& v, Eigen::Index n) {
  Eigen::VectorXf out = Eigen::VectorXf::Zero(n);
  out.head(v.size()) = v;
  return out;
}

}  // namespace

std::vector<int32_t> drawn_triangles(const RenderModel& model, const RenderOptions& options) {
  std::vector<int32_t> out;
  out.reserve(model.triangles.size());
  for (size_t t = 0; t < model.triangles.size(); ++t) {
    bool keep = true;
    for (int k = 0; k < 3; ++k) keep = keep && ((options.parts >> model.vertex_part[model.triangles[t][k]]) & 1u);
    if (keep) out.push_back(static_cast<int32_t>(t));
  }
  return out;
}

CpuRenderer::CpuRenderer(RenderModel model) : model_(std::move(model)) {
  std::string why;
  if (!model_.IsValid(&why)) throw Error("CPU renderer: " + why);
}

VertexState CpuRenderer::evaluate(const FaceParameters& params, CpuRenderTimes* times) const {
  std::string why;
  if (!params.IsValid(&why, static_cast<int>(model_.identity_basis.cols()), static_cast<int>(model_.expression_basis.cols()),
                      static_cast<int>(model_.albedo_basis.cols()))) {
    throw Error("invalid face parameters: " + why);
  }
  const int n = model_.num_vertices();
  auto start = Clock::now();
  VertexState s;
  s.model_positions = model_.mean_shape;
  if (model_.identity_basis.cols() > 0) s.model_positions += model_.identity_basis * padded(params.alpha, model_.identity_basis.cols());
  if (model_.expression_basis.cols() > 0) s.model_positions += model_.expression_basis * padded(params.delta, model_.expression_basis.cols());
  s.albedo = model_.mean_albedo;
  if (model_.albedo_basis.cols() > 0) s.albedo += model_.albedo_basis * padded(params.beta, model_.albedo_basis.cols());

  if (times) times->model_ms = ms_since(start);
  start = Clock::now();
  // Area-weighted vertex normals: the sum of the (unnormalised) cross products of the incident
  // triangles, whose length is twice the triangle area.
  Eigen::Matrix3Xf sums = Eigen::Matrix3Xf::Zero(3, n);
  auto pos = [&](int v) { return Eigen::Vector3f(s.model_positions.segment<3>(3 * v)); };
  for (const auto& t : model_.triangles) {
    const Eigen::Vector3f a = pos(t[0]);
    const Eigen::Vector3f face = (pos(t[1]) - a).cross(pos(t[2]) - a);
    for (int k = 0; k < 3; ++k) sums.col(t[k]) += face;
  }
  const Eigen::Matrix3f rotation = rotation_from_euler(params.euler);
  s.camera_positions.resize(3 * n);
  s.camera_normals.resize(3 * n);
  s.colors.resize(3 * n);
  for (int v = 0; v < n; ++v) {
    const float len = sums.col(v).norm();
    const Eigen::Vector3f normal = len > 0.f ? Eigen::Vector3f(sums.col(v) / len) : Eigen::Vector3f::Zero();
    const Eigen::Vector3f cam_normal = rotation * normal;
    s.camera_positions.segment<3>(3 * v) = rotation * pos(v) + params.translation;
    s.camera_normals.segment<3>(3 * v) = cam_normal;
    const auto basis = sh_basis(cam_normal);
    for (int c = 0; c < 3; ++c) {
      float irradiance = 0.f;
      for (int k = 0; k < kNumShCoefficients; ++k) irradiance += params.gamma[c * kNumShCoefficients + k] * basis[k];
      s.colors[3 * v + c] = s.albedo[3 * v + c] * irradiance;
    }
  }
  if (times) times->shade_ms = ms_since(start);
  return s;
}

GBuffer CpuRenderer::render(const FaceParameters& params, const PinholeCamera& camera, const RenderOptions& options,
                            CpuRenderTimes* times) const {
  std::string why;
  if (!camera.IsValid(&why)) throw Error("invalid camera: " + why);
  if (!options.IsValid(&why)) throw Error("invalid render options: " + why);
  VertexState state = evaluate(params, times);
  const auto start = Clock::now();
  GBuffer g = rasterize(state, camera, options);
  if (times) times->raster_ms = ms_since(start);
  return g;
}

GBuffer CpuRenderer::rasterize(const VertexState& state, const PinholeCamera& camera, const RenderOptions& options) const {
  GBuffer g;
  rasterize(state, camera, options, &g);
  return g;
}

void CpuRenderer::rasterize(const VertexState& state, const PinholeCamera& camera, const RenderOptions& options,
                            GBuffer* out) const {
  std::string why;
  if (!camera.IsValid(&why)) throw Error("invalid camera: " + why);
  GBuffer& g = *out;
  g.Resize(camera.width, camera.height);
  // The depth buffer is scratch: one per thread, kept, so a per-frame caller faults no new pages.
  thread_local std::vector<float> depth;
  depth.assign(static_cast<size_t>(camera.width) * camera.height, 1.0f);
  const double near = camera.near_plane, far = camera.far_plane;

  for (int32_t t : drawn_triangles(model_, options)) {
    const auto& tri = model_.triangles[t];
    Eigen::Vector3f p[3];
    bool inside_depth_range = true;
    for (int k = 0; k < 3; ++k) {
      p[k] = state.camera_positions.segment<3>(3 * tri[k]);
      inside_depth_range = inside_depth_range && (p[k].z() > camera.near_plane && p[k].z() < camera.far_plane);
    }
    if (!inside_depth_range) continue;
    // Framebuffer coordinates: the centre of pixel i is at i + 0.5.
    double ux[3], uy[3], sx[3], sy[3], d[3];
    for (int k = 0; k < 3; ++k) {
      const double z = p[k].z();
      ux[k] = camera.fx * p[k].x() / z + camera.cx + 0.5;
      uy[k] = camera.fy * p[k].y() / z + camera.cy + 0.5;
      sx[k] = snap(ux[k]);
      sy[k] = snap(uy[k]);
      d[k] = far * (z - near) / ((far - near) * z);
    }
    double area2 = (sx[1] - sx[0]) * (sy[2] - sy[0]) - (sx[2] - sx[0]) * (sy[1] - sy[0]);
    if (area2 == 0.0 || !std::isfinite(area2)) continue;
    // Front-facing triangles (counter-clockwise from outside) have area2 < 0 in this y-down frame.
    if (options.cull_back_faces && area2 > 0.0) continue;
    // Work on a copy ordered so that area2 > 0 (interior: every edge function positive).
    int order[3] = {0, 1, 2};
    if (area2 < 0.0) {
      std::swap(order[1], order[2]);
      area2 = -area2;
    }
    // The exact (unsnapped) area with the same corner order, for attribute interpolation.
    double exact_area2 = (ux[order[1]] - ux[order[0]]) * (uy[order[2]] - uy[order[0]]) -
                         (ux[order[2]] - ux[order[0]]) * (uy[order[1]] - uy[order[0]]);
    if (!(exact_area2 > 0.0)) {  // the snap turned a degenerate or flipped sliver visible: use the snapped plane
      for (int k = 0; k < 3; ++k) {
        ux[k] = sx[k];
        uy[k] = sy[k];
      }
      exact_area2 = area2;
    }
    const double ox[3] = {sx[order[0]], sx[order[1]], sx[order[2]]};
    const double oy[3] = {sy[order[0]], sy[order[1]], sy[order[2]]};
    // Edge e runs from corner e+1 to corner e+2 (opposite corner e); its function is the
    // screen-space barycentric weight of corner e times area2.
    bool top_left[3];
    for (int e = 0; e < 3; ++e) {
      const int a = (e + 1) % 3, b = (e + 2) % 3;
      const double dx = ox[b] - ox[a], dy = oy[b] - oy[a];
      top_left[e] = (dy == 0.0 && dx > 0.0) || dy < 0.0;
    }
    const double min_x = std::min({ox[0], ox[1], ox[2]}), max_x = std::max({ox[0], ox[1], ox[2]});
    const double min_y = std::min({oy[0], oy[1], oy[2]}), max_y = std::max({oy[0], oy[1], oy[2]});
    const int i0 = static_cast<int>(std::max(0.0, std::ceil(min_x - 0.5)));
    const int i1 = static_cast<int>(std::min(camera.width - 1.0, std::floor(max_x - 0.5)));
    const int j0 = static_cast<int>(std::max(0.0, std::ceil(min_y - 0.5)));
    const int j1 = static_cast<int>(std::min(camera.height - 1.0, std::floor(max_y - 0.5)));
    for (int j = j0; j <= j1; ++j) {
      const double py = j + 0.5;
      for (int i = i0; i <= i1; ++i) {
        const double px = i + 0.5;
        double w[3];
        bool inside = true;
        for (int e = 0; e < 3 && inside; ++e) {
          const int a = (e + 1) % 3, b = (e + 2) % 3;
          w[e] = (ox[b] - ox[a]) * (py - oy[a]) - (oy[b] - oy[a]) * (px - ox[a]);
          inside = w[e] > 0.0 || (w[e] == 0.0 && top_left[e]);
        }
        if (!inside) continue;
        // Screen-space weights back in the triangle's own corner order, from the unsnapped
        // positions: the snap decides coverage, attribute interpolation uses the exact plane.
        double lambda[3];
        for (int e = 0; e < 3; ++e) {
          const int a = order[(e + 1) % 3], b = order[(e + 2) % 3];
          lambda[order[e]] = ((ux[b] - ux[a]) * (py - uy[a]) - (uy[b] - uy[a]) * (px - ux[a])) / exact_area2;
        }
        const double dz = lambda[0] * d[0] + lambda[1] * d[1] + lambda[2] * d[2];
        const float depth_value = static_cast<float>(dz);
        const size_t pix = static_cast<size_t>(j) * camera.width + i;
        if (!(depth_value < depth[pix])) continue;
        depth[pix] = depth_value;
        double b[3], sum = 0.0;
        for (int k = 0; k < 3; ++k) {
          b[k] = lambda[k] / p[k].z();
          sum += b[k];
        }
        for (int k = 0; k < 3; ++k) b[k] /= sum;
        Eigen::Vector3d x = Eigen::Vector3d::Zero(), nrm = Eigen::Vector3d::Zero(), col = Eigen::Vector3d::Zero();
        for (int k = 0; k < 3; ++k) {
          x += b[k] * p[k].cast<double>();
          nrm += b[k] * state.camera_normals.segment<3>(3 * tri[k]).cast<double>();
          col += b[k] * state.colors.segment<3>(3 * tri[k]).cast<double>();
        }
        const double len = nrm.norm();
        if (len > 0.0) nrm /= len;
        for (int c = 0; c < 3; ++c) {
          g.color[3 * pix + c] = static_cast<float>(col[c]);
          g.position[3 * pix + c] = static_cast<float>(x[c]);
          g.normal[3 * pix + c] = static_cast<float>(nrm[c]);
          g.barycentric[3 * pix + c] = static_cast<float>(b[c]);
          g.vertices[3 * pix + c] = tri[c];
        }
        g.triangle[pix] = t;
      }
    }
  }
}

}  // namespace face_reenact::gpu
