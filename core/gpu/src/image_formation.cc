#include "face_reenact/gpu/image_formation.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <limits>

#include "face_reenact/common/error.h"
#include "face_reenact/common/parallel.h"
#include "face_reenact/model/face_model.h"

namespace face_reenact::gpu {
namespace {

bool all_finite(const Eigen::VectorXf& v) { return v.size() == 0 || v.allFinite(); }

}  // namespace

std::array<float, kNumShCoefficients> sh_basis(const Eigen::Vector3f& n) {
  const float x = n.x(), y = n.y(), z = n.z();
  return {0.282095f,
          0.488603f * y,
          0.488603f * z,
          0.488603f * x,
          1.092548f * x * y,
          1.092548f * y * z,
          0.315392f * (3.0f * z * z - 1.0f),
          1.092548f * x * z,
          0.546274f * (x * x - y * y)};
}

std::array<float, kNumShParameters> ambient_sh(const Eigen::Vector3f& rgb) {
  std::array<float, kNumShParameters> gamma{};
  for (int c = 0; c < 3; ++c) gamma[c * kNumShCoefficients] = rgb[c] / 0.282095f;
  return gamma;
}

Eigen::Matrix3f rotation_from_euler(const Eigen::Vector3f& e) {
  const float cx = std::cos(e.x()), sx = std::sin(e.x());
  const float cy = std::cos(e.y()), sy = std::sin(e.y());
  const float cz = std::cos(e.z()), sz = std::sin(e.z());
  Eigen::Matrix3f rx, ry, rz;
  rx << 1, 0, 0, 0, cx, -sx, 0, sx, cx;
  ry << cy, 0, sy, 0, 1, 0, -sy, 0, cy;
  rz << cz, -sz, 0, sz, cz, 0, 0, 0, 1;
  return rz * ry * rx;
}

Eigen::Vector3f head_rotation_axis_angle(const Eigen::Vector3f& euler_xyz) {
  const Eigen::Matrix3f r = rotation_from_euler(euler_xyz);
  const Eigen::Matrix3f r0 = rotation_from_euler(Eigen::Vector3f(static_cast<float>(M_PI), 0.f, 0.f));
  const Eigen::AngleAxisf aa(r0.transpose() * r);
  Eigen::Vector3f v = aa.axis() * aa.angle();
  if (!v.allFinite()) v.setZero();
  return v;
}

bool FaceParameters::IsValid(std::string* why, int max_identity, int max_expression, int max_albedo) const {
  if (!all_finite(alpha)) return fail_why(why, "identity coefficients (alpha) contain NaN or infinity");
  if (!all_finite(beta)) return fail_why(why, "albedo coefficients (beta) contain NaN or infinity");
  if (!all_finite(delta)) return fail_why(why, "expression coefficients (delta) contain NaN or infinity");
  for (float g : gamma) {
    if (!std::isfinite(g)) return fail_why(why, "SH lighting coefficients (gamma) contain NaN or infinity");
  }
  if (!euler.allFinite()) return fail_why(why, "rotation (Euler angles) contains NaN or infinity");
  if (!translation.allFinite()) return fail_why(why, "translation contains NaN or infinity");
  auto too_long = [&](const Eigen::VectorXf& v, int max, const char* what) {
    return max >= 0 && v.size() > max
               ? fail_why(why, std::string(what) + " has " + std::to_string(v.size()) + " coefficients, the model has " +
                               std::to_string(max))
               : true;
  };
  return too_long(alpha, max_identity, "alpha") && too_long(delta, max_expression, "delta") &&
         too_long(beta, max_albedo, "beta");
}

FaceParameters frontal_pose(float distance) {
  FaceParameters p;
  p.euler = Eigen::Vector3f(static_cast<float>(M_PI), 0.f, 0.f);
  p.translation = Eigen::Vector3f(0.f, 0.f, distance);
  p.gamma = ambient_sh(Eigen::Vector3f::Ones());
  return p;
}

float head_turn_from_camera_deg(const FaceParameters& params) {
  const Eigen::Vector3f forward = rotation_from_euler(params.euler) * Eigen::Vector3f::UnitZ();
  const Eigen::Vector3f to_camera = -params.translation.normalized();
  return static_cast<float>(std::acos(std::clamp(forward.dot(to_camera), -1.0f, 1.0f)) * 180.0 / M_PI);
}

bool PinholeCamera::IsValid(std::string* why) const {
  if (!(std::isfinite(fx) && std::isfinite(fy) && std::isfinite(cx) && std::isfinite(cy))) {
    return fail_why(why, "camera intrinsics contain NaN or infinity");
  }
  if (!(fx > 0 && fy > 0)) return fail_why(why, "camera focal lengths must be positive");
  if (width <= 0 || height <= 0 || width > 16384 || height > 16384) {
    return fail_why(why, "camera size " + std::to_string(width) + "x" + std::to_string(height) + " is outside 1..16384");
  }
  if (!(std::isfinite(near_plane) && std::isfinite(far_plane) && near_plane > 0 && far_plane > near_plane)) {
    return fail_why(why, "camera needs 0 < near_plane < far_plane");
  }
  return true;
}

PinholeCamera PinholeCamera::Downsampled(int level) const {
  if (level < 0 || level > 12) throw Error("pyramid level " + std::to_string(level) + " is outside 0..12");
  PinholeCamera c = *this;
  for (int l = 0; l < level; ++l) {
    c.fx *= 0.5f;
    c.fy *= 0.5f;
    c.cx = (c.cx + 0.5f) * 0.5f - 0.5f;
    c.cy = (c.cy + 0.5f) * 0.5f - 0.5f;
    c.width = std::max(1, c.width / 2);
    c.height = std::max(1, c.height / 2);
  }
  return c;
}

bool RenderOptions::IsValid(std::string* why) const {
  if (parts & ~kAllParts) return fail_why(why, "part mask has bits outside the 9 face parts");
  return true;
}

VertexColumns VertexColumns::Of(const BasisMatrix& basis, int num_vertices) {
  VertexColumns out;
  const Eigen::Index n = std::max(num_vertices, 0);
  const Eigen::Index cols = basis.rows() == 3 * n ? basis.cols() : 0;
  out.begin.reserve(static_cast<size_t>(n) + 1);
  out.begin.push_back(0);
  for (Eigen::Index v = 0; v < n; ++v) {
    for (Eigen::Index k = 0; k < cols; ++k) {
      const float x = basis(3 * v, k), y = basis(3 * v + 1, k), z = basis(3 * v + 2, k);
      if (x == 0.f && y == 0.f && z == 0.f) continue;
      out.column.push_back(static_cast<int32_t>(k));
      out.xyz.insert(out.xyz.end(), {x, y, z});
    }
    out.begin.push_back(static_cast<int32_t>(out.column.size()));
  }
  return out;
}

bool VertexColumns::Describes(const BasisMatrix& basis, int num_vertices) const {
  // The index Of would make, entry for entry: one rule for what is listed, not a second reading.
  if (basis.cols() > 0 && basis.rows() != 3 * static_cast<Eigen::Index>(std::max(num_vertices, 0))) return false;
  const VertexColumns made = Of(basis, num_vertices);
  return begin == made.begin && column == made.column && xyz == made.xyz;
}

bool RenderModel::IsValid(std::string* why) const {
  const int n = num_vertices();
  if (n == 0) return fail_why(why, "render model has no vertices");
  const Eigen::Index rows = 3 * static_cast<Eigen::Index>(n);
  if (mean_shape.size() != rows || mean_albedo.size() != rows) {
    return fail_why(why, "render model: mean shape/albedo must have 3N entries");
  }
  if (identity_basis.rows() != rows && identity_basis.cols() != 0) return fail_why(why, "identity basis must have 3N rows");
  if (expression_basis.rows() != rows && expression_basis.cols() != 0) return fail_why(why, "expression basis must have 3N rows");
  if (albedo_basis.rows() != rows && albedo_basis.cols() != 0) return fail_why(why, "albedo basis must have 3N rows");
  if (!mean_shape.allFinite() || !mean_albedo.allFinite() || !identity_basis.allFinite() ||
      !expression_basis.allFinite() || !albedo_basis.allFinite()) {
    return fail_why(why, "render model contains NaN or infinity");
  }
  if (!expression_columns.Describes(expression_basis, n))
    return fail_why(why, "render model: expression_columns do not describe expression_basis (IndexExpression)");
  for (const auto& t : triangles) {
    for (int k = 0; k < 3; ++k) {
      if (t[k] < 0 || t[k] >= n) return fail_why(why, "render model: triangle vertex index out of range");
    }
  }
  for (uint8_t p : vertex_part) {
    if (p >= 32) return fail_why(why, "render model: vertex part out of range");
  }
  return true;
}

RenderModel RenderModel::FromFaceModel(const FaceModel& model) {
  RenderModel r;
  r.triangles = model.triangles;
  r.vertex_part.reserve(model.vertex_part.size());
  for (FacePart p : model.vertex_part) r.vertex_part.push_back(static_cast<uint8_t>(p));
  r.mean_shape = model.mean_shape;
  r.identity_basis = model.identity_basis;
  r.expression_basis = model.expression_basis;
  r.mean_albedo = model.mean_albedo;
  r.albedo_basis = model.albedo_basis;
  const Eigen::Index rows = r.mean_shape.size();
  if (r.identity_basis.cols() == 0) r.identity_basis.resize(rows, 0);
  if (r.expression_basis.cols() == 0) r.expression_basis.resize(rows, 0);
  if (r.albedo_basis.cols() == 0) r.albedo_basis.resize(rows, 0);
  r.IndexExpression();
  std::string why;
  if (!r.IsValid(&why)) throw Error("face model cannot be rendered: " + why);
  return r;
}

void GBuffer::Resize(int w, int h) {
  width = w;
  height = h;
  const size_t n = static_cast<size_t>(w) * static_cast<size_t>(h);
  color.assign(3 * n, 0.f);
  position.assign(3 * n, 0.f);
  normal.assign(3 * n, 0.f);
  barycentric.assign(3 * n, 0.f);
  triangle.assign(n, -1);
  vertices.assign(3 * n, -1);
  drawn = DrawnTrace();
}

bool GBuffer::DrawnIsKnown(int w, int h) const {
  const size_t n = static_cast<size_t>(w) * static_cast<size_t>(h);
  return width == w && height == h && triangle.size() == n && vertices.size() == 3 * n && color.size() == 3 * n &&
         position.size() == 3 * n && normal.size() == 3 * n && barycentric.size() == 3 * n &&
         drawn.triangle_data != nullptr && drawn.triangle_data == triangle.data();
}

void GBuffer::ClearForDraw(int w, int h, int threads) {
  if (!DrawnIsKnown(w, h)) {
    Resize(w, h);
    return;
  }
  const DrawnTrace previous = drawn;
  drawn = DrawnTrace();
  if (previous.i1 < previous.i0 || previous.j1 < previous.j0) return;
  const size_t span = static_cast<size_t>(previous.i1 - previous.i0 + 1);
  ParallelFor(previous.j1 - previous.j0 + 1, threads, [&](int row) {
    const size_t p = static_cast<size_t>(previous.j0 + row) * static_cast<size_t>(w) + static_cast<size_t>(previous.i0);
    for (auto* v : {&color, &position, &normal, &barycentric}) std::fill_n(v->begin() + 3 * p, 3 * span, 0.f);
    std::fill_n(vertices.begin() + 3 * p, 3 * span, -1);
    std::fill_n(triangle.begin() + p, span, -1);
  });
}

PixelBox ProjectedBox(const VertexState& state, const PinholeCamera& camera, int margin) {
  float u0 = std::numeric_limits<float>::infinity(), u1 = -u0, v0 = u0, v1 = -u0;
  const Eigen::Index n = state.camera_positions.size() / 3;
  for (Eigen::Index k = 0; k < n; ++k) {
    const float x = state.camera_positions[3 * k], y = state.camera_positions[3 * k + 1];
    const float z = state.camera_positions[3 * k + 2];
    if (!(z > camera.near_plane && z < camera.far_plane)) continue;
    const float u = camera.fx * x / z + camera.cx, v = camera.fy * y / z + camera.cy;
    if (!std::isfinite(u) || !std::isfinite(v)) continue;
    u0 = std::min(u0, u), u1 = std::max(u1, u), v0 = std::min(v0, v), v1 = std::max(v1, v);
  }
  PixelBox box;
  if (!(u0 <= u1 && v0 <= v1)) return box;
  const float m = static_cast<float>(margin);
  const float i0 = std::floor(u0) - m, i1 = std::ceil(u1) + m, j0 = std::floor(v0) - m, j1 = std::ceil(v1) + m;
  const float w = static_cast<float>(camera.width - 1), h = static_cast<float>(camera.height - 1);
  if (i1 < 0.f || j1 < 0.f || i0 > w || j0 > h) return box;  // beside the image
  // Clamped as floats: a vertex just past the near plane projects far outside the image.
  box.i0 = static_cast<int>(std::max(i0, 0.f));
  box.i1 = static_cast<int>(std::min(i1, w));
  box.j0 = static_cast<int>(std::max(j0, 0.f));
  box.j1 = static_cast<int>(std::min(j1, h));
  return box;
}

size_t GBuffer::covered_count() const {
  size_t c = 0;
  for (int32_t t : triangle) c += t >= 0;
  return c;
}

}  // namespace face_reenact::gpu
