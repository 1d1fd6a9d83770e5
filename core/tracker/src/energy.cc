#include "face_reenact/tracker/energy.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <unordered_map>
#include <vector>

#include "face_reenact/common/error.h"
#include "face_reenact/model/face_model.h"
#include "math_internal.h"
#include "face_reenact/common/parallel.h"
#include "tracker_internal.h"

namespace face_reenact::tracker {
using internal::padded;
using internal::same_coefficients;
namespace {
bool weight_ok(double w) { return std::isfinite(w) && w >= 0; }

// Below this many pixels per thread, starting a thread costs more than it saves. 256 lets the
// coarse level of a 640x480 frame (about 1,650 face pixels, 7 of the 8 iterations) use 2 cores.
constexpr size_t kMinPixelsPerThread = 256;

// The full coefficient vectors (double) of the current x: solved blocks from x, the rest from
// the linearisation's base parameters, zero-padded to the model's sizes.
struct Coefficients {
  Eigen::VectorXd alpha, beta, delta;
  std::array<double, gpu::kNumShParameters> gamma{};
  Eigen::Vector3d euler, translation;
};

Coefficients coefficients(const TrackerModel& model, const Linearization& lin, const Eigen::VectorXd& x) {
  const ParameterLayout& l = lin.layout;
  Coefficients c;
  c.alpha = padded(lin.base.alpha, model.num_identity());
  c.beta = padded(lin.base.beta, model.num_albedo());
  c.delta = padded(lin.base.delta, model.num_expression());
  c.alpha.head(l.num_identity) = x.segment(l.offset(Block::kIdentity), l.num_identity);
  c.beta.head(l.num_albedo) = x.segment(l.offset(Block::kAlbedo), l.num_albedo);
  c.delta.head(l.num_expression) = x.segment(l.offset(Block::kExpression), l.num_expression);
  for (int k = 0; k < gpu::kNumShParameters; ++k) c.gamma[k] = x[l.offset(Block::kLighting) + k];
  c.euler = x.segment<3>(l.offset(Block::kRotation));
  c.translation = x.segment<3>(l.offset(Block::kTranslation));
  return c;
}

// out += (3 x K block of vertex v) * coefficients, for the identity and albedo bases (dense; the
// expression goes over each vertex's own blendshapes, VertexCache::position); `block` is scratch.
// The vertex's block of the (vertex-major) basis is converted to double in one vectorised pass
// and then multiplied; a product of the float block cast on the fly is evaluated coefficient by
// coefficient, which took a sixth of a tracking solve.
void add_product(const gpu::BasisMatrix& basis, int v, const Eigen::VectorXd& coefficients,
                 Eigen::Matrix<double, 3, Eigen::Dynamic, Eigen::RowMajor>* block, Eigen::Vector3d* out) {
  if (basis.cols() == 0) return;
  *block = basis.middleRows<3>(3 * v).cast<double>();
  out->noalias() += *block * coefficients;
}

// mean + identity part of vertex v's position, and its albedo: the same arithmetic whether
// evaluated here per call or once into FixedModelParts, so both give the same bits.
Eigen::Vector3d identity_shape(const gpu::RenderModel& m, int v, const Eigen::VectorXd& alpha,
                               Eigen::Matrix<double, 3, Eigen::Dynamic, Eigen::RowMajor>* block) {
  Eigen::Vector3d p = m.mean_shape.segment<3>(3 * v).cast<double>();
  add_product(m.identity_basis, v, alpha, block, &p);
  return p;
}
Eigen::Vector3d vertex_albedo(const gpu::RenderModel& m, int v, const Eigen::VectorXd& beta,
                              Eigen::Matrix<double, 3, Eigen::Dynamic, Eigen::RowMajor>* block) {
  Eigen::Vector3d a = m.mean_albedo.segment<3>(3 * v).cast<double>();
  add_product(m.albedo_basis, v, beta, block, &a);
  return a;
}

// Model-frame vertex positions and albedos, evaluated on demand in double precision.
class VertexCache {
 public:
  // `fixed_shape` / `fixed_albedo` (may be null): precomputed identity shapes / albedos for c's
  // alpha / beta.
  VertexCache(const TrackerModel& model, const Coefficients& c, const std::vector<Eigen::Vector3d>* fixed_shape,
              const std::vector<Eigen::Vector3d>* fixed_albedo)
      : model_(model), c_(c), fixed_shape_(fixed_shape), fixed_albedo_(fixed_albedo) {
    const size_t n = static_cast<size_t>(model.num_vertices());
    position_.resize(n);
    if (!fixed_albedo_) albedo_.resize(n);
    have_position_.assign(n, 0);
    if (!fixed_albedo_) have_albedo_.assign(n, 0);
  }
  const Eigen::Vector3d& position(int v) {
    if (!have_position_[v]) {
      const auto& m = model_.render;
      Eigen::Vector3d p = fixed_shape_ ? (*fixed_shape_)[v] : identity_shape(m, v, c_.alpha, &block_);
      // Over the blendshapes that move v only (RenderModel::expression_columns), in column order.
      const std::array<double, 3> e = m.expression_columns.Sum<double>(v, c_.delta);
      p += Eigen::Vector3d(e[0], e[1], e[2]);
      position_[v] = p;
      have_position_[v] = 1;
    }
    return position_[v];
  }
  const Eigen::Vector3d& albedo(int v) {
    if (fixed_albedo_) return (*fixed_albedo_)[v];
    if (!have_albedo_[v]) {
      albedo_[v] = vertex_albedo(model_.render, v, c_.beta, &block_);
      have_albedo_[v] = 1;
    }
    return albedo_[v];
  }
  // A vertex's shading under c's light, its normal `n_model` turned by `rot`: the SH basis of the
  // camera-space normal, each channel's irradiance and, with `derivatives`, each channel's
  // irradiance derivative along each Euler angle. A vertex is a corner of the triangles of many
  // pixels: made once per vertex, where each pixel made it for its three corners.
  struct Shading {
    std::array<double, 9> y;
    std::array<double, 3> irradiance;
    std::array<std::array<double, 3>, 3> d_irradiance;  // [channel][angle]
  };
  const Shading& shading(int v, const Eigen::Vector3d& n_model, const internal::RotationWithDerivatives& rot,
                         bool derivatives) {
    if (!shading_) {
      // Left unset: have_shading_ says which are made (zeroing 170 bytes for each of the model's
      // vertices, for every cache of every evaluation, was 1 % of a live session's time).
      shading_ = std::make_unique_for_overwrite<Shading[]>(position_.size());
      have_shading_.assign(position_.size(), 0);
    }
    const uint8_t want = derivatives ? 2 : 1;
    if (have_shading_[v] < want) {
      Shading& sh = shading_[v];
      const Eigen::Vector3d n_cam = rot.r * n_model;
      sh.y = internal::sh_basis(n_cam);
      for (int ch = 0; ch < 3; ++ch) {
        double irradiance = 0;
        for (int q = 0; q < 9; ++q) irradiance += c_.gamma[ch * 9 + q] * sh.y[q];
        sh.irradiance[ch] = irradiance;
      }
      if (derivatives) {
        const std::array<Eigen::Vector3d, 9> grad = internal::sh_basis_gradient(n_cam);
        for (int a = 0; a < 3; ++a) {
          const Eigen::Vector3d dn = rot.d[a] * n_model;  // d n_cam / d euler_a
          for (int ch = 0; ch < 3; ++ch) {
            double d_irr = 0;
            for (int q = 1; q < 9; ++q) d_irr += c_.gamma[ch * 9 + q] * grad[q].dot(dn);
            sh.d_irradiance[ch][a] = d_irr;
          }
        }
      }
      have_shading_[v] = want;
    }
    return shading_[v];
  }

 private:
  const TrackerModel& model_;
  const Coefficients& c_;
  const std::vector<Eigen::Vector3d>* fixed_shape_;
  const std::vector<Eigen::Vector3d>* fixed_albedo_;
  std::vector<Eigen::Vector3d> position_, albedo_;
  std::unique_ptr<Shading[]> shading_;  // made on first use: not every evaluation shades
  std::vector<uint8_t> have_position_, have_albedo_, have_shading_;  // shading: 1 without, 2 with derivatives
  Eigen::Matrix<double, 3, Eigen::Dynamic, Eigen::RowMajor> block_;
};

}  // namespace

namespace {
// The parts for full coefficient vectors (model-length, double).
FixedModelParts MakeFixedModelParts(const TrackerModel& model, Eigen::VectorXd alpha, Eigen::VectorXd beta,
                                    int threads) {
  FixedModelParts out;
  out.alpha = std::move(alpha);
  out.beta = std::move(beta);
  const int n = model.num_vertices();
  out.shape.resize(static_cast<size_t>(n));
  out.albedo.resize(static_cast<size_t>(n));
  constexpr int kVerticesPerItem = 512;
  ParallelFor((n + kVerticesPerItem - 1) / kVerticesPerItem, threads, [&](int item) {
    Eigen::Matrix<double, 3, Eigen::Dynamic, Eigen::RowMajor> block;
    for (int v = item * kVerticesPerItem; v < std::min(n, (item + 1) * kVerticesPerItem); ++v) {
      out.shape[static_cast<size_t>(v)] = identity_shape(model.render, v, out.alpha, &block);
      out.albedo[static_cast<size_t>(v)] = vertex_albedo(model.render, v, out.beta, &block);
    }
  });
  return out;
}
}  // namespace

FixedModelParts ComputeFixedModelParts(const TrackerModel& model, const gpu::FaceParameters& params, int threads) {
  return MakeFixedModelParts(model, padded(params.alpha, model.num_identity()), padded(params.beta, model.num_albedo()),
                             threads);
}

std::shared_ptr<const FixedModelParts> FixedModelPartsAt(const TrackerModel& model, const Linearization& lin,
                                                         const Eigen::VectorXd& x,
                                                         std::shared_ptr<const FixedModelParts> kept, int threads) {
  Coefficients c = coefficients(model, lin, x);
  if (kept && same_coefficients(kept->alpha, c.alpha) && same_coefficients(kept->beta, c.beta)) return kept;
  return std::make_shared<const FixedModelParts>(
      MakeFixedModelParts(model, std::move(c.alpha), std::move(c.beta), threads));
}

const char* term_name(Term t) {
  switch (t) {
    case Term::kPoint: return "point";
    case Term::kPlane: return "plane";
    case Term::kColor: return "color";
    case Term::kLandmark: return "landmark";
    case Term::kRegularizer: return "regularizer";
  }
  return "?";
}

double TermEnergies::total() const {
  double s = 0;
  for (double v : value) s += v;
  return s;
}

bool EnergyOptions::IsValid(std::string* why) const {
  if (!weight_ok(w_point) || !weight_ok(w_plane) || !weight_ok(w_col) || !weight_ok(w_lan) || !weight_ok(w_reg) ||
      !weight_ok(w_reg_expression) || !weight_ok(w_expression_sparsity)) {
    return fail_why(why, "energy: term weights must be finite and non-negative");
  }
  if (!(expression_sparsity_epsilon > 0) || !std::isfinite(expression_sparsity_epsilon)) {
    return fail_why(why, "energy: expression_sparsity_epsilon must be positive");
  }
  if (!(geometry_unit_m > 0) || !std::isfinite(geometry_unit_m)) return fail_why(why, "energy: geometry_unit_m must be positive");
  if (!(landmark_reference_width > 0) || !std::isfinite(landmark_reference_width)) {
    return fail_why(why, "energy: landmark_reference_width must be positive");
  }
  if (!(max_point_distance_m > 0)) return fail_why(why, "energy: max_point_distance_m must be positive");
  if (!(min_normal_dot >= -1 && min_normal_dot <= 1)) return fail_why(why, "energy: min_normal_dot must be in [-1, 1]");
  if (!(max_depth_jump_m > 0)) return fail_why(why, "energy: max_depth_jump_m must be positive");
  if (use_color && (color_parts & gpu::kAllParts) == 0) return fail_why(why, "energy: color_parts selects no part");
  if (!(color_robust_threshold >= 0) || !std::isfinite(color_robust_threshold)) {
    return fail_why(why, "energy: color_robust_threshold must be finite and non-negative (0 = off)");
  }
  if (!(landmark_occlusion_m > 0) || !std::isfinite(landmark_occlusion_m)) {
    return fail_why(why, "energy: landmark_occlusion_m must be positive");
  }
  if (pixel_sampling != 1 && pixel_sampling != 2 && pixel_sampling != 4) {
    return fail_why(why, "energy: pixel_sampling must be 1 (every pixel), 2 (every other pixel) or 4 (every fourth)");
  }
  if (!use_point && !use_plane && !use_color && !use_landmarks && !use_regularizer) {
    return fail_why(why, "energy: every term is switched off");
  }
  return true;
}

bool ColorFollowsProjection(const EnergyOptions& options, const InputFrame& frame) {
  return options.use_color && options.color_follows_projection && frame.has_depth();
}

bool UsesDepthTerms(const EnergyOptions& options, const InputFrame& frame) {
  return frame.has_depth() && (options.use_point || options.use_plane);
}

double RobustColorWeight(const gpu::GBuffer& gbuffer, size_t pixel, const Eigen::Vector3d& input_color, double threshold) {
  if (!(threshold > 0)) return 1.0;
  // In float, as tracker_classify.comp computes it.
  float sq = 0.f;
  for (int c = 0; c < 3; ++c) {
    const float d = gbuffer.color[3 * pixel + c] - static_cast<float>(input_color[c]);
    sq += d * d;
  }
  const float difference = std::sqrt(sq), k = static_cast<float>(threshold);
  return difference > k ? static_cast<double>(k / difference) : 1.0;
}

bool LandmarkVertexVisible(const Eigen::Vector3f& x, const gpu::GBuffer& gbuffer, const gpu::PinholeCamera& camera,
                           float occlusion_m) {
  if (!(x.z() > camera.near_plane)) return false;
  // In float, as tracker_landmarks.comp computes it, so both prune the same landmarks.
  const float u = camera.fx * x.x() / x.z() + camera.cx, v = camera.fy * x.y() / x.z() + camera.cy;
  const float fi = std::floor(u + 0.5f), fj = std::floor(v + 0.5f);
  if (!(fi >= 0.f && fj >= 0.f && fi < static_cast<float>(gbuffer.width) && fj < static_cast<float>(gbuffer.height))) return true;
  const int i = static_cast<int>(fi), j = static_cast<int>(fj);
  if (!gbuffer.covered(i, j)) return true;
  return !(gbuffer.depth(i, j) < x.z() - occlusion_m);
}

Linearization Linearize(const TrackerModel& model, const ParameterLayout& layout, const gpu::FaceParameters& params,
                        const gpu::VertexState& state, const gpu::GBuffer& gbuffer, const InputFrame& frame,
                        const EnergyOptions& options, bool regularize_shared) {
  std::string why;
  if (!options.IsValid(&why)) throw Error(why);
  if (!layout.IsValid(&why, model.num_identity(), model.num_albedo(), model.num_expression())) throw Error(why);
  if (gbuffer.width != frame.width() || gbuffer.height != frame.height()) {
    throw Error("linearise: the G-buffer is " + std::to_string(gbuffer.width) + "x" + std::to_string(gbuffer.height) +
                " but the input frame is " + std::to_string(frame.width()) + "x" + std::to_string(frame.height()));
  }
  const int n = model.num_vertices();
  if (state.camera_normals.size() != 3 * n || state.camera_positions.size() != 3 * n) {
    throw Error("linearise: vertex state does not match the model");
  }
  Linearization lin;
  lin.layout = layout;
  lin.base = params;
  lin.camera = frame.camera;
  const Eigen::Matrix3d rotation = internal::rotation_with_derivatives(params.euler.cast<double>()).r;
  lin.model_normals.resize(3 * n);
  for (int v = 0; v < n; ++v) {
    Eigen::Vector3d m = rotation.transpose() * state.camera_normals.segment<3>(3 * v).cast<double>();
    const double len = m.norm();
    lin.model_normals.segment<3>(3 * v) = len > 0 ? Eigen::Vector3d(m / len) : Eigen::Vector3d::Zero();
  }

  const std::vector<uint8_t>& vertex_part = model.render.vertex_part;
  const bool want_geometry = UsesDepthTerms(options, frame);
  const bool follows_projection = ColorFollowsProjection(options, frame);
  lin.color_follows_projection = follows_projection;
  const int w = frame.width();
  // A draw that says which rectangle it covered: room for that many samples at once, where they
  // were reallocated as they grew.
  const gpu::GBuffer::DrawnTrace& drawn = gbuffer.drawn;
  // Only that rectangle holds covered pixels (the others are as GBuffer::Resize leaves them): the
  // same samples in the same order as a scan of the whole level.
  int i0 = 0, i1 = w - 1, j0 = 0, j1 = frame.height() - 1;
  if (gbuffer.DrawnIsKnown(gbuffer.width, gbuffer.height)) {
    i0 = std::max(i0, drawn.i0), i1 = std::min(i1, drawn.i1), j0 = std::max(j0, drawn.j0), j1 = std::min(j1, drawn.j1);
    if (i0 <= i1 && j0 <= j1)
      lin.pixels.reserve(static_cast<size_t>(i1 - i0 + 1) * static_cast<size_t>(j1 - j0 + 1));
  }
  for (int j = j0; j <= j1; ++j) {
    for (int i = i0; i <= i1; ++i) {
      if (!SampledPixel(options.pixel_sampling, i, j)) continue;
      const size_t p = static_cast<size_t>(j) * w + i;
      if (gbuffer.triangle[p] < 0) continue;
      if (frame.has_depth() && !frame.depth_valid(i, j)) continue;  // input invalid
      PixelSample s;
      s.i = i;
      s.j = j;
      for (int k = 0; k < 3; ++k) {
        s.vertex[k] = gbuffer.vertices[3 * p + k];
        s.bary[k] = gbuffer.barycentric[3 * p + k];
      }
      if (s.vertex[0] < 0 || s.vertex[1] < 0 || s.vertex[2] < 0) continue;
      s.input_color = Eigen::Vector3d(frame.color[3 * p], frame.color[3 * p + 1], frame.color[3 * p + 2]);
      s.color = options.use_color;
      for (int k = 0; k < 3; ++k) s.color = s.color && ((options.color_parts >> vertex_part[s.vertex[k]]) & 1u);
      if (s.color && follows_projection) {
        s.input_color_gradient = InputColorGradient(frame, i, j);
        s.color_weight = RobustColorWeight(gbuffer, p, s.input_color, options.color_robust_threshold);
      }
      if (want_geometry) {
        s.input_point = frame.point(i, j);
        const Eigen::Vector3d synthetic(gbuffer.position[3 * p], gbuffer.position[3 * p + 1], gbuffer.position[3 * p + 2]);
        const Eigen::Vector3d synthetic_normal(gbuffer.normal[3 * p], gbuffer.normal[3 * p + 1], gbuffer.normal[3 * p + 2]);
        const bool near = (synthetic - s.input_point).norm() <= options.max_point_distance_m;
        s.point = options.use_point && near;
        if (options.use_plane && near && InputNormal(frame, i, j, options.max_depth_jump_m, &s.input_normal)) {
          s.plane = synthetic_normal.dot(s.input_normal) >= options.min_normal_dot;
        }
      }
      if (!s.point && !s.plane && !s.color) continue;
      lin.num_point += s.point;
      lin.num_plane += s.plane;
      lin.num_color += s.color;
      lin.pixels.push_back(s);
    }
  }

  if (options.use_landmarks) {
    std::unordered_map<int, const TrackerLandmark*> by_index;
    for (const auto& l : model.landmarks) {
      if (!EnergyUsesLandmark(options, l.ibug_index, l.flags, frame.has_depth())) continue;
      by_index[l.ibug_index] = &l;
    }
    for (const auto& in : frame.landmarks) {
      if (!(in.confidence > 0.f)) continue;
      auto it = by_index.find(in.ibug_index);
      if (it == by_index.end()) continue;
      const int v = LandmarkVertex(in, it->second->vertex, model.num_vertices());
      if (v < 0) continue;
      const Eigen::Vector3f x = state.camera_positions.segment<3>(3 * v);
      if (!LandmarkVertexVisible(x, gbuffer, frame.camera, static_cast<float>(options.landmark_occlusion_m))) continue;
      lin.landmarks.push_back({v, in.position.cast<double>(), in.confidence});
      lin.landmark_weight_sum += in.confidence;
    }
  }
  lin.regularize_shared = regularize_shared;
  if (options.use_regularizer) {
    lin.num_regularizer = RegularizerRows(layout, regularize_shared);
  }

  lin.term_rows[0] = 0;
  lin.term_rows[1] = lin.term_rows[0] + 3 * static_cast<Eigen::Index>(lin.num_point);
  lin.term_rows[2] = lin.term_rows[1] + 2 * static_cast<Eigen::Index>(lin.num_plane);
  lin.term_rows[3] = lin.term_rows[2] + 3 * static_cast<Eigen::Index>(lin.num_color);
  lin.term_rows[4] = lin.term_rows[3] + 2 * static_cast<Eigen::Index>(lin.landmarks.size());
  lin.term_rows[5] = lin.term_rows[4] + lin.num_regularizer;
  return lin;
}

void EvaluateResiduals(const TrackerModel& model, const Linearization& lin, const EnergyOptions& options,
                       const Eigen::VectorXd& x, Eigen::VectorXd* residuals, JacobianMatrix* jacobian,
                       TermEnergies* energies, int threads) {
  const ParameterLayout& layout = lin.layout;
  if (x.size() != layout.num_parameters()) throw Error("evaluate residuals: parameter vector has the wrong size");
  if (model.render.expression_columns.begin.size() != static_cast<size_t>(model.num_vertices()) + 1)
    throw Error("evaluate residuals: the model's expression is not indexed (RenderModel::IndexExpression)");
  const Eigen::Index m = lin.num_residuals();
  const int np = layout.num_parameters();
  Eigen::VectorXd local_r;
  Eigen::VectorXd& r = residuals ? *residuals : local_r;
  r.resize(m);
  // Not zeroed as a whole: every row is written in full where it is computed (the accumulated
  // colour, plane and landmark rows go through double scratch, the prior rows are zeroed first).
  // At 640x480's level 1, J is 18 MB, and a memset of it cost as much as a PCG product.
  if (jacobian) jacobian->resize(m, np);

  const Coefficients c = coefficients(model, lin, x);
  const internal::RotationWithDerivatives rot = internal::rotation_with_derivatives(c.euler);
  const Eigen::Matrix3d& R = rot.r;
  // The precomputed identity shapes / albedos, when they were computed for the coefficients
  // evaluated here (the same arithmetic, so the same bits as computing them vertex by vertex).
  const FixedModelParts* fixed = lin.fixed.get();
  const std::vector<Eigen::Vector3d>* fixed_shape =
      fixed && same_coefficients(fixed->alpha, c.alpha) ? &fixed->shape : nullptr;
  const std::vector<Eigen::Vector3d>* fixed_albedo =
      fixed && same_coefficients(fixed->beta, c.beta) ? &fixed->albedo : nullptr;
  VertexCache cache(model, c, fixed_shape, fixed_albedo);
  const auto& rm = model.render;
  const int k_id = layout.num_identity, k_alb = layout.num_albedo, k_exp = layout.num_expression;
  const int o_id = layout.offset(Block::kIdentity), o_alb = layout.offset(Block::kAlbedo);
  const int o_exp = layout.offset(Block::kExpression), o_gam = layout.offset(Block::kLighting);
  const int o_rot = layout.offset(Block::kRotation), o_t = layout.offset(Block::kTranslation);

  const double unit = options.geometry_unit_m;
  const double s_point = lin.num_point ? std::sqrt(options.w_point / lin.num_point) / unit : 0;
  const double s_plane = lin.num_plane ? std::sqrt(options.w_plane / lin.num_plane) / unit : 0;
  const double s_col = lin.num_color ? std::sqrt(options.w_col / lin.num_color) : 0;

  // The dense terms, pixel by pixel. Every pixel writes only its own rows, so contiguous chunks
  // of pixels run on separate threads (each with its own vertex cache and scratch) and give
  // bit-identical r and J for any thread count; a chunk's first rows come from counting the
  // terms of the pixels before it.
  auto dense_rows = [&](size_t begin, size_t end, Eigen::Index row_point, Eigen::Index row_plane, Eigen::Index row_col,
                        VertexCache& vertices) {
    // Scratch for the pixel-level derivatives of X_S (3 x np). Only the shape and pose columns
    // depend on the pixel, and every pixel writes all of them; the rest (albedo, light) stay the
    // zeros set here (a per-pixel clear of all np columns was a 2 KB memset per pixel).
    Eigen::Matrix<double, 3, Eigen::Dynamic> dx = Eigen::Matrix<double, 3, Eigen::Dynamic>::Zero(3, np);
    // A plane pair's and a colour triple's rows, accumulated in double and rounded once into J.
    Eigen::Matrix<double, 2, Eigen::Dynamic> d_plane(2, np);
    Eigen::Matrix<double, 3, Eigen::Dynamic> d_col(3, np);
    Eigen::MatrixXd e_id(3, k_id), e_exp(3, k_exp);
    for (size_t p = begin; p < end; ++p) {
      const PixelSample& s = lin.pixels[p];
      const bool color_moves = s.color && lin.color_follows_projection;
      // The surface point only where a term reads it: a colour term on RGB video does not (it is
      // not differentiated through the projection), and the vertex positions were 2 % of a
      // reenactment's time.
      const bool geometry = s.point || s.plane || color_moves;
      Eigen::Vector3d v_bar = Eigen::Vector3d::Zero(), n_bar = Eigen::Vector3d::Zero(), xs = Eigen::Vector3d::Zero();
      if (geometry) {
        for (int k = 0; k < 3; ++k) {
          v_bar += s.bary[k] * vertices.position(s.vertex[k]);
          n_bar += s.bary[k] * lin.model_normals.segment<3>(3 * s.vertex[k]);
        }
        xs = R * v_bar + c.translation;
      }
      if (jacobian && geometry) {
        if (k_id > 0) {
          e_id.setZero();
          for (int k = 0; k < 3; ++k) e_id += s.bary[k] * rm.identity_basis.block(3 * s.vertex[k], 0, 3, k_id).cast<double>();
          dx.middleCols(o_id, k_id) = R * e_id;
        }
        if (k_exp > 0) {
          // The corners' nonzero blocks only (the zeros added nothing): the same sums, fewer terms.
          e_exp.setZero();
          const gpu::VertexColumns& ec = rm.expression_columns;
          for (int k = 0; k < 3; ++k) {
            const size_t v = static_cast<size_t>(s.vertex[k]);
            for (int32_t q = ec.begin[v]; q < ec.begin[v + 1] && ec.column[static_cast<size_t>(q)] < k_exp; ++q) {
              const float* b = &ec.xyz[3 * static_cast<size_t>(q)];
              auto col = e_exp.col(ec.column[static_cast<size_t>(q)]);
              for (int a = 0; a < 3; ++a) col[a] += s.bary[k] * static_cast<double>(b[a]);
            }
          }
          dx.middleCols(o_exp, k_exp) = R * e_exp;
        }
        for (int a = 0; a < 3; ++a) dx.col(o_rot + a) = rot.d[a] * v_bar;
        dx.middleCols<3>(o_t).setIdentity();
      }
      if (s.point || s.plane) {
        const Eigen::Vector3d diff = xs - s.input_point;
        if (s.point) {
          r.segment<3>(row_point) = s_point * diff;
          if (jacobian) jacobian->middleRows(row_point, 3) = (s_point * dx).cast<float>();
          row_point += 3;
        }
        if (s.plane) {
          const double n_len = n_bar.norm();
          const Eigen::Vector3d n_model = n_len > 0 ? Eigen::Vector3d(n_bar / n_len) : Eigen::Vector3d::Zero();
          const Eigen::Vector3d n_s = R * n_model;
          r[row_plane] = s_plane * s.input_normal.dot(diff);
          r[row_plane + 1] = s_plane * n_s.dot(diff);
          if (jacobian) {
            d_plane.row(0) = s_plane * (s.input_normal.transpose() * dx);
            d_plane.row(1) = s_plane * (n_s.transpose() * dx);
            for (int a = 0; a < 3; ++a) d_plane(1, o_rot + a) += s_plane * (rot.d[a] * n_model).dot(diff);
            jacobian->middleRows(row_plane, 2) = d_plane.cast<float>();
          }
          row_plane += 2;
        }
      }
      if (s.color) {
        // C_c = sum_k b_k a_kc sum_j gamma_cj y_j(R n_k)
        Eigen::Vector3d color = Eigen::Vector3d::Zero();
        // Unless the colour follows the projection, a colour row holds its channel's lighting,
        // the albedo and the rotation only: those blocks are made and written, the rest of J's
        // row set to zero (made and scaled in full, a calibration's 3 x 175 doubles per pixel
        // were most of the rows' time).
        if (jacobian && color_moves) {
          d_col.setZero();
        } else if (jacobian) {
          for (int ch = 0; ch < 3; ++ch) d_col.block<1, 9>(ch, o_gam + ch * 9).setZero();
          d_col.middleCols(o_alb, k_alb).setZero();
          d_col.middleCols<3>(o_rot).setZero();
        }
        for (int k = 0; k < 3; ++k) {
          const int v = s.vertex[k];
          const VertexCache::Shading& shading =
              vertices.shading(v, lin.model_normals.segment<3>(3 * v), rot, jacobian != nullptr);
          const auto& y = shading.y;
          const Eigen::Vector3d& albedo = vertices.albedo(v);
          for (int ch = 0; ch < 3; ++ch) {
            const double irradiance = shading.irradiance[ch];
            color[ch] += s.bary[k] * albedo[ch] * irradiance;
            if (!jacobian) continue;
            auto jrow = d_col.row(ch);
            const double ba = s_col * s.bary[k] * albedo[ch];
            for (int q = 0; q < 9; ++q) jrow[o_gam + ch * 9 + q] += ba * y[q];
            if (k_alb > 0) {
              jrow.segment(o_alb, k_alb) +=
                  (s_col * s.bary[k] * irradiance) * rm.albedo_basis.row(3 * v + ch).head(k_alb).cast<double>();
            }
            for (int a = 0; a < 3; ++a) jrow[o_rot + a] += ba * shading.d_irradiance[ch][a];
          }
        }
        if (color_moves) {
          // The input colour where X_S projects, to first order around the pixel:
          // C_I(p) + G (Pi(X_S) - p); its derivative is G dPi/dX dX_S/dx.
          const auto& cam = lin.camera;
          const double iz = 1.0 / xs.z();
          const Eigen::Vector2d shift(cam.fx * xs.x() * iz + cam.cx - s.i, cam.fy * xs.y() * iz + cam.cy - s.j);
          color -= s.input_color_gradient * shift;
          if (jacobian) {
            Eigen::Matrix<double, 2, 3> dproj;
            dproj << cam.fx * iz, 0, -cam.fx * xs.x() * iz * iz, 0, cam.fy * iz, -cam.fy * xs.y() * iz * iz;
            d_col.noalias() -= (s_col * s.input_color_gradient * dproj) * dx;
          }
        }
        const double wsq = std::sqrt(s.color_weight);
        r.segment<3>(row_col) = wsq * s_col * (color - s.input_color);
        if (jacobian && color_moves) {
          jacobian->middleRows(row_col, 3) = (wsq * d_col).cast<float>();
        } else if (jacobian) {
          for (int ch = 0; ch < 3; ++ch) {
            auto row = jacobian->row(row_col + ch);
            row.setZero();
            row.segment<9>(o_gam + ch * 9) = (wsq * d_col.block<1, 9>(ch, o_gam + ch * 9)).cast<float>();
            row.segment(o_alb, k_alb) = (wsq * d_col.row(ch).segment(o_alb, k_alb)).cast<float>();
            row.segment<3>(o_rot) = (wsq * d_col.row(ch).segment<3>(o_rot)).cast<float>();
          }
        }
        row_col += 3;
      }
    }
  };
  const size_t num_pixels = lin.pixels.size();
  const int chunks = static_cast<int>(std::clamp<size_t>(num_pixels / kMinPixelsPerThread, 1, std::max(threads, 1)));
  if (chunks == 1) {
    dense_rows(0, num_pixels, lin.term_rows[0], lin.term_rows[1], lin.term_rows[2], cache);
  } else {
    // Each chunk's first pixel and first rows, from counting the terms of the pixels before it;
    // everything that may throw is made before the threads start.
    struct Chunk {
      size_t begin = 0, end = 0;
      Eigen::Index row_point = 0, row_plane = 0, row_col = 0;
    };
    std::vector<Chunk> plan(static_cast<size_t>(chunks));
    std::vector<std::unique_ptr<VertexCache>> caches;
    Eigen::Index row_point = lin.term_rows[0], row_plane = lin.term_rows[1], row_col = lin.term_rows[2];
    size_t begin = 0;
    for (int k = 0; k < chunks; ++k) {
      const size_t end = num_pixels * static_cast<size_t>(k + 1) / static_cast<size_t>(chunks);
      plan[static_cast<size_t>(k)] = {begin, end, row_point, row_plane, row_col};
      if (k + 1 < chunks) caches.push_back(std::make_unique<VertexCache>(model, c, fixed_shape, fixed_albedo));
      for (size_t q = begin; q < end; ++q) {
        const PixelSample& s = lin.pixels[q];
        row_point += s.point ? 3 : 0;
        row_plane += s.plane ? 2 : 0;
        row_col += s.color ? 3 : 0;
      }
      begin = end;
    }
    ParallelFor(chunks, chunks, [&](int k) {
      const Chunk& ch = plan[static_cast<size_t>(k)];
      // The last chunk uses the caller's cache, which the landmarks below read again.
      VertexCache& vc = k + 1 < chunks ? *caches[static_cast<size_t>(k)] : cache;
      dense_rows(ch.begin, ch.end, ch.row_point, ch.row_plane, ch.row_col, vc);
    });
  }

  // Landmarks (Eq. 10): projections of the landmark vertices against the detected points.
  Eigen::Index row = lin.term_rows[3];
  if (!lin.landmarks.empty()) {
    const auto& cam = lin.camera;
    const double s_lan = std::sqrt(options.w_lan / lin.landmark_weight_sum) * options.landmark_reference_width / cam.width;
    Eigen::Matrix<double, 2, Eigen::Dynamic> d_lan(2, np);  // a landmark's rows, rounded once into J
    for (const LandmarkSample& l : lin.landmarks) {
      const Eigen::Vector3d& v = cache.position(l.vertex);
      const Eigen::Vector3d X = R * v + c.translation;
      const double s = s_lan * std::sqrt(l.confidence);
      const double iz = 1.0 / X.z();
      const Eigen::Vector2d uv(cam.fx * X.x() * iz + cam.cx, cam.fy * X.y() * iz + cam.cy);
      r.segment<2>(row) = s * (uv - l.target);
      if (jacobian) {
        d_lan.setZero();
        Eigen::Matrix<double, 2, 3> dproj;
        dproj << cam.fx * iz, 0, -cam.fx * X.x() * iz * iz, 0, cam.fy * iz, -cam.fy * X.y() * iz * iz;
        const Eigen::Matrix<double, 2, 3> dr = s * dproj;
        const Eigen::Matrix<double, 2, 3> drr = dr * R;
        if (k_id > 0) d_lan.middleCols(o_id, k_id) = drr * rm.identity_basis.block(3 * l.vertex, 0, 3, k_id).cast<double>();
        if (k_exp > 0) {
          d_lan.middleCols(o_exp, k_exp) = drr * rm.expression_basis.block(3 * l.vertex, 0, 3, k_exp).cast<double>();
        }
        for (int a = 0; a < 3; ++a) d_lan.col(o_rot + a) = dr * (rot.d[a] * v);
        d_lan.middleCols<3>(o_t) = dr;
        jacobian->middleRows(row, 2) = d_lan.cast<float>();
      }
      row += 2;
    }
  }

  // Regulariser (Eq. 11).
  if (lin.num_regularizer > 0) {
    const double s_reg = std::sqrt(options.w_reg);
    auto prior = [&](int offset, int count, auto sigma_of) {
      for (int q = 0; q < count; ++q) {
        const double inv = s_reg / sigma_of(q);
        r[row] = inv * x[offset + q];
        if (jacobian) {
          jacobian->row(row).setZero();
          (*jacobian)(row, offset + q) = static_cast<float>(inv);
        }
        ++row;
      }
    };
    if (lin.regularize_shared) {
      prior(o_id, k_id, [&](int q) { return static_cast<double>(model.identity_sigma[q]); });
      prior(o_alb, k_alb, [&](int q) { return static_cast<double>(model.albedo_sigma[q]); });
    }
    // Eq. 11 plus the reweighted L1 prior (EnergyOptions::w_expression_sparsity).
    const double l2 = options.w_reg_expression / (static_cast<double>(model.expression_sigma) * model.expression_sigma);
    for (int q = 0; q < k_exp; ++q) {
      const double delta0 = std::abs(static_cast<double>(lin.base.delta[q]));
      const double inv = std::sqrt(l2 + options.w_expression_sparsity / (delta0 + options.expression_sparsity_epsilon));
      r[row] = inv * x[o_exp + q];
      if (jacobian) {
        jacobian->row(row).setZero();
        (*jacobian)(row, o_exp + q) = static_cast<float>(inv);
      }
      ++row;
    }
  }

  if (energies) {
    for (int t = 0; t < kNumTerms; ++t) {
      energies->value[t] = r.segment(lin.term_rows[t], lin.term_rows[t + 1] - lin.term_rows[t]).squaredNorm();
    }
  }
}

}  // namespace face_reenact::tracker
