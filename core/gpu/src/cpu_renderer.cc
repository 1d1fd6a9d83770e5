#include "face_reenact/gpu/cpu_renderer.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>

#include "face_reenact/common/error.h"
#include "face_reenact/common/parallel.h"
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

namespace {
// Vertices per item of evaluate's per-vertex passes, and triangles per item of its face-normal
// pass: fixed sizes, so the arithmetic does not depend on the thread count.
constexpr int kVerticesPerItem = 1024;
constexpr int kTrianglesPerItem = 2048;

int items_for(int count, int per_item) { return (count + per_item - 1) / per_item; }
}  // namespace

CpuRenderer::CpuRenderer(RenderModel model) : model_(std::move(model)) {
  std::string why;
  if (!model_.IsValid(&why)) throw Error("CPU renderer: " + why);
  // Each vertex's incident triangles in ascending order (compressed rows), so the normals can be
  // gathered per vertex in parallel and still add the face normals in the order a scatter over
  // the triangle list would.
  const int n = model_.num_vertices();
  incident_begin_.assign(static_cast<size_t>(n) + 1, 0);
  for (const auto& t : model_.triangles)
    for (int k = 0; k < 3; ++k) ++incident_begin_[static_cast<size_t>(t[k]) + 1];
  for (int v = 0; v < n; ++v) incident_begin_[static_cast<size_t>(v) + 1] += incident_begin_[static_cast<size_t>(v)];
  incident_.resize(static_cast<size_t>(incident_begin_.back()));
  std::vector<int32_t> fill(incident_begin_.begin(), incident_begin_.end() - 1);
  for (size_t t = 0; t < model_.triangles.size(); ++t) {
    for (int k = 0; k < 3; ++k) {
      int32_t& slot = fill[static_cast<size_t>(model_.triangles[t][k])];
      incident_[static_cast<size_t>(slot++)] = static_cast<int32_t>(t);
    }
  }
}

CpuRenderer::CpuRenderer(const CpuRenderer& other) : CpuRenderer(other.model_) {}

const std::vector<int32_t>& CpuRenderer::drawn_triangles_for(PartMask parts) const {
  std::lock_guard<std::mutex> lock(drawn_mutex_);
  auto it = drawn_.find(parts);
  if (it == drawn_.end()) {
    RenderOptions options;
    options.parts = parts;
    it = drawn_.emplace(parts, drawn_triangles(model_, options)).first;
  }
  return it->second;
}

std::shared_ptr<const CpuRenderer::IdentityParts> CpuRenderer::identity_parts(const FaceParameters& params) const {
  {
    std::lock_guard<std::mutex> lock(identity_mutex_);
    if (identity_ && identity_->alpha.size() == params.alpha.size() && identity_->alpha == params.alpha &&
        identity_->beta.size() == params.beta.size() && identity_->beta == params.beta) {
      return identity_;
    }
  }
  auto parts = std::make_shared<IdentityParts>();
  parts->alpha = params.alpha;
  parts->beta = params.beta;
  parts->shape = model_.mean_shape;
  if (model_.identity_basis.cols() > 0) parts->shape += model_.identity_basis * padded(params.alpha, model_.identity_basis.cols());
  parts->albedo = model_.mean_albedo;
  if (model_.albedo_basis.cols() > 0) parts->albedo += model_.albedo_basis * padded(params.beta, model_.albedo_basis.cols());
  std::lock_guard<std::mutex> lock(identity_mutex_);
  identity_ = parts;
  return parts;
}

VertexState CpuRenderer::evaluate(const FaceParameters& params, CpuRenderTimes* times, int threads,
                                  VertexColors colors) const {
  std::string why;
  if (!params.IsValid(&why, static_cast<int>(model_.identity_basis.cols()), static_cast<int>(model_.expression_basis.cols()),
                      static_cast<int>(model_.albedo_basis.cols()))) {
    throw Error("invalid face parameters: " + why);
  }
  const int n = model_.num_vertices();
  auto start = Clock::now();
  VertexState s;
  // a_id + E_id alpha and the albedo are kept for the last alpha/beta (a tracking solve renders
  // one identity many times), as the GPU renderer keeps them; the sums are the same either way.
  const std::shared_ptr<const IdentityParts> identity = identity_parts(params);
  s.model_positions = identity->shape;
  s.albedo = identity->albedo;
  const Eigen::Index k_exp = model_.expression_basis.cols();
  if (k_exp > 0) {
    // Each vertex over the blendshapes that move it (RenderModel::expression_columns), in column
    // order; the dense product read the whole 3N x K basis.
    const Eigen::VectorXf delta = padded(params.delta, k_exp);
    const VertexColumns& ec = model_.expression_columns;
    ParallelFor(items_for(n, kVerticesPerItem), threads, [&](int item) {
      const int end = std::min(n, (item + 1) * kVerticesPerItem);
      for (int v = item * kVerticesPerItem; v < end; ++v) {
        if (ec.begin[static_cast<size_t>(v)] == ec.begin[static_cast<size_t>(v) + 1]) continue;
        const std::array<float, 3> d = ec.Sum<float>(v, delta);
        for (int c = 0; c < 3; ++c) s.model_positions[3 * v + c] += d[static_cast<size_t>(c)];
      }
    });
  }
  if (times) times->model_ms = ms_since(start);
  start = Clock::now();
  // Area-weighted vertex normals: the sum of the (unnormalised) cross products of the incident
  // triangles, whose length is twice the triangle area.
  auto pos = [&](int v) { return Eigen::Vector3f(s.model_positions.segment<3>(3 * v)); };
  const int num_triangles = static_cast<int>(model_.triangles.size());
  std::vector<Eigen::Vector3f> face(static_cast<size_t>(num_triangles));
  ParallelFor(items_for(num_triangles, kTrianglesPerItem), threads, [&](int item) {
    const int end = std::min(num_triangles, (item + 1) * kTrianglesPerItem);
    for (int t = item * kTrianglesPerItem; t < end; ++t) {
      const auto& tri = model_.triangles[static_cast<size_t>(t)];
      const Eigen::Vector3f a = pos(tri[0]);
      face[static_cast<size_t>(t)] = (pos(tri[1]) - a).cross(pos(tri[2]) - a);
    }
  });
  const Eigen::Matrix3f rotation = rotation_from_euler(params.euler);
  s.camera_positions.resize(3 * n);
  s.camera_normals.resize(3 * n);
  const bool shade = colors == VertexColors::kShaded;
  if (shade) {
    s.colors.resize(3 * n);
  } else {
    s.colors.setZero(3 * n);
  }
  ParallelFor(items_for(n, kVerticesPerItem), threads, [&](int item) {
    const int end = std::min(n, (item + 1) * kVerticesPerItem);
    for (int v = item * kVerticesPerItem; v < end; ++v) {
      Eigen::Vector3f sum = Eigen::Vector3f::Zero();
      for (int32_t q = incident_begin_[static_cast<size_t>(v)]; q < incident_begin_[static_cast<size_t>(v) + 1]; ++q)
        sum += face[static_cast<size_t>(incident_[static_cast<size_t>(q)])];
      const float len = sum.norm();
      const Eigen::Vector3f normal = len > 0.f ? Eigen::Vector3f(sum / len) : Eigen::Vector3f::Zero();
      const Eigen::Vector3f cam_normal = rotation * normal;
      s.camera_positions.segment<3>(3 * v) = rotation * pos(v) + params.translation;
      s.camera_normals.segment<3>(3 * v) = cam_normal;
      if (!shade) continue;
      const auto basis = sh_basis(cam_normal);
      for (int c = 0; c < 3; ++c) {
        float irradiance = 0.f;
        for (int k = 0; k < kNumShCoefficients; ++k) irradiance += params.gamma[c * kNumShCoefficients + k] * basis[k];
        s.colors[3 * v + c] = s.albedo[3 * v + c] * irradiance;
      }
    }
  });
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

namespace {

// A vertex in framebuffer coordinates, exact and snapped, with its depths (set where its
// VertexPixelRange is in the depth range).
struct ProjectedVertex {
  double ux, uy, sx, sy;
  double z;  // camera-space depth (perspective correction)
  double d;  // depth-buffer value
};

// The pixel centres a vertex's snapped position lies beyond, per axis, clamped to the buffer:
// a triangle's pixel bounding box is the least lo and the greatest hi of its corners (ceil, floor
// and the clamps are monotonic, so taking them per vertex gives the box the corners' extremes
// give). Most triangles of a tracking level cover no pixel centre; this compact copy (20 bytes
// against ProjectedVertex's 48) lets the set-up pass drop them before reading anything else.
struct VertexPixelRange {
  int32_t x_lo, x_hi, y_lo, y_hi;
  bool in_depth_range;
};

// A triangle that passed culling and covers at least one pixel centre's bounding box, with what
// its pixels need: made once, then rasterised band by band.
struct TriangleSetup {
  int32_t triangle = 0;
  double ux[3], uy[3];  // exact (unsnapped) framebuffer positions, the triangle's corner order
  double d[3];          // depth-buffer values of the corners
  double z[3];          // camera-space depths (perspective correction)
  double ox[3], oy[3];  // snapped positions in coverage order (area2 > 0)
  int order[3];
  bool top_left[3];
  double exact_area2;
  int i0, i1, j0, j1;  // pixel bounding box, inclusive
};

// Rows per band of the raster pass: bands are taken in order from a shared counter, several
// per thread, so a band full of face does not leave the other threads waiting.
constexpr int kRowsPerBand = 16;
// Triangles per item of the setup pass.
constexpr size_t kTrianglesPerSetupItem = 2048;

}  // namespace

void CpuRenderer::rasterize(const VertexState& state, const PinholeCamera& camera, const RenderOptions& options,
                            GBuffer* out, int threads) const {
  std::string why;
  if (!camera.IsValid(&why)) throw Error("invalid camera: " + why);
  GBuffer& g = *out;
  // Sized here, cleared by the bands below (each its own rows): at 640x480 the G-buffer is 20 MB,
  // and clearing it on one thread cost as much as rasterising the face. A buffer whose last draw
  // is known (GBuffer::drawn: this rasteriser's, or a GPU read-back's) needs only that cleared.
  const size_t num_pixels = static_cast<size_t>(camera.width) * camera.height;
  const GBuffer::DrawnTrace previous = g.drawn;
  const bool previous_known = g.DrawnIsKnown(camera.width, camera.height);
  g.width = camera.width;
  g.height = camera.height;
  for (auto* v : {&g.color, &g.position, &g.normal, &g.barycentric}) v->resize(3 * num_pixels);
  g.vertices.resize(3 * num_pixels);
  g.triangle.resize(num_pixels);
  g.drawn = GBuffer::DrawnTrace();  // nothing known until this draw is done
  // The depth buffer is scratch: one per calling thread, kept, so a per-frame caller faults no
  // new pages. The bands below write disjoint rows of it.
  thread_local std::vector<float> depth_buffer;
  depth_buffer.resize(num_pixels);
  float* depth = depth_buffer.data();
  const double near = camera.near_plane, far = camera.far_plane;

  // Setup pass: per triangle, in draw order, independent of the others.
  const std::vector<int32_t>& drawn = drawn_triangles_for(options.parts);
  const int setup_items = static_cast<int>((drawn.size() + kTrianglesPerSetupItem - 1) / kTrianglesPerSetupItem);
  // The caller's, kept like the depth buffer: lists that grew by doubling on every draw moved
  // their 190-byte entries again and again (1 % of a live session's time).
  thread_local std::vector<std::vector<TriangleSetup>> setups_scratch;
  auto& setups = setups_scratch;
  setups.resize(static_cast<size_t>(setup_items));
  for (auto& list : setups) list.clear();
  // Each vertex projected once (a vertex is a corner of about six triangles).
  const int num_vertices = model_.num_vertices();
  thread_local std::vector<ProjectedVertex> projected_scratch;
  thread_local std::vector<VertexPixelRange> ranges_scratch;
  auto& projected = projected_scratch;  // the caller's, filled and read by the pool's threads too
  auto& ranges = ranges_scratch;
  projected.resize(static_cast<size_t>(num_vertices));
  ranges.resize(static_cast<size_t>(num_vertices));
  // Clamped on both sides before the casts (a NaN takes the low end): a vertex projecting
  // billions of pixels away (a fit far off, just in front of the near plane) overflowed the int,
  // and the box it gave reached outside the buffers (a crash filling the depth buffer).
  auto pixel = [](double v, double lo, double hi) { return static_cast<int32_t>(v >= lo ? (v <= hi ? v : hi) : lo); };
  const double w_px = camera.width, h_px = camera.height;
  ParallelFor(items_for(num_vertices, kVerticesPerItem), threads, [&](int item) {
    const int end = std::min(num_vertices, (item + 1) * kVerticesPerItem);
    for (int v = item * kVerticesPerItem; v < end; ++v) {
      const Eigen::Vector3f p = state.camera_positions.segment<3>(3 * v);
      ProjectedVertex& pv = projected[static_cast<size_t>(v)];
      VertexPixelRange& r = ranges[static_cast<size_t>(v)];
      r.in_depth_range = p.z() > camera.near_plane && p.z() < camera.far_plane;
      if (!r.in_depth_range) continue;
      // Framebuffer coordinates: the centre of pixel i is at i + 0.5.
      const double z = p.z();
      pv.z = z;
      pv.ux = camera.fx * p.x() / z + camera.cx + 0.5;
      pv.uy = camera.fy * p.y() / z + camera.cy + 0.5;
      pv.sx = snap(pv.ux);
      pv.sy = snap(pv.uy);
      pv.d = far * (z - near) / ((far - near) * z);
      r.x_lo = pixel(std::ceil(pv.sx - 0.5), 0.0, w_px);
      r.x_hi = pixel(std::floor(pv.sx - 0.5), -1.0, w_px - 1.0);
      r.y_lo = pixel(std::ceil(pv.sy - 0.5), 0.0, h_px);
      r.y_hi = pixel(std::floor(pv.sy - 0.5), -1.0, h_px - 1.0);
    }
  });
  ParallelFor(setup_items, threads, [&](int item) {
    std::vector<TriangleSetup>& list = setups[static_cast<size_t>(item)];
    const size_t begin = static_cast<size_t>(item) * kTrianglesPerSetupItem;
    const size_t end = std::min(drawn.size(), begin + kTrianglesPerSetupItem);
    for (size_t q = begin; q < end; ++q) {
      const int32_t t = drawn[q];
      const auto& tri = model_.triangles[t];
      const VertexPixelRange* r[3] = {&ranges[static_cast<size_t>(tri[0])], &ranges[static_cast<size_t>(tri[1])],
                                      &ranges[static_cast<size_t>(tri[2])]};
      if (!r[0]->in_depth_range || !r[1]->in_depth_range || !r[2]->in_depth_range) continue;
      // Most triangles of a small level cover no pixel centre: their bounding box is empty.
      const int i0 = std::min({r[0]->x_lo, r[1]->x_lo, r[2]->x_lo});
      const int i1 = std::max({r[0]->x_hi, r[1]->x_hi, r[2]->x_hi});
      if (i0 > i1) continue;
      const int j0 = std::min({r[0]->y_lo, r[1]->y_lo, r[2]->y_lo});
      const int j1 = std::max({r[0]->y_hi, r[1]->y_hi, r[2]->y_hi});
      if (j0 > j1) continue;
      const ProjectedVertex* pv[3] = {&projected[static_cast<size_t>(tri[0])], &projected[static_cast<size_t>(tri[1])],
                                      &projected[static_cast<size_t>(tri[2])]};
      double sx[3], sy[3];
      for (int k = 0; k < 3; ++k) {
        sx[k] = pv[k]->sx;
        sy[k] = pv[k]->sy;
      }
      double area2 = (sx[1] - sx[0]) * (sy[2] - sy[0]) - (sx[2] - sx[0]) * (sy[1] - sy[0]);
      if (area2 == 0.0 || !std::isfinite(area2)) continue;
      // Front-facing triangles (counter-clockwise from outside) have area2 < 0 in this y-down frame.
      if (options.cull_back_faces && area2 > 0.0) continue;
      TriangleSetup& ts = list.emplace_back();  // built in place: it is drawn
      ts.triangle = t;
      ts.i0 = i0, ts.i1 = i1, ts.j0 = j0, ts.j1 = j1;
      for (int k = 0; k < 3; ++k) {
        ts.z[k] = pv[k]->z;
        ts.ux[k] = pv[k]->ux;
        ts.uy[k] = pv[k]->uy;
        ts.d[k] = pv[k]->d;
      }
      // Work on a copy ordered so that area2 > 0 (interior: every edge function positive).
      ts.order[0] = 0;
      ts.order[1] = 1;
      ts.order[2] = 2;
      if (area2 < 0.0) std::swap(ts.order[1], ts.order[2]);
      const int* order = ts.order;
      // The exact (unsnapped) area with the same corner order, for attribute interpolation.
      ts.exact_area2 = (ts.ux[order[1]] - ts.ux[order[0]]) * (ts.uy[order[2]] - ts.uy[order[0]]) -
                       (ts.ux[order[2]] - ts.ux[order[0]]) * (ts.uy[order[1]] - ts.uy[order[0]]);
      if (!(ts.exact_area2 > 0.0)) {  // the snap turned a degenerate or flipped sliver visible: use the snapped plane
        for (int k = 0; k < 3; ++k) {
          ts.ux[k] = sx[k];
          ts.uy[k] = sy[k];
        }
        ts.exact_area2 = std::abs(area2);
      }
      for (int k = 0; k < 3; ++k) {
        ts.ox[k] = sx[order[k]];
        ts.oy[k] = sy[order[k]];
      }
      // Edge e runs from corner e+1 to corner e+2 (opposite corner e); its function is the
      // screen-space barycentric weight of corner e times area2.
      for (int e = 0; e < 3; ++e) {
        const int a = (e + 1) % 3, b = (e + 2) % 3;
        const double dx = ts.ox[b] - ts.ox[a], dy = ts.oy[b] - ts.oy[a];
        ts.top_left[e] = (dy == 0.0 && dx > 0.0) || dy < 0.0;
      }
    }
  });

  // Each band's triangles in draw order (scanning every triangle's set-up for every band read
  // 30 x 2 MB per 640x480 draw), and the pixels this draw may write: the union of the triangles'
  // bounding boxes.
  const int bands = (camera.height + kRowsPerBand - 1) / kRowsPerBand;
  thread_local std::vector<std::vector<const TriangleSetup*>> band_triangles_scratch;
  auto& band_triangles = band_triangles_scratch;  // the caller's, read by the pool's threads too
  band_triangles.resize(static_cast<size_t>(bands));
  for (auto& list : band_triangles) list.clear();
  GBuffer::DrawnTrace drawn_box;
  drawn_box.i0 = camera.width, drawn_box.j0 = camera.height;
  for (const auto& list : setups) {
    for (const TriangleSetup& ts : list) {
      drawn_box.i0 = std::min(drawn_box.i0, ts.i0), drawn_box.i1 = std::max(drawn_box.i1, ts.i1);
      drawn_box.j0 = std::min(drawn_box.j0, ts.j0), drawn_box.j1 = std::max(drawn_box.j1, ts.j1);
      for (int b = ts.j0 / kRowsPerBand; b <= ts.j1 / kRowsPerBand; ++b) band_triangles[static_cast<size_t>(b)].push_back(&ts);
    }
  }
  // Pixels [i0, i1] of rows [j0, j1] as GBuffer::Resize leaves them.
  auto clear = [&](int i0, int i1, int j0, int j1) {
    if (i0 > i1) return;
    for (int j = j0; j <= j1; ++j) {
      const size_t p0 = static_cast<size_t>(j) * camera.width + i0, p1 = static_cast<size_t>(j) * camera.width + i1 + 1;
      for (auto* v : {&g.color, &g.position, &g.normal, &g.barycentric})
        std::fill(v->begin() + static_cast<std::ptrdiff_t>(3 * p0), v->begin() + static_cast<std::ptrdiff_t>(3 * p1), 0.f);
      std::fill(g.vertices.begin() + static_cast<std::ptrdiff_t>(3 * p0), g.vertices.begin() + static_cast<std::ptrdiff_t>(3 * p1), -1);
      std::fill(g.triangle.begin() + static_cast<std::ptrdiff_t>(p0), g.triangle.begin() + static_cast<std::ptrdiff_t>(p1), -1);
    }
  };

  // Raster pass: bands of rows, each visiting the triangles in draw order, so every pixel sees
  // the same depth tests in the same order as a single pass would.
  ParallelFor(bands, threads, [&](int band) {
    const int band_j0 = band * kRowsPerBand, band_j1 = std::min(camera.height, band_j0 + kRowsPerBand) - 1;
    if (!previous_known) {
      clear(0, camera.width - 1, band_j0, band_j1);
    } else if (previous.j0 <= band_j1 && previous.j1 >= band_j0) {
      clear(previous.i0, previous.i1, std::max(band_j0, previous.j0), std::min(band_j1, previous.j1));
    }
    // The depth buffer at the far plane where this draw tests it.
    if (drawn_box.i0 <= drawn_box.i1 && drawn_box.j0 <= band_j1 && drawn_box.j1 >= band_j0) {
      for (int j = std::max(band_j0, drawn_box.j0); j <= std::min(band_j1, drawn_box.j1); ++j) {
        float* row = depth + static_cast<size_t>(j) * camera.width;
        std::fill(row + drawn_box.i0, row + drawn_box.i1 + 1, 1.0f);
      }
    }
    for (const TriangleSetup* setup : band_triangles[static_cast<size_t>(band)]) {
      const TriangleSetup& ts = *setup;
      const auto& tri = model_.triangles[ts.triangle];
      const double* ox = ts.ox;
      const double* oy = ts.oy;
      const int* order = ts.order;
      // Per edge, the coverage function's step along a row, and the unsnapped plane's terms in
      // the triangle's own corner order: the same operations on the same values as evaluating
      // each pixel afresh (snapped coordinates are multiples of 1/kSubpixel, so the edge
      // functions and their steps are exact in double and stepping changes no pixel).
      double step[3];
      for (int e = 0; e < 3; ++e) step[e] = oy[(e + 2) % 3] - oy[(e + 1) % 3];
      // Indexed by the corner whose weight the edge gives (order[e]), so each pixel writes its
      // weights straight into registers: stored through order[], they were reloaded as a pair,
      // and the store-to-load forwarding stall was the pass's hottest instruction.
      double plane_dx[3], plane_dy[3], plane_x[3], plane_y[3];
      for (int e = 0; e < 3; ++e) {
        const int a = order[(e + 1) % 3], b = order[(e + 2) % 3];
        const int k = order[e];
        plane_dx[k] = ts.ux[b] - ts.ux[a];
        plane_dy[k] = ts.uy[b] - ts.uy[a];
        plane_x[k] = ts.ux[a];
        plane_y[k] = ts.uy[a];
      }
      // Reciprocals taken once per triangle: a pixel multiplies instead of dividing (a dozen
      // double divisions per pixel were most of the pass's time).
      const double inv_area2 = 1.0 / ts.exact_area2;
      const double inv_z[3] = {1.0 / ts.z[0], 1.0 / ts.z[1], 1.0 / ts.z[2]};
      // The corners' attributes, as the interpolation reads them (in double).
      Eigen::Vector3d corner_x[3], corner_n[3], corner_c[3];
      for (int k = 0; k < 3; ++k) {
        corner_x[k] = state.camera_positions.segment<3>(3 * tri[k]).cast<double>();
        if (options.normals) corner_n[k] = state.camera_normals.segment<3>(3 * tri[k]).cast<double>();
        if (options.colors) corner_c[k] = state.colors.segment<3>(3 * tri[k]).cast<double>();
      }
      for (int j = std::max(ts.j0, band_j0); j <= std::min(ts.j1, band_j1); ++j) {
        const double py = j + 0.5;
        double row_term[3];  // the weights' part that is the same along the row
        for (int k = 0; k < 3; ++k) row_term[k] = plane_dx[k] * (py - plane_y[k]);
        double w[3];
        {
          const double px = ts.i0 + 0.5;
          for (int e = 0; e < 3; ++e) {
            const int a = (e + 1) % 3, b = (e + 2) % 3;
            w[e] = (ox[b] - ox[a]) * (py - oy[a]) - (oy[b] - oy[a]) * (px - ox[a]);
          }
        }
        bool entered = false;
        for (int i = ts.i0; i <= ts.i1; ++i, w[0] -= step[0], w[1] -= step[1], w[2] -= step[2]) {
          const bool inside = (w[0] > 0.0 || (w[0] == 0.0 && ts.top_left[0])) &&
                              (w[1] > 0.0 || (w[1] == 0.0 && ts.top_left[1])) &&
                              (w[2] > 0.0 || (w[2] == 0.0 && ts.top_left[2]));
          if (!inside) {
            if (entered) break;  // a triangle's pixels on a row are one run
            continue;
          }
          entered = true;
          const double px = i + 0.5;
          // Screen-space weights back in the triangle's own corner order, from the unsnapped
          // positions: the snap decides coverage, attribute interpolation uses the exact plane.
          double lambda[3];
          for (int k = 0; k < 3; ++k) lambda[k] = (row_term[k] - plane_dy[k] * (px - plane_x[k])) * inv_area2;
          const double dz = lambda[0] * ts.d[0] + lambda[1] * ts.d[1] + lambda[2] * ts.d[2];
          const float depth_value = static_cast<float>(dz);
          const size_t pix = static_cast<size_t>(j) * camera.width + i;
          if (!(depth_value < depth[pix])) continue;
          depth[pix] = depth_value;
          double b[3], sum = 0.0;
          for (int k = 0; k < 3; ++k) {
            b[k] = lambda[k] * inv_z[k];
            sum += b[k];
          }
          const double inv_sum = 1.0 / sum;
          for (int k = 0; k < 3; ++k) b[k] *= inv_sum;
          Eigen::Vector3d x = Eigen::Vector3d::Zero();
          for (int k = 0; k < 3; ++k) x += b[k] * corner_x[k];
          if (options.colors) {
            Eigen::Vector3d col = Eigen::Vector3d::Zero();
            for (int k = 0; k < 3; ++k) col += b[k] * corner_c[k];
            for (int c = 0; c < 3; ++c) g.color[3 * pix + c] = static_cast<float>(col[c]);
          }  // else zero, as the band's clear above left it
          if (options.normals) {
            Eigen::Vector3d nrm = Eigen::Vector3d::Zero();
            for (int k = 0; k < 3; ++k) nrm += b[k] * corner_n[k];
            const double len = nrm.norm();
            if (len > 0.0) nrm *= 1.0 / len;
            for (int c = 0; c < 3; ++c) g.normal[3 * pix + c] = static_cast<float>(nrm[c]);
          }  // else zero, as the band's clear above left it
          for (int c = 0; c < 3; ++c) {
            g.position[3 * pix + c] = static_cast<float>(x[c]);
            g.barycentric[3 * pix + c] = static_cast<float>(b[c]);
            g.vertices[3 * pix + c] = tri[c];
          }
          g.triangle[pix] = ts.triangle;
        }
      }
    }
  });
  drawn_box.triangle_data = g.triangle.data();
  g.drawn = drawn_box;
}

}  // namespace face_reenact::gpu
