#include "face_reenact/reenact/albedo_texture.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>
#include <numeric>
#include <tuple>

#include <opencv2/imgproc.hpp>

#include "face_reenact/common/error.h"
#include "face_reenact/gpu/image_formation.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/reenact/transfer.h"
#include "image_sampling.h"

namespace face_reenact::reenact {
namespace {

// Smallest pyramid level side the blend goes down to.
constexpr int kMinLevelSide = 8;
// The per-vertex base's weight in the blend: it shows only where no view's smoothed weight does.
constexpr float kBaseWeight = 1e-3f;
// Texels up to this far (texels) outside the island's triangles take the nearest triangle.
constexpr float kGutterTexels = 2.0f;

uint32_t float_bits(float f) {
  uint32_t b;
  std::memcpy(&b, &f, sizeof b);
  return b;
}

int find_root(std::vector<int>& parent, int a) {
  while (parent[static_cast<size_t>(a)] != a) {
    parent[static_cast<size_t>(a)] = parent[static_cast<size_t>(parent[static_cast<size_t>(a)])];
    a = parent[static_cast<size_t>(a)];
  }
  return a;
}

// Barycentric coordinates of p in the 2D triangle (a, b, c); false when it is degenerate.
bool barycentric_2d(const Eigen::Vector2f& a, const Eigen::Vector2f& b, const Eigen::Vector2f& c, const Eigen::Vector2f& p,
                    Eigen::Vector3f* w) {
  const Eigen::Vector2f e0 = b - a, e1 = c - a, d = p - a;
  const float det = e0.x() * e1.y() - e0.y() * e1.x();
  if (!(std::abs(det) > 1e-12f)) return false;
  const float l1 = (d.x() * e1.y() - d.y() * e1.x()) / det;
  const float l2 = (e0.x() * d.y() - e0.y() * d.x()) / det;
  *w = {1.f - l1 - l2, l1, l2};
  return true;
}

// The point of segment ab closest to p, as the parameter t along it.
float closest_on_segment(const Eigen::Vector2f& a, const Eigen::Vector2f& b, const Eigen::Vector2f& p) {
  const Eigen::Vector2f ab = b - a;
  const float len2 = ab.squaredNorm();
  return len2 > 0.f ? std::clamp((p - a).dot(ab) / len2, 0.0f, 1.0f) : 0.f;
}

std::vector<cv::Mat> gaussian_pyramid(const cv::Mat& image, int levels) {
  std::vector<cv::Mat> gauss{image};
  for (int l = 1; l < levels; ++l) {
    cv::Mat down;
    cv::pyrDown(gauss.back(), down);
    gauss.push_back(down);
  }
  return gauss;
}

// The Laplacian pyramid of `image` over `levels` levels (the last one the coarse residual).
std::vector<cv::Mat> laplacian_pyramid(const cv::Mat& image, int levels) {
  const std::vector<cv::Mat> gauss = gaussian_pyramid(image, levels);
  std::vector<cv::Mat> lap(static_cast<size_t>(levels));
  for (int l = 0; l + 1 < levels; ++l) {
    cv::Mat up;
    cv::pyrUp(gauss[static_cast<size_t>(l) + 1], up, gauss[static_cast<size_t>(l)].size());
    lap[static_cast<size_t>(l)] = gauss[static_cast<size_t>(l)] - up;
  }
  lap.back() = gauss.back();
  return lap;
}

// `image` (CV_32FC3) where `mask` (CV_32FC1, 0..1) is 0 filled smoothly from where it is not
// (push-pull: a pyramid of mask-weighted averages, each level's holes taken from the coarser
// one). A view's image filled so has no edge of its own where the view ends: the blend's coarse
// levels make the transition to what the other views and the base say there.
cv::Mat fill_holes(const cv::Mat& image, const cv::Mat& mask) {
  cv::Mat m3;
  cv::merge(std::vector<cv::Mat>{mask, mask, mask}, m3);
  std::vector<cv::Mat> sums{image.mul(m3)}, weights{mask.clone()};
  while (std::min(sums.back().cols, sums.back().rows) > 2) {
    cv::Mat s, w;
    cv::pyrDown(sums.back(), s);
    cv::pyrDown(weights.back(), w);
    sums.push_back(s);
    weights.push_back(w);
  }
  // The coarsest level: the weighted mean where anything was seen.
  cv::Mat filled;
  {
    const cv::Scalar total = cv::sum(sums.back());
    const double wsum = cv::sum(weights.back())[0];
    const cv::Scalar mean = wsum > 1e-12 ? total / wsum : cv::Scalar::all(0.5);
    filled = cv::Mat(sums.back().size(), CV_32FC3, mean);
  }
  for (int l = static_cast<int>(sums.size()) - 1; l >= 0; --l) {
    const size_t ul = static_cast<size_t>(l);
    if (l + 1 < static_cast<int>(sums.size())) {
      cv::Mat up;
      cv::pyrUp(filled, up, sums[ul].size());
      filled = up;
    }
    // Where this level's weight reaches 1 its own average; where it is 0 the coarser fill.
    cv::Mat w = weights[ul], rest;
    cv::max(1.0 - w, 0.0, rest);
    cv::Mat w3, rest3, den3;
    cv::merge(std::vector<cv::Mat>{w, w, w}, w3);
    cv::merge(std::vector<cv::Mat>{rest, rest, rest}, rest3);
    den3 = cv::max(w3 + rest3, 1e-12);
    filled = (sums[ul] + filled.mul(rest3)) / den3;
  }
  return filled;
}

}  // namespace

bool AlbedoTextureOptions::IsValid(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (size != 0 && (size < 64 || size > 8192)) return fail("albedo texture size must be 0 (off) or 64..8192");
  if (!(min_side_yaw_deg > 0.f) || !(side_yaw_deg >= min_side_yaw_deg) || !(max_side_yaw_deg >= side_yaw_deg) ||
      !(max_side_yaw_deg <= 60.f))
    return fail("albedo texture side views need 0 < min_side_yaw_deg <= side_yaw_deg <= max_side_yaw_deg <= 60");
  if (!(max_front_pitch_deg > 0.f) || !(max_front_pitch_deg <= 60.f))
    return fail("albedo texture max_front_pitch_deg must be in (0, 60]");
  if (!(max_expression > 0.f) || !(max_expression <= 1.f)) return fail("albedo texture max_expression must be in (0, 1]");
  if (!(min_closed_eyes_blink > max_expression) || !(min_closed_eyes_blink <= 1.f))
    return fail("albedo texture min_closed_eyes_blink must be in (max_expression, 1]");
  if (blend_levels < 1 || blend_levels > 10) return fail("albedo texture blend_levels must be in 1..10");
  return true;
}

std::shared_ptr<const AlbedoTextureLayout> AlbedoTextureLayout::ForModel(const FaceModel& model, int size) {
  if (size < 64 || size > 8192) throw Error("albedo texture: size " + std::to_string(size) + " is outside 64..8192");
  const size_t nt = model.triangles.size();
  if (model.corner_uvs.size() != 3 * nt || nt == 0)
    throw Error("albedo texture: the face model has no texture layout (UVs)");
  auto layout = std::make_shared<AlbedoTextureLayout>();
  AlbedoTextureLayout& L = *layout;
  L.size = size;
  auto is_face = [&](size_t t) {
    for (int k = 0; k < 3; ++k)
      if (model.vertex_part[static_cast<size_t>(model.triangles[t][static_cast<size_t>(k)])] != FacePart::Face) return false;
    return true;
  };
  // Islands: face triangles joined where they share a vertex at the same UV.
  std::vector<int> parent(nt);
  std::iota(parent.begin(), parent.end(), 0);
  std::map<std::tuple<int32_t, uint32_t, uint32_t>, int> corner_owner;
  for (size_t t = 0; t < nt; ++t) {
    if (!is_face(t)) continue;
    for (size_t k = 0; k < 3; ++k) {
      const auto& uv = model.corner_uvs[3 * t + k];
      const auto key = std::make_tuple(model.triangles[t][k], float_bits(uv[0]), float_bits(uv[1]));
      const auto [it, inserted] = corner_owner.emplace(key, static_cast<int>(t));
      if (!inserted) parent[static_cast<size_t>(find_root(parent, static_cast<int>(t)))] = find_root(parent, it->second);
    }
  }
  std::map<int, int> island_size;
  for (size_t t = 0; t < nt; ++t)
    if (is_face(t)) ++island_size[find_root(parent, static_cast<int>(t))];
  if (island_size.empty()) throw Error("albedo texture: the face model has no face triangles");
  const int island = std::max_element(island_size.begin(), island_size.end(),
                                      [](const auto& a, const auto& b) { return a.second < b.second; })
                         ->first;
  L.textured.assign(nt, 0);
  float lo_x = 1e30f, lo_y = 1e30f, hi_x = -1e30f, hi_y = -1e30f;
  const float s = static_cast<float>(size);
  for (size_t t = 0; t < nt; ++t) {
    if (!is_face(t) || find_root(parent, static_cast<int>(t)) != island) continue;
    bool finite = true;
    for (size_t k = 0; k < 3; ++k) {
      const auto& uv = model.corner_uvs[3 * t + k];
      if (!std::isfinite(uv[0]) || !std::isfinite(uv[1])) finite = false;
    }
    if (!finite) continue;
    L.textured[t] = 1;
    for (size_t k = 0; k < 3; ++k) {
      const auto& uv = model.corner_uvs[3 * t + k];
      lo_x = std::min(lo_x, uv[0] * s), hi_x = std::max(hi_x, uv[0] * s);
      lo_y = std::min(lo_y, (1.f - uv[1]) * s), hi_y = std::max(hi_y, (1.f - uv[1]) * s);
    }
  }
  if (!(hi_x > lo_x) || !(hi_y > lo_y)) throw Error("albedo texture: the face's UV island is empty");
  const int margin = static_cast<int>(std::ceil(kGutterTexels)) + 1;
  L.x0 = std::max(0, static_cast<int>(std::floor(lo_x)) - margin);
  L.y0 = std::max(0, static_cast<int>(std::floor(lo_y)) - margin);
  L.width = std::min(size, static_cast<int>(std::ceil(hi_x)) + margin) - L.x0;
  L.height = std::min(size, static_cast<int>(std::ceil(hi_y)) + margin) - L.y0;
  L.triangle.assign(L.texels(), -1);
  L.barycentric.assign(3 * L.texels(), 0.f);
  L.vertices.assign(3 * L.texels(), -1);
  std::vector<float> gutter_distance(L.texels(), kGutterTexels);

  auto corner = [&](size_t t, size_t k) {
    const auto& uv = model.corner_uvs[3 * t + k];
    return Eigen::Vector2f(uv[0] * s - static_cast<float>(L.x0), (1.f - uv[1]) * s - static_cast<float>(L.y0));
  };
  auto assign = [&](size_t texel, size_t t, const Eigen::Vector3f& w) {
    L.triangle[texel] = static_cast<int32_t>(t);
    for (size_t k = 0; k < 3; ++k) {
      L.barycentric[3 * texel + k] = w[static_cast<int>(k)];
      L.vertices[3 * texel + k] = model.triangles[t][k];
    }
  };
  // Interior texels first, then the gutter around them.
  for (int pass = 0; pass < 2; ++pass) {
    const int grow = pass == 0 ? 0 : static_cast<int>(std::ceil(kGutterTexels));
    for (size_t t = 0; t < nt; ++t) {
      if (!L.textured[t]) continue;
      const Eigen::Vector2f a = corner(t, 0), b = corner(t, 1), c = corner(t, 2);
      const int i0 = std::max(0, static_cast<int>(std::floor(std::min({a.x(), b.x(), c.x()}))) - grow);
      const int i1 = std::min(L.width - 1, static_cast<int>(std::ceil(std::max({a.x(), b.x(), c.x()}))) + grow);
      const int j0 = std::max(0, static_cast<int>(std::floor(std::min({a.y(), b.y(), c.y()}))) - grow);
      const int j1 = std::min(L.height - 1, static_cast<int>(std::ceil(std::max({a.y(), b.y(), c.y()}))) + grow);
      for (int j = j0; j <= j1; ++j)
        for (int i = i0; i <= i1; ++i) {
          const size_t texel = static_cast<size_t>(j) * static_cast<size_t>(L.width) + static_cast<size_t>(i);
          const Eigen::Vector2f p(static_cast<float>(i) + 0.5f, static_cast<float>(j) + 0.5f);
          Eigen::Vector3f w;
          if (!barycentric_2d(a, b, c, p, &w)) continue;
          const bool inside = w.minCoeff() >= -1e-5f;
          if (pass == 0) {
            if (inside && L.triangle[texel] < 0) assign(texel, t, w.cwiseMax(0.f) / w.cwiseMax(0.f).sum());
            continue;
          }
          if (inside || gutter_distance[texel] == 0.f) continue;  // on a triangle already
          // The closest point of the triangle's edges.
          float best = 1e30f;
          Eigen::Vector3f best_w;
          const Eigen::Vector2f pts[3] = {a, b, c};
          for (int e = 0; e < 3; ++e) {
            const int e1 = (e + 1) % 3;
            const float u = closest_on_segment(pts[e], pts[e1], p);
            const float d = (pts[e] + u * (pts[e1] - pts[e]) - p).norm();
            if (d < best) {
              best = d;
              best_w = Eigen::Vector3f::Zero();
              best_w[e] = 1.f - u;
              best_w[e1] = u;
            }
          }
          if (best < gutter_distance[texel]) {
            gutter_distance[texel] = best;
            assign(texel, t, best_w);
          }
        }
    }
    if (pass == 0)
      for (size_t texel = 0; texel < L.texels(); ++texel)
        if (L.triangle[texel] >= 0) gutter_distance[texel] = 0.f;
  }
  return layout;
}

bool AlbedoTexture::Sample(const Eigen::Vector2f& uv, Eigen::Vector3f* rgb, float* seen_weight) const {
  if (empty() || !layout) return false;
  const Eigen::Vector2f x = layout->ToTexel(uv);
  if (!(x.x() >= 0.f) || !(x.y() >= 0.f) || x.x() > static_cast<float>(albedo.cols - 1) ||
      x.y() > static_cast<float>(albedo.rows - 1))
    return false;
  const internal::Bilinear s(albedo.cols, albedo.rows, x.x(), x.y());
  const cv::Vec3f a = albedo.at<cv::Vec3f>(s.j0, s.i0), b = albedo.at<cv::Vec3f>(s.j0, s.i1),
                  c = albedo.at<cv::Vec3f>(s.j1, s.i0), d = albedo.at<cv::Vec3f>(s.j1, s.i1);
  for (int ch = 0; ch < 3; ++ch) (*rgb)[ch] = s.mix(a[ch], b[ch], c[ch], d[ch]);
  if (seen_weight)
    *seen_weight = s.mix(seen.at<float>(s.j0, s.i0), seen.at<float>(s.j0, s.i1), seen.at<float>(s.j1, s.i0),
                         seen.at<float>(s.j1, s.i1));
  return true;
}

AlbedoTexture BlendAlbedoViews(std::shared_ptr<const AlbedoTextureLayout> layout,
                               const std::vector<AlbedoTextureView>& views, const Eigen::VectorXf& base_albedo,
                               int levels) {
  if (!layout || layout->texels() == 0) throw Error("albedo texture: no layout");
  const AlbedoTextureLayout& L = *layout;
  const cv::Size size(L.width, L.height);
  for (const auto& v : views)
    if (v.albedo.type() != CV_32FC3 || v.weight.type() != CV_32FC1 || v.albedo.size() != size || v.weight.size() != size)
      throw Error("albedo texture: a view does not match the layout");
  // The base: the per-vertex albedo over each texel's triangle; texels on no triangle filled from
  // it (never sampled, but a pyramid sees them).
  cv::Mat base = cv::Mat::zeros(size, CV_32FC3), assigned(size, CV_32FC1, cv::Scalar(0.f));
  for (int j = 0; j < L.height; ++j)
    for (int i = 0; i < L.width; ++i) {
      const size_t texel = static_cast<size_t>(j) * static_cast<size_t>(L.width) + static_cast<size_t>(i);
      if (L.triangle[texel] < 0) continue;
      cv::Vec3f c(0.f, 0.f, 0.f);
      for (size_t k = 0; k < 3; ++k) {
        const int64_t v = L.vertices[3 * texel + k];
        if (3 * v + 2 >= base_albedo.size()) throw Error("albedo texture: the base albedo does not match the model");
        for (int ch = 0; ch < 3; ++ch) c[ch] += L.barycentric[3 * texel + k] * base_albedo[3 * v + ch];
      }
      base.at<cv::Vec3f>(j, i) = c;
      assigned.at<float>(j, i) = 1.f;
    }
  base = fill_holes(base, assigned);

  int lv = std::max(1, levels);
  while (lv > 1 && std::min(L.width, L.height) >> (lv - 1) < kMinLevelSide) --lv;

  // Each view's image: its albedo where it sees, filled smoothly elsewhere (fill_holes, so its
  // pyramid has no edge where its view ends); its weight, and the base's.
  std::vector<std::vector<cv::Mat>> lap, wgt;
  lap.push_back(laplacian_pyramid(base, lv));
  wgt.push_back(gaussian_pyramid(assigned * kBaseWeight, lv));
  AlbedoTexture out;
  out.layout = layout;
  out.base = base_albedo;
  out.seen = cv::Mat::zeros(size, CV_32FC1);
  for (const auto& v : views) {
    cv::Mat w = v.weight.mul(assigned);
    cv::Mat sees;
    cv::threshold(w, sees, 0.0, 1.0, cv::THRESH_BINARY);
    lap.push_back(laplacian_pyramid(fill_holes(v.albedo, sees), lv));
    wgt.push_back(gaussian_pyramid(w, lv));
    out.seen += w;
    out.views.push_back({v.frame_index, v.yaw_deg, v.seen_texels, v.closed_eyes});
  }
  std::vector<cv::Mat> blended(static_cast<size_t>(lv));
  for (int l = 0; l < lv; ++l) {
    const size_t ul = static_cast<size_t>(l);
    cv::Mat num = cv::Mat::zeros(lap[0][ul].size(), CV_32FC3), den = cv::Mat::zeros(lap[0][ul].size(), CV_32FC1);
    for (size_t i = 0; i < lap.size(); ++i) {
      cv::Mat w3;
      cv::merge(std::vector<cv::Mat>{wgt[i][ul], wgt[i][ul], wgt[i][ul]}, w3);
      num += lap[i][ul].mul(w3);
      den += wgt[i][ul];
    }
    cv::Mat den3;
    cv::merge(std::vector<cv::Mat>{den, den, den}, den3);
    cv::Mat level = num / cv::max(den3, 1e-12);
    // Where no weight reaches at all (texels on no triangle, far from any): the base's level.
    cv::Mat none = den <= 1e-12;
    lap[0][ul].copyTo(level, none);
    blended[ul] = level;
  }
  cv::Mat result = blended.back();
  for (int l = lv - 2; l >= 0; --l) {
    cv::Mat up;
    cv::pyrUp(result, up, blended[static_cast<size_t>(l)].size());
    result = up + blended[static_cast<size_t>(l)];
  }
  cv::min(cv::max(result, 0.0), 1.0, out.albedo);
  return out;
}

float head_yaw_deg(const gpu::FaceParameters& params) {
  const Eigen::Vector3f forward = gpu::rotation_from_euler(params.euler) * Eigen::Vector3f::UnitZ();
  const Eigen::Vector3f to_camera = -params.translation.normalized();
  const double a = std::atan2(forward.x(), -forward.z()) - std::atan2(to_camera.x(), -to_camera.z());
  double deg = a * 180.0 / M_PI;
  while (deg > 180.0) deg -= 360.0;
  while (deg < -180.0) deg += 360.0;
  return static_cast<float>(deg);
}

AlbedoViewChooser::Slot AlbedoViewChooser::Consider(const gpu::FaceParameters& params) {
  if (!params.translation.allFinite() || !params.euler.allFinite() || !(params.translation.norm() > 0.f)) return kNone;
  static const int blink_left = arkit_blendshape_index("eyeBlinkLeft"), blink_right = arkit_blendshape_index("eyeBlinkRight");
  if (expression_weight(params.delta, kJawOpenIndex) > options_.max_expression) return kNone;
  const float blink = std::min(expression_weight(params.delta, blink_left), expression_weight(params.delta, blink_right));
  const float yaw = head_yaw_deg(params);
  const float turn = gpu::head_turn_from_camera_deg(params);
  // Nearer rest is better too: every expression (gaze included) moves or hides some of the skin's
  // own marks (lashes, the lip line, creases), and the texture carries them into every frame. The
  // summed weights (about 0.5-1.5 on a tracked face at rest) count as this many degrees each.
  constexpr float kDegreesPerExpression = 4.0f;
  // A slot moves to a new frame only for a clearly better one: each move costs a rebuild.
  constexpr float kBetterByDeg = 2.0f;
  auto take = [&](Slot slot, float distance) {
    if (best_[slot] >= 0.f && !(distance < best_[slot] - kBetterByDeg)) return kNone;
    best_[slot] = distance;
    return slot;
  };
  if (blink >= options_.min_closed_eyes_blink) {
    // A blink facing the camera as a front view does (its lids are what it is kept for: a side
    // view sees them foreshortened), the more closed the better: the output closes them fully.
    if (!(std::abs(yaw) < options_.min_side_yaw_deg) || turn > options_.max_front_pitch_deg) return kNone;
    constexpr float kDegreesPerOpenness = 20.0f;
    const float rest = params.delta.cwiseAbs().sum() - expression_weight(params.delta, blink_left) -
                       expression_weight(params.delta, blink_right);
    return take(kClosedEyes, turn + kDegreesPerOpenness * (1.0f - blink) + kDegreesPerExpression * rest);
  }
  if (expression_weight(params.delta, blink_left) > options_.max_expression ||
      expression_weight(params.delta, blink_right) > options_.max_expression)
    return kNone;
  Slot slot = kNone;
  float distance = 0.f;
  if (turn > std::abs(yaw) + 12.f) {
    // Mostly a turn about the horizontal: a face looking up or down shows its chin or brow, not a
    // side. It is still the front view of an actor who never faces the camera level (a phone held
    // low, a laptop's camera below the eyes: d10 is pitched about 20 degrees throughout, and its
    // 125 frames gave no texture), so it may fill the front slot, at the distance of its whole
    // turn where a level view counts only its yaw: a level view at rest soon replaces it.
    if (turn > options_.max_front_pitch_deg) return kNone;
    slot = kFront;
    distance = turn;
  } else if (std::abs(yaw) < options_.min_side_yaw_deg) {
    slot = kFront;
    distance = std::abs(yaw);
  } else if (std::abs(yaw) <= options_.max_side_yaw_deg) {
    slot = yaw < 0.f ? kLeft : kRight;
    distance = std::abs(std::abs(yaw) - options_.side_yaw_deg);
  } else {
    return kNone;
  }
  return take(slot, distance + kDegreesPerExpression * params.delta.cwiseAbs().sum());
}

int AlbedoViewChooser::filled_count() const {
  return static_cast<int>(std::count_if(std::begin(best_), std::end(best_), [](float b) { return b >= 0.f; }));
}

void AlbedoViewChooser::Reset() { std::fill(std::begin(best_), std::end(best_), -1.f); }

}  // namespace face_reenact::reenact
