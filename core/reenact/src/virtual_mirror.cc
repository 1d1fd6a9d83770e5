#include "face_reenact/reenact/virtual_mirror.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cmath>
#include <limits>
#include <fstream>
#include <sstream>
#include <vector>

#include <Eigen/Dense>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "face_reenact/common/error.h"
#include "face_reenact/common/parallel.h"
#include "face_reenact/common/srgb.h"
#include "face_reenact/common/timing.h"
#include "face_reenact/gpu/cpu_renderer.h"
#include "face_parts.h"
#include "image_sampling.h"
#include "shading.h"

namespace face_reenact::reenact {
namespace {

using Clock = std::chrono::steady_clock;
using internal::Gamma;

using internal::part_bit;

// A named region in the face's own frame: s across (in outer-eye-corner distances, 0 between the
// eyes, positive towards the person's left, the image's right), t down (in eye-line-to-mouth
// distances: 0 on the line through the outer eye corners, 1 at the mouth's centre).
struct RegionBox {
  FaceRegion region;
  const char* name;
  float s, t;            // centre
  float half_s, half_t;  // half extents
};
constexpr RegionBox kRegions[] = {
    {FaceRegion::kFace, "face", 0.0f, 0.3f, 0.75f, 1.45f},
    {FaceRegion::kForehead, "forehead", 0.0f, -0.8f, 0.5f, 0.3f},
    {FaceRegion::kNose, "nose", 0.0f, 0.45f, 0.13f, 0.35f},
    {FaceRegion::kLeftCheek, "left-cheek", 0.42f, 0.45f, 0.2f, 0.28f},
    {FaceRegion::kRightCheek, "right-cheek", -0.42f, 0.45f, 0.2f, 0.28f},
    {FaceRegion::kChin, "chin", 0.0f, 1.5f, 0.25f, 0.15f},
};

const RegionBox& region_box(FaceRegion r) {
  for (const RegionBox& b : kRegions)
    if (b.region == r) return b;
  return kRegions[0];
}

struct Preset {
  const char* name;
  Eigen::Vector3f direction, colour;
};
// Directions from the image's point of view (camera space: x right, y down, -z towards the camera),
// 60 degrees off the view axis for the side lights.
const Preset kPresets[] = {
    {"front", {0.f, 0.f, -1.f}, {1.f, 1.f, 1.f}},
    {"left", {-0.87f, 0.f, -0.5f}, {1.f, 1.f, 1.f}},
    {"right", {0.87f, 0.f, -0.5f}, {1.f, 1.f, 1.f}},
    {"top", {0.f, -0.87f, -0.5f}, {1.f, 1.f, 1.f}},
    {"bottom", {0.f, 0.87f, -0.5f}, {1.f, 1.f, 1.f}},
    {"warm", {0.f, -0.26f, -0.97f}, {1.f, 0.78f, 0.55f}},
    {"cool", {0.f, -0.26f, -0.97f}, {0.7f, 0.85f, 1.f}},
};

std::string preset_names() {
  std::string names;
  for (const Preset& p : kPresets) names += (names.empty() ? "" : ", ") + std::string(p.name);
  return names;
}

// The 9 SH coefficients of a unit light: irradiance ambient + (1 - ambient) * max(0, n . d),
// fitted in the renderer's own SH basis over normals spread evenly on the sphere (so the fit
// does not depend on the basis' normalisation).
std::array<float, 9> unit_light(const Eigen::Vector3f& direction, float ambient) {
  constexpr int kNormals = 600;
  Eigen::MatrixXd a(kNormals, 9);
  Eigen::VectorXd b(kNormals);
  const Eigen::Vector3f d = direction.normalized();
  const double golden = M_PI * (3.0 - std::sqrt(5.0));
  for (int i = 0; i < kNormals; ++i) {
    const double y = 1.0 - 2.0 * (i + 0.5) / kNormals, r = std::sqrt(1.0 - y * y), phi = golden * i;
    const Eigen::Vector3f n(static_cast<float>(r * std::cos(phi)), static_cast<float>(y), static_cast<float>(r * std::sin(phi)));
    const auto basis = gpu::sh_basis(n);
    for (int k = 0; k < 9; ++k) a(i, k) = basis[static_cast<size_t>(k)];
    b[i] = ambient + (1.0 - ambient) * std::max(0.0f, n.dot(d));
  }
  const Eigen::VectorXd c = a.colPivHouseholderQr().solve(b);
  std::array<float, 9> out{};
  for (int k = 0; k < 9; ++k) out[static_cast<size_t>(k)] = static_cast<float>(c[k]);
  return out;
}

// The preset's SH coefficients from its unit light (unit_light): each channel as bright towards
// the camera as `tracked`'s times the preset's colour.
Gamma preset_from_unit(const std::array<float, 9>& unit, const Eigen::Vector3f& colour, const Gamma& tracked) {
  const Gamma old_light = internal::rendering_lighting(tracked);
  const auto& facing = internal::camera_facing_basis();
  float unit_facing = 0.f;
  for (int k = 0; k < 9; ++k) unit_facing += unit[static_cast<size_t>(k)] * facing[static_cast<size_t>(k)];
  // The camera's exposure and white balance stay, the light's direction (and tint) change.
  Gamma out{};
  for (int c = 0; c < 3; ++c) {
    const float scale = unit_facing > 1e-6f ? internal::camera_facing_irradiance(old_light, c) * colour[c] / unit_facing : 0.f;
    for (int k = 0; k < 9; ++k) out[static_cast<size_t>(c * 9 + k)] = unit[static_cast<size_t>(k)] * scale;
  }
  return out;
}

}  // namespace

bool ParseFaceRegion(const std::string& name, FaceRegion* region) {
  for (const RegionBox& b : kRegions)
    if (name == b.name) {
      *region = b.region;
      return true;
    }
  return false;
}

const char* FaceRegionName(FaceRegion region) { return region_box(region).name; }

bool UvRect::IsValid(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  for (float x : {u0, v0, u1, v1})
    if (!std::isfinite(x) || x < 0.f || x > 1.f) return fail("UV coordinates must be within [0, 1]");
  if (!(u0 < u1 && v0 < v1)) return fail("a UV rectangle needs u0 < u1 and v0 < v1");
  return true;
}

bool MirrorLight::IsValid(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (kind == Kind::kPreset) {
    if (!direction.allFinite() || direction.norm() < 1e-6f) return fail("the light's direction must be a finite, nonzero vector");
    if (!colour.allFinite() || colour.minCoeff() < 0.f || colour.maxCoeff() <= 0.f)
      return fail("the light's colour must be finite, not negative, and not black");
    if (!(ambient_share >= 0.f && ambient_share <= 1.f)) return fail("the light's ambient share must be within [0, 1]");
  }
  if (kind == Kind::kCoefficients) {
    for (float g : gamma)
      if (!std::isfinite(g)) return fail("the light's SH coefficients must be finite");
    for (int c = 0; c < 3; ++c)
      if (!(gamma[static_cast<size_t>(c * 9)] > 0.f)) return fail("each channel's ambient (first) SH coefficient must be positive");
  }
  return true;
}

MirrorLight ParseLightPreset(const std::string& name) {
  for (const Preset& p : kPresets)
    if (name == p.name) {
      MirrorLight l;
      l.kind = MirrorLight::Kind::kPreset;
      l.name = p.name;
      l.direction = p.direction;
      l.colour = p.colour;
      return l;
    }
  throw Error("unknown light '" + name + "': give one of " + preset_names() + ", or a .json file with \"gamma\"");
}

MirrorLight ReadLightFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("cannot read the light file '" + path + "'");
  std::stringstream text;
  text << in.rdbuf();
  return ParseLightJson(text.str(), path);
}

MirrorLight ParseLightJson(const std::string& text, const std::string& name) {
  const std::string what = "the light file '" + name + "'";
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(text);
  } catch (const nlohmann::json::exception& e) {
    throw Error(what + " is not JSON: " + e.what());
  }
  if (!j.is_object() || !j.contains("gamma") || !j["gamma"].is_array())
    throw Error(what + " has no \"gamma\" array (27 SH coefficients, as in track's PARAMS.jsonl)");
  const auto& g = j["gamma"];
  if (g.size() != static_cast<size_t>(gpu::kNumShParameters))
    throw Error(what + " has " + std::to_string(g.size()) + " coefficients in \"gamma\", not 27");
  MirrorLight l;
  l.kind = MirrorLight::Kind::kCoefficients;
  l.name = name;
  for (size_t k = 0; k < g.size(); ++k) {
    if (!g[k].is_number()) throw Error(what + ": \"gamma\" holds something that is not a number");
    // A number beyond float's range has no float (casting it is undefined behaviour).
    const double value = g[k].get<double>();
    if (!(std::abs(value) <= std::numeric_limits<float>::max()))
      throw Error(what + ": \"gamma\" holds a number beyond a float's range");
    l.gamma[k] = static_cast<float>(value);
  }
  std::string why;
  if (!l.IsValid(&why)) throw Error(what + ": " + why);
  return l;
}

std::array<float, gpu::kNumShParameters> PresetCoefficients(const MirrorLight& light,
                                                            const std::array<float, gpu::kNumShParameters>& tracked) {
  return preset_from_unit(unit_light(light.direction, light.ambient_share), light.colour, tracked);
}

TexturePlacement ParseTexturePlacement(const std::string& at) {
  TexturePlacement p;
  if (at.rfind("uv:", 0) == 0) {
    UvRect r;
    char tail = 0;
    if (std::sscanf(at.c_str() + 3, "%f,%f,%f,%f%c", &r.u0, &r.v0, &r.u1, &r.v1, &tail) != 4)
      throw Error("texture placement '" + at + "': uv: needs four numbers, uv:U0,V0,U1,V1");
    std::string why;
    if (!r.IsValid(&why)) throw Error("texture placement '" + at + "': " + why);
    p.region.reset();
    p.uv = r;
    return p;
  }
  FaceRegion region;
  if (!ParseFaceRegion(at, &region)) {
    std::string names;
    for (const RegionBox& b : kRegions) names += (names.empty() ? "" : ", ") + std::string(b.name);
    throw Error("texture placement '" + at + "' is neither a region (" + names + ") nor uv:U0,V0,U1,V1");
  }
  p.region = region;
  return p;
}

MirrorLight ParseMirrorLight(const std::string& light) {
  if (light.empty()) return MirrorLight{};
  const std::string ext = light.size() >= 5 ? light.substr(light.size() - 5) : "";
  return ext == ".json" ? ReadLightFile(light) : ParseLightPreset(light);
}

MirrorOptions MirrorOptionsFromSettings(const std::string& texture, const std::string& at, float opacity,
                                        const std::string& light) {
  MirrorOptions o;
  if (!texture.empty()) {
    o.texture = cv::imread(texture, cv::IMREAD_UNCHANGED);
    if (o.texture.empty()) throw Error("the texture '" + texture + "' is not an image that can be read");
    if (o.texture.depth() == CV_16U) o.texture.convertTo(o.texture, CV_8U, 1.0 / 257.0);
    if (o.texture.depth() != CV_8U) throw Error("the texture '" + texture + "' is not an 8- or 16-bit image");
    if (o.texture.channels() == 1) cv::cvtColor(o.texture, o.texture, cv::COLOR_GRAY2BGR);
    if (o.texture.channels() == 2) throw Error("the texture '" + texture + "': grey with alpha is not supported");
    o.placement = ParseTexturePlacement(at);
  }
  o.opacity = opacity;
  o.light = ParseMirrorLight(light);
  std::string why;
  if (!o.IsValid(&why)) throw Error("virtual mirror: " + why);
  return o;
}

bool MirrorOptions::IsValid(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (!texture.empty() && texture.type() != CV_8UC4 && texture.type() != CV_8UC3)
    return fail("the texture must be an 8-bit colour image (with or without alpha)");
  if (!texture.empty() && (texture.cols < 2 || texture.rows < 2)) return fail("the texture must be at least 2x2 pixels");
  if (!placement.region && !placement.uv.IsValid(why)) return false;
  if (!(opacity >= 0.f && opacity <= 1.f)) return fail("the opacity must be within [0, 1]");
  if (!light.IsValid(why)) return false;
  if (relight_levels < 1 || relight_levels > 8) return fail("relight_levels must be within 1-8");
  if (!(depth_occluder_m >= 0.f && depth_occluder_m <= 1.f)) return fail("depth_occluder_m must be within [0, 1] metres");
  return true;
}

struct VirtualMirror::Impl {
  const FaceModel& model;
  MirrorOptions options;
  gpu::CpuRenderer renderer;
  // texture pixel (x, y) -> UV: uv = origin + x * axis_x + y * axis_y (continuous pixel
  // coordinates, 0 at the texture's top-left corner), and its inverse.
  Eigen::Vector2f origin = Eigen::Vector2f::Zero(), axis_x = Eigen::Vector2f::UnitX(), axis_y = Eigen::Vector2f::UnitY();
  Eigen::Matrix2f to_texture = Eigen::Matrix2f::Identity();
  cv::Mat texture_bgra;  // CV_8UC4
  // A preset's unit light, fitted once (a least-squares fit over 600 normals) rather than per frame.
  std::array<float, 9> preset_unit{};

  Impl(const FaceModel& m, MirrorOptions o)
      : model(m), options(std::move(o)), renderer(gpu::RenderModel::FromFaceModel(m)) {
    std::string why;
    if (!options.IsValid(&why)) throw Error("virtual mirror: " + why);
    if (options.light.kind == MirrorLight::Kind::kPreset)
      preset_unit = unit_light(options.light.direction, options.light.ambient_share);
    if (options.texture.empty()) return;
    if (model.corner_uvs.size() != 3 * model.triangles.size())
      throw Error("virtual mirror: the face model has no texture layout (UVs) to paint into");
    if (options.texture.type() == CV_8UC3)
      cv::cvtColor(options.texture, texture_bgra, cv::COLOR_BGR2BGRA);
    else
      texture_bgra = options.texture;
    const float w = static_cast<float>(texture_bgra.cols), h = static_cast<float>(texture_bgra.rows);
    if (!options.placement.region) {
      const UvRect& r = options.placement.uv;
      origin = {r.u0, r.v1};
      axis_x = {(r.u1 - r.u0) / w, 0.f};
      axis_y = {0.f, -(r.v1 - r.v0) / h};
    } else {
      PlaceInRegion(*options.placement.region, w, h);
    }
    Eigen::Matrix2f a;
    a << axis_x, axis_y;
    if (std::abs(a.determinant()) < 1e-20f) throw Error("virtual mirror: the texture's placement is degenerate");
    to_texture = a.inverse();
  }

  // The UV of landmark `ibug` (a vertex on a seam of the layout has several: the one nearest
  // `near` when given).
  Eigen::Vector2f LandmarkUv(int ibug, const Eigen::Vector2f* near) const {
    int32_t vertex = -1;
    for (const auto& l : model.landmarks)
      if (l.ibug_index == ibug) vertex = l.vertex;
    if (vertex < 0) throw Error("virtual mirror: the face model has no landmark " + std::to_string(ibug) + " to place the texture by");
    Eigen::Vector2f best(0.f, 0.f);
    float best_d = -1.f;
    for (size_t t = 0; t < model.triangles.size(); ++t)
      for (size_t k = 0; k < 3; ++k) {
        if (model.triangles[t][k] != vertex) continue;
        const auto& uv = model.corner_uvs[3 * t + k];
        const Eigen::Vector2f c(uv[0], uv[1]);
        const float d = near ? (c - *near).squaredNorm() : 0.f;
        if (best_d < 0.f || d < best_d) best = c, best_d = d;
      }
    if (best_d < 0.f) throw Error("virtual mirror: landmark " + std::to_string(ibug) + " is on no triangle");
    return best;
  }

  Eigen::Vector3f LandmarkPosition(int ibug) const {
    for (const auto& l : model.landmarks)
      if (l.ibug_index == ibug) return model.mean_shape.segment<3>(3 * l.vertex);
    throw Error("virtual mirror: the face model has no landmark " + std::to_string(ibug));
  }

  // The face's frame in the layout from its landmarks: the outer eye corners (36, 45) across,
  // the eye line to the mouth's centre (51, 57) down. The texture keeps its aspect in millimetres
  // on the mean face, centred in the region.
  void PlaceInRegion(FaceRegion region, float w, float h) {
    const Eigen::Vector2f nose = LandmarkUv(30, nullptr);
    const Eigen::Vector2f right_eye = LandmarkUv(36, &nose), left_eye = LandmarkUv(45, &nose);
    const Eigen::Vector2f mouth = 0.5f * (LandmarkUv(51, &nose) + LandmarkUv(57, &nose));
    const Eigen::Vector2f eyes = 0.5f * (right_eye + left_eye);
    const Eigen::Vector2f across = left_eye - right_eye, down = mouth - eyes;
    const float across_mm = 1000.f * (LandmarkPosition(45) - LandmarkPosition(36)).norm();
    const float down_mm =
        1000.f * (0.5f * (LandmarkPosition(51) + LandmarkPosition(57)) - 0.5f * (LandmarkPosition(36) + LandmarkPosition(45))).norm();
    if (!(across_mm > 1.f && down_mm > 1.f)) throw Error("virtual mirror: the model's landmarks do not span a face");
    const RegionBox& box = region_box(region);
    const float box_w_mm = 2.f * box.half_s * across_mm, box_h_mm = 2.f * box.half_t * down_mm;
    const float scale_mm = std::min(box_w_mm / w, box_h_mm / h);  // mm per texture pixel
    const Eigen::Vector2f centre = eyes + box.s * across + box.t * down;
    axis_x = across * (scale_mm / across_mm);
    axis_y = down * (scale_mm / down_mm);
    origin = centre - 0.5f * w * axis_x - 0.5f * h * axis_y;
  }

  Eigen::Vector2f ToTexture(const Eigen::Vector2f& uv) const { return to_texture * (uv - origin); }
};

VirtualMirror::VirtualMirror(const FaceModel& model, MirrorOptions options)
    : impl_(std::make_unique<Impl>(model, std::move(options))) {}
VirtualMirror::~VirtualMirror() = default;

const MirrorOptions& VirtualMirror::options() const { return impl_->options; }

Eigen::Vector2f VirtualMirror::TexturePixelToUv(float x, float y) const {
  return impl_->origin + x * impl_->axis_x + y * impl_->axis_y;
}

MirrorResult VirtualMirror::Apply(const cv::Mat& frame_bgr, const gpu::PinholeCamera& camera,
                                  const gpu::FaceParameters& tracked, const cv::Mat* depth) const {
  const Impl& im = *impl_;
  const MirrorOptions& opt = im.options;
  std::string why;
  if (!camera.IsValid(&why)) throw Error("virtual mirror: invalid camera: " + why);
  if (frame_bgr.type() != CV_8UC3 || frame_bgr.cols != camera.width || frame_bgr.rows != camera.height)
    throw Error("virtual mirror: the frame must be 8-bit BGR of the camera's size (" + std::to_string(camera.width) + "x" +
                std::to_string(camera.height) + ")");
  if (!tracked.IsValid(&why, im.model.num_identity(), im.model.num_expression(), im.model.num_albedo()))
    throw Error("virtual mirror: invalid face parameters: " + why);
  if (depth && !depth->empty() && (depth->type() != CV_32FC1 || depth->size() != frame_bgr.size()))
    throw Error("virtual mirror: the depth must be CV_32FC1 metres of the frame's size");
  const bool check_depth = depth && !depth->empty() && opt.depth_occluder_m > 0.f;
  MirrorResult result;
  result.bgr = frame_bgr.clone();
  const bool retexture = !im.texture_bgra.empty() && opt.opacity > 0.f;
  const bool relight = opt.light.kind != MirrorLight::Kind::kTracked;
  if (!retexture && !relight) return result;

  // --- the tracked face: skin (what is re-textured) and eyes (re-lit with the skin around them).
  auto start = Clock::now();
  const int threads = ResolvedThreadCount(0);
  const gpu::VertexState state = im.renderer.evaluate(tracked, nullptr, threads);
  gpu::RenderOptions ropt;
  ropt.parts = part_bit(FacePart::Face) | part_bit(FacePart::LeftEye) | part_bit(FacePart::RightEye);
  ropt.cull_back_faces = true;
  // Reused from frame to frame on each thread (16 values per pixel: allocating and page-faulting
  // 20 MB anew at 640x480 cost more than rasterising).
  thread_local gpu::GBuffer g;
  im.renderer.rasterize(state, camera, ropt, &g, threads);
  result.render_ms = ms_since(start);
  start = Clock::now();
  const int w = camera.width, h = camera.height;
  const cv::Rect face = internal::covered_rect(g, 0);
  if (face.empty()) {
    result.composite_ms = ms_since(start);
    return result;
  }
  result.drawn = true;
  // Work in a box around the face, wide enough for the coarsest level's reach.
  const int pad = 2 << opt.relight_levels;
  const cv::Rect roi = internal::grown_within(face, pad, w, h);
  const auto& decode = srgb_decode_table();
  cv::Mat linear(roi.size(), CV_32FC3), covered = cv::Mat::zeros(roi.size(), CV_32FC1),
                                         occluded = cv::Mat::zeros(roi.size(), CV_32FC1);
  for (int j = 0; j < roi.height; ++j)
    for (int i = 0; i < roi.width; ++i) {
      const cv::Vec3b px = frame_bgr.at<cv::Vec3b>(j + roi.y, i + roi.x);
      linear.at<cv::Vec3f>(j, i) = cv::Vec3f(decode[px[2]], decode[px[1]], decode[px[0]]);  // RGB
      const size_t p = static_cast<size_t>(j + roi.y) * w + (i + roi.x);
      if (g.triangle[p] < 0) continue;
      if (check_depth) {
        const float d = depth->at<float>(j + roi.y, i + roi.x);
        if (std::isfinite(d) && d > 0.f && g.position[3 * p + 2] - d > opt.depth_occluder_m) {
          ++result.occluded_pixels;
          occluded.at<float>(j, i) = 1.f;
          continue;
        }
      }
      covered.at<float>(j, i) = 1.f;
    }
  // The rendered silhouette has no anti-aliasing: the changes fade in over its border, as the
  // compositor's mask does.
  cv::Mat soft;
  cv::erode(covered, soft, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(5, 5)));
  cv::GaussianBlur(soft, soft, cv::Size(0, 0), 2.0);
  const Gamma old_light = internal::rendering_lighting(tracked.gamma);
  // The SH basis at each covered pixel's normal, evaluated once for every light below.
  std::vector<std::array<float, 9>> basis(static_cast<size_t>(roi.area()));
  for (int j = 0; j < roi.height; ++j)
    for (int i = 0; i < roi.width; ++i) {
      if (!(covered.at<float>(j, i) > 0.f)) continue;
      const size_t p = static_cast<size_t>(j + roi.y) * w + (i + roi.x);
      const Eigen::Vector3f n(g.normal[3 * p], g.normal[3 * p + 1], g.normal[3 * p + 2]);
      const Eigen::Vector3f x(g.position[3 * p], g.position[3 * p + 1], g.position[3 * p + 2]);
      basis[static_cast<size_t>(j) * roi.width + i] = gpu::sh_basis(internal::lit_normal(n.normalized(), x));
    }
  auto irradiance_at = [&](const Gamma& light, int i, int j) {
    const auto& b = basis[static_cast<size_t>(j) * roi.width + i];
    return Eigen::Vector3f(internal::irradiance(light, b, 0), internal::irradiance(light, b, 1), internal::irradiance(light, b, 2));
  };

  // --- re-texturing: the texture is the surface's albedo where it covers it, shaded by the
  // tracked light at the pixel's normal (so it sits in the scene's light, not on top of it).
  if (retexture) {
    const cv::Mat& tex = im.texture_bgra;
    const float tw = static_cast<float>(tex.cols), th = static_cast<float>(tex.rows);
    for (int j = 0; j < roi.height; ++j)
      for (int i = 0; i < roi.width; ++i) {
        const size_t p = static_cast<size_t>(j + roi.y) * w + (i + roi.x);
        const int32_t tri = g.triangle[p];
        if (!(covered.at<float>(j, i) > 0.f) || im.model.vertex_part[static_cast<size_t>(g.vertices[3 * p])] != FacePart::Face)
          continue;
        Eigen::Vector2f uv = Eigen::Vector2f::Zero();
        for (size_t k = 0; k < 3; ++k) {
          const auto& c = im.model.corner_uvs[3 * static_cast<size_t>(tri) + k];
          uv += g.barycentric[3 * p + k] * Eigen::Vector2f(c[0], c[1]);
        }
        const Eigen::Vector2f xy = im.ToTexture(uv);
        if (!(xy.x() >= 0.f && xy.y() >= 0.f && xy.x() <= tw && xy.y() <= th)) continue;
        // Bilinear on pixel centres, clamped to the border; colour weighted by alpha, so a
        // transparent pixel's colour does not bleed in.
        const internal::Bilinear s(tex.cols, tex.rows, std::clamp(xy.x() - 0.5f, 0.f, tw - 1.f),
                                   std::clamp(xy.y() - 0.5f, 0.f, th - 1.f));
        const cv::Vec4b t00 = tex.at<cv::Vec4b>(s.j0, s.i0), t01 = tex.at<cv::Vec4b>(s.j0, s.i1),
                        t10 = tex.at<cv::Vec4b>(s.j1, s.i0), t11 = tex.at<cv::Vec4b>(s.j1, s.i1);
        auto alpha_of = [](const cv::Vec4b& t) { return static_cast<float>(t[3]) / 255.f; };
        float rgba[4];
        rgba[3] = s.mix(alpha_of(t00), alpha_of(t01), alpha_of(t10), alpha_of(t11));
        for (int c = 0; c < 3; ++c) {
          auto premultiplied = [&](const cv::Vec4b& t) { return alpha_of(t) * decode[t[2 - c]]; };
          rgba[c] = s.mix(premultiplied(t00), premultiplied(t01), premultiplied(t10), premultiplied(t11));
        }
        const float alpha = rgba[3] * opt.opacity * soft.at<float>(j, i);
        if (!(alpha > 1.f / 255.f)) continue;
        ++result.textured_pixels;
        const Eigen::Vector3f e = irradiance_at(old_light, i, j);
        cv::Vec3f& px = linear.at<cv::Vec3f>(j, i);
        for (int c = 0; c < 3; ++c) {
          const float albedo = rgba[c] / rgba[3];
          px[c] = (1.f - alpha) * px[c] + alpha * std::min(1.0f, albedo * e[c]);
        }
      }
  }

  // --- re-lighting (Sec. 8.3): the face under the new light is the frame times the change of its
  // shading, E_new / E_old at each pixel's normal; only the coarsest pyramid level of that change
  // over the face's foreground is applied (its low frequencies, as the paper re-lights only the
  // coarsest level of the Laplacian pyramid it composites with), so the frame's own fine shading
  // stays, and the change fades out over about 2^levels pixels around the face's border (the
  // model ends below the hairline: a hard edge there drew a step on the forehead).
  cv::Mat touched = soft > 0.f;
  if (relight) {
    Gamma new_light = internal::rendering_lighting(opt.light.kind == MirrorLight::Kind::kPreset
                                                       ? preset_from_unit(im.preset_unit, opt.light.colour, tracked.gamma)
                                                       : opt.light.gamma);
    if (opt.light.kind == MirrorLight::Kind::kPreset) {
      // A preset moves the light, not the exposure: per channel, the face's mean irradiance stays
      // the tracked light's (matching only the camera-facing direction darkened most of a face
      // lit from the front, its forehead and cheeks facing up or aside).
      Eigen::Vector3d old_sum = Eigen::Vector3d::Zero(), new_sum = Eigen::Vector3d::Zero();
      for (int j = 0; j < roi.height; ++j)
        for (int i = 0; i < roi.width; ++i) {
          if (!(covered.at<float>(j, i) > 0.f)) continue;
          old_sum += irradiance_at(old_light, i, j).cast<double>();
          new_sum += irradiance_at(new_light, i, j).cast<double>();
        }
      for (int c = 0; c < 3; ++c) {
        const float scale = new_sum[c] > 1e-9 ? static_cast<float>(old_sum[c] / new_sum[c]) : 1.f;
        for (int k = 0; k < 9; ++k) new_light[static_cast<size_t>(c * 9 + k)] *= scale;
      }
    }
    cv::Mat change = cv::Mat::zeros(roi.size(), CV_32FC3);
    for (int j = 0; j < roi.height; ++j)
      for (int i = 0; i < roi.width; ++i) {
        if (!(covered.at<float>(j, i) > 0.f)) continue;
        const Eigen::Vector3f e_old = irradiance_at(old_light, i, j), e_new = irradiance_at(new_light, i, j);
        const Eigen::Vector3f ratio = internal::shading_change(e_new, e_old).cwiseMax(0.1f).cwiseMin(10.f);
        const cv::Vec3f px = linear.at<cv::Vec3f>(j, i);
        cv::Vec3f& d = change.at<cv::Vec3f>(j, i);
        for (int c = 0; c < 3; ++c) d[c] = px[c] * (ratio[c] - 1.f);
      }
    auto coarsest = [&](const cv::Mat& in) {
      std::vector<cv::Size> sizes;
      cv::Mat level = in;
      for (int l = 0; l < opt.relight_levels && level.cols > 1 && level.rows > 1; ++l) {
        sizes.push_back(level.size());
        cv::Mat down;
        cv::pyrDown(level, down);
        level = down;
      }
      for (auto it = sizes.rbegin(); it != sizes.rend(); ++it) {
        cv::Mat up;
        cv::pyrUp(level, up, *it);
        level = up;
      }
      return level;
    };
    cv::Mat low_change = coarsest(change);
    // Not onto what stands in front of the face: the coarse change reaches across it as across
    // the face's border, and a hand over the cheek would take the new light.
    if (result.occluded_pixels > 0) {
      cv::Mat in_front;
      cv::dilate(occluded, in_front, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(5, 5)));
      cv::GaussianBlur(in_front, in_front, cv::Size(0, 0), 2.0);
      for (int j = 0; j < roi.height; ++j)
        for (int i = 0; i < roi.width; ++i) low_change.at<cv::Vec3f>(j, i) *= 1.f - std::min(1.f, in_front.at<float>(j, i));
    }
    // A brightened pixel stops where its brightest channel reaches white, all channels alike: a
    // channel clipped alone turns skin grey (its red saturates first).
    for (int j = 0; j < roi.height; ++j)
      for (int i = 0; i < roi.width; ++i) {
        cv::Vec3f& px = linear.at<cv::Vec3f>(j, i);
        const cv::Vec3f d = low_change.at<cv::Vec3f>(j, i);
        float t = 1.f;
        for (int c = 0; c < 3; ++c)
          if (d[c] > 0.f && px[c] + d[c] > 1.f) t = std::min(t, std::max(0.f, 1.f - px[c]) / d[c]);
        px += t * d;
      }
    cv::Mat moved;
    cv::cvtColor(cv::abs(low_change), moved, cv::COLOR_RGB2GRAY);
    touched |= moved > 1e-5f;
  }

  // Back to 8-bit where anything may have changed; every other pixel is the frame's, bit for bit.
  for (int j = 0; j < roi.height; ++j)
    for (int i = 0; i < roi.width; ++i) {
      if (!touched.at<uchar>(j, i)) continue;
      const cv::Vec3f px = linear.at<cv::Vec3f>(j, i);
      cv::Vec3b& out = result.bgr.at<cv::Vec3b>(j + roi.y, i + roi.x);
      for (int c = 0; c < 3; ++c)
        out[2 - c] = static_cast<uchar>(std::lround(255.f * srgb_encode(std::clamp(px[c], 0.f, 1.f))));
    }
  result.composite_ms = ms_since(start);
  return result;
}

}  // namespace face_reenact::reenact
