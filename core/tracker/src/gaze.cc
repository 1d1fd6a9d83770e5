#include "face_reenact/tracker/gaze.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <exception>
#include <limits>
#include <tuple>
#include <utility>
#include <vector>

#include "face_reenact/common/error.h"
#include "face_reenact/common/parallel.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/tracker/energy.h"
#include "tracker_internal.h"

namespace face_reenact::tracker {
namespace {

using Clock = std::chrono::steady_clock;

// Vertices of an eyeball within this angle of the model's +z (from the eyeball's centre) are its
// front: their centroid lies on the eye's axis (the pupil is within 14 degrees, the iris 32).
constexpr double kFrontDegrees = 20.0;
// A pixel's squared colour difference counts at most this much (linear RGB): an iris where the
// sclera is costs about 0.6, sensor noise about 0.002.
constexpr double kMaxPixelCost = 0.3;
// A real iris: 11.7 mm across (the mean horizontal visible iris diameter of adults, which varies
// by about half a millimetre), in a face whose eyes are 63 mm apart.
constexpr double kRealIrisDiameterM = 11.7e-3, kRealEyeDistanceM = 63e-3;
// The range of the per-eye brightness gain of the gaze search.
constexpr double kMinGain = 0.5, kMaxGain = 2.0;
// The albedo profile around the axis, in bins of this many degrees.
constexpr double kProfileBinDegrees = 2.0;
constexpr int kProfileBins = static_cast<int>(180.0 / kProfileBinDegrees);

// Albedo as a function of the angle from the eye's axis: the mean vertex albedo per bin, empty
// bins interpolated linearly between their neighbours (the render interpolates vertex albedos
// across triangles the same way).
struct AlbedoProfile {
  std::array<Eigen::Vector3d, kProfileBins> bin{};

  Eigen::Vector3d at(double degrees) const {
    const double x = std::clamp(degrees / kProfileBinDegrees - 0.5, 0.0, static_cast<double>(kProfileBins - 1));
    const int k = std::min(static_cast<int>(x), kProfileBins - 2);
    const double f = x - k;
    return (1 - f) * bin[k] + f * bin[k + 1];
  }
};

AlbedoProfile make_profile(const std::vector<double>& degrees, const std::vector<Eigen::Vector3d>& albedo) {
  std::array<Eigen::Vector3d, kProfileBins> sum{};
  std::array<int, kProfileBins> count{};
  for (auto& s : sum) s.setZero();
  for (size_t i = 0; i < degrees.size(); ++i) {
    const int k = std::clamp(static_cast<int>(degrees[i] / kProfileBinDegrees), 0, kProfileBins - 1);
    sum[k] += albedo[i];
    ++count[k];
  }
  std::vector<int> filled;
  for (int k = 0; k < kProfileBins; ++k)
    if (count[k] > 0) filled.push_back(k);
  AlbedoProfile p;
  for (int k = 0; k < kProfileBins; ++k) {
    // The filled bins on either side (the first / last one beyond the ends).
    auto hi = std::lower_bound(filled.begin(), filled.end(), k);
    if (hi == filled.end()) {
      p.bin[k] = sum[filled.back()] / count[filled.back()];
    } else if (*hi == k || hi == filled.begin()) {
      p.bin[k] = sum[*hi] / count[*hi];
    } else {
      const int a = *(hi - 1), b = *hi;
      const double f = static_cast<double>(k - a) / (b - a);
      p.bin[k] = (1 - f) * sum[a] / count[a] + f * sum[b] / count[b];
    }
  }
  return p;
}

// One eyeball pixel: the surface point it shows (model frame), its shading per channel, and the
// colour the camera saw.
struct EyePixel {
  Eigen::Vector3d position;
  Eigen::Vector3d irradiance;
  Eigen::Vector3d input;
  int i = 0, j = 0;           // in the crop
  bool looks_like_lid = false;  // nearer the lid's colour than any colour of the eyeball
};

// The eyeball's iris and sclera colours: the means of the vertex colours darker and brighter than
// halfway between the darkest and the brightest (by the sum of the channels). False when the
// eyeball has one colour.
bool split_iris_and_sclera(const std::vector<Eigen::Vector3d>& albedo, Eigen::Vector3d* dark, Eigen::Vector3d* bright) {
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (const auto& a : albedo) lo = std::min(lo, a.sum()), hi = std::max(hi, a.sum());
  if (!(hi > lo)) return false;
  dark->setZero();
  bright->setZero();
  int nd = 0, nb = 0;
  for (const auto& a : albedo) {
    if (a.sum() < 0.5 * (lo + hi)) {
      *dark += a, ++nd;
    } else {
      *bright += a, ++nb;
    }
  }
  *dark /= nd;
  *bright /= nb;
  return true;
}

// The profile of an iris `iris_degrees` wide from the axis: `dark` within it, `bright` beyond
// (the bin it ends in mixed by the share of the bin it covers).
AlbedoProfile two_tone_profile(const Eigen::Vector3d& dark, const Eigen::Vector3d& bright, double iris_degrees) {
  AlbedoProfile p;
  for (int k = 0; k < kProfileBins; ++k) {
    const double f = std::clamp(iris_degrees / kProfileBinDegrees - k, 0.0, 1.0);
    p.bin[static_cast<size_t>(k)] = f * dark + (1 - f) * bright;
  }
  return p;
}

}  // namespace

// One eye as the fitted face has it: its centre and front (the centroid of the front vertices),
// the albedo profile around the axis from centre to front, its pixels.
struct GazeEstimator::EyeState {
  Eigen::Vector3d centre = Eigen::Vector3d::Zero(), front = Eigen::Vector3d::Zero();
  AlbedoProfile profile;
  std::vector<EyePixel> pixels;
  // The colour of the skin around the eye as the camera sees it (the median of the face pixels
  // next to the eyeball in the render).
  Eigen::Vector3d skin = Eigen::Vector3d::Zero();
  // An iris of a given size (ReadEye's iris_degrees): the profile is these two colours, iris and
  // sclera, and a pixel between them (an iris edge, blurred) is eyeball, not lid.
  bool two_tone = false;
  Eigen::Vector3d dark = Eigen::Vector3d::Zero(), bright = Eigen::Vector3d::Zero();
};

namespace {

Eigen::Vector3d vec3(const Eigen::VectorXf& v, int i) { return v.segment<3>(3 * i).cast<double>(); }

// The eyeball's centre: the centroid of its vertices (the builder's eyeball is an evenly spaced
// sphere, docs/face-model.md).
Eigen::Vector3d centroid(const Eigen::VectorXf& positions, const std::vector<int>& vertices) {
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  for (int v : vertices) c += vec3(positions, v);
  return c / static_cast<double>(vertices.size());
}

}  // namespace

bool GazeOptions::IsValid(std::string* why) const {
  auto fail = [&](const char* m) {
    if (why) *why = m;
    return false;
  };
  if (min_eye_pixels < 1) return fail("gaze: min_eye_pixels must be >= 1");
  if (!(min_vergence > 0 && min_vergence <= 2)) return fail("gaze: min_vergence must be in (0, 2]");
  if (!(vergence_improvement >= 0 && vergence_improvement < 1)) return fail("gaze: vergence_improvement must be in [0, 1)");
  if (!(max_blink_for_vergence >= 0 && max_blink_for_vergence <= 1)) return fail("gaze: max_blink_for_vergence must be in [0, 1]");
  if (min_vertical_rows < 1) return fail("gaze: min_vertical_rows must be >= 1");
  if (!(min_open_fraction >= 0 && min_open_fraction <= 1)) return fail("gaze: min_open_fraction must be in [0, 1]");
  if (grid_steps < 3 || grid_steps > 201) return fail("gaze: grid_steps must be in [3, 201]");
  if (refine_steps < 1 || refine_steps > 201) return fail("gaze: refine_steps must be in [1, 201]");
  if (!(prior >= 0 && std::isfinite(prior))) return fail("gaze: prior must be finite and >= 0");
  if (!(min_improvement >= 0 && std::isfinite(min_improvement))) return fail("gaze: min_improvement must be finite and >= 0");
  if (!(lids_below_open_fraction >= 0 && lids_below_open_fraction <= 1)) {
    return fail("gaze: lids_below_open_fraction must be in [0, 1]");
  }
  if (!(lids_from_weight >= 0 && lids_from_weight <= 1)) return fail("gaze: lids_from_weight must be in [0, 1]");
  if (lid_steps < 2 || lid_steps > 101) return fail("gaze: lid_steps must be in [2, 101]");
  if (!(real_iris_check_above >= 0 && real_iris_check_above <= 1))
    return fail("gaze: real_iris_check_above must be in [0, 1]");
  if (!(real_iris_disagreement >= 0 && real_iris_disagreement <= 2))
    return fail("gaze: real_iris_disagreement must be in [0, 2]");
  if (!(real_iris_crossed_min_turn >= 0 && real_iris_crossed_min_turn <= 1))
    return fail("gaze: real_iris_crossed_min_turn must be in [0, 1]");
  if (threads < 0) return fail("gaze: threads must be >= 0 (0: one per hardware thread)");
  return true;
}

GazeEstimator::GazeEstimator(const TrackerModel& model) : model_(&model) {
  const auto& rm = model.render;
  const auto& names = arkit_eye_look_names();
  for (int e = 0; e < 2; ++e) {
    for (int k = 0; k < 4; ++k) {
      look_[e][k] = arkit_blendshape_index(names[static_cast<size_t>(e)][static_cast<size_t>(k)]);
      if (look_[e][k] < 0 || look_[e][k] >= model.num_expression()) return;
    }
    Eye& eye = eyes_[e];
    eye.part = static_cast<int>(e == 0 ? FacePart::LeftEye : FacePart::RightEye);
    for (int v = 0; v < rm.num_vertices(); ++v)
      if (rm.vertex_part[v] == eye.part) eye.vertices.push_back(v);
    if (eye.vertices.size() < 20) return;
    const Eigen::Vector3d c = centroid(rm.mean_shape, eye.vertices);
    const double cos_front = std::cos(kFrontDegrees * M_PI / 180.0);
    for (int v : eye.vertices) {
      const Eigen::Vector3d d = vec3(rm.mean_shape, v) - c;
      if (d.norm() > 0 && d.normalized().z() > cos_front) eye.front.push_back(v);
    }
    if (eye.front.empty()) return;
    const int blink = arkit_blendshape_index(e == 0 ? "eyeBlinkLeft" : "eyeBlinkRight");
    blink_[e] = blink >= 0 && blink < model.num_expression() ? blink : -1;
    // The blendshapes are linear offsets, so centre and front move linearly with each weight.
    for (int k = 0; k < 4; ++k) {
      Eigen::Vector3d all = Eigen::Vector3d::Zero(), fr = Eigen::Vector3d::Zero();
      for (int v : eye.vertices) all += rm.expression_basis.block(3 * v, look_[e][k], 3, 1).cast<double>();
      for (int v : eye.front) fr += rm.expression_basis.block(3 * v, look_[e][k], 3, 1).cast<double>();
      eye.centre_per_weight[k] = all / static_cast<double>(eye.vertices.size());
      eye.front_per_weight[k] = fr / static_cast<double>(eye.front.size());
    }
  }
  // The vertices the lids move, and how far per unit weight of both eyeBlink weights.
  if (blink_[0] >= 0 && blink_[1] >= 0) {
    for (int v = 0; v < rm.num_vertices(); ++v) {
      const Eigen::Vector3f d = rm.expression_basis.block(3 * v, blink_[0], 3, 1) + rm.expression_basis.block(3 * v, blink_[1], 3, 1);
      if (d.squaredNorm() > 0) lid_vertices_.push_back({v, d});
    }
  }
  // A real iris on the model's eyeball, scaled by the mean face's eye distance.
  {
    const Eigen::Vector3d c0 = centroid(rm.mean_shape, eyes_[0].vertices);
    const Eigen::Vector3d c1 = centroid(rm.mean_shape, eyes_[1].vertices);
    double radius = 0;
    for (int v : eyes_[0].vertices) radius += (vec3(rm.mean_shape, v) - c0).norm();
    radius /= static_cast<double>(eyes_[0].vertices.size());
    const double iris_radius = 0.5 * kRealIrisDiameterM * (c1 - c0).norm() / kRealEyeDistanceM;
    if (radius > iris_radius) real_iris_degrees_ = std::asin(iris_radius / radius) * 180.0 / M_PI;
  }
  available_ = true;
}

std::array<GazeEstimator::Weight, 8> GazeEstimator::WeightsFor(float horizontal, float vertical) const {
  return WeightsForEyes(horizontal, horizontal, vertical);
}

std::array<GazeEstimator::Weight, 8> GazeEstimator::WeightsForEyes(float left, float right, float vertical) const {
  const float up = std::max(vertical, 0.f), down = std::max(-vertical, 0.f);
  // Looking to the person's left turns the left eye out and the right eye in.
  return {{{look_[0][0], std::max(left, 0.f)},
           {look_[0][1], std::max(-left, 0.f)},
           {look_[0][2], up},
           {look_[0][3], down},
           {look_[1][0], std::max(-right, 0.f)},
           {look_[1][1], std::max(right, 0.f)},
           {look_[1][2], up},
           {look_[1][3], down}}};
}

// The fitted face rendered at full resolution in a crop around both eyes.
struct GazeEstimator::EyeRegion {
  std::string message;  // why there is no render (empty: rendered)
  gpu::VertexState state;
  gpu::PinholeCamera crop;  // the camera of the crop
  gpu::GBuffer g;           // the crop
  int x0 = 0, y0 = 0;       // the crop's corner in the image
};

// The eye renders' parts; their states are not shaded (VertexColors::kNone) and their colours
// never read.
constexpr gpu::RenderOptions kEyeRegionRender = [] {
  gpu::RenderOptions o = kTrackedParts;
  o.colors = false;
  return o;
}();

GazeEstimator::EyeRegion GazeEstimator::RenderEyeRegion(const gpu::CpuRenderer& renderer, const InputFrame& frame,
                                                        const gpu::FaceParameters& at, int threads) const {
  EyeRegion out;
  const int w = frame.width(), h = frame.height();
  try {
    out.state = renderer.evaluate(at, nullptr, threads, gpu::VertexColors::kNone);  // read: geometry and albedo
  } catch (const std::exception& e) {
    out.message = std::string("the fit cannot be rendered: ") + e.what();
    return out;
  }
  // The image region of both eyes, with a margin.
  const gpu::PinholeCamera& cam = frame.camera;
  double u0 = std::numeric_limits<double>::infinity(), vmin = u0, u1 = -u0, vmax = -u0;
  for (const Eye& eye : eyes_) {
    for (int v : eye.vertices) {
      const Eigen::Vector3d x = vec3(out.state.camera_positions, v);
      if (!(x.z() > cam.near_plane)) {
        out.message = "an eye is behind the camera";
        return out;
      }
      const double u = cam.fx * x.x() / x.z() + cam.cx, vv = cam.fy * x.y() / x.z() + cam.cy;
      u0 = std::min(u0, u), u1 = std::max(u1, u), vmin = std::min(vmin, vv), vmax = std::max(vmax, vv);
    }
  }
  if (!(std::isfinite(u0) && std::isfinite(u1) && std::isfinite(vmin) && std::isfinite(vmax))) {
    out.message = "the fit is not finite";
    return out;
  }
  // Clamped in double first: a face far outside the image must not overflow the int casts.
  auto clamp_px = [](double x, int hi) { return static_cast<int>(std::clamp(x, -1.0, static_cast<double>(hi) + 1)); };
  const int x0 = std::max(0, clamp_px(std::floor(u0), w) - 2), x1 = std::min(w - 1, clamp_px(std::ceil(u1), w) + 2);
  const int y0 = std::max(0, clamp_px(std::floor(vmin), h) - 2), y1 = std::min(h - 1, clamp_px(std::ceil(vmax), h) + 2);
  if (x0 > x1 || y0 > y1) {
    out.message = "the eyes are outside the image";
    return out;
  }
  gpu::PinholeCamera& crop = out.crop;
  crop = cam;
  crop.width = x1 - x0 + 1;
  crop.height = y1 - y0 + 1;
  crop.cx -= static_cast<float>(x0);
  crop.cy -= static_cast<float>(y0);
  renderer.rasterize(out.state, crop, kEyeRegionRender, &out.g, threads);
  out.x0 = x0;
  out.y0 = y0;
  return out;
}

// Eye e as the render `region` of `at` shows it: its axis and albedo profile, its pixels (each
// marked when it looks like the lid), the lid's colour; *opening_rows: the rows its pixels span.
// Returns an empty string, or why the eye cannot be read.
std::string GazeEstimator::ReadEye(const EyeRegion& region, const InputFrame& frame, const gpu::FaceParameters& at,
                                   int e, double iris_degrees, EyeState* out, int* opening_rows) const {
  const auto& rm = model_->render;
  const gpu::GBuffer& g = region.g;
  const int w = frame.width();
  const Eigen::Matrix3d R = gpu::rotation_from_euler(at.euler).cast<double>();
  const Eigen::Vector3d t = at.translation.cast<double>();
  // The input colour at a pixel of the crop.
  auto sample = [&](int i, int j) {
    const size_t f = (static_cast<size_t>(j + region.y0) * w + (i + region.x0)) * 3;
    return Eigen::Vector3d(frame.color[f], frame.color[f + 1], frame.color[f + 2]);
  };
  const Eye& eye = eyes_[e];
  EyeState& s = *out;
  // The centre of the rendered eyeball (turned by its eyeLook weights), and its front.
  s.centre = centroid(region.state.model_positions, eye.vertices);
  s.front.setZero();
  for (int v : eye.front) s.front += vec3(region.state.model_positions, v);
  s.front /= static_cast<double>(eye.front.size());
  if (!((s.front - s.centre).norm() > 0)) return "degenerate eyeball";
  std::vector<double> degrees;
  std::vector<Eigen::Vector3d> albedo;
  const Eigen::Vector3d a = (s.front - s.centre).normalized();
  for (int v : eye.vertices) {
    const Eigen::Vector3d d = (vec3(region.state.model_positions, v) - s.centre).normalized();
    degrees.push_back(std::acos(std::clamp(d.dot(a), -1.0, 1.0)) * 180.0 / M_PI);
    albedo.push_back(vec3(region.state.albedo, v));
  }
  s.profile = make_profile(degrees, albedo);
  if (iris_degrees > 0 && split_iris_and_sclera(albedo, &s.dark, &s.bright)) {
    s.two_tone = true;
    s.profile = two_tone_profile(s.dark, s.bright, iris_degrees);
  }

  int row_min = g.height, row_max = -1;
  for (int j = 0; j < g.height; ++j) {
    for (int i = 0; i < g.width; ++i) {
      const size_t p = static_cast<size_t>(j) * g.width + i;
      if (g.triangle[p] < 0) continue;
      bool on_eye = true;
      for (int k = 0; k < 3; ++k) on_eye = on_eye && rm.vertex_part[g.vertices[3 * p + k]] == eye.part;
      if (!on_eye) continue;
      const Eigen::Vector3d x(g.position[3 * p], g.position[3 * p + 1], g.position[3 * p + 2]);
      const Eigen::Vector3d position = R.transpose() * (x - t);
      const Eigen::Vector3f n(g.normal[3 * p], g.normal[3 * p + 1], g.normal[3 * p + 2]);
      const auto y = gpu::sh_basis(n);
      Eigen::Vector3d irr;
      for (int ch3 = 0; ch3 < 3; ++ch3) {
        double sum = 0;
        for (int q = 0; q < gpu::kNumShCoefficients; ++q) sum += at.gamma[ch3 * 9 + q] * y[q];
        irr[ch3] = sum;
      }
      const Eigen::Vector3d input = sample(i, j);
      if (!position.allFinite() || !irr.allFinite() || !input.allFinite()) continue;
      s.pixels.push_back({position, irr, input, i, j, false});
      row_min = std::min(row_min, j), row_max = std::max(row_max, j);
    }
  }
  *opening_rows = row_max - row_min + 1;
  // The lids around the eyeball: face pixels within 2 px of one of its pixels.
  std::vector<double> channel[3];
  const int face = static_cast<int>(FacePart::Face);
  auto part_at = [&](int i, int j) {
    const size_t p = static_cast<size_t>(j) * g.width + i;
    return g.triangle[p] < 0 ? -1 : static_cast<int>(rm.vertex_part[g.vertices[3 * p]]);
  };
  // Within 2 px: the eyeball's pixels spread over a 5 x 5 square, one axis at a time (a 5 x 5
  // scan per face pixel was a fifth of the gaze reading's time on a 250 px face).
  constexpr int kLidReachPx = 2;
  const size_t gw = static_cast<size_t>(g.width);
  std::vector<char> on_eye(gw * static_cast<size_t>(g.height)), across(on_eye.size()), near(on_eye.size());
  for (int j = 0; j < g.height; ++j)
    for (int i = 0; i < g.width; ++i) on_eye[static_cast<size_t>(j) * gw + static_cast<size_t>(i)] = part_at(i, j) == eye.part;
  // `to` at (i, j): whether `from` is set within kLidReachPx along the rows (di 1) or the columns (dj 1).
  auto spread = [&](const std::vector<char>& from, std::vector<char>* to, int di, int dj) {
    for (int j = 0; j < g.height; ++j)
      for (int i = 0; i < g.width; ++i) {
        char any = 0;
        for (int k = -kLidReachPx; k <= kLidReachPx && !any; ++k) {
          const int ii = i + k * di, jj = j + k * dj;
          any = ii >= 0 && jj >= 0 && ii < g.width && jj < g.height && from[static_cast<size_t>(jj) * gw + static_cast<size_t>(ii)];
        }
        (*to)[static_cast<size_t>(j) * gw + static_cast<size_t>(i)] = any;
      }
  };
  spread(on_eye, &across, 1, 0);
  spread(across, &near, 0, 1);
  for (int j = 0; j < g.height; ++j) {
    for (int i = 0; i < g.width; ++i) {
      if (!near[static_cast<size_t>(j) * gw + static_cast<size_t>(i)] || part_at(i, j) != face) continue;
      const Eigen::Vector3d input = sample(i, j);
      for (int c3 = 0; c3 < 3; ++c3)
        if (std::isfinite(input[c3])) channel[c3].push_back(input[c3]);
    }
  }
  for (int c3 = 0; c3 < 3; ++c3) {
    // No lid seen: every pixel is eyeball.
    s.skin[c3] = channel[c3].empty() ? std::numeric_limits<double>::quiet_NaN() : internal::median(std::move(channel[c3]));
  }
  // A pixel the fit puts on the eyeball may show lid in the image: a squint or a blink the
  // solve did not read (on a smiling synthetic actor the rendered openings were a third taller
  // than the real ones). A pixel nearer the lid's colour than any colour of the eyeball (pupil,
  // iris, sclera under that pixel's shading) looks like the lid.
  if (s.skin.allFinite()) {
    for (EyePixel& px : s.pixels) {
      double eyeball = std::numeric_limits<double>::infinity();
      for (const Eigen::Vector3d& alb : s.profile.bin)
        eyeball = std::min(eyeball, (alb.cwiseProduct(px.irradiance) - px.input).squaredNorm());
      if (s.two_tone) {  // the nearest colour between iris and sclera
        const Eigen::Vector3d a = s.dark.cwiseProduct(px.irradiance), ab = s.bright.cwiseProduct(px.irradiance) - a;
        const double t = ab.squaredNorm() > 0 ? std::clamp((px.input - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0) : 0.0;
        eyeball = std::min(eyeball, (a + t * ab - px.input).squaredNorm());
      }
      px.looks_like_lid = (s.skin - px.input).squaredNorm() < eyeball;
    }
  }
  return "";
}

// One search: the face rendered with the gaze (h0, v0), candidates within `half` of (ch, cv).
GazeEstimator::Pass GazeEstimator::Search(const gpu::CpuRenderer& renderer, const InputFrame& frame,
                                          const gpu::FaceParameters& fit, float h0, float v0, double ch, double cv,
                                          double half, const GazeOptions& options, double iris_degrees,
                                          std::shared_ptr<const EyeRegion> reuse) const {
  Pass out;
  const int threads = ResolvedThreadCount(options.threads);
  gpu::FaceParameters at = fit;
  const auto rendered = WeightsFor(h0, v0);
  for (const Weight& wt : rendered) at.delta[wt.index] = wt.value;
  out.region =
      reuse ? std::move(reuse) : std::make_shared<const EyeRegion>(RenderEyeRegion(renderer, frame, at, threads));
  const EyeRegion& region = *out.region;
  if (!region.message.empty()) {
    out.message = region.message;
    return out;
  }
  std::array<EyeState, 2> eyes;
  for (int e = 0; e < 2; ++e) {
    EyeState& s = eyes[e];
    int rows = 0;
    const std::string why = ReadEye(region, frame, at, e, iris_degrees, &s, &rows);
    if (!why.empty()) {
      out.message = why;
      return out;
    }
    const int rendered_eye_pixels = static_cast<int>(s.pixels.size());
    out.opening_rows = std::max(out.opening_rows, rows);
    // Pixels that look like the lid are left out. Kept, they read as an iris turned down into
    // them (eyeLookDown 0.8-1.0 on every frame); costed as the lesser of eyeball and lid per
    // candidate, they biased every vertical reading downwards.
    s.pixels.erase(std::remove_if(s.pixels.begin(), s.pixels.end(), [](const EyePixel& px) { return px.looks_like_lid; }),
                   s.pixels.end());
    // An eye too small to say anything counts as open.
    out.open_fraction[e] = rendered_eye_pixels >= options.min_eye_pixels
                               ? static_cast<double>(s.pixels.size()) / rendered_eye_pixels
                               : 1.0;
    out.rendered_pixels += rendered_eye_pixels;
    out.pixels += static_cast<int>(s.pixels.size());
  }
  if (out.rendered_pixels > 0 && out.pixels < options.min_open_fraction * out.rendered_pixels) {
    out.message = "eyes mostly covered: " + std::to_string(out.pixels) + " of the fit's " +
                  std::to_string(out.rendered_pixels) + " eyeball pixels look like an eyeball (a blink or squint)";
    return out;
  }
  if (out.pixels < options.min_eye_pixels) {
    out.message = "eyes closed or too small: " + std::to_string(out.pixels) + " eyeball pixels, " +
                  std::to_string(options.min_eye_pixels) + " needed";
    return out;
  }

  // Mean squared colour difference over both eyes for a conjugate gaze, plus the prior. The eyes
  // move from where they were rendered by the difference of the weights. The predicted colours
  // carry one brightness gain per eye: the lighting fitted to the whole face can be off around
  // the eyes, and swapping the truth's lighting for the fit's alone turned readings of 0.37-0.43
  // into 0.06-0.16 on a synthetic actor. The sideways search solves the gains in closed form for
  // each candidate (a sideways turn moves the iris across the opening, which no gain can mimic).
  // The vertical search takes the fitted lighting as it is: a turn up or down changes how much
  // dark iris the opening shows, which a gain absorbs (free gains read 0.13-0.21 up on renders
  // looking straight ahead, the sideways reading's gains 0.10-0.12, none -0.02-0).
  // Eye e's summed squared colour difference (added to *sum) with its sideways turn hz. Each
  // candidate's on its own (the grids below cost them on the pool's threads).
  auto eye_energy = [&](int e, double hz, double vt, bool fit_gains, double* sum) {
    const auto weights = WeightsFor(static_cast<float>(hz), static_cast<float>(vt));
    const EyeState& s = eyes[e];
    Eigen::Vector3d centre = s.centre, front = s.front;
    for (int k = 0; k < 4; ++k) {
      const double dw = static_cast<double>(weights[4 * e + k].value) - rendered[4 * e + k].value;
      centre += dw * eyes_[e].centre_per_weight[k];
      front += dw * eyes_[e].front_per_weight[k];
    }
    const Eigen::Vector3d axis = (front - centre).normalized();
    // The least-squares gain (sum |g p - i|^2 is least at g = pi / pp), then each pixel's
    // squared difference capped at kMaxPixelCost: a few pixels the model cannot explain (lashes
    // and a lid margin that a blink starting or a squint brings into the opening) cannot drag
    // the iris across the eye, while a misplaced iris still costs every pixel it misses.
    double pp = 0, pi = 0;
    std::vector<Eigen::Vector3d> predicted(s.pixels.size());
    for (size_t q = 0; q < s.pixels.size(); ++q) {
      const EyePixel& px = s.pixels[q];
      const Eigen::Vector3d direction = (px.position - centre).normalized();
      const double deg = std::acos(std::clamp(direction.dot(axis), -1.0, 1.0)) * 180.0 / M_PI;
      predicted[q] = s.profile.at(deg).cwiseProduct(px.irradiance);
      pp += predicted[q].squaredNorm();
      pi += predicted[q].dot(px.input);
    }
    const double g = fit_gains && pp > 0 && pi > 0 ? std::clamp(pi / pp, kMinGain, kMaxGain) : 1.0;
    for (size_t q = 0; q < s.pixels.size(); ++q)
      *sum += std::min((g * predicted[q] - s.pixels[q].input).squaredNorm(), kMaxPixelCost);
  };
  auto energy = [&](double hz, double vt, bool fit_gains) {
    double sum = 0;
    for (int e = 0; e < 2; ++e) eye_energy(e, hz, vt, fit_gains, &sum);
    return sum / out.pixels + options.prior * (hz * hz + vt * vt);
  };
  // The costs of candidates 0..count-1, computed on the pool's threads; the grids take the
  // first best in their own order, so the reading does not depend on the thread count.
  auto costs_of = [&](int count, const auto& cost) {
    std::vector<double> costs(static_cast<size_t>(count));
    ParallelFor(count, threads, [&](int k) { costs[static_cast<size_t>(k)] = cost(k); });
    return costs;
  };
  // grid(centre h, centre v, half width, steps, vertical too, fit gains): the best candidate
  // into out; returns the grid's step.
  auto grid = [&](double gh, double gv, double gh_half, int steps, bool with_vertical, bool fit_gains) {
    const double step = steps > 1 ? 2 * gh_half / (steps - 1) : 0;
    const int rows = with_vertical ? steps : 1;
    auto candidate = [&](int k) {  // (a, b) = (k / rows, k % rows)
      const int a = k / rows, b = k % rows;
      const double hz = std::clamp(gh - gh_half + a * step, -1.0, 1.0);
      const double vt = with_vertical ? std::clamp(gv - gh_half + b * step, -1.0, 1.0) : gv;
      return std::pair{hz, vt};
    };
    const std::vector<double> costs = costs_of(steps * rows, [&](int k) {
      const auto [hz, vt] = candidate(k);
      return energy(hz, vt, fit_gains);
    });
    for (int k = 0; k < steps * rows; ++k) {
      const double en = costs[static_cast<size_t>(k)];
      if (en < out.energy) std::tie(out.h, out.v) = candidate(k), out.energy = en;
    }
    return step;
  };
  // A turn up or down moves the iris about half as far as one to the side (eyeLookUp moves the
  // front of the eyeball 2.7 mm per unit weight, eyeLookOut 5.4 mm), and in an opening a few
  // pixels tall the lids hide what it moves: on 640x480 synthetic actors 1 m away (openings 3-4
  // rows) the vertical reading went to the end of the range on nearly every frame. So the
  // vertical gaze is read only when asked for and where the opening is tall enough.
  const bool vertical = options.read_vertical && out.opening_rows >= options.min_vertical_rows;
  out.vertical_read = vertical;
  out.h = std::clamp(ch, -1.0, 1.0);
  out.v = vertical ? std::clamp(cv, -1.0, 1.0) : 0.0;
  out.energy = energy(out.h, out.v, true);
  out.straight_energy = energy(0.0, 0.0, true);
  const double step = grid(ch, out.v, half, options.grid_steps, false, true);
  grid(out.h, out.v, step, options.refine_steps, false, true);
  if (vertical) {
    out.energy = energy(out.h, out.v, false);
    grid(out.h, out.v, half, options.grid_steps, true, false);
    grid(out.h, out.v, step, options.refine_steps, true, false);
  }
  // Each eye on its own (GazeOptions::read_vergence): its sideways turn over the whole range, then
  // finer around its best; the energy is the conjugate one's with each eye at its own turn.
  if (options.read_vergence) {
    auto eye_cost = [&](int e, double hz) {
      double sum = 0;
      eye_energy(e, hz, out.v, true, &sum);
      return sum / out.pixels + 0.5 * options.prior * hz * hz;
    };
    std::array<double, 2> best{}, at_conjugate{};
    for (int e = 0; e < 2; ++e) {
      at_conjugate[e] = best[e] = eye_cost(e, out.h);
      out.per_eye[e] = out.h;
      auto eye_grid = [&](double centre, double reach, int steps) {
        const double s = steps > 1 ? 2 * reach / (steps - 1) : 0;
        auto candidate = [&](int a) { return std::clamp(centre - reach + a * s, -1.0, 1.0); };
        const std::vector<double> costs = costs_of(steps, [&](int a) { return eye_cost(e, candidate(a)); });
        for (int a = 0; a < steps; ++a)
          if (costs[static_cast<size_t>(a)] < best[e]) best[e] = costs[static_cast<size_t>(a)], out.per_eye[e] = candidate(a);
        return s;
      };
      const double eye_step = eye_grid(0.0, 1.0, options.grid_steps);
      eye_grid(out.per_eye[e], eye_step, options.refine_steps);
    }
    const double apart = out.per_eye[1] - out.per_eye[0];
    // Turned towards each other or away (opposite sides): two readings of one side differing in
    // size are the side the iris hides in a corner (liveportrait_d0 glancing hard aside read -1.0
    // and -0.33, a conjugate -0.7). And only open eyes: in a slit each eye's few pixels read any
    // turn (liveportrait_d14 with her eyes nearly shut, frame 112: -0.6 and 0.97).
    bool open = true;
    for (int e = 0; e < 2; ++e) open = open && (blink_[e] < 0 || fit.delta[blink_[e]] <= options.max_blink_for_vergence);
    // Each eye's own drop (GazeOptions::vergence_improvement): an eye turned past the model's
    // range keeps most of its difference at any turn and would hide the other's in the sum.
    bool lowered = false;
    for (int e = 0; e < 2; ++e)
      lowered = lowered || at_conjugate[e] - best[e] >= options.vergence_improvement * at_conjugate[e];
    out.vergent = open && out.per_eye[0] * out.per_eye[1] <= 0 && std::abs(apart) >= options.min_vergence && lowered;
  }
  out.ok = true;
  return out;
}

bool GazeEstimator::ReadLids(const gpu::CpuRenderer& renderer, const InputFrame& frame, const gpu::FaceParameters& fit,
                             const GazeOptions& options, GazeReading* reading) const {
  if (blink_[0] < 0 || blink_[1] < 0) {
    reading->lids_message = "the model has no eyeBlink blendshapes";
    return false;
  }
  const auto& rm = model_->render;
  // The eyes rendered open: each pixel of the opening looks like eyeball or like lid.
  gpu::FaceParameters open_at = fit;
  open_at.delta[blink_[0]] = 0.f;
  open_at.delta[blink_[1]] = 0.f;
  const int threads = ResolvedThreadCount(options.threads);
  const EyeRegion open = RenderEyeRegion(renderer, frame, open_at, threads);
  if (!open.message.empty()) {
    reading->lids_message = open.message;
    return false;
  }
  const size_t crop_pixels = open.g.triangle.size();
  std::array<std::vector<int8_t>, 2> seen;  // per crop pixel: -1 no eyeball open, 0 lid, 1 eyeball
  std::array<int, 2> open_pixels{};
  std::array<bool, 2> readable{};
  for (int e = 0; e < 2; ++e) {
    EyeState s;
    int rows = 0;
    const std::string why = ReadEye(open, frame, open_at, e, /*iris_degrees=*/0, &s, &rows);
    if (!why.empty()) {
      reading->lids_message = why;
      return false;
    }
    seen[e].assign(crop_pixels, -1);
    int eyeball = 0;
    for (const EyePixel& px : s.pixels) {
      seen[e][static_cast<size_t>(px.j) * open.g.width + px.i] = px.looks_like_lid ? 0 : 1;
      eyeball += px.looks_like_lid ? 0 : 1;
    }
    open_pixels[e] = static_cast<int>(s.pixels.size());
    reading->open_fraction[e] = open_pixels[e] > 0 ? static_cast<double>(eyeball) / open_pixels[e] : 0.0;
    // Without lid colour around it no pixel can look like lid; an eye this small says nothing.
    readable[e] = s.skin.allFinite() && open_pixels[e] >= options.min_eye_pixels;
  }
  if (!readable[0] && !readable[1]) {
    reading->lids_message = "the open eyes show too few pixels, or no lid around them";
    return false;
  }
  // Per candidate weight (both lids at it), per eye: the pixels where the render and the marks
  // disagree (the render shows eyeball where the image shows lid or the open render none, or
  // hides eyeball the image shows), as a fraction of the open eye's pixels.
  // The candidates move only the vertices the eyeBlink blendshapes move, and only which pixels
  // show eyeball matters: the open render's vertices with those moved, rasterised into the same
  // crop (no model evaluation, normals or shading).
  // The weights are tried from 0 up while the disagreement falls for some eye (it has one
  // minimum): an open eye the fit misplaces (a third of its pixels looking like lid is common
  // with dlib's landmarks) is settled after the first closed candidate.
  const int steps = options.lid_steps;
  std::vector<std::array<double, 2>> cost(static_cast<size_t>(steps));
  const Eigen::Matrix3f R = gpu::rotation_from_euler(open_at.euler);
  gpu::VertexState shut = open.state;
  gpu::GBuffer shut_g;
  int tried = 0;
  for (int k = 0; k < steps; ++k) {
    if (k >= 2) {
      bool falling = false;
      for (int e = 0; e < 2; ++e)
        falling = falling || (readable[e] && cost[static_cast<size_t>(k - 1)][e] <= cost[static_cast<size_t>(k - 2)][e]);
      if (!falling) break;
    }
    tried = k + 1;
    const float b = static_cast<float>(k) / static_cast<float>(steps - 1);
    if (k > 0) {
      for (const LidVertex& lv : lid_vertices_) {
        const Eigen::Vector3f x = open.state.model_positions.segment<3>(3 * lv.vertex) + b * lv.offset;
        shut.camera_positions.segment<3>(3 * lv.vertex) = R * x + open_at.translation;
      }
      renderer.rasterize(shut, open.crop, kEyeRegionRender, &shut_g, threads);
    }
    const gpu::GBuffer& g = k > 0 ? shut_g : open.g;
    for (int e = 0; e < 2; ++e) {
      if (!readable[e]) continue;
      const int part = eyes_[e].part;
      int disagree = 0;
      for (size_t p = 0; p < g.triangle.size(); ++p) {
        bool shown = g.triangle[p] >= 0;
        for (int q = 0; q < 3 && shown; ++q) shown = rm.vertex_part[g.vertices[3 * p + q]] == part;
        if (shown != (seen[e][p] == 1)) ++disagree;
      }
      cost[static_cast<size_t>(k)][e] = static_cast<double>(disagree) / open_pixels[e];
    }
  }
  for (int e = 0; e < 2; ++e) {
    if (!readable[e]) {
      reading->blink[e] = fit.delta[blink_[e]];
      continue;
    }
    int best = 0;
    for (int k = 1; k < tried; ++k)
      if (cost[static_cast<size_t>(k)][e] < cost[static_cast<size_t>(best)][e]) best = k;
    // Between the grid's weights: the vertex of the parabola through the best and its neighbours.
    double x = best;
    if (best > 0 && best + 1 < tried) {
      const double c0 = cost[static_cast<size_t>(best - 1)][e], c1 = cost[static_cast<size_t>(best)][e],
                   c2 = cost[static_cast<size_t>(best + 1)][e];
      const double curvature = c0 - 2 * c1 + c2;
      if (curvature > 0) x += std::clamp(0.5 * (c0 - c2) / curvature, -0.5, 0.5);
    }
    reading->blink[e] = static_cast<float>(std::clamp(x / (steps - 1), 0.0, 1.0));
  }
  reading->lids_read = true;
  return true;
}

GazeReading GazeEstimator::Read(const gpu::CpuRenderer& renderer, const InputFrame& frame, gpu::FaceParameters* params,
                                const GazeOptions& options, bool lids_fit) const {
  const auto t0 = Clock::now();
  GazeReading out;
  auto done = [&](const std::string& message) {
    out.message = message;
    out.ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
    return out;
  };
  if (!available_) return done("the model has no eyeballs with eyeLook blendshapes");
  const int w = frame.width(), h = frame.height();
  if (w <= 0 || h <= 0 || frame.color.size() != static_cast<size_t>(3) * w * h) return done("no colour image");
  gpu::FaceParameters fit = *params;
  if (fit.delta.size() < model_->num_expression()) {
    Eigen::VectorXf d = Eigen::VectorXf::Zero(model_->num_expression());
    d.head(fit.delta.size()) = fit.delta;
    fit.delta = d;
  }
  // First over the whole range with the eyes rendered straight ahead (exactly the model's
  // spheres), then around that reading with the eyes rendered turned: the eyeLook blendshapes
  // move the lids a little too, and the second render has them where the reading puts them.
  // The first pass's own per-eye (vergence) reading counts only where the second pass fails, so
  // it runs only then: it was a third of the search's candidates on every frame.
  GazeOptions conjugate_only = options;
  conjugate_only.read_vergence = false;
  const double iris = 0;  // the model's own iris
  Pass first = Search(renderer, frame, fit, 0.f, 0.f, 0.0, 0.0, 1.0, conjugate_only, iris);
  // The lids first, where the fit's opening shows lid or the fit has an eye closed: the gaze is
  // then read in the opening they leave.
  if (options.read_lids && !frame.has_depth()) {
    out.lids_message = "no depth: the lids are read on RGB-D frames only";
  } else if (options.read_lids && !lids_fit) {
    out.lids_message = "the fit does not place the eyes well enough for the lids (no depth or no calibration)";
  } else if (options.read_lids && blink_[0] >= 0 && blink_[1] >= 0) {
    bool look = false;
    for (int e = 0; e < 2; ++e)
      look = look || (first.rendered_pixels > 0 && first.open_fraction[e] < options.lids_below_open_fraction) ||
             fit.delta[blink_[e]] > options.lids_from_weight;
    if (look && ReadLids(renderer, frame, fit, options, &out)) {
      fit.delta[blink_[0]] = out.blink[0];
      fit.delta[blink_[1]] = out.blink[1];
      params->delta = fit.delta;
      first = Search(renderer, frame, fit, 0.f, 0.f, 0.0, 0.0, 1.0, conjugate_only, iris);
    }
  }
  out.pixels = first.pixels;
  out.eyeball_pixels = first.rendered_pixels;
  if (!first.ok) return done(first.message);
  GazeOptions local = options;
  local.grid_steps = 7;
  const double cell = 2.0 / (options.grid_steps - 1);
  const Pass second = Search(renderer, frame, fit, static_cast<float>(first.h), static_cast<float>(first.v), first.h,
                             first.v, 1.5 * cell, local, iris);
  if (!second.ok && options.read_vergence)
    first = Search(renderer, frame, fit, 0.f, 0.f, 0.0, 0.0, 1.0, options, iris, first.region);
  const Pass& best = second.ok ? second : first;
  // A gaze the image shows clearly lowers the straight-ahead difference by far more than noise
  // and an eye region the fit does not match do (see GazeOptions::min_improvement).
  // The model's iris is half as wide again as a real one (kRealIrisDiameterM): on a real eye
  // looking nearly ahead, the best match for its iris can be the model's turned into a corner
  // (liveportrait_d14, frames 220-262: +-0.8-1.0 where she looks within 0.3 of ahead), and a hard
  // glance can leave too little of the model's iris on show to pass the gate (d14, 61-65).
  // Read again with an iris of a real size there (GazeOptions::real_iris_check_above); on a render
  // of the model the two readings agree within the disagreement (0.5 read 0.71), so renders keep
  // the model's own reading.
  auto real_iris = [&](const Pass& full) {
    Pass real = full;
    if (!full.ok) return real;
    GazeOptions refine = conjugate_only;
    refine.grid_steps = 7;
    const Pass around = Search(renderer, frame, fit, static_cast<float>(full.h), 0.f, full.h, 0.0, 1.5 * cell, refine,
                               real_iris_degrees_);
    if (around.ok) real = around;
    return real;
  };
  auto take_real = [&](const Pass& real, const Pass& full) {
    out.ok = true;
    out.real_iris = true;
    out.horizontal = static_cast<float>(real.h);
    out.energy = real.energy;
    out.straight_energy = full.straight_energy;
    out.pixels = real.pixels;
    out.eyeball_pixels = real.rendered_pixels;
    for (const Weight& wt : out.vergence_read ? WeightsForEyes(out.per_eye[0], out.per_eye[1], 0.f)
                                              : WeightsFor(out.horizontal, 0.f))
      fit.delta[wt.index] = wt.value;
    params->delta = fit.delta;
    return done("");
  };
  // Each eye on its own with the real-sized iris (read_vergence's search and test): eyes crossed,
  // which the conjugate reading reads as one glance to a side (GazeOptions::real_iris_crossed_min_turn).
  auto real_iris_eyes = [&] {
    GazeOptions with_vergence = options;
    with_vergence.read_vergence = true;
    return Search(renderer, frame, fit, 0.f, 0.f, 0.0, 0.0, 1.0, with_vergence, real_iris_degrees_, first.region);
  };
  auto crossed = [&](const Pass& eyes) {
    const double turn = options.real_iris_crossed_min_turn;  // the left eye to the right, the right eye to the left
    return options.read_vergence && eyes.ok && eyes.vergent && eyes.per_eye[0] <= -turn && eyes.per_eye[1] >= turn;
  };
  auto take_real_eyes = [&](const Pass& eyes, const Pass& full) {
    out.vergence_read = true;
    out.per_eye = {static_cast<float>(eyes.per_eye[0]), static_cast<float>(eyes.per_eye[1])};
    return take_real(eyes, full);
  };
  const bool check_real = options.real_iris_check && real_iris_degrees_ > 0;
  const bool clear = first.straight_energy - best.energy >= options.min_improvement * best.energy;
  if (check_real && clear && !best.vergent && std::abs(best.h) >= options.real_iris_check_above) {
    const Pass full =
        Search(renderer, frame, fit, 0.f, 0.f, 0.0, 0.0, 1.0, conjugate_only, real_iris_degrees_, first.region);
    const Pass real = real_iris(full);
    if (real.ok && std::abs(real.h - best.h) > options.real_iris_disagreement) {
      if (options.read_vergence)
        if (const Pass eyes = real_iris_eyes(); crossed(eyes)) return take_real_eyes(eyes, full);
      return take_real(real, full);
    }
  }
  if (check_real && !clear) {
    // Only a hard glance, clear by the same gate, with the eyes turned together or crossed:
    // without each eye's own search (read_vergence's test) an actor crossing her eyes (d6,
    // 246-250) was read as a conjugate glance; eyes turned apart otherwise are not read. Not each
    // eye's own reading wherever the conjugate one is unclear: gated by its own colour difference,
    // it read d14's wide-open eyes looking ahead (67-78) and d0's at rest (0-3) as crossed.
    const Pass full =
        Search(renderer, frame, fit, 0.f, 0.f, 0.0, 0.0, 1.0, conjugate_only, real_iris_degrees_, first.region);
    if (full.ok && std::abs(full.h) >= options.real_iris_check_above) {
      const Pass real = real_iris(full);
      if (real.ok && std::abs(real.h) >= options.real_iris_check_above &&
          full.straight_energy - real.energy >= options.min_improvement * real.energy) {
        const Pass eyes = real_iris_eyes();
        if (crossed(eyes)) return take_real_eyes(eyes, full);
        if (eyes.ok && !eyes.vergent) return take_real(real, full);
      }
    }
  }
  if (!clear) {
    out.message = "no clear gaze: looking straight ahead differs by " +
                  std::to_string(best.energy > 0 ? (first.straight_energy - best.energy) / best.energy : 0.0) +
                  " of the reading's colour difference";
    return done(out.message);
  }
  out.ok = true;
  out.horizontal = static_cast<float>(best.h);
  out.vertical = static_cast<float>(best.v);
  out.vergence_read = best.vergent;
  out.per_eye = {static_cast<float>(best.per_eye[0]), static_cast<float>(best.per_eye[1])};
  out.energy = best.energy;
  out.straight_energy = first.straight_energy;
  out.pixels = best.pixels;
  out.eyeball_pixels = best.rendered_pixels;
  out.vertical_read = best.vertical_read;
  for (const Weight& wt : out.vergence_read ? WeightsForEyes(out.per_eye[0], out.per_eye[1], out.vertical)
                                            : WeightsFor(out.horizontal, out.vertical))
    fit.delta[wt.index] = wt.value;
  params->delta = fit.delta;
  return done("");
}

}  // namespace face_reenact::tracker
