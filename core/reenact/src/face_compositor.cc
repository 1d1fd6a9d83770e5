#include "face_reenact/reenact/face_compositor.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <optional>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "face_reenact/common/error.h"
#include "face_reenact/common/parallel.h"
#include "face_reenact/common/srgb.h"
#include "face_reenact/gpu/context.h"
#include "face_reenact/gpu/cpu_renderer.h"
#include "face_reenact/gpu/renderer.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/reenact/laplacian_blend.h"
#include "face_reenact/reenact/teeth_texture.h"
#include "face_reenact/reenact/transfer.h"
#include "face_parts.h"
#include "image_sampling.h"
#include "eye_aperture.h"
#include "eyeball_fill.h"
#include "mouth_pass.h"
#include "shading.h"
#include "face_reenact/common/timing.h"

namespace face_reenact::reenact {
namespace {

using Clock = std::chrono::steady_clock;
using internal::sample_float;
using internal::sample_linear;
using internal::Gamma;
using internal::irradiance;
using internal::lit_normal;
using internal::rendering_lighting;

using internal::display_bgr;
using internal::copy_pixel;
using internal::covered_rect;
using internal::pixel_floor;
using internal::pixel_round;
using internal::grown_within;
using internal::kEyeParts;
using internal::kMouthParts;
using internal::part_bit;

// The share of the camera-facing light that enters the mouth's opening (the cavity, the lips'
// inner faces; the mouth pass's entering light).
constexpr float kCavityOcclusion = 0.35f;

float luminance(const Eigen::Vector3f& rgb) { return linear_luminance(rgb[0], rgb[1], rgb[2]); }

// --- What a frame's colour divided by the shading may teach the albedo: the per-vertex map
// (ObserveAlbedo) and the texture's views (UnwrapAlbedo) take the same rules.
constexpr float kAlbedoMinCos = 0.5f;  // grazing views are blurred, badly lit, near silhouettes
constexpr float kAlbedoDepthToleranceM = 0.0025f;  // the view's own rendering at the point's depth
constexpr float kAlbedoMeasuredDepthToleranceM = 0.015f;  // a depth map's measure of the point
// A pixel this bright in any channel is clipped: its colour says nothing of the surface (a
// blown-out window behind the face where the fit's silhouette overshoots it, a highlight).
constexpr int kClippedLevel = 250;
// Surface this close to an occluding boundary of the rendering is not observed: the fit is off by
// a pixel or two, and the sample reaches one more, so there the frame shows the other side (the
// eyeball or the lashes for a lid margin, the lip line or the mouth cavity for a lip, the
// background for the face's outline). Written into the map, those colours came back wherever the
// output shows the surface and the frame does not: on the webcam clip the lids d14 closes were
// greyer with them, with a light line along the lid margin. Such surface keeps what clearer views
// gave it, or the colour of the skin around.
constexpr float kAlbedoBoundaryClearancePx = 2.5f;
// A resting eye folds its upper lid away under the brow, and a blink unfolds it over the eye: the
// model's eyeBlink blendshapes stretch the lid's triangles 2-4 times. A frame teaches the albedo
// a lid's surface in proportion to how far it unfolds it (Impl::LidUnfolding): not at all where
// the area around a vertex is at most kFoldedLid of its area with the eyes closed, fully from
// kUnfoldedLid. Open eyes show that skin only as a shadowed band under the brow (on the webcam
// clip a grey-blue one); learned from it, the lids a source's blink closes over the target's eyes
// were drawn grey and smeared.
constexpr float kFoldedLid = 0.5f, kUnfoldedLid = 0.7f;
// An eyeBlink moving a face vertex at least this far (metres) makes its triangles lid surface.
constexpr float kLidMotionM = 0.0005f;
// A lid the output closes further than the target's is closing in full from this much more blink.
constexpr float kLidCloseSpan = 0.3f;
// The per-vertex map knows a lid vertex in full from this observation weight (a blink facing the
// camera gives it about 0.5-1: cos^2 of the view angle times the lid's unfolding).
constexpr float kLearnedLidWeight = 0.25f;
// Under the frame texture, the albedo texture replaces the per-vertex map in full where its views'
// summed weight reaches this (a view facing the surface at cos 0.45), in part below.
constexpr float kTextureSeenForFull = 0.2f;

// A light whose colour is that far from white (one channel's ambient under a quarter of another's,
// or none at all) is the lighting fit making up for something else (on the webcam clip, as the
// camera's exposure dropped, green and blue ambient fell below zero); dividing the frame by it
// would write that error into the map, which later frames show wherever the frame does not.
bool light_usable_for_albedo(const Gamma& light) {
  constexpr float kMinLightChroma = 0.25f;
  const float lo = std::min({light[0], light[9], light[18]}), hi = std::max({light[0], light[9], light[18]});
  return lo > 0.f && lo >= kMinLightChroma * hi;
}

// Only well-lit surface: where the fitted light is weak (below 40 % of its ambient part, or
// nearly none), dividing by it amplifies every error of the lighting fit.
bool well_lit(const Gamma& light, const std::array<float, 9>& basis, int c) {
  const float e = irradiance(light, basis, c);
  const float ambient = light[static_cast<size_t>(c * 9)] * basis[0];
  return e > 0.05f && e > 0.4f * ambient;
}

// An observed albedo held against the model's `prior` at that point. Brightness may differ from
// the prior by the range real faces show against a skin mean (brows and lips darker, not much
// brighter): clamped to it. Far brighter than that is not this surface (the background behind a
// fit whose silhouette overshoots the face, a highlight): false, rejected, since clamped, such a
// pixel would still pull the point to 1.8 x the model's colour. Skin, lips and brows differ from
// the model's albedo mostly in brightness; a large change of chromaticity is a wrong observation
// (a background pixel at a silhouette, noise, a highlight), so the observed chromaticity is
// pulled back to within kMaxChromaShift of the prior's.
bool plausible_albedo(const Eigen::Vector3f& prior, Eigen::Vector3f* observed) {
  constexpr float kMaxChromaShift = 0.1f;
  constexpr float kMinBrightnessRatio = 0.15f, kMaxBrightnessRatio = 1.8f;
  constexpr float kImplausiblyBright = 1.25f;  // rejected beyond kMaxBrightnessRatio by this
  Eigen::Vector3f& o = *observed;
  const float prior_l = prior.sum(), obs_l = o.sum();
  if (prior_l > 1e-4f && obs_l > kMaxBrightnessRatio * prior_l * kImplausiblyBright) return false;
  if (prior_l > 1e-4f && obs_l > 1e-4f) {
    const float ratio = std::clamp(obs_l / prior_l, kMinBrightnessRatio, kMaxBrightnessRatio);
    o *= ratio * prior_l / obs_l;
    o = o.cwiseMin(1.0f);
  }
  const float obs_sum = o.sum(), prior_sum = prior.sum();
  if (obs_sum > 1e-4f && prior_sum > 1e-4f) {
    const Eigen::Vector3f obs_chroma = o / obs_sum, prior_chroma = prior / prior_sum;
    const Eigen::Vector3f shift = obs_chroma - prior_chroma;
    const float len = shift.norm();
    if (len > kMaxChromaShift) o = obs_sum * (prior_chroma + shift * (kMaxChromaShift / len));
    o = o.cwiseMax(0.0f).cwiseMin(1.0f);
  }
  return true;
}

// A surface point counts as shown in a frame when the frame's visible surface at its projection
// is within this depth of it: a few millimetres, more where one pixel spans more than that.
constexpr float kShownToleranceM = 0.004f;

// An eyeball sample this close to the edge of the eyeball a frame's fit draws (its lids, in
// pixels of BoundaryDistance) is trusted only kEyeballEdgeTrust where it moves, fully from
// kEyeballEdgeFullPx: a fit off by a pixel or two puts the lid's rim and lashes there, and moved
// into the output's eye they drew a red line inside it (the webcam clip's blink frames, drawn
// from his open eyes). The fill by place (internal::EyeballFill) gives such pixels the eyeball's
// colour next to them. Not nothing: an eye a few pixels tall is all edge.
constexpr float kEyeballEdgePx = 1.0f, kEyeballEdgeFullPx = 2.5f, kEyeballEdgeTrust = 0.25f;
float eyeball_edge_trust(float distance_px) {
  const float away = std::clamp((distance_px - kEyeballEdgePx) / (kEyeballEdgeFullPx - kEyeballEdgePx), 0.0f, 1.0f);
  return kEyeballEdgeTrust + (1.0f - kEyeballEdgeTrust) * away;
}

// An eye the target holds closed further than this is not the frame's to show open: where the
// output opens it, its eyeball comes from the actor's open eyes (EyeExemplar).
constexpr float kClosedForExemplar = 0.3f;
// The detector's lid points give an eye's real opening (eye_aperture.h) up to this eyeBlink: an
// eye narrowed that far still shows its iris between points a few pixels apart; beyond, its
// lids nearly meet and the six points no longer outline an opening.
constexpr float kMaxBlinkForOpening = 0.6f;

// The detector's lid points are the eye's real opening (eye_aperture.h) only while each lies
// within this share of the eye's width of the fit's own (a detector that lost the eye, a fit
// that did, are not drawn from).
constexpr float kMaxOpeningOffset = 0.25f;

// A frame's eye opening as a signed distance map around it (pixels, positive inside), for the
// frame texture's per-pixel tests; empty where the opening is not known.
struct FrameOpening {
  cv::Rect box;
  cv::Mat distance;  // CV_32FC1 over box
  FrameOpening() = default;
  FrameOpening(const internal::EyeAperture& a, int w, int h) {
    constexpr int kMargin = 3;
    box = a.Bounds(internal::EyeAperture::Which::kFrame, kMargin, w, h);
    distance = cv::Mat(box.size(), CV_32FC1);
    for (int j = 0; j < box.height; ++j)
      for (int i = 0; i < box.width; ++i)
        distance.at<float>(j, i) = a.SignedDistance(Eigen::Vector2f(static_cast<float>(box.x + i), static_cast<float>(box.y + j)),
                                                    internal::EyeAperture::Which::kFrame);
  }
  bool empty() const { return distance.empty(); }
  // How far inside the opening (u, v) lies, in pixels (negative outside; -1 where not known or
  // beyond the map).
  float Inside(float u, float v) const {
    if (empty()) return -1.f;
    const float x = u - static_cast<float>(box.x), y = v - static_cast<float>(box.y);
    if (!(x >= 0.f && y >= 0.f && x <= static_cast<float>(box.width - 1) && y <= static_cast<float>(box.height - 1))) return -1.f;
    return sample_float(distance, x, y);
  }
};

// An output pixel the fit's opening draws as eyeball outside the output's real opening: it shows
// the frame's lid at `at`, by alpha (the share of the pixel outside the opening).
struct LidPixel {
  size_t p;
  Eigen::Vector2f at;  // where the frame shows that lid (EyeAperture::FrameLidPoint)
  float alpha;
};

// The pixel position (u, v) of camera-space point x (in front of the camera).
Eigen::Vector2f project(const gpu::PinholeCamera& camera, const Eigen::Vector3f& x) {
  return {camera.fx * x.x() / x.z() + camera.cx, camera.fy * x.y() / x.z() + camera.cy};
}

bool same_geometry(const gpu::FaceParameters& a, const gpu::FaceParameters& b) {
  return a.alpha == b.alpha && a.delta == b.delta && a.euler == b.euler && a.translation == b.translation;
}

}  // namespace

struct FaceCompositor::Impl {
  const FaceModel& model;
  gpu::CpuRenderer renderer;
  ReenactmentOptions options;
  // The Vulkan rasteriser (RendererKind::kVulkan), made on first use; when no device opens the
  // compositor says why once and stays on the CPU.
  mutable std::unique_ptr<gpu::Context> vk_context;
  mutable std::unique_ptr<gpu::Renderer> vk_renderer;
  mutable std::string vk_failure;
  std::vector<int32_t> inner_lip_vertices;  // iBUG 60-67 in order around the opening
  // The inner lip line and the lid margins (iBUG 60-67, 36-41, 42-47), each in order around its
  // opening: where a closed mouth or eye meets itself, with no change of surface in a G-buffer.
  std::vector<std::vector<int32_t>> seam_contours;
  std::vector<std::vector<int32_t>> lid_contours;  // the seam contours but the lips' (lid margins 36-41, 42-47)
  std::vector<int> lid_blink_index;                 // per lid contour: its eye's eyeBlink blendshape
  std::vector<int> lid_eye_slot;                    // per lid contour: its eye's EyeSlot
  std::vector<int> lid_opening;                     // per lid contour: its EyeOpenings index (0: 36-41)
  std::vector<std::array<int32_t, 2>> eye_corners;  // per eye: its inner and outer corner (iBUG 39/36, 42/45)
  // Per vertex of an eyeball, its place on it (internal::EyeballFill): the unit direction from
  // the eyeball's centre in the rest shape; zero elsewhere. Per eye (EyeSlot): its vertices and
  // its radius in the rest shape (metres).
  std::vector<Eigen::Vector3f> eyeball_place;
  std::array<std::vector<int32_t>, 2> eyeball_vertices;
  std::array<float, 2> eyeball_radius{0.f, 0.f};
  std::vector<std::vector<int32_t>> neighbours;  // mesh adjacency, for filling the albedo map
  // Face vertices inside the mouth: the skin behind the inner lip line (the lips' inner faces
  // and the wall behind them). See irradiance_at.
  std::vector<char> in_mouth;
  // The teeth's texture coordinates per vertex (TeethTextureCoordinates; NaN off the teeth).
  std::vector<Eigen::Vector2f> teeth_uv;
  std::vector<int32_t> skin_around_mouth;  // ViewMouth's skin vertices
  // The lids' unfolding (kFoldedLid): the face triangles an eyeBlink moves, their vertices, the
  // eyeBlink blendshapes, and per vertex the eyeBlink that unfolds it where the resting mean face
  // shows its surface folded (LidUnfolding below 1: the surface only a blink shows in full), -1
  // elsewhere.
  std::vector<std::array<int32_t, 3>> lid_triangles;
  std::vector<int32_t> lid_vertices;
  std::vector<int> blink_indices;
  std::vector<int> folded_lid_blink;

  Impl(const FaceModel& m, const ReenactmentOptions& o) : model(m), renderer(gpu::RenderModel::FromFaceModel(m)), options(o) {
    std::array<int32_t, 68> by_index;
    by_index.fill(-1);
    for (const auto& l : model.landmarks)
      if (l.ibug_index >= 0 && l.ibug_index < 68) by_index[static_cast<size_t>(l.ibug_index)] = l.vertex;
    for (int i = 60; i <= 67; ++i)
      if (by_index[static_cast<size_t>(i)] >= 0) inner_lip_vertices.push_back(by_index[static_cast<size_t>(i)]);
    for (const auto& [first, last] : {std::pair{60, 67}, std::pair{36, 41}, std::pair{42, 47}}) {
      std::vector<int32_t> contour;
      for (int i = first; i <= last; ++i)
        if (by_index[static_cast<size_t>(i)] >= 0) contour.push_back(by_index[static_cast<size_t>(i)]);
      if (contour.size() < 3) continue;
      if (first != 60) {
        // The model's +x is the person's left: iBUG 42-47 is the left eye (eyeBlinkLeft).
        float x = 0.f;
        for (int32_t v : contour) x += model.mean_shape[3 * v];
        lid_blink_index.push_back(arkit_blendshape_index(x > 0.f ? "eyeBlinkLeft" : "eyeBlinkRight"));
        lid_eye_slot.push_back(EyeSlot(x > 0.f ? FacePart::LeftEye : FacePart::RightEye));
        lid_opening.push_back(first == 36 ? 0 : 1);
        lid_contours.push_back(contour);
      }
      seam_contours.push_back(std::move(contour));
    }
    for (const auto& [inner, outer] : {std::pair{39, 36}, std::pair{42, 45}})
      if (by_index[static_cast<size_t>(inner)] >= 0 && by_index[static_cast<size_t>(outer)] >= 0)
        eye_corners.push_back({by_index[static_cast<size_t>(inner)], by_index[static_cast<size_t>(outer)]});
    FindEyeballPlaces();
    FindLids();
    FindMouthInterior();
    teeth_uv = TeethTextureCoordinates(model);
    FindSkinAroundMouth();
    neighbours.resize(static_cast<size_t>(model.num_vertices()));
    for (const auto& t : model.triangles)
      for (int k = 0; k < 3; ++k) {
        auto& list = neighbours[static_cast<size_t>(t[static_cast<size_t>(k)])];
        for (int o = 1; o <= 2; ++o) {
          const int32_t nb = t[static_cast<size_t>((k + o) % 3)];
          if (std::find(list.begin(), list.end(), nb) == list.end()) list.push_back(nb);
        }
      }
  }

  // The real openings of the eyes `target` holds at most kMaxBlinkForOpening closed (the frame's
  // detected lid points, each within kMaxOpeningOffset of the fit's), each moved by the output's
  // lid motion (ts: the tracked geometry, os: the output's).
  std::array<std::optional<internal::EyeAperture>, 2> EyeApertures(const EyeOpenings& openings,
                                                                   const gpu::FaceParameters& target,
                                                                   const gpu::VertexState& ts, const gpu::VertexState& os,
                                                                   const gpu::PinholeCamera& camera,
                                                                   bool unmoved_too = false) const {
    std::array<std::optional<internal::EyeAperture>, 2> out;
    constexpr float kUnmovedPx = 0.25f;
    for (size_t k = 0; k < lid_contours.size(); ++k) {
      const size_t o = static_cast<size_t>(lid_opening[k]), slot = static_cast<size_t>(lid_eye_slot[k]);
      if (!openings.known[o] || lid_contours[k].size() != 6) continue;
      if (expression_weight(target.delta, lid_blink_index[k]) > kMaxBlinkForOpening) continue;
      std::array<Eigen::Vector2f, 6> fit, motion;
      bool in_front = true;
      for (size_t i = 0; i < 6 && in_front; ++i) {
        const int32_t v = lid_contours[k][i];
        const Eigen::Vector3f a = ts.camera_positions.segment<3>(3 * v), b = os.camera_positions.segment<3>(3 * v);
        in_front = a.z() > camera.near_plane && b.z() > camera.near_plane;
        if (!in_front) break;
        fit[i] = project(camera, a);
        motion[i] = project(camera, b) - fit[i];
      }
      if (!in_front) continue;
      // An eye whose lids and eyeball the output leaves where the target's are keeps the frame's
      // own pixels (each samples itself): nothing to redraw (unless `unmoved_too`: the openings of
      // a frame sampled elsewhere, the open eyes').
      float moved = 0.f;
      for (const Eigen::Vector2f& m : motion) moved = std::max(moved, m.norm());
      for (int32_t v : eyeball_vertices[slot]) {
        if (moved >= kUnmovedPx) break;
        const Eigen::Vector3f a = ts.camera_positions.segment<3>(3 * v), b = os.camera_positions.segment<3>(3 * v);
        if (a.z() > camera.near_plane && b.z() > camera.near_plane) moved = std::max(moved, (project(camera, b) - project(camera, a)).norm());
      }
      if (!unmoved_too && !(moved >= kUnmovedPx)) continue;
      const float width = (fit[3] - fit[0]).norm();
      float offset = 0.f;
      for (size_t i = 0; i < 6; ++i) {
        const float d = (openings.points[o][i] - fit[i]).norm();
        offset = std::isfinite(d) ? std::max(offset, d) : std::numeric_limits<float>::infinity();
      }
      constexpr float kMinEyeWidthPx = 6.f;  // an eye this small is a few pixels of lashes
      bool finite_motion = true;
      for (const Eigen::Vector2f& m : motion) finite_motion = finite_motion && m.allFinite();
      if (!(width >= kMinEyeWidthPx) || !(offset <= kMaxOpeningOffset * width) || !finite_motion) continue;
      // Where the output closes the eye further, the upper lid moves so that the real opening
      // keeps its share of the fit's: a fit whose lids part by 9 px and meet in the output shuts
      // a real eye 12 px tall, where the fit's 9 px of motion left a 3 px slit of his open eye
      // along the shut lids (a light dotted line; d14 with her eyes shut onto the webcam clip,
      // output frame 95). Where it opens the eye, the fit's motion as it is (the share overshot
      // on d10's narrowed eyes, output frame 116: the output's wider than her open ones).
      for (const auto& [upper, lower] : {std::pair<size_t, size_t>{1, 5}, std::pair<size_t, size_t>{2, 4}}) {
        const float fit_gap = fit[lower].y() - fit[upper].y();
        const float out_gap = fit_gap + motion[lower].y() - motion[upper].y();
        const float real_gap = openings.points[o][lower].y() - openings.points[o][upper].y();
        if (!(fit_gap > 0.5f) || !(real_gap > 0.f) || !(out_gap < fit_gap)) continue;
        const float share = std::max(0.0f, out_gap / fit_gap);
        motion[upper].y() = motion[lower].y() + real_gap - share * real_gap;
      }
      out[slot].emplace(openings.points[o], motion);
    }
    return out;
  }

  // The output G-buffer `g` (of `os`, evaluated at `output`) opened to the output's real openings:
  // a lid pixel within one shows the eyeball behind it (the eyes drawn alone), an eyeball pixel
  // outside one is returned, to show the frame's lid.
  std::vector<LidPixel> OpenEyesToApertures(const std::array<std::optional<internal::EyeAperture>, 2>& apertures,
                                            const gpu::FaceParameters& output, const gpu::VertexState& os,
                                            const gpu::PinholeCamera& camera, const gpu::RenderOptions& ropt,
                                            gpu::GBuffer* g) const {
    const int w = camera.width, h = camera.height;
    gpu::GBuffer& eyes = scratch_gbuffer(4);
    gpu::RenderOptions eyes_ropt = ropt;
    eyes_ropt.parts = kEyeParts;
    rasterize(os, output, camera, eyes_ropt, &eyes);
    std::vector<LidPixel> lids;
    constexpr float kLidInFrontM = 0.0005f;  // the eyeball lies behind the lid over it
    for (size_t e = 0; e < 2; ++e) {
      if (!apertures[e]) continue;
      const internal::EyeAperture& a = *apertures[e];
      // Around the opening as far as the fit's may reach (kMaxOpeningOffset of the eye's width).
      const cv::Rect opening = a.Bounds(internal::EyeAperture::Which::kOutput, 0, w, h);
      const cv::Rect box = a.Bounds(internal::EyeAperture::Which::kOutput,
                                    2 + static_cast<int>(std::ceil(kMaxOpeningOffset * static_cast<float>(opening.width))), w, h);
      for (int j = box.y; j < box.y + box.height; ++j)
        for (int i = box.x; i < box.x + box.width; ++i) {
          const size_t p = static_cast<size_t>(j) * w + i;
          if (g->triangle[p] < 0) continue;
          const FacePart part = part_of(g->vertices[3 * p]);
          const bool this_eye = (kEyeParts & part_bit(part)) && static_cast<size_t>(EyeSlot(part)) == e;
          if (part != FacePart::Face && !this_eye) continue;
          if (!this_eye && !opening.contains(cv::Point(i, j))) continue;  // skin outside the opening stays
          Eigen::Vector2f motion;
          const Eigen::Vector2f here(static_cast<float>(i), static_cast<float>(j));
          const float inside = a.SignedDistance(here, internal::EyeAperture::Which::kOutput, &motion);
          if (this_eye) {
            if (inside < 0.5f) lids.push_back({p, a.FrameLidPoint(here, motion), std::clamp(0.5f - inside, 0.0f, 1.0f)});
            continue;
          }
          // A lid pixel inside: the eyeball of this eye behind it, when the eyes alone draw one.
          if (!(inside > 0.f) || eyes.triangle[p] < 0) continue;
          const FacePart behind = part_of(eyes.vertices[3 * p]);
          if (!(kEyeParts & part_bit(behind)) || static_cast<size_t>(EyeSlot(behind)) != e) continue;
          if (eyes.position[3 * p + 2] < g->position[3 * p + 2] - kLidInFrontM) continue;
          copy_pixel(eyes, p, g);
          // Its share outside the opening is the lid's (the lids' edge drawn without steps).
          if (inside < 0.5f) lids.push_back({p, a.FrameLidPoint(here, motion), 0.5f - inside});
        }
    }
    return lids;
  }

  // The inner-lip polygon of a evaluated face in pixels (empty: no such landmarks, or a lip
  // point at or behind the near plane).
  std::vector<Eigen::Vector2f> Opening(const gpu::PinholeCamera& camera, const gpu::VertexState& state) const {
    std::vector<Eigen::Vector2f> polygon;
    if (inner_lip_vertices.size() < 3) return polygon;
    for (int32_t v : inner_lip_vertices) {
      const Eigen::Vector3f x = state.camera_positions.segment<3>(3 * v);
      if (!(x.z() > camera.near_plane)) return {};
      polygon.push_back(project(camera, x));
    }
    return polygon;
  }

  // lid_triangles, lid_vertices, blink_indices and folded_lid_blink from the mean shape.
  void FindLids() {
    const int n = model.num_vertices();
    for (const char* name : {"eyeBlinkLeft", "eyeBlinkRight"})
      if (const int b = arkit_blendshape_index(name); b >= 0 && b < model.num_expression()) blink_indices.push_back(b);
    std::vector<char> moved(static_cast<size_t>(n), 0), in_lid(static_cast<size_t>(n), 0);
    for (int v = 0; v < n; ++v)
      for (int b : blink_indices)
        if (part_of(v) == FacePart::Face && model.expression_basis.block(3 * v, b, 3, 1).norm() >= kLidMotionM) moved[static_cast<size_t>(v)] = 1;
    for (const auto& t : model.triangles) {
      bool face = true, any = false;
      for (int32_t v : t) {
        face = face && part_of(v) == FacePart::Face;
        any = any || moved[static_cast<size_t>(v)];
      }
      if (!face || !any) continue;
      lid_triangles.push_back(t);
      for (int32_t v : t) in_lid[static_cast<size_t>(v)] = 1;
    }
    for (int v = 0; v < n; ++v)
      if (in_lid[static_cast<size_t>(v)]) lid_vertices.push_back(v);
    gpu::FaceParameters rest;
    const std::vector<float> unfolded = LidUnfolding(rest);
    folded_lid_blink.assign(static_cast<size_t>(n), -1);
    for (int v = 0; v < n; ++v) {
      if (!(unfolded[static_cast<size_t>(v)] < 1.0f)) continue;
      float most = 0.f;
      for (int b : blink_indices)
        if (const float m = model.expression_basis.block(3 * v, b, 3, 1).norm(); m > most) {
          most = m;
          folded_lid_blink[static_cast<size_t>(v)] = b;
        }
    }
  }

  // How much further the output closes the eye of eyeBlink `b` than the target's: 0-1, in full
  // from kLidCloseSpan more blink.
  static float LidClosing(const gpu::FaceParameters& target, const gpu::FaceParameters& output, int b) {
    return std::clamp((expression_weight(output.delta, b) - expression_weight(target.delta, b)) / kLidCloseSpan, 0.0f, 1.0f);
  }

  // The lash line of the lids the output shuts over eyes the target holds open. No frame of such
  // a target shows its closed margin, and the frame texture draws it from the frame's own lash
  // line only where a dark sample lands near it: a dotted, stair-stepped line (NASA's portrait,
  // which never blinks, under d14's shut eyes; the webcam clip under her blinks). A shut eye's
  // margin is one unbroken dark line. It is drawn here along the output's upper lid margin (a
  // Catmull-Rom curve through the corners and the two upper lid points), in the colour of the
  // target's own lash line: the darkest eighth (by the brightest channel, so a red lid rim does not
  // pass for lashes) of the frame at and up to 2 px above its upper margin, where an open eye's
  // upper lashes are (on the webcam clip a red-brown, his lashes' colour in that camera; on the
  // portrait her dark brown). kLashLineWidth of the eye's width wide (the portrait's 17 px eye:
  // 1.2 px), thinning out towards the inner corner, as strong as the output closes the lid further
  // than the target's (LidClosing) once the lid is nearly down (eyeBlink kLashLineFrom ->
  // kLashLineFull). Only darker: a target whose margin is not darker than the shut lid gets none.
  // `rendered`: display BGR (0..255), drawn where `face_mask` is. Cost: one model evaluation on the
  // frames that shut an eye the target holds open.
  static constexpr float kLashLineFrom = 0.5f, kLashLineFull = 0.8f;
  static constexpr float kLashLineWidth = 0.07f;  // of the eye's width (corner to corner)
  static constexpr float kLashLineOpacity = 0.9f;
  void DrawClosedLashLines(const cv::Mat& target_bgr, const gpu::PinholeCamera& camera,
                           const gpu::FaceParameters& target, const gpu::FaceParameters& output,
                           const gpu::VertexState& out_state, const cv::Mat& face_mask, cv::Mat* rendered) const {
    std::vector<std::pair<size_t, float>> lines;  // (lid contour, strength)
    for (size_t k = 0; k < lid_contours.size(); ++k) {
      if (lid_contours[k].size() != 6) continue;
      const int b = lid_blink_index[k];
      const float shut =
          std::clamp((expression_weight(output.delta, b) - kLashLineFrom) / (kLashLineFull - kLashLineFrom), 0.f, 1.f);
      const float strength = shut * LidClosing(target, output, b);
      if (strength > 0.f) lines.push_back({k, strength});
    }
    if (lines.empty()) return;
    const gpu::VertexState ts = renderer.evaluate(target, nullptr, threads());
    const int w = camera.width, h = camera.height;
    // The upper margin of contour k (its first four points: corner, two upper lid points, corner)
    // in `state`, as points about a quarter pixel apart, each with its share of the way from the
    // first corner; empty when a point is behind the camera.
    auto margin = [&](size_t k, const gpu::VertexState& state, std::vector<float>* along) {
      std::array<Eigen::Vector2f, 4> c;
      for (size_t i = 0; i < 4; ++i) {
        const Eigen::Vector3f x = state.camera_positions.segment<3>(3 * lid_contours[k][i]);
        if (!(x.z() > camera.near_plane)) return std::vector<Eigen::Vector2f>{};
        c[i] = project(camera, x);
        // Far outside the frame or not finite: no line to draw (and no box to cast to pixels).
        if (!(c[i].cwiseAbs().maxCoeff() < 1e6f)) return std::vector<Eigen::Vector2f>{};
      }
      std::vector<Eigen::Vector2f> points;
      along->clear();
      for (int s = 0; s < 3; ++s) {
        const Eigen::Vector2f p0 = c[static_cast<size_t>(std::max(s - 1, 0))], p1 = c[static_cast<size_t>(s)],
                              p2 = c[static_cast<size_t>(s + 1)], p3 = c[static_cast<size_t>(std::min(s + 2, 3))];
        const int steps = std::max(1, static_cast<int>(std::ceil(4.f * (p2 - p1).norm())));
        for (int q = 0; q < steps; ++q) {
          const float t = static_cast<float>(q) / static_cast<float>(steps), t2 = t * t, t3 = t2 * t;
          points.push_back(0.5f * (2.f * p1 + (p2 - p0) * t + (2.f * p0 - 5.f * p1 + 4.f * p2 - p3) * t2 +
                                   (3.f * p1 - p0 - 3.f * p2 + p3) * t3));
          along->push_back((static_cast<float>(s) + t) / 3.f);
        }
      }
      points.push_back(c[3]);
      along->push_back(1.f);
      return points;
    };
    for (const auto& [k, strength] : lines) {
      // The target's lash colour (linear RGB).
      std::vector<float> along;
      const std::vector<Eigen::Vector2f> frame_margin = margin(k, ts, &along);
      std::vector<std::pair<float, Eigen::Vector3f>> seen;  // (brightest channel, colour)
      for (const Eigen::Vector2f& p : frame_margin)
        for (float dy : {-2.f, -1.f, 0.f}) {
          const float u = p.x(), v = p.y() + dy;
          if (!(u >= 0.f && v >= 0.f && u <= static_cast<float>(w - 1) && v <= static_cast<float>(h - 1))) continue;
          const Eigen::Vector3f c = sample_linear(target_bgr, u, v);
          seen.push_back({c.maxCoeff(), c});
        }
      const size_t darkest = seen.size() / 8;
      if (darkest < 4) continue;
      std::nth_element(seen.begin(), seen.begin() + static_cast<std::ptrdiff_t>(darkest), seen.end(),
                       [](const auto& a, const auto& b) { return a.first < b.first; });
      Eigen::Vector3f lash = Eigen::Vector3f::Zero();
      for (size_t q = 0; q < darkest; ++q) lash += seen[q].second;
      lash /= static_cast<float>(darkest);
      const float lash_luminance = luminance(lash);
      // The output's closed margin, and the line's half width.
      const std::vector<Eigen::Vector2f> line = margin(k, out_state, &along);
      if (line.size() < 2) continue;
      const float eye_width = (line.front() - line.back()).norm();
      const float half = std::max(0.5f, 0.5f * kLashLineWidth * eye_width);
      // Which end is the inner corner: iBUG 39 ends the right eye's contour (36-41), 42 starts the left's.
      const bool inner_last = lid_opening[k] == 0;
      cv::Rect box;
      for (const Eigen::Vector2f& p : line)
        box |= cv::Rect(static_cast<int>(std::floor(p.x() - half - 1.f)),
                        static_cast<int>(std::floor(p.y() - half - 1.f)), static_cast<int>(2.f * half) + 3,
                        static_cast<int>(2.f * half) + 3);
      box &= cv::Rect(0, 0, w, h);
      for (int j = box.y; j < box.y + box.height; ++j)
        for (int i = box.x; i < box.x + box.width; ++i) {
          if (!face_mask.at<uchar>(j, i)) continue;
          float best = std::numeric_limits<float>::infinity(), at = 0.f;
          for (size_t q = 0; q < line.size(); ++q) {
            const float d = (line[q] - Eigen::Vector2f(static_cast<float>(i), static_cast<float>(j))).squaredNorm();
            if (d < best) best = d, at = along[q];
          }
          // Covered as a line of width 2 * half would cover the pixel (a pixel's fade at its edge).
          const float cover = std::clamp(half + 0.5f - std::sqrt(best), 0.f, 1.f);
          if (!(cover > 0.f)) continue;
          // Lashes thin out towards the inner corner and end at both.
          const float from_inner = inner_last ? 1.f - at : at;
          const float taper =
              std::clamp(from_inner / 0.3f, 0.f, 1.f) * std::clamp((1.f - from_inner) / 0.05f, 0.f, 1.f);
          const float alpha = kLashLineOpacity * strength * cover * taper;
          if (!(alpha > 0.f)) continue;
          cv::Vec3f& px = rendered->at<cv::Vec3f>(j, i);
          Eigen::Vector3f now;  // linear RGB of the pixel
          for (int c = 0; c < 3; ++c) now[c] = srgb_decode(std::clamp(px[2 - c] / 255.f, 0.f, 1.f));
          if (!(lash_luminance < luminance(now))) continue;
          px = display_bgr((1.f - alpha) * now + alpha * lash);
        }
    }
  }

  // Per vertex, how far the face at `params` (identity and expression) unfolds its surface
  // (kFoldedLid): 0 where it shows it folded, 1 where unfolded or where a blink stretches nothing.
  std::vector<float> LidUnfolding(const gpu::FaceParameters& params) const {
    const int n = model.num_vertices();
    std::vector<float> share(static_cast<size_t>(n), 1.0f);
    if (lid_triangles.empty()) return share;
    const Eigen::Index ka = std::min<Eigen::Index>(params.alpha.size(), model.num_identity());
    const Eigen::Index kd = std::min<Eigen::Index>(params.delta.size(), model.num_expression());
    std::vector<Eigen::Vector3f> now(static_cast<size_t>(n)), closed(static_cast<size_t>(n));
    for (int32_t v : lid_vertices) {
      Eigen::Vector3f x = model.mean_shape.segment<3>(3 * v);
      if (ka > 0) x += model.identity_basis.block(3 * v, 0, 3, ka) * params.alpha.head(ka);
      if (kd > 0) x += model.expression_basis.block(3 * v, 0, 3, kd) * params.delta.head(kd);
      Eigen::Vector3f c = x;
      for (int b : blink_indices)
        c += (1.0f - std::clamp(expression_weight(params.delta, b), 0.0f, 1.0f)) * model.expression_basis.block(3 * v, b, 3, 1);
      now[static_cast<size_t>(v)] = x;
      closed[static_cast<size_t>(v)] = c;
    }
    std::vector<float> area_now(static_cast<size_t>(n), 0.f), area_closed(static_cast<size_t>(n), 0.f);
    auto area = [](const std::vector<Eigen::Vector3f>& x, const std::array<int32_t, 3>& t) {
      const Eigen::Vector3f& a = x[static_cast<size_t>(t[0])];
      return 0.5f * (x[static_cast<size_t>(t[1])] - a).cross(x[static_cast<size_t>(t[2])] - a).norm();
    };
    for (const auto& t : lid_triangles) {
      const float an = area(now, t), ac = area(closed, t);
      for (int32_t v : t) {
        area_now[static_cast<size_t>(v)] += an;
        area_closed[static_cast<size_t>(v)] += ac;
      }
    }
    for (int32_t v : lid_vertices) {
      const size_t i = static_cast<size_t>(v);
      if (!(area_closed[i] > area_now[i])) continue;
      share[i] = std::clamp((area_now[i] / area_closed[i] - kFoldedLid) / (kUnfoldedLid - kFoldedLid), 0.0f, 1.0f);
    }
    return share;
  }

  // eyeball_place, eyeball_vertices and eyeball_radius from the mean shape (the builder's eyeball
  // is an evenly spaced sphere looking along +z: docs/face-model.md).
  void FindEyeballPlaces() {
    const int n = model.num_vertices();
    eyeball_place.assign(static_cast<size_t>(n), Eigen::Vector3f::Zero());
    for (int v = 0; v < n; ++v)
      if (kEyeParts & part_bit(part_of(v))) eyeball_vertices[static_cast<size_t>(EyeSlot(part_of(v)))].push_back(v);
    for (size_t e = 0; e < 2; ++e) {
      if (eyeball_vertices[e].empty()) continue;
      Eigen::Vector3f centre = Eigen::Vector3f::Zero();
      for (int32_t v : eyeball_vertices[e]) centre += model.mean_shape.segment<3>(3 * v);
      centre /= static_cast<float>(eyeball_vertices[e].size());
      float radius = 0.f;
      for (int32_t v : eyeball_vertices[e]) {
        const Eigen::Vector3f d = model.mean_shape.segment<3>(3 * v) - centre;
        radius += d.norm();
        if (d.norm() > 0.f) eyeball_place[static_cast<size_t>(v)] = d.normalized();
      }
      eyeball_radius[e] = radius / static_cast<float>(eyeball_vertices[e].size());
    }
  }

  // in_mouth from the mean shape (model space: x to the person's left, y up, z towards the
  // viewer): every face vertex between the mouth corners, within 5 mm of the inner lip line's
  // height and more than 0.5 mm behind it (the line's depth interpolated along x over the upper
  // inner lip, iBUG 60-64). The lips' outer, red surface lies in front of
  // that line, the skin above and below the lips farther than 5 mm from it.
  void FindMouthInterior() {
    const int n = model.num_vertices();
    in_mouth.assign(static_cast<size_t>(n), 0);
    if (inner_lip_vertices.size() != 8) return;
    auto at = [&](int32_t v) { return Eigen::Vector3f(model.mean_shape.segment<3>(3 * v)); };
    std::vector<Eigen::Vector3f> line;  // iBUG 60..64 along x
    for (size_t k = 0; k <= 4; ++k) line.push_back(at(inner_lip_vertices[k]));
    std::sort(line.begin(), line.end(), [](const auto& a, const auto& b) { return a.x() < b.x(); });
    constexpr float kHalfHeightM = 0.005f, kBehindM = 0.0005f;
    for (int v = 0; v < n; ++v) {
      if (part_of(v) != FacePart::Face) continue;
      const Eigen::Vector3f x = at(v);
      if (x.x() < line.front().x() || x.x() > line.back().x()) continue;
      size_t k = 0;
      while (k + 2 < line.size() && x.x() > line[k + 1].x()) ++k;
      const float span = line[k + 1].x() - line[k].x();
      const float t = span > 0.f ? std::clamp((x.x() - line[k].x()) / span, 0.0f, 1.0f) : 0.f;
      const Eigen::Vector3f ref = (1.f - t) * line[k] + t * line[k + 1];
      if (std::abs(x.y() - ref.y()) < kHalfHeightM && x.z() < ref.z() - kBehindM) in_mouth[static_cast<size_t>(v)] = 1;
    }
  }

  // Face vertices 22-30 mm from the mouth's centre (the inner-lip vertices' mean) in the face's
  // plane and at most 15 mm behind it: the skin of the upper lip, the cheeks beside the mouth and
  // the chin, where a frame shows the actor's skin under this light (ViewMouth).
  void FindSkinAroundMouth() {
    if (inner_lip_vertices.size() != 8) return;
    Eigen::Vector3f centre = Eigen::Vector3f::Zero();
    for (int32_t v : inner_lip_vertices) centre += model.mean_shape.segment<3>(3 * v);
    centre /= 8.f;
    constexpr float kInnerM = 0.022f, kOuterM = 0.030f, kBehindM = 0.015f;
    for (int v = 0; v < model.num_vertices(); ++v) {
      if (part_of(v) != FacePart::Face || in_mouth[static_cast<size_t>(v)]) continue;
      const Eigen::Vector3f x = model.mean_shape.segment<3>(3 * v);
      const float r = (x - centre).head<2>().norm();
      if (r >= kInnerM && r <= kOuterM && x.z() >= centre.z() - kBehindM) skin_around_mouth.push_back(v);
    }
  }

  // The SH basis vertex v is lit at, from its camera-space normal and position: at lit_normal
  // (the fit's light within the normals it saw) for the skin; the mouth's own surfaces keep
  // their normal, their light has rules of its own (irradiance_at, the mouth pass).
  std::array<float, 9> lit_basis(int v, const Eigen::Vector3f& normal, const Eigen::Vector3f& position) const {
    const bool mouth = in_mouth[static_cast<size_t>(v)] || (kMouthParts & part_bit(part_of(v)));
    return gpu::sh_basis(mouth ? normal : lit_normal(normal, position));
  }

  // Irradiance of vertex v's channel c under `light` at the normal with SH basis `basis`.
  // Surfaces inside the mouth face up, down or away from the camera, where the SH fit is an
  // extrapolation floored at 15 % of its ambient part (irradiance()). Shaded so, the lips' inner
  // faces, seen edge-on in a barely opened mouth, drew a hard, nearly black slit with reddish
  // edges along the lips (on the webcam clip wherever the output's mouth opens a little wider
  // than the target's; mostly just outside the inner-lip polygon, where the mouth pass draws
  // nothing): darker than the cavity the mouth pass draws behind them.
  // They are lit by the light that enters the opening, as the cavity is (kCavityOcclusion of the
  // camera-facing irradiance), so that is their floor: a parted mouth's gap is then the lips'
  // colour darkening softly into the cavity colour as it opens, never darker than the cavity.
  // The output's shading, the frame texture's tracked shading (its re-lighting ratio) and the
  // albedo map's division all use this, so they stay consistent with one another. Teeth and
  // tongue keep the plain fit: lit so, the lower teeth seen through a barely opened gap drew
  // white specks on the webcam clip; the mouth pass shades them (no darker than the cavity).
  float irradiance_at(const Gamma& light, const std::array<float, 9>& basis, int c, int v) const {
    const float e = irradiance(light, basis, c);
    if (!in_mouth[static_cast<size_t>(v)]) return e;
    return std::max(e, entering_light(light, c));
  }
  static float entering_light(const Gamma& light, int c) {
    return internal::camera_facing_irradiance(light, c) * kCavityOcclusion;
  }

  // Skin vertices never observed (turned away, hidden) take the model albedo scaled by the
  // observed-to-model ratio of their surroundings: the ratio field is spread from the observed
  // vertices over the mesh (Jacobi iterations of neighbour averages), so an unseen cheek gets the
  // actor's skin tone, not the model's mean.
  void FillUnobserved(const Eigen::VectorXf& model_albedo, AlbedoMap* map) const {
    const int n = model.num_vertices();
    std::vector<Eigen::Vector3f> ratio(static_cast<size_t>(n), Eigen::Vector3f::Ones());
    std::vector<char> fixed(static_cast<size_t>(n), 0), skin(static_cast<size_t>(n), 0);
    std::vector<float> per_channel[3];
    for (int v = 0; v < n; ++v) {
      const FacePart p = part_of(v);
      skin[static_cast<size_t>(v)] = p == FacePart::Face || p == FacePart::Scalp || p == FacePart::Ear || p == FacePart::Neck;
      if (!skin[static_cast<size_t>(v)] || !(map->weight[v] > 0.f)) continue;
      for (int c = 0; c < 3; ++c) {
        const float r = std::clamp(map->albedo[3 * v + c] / std::max(model_albedo[3 * v + c], 1e-3f), 0.2f, 5.0f);
        ratio[static_cast<size_t>(v)][c] = r;
        per_channel[c].push_back(r);
      }
      fixed[static_cast<size_t>(v)] = 1;
    }
    if (per_channel[0].empty()) return;
    Eigen::Vector3f median;
    for (int c = 0; c < 3; ++c) {
      auto& pc = per_channel[c];
      std::nth_element(pc.begin(), pc.begin() + static_cast<std::ptrdiff_t>(pc.size() / 2), pc.end());
      median[c] = pc[pc.size() / 2];
    }
    for (int v = 0; v < n; ++v)
      if (skin[static_cast<size_t>(v)] && !fixed[static_cast<size_t>(v)]) ratio[static_cast<size_t>(v)] = median;
    constexpr int kIterations = 25;
    for (int it = 0; it < kIterations; ++it) {
      for (int v = 0; v < n; ++v) {
        if (!skin[static_cast<size_t>(v)] || fixed[static_cast<size_t>(v)]) continue;
        Eigen::Vector3f sum = Eigen::Vector3f::Zero();
        int count = 0;
        for (int32_t nb : neighbours[static_cast<size_t>(v)]) {
          if (!skin[static_cast<size_t>(nb)]) continue;
          sum += ratio[static_cast<size_t>(nb)];
          ++count;
        }
        if (count) ratio[static_cast<size_t>(v)] = sum / static_cast<float>(count);
      }
    }
    for (int v = 0; v < n; ++v) {
      if (!skin[static_cast<size_t>(v)] || fixed[static_cast<size_t>(v)]) continue;
      for (int c = 0; c < 3; ++c)
        map->albedo[3 * v + c] = std::clamp(model_albedo[3 * v + c] * ratio[static_cast<size_t>(v)][c], 0.0f, 1.0f);
    }
  }

  gpu::Renderer* vulkan() const {
    if (options.renderer != RendererKind::kVulkan || !vk_failure.empty()) return nullptr;
    if (!vk_renderer) {
      try {
        gpu::Context::Options co;
        vk_context = std::make_unique<gpu::Context>(co);
        gpu::Renderer::Options ro;
        ro.timestamps = false;
        vk_renderer = std::make_unique<gpu::Renderer>(*vk_context, renderer.model(), ro);
      } catch (const Error& e) {
        vk_renderer.reset();
        vk_context.reset();
        vk_failure = e.what();
        return nullptr;
      }
    }
    return vk_renderer.get();
  }

  int threads() const { return ResolvedThreadCount(options.render_threads); }

  // The G-buffer of `state` (evaluated at `params`) into `out`, rasterised by Vulkan or the CPU
  // twin. The colour channel is always the Gouraud interpolation of state.colors (the
  // compositor's own shading: albedo map, rendering lighting), whichever rasteriser ran.
  void rasterize(const gpu::VertexState& state, const gpu::FaceParameters& params, const gpu::PinholeCamera& camera,
                 const gpu::RenderOptions& ropt, gpu::GBuffer* out) const {
    gpu::Renderer* vk = vulkan();
    if (!vk) {
      renderer.rasterize(state, camera, ropt, out, threads());
      return;
    }
    // Only the face's box comes back: `state` is the same evaluation the device makes of `params`,
    // so its vertices bound every pixel drawn (2 pixels for the two evaluations' rounding).
    const gpu::PixelBox box = gpu::ProjectedBox(state, camera, 2);
    vk->render(params, camera, ropt);
    vk->read_gbuffer(out, &box);
    gpu::GBuffer& g = *out;
    if (box.empty()) return;
    ParallelFor(box.j1 - box.j0 + 1, threads(), [&](int row) {
      const size_t first = static_cast<size_t>(box.j0 + row) * static_cast<size_t>(g.width);
      for (size_t p = first + box.i0; p <= first + box.i1; ++p) {
        if (g.triangle[p] < 0) continue;
        for (int c = 0; c < 3; ++c) {
          float v = 0.f;
          for (int k = 0; k < 3; ++k)
            v += g.barycentric[3 * p + static_cast<size_t>(k)] *
                 state.colors[3 * g.vertices[3 * p + static_cast<size_t>(k)] + c];
          g.color[3 * p + static_cast<size_t>(c)] = v;
        }
      }
    });
  }

  // The albedo texture's colour of drawn pixels whose triangle it covers: the texture's albedo at
  // the pixel's UV times the interpolation of a per-vertex factor, the per-vertex map's change
  // since the texture was blended (`map` against texture.base, per channel, bounded to 0.5..2)
  // times the irradiance Compose lit the vertex with (`shade`). The texture adds the detail, the
  // map keeps the colour current (a camera's exposure drifting, later frames refining it).
  struct TextureShading {
    const AlbedoTexture* texture = nullptr;
    std::vector<Eigen::Vector3f> factor;  // per vertex
    bool Colour(const FaceModel& model, const gpu::GBuffer& g, size_t p, Eigen::Vector3f* rgb,
                float* seen_weight = nullptr) const {
      const int32_t t = g.triangle[p];
      if (t < 0 || !texture->layout->textured[static_cast<size_t>(t)]) return false;
      Eigen::Vector2f uv = Eigen::Vector2f::Zero();
      Eigen::Vector3f f = Eigen::Vector3f::Zero();
      for (size_t k = 0; k < 3; ++k) {
        const float b = g.barycentric[3 * p + k];
        const auto& c = model.corner_uvs[3 * static_cast<size_t>(t) + k];
        uv += b * Eigen::Vector2f(c[0], c[1]);
        f += b * factor[static_cast<size_t>(g.vertices[3 * p + k])];
      }
      Eigen::Vector3f a;
      if (!texture->Sample(uv, &a, seen_weight)) return false;
      *rgb = a.cwiseProduct(f);
      return true;
    }
  };
  // Null texture (none, or of another model): an empty TextureShading (texture null).
  TextureShading MakeTextureShading(const AlbedoTexture* texture, const Eigen::VectorXf& map,
                                    const std::vector<Eigen::Vector3f>& shade) const {
    TextureShading ts;
    if (!texture || texture->empty() || !texture->layout || texture->layout->textured.size() != model.triangles.size() ||
        texture->base.size() != map.size() || static_cast<size_t>(map.size()) != 3 * shade.size())
      return ts;
    ts.texture = texture;
    ts.factor.resize(shade.size());
    for (size_t v = 0; v < shade.size(); ++v)
      for (int c = 0; c < 3; ++c) {
        const float then = texture->base[static_cast<Eigen::Index>(3 * v) + c], now = map[static_cast<Eigen::Index>(3 * v) + c];
        ts.factor[v][c] = (then > 1e-4f ? std::clamp(now / then, 0.5f, 2.0f) : 1.0f) * shade[v][c];
      }
    return ts;
  }
  // Appearance::kAlbedoMap: every pixel the texture covers takes its colour.
  void ApplyAlbedoTexture(const TextureShading& ts, gpu::GBuffer* g) const {
    ParallelFor(g->height, threads(), [&](int j) {
      Eigen::Vector3f rgb;
      for (int i = 0; i < g->width; ++i) {
        const size_t p = static_cast<size_t>(j) * static_cast<size_t>(g->width) + static_cast<size_t>(i);
        if (!ts.Colour(model, *g, p, &rgb)) continue;
        for (int c = 0; c < 3; ++c) g->color[3 * p + static_cast<size_t>(c)] = rgb[c];
      }
    });
  }

  // Distance (pixels, over `roi`) from each pixel of `tg` (the target's rendering of `ts`) to the
  // nearest occluding boundary: a change of surface between neighbouring pixels (nothing drawn,
  // skin, an eyeball, teeth, tongue), a depth jump within one surface (an occluding contour such
  // as the nose on a turned head), and the seam contours (a closed mouth or eye shows neither),
  // the inner lip line only `with_lip_seam` (without it, the lids' alone). Across such a boundary
  // the frame shows something else than the surface on this side.
  cv::Mat BoundaryDistance(const gpu::GBuffer& tg, const gpu::VertexState& ts, const gpu::PinholeCamera& camera,
                           const cv::Rect& roi, bool with_lip_seam = true) const {
    constexpr float kDepthJumpM = 0.01f;  // ~10 pixel footprints at 0.6 m: no smooth surface but a grazing one
    const int w = camera.width;
    cv::Mat open(roi.size(), CV_8UC1, cv::Scalar(255));  // 0 on the boundary
    auto surface = [&](size_t p) { return tg.triangle[p] < 0 ? -1 : static_cast<int>(part_of(tg.vertices[3 * p])); };
    // A pixel is on the boundary when it differs from any of its four neighbours within roi (the
    // test is symmetric), so each pixel decides its own: rows on the pool's threads.
    ForRowsOf(roi, [&](int row) {
      const int j = roi.y + row;
      for (int i = roi.x; i < roi.x + roi.width; ++i) {
        const size_t p = static_cast<size_t>(j) * w + i;
        const int sp = surface(p);
        for (const auto& [di, dj] : {std::pair{1, 0}, std::pair{0, 1}, std::pair{-1, 0}, std::pair{0, -1}}) {
          const int ni = i + di, nj = j + dj;
          if (ni < roi.x || nj < roi.y || ni >= roi.x + roi.width || nj >= roi.y + roi.height) continue;
          const size_t q = static_cast<size_t>(nj) * w + ni;
          if (sp == surface(q) && (sp < 0 || std::abs(tg.position[3 * p + 2] - tg.position[3 * q + 2]) <= kDepthJumpM))
            continue;
          open.at<uchar>(row, i - roi.x) = 0;
          break;
        }
      }
    });
    DrawContours(with_lip_seam ? seam_contours : lid_contours, ts, camera, roi.tl(), &open);
    cv::Mat dist;
    cv::distanceTransform(open, dist, cv::DIST_L2, cv::DIST_MASK_3);
    return dist;
  }

  // Each closed contour (vertex indices) as `state` projects it, a 1 px line of 0 in `open` (whose
  // pixel (0, 0) is the image's `origin`). A contour with a point at or behind the near plane is
  // left out.
  static void DrawContours(const std::vector<std::vector<int32_t>>& contours, const gpu::VertexState& state,
                           const gpu::PinholeCamera& camera, const cv::Point& origin, cv::Mat* open) {
    for (const auto& contour : contours) {
      const std::vector<cv::Point> line = PixelContour(contour, state, camera, origin);
      if (!line.empty()) cv::polylines(*open, line, true, cv::Scalar(0), 1, cv::LINE_8);
    }
  }
  // `contour`'s vertices at `state` projected and rounded to pixels, relative to `origin`; empty
  // when any of them is not in front of the camera.
  static std::vector<cv::Point> PixelContour(const std::vector<int32_t>& contour, const gpu::VertexState& state,
                                             const gpu::PinholeCamera& camera, const cv::Point& origin = cv::Point(0, 0)) {
    std::vector<cv::Point> line;
    for (int32_t v : contour) {
      const Eigen::Vector3f x = state.camera_positions.segment<3>(3 * v);
      if (!(x.z() > camera.near_plane)) return {};
      const Eigen::Vector2f uv = project(camera, x);
      line.emplace_back(pixel_round(uv.x()) - origin.x, pixel_round(uv.y()) - origin.y);
    }
    return line;
  }
  // The colour of the open eyes (`eyes`, evaluated and rasterised as `eyes_state` and `eyes_g`,
  // `eyes_edge` their BoundaryDistance over the crop) at the surface point of output pixel p of
  // `g`, an eyeball pixel of `part`, into `colour`, with its `trust` (eyeball_edge_trust: every
  // such sample moves); nothing where they do not show it.
  void SampleOpenEyes(const EyeExemplar& eyes, const gpu::VertexState& eyes_state, const gpu::GBuffer& eyes_g,
                      const cv::Mat& eyes_edge, const FrameOpening& opening, const gpu::GBuffer& g, size_t p,
                      FacePart part, cv::Vec3f* colour, float* trust) const {
    Eigen::Vector3f x = Eigen::Vector3f::Zero();
    for (int k = 0; k < 3; ++k)
      x += g.barycentric[3 * p + static_cast<size_t>(k)] * eyes_state.camera_positions.segment<3>(3 * g.vertices[3 * p + static_cast<size_t>(k)]);
    if (!(x.z() > eyes.camera.near_plane)) return;
    const Eigen::Vector2f u = project(eyes.camera, x);
    const float cu = u.x() - static_cast<float>(eyes.origin.x), cv_ = u.y() - static_cast<float>(eyes.origin.y);
    if (!(cu >= 0.f && cv_ >= 0.f && cu <= static_cast<float>(eyes.bgr.cols - 1) && cv_ <= static_cast<float>(eyes.bgr.rows - 1))) return;
    // Within the frame's real opening where it is known (eye_aperture.h), else where its fit
    // draws this eyeball.
    const float inside = opening.Inside(u.x(), u.y());
    if (!opening.empty()) {
      if (!(inside > 0.f)) return;
    } else {
      const size_t q = static_cast<size_t>(std::lround(u.y())) * eyes_g.width + static_cast<size_t>(std::lround(u.x()));
      if (eyes_g.triangle[q] < 0 || part_of(eyes_g.vertices[3 * q]) != part ||
          std::abs(eyes_g.position[3 * q + 2] - x.z()) > std::max(kShownToleranceM, 1.5f * x.z() / eyes.camera.fx))
        return;
    }
    const Eigen::Vector3f seen = sample_linear(eyes.bgr, cu, cv_);
    *colour = cv::Vec3f(std::min(1.0f, seen[0]), std::min(1.0f, seen[1]), std::min(1.0f, seen[2]));
    *trust = eyeball_edge_trust(opening.empty() ? sample_float(eyes_edge, cu, cv_) : inside);
  }
  // The per-eye arrays' slot of an eyeball part: 0 the left eye (LeftEye), 1 the right.
  static int EyeSlot(FacePart part) { return part == FacePart::LeftEye ? 0 : 1; }

  // How far apart `state` holds the inner lips, as a share of the mouth's width: the largest of
  // the projected distances between iBUG 61 and 67, 62 and 66, 63 and 65 over the distance from
  // 60 to 64 (infinite when the model has no inner lip landmarks or one is not in front of the
  // camera).
  float InnerLipGap(const gpu::VertexState& state, const gpu::PinholeCamera& camera) const {
    const std::vector<Eigen::Vector2f> at = Opening(camera, state);
    if (at.size() != 8) return std::numeric_limits<float>::infinity();
    float gap = 0.f;
    for (size_t k = 1; k <= 3; ++k) gap = std::max(gap, (at[k] - at[8 - k]).norm());
    const float width = (at[4] - at[0]).norm();
    return width > 0.f ? gap / width : std::numeric_limits<float>::infinity();
  }
  // Lips further apart than this share of the mouth's width are parted (InnerLipGap). The
  // model's inner lip vertices do not meet where real lips close: over the webcam clip's 284
  // frames (its fits, d6 reenacted onto it) the gap was 0.02-0.04 on 158, its closed mouth, and
  // its talking mouth's a second cluster at 0.10-0.16, with 9 frames at 0.08-0.10 between.
  static constexpr float kLipsParted = 0.08f;

  // Appearance::kFrameTexture: every drawn pixel of `g` (the output's G-buffer)
  // whose surface point the target frame shows takes that frame's colour there, times the
  // change of the point's shading from the tracked normal to the output's. The surface point is
  // the pixel's triangle and barycentrics evaluated on the target's tracked geometry; it is
  // shown when the target's own G-buffer at its projection lies at its depth. Other pixels keep
  // the albedo map: `fallback_texture`'s colour where it covers the surface (the texture is looked
  // up only where some of the map shows), else g->color. `e_out`: the output's per-vertex
  // irradiance (uncapped), as Compose computed it for the shading. `mouth_redraw`: how much of the mouth opening the
  // mouth pass will replace (0..1). `shown` (optional): set to the frame's trust in its own sample
  // at each drawn pixel (0..1; 0 where the frame does not show the surface), frame-sized, CV_32FC1.
  //
  // A shown sample is still not trusted near an occluding boundary of the target's rendering
  // (BoundaryDistance; grazing views count too): the fit is off by a pixel or two, so a lip
  // point there samples the mouth cavity or the teeth, a lid point the eyeball, a chin point
  // the neck. Left in place that sample shows what the frame shows there anyway. Moved by the
  // output expression, or next to a mouth opening the mouth pass redraws, it draws a dark or
  // white line along the lips and strokes on the cheek or neck. There the frame's weight fades to
  // the albedo map over options.frame_texture_boundary_px (smooth in distance and in motion, so
  // the fallback draws no seam of its own).
  void ApplyFrameTexture(const cv::Mat& target_bgr, const gpu::PinholeCamera& camera,
                         const gpu::FaceParameters& target, const gpu::FaceParameters& output,
                         const gpu::VertexState& out_state, const std::vector<Eigen::Vector3f>& e_out,
                         const Gamma& light, const gpu::RenderOptions& ropt, float mouth_redraw,
                         const TextureShading& fallback_texture, gpu::GBuffer* g, cv::Mat* shown = nullptr,
                         const EyeExemplar* open_eyes = nullptr, bool* eyes_drawn = nullptr,
                         const EyeOpenings* openings = nullptr, const Eigen::VectorXf* map_weight = nullptr) const {
    const int w = camera.width, h = camera.height, n = model.num_vertices();
    if (shown) {
      shown->create(h, w, CV_32FC1);
      shown->setTo(0.0f);
    }
    if (eyes_drawn) *eyes_drawn = false;

    const cv::Rect box = covered_rect(*g, 2);  // the drawn pixels to texture
    if (box.empty()) return;
    // The tracked geometry (the output's own when only the lighting or albedo differ).
    const bool same = same_geometry(target, output);
    gpu::VertexState target_state;
    gpu::GBuffer& target_g = scratch_gbuffer(1);
    if (!same) {
      // Its colours are never read (the irradiance below is the compositor's own).
      target_state = renderer.evaluate(target, nullptr, threads(), gpu::VertexColors::kNone);
      gpu::RenderOptions tracked_ropt = ropt;
      tracked_ropt.normals = false;  // read below: which surface, its vertices and depth
      tracked_ropt.colors = false;
      rasterize(target_state, target, camera, tracked_ropt, &target_g);
    }
    const gpu::VertexState& ts = same ? out_state : target_state;
    const gpu::GBuffer& tg = same ? *g : target_g;
    // Per-vertex irradiance at the tracked normals, under the lighting e_out (the output's, at
    // its normals) was computed with.
    std::vector<Eigen::Vector3f> tracked_irradiance;
    if (!same) {
      tracked_irradiance.resize(static_cast<size_t>(n));
      ForVerticesOf(n, [&](int v) {
        const auto basis = lit_basis(v, ts.camera_normals.segment<3>(3 * v), ts.camera_positions.segment<3>(3 * v));
        for (int c = 0; c < 3; ++c) tracked_irradiance[static_cast<size_t>(v)][c] = irradiance_at(light, basis, c, v);
      });
    }
    const std::vector<Eigen::Vector3f>& e_target = same ? e_out : tracked_irradiance;
    // The boundary distance of the tracked rendering; none needed for the same geometry (every
    // sample lands on its own pixel, and the mouth keeps the target's: nothing is redrawn).
    const float ramp_px = options.frame_texture_boundary_px;
    const bool distrust = !same && ramp_px > 0.f;
    cv::Rect roi, mouth_zone;
    std::vector<std::pair<cv::Rect, float>> closing_lids;  // (zone, how much the output closes it further)
    cv::Mat boundary_px;
    if (distrust) {
      const int margin = static_cast<int>(std::ceil(ramp_px)) + 2;
      roi = covered_rect(tg, margin);
      // Not the inner lip line where both the target and the output hold the lips closed:
      // across it the frame shows the other lip and the seam where they meet, which is what the
      // output's closed lips are to show there too. Held as a boundary, it distrusted the samples
      // in a band as tall as the ramp, and the output's seam was what the fill and the albedo map
      // drew there: a dotted or dashed dark line where the lips' inner faces fell on pixel
      // centres, nothing between (d6 pressing her lips onto the webcam clip, output frame 120;
      // d14 onto it, 30). Lips the output parts keep it: trusted, the target's seam was drawn as
      // a dark rim along the opened upper lip (d6 onto the webcam clip, frame 30).
      const bool lips_closed = InnerLipGap(ts, camera) <= kLipsParted && InnerLipGap(out_state, camera) <= kLipsParted;
      if (!roi.empty()) boundary_px = BoundaryDistance(tg, ts, camera, roi, /*with_lip_seam=*/!lips_closed);
      // Samples landing here are next to the opening the mouth pass redraws.
      if (mouth_redraw > 0.f) {
        for (int32_t v : inner_lip_vertices) {
          const Eigen::Vector3f x = ts.camera_positions.segment<3>(3 * v);
          if (!(x.z() > camera.near_plane)) continue;
          const Eigen::Vector2f uv = project(camera, x);
          mouth_zone |= cv::Rect(pixel_floor(uv.x()), pixel_floor(uv.y()), 2, 2);
        }
        mouth_zone = mouth_zone + cv::Size(2 * margin, 2 * margin) - cv::Point(margin, margin);
      }
      // Samples landing here are next to lids the output closes further than the target: the
      // frame shows an open eye's margin there (the lower lid's rim, a sliver of the eyeball the
      // fit misses by a pixel), which an unmoved sample keeps; beside a closed lid that rim drew a
      // light line along the lash line (d14 smiling with her eyes shut onto the webcam clip, output
      // frame 95: the lower lids' samples, unmoved and trusted, were the frame's eye white and
      // rim). How much: the extra blink over kLidCloseSpan.
      for (size_t k = 0; k < lid_contours.size(); ++k) {
        const int b = lid_blink_index[k];
        const float closing = LidClosing(target, output, b);
        if (!(closing > 0.f)) continue;
        cv::Rect zone;
        for (int32_t v : lid_contours[k]) {
          const Eigen::Vector3f x = ts.camera_positions.segment<3>(3 * v);
          if (!(x.z() > camera.near_plane)) continue;
          const Eigen::Vector2f uv = project(camera, x);
          zone |= cv::Rect(pixel_floor(uv.x()), pixel_floor(uv.y()), 2, 2);
        }
        if (zone.empty()) continue;
        closing_lids.push_back({zone + cv::Size(2 * margin, 2 * margin) - cv::Point(margin, margin), closing});
      }
    }
    // The eyes' inner corners in the frame, and each eye's width there: the corner holds the
    // caruncle, pink flesh the model's eyeball covers (its lids are fitted to the corners' landmarks,
    // not to where the white begins). The caruncle does not turn with the eye; an eyeball sample the
    // gaze moves onto it drew a pink patch on the white (d6 looking hard aside onto d10, output
    // frame 120: the samples moved 9 px toward the nose). Moved samples that land within
    // kCaruncleShare of the eye's width from the inner corner are not trusted (full trust from
    // twice that); unmoved ones keep the frame's own corner.
    constexpr float kCaruncleShare = 0.1f;
    std::vector<std::pair<Eigen::Vector2f, float>> inner_corners;  // (position, eye width) in pixels
    if (distrust)
      for (const auto& [inner, outer] : eye_corners) {
        const Eigen::Vector3f a = ts.camera_positions.segment<3>(3 * inner), b = ts.camera_positions.segment<3>(3 * outer);
        if (!(a.z() > camera.near_plane) || !(b.z() > camera.near_plane)) continue;
        const Eigen::Vector2f ua = project(camera, a);
        const float width = (project(camera, b) - ua).norm();
        if (width > 1.f) inner_corners.push_back({ua, width});
      }
    // An eye the target holds closed (a blink) and the output open: the frame shows its lids
    // where the output shows the eyeball, and the eyeball took the fill and the map (on the webcam
    // clip, blinking at output frames 19 and 20 under d14's open eyes: an orange-brown iris and the
    // model's white, or skin, for two frames of every blink). That eyeball takes the actor's open
    // eyes (`open_eyes`), sampled at its surface points in that frame's fit as the frame is here,
    // unless the frame shows most of it after all (below: an eye held a little narrower than the
    // one the fit calls open).
    constexpr float kExemplarMargin = 0.1f;
    std::array<bool, 2> from_exemplar{false, false};  // LeftEye, RightEye
    gpu::VertexState exemplar_state;
    gpu::GBuffer* exemplar_g = nullptr;
    cv::Mat exemplar_edge;
    std::array<FrameOpening, 2> exemplar_openings;  // its real openings, where known
    const cv::Rect open_eyes_crop = open_eyes ? cv::Rect(open_eyes->origin, open_eyes->bgr.size()) & cv::Rect(0, 0, w, h) : cv::Rect();
    if (distrust && open_eyes && !open_eyes->empty() && open_eyes->camera.width == w && open_eyes->camera.height == h &&
        open_eyes_crop.size() == open_eyes->bgr.size()) {
      for (size_t k = 0; k < lid_contours.size(); ++k) {
        const int b = lid_blink_index[k];
        const float closed = expression_weight(target.delta, b);
        from_exemplar[static_cast<size_t>(lid_eye_slot[k])] =
            closed > kClosedForExemplar && expression_weight(output.delta, b) < closed - kExemplarMargin;
      }
      if (from_exemplar[0] || from_exemplar[1]) {
        exemplar_state = renderer.evaluate(open_eyes->params, nullptr, threads());
        exemplar_g = &scratch_gbuffer(3);
        rasterize(exemplar_state, open_eyes->params, open_eyes->camera, ropt, exemplar_g);
        exemplar_edge = BoundaryDistance(*exemplar_g, exemplar_state, open_eyes->camera, open_eyes_crop);
        const auto real =
            EyeApertures(open_eyes->openings, open_eyes->params, exemplar_state, exemplar_state, open_eyes->camera, true);
        for (size_t e = 0; e < 2; ++e)
          if (real[e]) exemplar_openings[e] = FrameOpening(*real[e], w, h);
      }
    }
    // The eyes' real openings (eye_aperture.h): the output's eyeball drawn within the output's,
    // its lids kept where the frame shows them, the frame's eyeball samples taken within the frame's.
    std::array<std::optional<internal::EyeAperture>, 2> apertures;  // LeftEye, RightEye
    std::array<FrameOpening, 2> frame_openings;
    std::vector<LidPixel> lid_pixels;
    if (distrust && openings) {
      apertures = EyeApertures(*openings, target, ts, out_state, camera);
      if (apertures[0] || apertures[1]) {
        lid_pixels = OpenEyesToApertures(apertures, output, out_state, camera, ropt, g);
        for (size_t e = 0; e < 2; ++e)
          if (apertures[e]) frame_openings[e] = FrameOpening(*apertures[e], w, h);
      }
    }
    constexpr float kMinShadingRatio = 0.5f, kMaxShadingRatio = 2.0f;
    cv::Mat weight = cv::Mat::zeros(box.size(), CV_32FC1), covered = cv::Mat::zeros(box.size(), CV_32FC1);
    cv::Mat texture = cv::Mat::zeros(box.size(), CV_32FC3);  // (set where a sample is taken)
    cv::Mat sampled_at(box.size(), CV_32FC2, cv::Scalar(std::nanf(""), std::nanf("")));  // the frame position sampled
    // The frame's sample and the change of shading apart, for the smoothing below (only where the
    // geometry changes: the same geometry keeps a ratio of 1 and needs neither).
    cv::Mat seen_at, ratio_at;
    if (!same) seen_at = cv::Mat::zeros(box.size(), CV_32FC3), ratio_at = cv::Mat::zeros(box.size(), CV_32FC3);
    cv::Mat exemplar_texture, exemplar_weight;  // the open eyes' samples (with exemplar_g)
    if (exemplar_g) exemplar_texture = cv::Mat::zeros(box.size(), CV_32FC3), exemplar_weight = cv::Mat::zeros(box.size(), CV_32FC1);
    // Rows of the box on the pool's threads: each pixel writes only its own texture, weight and
    // coverage, so the result is the same for any thread count.
    ForRowsOf(box, [&](int bj) {
      const int j = box.y + bj;
      for (int i = box.x; i < box.x + box.width; ++i) {
        const size_t p = static_cast<size_t>(j) * w + i;
        if (g->triangle[p] < 0) continue;
        const int bi = i - box.x;
        covered.at<float>(bj, bi) = 1.0f;
        const FacePart pixel_part = part_of(g->vertices[3 * p]);
        const bool eyeball = kEyeParts & part_bit(pixel_part);
        // The open eyes' sample too, for an eye the target holds closed (chosen per eye below).
        if (eyeball && from_exemplar[static_cast<size_t>(EyeSlot(pixel_part))])
          SampleOpenEyes(*open_eyes, exemplar_state, *exemplar_g, exemplar_edge,
                         exemplar_openings[static_cast<size_t>(EyeSlot(pixel_part))], *g, p, pixel_part,
                         &exemplar_texture.at<cv::Vec3f>(bj, bi), &exemplar_weight.at<float>(bj, bi));
        Eigen::Vector3f x = Eigen::Vector3f::Zero(), eo = Eigen::Vector3f::Zero(), et = Eigen::Vector3f::Zero(),
                        nt = Eigen::Vector3f::Zero();
        for (int k = 0; k < 3; ++k) {
          const int32_t v = g->vertices[3 * p + static_cast<size_t>(k)];
          const float b = g->barycentric[3 * p + static_cast<size_t>(k)];
          x += b * ts.camera_positions.segment<3>(3 * v);
          nt += b * ts.camera_normals.segment<3>(3 * v);
          eo += b * e_out[static_cast<size_t>(v)];
          et += b * e_target[static_cast<size_t>(v)];
        }
        if (!(x.z() > camera.near_plane)) continue;
        const Eigen::Vector2f uv = project(camera, x);
        const float u = uv.x(), vv = uv.y();
        if (!(u >= 0.f && vv >= 0.f && u <= static_cast<float>(w - 1) && vv <= static_cast<float>(h - 1))) continue;
        const size_t q = static_cast<size_t>(std::lround(vv)) * w + static_cast<size_t>(std::lround(u));
        // An eye whose real opening is known: its eyeball is shown wherever that opening holds
        // the sample, and no skin from more than a pixel inside it (the frame's eyeball there:
        // the fit's lid over it took the iris, a dark crescent under the output's lower lid).
        const FrameOpening* opening = eyeball ? &frame_openings[static_cast<size_t>(EyeSlot(pixel_part))] : nullptr;
        const float inside_px = opening && !opening->empty() ? opening->Inside(u, vv) : 0.f;
        if (opening && !opening->empty()) {
          if (!(inside_px > 0.f)) continue;
        } else {
          if (!eyeball && (frame_openings[0].Inside(u, vv) > kEyeballEdgePx || frame_openings[1].Inside(u, vv) > kEyeballEdgePx))
            continue;
          // Not shown: nothing of the model there, or a surface at another depth (the point is
          // hidden in the frame).
          if (tg.triangle[q] < 0) continue;
          const float tolerance = std::max(kShownToleranceM, 1.5f * x.z() / camera.fx);
          if (std::abs(tg.position[3 * q + 2] - x.z()) > tolerance) continue;
          // An eyeball point is shown only where the frame shows an eyeball: a lid lies a few
          // millimetres in front of it, within the tolerance, and its skin drew the eyes opened
          // wider than the target's with skin-coloured bands.
          if (eyeball && !(kEyeParts & part_bit(part_of(tg.vertices[3 * q])))) continue;
        }
        sampled_at.at<cv::Vec2f>(bj, bi) = cv::Vec2f(u, vv);
        const Eigen::Vector3f seen = sample_linear(target_bgr, u, vv);
        const Eigen::Vector3f ratio = internal::shading_change(eo, et).cwiseMax(kMinShadingRatio).cwiseMin(kMaxShadingRatio);
        cv::Vec3f& t = texture.at<cv::Vec3f>(bj, bi);
        for (int c = 0; c < 3; ++c) t[c] = std::min(1.0f, seen[c] * ratio[c]);
        if (!same) {
          seen_at.at<cv::Vec3f>(bj, bi) = cv::Vec3f(seen[0], seen[1], seen[2]);
          ratio_at.at<cv::Vec3f>(bj, bi) = cv::Vec3f(ratio[0], ratio[1], ratio[2]);
        }
        float trust = 1.0f;
        // 0 while the sample stays within half a pixel of its own pixel, 1 from 1.5 px on.
        const float moved = std::clamp(std::hypot(static_cast<float>(i) - u, static_cast<float>(j) - vv) - 0.5f, 0.0f, 1.0f);
        // The eyeballs keep the frame wherever it shows them: a gaze turn moves every eyeball
        // sample, all of them lie within a few pixels of the lids, and the per-vertex albedo map
        // holds no iris (it drew the eyes reddish brown on the webcam clip); the frame's iris
        // moved by the gaze is what the reenactment is to show. Not the caruncle, and not the
        // eyeball's edge (eyeball_edge_trust), where the fill by place does better.
        if (eyeball && moved > 0.f) {
          for (const auto& [corner, width] : inner_corners) {
            const float share = (Eigen::Vector2f(u, vv) - corner).norm() / width;
            const float away = std::clamp(share / kCaruncleShare - 1.0f, 0.0f, 1.0f);
            trust = std::min(trust, 1.0f - moved * (1.0f - away));
          }
          if (opening && !opening->empty()) {
            trust = std::min(trust, 1.0f - moved * (1.0f - eyeball_edge_trust(inside_px)));
          } else if (!boundary_px.empty()) {
            const float edge = eyeball_edge_trust(sample_float(boundary_px, u - static_cast<float>(roi.x), vv - static_cast<float>(roi.y)));
            trust = std::min(trust, 1.0f - moved * (1.0f - edge));
          }
        }
        if (!boundary_px.empty() && !eyeball) {
          const cv::Point at(static_cast<int>(u), static_cast<int>(vv));
          float exposed = std::max(moved, mouth_zone.contains(at) ? mouth_redraw : 0.0f);
          for (const auto& [zone, closing] : closing_lids)
            if (zone.contains(at)) exposed = std::max(exposed, closing);
          if (exposed > 0.f) {
            const float d = sample_float(boundary_px, u - static_cast<float>(roi.x), vv - static_cast<float>(roi.y));
            const float away = std::clamp(2.0f * d / ramp_px - 1.0f, 0.0f, 1.0f);
            // Grazing views (the tracked normal within ~80 degrees of the view ray) are smeared
            // and sit at silhouettes.
            const float cos_view = -nt.normalized().dot(x.normalized());
            const float facing = std::clamp((cos_view - 0.1f) / 0.2f, 0.0f, 1.0f);
            trust = 1.0f - exposed * (1.0f - away * facing);
          }
        }
        weight.at<float>(bj, bi) = trust;
      }
    });
    // The change of shading, smoothed over about a pixel. It comes from per-vertex irradiance, and
    // where the output's expression folds the mesh (a lower lip rolled out by the source's grimace)
    // the normals of one row of narrow triangles along the crease turn away from the light: the
    // ratio fell to 0.76 for one pixel row along the lower lip's bottom edge and drew a dotted dark
    // line there (d6 onto the webcam clip, frame 60; the frame's own edge is a smooth 4-pixel
    // ramp). Smoothed over the shown pixels only (a normalised convolution), so no colour leaks
    // across what the frame does not show. The same geometry changes nothing (the ratio is 1).
    constexpr double kShadingSmoothSigmaPx = 1.0;
    if (!same) {
      cv::Mat shown_mask(box.size(), CV_32FC1);
      ForRowsOf(box, [&](int bj) {
        for (int bi = 0; bi < box.width; ++bi)
          shown_mask.at<float>(bj, bi) = std::isnan(sampled_at.at<cv::Vec2f>(bj, bi)[0]) ? 0.f : 1.f;
      });
      cv::Mat ratio_sum, mask_sum;
      const cv::Size auto_size(0, 0);  // the kernel from sigma
      ParallelInvoke(threads(), {[&] { cv::GaussianBlur(ratio_at, ratio_sum, auto_size, kShadingSmoothSigmaPx); },
                                 [&] { cv::GaussianBlur(shown_mask, mask_sum, auto_size, kShadingSmoothSigmaPx); }});
      ForRowsOf(box, [&](int bj) {
        for (int bi = 0; bi < box.width; ++bi) {
          if (!(shown_mask.at<float>(bj, bi) > 0.f)) continue;
          const cv::Vec3f ratio = ratio_sum.at<cv::Vec3f>(bj, bi) / std::max(1e-6f, mask_sum.at<float>(bj, bi));
          const cv::Vec3f seen = seen_at.at<cv::Vec3f>(bj, bi);
          cv::Vec3f& t = texture.at<cv::Vec3f>(bj, bi);
          for (int c = 0; c < 3; ++c) t[c] = std::min(1.0f, seen[c] * ratio[c]);
        }
      });
    }
    // A sample is not trusted where the frame shows the surface squeezed: the output spreads
    // over each pixel less than about half a pixel of the frame (the determinant of the
    // output-to-frame map below kMinFootprint; full trust from kFullFootprint). A lid the output
    // closes over an eye the target holds open is the case: the frame shows that skin as a
    // shadowed band under the brow, 2-3 times thinner than the closed lid, and stretched over it
    // the band drew the closed lids blue-grey on the webcam clip. Such pixels fill like other
    // distrusted ones (the map where no trusted skin is near).
    constexpr float kMinFootprint = 0.35f, kFullFootprint = 0.55f;
    cv::Mat footprint_trust(box.size(), CV_32FC1, cv::Scalar(1.0f));
    {
      // The footprint of one surface: a lid's last row beside the eyeball (which the gaze moves
      // elsewhere) is no squeeze; there the difference looks at the pixel behind, on the lid. On
      // d6 onto d10 (output frame 30) the lid margin's lash-line samples were distrusted as
      // squeezed, and the map's skin drew an orange line over the iris.
      auto eyeball_at = [&](int bj, int bi) {
        return kEyeParts & part_bit(part_of(g->vertices[3 * (static_cast<size_t>(bj + box.y) * w + static_cast<size_t>(bi + box.x))]));
      };
      auto step = [&](int bj, int bi, int dj, int di, cv::Vec2f* d) {
        const cv::Vec2f at = sampled_at.at<cv::Vec2f>(bj, bi), ahead = sampled_at.at<cv::Vec2f>(bj + dj, bi + di);
        if (std::isnan(ahead[0])) return false;
        if (eyeball_at(bj + dj, bi + di) == eyeball_at(bj, bi)) return *d = ahead - at, true;
        if (bj - dj < 0 || bi - di < 0) return false;
        const cv::Vec2f behind = sampled_at.at<cv::Vec2f>(bj - dj, bi - di);
        if (std::isnan(behind[0]) || eyeball_at(bj - dj, bi - di) != eyeball_at(bj, bi)) return false;
        return *d = at - behind, true;
      };
      ForRowsOf(box, [&](int bj) {
        if (bj + 1 >= box.height) return;
        for (int bi = 0; bi + 1 < box.width; ++bi) {
          cv::Vec2f dx, dy;
          if (std::isnan(sampled_at.at<cv::Vec2f>(bj, bi)[0]) || !step(bj, bi, 0, 1, &dx) || !step(bj, bi, 1, 0, &dy)) continue;
          const float area = std::abs(dx[0] * dy[1] - dx[1] * dy[0]);
          footprint_trust.at<float>(bj, bi) = std::clamp((area - kMinFootprint) / (kFullFootprint - kMinFootprint), 0.0f, 1.0f);
        }
      });
      // Smooth, and reaching a pixel past the squeezed region (the differences look one pixel
      // ahead), so the change draws no edge of its own.
      cv::erode(footprint_trust, footprint_trust, cv::Mat());
      cv::GaussianBlur(footprint_trust, footprint_trust, cv::Size(0, 0), 1.0);
      weight = weight.mul(footprint_trust);
    }
    // Per eye, the frame or the open eyes, never both: the two fits' gazes differ, and mixed in
    // one eye the frame's iris and the open eyes' drew two irises (d10 narrowing her eyes to a
    // blink reading of 0.32-0.42 under d6's wide-open ones, output frames 116-119). The open eyes
    // where the frame shows less than half of the output's eyeball; the frame's own eye, filled by
    // place, where it shows more.
    constexpr float kShownForTheFramesEye = 0.5f;
    if (exemplar_g) {
      std::array<float, 2> shown_share{0.f, 0.f}, drawn{0.f, 0.f};
      for (int bj = 0; bj < box.height; ++bj)
        for (int bi = 0; bi < box.width; ++bi) {
          const size_t p = static_cast<size_t>(bj + box.y) * w + static_cast<size_t>(bi + box.x);
          if (!(covered.at<float>(bj, bi) > 0.f) || !(kEyeParts & part_bit(part_of(g->vertices[3 * p])))) continue;
          const size_t slot = static_cast<size_t>(EyeSlot(part_of(g->vertices[3 * p])));
          shown_share[slot] += std::clamp(weight.at<float>(bj, bi), 0.0f, 1.0f);
          drawn[slot] += 1.f;
        }
      for (size_t e = 0; e < 2; ++e)
        if (from_exemplar[e] && drawn[e] > 0.f && shown_share[e] >= kShownForTheFramesEye * drawn[e]) from_exemplar[e] = false;
      for (int bj = 0; (from_exemplar[0] || from_exemplar[1]) && bj < box.height; ++bj)
        for (int bi = 0; bi < box.width; ++bi) {
          const size_t p = static_cast<size_t>(bj + box.y) * w + static_cast<size_t>(bi + box.x);
          if (!(covered.at<float>(bj, bi) > 0.f) || !(kEyeParts & part_bit(part_of(g->vertices[3 * p])))) continue;
          if (!from_exemplar[static_cast<size_t>(EyeSlot(part_of(g->vertices[3 * p])))]) continue;
          texture.at<cv::Vec3f>(bj, bi) = exemplar_texture.at<cv::Vec3f>(bj, bi);
          weight.at<float>(bj, bi) = exemplar_weight.at<float>(bj, bi);
        }
      if (eyes_drawn) *eyes_drawn = from_exemplar[0] || from_exemplar[1];
    }
    if (shown) weight.copyTo((*shown)(box));
    // Each eye's white as this frame shows it: the mean of the brightest quarter of the frame's
    // pixels inside the target's lid margins (one pixel in; at least kMinWhiteSamples). Eyeball
    // surface the frame does not show (under the target's lid, bared by a gaze turned further than
    // the target's) is mostly white, and there it replaces the albedo map's eyeball, the model's
    // white: on the webcam clip (a dim camera, eye whites at about 0.3 in linear light) a gaze
    // turned hard aside drew a bright blue-white wedge beside the iris (d14 onto it, output frames
    // 19 and 53).
    constexpr int kMinWhiteSamples = 6;
    std::array<std::optional<Eigen::Vector3f>, 2> eye_white;  // LeftEye, RightEye
    // Not from eyes the target holds partly closed: inside their lid margins the frame shows the
    // lids (on the webcam clip, blinking at output frames 19 and 20, eyeBlink 0.65 and 0.50, the
    // estimate was skin, and the eyes the output opens were drawn as skin). An eye drawn from the
    // open eyes (EyeExemplar) takes their white.
    constexpr float kMaxBlinkForWhite = 0.3f;
    for (size_t k = 0; k < lid_contours.size(); ++k) {
      const size_t slot = static_cast<size_t>(lid_eye_slot[k]);
      const bool exemplar = from_exemplar[slot];
      const cv::Mat& image = exemplar ? open_eyes->bgr : target_bgr;
      const cv::Point origin = exemplar ? open_eyes->origin : cv::Point(0, 0);
      const gpu::VertexState& state = exemplar ? exemplar_state : ts;
      const gpu::PinholeCamera& frame_camera = exemplar ? open_eyes->camera : camera;
      if (!exemplar && expression_weight(target.delta, lid_blink_index[k]) > kMaxBlinkForWhite) continue;
      std::vector<cv::Point> polygon = !exemplar && apertures[slot]
                                           ? apertures[slot]->PixelOutline(internal::EyeAperture::Which::kFrame)
                                           : PixelContour(lid_contours[k], state, frame_camera, origin);
      if (polygon.empty()) continue;
      const cv::Rect zone = cv::boundingRect(polygon) & cv::Rect(0, 0, image.cols, image.rows);
      if (zone.width < 3 || zone.height < 3) continue;
      cv::Mat inside = cv::Mat::zeros(zone.size(), CV_8UC1);
      for (cv::Point& q : polygon) q -= zone.tl();
      cv::fillPoly(inside, std::vector<std::vector<cv::Point>>{polygon}, cv::Scalar(255));
      cv::erode(inside, inside, cv::Mat());
      std::vector<std::pair<float, Eigen::Vector3f>> pixels;  // (luminance, colour)
      for (int j = 0; j < zone.height; ++j)
        for (int i = 0; i < zone.width; ++i)
          if (inside.at<uchar>(j, i)) {
            const Eigen::Vector3f c = sample_linear(image, static_cast<float>(zone.x + i), static_cast<float>(zone.y + j));
            pixels.push_back({linear_luminance(c[0], c[1], c[2]), c});
          }
      const size_t top = pixels.size() / 4;
      if (top < static_cast<size_t>(kMinWhiteSamples)) continue;
      std::nth_element(pixels.begin(), pixels.begin() + static_cast<std::ptrdiff_t>(top), pixels.end(),
                       [](const auto& a, const auto& b) { return a.first > b.first; });
      Eigen::Vector3f sum = Eigen::Vector3f::Zero();
      for (size_t q = 0; q < top; ++q) sum += pixels[q].second;
      eye_white[slot] = sum / static_cast<float>(top);
    }
    // The albedo map's colour balance against this frame's: per channel, the frame's texture over
    // the albedo map's rendering where the frame is fully trusted. The map was learned under the
    // lighting of earlier frames; when the tracked light's colour has drifted since (on the webcam
    // clip, as the camera's exposure dropped and the face turned darker and warmer, its green and
    // blue ambient fell to a fifth of the red's, far more than the frame's colours changed), the
    // map's surface rendered under the new light is tinted, and the lips, lids and nose tip the
    // frame does not show turned pink. The fallback pixels take the map's colour times this gain,
    // so they match the shown skin around them (a camera's white balance moving is matched the
    // same way).
    Eigen::Vector3d frame_sum = Eigen::Vector3d::Zero(), map_sum = Eigen::Vector3d::Zero();
    int balanced = 0;
    for (int bj = 0; bj < box.height; ++bj)
      for (int bi = 0; bi < box.width; ++bi) {
        if (!(weight.at<float>(bj, bi) >= 1.f)) continue;
        const size_t p = static_cast<size_t>(bj + box.y) * w + static_cast<size_t>(bi + box.x);
        if (part_of(g->vertices[3 * p]) != FacePart::Face) continue;
        const cv::Vec3f t = texture.at<cv::Vec3f>(bj, bi);
        for (int c = 0; c < 3; ++c) {
          frame_sum[c] += t[c];
          map_sum[c] += g->color[3 * p + static_cast<size_t>(c)];
        }
        ++balanced;
      }
    Eigen::Vector3f gain = Eigen::Vector3f::Ones();
    constexpr int kMinBalancePixels = 100;
    constexpr float kMaxGain = 4.0f;
    if (balanced >= kMinBalancePixels && map_sum.minCoeff() > 1e-6)
      for (int c = 0; c < 3; ++c)
        gain[c] = std::clamp(static_cast<float>(frame_sum[c] / map_sum[c]), 1.0f / kMaxGain, kMaxGain);
    // Skin pixels whose sample is distrusted take the frame's colour of the trusted skin samples
    // around them (a normalised convolution of the weighted texture), and the albedo map only where
    // too few are near: the map knows the surface's colour but not this frame's shading of a
    // sliver. On the webcam clip (d14 as source, frame 172) the distrusted pixels were slivers a
    // pixel wide where the map's shading is far from the frame's, the underside of a pursed upper
    // lip and the neck below the chin, lit at the SH fit's floor (the neck 0.25 / 0.08 / 0.09 in
    // linear light beside the frame's 0.34 / 0.24 / 0.23): dotted dark lines along the lip line and
    // the chin. The confidence in the frame is the trusted share of the drawn pixels around,
    // reaching 1 at half: a distrusted pixel among trusted ones takes their colour, the border of a
    // shown region next to an unshown one (a closed lid, a cheek a turn reveals) still fades to the
    // map over about a pixel, so no seam shows. Only skin fills skin (an eyeball's or a tooth's
    // colour on a lid or a lip would be a white rim). Teeth and tongue keep their own samples,
    // faded to the map next to distrusted ones.
    //
    // The eyeballs fill by place on the eyeball (internal::EyeballFill), from the frame's own
    // samples of that eye: the same place nearby, the mirror place across the meridian, the same
    // angle from the axis; then the eye's white as the frame shows it, then the map. Only eyes
    // fill eyes.
    constexpr float kFillSigmaPx = 2.0f, kTrustedShareForFull = 0.3f;
    std::array<std::optional<internal::EyeballFill>, 2> eye_fill;  // LeftEye, RightEye
    for (size_t e = 0; e < 2; ++e) {
      if (eyeball_vertices[e].empty()) continue;
      Eigen::Vector3f centre = Eigen::Vector3f::Zero();
      for (int32_t v : eyeball_vertices[e]) centre += out_state.camera_positions.segment<3>(3 * v);
      centre /= static_cast<float>(eyeball_vertices[e].size());
      if (centre.z() > camera.near_plane) eye_fill[e].emplace(eyeball_radius[e] * camera.fx / centre.z());
    }
    auto eyeball_place_at = [&](size_t p) {
      Eigen::Vector3f d = Eigen::Vector3f::Zero();
      for (int k = 0; k < 3; ++k)
        d += g->barycentric[3 * p + static_cast<size_t>(k)] * eyeball_place[static_cast<size_t>(g->vertices[3 * p + static_cast<size_t>(k)])];
      return d.norm() > 0.f ? Eigen::Vector3f(d.normalized()) : d;
    };
    cv::Mat skin_weight = cv::Mat::zeros(box.size(), CV_32FC1), weighted_texture = cv::Mat::zeros(box.size(), CV_32FC3);
    auto sample_weight = [&](int bj, int bi, size_t p, FacePart* part) {
      if (!(covered.at<float>(bj, bi) > 0.f)) return 0.f;
      *part = part_of(g->vertices[3 * p]);
      return weight.at<float>(bj, bi);
    };
    ForRowsOf(box, [&](int bj) {
      for (int bi = 0; bi < box.width; ++bi) {
        FacePart part;
        const size_t p = static_cast<size_t>(bj + box.y) * w + static_cast<size_t>(bi + box.x);
        const float wt = sample_weight(bj, bi, p, &part);
        if (!(wt > 0.f) || part != FacePart::Face) continue;
        skin_weight.at<float>(bj, bi) = wt;
        weighted_texture.at<cv::Vec3f>(bj, bi) = texture.at<cv::Vec3f>(bj, bi) * wt;
      }
    });
    // The eyes' samples in row order, on one thread (each eye's fill sums them in that order).
    if (eye_fill[0] || eye_fill[1])
      for (int bj = 0; bj < box.height; ++bj)
        for (int bi = 0; bi < box.width; ++bi) {
          const size_t p = static_cast<size_t>(bj + box.y) * w + static_cast<size_t>(bi + box.x);
          FacePart part;
          const float wt = sample_weight(bj, bi, p, &part);
          if (!(wt > 0.f) || !(kEyeParts & part_bit(part))) continue;
          auto& fill = eye_fill[static_cast<size_t>(EyeSlot(part))];
          const cv::Vec3f t = texture.at<cv::Vec3f>(bj, bi);
          if (fill) fill->Add(eyeball_place_at(p), Eigen::Vector3f(t[0], t[1], t[2]), wt);
        }
    // A normalised convolution: the weighted samples, their weights and the drawn pixels they
    // share with, each blurred at one kernel; and every drawn pixel's own trust, for the other
    // parts (teeth, tongue). Four images filtered at once.
    struct Fill {
      cv::Mat sums, weights, coverage;
    } skin;
    cv::Mat ws;
    ParallelInvoke(threads(), {[&] { cv::GaussianBlur(weighted_texture, skin.sums, cv::Size(0, 0), kFillSigmaPx); },
                               [&] {
                                 cv::GaussianBlur(skin_weight, skin.weights, cv::Size(0, 0), kFillSigmaPx);
                                 cv::GaussianBlur(covered, skin.coverage, cv::Size(0, 0), kFillSigmaPx);
                               },
                               [&] { cv::GaussianBlur(weight, ws, cv::Size(0, 0), kFillSigmaPx); }});
    // The output's lid margins: distrusted skin this close to one takes the map, not its
    // neighbours' samples. The fill is spatial, and across a lid the output closes the nearest
    // trusted skin is the lower lid's, the shadowed skin under the eye: it drew a grey-blue band
    // along the closed lid. (The lips keep the fill: there it mends the map's shading of slivers.)
    const float lid_reach_px = 2.0f * kFillSigmaPx;
    // Measured within the lid contours' rectangle grown past the reach (beyond it every pixel is
    // farther than the reach, and a chamfer path to a contour shorter than the reach stays inside
    // the rectangle, so the distances that count are the whole box's).
    cv::Mat lid_distance(box.size(), CV_32FC1, cv::Scalar(std::numeric_limits<float>::max()));
    {
      cv::Rect lids;
      for (const auto& contour : lid_contours)
        for (const cv::Point& q : PixelContour(contour, out_state, camera, box.tl())) lids |= cv::Rect(q.x, q.y, 1, 1);
      const cv::Rect zone = grown_within(lids, static_cast<int>(std::ceil(lid_reach_px)) + 2, box.width, box.height);
      if (!zone.empty()) {
        cv::Mat open(zone.size(), CV_8UC1, cv::Scalar(255));
        DrawContours(lid_contours, out_state, camera, box.tl() + zone.tl(), &open);
        cv::Mat zone_distance = lid_distance(zone);
        cv::distanceTransform(open, zone_distance, cv::DIST_L2, cv::DIST_MASK_3);
      }
    }
    // The lids' shadow on the filled eyeball: this much darker at the opening's edge, fading out
    // over this share of the eye's width (a real eye's white darkens over its outer fifth).
    constexpr float kLidShadow = 0.35f, kLidShadowReach = 0.15f;
    std::array<float, 2> aperture_width{1.f, 1.f};
    for (size_t e = 0; e < 2; ++e)
      if (apertures[e]) aperture_width[e] = std::max(1.0f, static_cast<float>(apertures[e]->Bounds(internal::EyeAperture::Which::kOutput, 0, w, h).width));
    // The lids the output closes further than the target's (kFoldedLid): the frame shows their
    // surface only folded, and the trusted skin nearest them is the shadowed band under the brow
    // above and the lower lid's below; filled from those, the closed lids were grey-blue (d14 with
    // her eyes shut onto the webcam clip, output frames 75 and 89). Where the map learned the lids
    // from the target's own blinks (ObserveAlbedo, the texture's closed-eyes view), their
    // distrusted pixels take it, by the share of the pixel's surface that is such a lid, smoothed
    // so the change draws no edge. A map that never saw a blink knows them only from the skin
    // around (FillUnobserved), no better than the fill (d12, behind glasses: a dull patch).
    cv::Mat closing_lid;
    if (map_weight) {
      std::vector<std::pair<int, float>> closing;  // (eyeBlink, how much the output closes it further)
      for (int b : blink_indices)
        if (const float c = LidClosing(target, output, b); c > 0.f) closing.push_back({b, c});
      if (!closing.empty()) {
        closing_lid = cv::Mat::zeros(box.size(), CV_32FC1);
        ForRowsOf(box, [&](int bj) {
          for (int bi = 0; bi < box.width; ++bi) {
            if (!(covered.at<float>(bj, bi) > 0.f)) continue;
            const size_t p = static_cast<size_t>(bj + box.y) * w + static_cast<size_t>(bi + box.x);
            float share = 0.f;
            for (size_t k = 0; k < 3; ++k) {
              const int32_t v = g->vertices[3 * p + k];
              const int b = folded_lid_blink[static_cast<size_t>(v)];
              const float learned = std::clamp((*map_weight)[v] / kLearnedLidWeight, 0.0f, 1.0f);
              for (const auto& [blink, c] : closing)
                if (b == blink) share += c * learned * g->barycentric[3 * p + k];
            }
            closing_lid.at<float>(bj, bi) = share;
          }
        });
        cv::GaussianBlur(closing_lid, closing_lid, cv::Size(0, 0), kFillSigmaPx);
      }
    }
    // Each pixel writes only its own colour: rows on the pool's threads.
    ForRowsOf(box, [&](int bj) {
      for (int bi = 0; bi < box.width; ++bi) {
        if (!(covered.at<float>(bj, bi) > 0.f)) continue;
        const size_t p = static_cast<size_t>(bj + box.y) * w + static_cast<size_t>(bi + box.x);
        const FacePart part = part_of(g->vertices[3 * p]);
        float own = std::clamp(weight.at<float>(bj, bi), 0.0f, 1.0f);
        const float cw = skin.coverage.at<float>(bj, bi);
        float a = 0.f;
        cv::Vec3f t(0.f, 0.f, 0.f);  // (the texture holds nothing where no sample was taken)
        if (kEyeParts & part_bit(part)) {
          // The pixel's own sample as far as it is trusted, the fill by place for the rest.
          const size_t slot = static_cast<size_t>(EyeSlot(part));
          const auto& fill = eye_fill[slot];
          const cv::Vec3f own_t = texture.at<cv::Vec3f>(bj, bi);
          if (own < 1.f) {
            const Eigen::Vector3f fallback = eye_white[slot] ? *eye_white[slot] : MapColour(fallback_texture, *g, p, &gain);
            Eigen::Vector3f around = fill ? fill->At(eyeball_place_at(p), fallback) : fallback;
            // Within a real opening, the filled eyeball darkens towards the lids as an eye does
            // (the lids' shadow, the ball turning away): filled flat, the white bared in the
            // corners of eyes turned hard aside was a flat pale patch against the frame's lids.
            if (apertures[slot]) {
              const float inside = apertures[slot]->SignedDistance(
                  Eigen::Vector2f(static_cast<float>(bi + box.x), static_cast<float>(bj + box.y)), internal::EyeAperture::Which::kOutput);
              around *= 1.0f - kLidShadow * (1.0f - std::clamp(inside / (kLidShadowReach * aperture_width[slot]), 0.0f, 1.0f));
            }
            for (int c = 0; c < 3; ++c) t[c] = own * own_t[c] + (1.0f - own) * around[c];
          } else {
            t = own_t;
          }
          a = 1.0f;
        } else if (part == FacePart::Face) {
          const float trusted = skin.weights.at<float>(bj, bi), coverage = skin.coverage.at<float>(bj, bi);
          if (lid_distance.at<float>(bj, bi) < lid_reach_px) {
            t = texture.at<cv::Vec3f>(bj, bi);
            // A sample darker than the map in every channel is the lash line (or an eyeliner, or
            // the iris a lid margin missed by a pixel lands on): what a lid margin shows. Beside
            // the lids the output lowers, the boundary and closing rules distrusted the frame's
            // lash line, the map has none (its lid margins are not observed), and the margin was
            // drawn as a pale band over the eye, or as a reddish line where the frame's iris and
            // the map's lid mixed (d6 onto d10, output frames 100 and 120). Full trust when every
            // channel is below half the map's; a squeezed sample stays distrusted (the shadowed
            // band above a closed lid is darker too). A light sample (the eye white, a lid's rim)
            // never gains from this.
            if (own < 1.f && !std::isnan(sampled_at.at<cv::Vec2f>(bj, bi)[0])) {
              const Eigen::Vector3f map = MapColour(fallback_texture, *g, p, &gain);
              float lighter = 0.f;  // the largest channel ratio of sample to map
              for (int c = 0; c < 3; ++c) lighter = std::max(lighter, t[c] / std::max(1e-4f, map[c]));
              const float dark = std::clamp(2.0f * (1.0f - lighter), 0.0f, 1.0f);
              own = std::max(own, dark * footprint_trust.at<float>(bj, bi));
            }
            a = own;
          } else if (trusted > 1e-4f && coverage > 1e-6f) {
            a = std::clamp(trusted / (kTrustedShareForFull * coverage), 0.0f, 1.0f);
            // The pixel's own sample as far as it is trusted, its trusted neighbours' for the rest.
            const cv::Vec3f around = skin.sums.at<cv::Vec3f>(bj, bi) / trusted;
            t = own > 0.f ? own * texture.at<cv::Vec3f>(bj, bi) + (1.0f - own) * around : around;
          }
          if (const float lid = closing_lid.empty() ? 0.f : std::min(1.0f, closing_lid.at<float>(bj, bi));
              lid > 0.f && !(lid_distance.at<float>(bj, bi) < lid_reach_px) && own < 1.f) {
            // The pixel's own sample as far as it is trusted, the map for the rest (above).
            const Eigen::Vector3f map = MapColour(fallback_texture, *g, p, &gain);
            const cv::Vec3f own_t = texture.at<cv::Vec3f>(bj, bi);
            for (int c = 0; c < 3; ++c) {
              const float filled = a * std::min(1.0f, t[c]) + (1.0f - a) * map[c];
              const float mapped = own * std::min(1.0f, own_t[c]) + (1.0f - own) * map[c];
              t[c] = lid * mapped + (1.0f - lid) * filled;
            }
            a = 1.0f;
          }
        } else if (own > 0.f) {
          a = cw > 1e-6f ? std::clamp(ws.at<float>(bj, bi) / cw, 0.0f, 1.0f) : 1.0f;
          // Where the mouth pass leaves the pixel to the frame, the frame's sample alone: faded to
          // the map, a mouth part took the model's teeth, lit and never darkened (the pass darkens
          // what it draws): on a closed smile's lip line, whose gap of a pixel shows the teeth, a
          // white dash, half the frame's lip and half the map's teeth (d14 onto the webcam clip,
          // output frame 100: own trust 0.55, faded to 0.45).
          if (shown && own >= internal::kShownByTheFrame) a = 1.0f;
          t = texture.at<cv::Vec3f>(bj, bi);
        }
        // Teeth and tongue keep the plain map (the mouth pass darkens them), the skin takes the
        // balance.
        const bool balance = !(kMouthParts & part_bit(part));
        const Eigen::Vector3f map =
            !(a < 1.0f) ? Eigen::Vector3f::Zero() : MapColour(fallback_texture, *g, p, balance ? &gain : nullptr);
        for (int c = 0; c < 3; ++c) g->color[3 * p + static_cast<size_t>(c)] = a * std::min(1.0f, t[c]) + (1.0f - a) * map[c];
      }
    });
    // The lids around the output's opening, where the fit's opening shows eyeball: the frame's
    // own lid, moved as the output moves the lid.
    for (const LidPixel& l : lid_pixels) {
      const float x = l.at.x(), y = l.at.y();
      if (!(x >= 0.f && y >= 0.f && x <= static_cast<float>(w - 1) && y <= static_cast<float>(h - 1))) continue;
      const Eigen::Vector3f lid = sample_linear(target_bgr, x, y);
      for (int c = 0; c < 3; ++c) {
        float& col = g->color[3 * l.p + static_cast<size_t>(c)];
        col = l.alpha * lid[c] + (1.0f - l.alpha) * col;
      }
    }
  }

  // body(row) for each row 0..box.height-1 of `box`, in bands of 8 rows on the pool's threads
  // (per-pixel passes; ParallelForBlocks).
  template <typename Body>
  void ForRowsOf(const cv::Rect& box, const Body& body) const {
    ParallelForBlocks(box.height, 8, threads(), body);
  }
  // body(v) for each vertex 0..n-1, in blocks of 1024 (per-vertex passes).
  template <typename Body>
  void ForVerticesOf(int n, const Body& body) const {
    ParallelForBlocks(n, 1024, threads(), body);
  }

  // The albedo map's colour at G-buffer pixel p of `g` (before the frame texture replaces it): the
  // texture as far as a view saw the surface (its unseen texels are the per-vertex map blurred by
  // the blend's coarse levels: the map itself is the better fallback there), g's per-vertex colour
  // for the rest; times `gain` per channel, capped at 1, when one is given.
  Eigen::Vector3f MapColour(const TextureShading& fallback_texture, const gpu::GBuffer& g, size_t p,
                            const Eigen::Vector3f* gain) const {
    Eigen::Vector3f textured;
    float seen = 0.f;
    const bool from_texture = fallback_texture.texture && fallback_texture.Colour(model, g, p, &textured, &seen);
    const float texture_share = from_texture ? std::clamp(seen / kTextureSeenForFull, 0.0f, 1.0f) : 0.0f;
    Eigen::Vector3f map;
    for (int c = 0; c < 3; ++c) {
      const float below = texture_share * (from_texture ? textured[c] : 0.f) + (1.0f - texture_share) * g.color[3 * p + static_cast<size_t>(c)];
      map[c] = gain ? std::min(1.0f, below * (*gain)[c]) : below;
    }
    return map;
  }

  // The actor's learned skin against the model's skin (per channel, over the face vertices the
  // map has observed, the mouth's inner skin left out; clamped to 1/4..4; ones with fewer than 50
  // observed): the colour cast and exposure of this camera and grade, which the map holds since it
  // divides the frame by the tracked light. The model's teeth, tongue and cavity are multiplied by
  // it, so they stand to the actor's skin as the model's stand to the model's skin. Without it, on
  // the Breaking Bad still (a teal and orange grade, a hard coloured light) the model's plain teeth
  // under the tracked light drew blue-purple in the lip slit.
  Eigen::Vector3f SkinCast(const AlbedoMap& map, const gpu::VertexState& model_state) const {
    const int n = model.num_vertices();
    if (map.albedo.size() != 3 * n || map.weight.size() != n) return Eigen::Vector3f::Ones();
    Eigen::Vector3d learned = Eigen::Vector3d::Zero(), modelled = Eigen::Vector3d::Zero();
    int count = 0;
    for (int v = 0; v < n; ++v) {
      if (part_of(v) != FacePart::Face || in_mouth[static_cast<size_t>(v)] || !(map.weight[v] > 0.f)) continue;
      for (int c = 0; c < 3; ++c) {
        learned[c] += map.albedo[3 * v + c];
        modelled[c] += model_state.albedo[3 * v + c];
      }
      ++count;
    }
    constexpr int kMinObserved = 50;
    constexpr float kMaxCast = 4.0f;
    Eigen::Vector3f cast = Eigen::Vector3f::Ones();
    if (count < kMinObserved || !(modelled.minCoeff() > 1e-6)) return cast;
    for (int c = 0; c < 3; ++c)
      cast[c] = std::clamp(static_cast<float>(learned[c] / modelled[c]), 1.0f / kMaxCast, kMaxCast);
    return cast;
  }

  // The model's teeth and tongue are inside the head, but the rig can push them through the skin:
  // jawForward over an opened jaw moves the lower teeth forward through the chin (d6 baring her
  // teeth onto d10, output frame 120: jawForward 0.42, jawOpen 0.48; a pale blob on the chin 30
  // px below the lips, the albedo map's teeth where the frame could not be sampled). Nothing of
  // them can be seen farther than kStrayMouthPartsPx from the inner-lip polygon (the mouth pass
  // reaches 14 px past it); there the skin behind them is drawn, from a rendering of the skin
  // alone, made only on the frames that need it.
  void DrawSkinOverStrayMouthParts(const gpu::VertexState& state, const gpu::FaceParameters& params,
                                   const gpu::PinholeCamera& camera, const gpu::RenderOptions& ropt,
                                   gpu::GBuffer* g) const {
    if (!(ropt.parts & kMouthParts)) return;
    const std::vector<Eigen::Vector2f> opening = Opening(camera, state);
    if (opening.size() < 3) return;
    constexpr int kStrayMouthPartsPx = 16;
    std::vector<cv::Point> polygon;
    for (const Eigen::Vector2f& uv : opening)
      polygon.emplace_back(pixel_round(uv.x()), pixel_round(uv.y()));
    const int w = g->width, h = g->height;
    const cv::Rect zone = grown_within(cv::boundingRect(polygon), kStrayMouthPartsPx + 1, w, h);
    cv::Mat opening_mask = cv::Mat::zeros(std::max(1, zone.height), std::max(1, zone.width), CV_8UC1);
    if (!zone.empty()) {
      std::vector<cv::Point> local;
      for (const cv::Point& q : polygon) local.push_back(q - zone.tl());
      cv::fillPoly(opening_mask, std::vector<std::vector<cv::Point>>{local}, cv::Scalar(255));
    }
    // Near the mouth: within the opening dilated by a disc of kStrayMouthPartsPx (cv::dilate's
    // structuring element), tested at the mouth parts' pixels alone, most of them inside the
    // opening itself (dilating the whole zone cost a third of a millisecond at 640x480).
    static const cv::Mat disc =
        cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * kStrayMouthPartsPx + 1, 2 * kStrayMouthPartsPx + 1));
    auto near_mouth = [&](int i, int j) {
      if (opening_mask.at<uchar>(j - zone.y, i - zone.x)) return true;
      for (int dj = -kStrayMouthPartsPx; dj <= kStrayMouthPartsPx; ++dj) {
        const int y = j - zone.y + dj;
        if (y < 0 || y >= zone.height) continue;
        const uchar* element = disc.ptr<uchar>(dj + kStrayMouthPartsPx);
        const uchar* row = opening_mask.ptr<uchar>(y);
        for (int di = -kStrayMouthPartsPx; di <= kStrayMouthPartsPx; ++di) {
          const int x = i - zone.x + di;
          if (x >= 0 && x < zone.width && element[di + kStrayMouthPartsPx] && row[x]) return true;
        }
      }
      return false;
    };
    std::vector<size_t> stray;
    const cv::Rect drawn = covered_rect(*g, 0);
    for (int j = drawn.y; j < drawn.y + drawn.height; ++j)
      for (int i = drawn.x; i < drawn.x + drawn.width; ++i) {
        const size_t p = static_cast<size_t>(j) * w + i;
        if (g->triangle[p] < 0 || !(kMouthParts & part_bit(part_of(g->vertices[3 * p])))) continue;
        if (zone.contains(cv::Point(i, j)) && near_mouth(i, j)) continue;
        stray.push_back(p);
      }
    if (stray.empty()) return;
    gpu::RenderOptions skin_only = ropt;
    skin_only.parts &= ~kMouthParts;
    gpu::GBuffer& skin = scratch_gbuffer(2);
    rasterize(state, params, camera, skin_only, &skin);
    // In place, within the rectangle the output's draw covered (its trace stays valid).
    for (const size_t p : stray) copy_pixel(skin, p, g);
  }

  // Per-thread G-buffers reused from frame to frame (16 values per pixel; allocating them anew
  // every frame cost more than rasterising at 640x480). 0: the output, 1: the tracked geometry,
  // 2: the output's skin alone (DrawSkinOverStrayMouthParts), 3: the actor's open eyes' frame
  // (EyeExemplar), 4: the output's eyeballs alone (OpenEyesToApertures); these three allocated on
  // first use.
  static gpu::GBuffer& scratch_gbuffer(int which) {
    thread_local std::array<gpu::GBuffer, 5> buffers;
    return buffers[static_cast<size_t>(which)];
  }
  // Frame-sized images Compose fills every frame, kept per thread like the G-buffers: made anew,
  // each was a fresh mapping whose pages the kernel faulted in and zeroed before the pass wrote
  // them (at 1280x720, 18 MB a frame). `create` keeps a buffer of the same size and type.
  enum ScratchImage { kRendered, kBlendMask, kFrameShown, kScratchImages };
  static cv::Mat& scratch_image(ScratchImage which, int w, int h, int type) {
    thread_local std::array<cv::Mat, kScratchImages> images;
    cv::Mat& m = images[static_cast<size_t>(which)];
    m.create(h, w, type);
    return m;
  }

  gpu::PartMask drawn_parts() const {
    gpu::PartMask parts = options.face_only ? part_bit(FacePart::Face) : gpu::kSkinParts;
    parts |= kEyeParts;
    if (options.render_mouth) parts |= kMouthParts;
    return parts;
  }
  FacePart part_of(int32_t vertex) const { return model.vertex_part[static_cast<size_t>(vertex)]; }

  // The teeth texture's pattern at G-buffer pixel p (a teeth pixel), its coordinates interpolated
  // from the triangle's vertices; 1 without a texture.
  Eigen::Vector3f TeethPatternAt(const gpu::GBuffer& g, size_t p) const {
    if (!options.teeth_texture || options.teeth_texture->empty() || teeth_uv.empty()) return Eigen::Vector3f::Ones();
    Eigen::Vector2f uv = Eigen::Vector2f::Zero();
    for (int k = 0; k < 3; ++k) {
      const int32_t v = g.vertices[3 * p + static_cast<size_t>(k)];
      if (v < 0 || !teeth_uv[static_cast<size_t>(v)].allFinite()) return Eigen::Vector3f::Ones();
      uv += g.barycentric[3 * p + static_cast<size_t>(k)] * teeth_uv[static_cast<size_t>(v)];
    }
    return TeethPattern(*options.teeth_texture, uv.x(), uv.y());
  }
};

FaceCompositor::FaceCompositor(const FaceModel& model, const ReenactmentOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw Error("reenactment options: " + why);
  if (!model.IsValid(&why)) throw Error("face model: " + why);
  impl_ = std::make_unique<Impl>(model, options);
}

FaceCompositor::~FaceCompositor() = default;

std::vector<Eigen::Vector2f> FaceCompositor::MouthOpening(const gpu::PinholeCamera& camera,
                                                          const gpu::FaceParameters& params) const {
  const Impl& im = *impl_;
  if (im.inner_lip_vertices.size() < 3) return {};
  std::string why;
  if (!camera.IsValid(&why)) throw Error("reenactment: invalid camera: " + why);
  return im.Opening(camera, im.renderer.evaluate(params, nullptr, im.threads()));
}

bool FaceCompositor::CaptureEyes(const cv::Mat& frame_bgr, const gpu::PinholeCamera& camera,
                                 const gpu::FaceParameters& params, int64_t frame_index, EyeExemplar* eyes,
                                 const EyeOpenings* openings) const {
  const Impl& im = *impl_;
  std::string why;
  if (!camera.IsValid(&why)) throw Error("open eyes: invalid camera: " + why);
  if (frame_bgr.type() != CV_8UC3 || frame_bgr.cols != camera.width || frame_bgr.rows != camera.height)
    throw Error("open eyes: the frame must be 8-bit BGR of the camera's size");
  if (!params.IsValid(&why, static_cast<int>(im.model.identity_basis.cols()), static_cast<int>(im.model.expression_basis.cols()),
                      static_cast<int>(im.model.albedo_basis.cols())))
    throw Error("open eyes: invalid face parameters: " + why);
  // Open: lids at most this far closed (a tracked blink reads 0.5-0.65 on the webcam clip, an
  // open eye 0-0.04); facing: a turned head shows one eye foreshortened; looking ahead: the gaze
  // reading saturates at a hard glance aside (eyeLook 1.0 while the iris is turned further), and
  // eyes taken so drew their iris beside the frame's, two irises in one eye (d10 glancing aside at
  // frames 105-112, drawn through her narrower eyes at 116-119 under d6's wide ones).
  constexpr float kMaxBlink = 0.15f, kMaxTurnDeg = 25.0f, kMaxLook = 0.3f;
  constexpr int kMarginPx = 6;  // around the lid margins (bilinear samples near the rim)
  if (im.lid_contours.size() != 2) return false;
  for (int b : im.lid_blink_index)
    if (!(expression_weight(params.delta, b) <= kMaxBlink)) return false;
  for (const auto& eye : arkit_eye_look_names())
    for (const char* look : eye)
      if (!(expression_weight(params.delta, arkit_blendshape_index(look)) <= kMaxLook)) return false;
  if (!(gpu::head_turn_from_camera_deg(params) <= kMaxTurnDeg)) return false;
  const gpu::VertexState state = im.renderer.evaluate(params, nullptr, im.threads());
  cv::Rect box;
  for (const auto& contour : im.lid_contours)
    for (int32_t v : contour) {
      const Eigen::Vector3f x = state.camera_positions.segment<3>(3 * v);
      if (!(x.z() > camera.near_plane) || !x.allFinite()) return false;
      const Eigen::Vector2f uv = project(camera, x);
      box |= cv::Rect(static_cast<int>(std::floor(uv.x())), static_cast<int>(std::floor(uv.y())), 2, 2);
    }
  // The real openings too (a wide eye reaches past the fit's lids).
  if (openings)
    for (size_t e = 0; e < 2; ++e)
      if (openings->known[e])
        for (const Eigen::Vector2f& q : openings->points[e])
          if (q.allFinite() && q.cwiseAbs().maxCoeff() < 1e6f)
            box |= cv::Rect(static_cast<int>(std::floor(q.x())), static_cast<int>(std::floor(q.y())), 2, 2);
  box = grown_within(box, kMarginPx, camera.width, camera.height);
  if (box.width < 8 || box.height < 4) return false;
  eyes->bgr = frame_bgr(box).clone();
  eyes->origin = box.tl();
  eyes->camera = camera;
  eyes->params = params;
  eyes->openings = openings ? *openings : EyeOpenings{};
  eyes->frame_index = frame_index;
  return true;
}

FaceCompositor::MouthView FaceCompositor::ViewMouth(const cv::Mat& frame_bgr, const gpu::PinholeCamera& camera,
                                                   const gpu::FaceParameters& params) const {
  const Impl& im = *impl_;
  std::string why;
  if (!camera.IsValid(&why)) throw Error("reenactment: invalid camera: " + why);
  if (frame_bgr.type() != CV_8UC3 || frame_bgr.cols != camera.width || frame_bgr.rows != camera.height)
    throw Error("reenactment: the frame must be 8-bit BGR of the camera's size");
  const gpu::VertexState state = im.renderer.evaluate(params, nullptr, im.threads());
  MouthView view;
  view.opening = im.Opening(camera, state);
  std::array<std::vector<float>, 3> channels;
  for (int32_t v : im.skin_around_mouth) {
    const Eigen::Vector3f x = state.camera_positions.segment<3>(3 * v);
    const Eigen::Vector3f n = state.camera_normals.segment<3>(3 * v);
    if (!(x.z() > camera.near_plane) || !(n.dot(-x.normalized()) > 0.3f)) continue;  // facing the camera
    const Eigen::Vector2f uv = project(camera, x);
    if (!(uv.x() >= 0.f && uv.y() >= 0.f && uv.x() <= static_cast<float>(camera.width - 1) &&
          uv.y() <= static_cast<float>(camera.height - 1)))
      continue;
    const Eigen::Vector3f c = internal::sample_linear(frame_bgr, uv.x(), uv.y());
    for (int k = 0; k < 3; ++k) channels[static_cast<size_t>(k)].push_back(c[k]);
  }
  if (channels[0].size() < 20) return view;
  for (int k = 0; k < 3; ++k) {
    auto& ch = channels[static_cast<size_t>(k)];
    std::nth_element(ch.begin(), ch.begin() + static_cast<long>(ch.size() / 2), ch.end());
    view.skin[k] = ch[ch.size() / 2];
  }
  view.has_skin = true;
  return view;
}

void FaceCompositor::SetOptions(const ReenactmentOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw Error("reenactment options: " + why);
  if (options.renderer != impl_->options.renderer) impl_->vk_failure.clear();
  impl_->options = options;
}

const FaceModel& FaceCompositor::model() const { return impl_->model; }

std::string FaceCompositor::renderer_description() const {
  if (impl_->options.renderer == RendererKind::kCpu) return "cpu";
  if (impl_->vk_renderer) return "vulkan (" + impl_->vk_context->device_info().name + ")";
  if (!impl_->vk_failure.empty()) return "cpu (Vulkan unavailable: " + impl_->vk_failure + ")";
  return "vulkan (not opened yet)";
}

CompositeResult FaceCompositor::Compose(const cv::Mat& target_bgr, const gpu::PinholeCamera& camera,
                                        const gpu::FaceParameters& target, const gpu::FaceParameters& output,
                                        const AlbedoMap* albedo, const cv::Mat* target_depth,
                                        const MouthExemplar* mouth, const DetailTransfer* detail,
                                        const EyeExemplar* eyes, const EyeOpenings* openings) const {
  std::string why;
  if (!camera.IsValid(&why)) throw Error("reenactment: invalid camera: " + why);
  if (target_bgr.type() != CV_8UC3 || target_bgr.cols != camera.width || target_bgr.rows != camera.height)
    throw Error("reenactment: the target image must be 8-bit BGR of the camera's size (" + std::to_string(camera.width) +
                "x" + std::to_string(camera.height) + ")");
  const Impl& im = *impl_;
  const ReenactmentOptions& opt = im.options;
  CompositeResult result;
  const int w = camera.width, h = camera.height;

  // --- re-render (Sec. 7.4): the target's identity, pose and lighting with the output expression.
  auto start = Clock::now();
  // Unshaded: the colours are the compositor's own (below, every vertex's).
  gpu::VertexState state = im.renderer.evaluate(output, nullptr, im.threads(), gpu::VertexColors::kNone);
  const int n = im.model.num_vertices();
  const Gamma light = rendering_lighting(output.gamma);
  const bool use_map = albedo && albedo->albedo.size() == 3 * n;
  const bool cap = use_map && albedo->max_irradiance.minCoeff() > 0.f;
  const Eigen::Vector3f cast = use_map ? im.SkinCast(*albedo, state) : Eigen::Vector3f::Ones();
  // The colour teeth and tongue are lit with: the light entering the mouth (camera-facing
  // irradiance), at half its saturation (the square root of its colour over its luminance). The
  // fit's light carries much of the skin's own colour (the albedo prior holds the skin near the
  // model's mean), so its colour overstates the real light's: under the Breaking Bad still's
  // orange key (entering light 0.99 / 0.60 / 0.22) the full colour drew the whole opening dark red.
  Eigen::Vector3f entering_colour = Eigen::Vector3f::Ones();
  {
    Eigen::Vector3f entering;
    for (int c = 0; c < 3; ++c) entering[c] = Impl::entering_light(light, c);
    const float lum = luminance(entering);
    if (lum > 1e-6f && entering.minCoeff() > 0.f) {
      entering_colour = (entering / lum).cwiseSqrt();
      entering_colour /= luminance(entering_colour);
    }
  }
  std::vector<Eigen::Vector3f> irradiance_out(static_cast<size_t>(n));  // uncapped, per vertex
  std::vector<Eigen::Vector3f> shade(static_cast<size_t>(n));           // as drawn (capped)
  // Each vertex writes only its own values: on the pool's threads.
  im.ForVerticesOf(n, [&](int v) {
    const auto basis = im.lit_basis(v, state.camera_normals.segment<3>(3 * v), state.camera_positions.segment<3>(3 * v));
    const bool mouth_part = kMouthParts & part_bit(im.part_of(v));
    // Teeth and tongue the map never saw: the model's, in the actor's cast (SkinCast).
    const bool unseen_mouth = use_map && mouth_part && !(albedo->weight.size() == n && albedo->weight[v] > 0.f);
    Eigen::Vector3f e;
    for (int c = 0; c < 3; ++c) e[c] = im.irradiance_at(light, basis, c, v);
    // Teeth and tongue face up, down and inwards, where the SH fit is an extrapolation whose
    // colour can be anything (under the Breaking Bad still's teal window light and orange key,
    // lower teeth blue and upper ones red): they keep the fit's brightness at their normal but
    // take the colour of the light entering the opening.
    if (mouth_part) e = luminance(e) * entering_colour;
    for (int c = 0; c < 3; ++c) {
      if (unseen_mouth)
        state.albedo[3 * v + c] *= cast[c];
      else if (use_map)
        state.albedo[3 * v + c] = albedo->albedo[3 * v + c];
      float e_c = e[c];
      irradiance_out[static_cast<size_t>(v)][c] = e_c;
      if (cap) e_c = std::min(e_c, 1.05f * albedo->max_irradiance[c]);
      shade[static_cast<size_t>(v)][c] = e_c;
      state.colors[3 * v + c] = state.albedo[3 * v + c] * e_c;
    }
  });
  gpu::RenderOptions ropt;
  ropt.parts = im.drawn_parts();
  ropt.cull_back_faces = true;
  const float out_jaw = expression_weight(output.delta, kJawOpenIndex);
  const float target_jaw = expression_weight(target.delta, kJawOpenIndex);
  const bool mouth_pass = opt.render_mouth && out_jaw > opt.mouth_open_threshold && im.inner_lip_vertices.size() >= 3;
  // Without a mouth pass (the output's jaw closed) the output shows no teeth or tongue: the lips
  // of some closed expressions keep a pixel's gap, and there the model's teeth, lit and never
  // darkened by the pass, drew a white dash on the lip line (d14's closed smile onto the webcam
  // clip, output frame 100: six pixels of the map's teeth, 0.8-1.0 in linear light). The skin
  // behind them (the lips' inner faces) takes the gap. The tracked geometry keeps them (ropt):
  // a frame's teeth must still hide the wall behind them.
  gpu::RenderOptions output_ropt = ropt;
  if (!mouth_pass) output_ropt.parts &= ~kMouthParts;
  output_ropt.normals = detail != nullptr;  // read by the detail transfer alone
  gpu::GBuffer& g = Impl::scratch_gbuffer(0);
  im.rasterize(state, output, camera, output_ropt, &g);
  im.DrawSkinOverStrayMouthParts(state, output, camera, output_ropt, &g);
  const Impl::TextureShading texture_shading =
      im.MakeTextureShading(use_map ? albedo->texture.get() : nullptr, use_map ? albedo->albedo : Eigen::VectorXf(), shade);
  if (texture_shading.texture && opt.appearance == Appearance::kAlbedoMap) im.ApplyAlbedoTexture(texture_shading, &g);
  result.mouth_opened_wider = out_jaw > target_jaw + opt.mouth_open_threshold;
  // How much of the mouth interior replaces what the opening shows. With the albedo map, all of
  // it whenever the rendered mouth is open: the re-rendered face covers the target's own mouth.
  // With the frame texture the opening already shows the target's own mouth as far as the output
  // opens no wider than the tracked one (the same geometry samples the same pixels: the target's
  // real lips, closed or open), and the interior fades in over the next kMouthFadeJaw of extra
  // jawOpen. So a closed source mouth on a target whose closed mouth the tracker reads as
  // slightly open (jawOpen 0.25 on the demo's target with dlib's points) keeps the target's
  // lips instead of showing a dark slit, and an opening mouth darkens without a jump.
  constexpr float kMouthFadeJaw = 0.1f;
  const float mouth_alpha =
      opt.appearance == Appearance::kFrameTexture
          ? std::clamp((out_jaw - target_jaw - opt.mouth_open_threshold) / kMouthFadeJaw, 0.0f, 1.0f)
          : 1.0f;
  // Frame texture with a mouth pass: the frame's trust in its own sample of each drawn pixel.
  cv::Mat frame_shown;  // (empty unless the mouth pass reads it)
  if (opt.appearance == Appearance::kFrameTexture && mouth_pass)
    frame_shown = Impl::scratch_image(Impl::kFrameShown, w, h, CV_32FC1);
  if (opt.appearance == Appearance::kFrameTexture)
    im.ApplyFrameTexture(target_bgr, camera, target, output, state, irradiance_out, light, ropt,
                         mouth_pass ? mouth_alpha : 0.0f, texture_shading, &g, mouth_pass ? &frame_shown : nullptr, eyes,
                         &result.eyes_from_exemplar, openings,
                         use_map && albedo->weight.size() == n ? &albedo->weight : nullptr);

  // Float BGR 0..255, the target where nothing is drawn.
  cv::Mat& rendered = Impl::scratch_image(Impl::kRendered, w, h, CV_32FC3);
  target_bgr.convertTo(rendered, CV_32FC3);
  result.face_mask = cv::Mat::zeros(h, w, CV_8UC1);
  result.mouth_mask = cv::Mat::zeros(h, w, CV_8UC1);
  result.face_depth = cv::Mat::zeros(h, w, CV_32FC1);
  const bool check_depth = target_depth && target_depth->type() == CV_32FC1 && target_depth->size() == target_bgr.size() &&
                           (opt.depth_background_m > 0.f || opt.depth_occluder_m > 0.f);
  // Rows of the drawn rectangle on the pool's threads (each pixel writes only its own).
  const cv::Rect drawn_rect = covered_rect(g, 0);  // (empty: nothing drawn)
  im.ForRowsOf(drawn_rect, [&](int row) {
    const int j = drawn_rect.y + row;
    for (int i = drawn_rect.x; i < drawn_rect.x + drawn_rect.width; ++i) {
      const size_t p = static_cast<size_t>(j) * w + i;
      if (g.triangle[p] < 0) continue;
      if (check_depth) {
        const float d = target_depth->at<float>(j, i), z = g.position[3 * p + 2];
        if (std::isfinite(d) && d > 0.f &&
            ((opt.depth_background_m > 0.f && d - z > opt.depth_background_m) ||
             (opt.depth_occluder_m > 0.f && z - d > opt.depth_occluder_m)))
          continue;  // the fit overshoots onto the background, or something covers the face
      }
      rendered.at<cv::Vec3f>(j, i) = display_bgr(g.color[3 * p], g.color[3 * p + 1], g.color[3 * p + 2]);
      result.face_mask.at<uchar>(j, i) = 255;
      result.face_depth.at<float>(j, i) = g.position[3 * p + 2];
    }
  });
  result.render_ms = ms_since(start);
  if (cv::countNonZero(result.face_mask) == 0) {
    result.bgr = target_bgr.clone();
    result.rendered_bgr = target_bgr.clone();
    return result;
  }
  result.drawn = true;

  // --- the source's folds and wrinkles on the re-rendered skin (Sec. 7.3; the mouth pass
  // below draws over the opening).
  if (detail) result.detail = detail->Apply(g, camera, result.face_mask, &rendered);
  // The lash line of lids the output shuts over eyes the target holds open (the frame shows none).
  im.DrawClosedLashLines(target_bgr, camera, target, output, state, result.face_mask, &rendered);

  // --- mouth (Sec. 7.3): inside the lip opening, teeth and tongue (already placed by the
  // jawOpen / tongueOut blendshapes) lit through the opening (darker the deeper and the narrower
  // the opening), and a dark cavity wherever the opening shows the inside of the head or nothing.
  start = Clock::now();
  // With the frame texture, the interior is also drawn wherever the frame does not show the
  // mouth's own surfaces (teeth, tongue, the cavity's wall) that the output's opening shows, even
  // when the output opens no wider than the target: on d12 as the target (its mouth wide open,
  // output frame 125, d6 baring clenched teeth) the output's lower teeth sampled points the frame
  // shows 18 px lower; distrusted, they took the albedo map's plain teeth, a hard grey-green band
  // along the lower lip.
  if (mouth_pass && (mouth_alpha > 0.f || !frame_shown.empty())) {
    internal::MouthPassInput in;
    in.gbuffer = &g;
    in.opening = im.Opening(camera, state);
    for (int32_t v : im.inner_lip_vertices) in.lip_z += state.camera_positions[3 * v + 2];
    in.lip_z /= static_cast<float>(im.inner_lip_vertices.size());
    in.vertex_part = &im.model.vertex_part;
    in.in_mouth = &im.in_mouth;
    in.teeth_pattern = [&](size_t p) { return im.TeethPatternAt(g, p); };
    for (int c = 0; c < 3; ++c) in.entering_light[c] = Impl::entering_light(light, c);
    in.vertex_albedo = &state.albedo;
    Eigen::Vector3f front;
    for (int c = 0; c < 3; ++c) front[c] = internal::camera_facing_irradiance(light, c);
    in.front_light = luminance(front) * entering_colour;
    in.focal_px = camera.fx;
    in.skin_cast = cast;
    in.exemplar = mouth;
    in.mouth_alpha = mouth_alpha;
    in.frame_shown = frame_shown.empty() ? nullptr : &frame_shown;
    const internal::MouthPassResult drawn =
        internal::DrawMouth(in, &rendered, &result.face_mask, &result.mouth_mask, &result.face_depth);
    result.mouth_drawn = drawn.drawn;
    result.mouth_from_exemplar = drawn.from_exemplar;
  }
  result.mouth_ms = ms_since(start);

  // --- composite (Sec. 7.4.2): the coverage mask, eroded so the rendered silhouette's
  // anti-aliasing-free edge never shows, feathered, then the Laplacian blend.
  start = Clock::now();
  // Eroded and feathered within the face's box grown by the kernels' reach: the mask is 0 beyond
  // it either way, and the filters read the whole image's pixels around the box (a view into it),
  // so the result is the whole frame's; at 640x480 a face covers a fifth of the frame.
  const int erosion_k = opt.mask_erosion_px > 0.f ? 2 * static_cast<int>(std::ceil(opt.mask_erosion_px)) + 1 : 0;
  const int mask_reach = erosion_k + 4 * static_cast<int>(std::ceil(opt.mask_feather_px)) + 2;
  const cv::Rect mask_box = grown_within(cv::boundingRect(result.face_mask), mask_reach, w, h);
  cv::Mat& mask = Impl::scratch_image(Impl::kBlendMask, w, h, CV_32FC1);
  mask.setTo(0.0f);
  cv::Mat mask_in_box = mask(mask_box);
  result.face_mask(mask_box).convertTo(mask_in_box, CV_32FC1, 1.0 / 255.0);
  if (erosion_k > 0) cv::erode(mask_in_box, mask_in_box, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(erosion_k, erosion_k)));
  if (opt.mask_feather_px > 0.f) cv::GaussianBlur(mask_in_box, mask_in_box, cv::Size(0, 0), opt.mask_feather_px);
  // Pixels outside the rendered coverage carry the target in `rendered`, so the feathered
  // mask may extend there without effect.
  LaplacianBlendOptions bopt;
  bopt.levels = opt.blend_levels;
  bopt.threads = im.threads();
  result.bgr = LaplacianBlend(target_bgr, rendered, mask, bopt);
  // The target's own bytes beyond the face's box (`rendered` holds them converted to float and
  // back: the same values), the float image converted within it.
  result.rendered_bgr = target_bgr.clone();
  {
    cv::Mat face_part = result.rendered_bgr(mask_box);
    rendered(mask_box).convertTo(face_part, CV_8UC3);
  }
  result.composite_ms = ms_since(start);
  return result;
}

void FaceCompositor::ObserveAlbedo(const cv::Mat& frame_bgr, const gpu::PinholeCamera& camera,
                                   const gpu::FaceParameters& params, AlbedoMap* map, const cv::Mat* frame_depth,
                                   bool folded_lids_only) const {
  if (!map) return;
  std::string why;
  if (!camera.IsValid(&why)) throw Error("albedo observation: invalid camera: " + why);
  if (frame_bgr.type() != CV_8UC3 || frame_bgr.cols != camera.width || frame_bgr.rows != camera.height)
    throw Error("albedo observation: the frame must be 8-bit BGR of the camera's size");
  const Impl& im = *impl_;
  const int n = im.model.num_vertices();
  const gpu::VertexState state = im.renderer.evaluate(params, nullptr, im.threads());
  if (map->albedo.size() != 3 * n || map->weight.size() != n) {
    map->albedo = state.albedo;
    map->weight = Eigen::VectorXf::Zero(n);
  }
  gpu::RenderOptions ropt;
  ropt.parts = im.drawn_parts();
  gpu::GBuffer& g = Impl::scratch_gbuffer(1);
  im.rasterize(state, params, camera, ropt, &g);
  constexpr float kMaxWeight = 12.0f;      // later frames keep refining, never frozen
  const Eigen::VectorXf model_albedo = state.albedo;
  const Gamma light = rendering_lighting(params.gamma);
  if (!light_usable_for_albedo(light)) return;
  const cv::Rect roi = covered_rect(g, 2);
  const cv::Mat boundary_px = roi.empty() ? cv::Mat() : im.BoundaryDistance(g, state, camera, roi);
  Eigen::Vector3f brightest = Eigen::Vector3f::Zero();
  const std::vector<float> unfolded = im.LidUnfolding(params);
  for (int v = 0; v < n; ++v) {
    const FacePart part = im.part_of(v);
    if (!(ropt.parts & part_bit(part)) || !(unfolded[static_cast<size_t>(v)] > 0.f)) continue;
    if (folded_lids_only && im.folded_lid_blink[static_cast<size_t>(v)] < 0) continue;
    const Eigen::Vector3f x = state.camera_positions.segment<3>(3 * v);
    if (!(x.z() > camera.near_plane)) continue;
    const Eigen::Vector2f uv = project(camera, x);
    const int i = pixel_round(uv.x()), j = pixel_round(uv.y());
    if (i < 1 || j < 1 || i >= camera.width - 1 || j >= camera.height - 1) continue;
    if (!g.covered(i, j) || std::abs(g.depth(i, j) - x.z()) > kAlbedoDepthToleranceM) continue;  // hidden
    if (boundary_px.empty() || !(boundary_px.at<float>(j - roi.y, i - roi.x) >= kAlbedoBoundaryClearancePx)) continue;
    if (frame_depth && frame_depth->type() == CV_32FC1 && frame_depth->size() == frame_bgr.size()) {
      // With a depth map, only pixels whose measured depth confirms this surface: sensor holes
      // sit at silhouettes, where a misfit model samples the background.
      const float d = frame_depth->at<float>(j, i);
      if (!std::isfinite(d) || !(d > 0.f) || std::abs(d - x.z()) > kAlbedoMeasuredDepthToleranceM) continue;
    }
    const Eigen::Vector3f nrm = state.camera_normals.segment<3>(3 * v);
    const float cos_view = -nrm.dot(x.normalized());
    if (cos_view < kAlbedoMinCos) continue;
    const auto basis = gpu::sh_basis(nrm);
    // A 3x3 average (in linear light) of the pixels whose surface is this vertex's, against noise.
    Eigen::Vector3f linear = Eigen::Vector3f::Zero();
    int samples = 0;
    bool clipped = false;
    for (int dj = -1; dj <= 1; ++dj)
      for (int di = -1; di <= 1; ++di) {
        if (!g.covered(i + di, j + dj) || std::abs(g.depth(i + di, j + dj) - x.z()) > 2.0f * kAlbedoDepthToleranceM) continue;
        const cv::Vec3b px = frame_bgr.at<cv::Vec3b>(j + dj, i + di);
        if (px[0] >= kClippedLevel || px[1] >= kClippedLevel || px[2] >= kClippedLevel) clipped = true;
        for (int c = 0; c < 3; ++c) linear[c] += srgb_decode_table()[px[2 - c]];
        ++samples;
      }
    if (samples < 5 || clipped) continue;
    linear /= static_cast<float>(samples);
    bool ok = true;
    Eigen::Vector3f observed;
    for (int c = 0; c < 3; ++c) {
      if (!well_lit(light, basis, c)) ok = false;
      // Divided by the irradiance the re-rendering uses (the mouth's floor included), so the
      // observed colour is what it reproduces.
      observed[c] = std::clamp(linear[c] / std::max(im.irradiance_at(light, basis, c, v), 0.05f), 0.0f, 1.0f);
    }
    if (!ok) continue;
    for (int c = 0; c < 3; ++c) brightest[c] = std::max(brightest[c], irradiance(light, basis, c));
    if (!plausible_albedo(model_albedo.segment<3>(3 * v), &observed)) continue;
    const float wv = cos_view * cos_view * unfolded[static_cast<size_t>(v)];
    const float wold = std::min(map->weight[v], kMaxWeight);
    map->albedo.segment<3>(3 * v) = (map->albedo.segment<3>(3 * v) * wold + observed * wv) / (wold + wv);
    map->weight[v] = wold + wv;
  }
  // (A lids-only observation sees too little of the face to say how bright its light gets.)
  if (!folded_lids_only && brightest.minCoeff() > 0.f) map->max_irradiance = brightest;
  im.FillUnobserved(model_albedo, map);
}

AlbedoTexture FaceCompositor::BuildAlbedoTexture(const std::vector<AlbedoTextureFrame>& frames,
                                                 std::shared_ptr<const AlbedoTextureLayout> layout,
                                                 const Eigen::VectorXf& base_albedo, int levels) const {
  const auto start = Clock::now();
  if (!layout) throw Error("albedo texture: no layout");
  std::vector<AlbedoTextureView> views;
  for (const AlbedoTextureFrame& f : frames) {
    AlbedoTextureView v = UnwrapAlbedo(f.bgr, f.camera, f.params, *layout, f.depth.empty() ? nullptr : &f.depth);
    v.frame_index = f.frame_index;
    v.closed_eyes = f.closed_eyes;
    if (f.closed_eyes) {
      // Only on the lids a resting eye folds: elsewhere the resting views are the face's rest.
      const Impl& im = *impl_;
      v.seen_texels = 0;
      for (int j = 0; j < layout->height; ++j)
        for (int i = 0; i < layout->width; ++i) {
          const size_t texel = static_cast<size_t>(j) * static_cast<size_t>(layout->width) + static_cast<size_t>(i);
          if (layout->triangle[texel] < 0) continue;
          float folded = 0.f;
          for (size_t k = 0; k < 3; ++k)
            if (im.folded_lid_blink[static_cast<size_t>(layout->vertices[3 * texel + k])] >= 0) folded += layout->barycentric[3 * texel + k];
          v.weight.at<float>(j, i) *= folded;
          v.seen_texels += v.weight.at<float>(j, i) > 0.f;
        }
    }
    views.push_back(std::move(v));
  }
  AlbedoTexture texture = BlendAlbedoViews(std::move(layout), views, base_albedo, levels);
  texture.build_ms = ms_since(start);
  return texture;
}

AlbedoTextureView FaceCompositor::UnwrapAlbedo(const cv::Mat& frame_bgr, const gpu::PinholeCamera& camera,
                                               const gpu::FaceParameters& params, const AlbedoTextureLayout& layout,
                                               const cv::Mat* frame_depth) const {
  std::string why;
  if (!camera.IsValid(&why)) throw Error("albedo texture: invalid camera: " + why);
  if (frame_bgr.type() != CV_8UC3 || frame_bgr.cols != camera.width || frame_bgr.rows != camera.height)
    throw Error("albedo texture: the frame must be 8-bit BGR of the camera's size");
  const Impl& im = *impl_;
  if (layout.textured.size() != im.model.triangles.size())
    throw Error("albedo texture: the layout belongs to another face model");
  AlbedoTextureView view;
  view.albedo = cv::Mat::zeros(layout.height, layout.width, CV_32FC3);
  view.weight = cv::Mat::zeros(layout.height, layout.width, CV_32FC1);
  view.yaw_deg = head_yaw_deg(params);
  const Gamma light = rendering_lighting(params.gamma);
  if (!light_usable_for_albedo(light)) return view;
  const int n = im.model.num_vertices();
  const gpu::VertexState state = im.renderer.evaluate(params, nullptr, im.threads());
  gpu::RenderOptions ropt;
  ropt.parts = im.drawn_parts();
  // The CPU rasteriser whatever options.renderer says: the unwrap may run beside the frame's own
  // rendering (AlbedoTextureOptions::background), and the Vulkan renderer is not shared.
  gpu::GBuffer& g = Impl::scratch_gbuffer(1);
  im.renderer.rasterize(state, camera, ropt, &g, im.threads());
  const cv::Rect roi = covered_rect(g, 2);
  if (roi.empty()) return view;
  const cv::Mat boundary_px = im.BoundaryDistance(g, state, camera, roi);
  // Per vertex, the irradiance the re-rendering shades it with (Compose), so the texel's albedo
  // times the same interpolation reproduces the frame; and whether its light is strong enough.
  std::vector<Eigen::Vector3f> lit(static_cast<size_t>(n));
  std::vector<char> lit_well(static_cast<size_t>(n), 1);
  for (int v = 0; v < n; ++v) {
    const Eigen::Vector3f nrm = state.camera_normals.segment<3>(3 * v);
    const auto basis = im.lit_basis(v, nrm, state.camera_positions.segment<3>(3 * v));
    for (int c = 0; c < 3; ++c) {
      lit[static_cast<size_t>(v)][c] = im.irradiance_at(light, basis, c, v);
      if (!well_lit(light, gpu::sh_basis(nrm), c)) lit_well[static_cast<size_t>(v)] = 0;
    }
  }
  const std::vector<float> unfolded = im.LidUnfolding(params);
  const bool with_depth = frame_depth && frame_depth->type() == CV_32FC1 && frame_depth->size() == frame_bgr.size();
  const float w_max = static_cast<float>(camera.width - 1), h_max = static_cast<float>(camera.height - 1);
  // The weight rises from nothing at a grazing kMinCos to cos^2 at kFullCos and beyond, and from
  // nothing at kAlbedoBoundaryClearancePx to full at twice that: the views' seams and the
  // fallback's border fall where neither view is sharp, and the blend spreads them. Grazing
  // surface is taken further than the per-vertex map takes it (kAlbedoMinCos): the sides of the
  // nose face the camera at 0.3-0.5 in a frontal view, and a side view, where there is one,
  // outweighs it by cos^2; without one, the frame's blurred colour there is still the actor's,
  // where the per-vertex map's fill drew a grey nose.
  constexpr float kMinCos = 0.2f, kFullCos = 0.4f;
  // Pixels this close to a blown-out one (every channel clipped: a window, a lamp) are not taken:
  // the fit's silhouette a few pixels off puts its edge, mixed with the skin, on the cheek (white
  // flecks along the webcam clip's left cheek). Skin clipped in one channel is still skin (the
  // overexposed webcam clip's cheeks are red-clipped over large areas): taken, a little too dark
  // in that channel, as the frame shows it.
  constexpr int kClippedReachPx = 3;
  cv::Mat near_clipped;
  {
    std::vector<cv::Mat> channels;
    cv::split(frame_bgr, channels);
    cv::Mat clipped = (channels[0] >= kClippedLevel) & (channels[1] >= kClippedLevel) & (channels[2] >= kClippedLevel);
    cv::dilate(clipped, near_clipped,
               cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * kClippedReachPx + 1, 2 * kClippedReachPx + 1)));
  }
  std::atomic<int> seen{0};
  ParallelFor(layout.height, im.threads(), [&](int j) {
    int seen_here = 0;
    for (int i = 0; i < layout.width; ++i) {
      const size_t texel = static_cast<size_t>(j) * static_cast<size_t>(layout.width) + static_cast<size_t>(i);
      if (layout.triangle[texel] < 0) continue;
      Eigen::Vector3f x = Eigen::Vector3f::Zero(), nrm = Eigen::Vector3f::Zero(), e = Eigen::Vector3f::Zero();
      bool well = true;
      float unfolded_w = 0.f;
      for (size_t k = 0; k < 3; ++k) {
        const int32_t v = layout.vertices[3 * texel + k];
        const float b = layout.barycentric[3 * texel + k];
        unfolded_w += b * unfolded[static_cast<size_t>(v)];
        x += b * state.camera_positions.segment<3>(3 * v);
        nrm += b * state.camera_normals.segment<3>(3 * v);
        e += b * lit[static_cast<size_t>(v)];
        well = well && lit_well[static_cast<size_t>(v)];
      }
      if (!well || !(unfolded_w > 0.f) || !(x.z() > camera.near_plane) || !(nrm.norm() > 1e-6f)) continue;
      const float facing = -nrm.normalized().dot(x.normalized());
      if (facing < kMinCos) continue;
      const Eigen::Vector2f px = project(camera, x);
      if (!(px.x() >= 1.f) || !(px.y() >= 1.f) || !(px.x() <= w_max - 1.f) || !(px.y() <= h_max - 1.f)) continue;
      const int pi = static_cast<int>(std::lround(px.x())), pj = static_cast<int>(std::lround(px.y()));
      if (!g.covered(pi, pj) || std::abs(g.depth(pi, pj) - x.z()) > kAlbedoDepthToleranceM) continue;  // hidden
      const float clearance = boundary_px.at<float>(pj - roi.y, pi - roi.x);
      if (!(clearance > kAlbedoBoundaryClearancePx)) continue;
      if (with_depth) {
        const float d = frame_depth->at<float>(pj, pi);
        if (!std::isfinite(d) || !(d > 0.f) || std::abs(d - x.z()) > kAlbedoMeasuredDepthToleranceM) continue;
      }
      if (near_clipped.at<uchar>(pj, pi)) continue;
      const Eigen::Vector3f linear = sample_linear(frame_bgr, px.x(), px.y());
      Eigen::Vector3f observed, prior = Eigen::Vector3f::Zero();
      for (size_t k = 0; k < 3; ++k)
        prior += layout.barycentric[3 * texel + k] * state.albedo.segment<3>(3 * layout.vertices[3 * texel + k]);
      for (int c = 0; c < 3; ++c) observed[c] = std::clamp(linear[c] / std::max(e[c], 0.05f), 0.0f, 1.0f);
      if (!plausible_albedo(prior, &observed)) continue;
      const float cos_w = std::clamp((facing - kMinCos) / (kFullCos - kMinCos), 0.0f, 1.0f);
      const float edge_w = std::clamp(clearance / kAlbedoBoundaryClearancePx - 1.0f, 0.0f, 1.0f);
      view.albedo.at<cv::Vec3f>(j, i) = cv::Vec3f(observed[0], observed[1], observed[2]);
      view.weight.at<float>(j, i) = unfolded_w * cos_w * edge_w * std::min(facing, 1.0f) * std::min(facing, 1.0f);
      ++seen_here;
    }
    seen += seen_here;
  });
  view.seen_texels = seen.load();
  return view;
}

}  // namespace face_reenact::reenact
