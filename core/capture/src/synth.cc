// Head-and-shoulders model, background room, rendering and compositing of synthetic recordings.
#include "face_reenact/capture/synth.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <set>

#include <Eigen/Geometry>
#include <opencv2/imgproc.hpp>

#include "face_reenact/common/error.h"
#include "face_reenact/common/timing.h"
#include "face_reenact/gpu/context.h"
#include "face_reenact/gpu/renderer.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/model/makehuman_formats.h"

namespace face_reenact::capture {
namespace {

using Clock = std::chrono::steady_clock;

double value_noise(uint64_t key, double u, double v) {
  const double fu = std::floor(u), fv = std::floor(v);
  const double a = u - fu, b = v - fv;
  auto at = [&](double x, double y) {
    return uniform01(hash_key(key, static_cast<uint64_t>(static_cast<int64_t>(x)), static_cast<uint64_t>(static_cast<int64_t>(y))));
  };
  const double sa = a * a * (3 - 2 * a), sb = b * b * (3 - 2 * b);
  return (1 - sb) * ((1 - sa) * at(fu, fv) + sa * at(fu + 1, fv)) + sb * ((1 - sa) * at(fu, fv + 1) + sa * at(fu + 1, fv + 1));
}

float dist_to_segment(const Eigen::Vector3f& p, const Eigen::Vector3f& a, const Eigen::Vector3f& b) {
  const Eigen::Vector3f ab = b - a;
  const float t = std::clamp((p - a).dot(ab) / std::max(ab.squaredNorm(), 1e-12f), 0.0f, 1.0f);
  return (a + t * ab - p).norm();
}

bool inside_polygon_xy(const Eigen::Vector3f& p, const std::vector<Eigen::Vector3f>& poly) {
  bool in = false;
  for (size_t i = 0, j = poly.size() - 1; i < poly.size(); j = i++) {
    const auto& a = poly[i];
    const auto& b = poly[j];
    if ((a.y() > p.y()) != (b.y() > p.y()) && p.x() < (b.x() - a.x()) * (p.y() - a.y()) / (b.y() - a.y()) + a.x()) in = !in;
  }
  return in;
}

}  // namespace

// ------------------------------------------------------------------ body model

bool BodyModelOptions::IsValid(std::string* why) const {
  if (!(torso_cut_dm > -8 && torso_cut_dm < 5.5)) return fail_why(why, "torso_cut_dm must be in (-8, 5.5)");
  if (!(blend_dm > 0.05 && blend_dm < 10)) return fail_why(why, "blend_dm must be in (0.05, 10)");
  return true;
}

Appearance random_appearance(uint64_t seed) {
  // Mostly dark hair, as in most of the population; one blond and one grey shade.
  static const Eigen::Vector3f kHair[] = {{0.02f, 0.015f, 0.012f}, {0.05f, 0.03f, 0.018f}, {0.10f, 0.06f, 0.03f},
                                          {0.30f, 0.21f, 0.11f},   {0.22f, 0.21f, 0.20f}};
  static const Eigen::Vector3f kCloth[] = {{0.05f, 0.07f, 0.16f}, {0.40f, 0.40f, 0.42f}, {0.45f, 0.08f, 0.07f},
                                           {0.06f, 0.20f, 0.10f}, {0.03f, 0.03f, 0.03f}, {0.55f, 0.50f, 0.40f}};
  Appearance a;
  a.hair = kHair[static_cast<int>(uniform01(hash_key(seed, 301)) * 5) % 5];
  a.clothing = kCloth[static_cast<int>(uniform01(hash_key(seed, 302)) * 6) % 6];
  a.eyebrow_strength = 0.6 + 0.3 * uniform01(hash_key(seed, 303));
  return a;
}

BodyModel build_body_model(const FaceModel& model, const std::string& hm08_obj, const Appearance& appearance,
                           const BodyModelOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw Error("body model: " + why);
  if (!model.IsValid(&why)) throw Error("body model: invalid face model: " + why);
  const BaseMesh mesh = parse_obj(hm08_obj, "base.obj");
  const int nb = static_cast<int>(mesh.positions.size());
  const int body_group = mesh.group_index("body");
  if (body_group < 0) throw Error("base.obj has no 'body' group");
  const int n = model.num_vertices();
  std::vector<int32_t> model_of(static_cast<size_t>(nb), -1);
  for (int i = 0; i < n; ++i) {
    const int b = model.base_vertex[static_cast<size_t>(i)];
    if (b < 0 || b >= nb) throw Error("face model vertex " + std::to_string(i) + " maps to hm08 vertex " + std::to_string(b) +
                                      ", outside base.obj (" + std::to_string(nb) + " vertices): model and mesh do not match");
    model_of[static_cast<size_t>(b)] = i;
  }
  // Skin vertices of the model: the correspondences for the similarity transform and the
  // sources of the extended deformation.
  std::vector<int> skin;
  for (int i = 0; i < n; ++i)
    if (static_cast<int>(model.vertex_part[static_cast<size_t>(i)]) <= static_cast<int>(FacePart::Neck)) skin.push_back(i);
  if (skin.size() < 10) throw Error("face model has too few skin vertices");
  Eigen::Matrix3Xf src(3, skin.size()), dst(3, skin.size());
  for (size_t k = 0; k < skin.size(); ++k) {
    src.col(static_cast<int>(k)) = mesh.positions[static_cast<size_t>(model.base_vertex[static_cast<size_t>(skin[k])])];
    dst.col(static_cast<int>(k)) = model.mean_shape.segment<3>(3 * skin[k]);
  }
  const Eigen::Matrix4f sim = Eigen::umeyama(src, dst, true);
  auto to_model = [&](const Eigen::Vector3f& p) { return Eigen::Vector3f((sim * p.homogeneous()).head<3>()); };
  // The extra vertices: body vertices above the torso cut not in the model.
  std::set<int> body_vertices;
  for (const auto& f : mesh.faces)
    if (f.group == body_group) body_vertices.insert(f.vertices.begin(), f.vertices.end());
  std::vector<int> extra_base;
  std::vector<int32_t> index_of(static_cast<size_t>(nb), -1);
  for (int i = 0; i < n; ++i) index_of[static_cast<size_t>(model.base_vertex[static_cast<size_t>(i)])] = i;
  for (int v : body_vertices)
    if (model_of[static_cast<size_t>(v)] < 0 && mesh.positions[static_cast<size_t>(v)].y() > options.torso_cut_dm) {
      index_of[static_cast<size_t>(v)] = n + static_cast<int>(extra_base.size());
      extra_base.push_back(v);
    }
  const int ne = static_cast<int>(extra_base.size());
  const int nt = n + ne;

  BodyModel out;
  out.face_vertices = n;
  gpu::RenderModel& r = out.render;
  r.triangles = model.triangles;
  for (const auto& f : mesh.faces) {
    if (f.group != body_group) continue;
    bool all = true, any_extra = false;
    for (int v : f.vertices) {
      all = all && index_of[static_cast<size_t>(v)] >= 0;
      any_extra = any_extra || index_of[static_cast<size_t>(v)] >= n;
    }
    if (!all || !any_extra) continue;  // faces fully inside the model are already there
    for (size_t c = 1; c + 1 < f.vertices.size(); ++c)
      r.triangles.push_back({index_of[static_cast<size_t>(f.vertices[0])], index_of[static_cast<size_t>(f.vertices[c])],
                             index_of[static_cast<size_t>(f.vertices[c + 1])]});
  }
  const int kid = model.num_identity(), kexp = model.num_expression(), kalb = model.num_albedo();
  r.vertex_part.resize(static_cast<size_t>(nt));
  r.mean_shape.resize(3 * nt);
  r.identity_basis.setZero(3 * nt, kid);
  r.expression_basis.setZero(3 * nt, kexp);
  r.mean_albedo.resize(3 * nt);
  r.albedo_basis.setZero(3 * nt, kalb);
  r.mean_shape.head(3 * n) = model.mean_shape;
  r.identity_basis.topRows(3 * n) = model.identity_basis;
  r.expression_basis.topRows(3 * n) = model.expression_basis;
  r.mean_albedo.head(3 * n) = model.mean_albedo;
  r.albedo_basis.topRows(3 * n) = model.albedo_basis;
  out.material.assign(static_cast<size_t>(nt), Material::Skin);
  for (int i = 0; i < n; ++i) {
    const FacePart p = model.vertex_part[static_cast<size_t>(i)];
    r.vertex_part[static_cast<size_t>(i)] = static_cast<uint8_t>(p);
    out.material[static_cast<size_t>(i)] = p == FacePart::Scalp                                ? Material::Hair
                                           : p == FacePart::LeftEye || p == FacePart::RightEye ? Material::Eye
                                           : p >= FacePart::UpperTeeth                         ? Material::Mouth
                                                                                               : Material::Skin;
  }
  // Extra vertices: inverse-distance weights of the 6 nearest skin vertices (hm08 space).
  constexpr int kNearest = 6;
  for (int e = 0; e < ne; ++e) {
    const Eigen::Vector3f p = mesh.positions[static_cast<size_t>(extra_base[static_cast<size_t>(e)])];
    std::array<std::pair<float, int>, kNearest> best;
    best.fill({1e30f, -1});
    for (int s : skin) {
      const float d = (mesh.positions[static_cast<size_t>(model.base_vertex[static_cast<size_t>(s)])] - p).squaredNorm();
      if (d < best.back().first) {
        best.back() = {d, s};
        std::sort(best.begin(), best.end());
      }
    }
    const int row = 3 * (n + e);
    const float nearest_dm = std::sqrt(best[0].first);
    const float falloff = static_cast<float>(1.0 - smoothstep01(nearest_dm / options.blend_dm));
    Eigen::Vector3f residual = Eigen::Vector3f::Zero(), albedo = Eigen::Vector3f::Zero();
    float wsum = 0;
    for (const auto& [d2, s] : best) {
      const float w = 1.0f / (d2 + 1e-4f);
      wsum += w;
    }
    for (const auto& [d2, s] : best) {
      const float w = 1.0f / (d2 + 1e-4f) / wsum;
      const Eigen::Vector3f base_model = to_model(mesh.positions[static_cast<size_t>(model.base_vertex[static_cast<size_t>(s)])]);
      residual += w * (model.mean_shape.segment<3>(3 * s) - base_model);
      r.identity_basis.middleRows(row, 3) += w * falloff * model.identity_basis.middleRows(3 * s, 3);
      r.expression_basis.middleRows(row, 3) += w * falloff * model.expression_basis.middleRows(3 * s, 3);
      albedo += w * model.mean_albedo.segment<3>(3 * s);
      r.albedo_basis.middleRows(row, 3) += w * model.albedo_basis.middleRows(3 * s, 3);
    }
    r.mean_shape.segment<3>(row) = to_model(p) + falloff * residual;
    r.vertex_part[static_cast<size_t>(n + e)] = static_cast<uint8_t>(FacePart::Neck);
    // A crew-neck shirt: clothing below the base of the neck (lower at the front).
    const bool front = p.z() > 0.3f;
    const float neckline = front ? 5.05f + 0.35f * std::min(1.0f, std::abs(p.x()) / 0.9f) : 5.45f;
    if (p.y() < neckline) {
      out.material[static_cast<size_t>(n + e)] = Material::Clothing;
      r.albedo_basis.middleRows(row, 3).setZero();
      const float weave = 0.92f + 0.16f * static_cast<float>(uniform01(hash_key(static_cast<uint64_t>(e), 77)));
      r.mean_albedo.segment<3>(row) = appearance.clothing * weave;
    } else {
      r.mean_albedo.segment<3>(row) = albedo;
    }
  }
  // Hair on the scalp, eyebrows and lip colour on the face (the model's albedo is skin only).
  std::vector<Eigen::Vector3f> lm(kNumLandmarks);
  for (const auto& l : model.landmarks) lm[static_cast<size_t>(l.ibug_index)] = model.mean_shape.segment<3>(3 * l.vertex);
  std::vector<Eigen::Vector3f> outer_lip(lm.begin() + 48, lm.begin() + 60);
  const float brow_half_width = 0.0045f;
  for (int i = 0; i < n; ++i) {
    const int row = 3 * i;
    const Eigen::Vector3f v = model.mean_shape.segment<3>(row);
    if (out.material[static_cast<size_t>(i)] == Material::Hair) {
      const float strand = 0.8f + 0.4f * static_cast<float>(uniform01(hash_key(static_cast<uint64_t>(i), 78)));
      r.mean_albedo.segment<3>(row) = appearance.hair * strand;
      r.albedo_basis.middleRows(row, 3).setZero();
      continue;
    }
    if (model.vertex_part[static_cast<size_t>(i)] != FacePart::Face) continue;
    float brow = 1e9f;
    for (int a = 17; a < 26; ++a)
      if (a != 21) brow = std::min(brow, dist_to_segment(v, lm[static_cast<size_t>(a)], lm[static_cast<size_t>(a + 1)]));
    if (brow < 2 * brow_half_width) {
      const float w = static_cast<float>(appearance.eyebrow_strength * (1.0 - smoothstep01((brow - brow_half_width) / brow_half_width)));
      r.mean_albedo.segment<3>(row) = (1 - w) * r.mean_albedo.segment<3>(row) + w * appearance.hair;
    }
    if (v.z() > lm[33].z() - 0.03f && inside_polygon_xy(v, outer_lip)) {
      const Eigen::Vector3f a = r.mean_albedo.segment<3>(row);
      r.mean_albedo.segment<3>(row) = Eigen::Vector3f(a.x() * 0.95f, a.y() * 0.6f, a.z() * 0.65f);
    }
  }
  r.IndexExpression();
  if (!r.IsValid(&why)) throw Error("body model: " + why);
  return out;
}

// ------------------------------------------------------------------ background

BackgroundScene random_background(uint64_t seed) {
  auto u = [&](uint64_t k) { return static_cast<float>(uniform01(hash_key(seed, 400 + k))); };
  BackgroundScene s;
  const float back = 2.3f + 0.8f * u(1);
  const float left = 1.0f + 0.5f * u(2);
  const float floor_y = 1.1f + 0.2f * u(3);
  const float ceiling_y = -1.3f;
  const Eigen::Vector3f wall_colour = Eigen::Vector3f(0.55f, 0.52f, 0.45f) + 0.15f * Eigen::Vector3f(u(4), u(5), u(6));
  const float big = 100.0f;
  auto plane = [&](Eigen::Vector3f point, Eigen::Vector3f normal, Eigen::Vector3f u_axis, Eigen::Vector2f lo,
                   Eigen::Vector2f hi, Eigen::Vector3f albedo, int texture) {
    BackgroundScene::Plane p;
    p.point = point;
    p.normal = normal.normalized();
    p.u_axis = u_axis.normalized();
    p.v_axis = p.normal.cross(p.u_axis);
    p.extent_min = lo;
    p.extent_max = hi;
    p.albedo = albedo;
    p.texture = texture;
    s.planes.push_back(p);
  };
  // Back wall, left wall (seen at grazing angles near the camera), floor, ceiling.
  plane({0, 0, back}, {0, 0, -1}, {1, 0, 0}, {-big, -big}, {big, big}, wall_colour, 0);
  plane({-left, 0, 0}, {1, 0, 0}, {0, 0, 1}, {-big, -big}, {big, big}, wall_colour * 0.9f, 0);
  plane({0, floor_y, 0}, {0, -1, 0}, {1, 0, 0}, {-big, -big}, {big, big}, Eigen::Vector3f(0.35f, 0.25f, 0.16f), 1);
  plane({0, ceiling_y, 0}, {0, 1, 0}, {1, 0, 0}, {-big, -big}, {big, big}, Eigen::Vector3f(0.75f, 0.75f, 0.72f), 0);
  // A picture on the back wall.
  const float px = -0.6f + 0.5f * u(7), py = -0.55f + 0.2f * u(8);
  plane({px, py, back - 0.02f}, {0, 0, -1}, {1, 0, 0}, {0, 0}, {0.6f + 0.3f * u(9), 0.45f}, Eigen::Vector3f(0.5f, 0.4f, 0.3f), 2);
  // A cabinet/shelf on the right: front, top and left side.
  const float cx0 = 0.45f + 0.3f * u(10), cw = 0.5f + 0.3f * u(11), cd = 0.4f, ctop = floor_y - 0.9f - 0.5f * u(12);
  const float cz = back - cd - 0.05f - 0.6f * u(13);
  const Eigen::Vector3f wood(0.42f, 0.26f, 0.14f);
  // (v_axis = normal x u_axis: up on planes facing the camera, away from it on the top.)
  plane({cx0, ctop, cz}, {0, 0, -1}, {1, 0, 0}, {0, -(floor_y - ctop)}, {cw, 0}, wood, 1);
  plane({cx0, ctop, cz}, {0, -1, 0}, {1, 0, 0}, {0, 0}, {cw, cd}, wood * 1.1f, 1);
  plane({cx0, ctop, cz}, {-1, 0, 0}, {0, 0, 1}, {0, 0}, {cd, floor_y - ctop}, wood * 0.9f, 1);
  // A door-like panel on the left part of the back wall.
  plane({-left + 0.2f + 0.2f * u(14), floor_y, back - 0.03f}, {0, 0, -1}, {1, 0, 0}, {0, 0}, {0.8f, floor_y + 0.9f},
        Eigen::Vector3f(0.7f, 0.68f, 0.62f), 3);
  return s;
}

BackgroundImage render_background(const BackgroundScene& scene, const gpu::PinholeCamera& cam) {
  BackgroundImage img;
  img.depth = cv::Mat(cam.height, cam.width, CV_32FC1, cv::Scalar(0));
  img.normal = cv::Mat(cam.height, cam.width, CV_32FC3, cv::Scalar(0, 0, -1));
  img.albedo = cv::Mat(cam.height, cam.width, CV_32FC3, cv::Scalar(0, 0, 0));
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      const Eigen::Vector3f d((x - cam.cx) / cam.fx, (y - cam.cy) / cam.fy, 1.0f);  // z = 1: t is the depth
      float best = 1e30f;
      const BackgroundScene::Plane* hit = nullptr;
      Eigen::Vector2f hit_uv;
      for (const auto& p : scene.planes) {
        const float dn = d.dot(p.normal);
        if (dn >= -1e-6f) continue;  // seen from behind or edge-on
        const float t = p.point.dot(p.normal) / dn;
        if (!(t > 0.05f) || t >= best) continue;
        const Eigen::Vector3f q = t * d - p.point;
        const Eigen::Vector2f uv(q.dot(p.u_axis), q.dot(p.v_axis));
        if ((uv.array() < p.extent_min.array()).any() || (uv.array() > p.extent_max.array()).any()) continue;
        best = t;
        hit = &p;
        hit_uv = uv;
      }
      if (!hit) continue;
      // Planes lying exactly on a wall win by being drawn slightly in front (pictures, doors).
      Eigen::Vector3f a = hit->albedo;
      const uint64_t tex_key = static_cast<uint64_t>(hit - scene.planes.data());
      const double un = hit_uv.x(), vn = hit_uv.y();
      switch (hit->texture) {
        case 0: a *= static_cast<float>(0.94 + 0.06 * value_noise(tex_key, un * 20, vn * 20) + 0.03 * value_noise(tex_key + 9, un * 3, vn * 3)); break;
        case 1: a *= static_cast<float>(0.8 + 0.12 * std::sin(un * 90 + 6 * value_noise(tex_key, un * 2, vn * 8)) + 0.08 * value_noise(tex_key + 3, un * 40, vn * 4)); break;
        case 2: {
          const uint64_t cell = hash_key(tex_key, static_cast<uint64_t>(std::floor(un * 9)), static_cast<uint64_t>(std::floor(vn * 7)));
          const bool frame = un < 0.03 || vn < 0.03 || un > hit->extent_max.x() - 0.03 || vn > hit->extent_max.y() - 0.03;
          a = frame ? Eigen::Vector3f(0.05f, 0.04f, 0.03f)
                    : Eigen::Vector3f(float(0.1 + 0.7 * uniform01(cell)), float(0.1 + 0.6 * uniform01(cell + 1)),
                                      float(0.1 + 0.6 * uniform01(cell + 2))) *
                          float(0.8 + 0.2 * value_noise(tex_key, un * 30, vn * 30));
          break;
        }
        case 3: {
          const bool panel_edge = std::fmod(std::abs(vn) + 0.02, 0.5) < 0.03 || un < 0.04 || un > 0.76;
          a *= panel_edge ? 0.75f : 1.0f;
          break;
        }
        default: break;
      }
      img.depth.at<float>(y, x) = best;
      img.normal.at<cv::Vec3f>(y, x) = cv::Vec3f(hit->normal.x(), hit->normal.y(), hit->normal.z());
      img.albedo.at<cv::Vec3f>(y, x) = cv::Vec3f(a.x(), a.y(), a.z());
    }
  return img;
}

// ------------------------------------------------------------------ synthesiser

bool SynthOptions::IsValid(std::string* why) const {
  if (frames < 1 || frames > 1000000) return fail_why(why, "frames must be in 1..1000000");
  if (width < 16 || height < 16 || width > 4096 || height > 4096) return fail_why(why, "size must be within 16x16..4096x4096");
  if (!(fps > 0 && fps <= 240)) return fail_why(why, "fps must be in (0, 240]");
  if (supersample < 1 || supersample > 4) return fail_why(why, "supersample must be in 1..4");
  std::string w;
  if (!sensor.IsValid(&w)) return fail_why(why, "sensor: " + w);
  if (!body.IsValid(&w)) return fail_why(why, "body: " + w);
  return true;
}

gpu::PinholeCamera SynthOptions::camera() const {
  gpu::PinholeCamera c;
  const float s = static_cast<float>(width) / 640.0f;
  c.width = width;
  c.height = height;
  c.fx = c.fy = 525.0f * s;
  c.cx = 0.5f * static_cast<float>(width) - 0.5f;
  c.cy = 0.5f * static_cast<float>(height) - 0.5f;
  return c;
}

struct Synthesizer::Impl {
  Impl(const gpu::Context& context, const gpu::RenderModel& model) : renderer(context, model) {}
  gpu::Renderer renderer;
  gpu::PinholeCamera camera_ss;
  BackgroundImage background;  // at supersampled resolution
  std::unique_ptr<SensorModel> sensor;
  cv::Mat composite_depth_ss;  // of the last frame (landmark visibility)
};

Synthesizer::Synthesizer(const gpu::Context& context, const FaceModel& model, const std::string& hm08_obj,
                         const SynthOptions& options, SynthIdentity identity, Timeline timeline)
    : options_(options), model_(model), identity_(std::move(identity)), timeline_(std::move(timeline)) {
  std::string why;
  if (!options.IsValid(&why)) throw Error("synth: " + why);
  if (identity_.alpha.size() > model.num_identity() || identity_.beta.size() > model.num_albedo())
    throw Error("synth: identity has more coefficients than the model");
  if (model.num_expression() != 52) throw Error("synth: the face model must have the 52 ARKit blendshapes");
  camera_ = options.camera();
  body_ = build_body_model(model, hm08_obj, random_appearance(options.seed), options.body);
  impl_ = std::make_unique<Impl>(context, body_.render);
  const int ss = options.supersample;
  gpu::PinholeCamera& c = impl_->camera_ss;
  c = camera_;
  c.width = camera_.width * ss;
  c.height = camera_.height * ss;
  c.fx = camera_.fx * ss;
  c.fy = camera_.fy * ss;
  c.cx = (camera_.cx + 0.5f) * ss - 0.5f;
  c.cy = (camera_.cy + 0.5f) * ss - 0.5f;
  impl_->background = render_background(random_background(options.seed), c);
  impl_->sensor = std::make_unique<SensorModel>(options.sensor, options.seed, options.fps);
}

Synthesizer::~Synthesizer() = default;

gpu::FaceParameters Synthesizer::parameters(int index) const {
  const PerformanceState s = timeline_.at(index / options_.fps);
  gpu::FaceParameters p;
  p.alpha = identity_.alpha;
  p.beta = identity_.beta;
  p.delta = s.expression;
  p.gamma = sh_from_light(s.light);
  p.euler = s.euler();
  p.translation = s.translation;
  return p;
}

RgbdFrame Synthesizer::render(int index, SynthFrameTimes* times) {
  if (index < 0) throw Error("synth: negative frame index");
  SynthFrameTimes local;
  SynthFrameTimes& tm = times ? *times : local;
  const gpu::FaceParameters params = parameters(index);
  auto t0 = Clock::now();
  gpu::RenderOptions ro;
  ro.parts = gpu::kAllParts;
  ro.cull_back_faces = true;
  impl_->renderer.render(params, impl_->camera_ss, ro);
  const gpu::GBuffer g = impl_->renderer.read_gbuffer();
  tm.render_ms = ms_since(t0);

  // Composite head over background at the supersampled resolution.
  t0 = Clock::now();
  const gpu::PinholeCamera& cs = impl_->camera_ss;
  const BackgroundImage& bg = impl_->background;
  cv::Mat color_ss(cs.height, cs.width, CV_32FC3), depth_ss(cs.height, cs.width, CV_32FC1), cos_ss(cs.height, cs.width, CV_32FC1);
  for (int y = 0; y < cs.height; ++y)
    for (int x = 0; x < cs.width; ++x) {
      const size_t p = static_cast<size_t>(y) * cs.width + x;
      const Eigen::Vector3f ray = Eigen::Vector3f((x - cs.cx) / cs.fx, (y - cs.cy) / cs.fy, 1.0f).normalized();
      const float zb = bg.depth.at<float>(y, x);
      const float zh = g.triangle[p] >= 0 ? g.position[3 * p + 2] : 0.0f;
      if (zh > 0 && (zb <= 0 || zh < zb)) {
        color_ss.at<cv::Vec3f>(y, x) = cv::Vec3f(g.color[3 * p], g.color[3 * p + 1], g.color[3 * p + 2]);
        depth_ss.at<float>(y, x) = zh;
        const Eigen::Vector3f nrm(g.normal[3 * p], g.normal[3 * p + 1], g.normal[3 * p + 2]);
        cos_ss.at<float>(y, x) = std::abs(nrm.dot(ray));
      } else {
        const cv::Vec3f n = bg.normal.at<cv::Vec3f>(y, x);
        const cv::Vec3f a = bg.albedo.at<cv::Vec3f>(y, x);
        const auto sh = gpu::sh_basis(Eigen::Vector3f(n[0], n[1], n[2]));
        cv::Vec3f c;
        for (int ch = 0; ch < 3; ++ch) {
          float e = 0;
          for (int k = 0; k < 9; ++k) e += params.gamma[static_cast<size_t>(ch * 9 + k)] * sh[static_cast<size_t>(k)];
          c[ch] = a[ch] * std::max(0.0f, e);
        }
        color_ss.at<cv::Vec3f>(y, x) = c;
        depth_ss.at<float>(y, x) = zb;
        cos_ss.at<float>(y, x) = std::abs(Eigen::Vector3f(n[0], n[1], n[2]).dot(ray));
      }
    }
  // Box-filter down to the output resolution; depth from the majority surface of each block.
  const int ss = options_.supersample;
  IdealFrame ideal;
  cv::resize(color_ss, ideal.linear_rgb, cv::Size(camera_.width, camera_.height), 0, 0, cv::INTER_AREA);
  ideal.depth = cv::Mat(camera_.height, camera_.width, CV_32FC1, cv::Scalar(0));
  ideal.view_cosine = cv::Mat(camera_.height, camera_.width, CV_32FC1, cv::Scalar(0));
  std::vector<std::pair<float, float>> samples;
  for (int y = 0; y < camera_.height; ++y)
    for (int x = 0; x < camera_.width; ++x) {
      samples.clear();
      for (int dy = 0; dy < ss; ++dy)
        for (int dx = 0; dx < ss; ++dx) {
          const float z = depth_ss.at<float>(y * ss + dy, x * ss + dx);
          if (z > 0) samples.emplace_back(z, cos_ss.at<float>(y * ss + dy, x * ss + dx));
        }
      if (samples.size() * 2 < static_cast<size_t>(ss * ss)) continue;
      std::sort(samples.begin(), samples.end());
      // Split at the largest gap above 3 cm; keep the larger group (the nearer one on ties).
      size_t split = samples.size();
      float gap = 0.03f;
      for (size_t i = 1; i < samples.size(); ++i)
        if (samples[i].first - samples[i - 1].first > gap) {
          gap = samples[i].first - samples[i - 1].first;
          split = i;
        }
      const size_t b0 = split == samples.size() || split * 2 >= samples.size() ? 0 : split;
      const size_t b1 = b0 == 0 ? split : samples.size();
      float z = 0, c = 0;
      for (size_t i = b0; i < b1; ++i) {
        z += samples[i].first;
        c += samples[i].second;
      }
      ideal.depth.at<float>(y, x) = z / static_cast<float>(b1 - b0);
      ideal.view_cosine.at<float>(y, x) = c / static_cast<float>(b1 - b0);
    }
  impl_->composite_depth_ss = depth_ss;
  tm.composite_ms = ms_since(t0);

  t0 = Clock::now();
  RgbdFrame frame;
  frame.index = index;
  frame.timestamp_s = index / options_.fps;
  frame.camera = camera_;
  frame.depth = impl_->sensor->measure_depth(ideal, camera_.fx, index);
  frame.color = impl_->sensor->measure_color(ideal, index);
  tm.sensor_ms = ms_since(t0);

  // Ground truth: P and the projected landmark vertices, visible where nothing lies in front.
  frame.ground_truth.params = params;
  std::array<LandmarkObservation, kNumLandmarks> lms;
  const Eigen::Matrix3f R = gpu::rotation_from_euler(params.euler);
  for (const auto& l : model_.landmarks) {
    const int row = 3 * l.vertex;
    Eigen::Vector3f v = model_.mean_shape.segment<3>(row);
    if (params.alpha.size() > 0)
      v += model_.identity_basis.block(row, 0, 3, params.alpha.size()) * params.alpha;
    v += model_.expression_basis.middleRows(row, 3) * params.delta;
    const Eigen::Vector3f X = R * v + params.translation;
    LandmarkObservation& o = lms[static_cast<size_t>(l.ibug_index)];
    if (X.z() <= 0) continue;
    o.pixel = Eigen::Vector2f(camera_.fx * X.x() / X.z() + camera_.cx, camera_.fy * X.y() / X.z() + camera_.cy);
    const int sx = static_cast<int>(std::lround((o.pixel.x() + 0.5f) * ss - 0.5f));
    const int sy = static_cast<int>(std::lround((o.pixel.y() + 0.5f) * ss - 0.5f));
    if (sx < 0 || sy < 0 || sx >= cs.width || sy >= cs.height) continue;
    const float zc = depth_ss.at<float>(sy, sx);
    o.visible = zc <= 0 || zc > X.z() - 0.01f;
  }
  frame.ground_truth.landmarks = lms;
  last_ideal_ = ideal;
  return frame;
}

SynthSummary write_synthetic_recording(Synthesizer& synth, const std::string& out_dir, bool overwrite,
                                       const std::string& generator,
                                       const std::function<void(const RgbdFrame&, int)>& on_frame) {
  const auto t0 = Clock::now();
  RecordingInfo info;
  info.camera = synth.camera();
  info.fps = synth.options().fps;
  info.has_depth = true;
  info.source = "synthetic";
  info.generator = generator;
  RecordingWriter::Options wo;
  wo.overwrite = overwrite;
  RecordingWriter writer(out_dir, info, wo);
  SynthSummary sum;
  const int n = synth.options().frames;
  for (int i = 0; i < n; ++i) {
    SynthFrameTimes t;
    RgbdFrame f = synth.render(i, &t);
    sum.mean_times.render_ms += t.render_ms / n;
    sum.mean_times.composite_ms += t.composite_ms / n;
    sum.mean_times.sensor_ms += t.sensor_ms / n;
    writer.write(f);
    if (on_frame) on_frame(f, n);
  }
  sum.output_dir = writer.finish();
  sum.frames = n;
  sum.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  return sum;
}

std::vector<int> contact_sheet_indices(int frames, int rows) {
  std::vector<int> out;
  if (frames < 1) return out;
  rows = std::clamp(rows, 1, frames);
  for (int r = 0; r < rows; ++r) out.push_back(rows == 1 ? 0 : static_cast<int>(static_cast<int64_t>(r) * (frames - 1) / (rows - 1)));
  return out;
}

cv::Mat contact_sheet(const std::vector<RgbdFrame>& frames, bool draw_landmarks) {
  if (frames.empty()) throw Error("contact sheet: no frames");
  std::vector<cv::Mat> lines;
  for (const RgbdFrame& f : frames) {
    if (f.color.type() != CV_8UC3 || f.color.size() != frames.front().color.size() ||
        (!f.depth.empty() && (f.depth.type() != CV_32FC1 || f.depth.size() != f.color.size())))
      throw Error("contact sheet: frames need 8-bit colour and depth of the same size");
    cv::Mat color = f.color.clone();
    cv::Mat depth_vis(color.size(), CV_8UC3, cv::Scalar(0, 0, 0));
    if (!f.depth.empty()) {
      cv::Mat scaled(f.depth.size(), CV_8UC1);
      for (int y = 0; y < f.depth.rows; ++y)
        for (int x = 0; x < f.depth.cols; ++x) {
          const float z = f.depth.at<float>(y, x);
          scaled.at<uint8_t>(y, x) = static_cast<uint8_t>(std::clamp(255.0 * (1.0 - (z - 0.4) / 3.6), 0.0, 255.0));
        }
      cv::applyColorMap(scaled, depth_vis, cv::COLORMAP_JET);
      for (int y = 0; y < f.depth.rows; ++y)
        for (int x = 0; x < f.depth.cols; ++x)
          if (!(f.depth.at<float>(y, x) > 0)) depth_vis.at<cv::Vec3b>(y, x) = cv::Vec3b(0, 0, 0);
    }
    if (draw_landmarks && f.ground_truth.landmarks)
      for (const auto& l : *f.ground_truth.landmarks)
        cv::circle(color, cv::Point(static_cast<int>(std::lround(l.pixel.x())), static_cast<int>(std::lround(l.pixel.y()))), 2,
                   l.visible ? cv::Scalar(0, 255, 0) : cv::Scalar(0, 0, 255), cv::FILLED);
    cv::putText(color, "frame " + std::to_string(f.index), cv::Point(8, 20), cv::FONT_HERSHEY_SIMPLEX, 0.5,
                cv::Scalar(255, 255, 255), 1);
    cv::Mat line;
    cv::hconcat(color, depth_vis, line);
    lines.push_back(line);
  }
  cv::Mat sheet;
  cv::vconcat(lines, sheet);
  return sheet;
}

}  // namespace face_reenact::capture
