#include "face_reenact/reenact/detail_transfer.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <sstream>
#include <vector>

#include <Eigen/Core>
#include <opencv2/imgproc.hpp>

#include "face_reenact/common/error.h"
#include "face_reenact/common/parallel.h"
#include "face_reenact/common/srgb.h"
#include "face_reenact/common/timing.h"
#include "face_reenact/gpu/cpu_renderer.h"
#include "face_parts.h"
#include "image_sampling.h"

namespace face_reenact::reenact {
namespace {

using internal::sample_float;

// The Laplacian levels kept of a source frame: the finest three (the one read is chosen by the
// ratio of the two faces' sizes in pixels).
constexpr int kLevels = 3;
// The relative detail's denominator never falls below this linear luminance (a black pixel has
// no contrast to speak of).
constexpr float kMinLuminance = 0.02f;
// A rest frame's 5x5 detail range up to kSmoothRange is smooth skin (its pores, the camera's
// noise); from kTexturedRange on it is hair, a brow or an edge (measured on the shared clips).
constexpr float kSmoothRange = 0.08f, kTexturedRange = 0.2f;
// A fold darkens skin by a fraction: a new detail of relative contrast up to kFoldContrast is
// taken whole, fading to none at kEdgeContrast (a hair strand over the cheek, a jaw's shadow line
// read a few pixels off: -0.2 and darker on the shared clips).
constexpr float kFoldContrast = 0.12f, kEdgeContrast = 0.2f;
// A fold is a valley: the level below it barely changes across it. A face's outline is a step
// (the jaw over the shadowed neck, a cheek against the background, a hair strand's edge): the
// level below changes across it by a large fraction per pixel. Where the fit is off by more than
// the outline guard allows (a source whose jaw the model does not reach: liveportrait_d14's
// narrow chin), the step's dark side was read as a new fold and drawn on the target's cheek as a
// thin curve. Up to kFoldStep of relative change per pixel (of the level read) is skin, from
// kOutlineStep on an outline (the pixels d14's frame 160 changed strongly, nearly all along her
// jaw: median 0.18, 0.05-0.34 from the tenth to the ninetieth percentile; a fold 12 % deep painted
// on a rendered cheek keeps its full darkening).
constexpr float kFoldStep = 0.06f, kOutlineStep = 0.12f;
// No detail within kOutlineZeroPx of a face's outline in its frame, all of it from kOutlineFullPx.
constexpr float kOutlineZeroPx = 3.0f, kOutlineFullPx = 10.0f;

// Each pixel's distance (px) from the nearest pixel outside `covered` (CV_8UC1, nonzero = in).
cv::Mat distance_inside(const cv::Mat& covered) {
  cv::Mat padded, dist;
  // A border of "outside" around the box: the box's edge is the frame's edge or beyond the face.
  cv::copyMakeBorder(covered, padded, 1, 1, 1, 1, cv::BORDER_CONSTANT, cv::Scalar(0));
  cv::distanceTransform(padded, dist, cv::DIST_L2, cv::DIST_MASK_3);
  return dist(cv::Rect(1, 1, covered.cols, covered.rows)).clone();
}

// Linear luminance of an 8-bit BGR image.
cv::Mat luminance_of(const cv::Mat& bgr) {
  const auto& lut = srgb_decode_table();
  cv::Mat y(bgr.size(), CV_32FC1);
  for (int j = 0; j < bgr.rows; ++j) {
    const cv::Vec3b* in = bgr.ptr<cv::Vec3b>(j);
    float* out = y.ptr<float>(j);
    for (int i = 0; i < bgr.cols; ++i) out[i] = linear_luminance(lut[in[i][2]], lut[in[i][1]], lut[in[i][0]]);
  }
  return y;
}

// Levels 0..count-1 of the relative Laplacian pyramid of `y`: (G_k - up(G_k+1)) / up(G_k+1).
// With `steps`, each level's relative step too: |grad up(G_k+1)| / up(G_k+1) per pixel of level k
// (how much the smoother image changes across the pixel: large at an outline, small at a fold).
std::vector<cv::Mat> relative_detail(const cv::Mat& y, int count, std::vector<cv::Mat>* steps = nullptr) {
  std::vector<cv::Mat> levels;
  cv::Mat g = y;
  for (int k = 0; k < count; ++k) {
    if (g.cols < 4 || g.rows < 4) break;
    cv::Mat down, up;
    cv::pyrDown(g, down);
    cv::pyrUp(down, up, g.size());
    cv::Mat d(g.size(), CV_32FC1);
    for (int j = 0; j < g.rows; ++j) {
      const float* gr = g.ptr<float>(j);
      const float* ur = up.ptr<float>(j);
      float* dr = d.ptr<float>(j);
      for (int i = 0; i < g.cols; ++i) dr[i] = (gr[i] - ur[i]) / std::max(ur[i], kMinLuminance);
    }
    levels.push_back(std::move(d));
    if (steps) {
      cv::Mat gx, gy;
      cv::Sobel(up, gx, CV_32F, 1, 0, 3, 1.0 / 8.0);  // 1/8: the kernel's weights, per pixel
      cv::Sobel(up, gy, CV_32F, 0, 1, 3, 1.0 / 8.0);
      cv::Mat st(g.size(), CV_32FC1);
      for (int j = 0; j < g.rows; ++j) {
        const float* xr = gx.ptr<float>(j);
        const float* yr = gy.ptr<float>(j);
        const float* ur = up.ptr<float>(j);
        float* sr = st.ptr<float>(j);
        for (int i = 0; i < g.cols; ++i) sr[i] = std::hypot(xr[i], yr[i]) / std::max(ur[i], kMinLuminance);
      }
      // The largest within 2 px: a fold's reading beside an edge sits on the edge's lobe.
      cv::dilate(st, st, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(5, 5)));
      steps->push_back(std::move(st));
    }
    g = down;
  }
  return levels;
}

// Position of full-resolution pixel coordinate x at pyramid level k (cv::pyrDown's centres).
float at_level(float x, int k) { return (x + 0.5f) / static_cast<float>(1 << k) - 0.5f; }

float smoothstep(float edge0, float edge1, float x) {
  const float t = std::clamp((x - edge0) / (edge1 - edge0), 0.0f, 1.0f);
  return t * t * (3.0f - 2.0f * t);
}

// A source frame prepared for reading: its detail levels and its fitted surface, over the face's
// box only (`camera` is the frame's, cropped to it: projections land in the box's pixels).
struct PreparedFrame {
  std::vector<cv::Mat> detail;            // relative Laplacian levels 0..kLevels-1
  // The rest frame's detail range around each pixel (its 5x5 minimum and maximum per level): a
  // detail the current frame shows within that range is the rest frame's own, seen a pixel or two
  // off (a fit is never exact), not something the expression made. A wide range marks hair, a
  // brow, a lid's edge: no smooth skin for a fold to show on.
  std::vector<cv::Mat> low, high;
  std::vector<cv::Mat> step;              // each level's relative step (relative_detail)
  Eigen::VectorXf positions, normals;     // 3N, camera space
  cv::Mat depth;                          // CV_32FC1, z of the visible face surface, 0 = none
  cv::Mat inside;                         // CV_32FC1, pixels from the visible face's outline
  gpu::PinholeCamera camera;
  float pixels_per_metre = 0.f;           // fx / z of the head
  int64_t frame_index = -1;
  gpu::PinholeCamera frame_camera;        // the view's own camera and fit (same_view)
  gpu::FaceParameters params;
  float expression = 0.f;                 // how far from relaxed (sum of |weights|, gaze excluded)
  bool empty() const { return detail.empty(); }
};

// Where a surface point (triangle corners v, barycentrics b) lies in a prepared frame and the
// detail read there at `level` (with `low` and `high`, also the frame's range there: a rest
// frame's; with `step`, the frame's relative step there); `facing` how squarely and how far inside
// its outline the frame shows it. False where the frame does not show the point.
bool read_detail(const PreparedFrame& f, const int32_t* v, const float* b, int level, float* detail, float* facing,
                 float* low = nullptr, float* high = nullptr, float* step = nullptr) {
  Eigen::Vector3f x = Eigen::Vector3f::Zero(), n = Eigen::Vector3f::Zero();
  for (int k = 0; k < 3; ++k) {
    x += b[k] * f.positions.segment<3>(3 * v[k]);
    n += b[k] * f.normals.segment<3>(3 * v[k]);
  }
  if (!(x.z() > f.camera.near_plane)) return false;
  const float u = f.camera.fx * x.x() / x.z() + f.camera.cx, w = f.camera.fy * x.y() / x.z() + f.camera.cy;
  if (!(u >= 0.f && w >= 0.f && u <= static_cast<float>(f.camera.width - 1) && w <= static_cast<float>(f.camera.height - 1)))
    return false;
  // Shown: the frame's visible face surface at the projection lies at the point's depth.
  const float z = f.depth.at<float>(static_cast<int>(std::lround(w)), static_cast<int>(std::lround(u)));
  const float tolerance = std::max(0.004f, 1.5f * x.z() / f.camera.fx);
  if (!(z > 0.f) || std::abs(z - x.z()) > tolerance) return false;
  // Grazing views smear the detail and sit at the silhouette, where the frame's edge against the
  // neck or the background is no skin detail: more than ~65 degrees from the view ray fades it.
  const float cos_view = -n.normalized().dot(x.normalized());
  // Away from the fitted face's outline in the frame: there (the jaw against the neck, the
  // hairline, hair over the cheek) a fit a few pixels off reads the frame's edges as detail.
  *facing = smoothstep(0.4f, 0.7f, cos_view) * smoothstep(kOutlineZeroPx, kOutlineFullPx, sample_float(f.inside, u, w));
  if (*facing <= 0.f) return false;
  const size_t k = static_cast<size_t>(std::min(level, static_cast<int>(f.detail.size()) - 1));
  const float lu = at_level(u, static_cast<int>(k)), lw = at_level(w, static_cast<int>(k));
  *detail = sample_float(f.detail[k], lu, lw);
  if (low && high) {
    if (f.low.size() <= k) return false;
    *low = sample_float(f.low[k], lu, lw);
    *high = sample_float(f.high[k], lu, lw);
  }
  if (step) *step = k < f.step.size() ? sample_float(f.step[k], lu, lw) : 0.f;
  return true;
}

}  // namespace

bool SourceView::IsValid(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  std::string sub;
  if (!camera.IsValid(&sub)) return fail("the source view's camera: " + sub);
  if (bgr.type() != CV_8UC3 || bgr.cols != camera.width || bgr.rows != camera.height)
    return fail("the source view's image must be 8-bit BGR of its camera's size (" + std::to_string(camera.width) + "x" +
                std::to_string(camera.height) + ")");
  if (!params.IsValid(&sub)) return fail("the source view's parameters: " + sub);
  return true;
}

const char* detail_mode_name(DetailMode mode) {
  switch (mode) {
    case DetailMode::kOff: return "off";
    case DetailMode::kTransient: return "transient";
    case DetailMode::kCopy: return "copy";
  }
  return "unknown";
}

bool ParseDetailMode(const std::string& name, DetailMode* mode) {
  for (DetailMode m : {DetailMode::kOff, DetailMode::kTransient, DetailMode::kCopy})
    if (name == detail_mode_name(m)) {
      *mode = m;
      return true;
    }
  return false;
}

bool DetailTransferOptions::IsValid(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (mode != DetailMode::kOff && mode != DetailMode::kTransient && mode != DetailMode::kCopy)
    return fail("unknown detail mode");
  if (!std::isfinite(gain) || gain < 0.f || gain > 4.f) return fail("detail gain must be in [0, 4]");
  if (!std::isfinite(coring) || coring < 0.f || coring > 0.5f) return fail("detail coring must be in [0, 0.5]");
  if (!std::isfinite(max_contrast) || max_contrast <= 0.f || max_contrast > 1.f)
    return fail("detail max_contrast must be in (0, 1]");
  if (!std::isfinite(rest_max_turn_deg) || rest_max_turn_deg <= 0.f || rest_max_turn_deg > 90.f)
    return fail("detail rest_max_turn_deg must be in (0, 90]");
  return true;
}

struct DetailTransfer::Impl {
  const FaceModel& model;
  DetailTransferOptions options;
  gpu::CpuRenderer renderer;
  std::vector<float> skin;          // per vertex, skin_weight()
  std::vector<char> gaze;           // per expression weight: an eyeLook (moves no skin)
  PreparedFrame now, rest;
  float strength = 1.f;
  mutable gpu::GBuffer scratch;

  Impl(const FaceModel& m, const DetailTransferOptions& o)
      : model(m), options(o), renderer(gpu::RenderModel::FromFaceModel(m)) {
    BuildSkinWeight();
    gaze.assign(static_cast<size_t>(model.num_expression()), 0);
    for (int k = 0; k < model.num_expression() && k < static_cast<int>(model.expression_names.size()); ++k)
      gaze[static_cast<size_t>(k)] = model.expression_names[static_cast<size_t>(k)].rfind("eyeLook", 0) == 0;
  }

  // The skin weight from the mean shape seen from the front (model x, y in millimetres): 0
  // inside the outer lip line, the eye openings and along the nostrils' lower edge, rising to
  // 1 a few millimetres away. Their edges are the frame's own strong lines; read through a fit
  // off by a pixel they would draw a second lip line or lid, not a wrinkle.
  void BuildSkinWeight() {
    const int n = model.num_vertices();
    std::array<int32_t, 68> at;
    at.fill(-1);
    for (const auto& l : model.landmarks)
      if (l.ibug_index >= 0 && l.ibug_index < 68) at[static_cast<size_t>(l.ibug_index)] = l.vertex;
    auto xy = [&](int32_t v) {
      return cv::Point2f(1000.f * model.mean_shape[3 * v], 1000.f * model.mean_shape[3 * v + 1]);
    };
    auto polygon = [&](int first, int last) {
      std::vector<cv::Point2f> p;
      for (int i = first; i <= last; ++i) {
        if (at[static_cast<size_t>(i)] < 0) throw Error("detail transfer: the face model lacks landmark " + std::to_string(i));
        p.push_back(xy(at[static_cast<size_t>(i)]));
      }
      return p;
    };
    // (polygon, zero within this many mm outside it, full weight from this far)
    struct Zone {
      std::vector<cv::Point2f> outline;
      float zero_mm, full_mm;
    };
    const std::vector<Zone> zones = {{polygon(48, 59), 1.0f, 4.0f},   // the lips
                                     {polygon(36, 41), 4.0f, 7.0f},   // the right eye's opening and lids
                                     {polygon(42, 47), 4.0f, 7.0f},   // the left eye's
                                     {polygon(31, 35), 1.5f, 4.0f}};  // the nostrils' lower edge
    // The brows (17-21, 22-26) as lines: their hair moves over the skin as they rise and fall,
    // and a brow edge read a pixel off is no fold; the frown's lines between them stay.
    const std::vector<std::vector<cv::Point2f>> brows = {polygon(17, 21), polygon(22, 26)};
    auto distance_to_line = [](const std::vector<cv::Point2f>& line, const cv::Point2f& p) {
      float best = std::numeric_limits<float>::max();
      for (size_t i = 0; i + 1 < line.size(); ++i) {
        const cv::Point2f a = line[i], d = line[i + 1] - line[i];
        const float t = std::clamp((p - a).dot(d) / std::max(d.dot(d), 1e-9f), 0.0f, 1.0f);
        const cv::Point2f q = a + t * d;
        best = std::min(best, static_cast<float>(std::hypot(p.x - q.x, p.y - q.y)));
      }
      return best;
    };
    // Inside the jaw line (0-16, closed far above the forehead): the jaw's edge against the neck
    // is a line of the frame, and a fit's jaw is the least certain of its contours.
    std::vector<cv::Point2f> outline = polygon(0, 16);
    outline.push_back(outline.back() + cv::Point2f(0.f, 150.f));
    outline.push_back(outline.front() + cv::Point2f(0.f, 150.f));
    // The face part's border with the scalp, the ears and the neck: the hairline and the jaw's
    // edge are the frame's strong lines, no skin detail.
    std::vector<Eigen::Vector3f> border;
    for (int v = 0; v < n; ++v) {
      const FacePart part = model.vertex_part[static_cast<size_t>(v)];
      if (part == FacePart::Scalp || part == FacePart::Ear || part == FacePart::Neck)
        border.push_back(1000.f * Eigen::Vector3f(model.mean_shape.segment<3>(3 * v)));
    }
    skin.assign(static_cast<size_t>(n), 0.f);
    for (int v = 0; v < n; ++v) {
      if (model.vertex_part[static_cast<size_t>(v)] != FacePart::Face) continue;
      const cv::Point2f p = xy(v);
      float w = 1.f;
      for (const Zone& z : zones) {
        // Signed distance, positive inside.
        const float inside = static_cast<float>(cv::pointPolygonTest(z.outline, p, true));
        w = std::min(w, smoothstep(z.zero_mm, z.full_mm, -inside));
      }
      for (const auto& brow : brows) w = std::min(w, smoothstep(6.0f, 11.0f, distance_to_line(brow, p)));
      w = std::min(w, smoothstep(6.0f, 15.0f, static_cast<float>(cv::pointPolygonTest(outline, p, true))));
      const Eigen::Vector3f x = 1000.f * Eigen::Vector3f(model.mean_shape.segment<3>(3 * v));
      float nearest = std::numeric_limits<float>::max();
      for (const Eigen::Vector3f& b : border) nearest = std::min(nearest, (b - x).squaredNorm());
      w = std::min(w, smoothstep(4.0f, 10.0f, std::sqrt(nearest)));
      skin[static_cast<size_t>(v)] = w;
    }
  }

  // Prepares `view` (empty when the face is not in its frame).
  PreparedFrame Prepare(const SourceView& view) {
    PreparedFrame f;
    const gpu::VertexState state = renderer.evaluate(view.params, nullptr, threads());
    // The face's box in the frame (with a margin for the pyramid's filters): only it is
    // rasterised and decomposed.
    cv::Rect box;
    for (int v = 0; v < model.num_vertices(); ++v) {
      if (skin[static_cast<size_t>(v)] <= 0.f) continue;
      const Eigen::Vector3f x = state.camera_positions.segment<3>(3 * v);
      if (!(x.z() > view.camera.near_plane)) continue;
      const float u = view.camera.fx * x.x() / x.z() + view.camera.cx, w = view.camera.fy * x.y() / x.z() + view.camera.cy;
      if (!(std::abs(u) < 1e6f && std::abs(w) < 1e6f)) continue;
      box |= cv::Rect(static_cast<int>(std::floor(u)), static_cast<int>(std::floor(w)), 2, 2);
    }
    constexpr int kMargin = 16;
    box = (box + cv::Size(2 * kMargin, 2 * kMargin) - cv::Point(kMargin, kMargin)) &
          cv::Rect(0, 0, view.camera.width, view.camera.height);
    if (box.width < 8 || box.height < 8) return f;
    gpu::PinholeCamera crop = view.camera;
    crop.cx -= static_cast<float>(box.x);
    crop.cy -= static_cast<float>(box.y);
    crop.width = box.width;
    crop.height = box.height;
    gpu::RenderOptions ropt;
    ropt.parts = internal::part_bit(FacePart::Face);
    ropt.cull_back_faces = true;
    ropt.normals = false;  // read below: coverage and depth (the normals come from `state`)
    ropt.colors = false;
    renderer.rasterize(state, crop, ropt, &scratch, threads());
    f.depth = cv::Mat::zeros(crop.height, crop.width, CV_32FC1);
    cv::Mat covered = cv::Mat::zeros(crop.height, crop.width, CV_8UC1);
    for (int j = 0; j < crop.height; ++j) {
      float* row = f.depth.ptr<float>(j);
      for (int i = 0; i < crop.width; ++i)
        if (scratch.covered(i, j)) {
          row[i] = scratch.depth(i, j);
          covered.at<uchar>(j, i) = 255;
        }
    }
    f.inside = distance_inside(covered);
    f.detail = relative_detail(luminance_of(view.bgr(box)), kLevels, &f.step);
    f.positions = state.camera_positions;
    f.normals = state.camera_normals;
    f.camera = crop;
    f.pixels_per_metre = view.params.translation.z() > 0.f ? view.camera.fx / view.params.translation.z() : 0.f;
    f.frame_index = view.frame_index;
    f.frame_camera = view.camera;
    f.params = view.params;
    for (int k = 0; k < view.params.delta.size(); ++k)
      if (k >= static_cast<int>(gaze.size()) || !gaze[static_cast<size_t>(k)]) f.expression += std::abs(view.params.delta[k]);
    return f;
  }

  // The rest frame's detail range (PreparedFrame::low / high).
  static void MakeRange(PreparedFrame* f) {
    const cv::Mat kernel = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(5, 5));
    f->low.clear();
    f->high.clear();
    for (const cv::Mat& d : f->detail) {
      cv::Mat lo, hi;
      cv::erode(d, lo, kernel);
      cv::dilate(d, hi, kernel);
      f->low.push_back(lo);
      f->high.push_back(hi);
    }
  }

  // Whether `view` is the frame `f` was prepared from: the same frame of the source, with the
  // same camera and fit.
  static bool SameView(const PreparedFrame& f, const SourceView& view) {
    const gpu::PinholeCamera& a = f.frame_camera;
    const gpu::PinholeCamera& b = view.camera;
    const gpu::FaceParameters& p = f.params;
    const gpu::FaceParameters& q = view.params;
    auto same = [](const Eigen::VectorXf& x, const Eigen::VectorXf& y) { return x.size() == y.size() && x == y; };
    return view.frame_index >= 0 && view.frame_index == f.frame_index && a.fx == b.fx && a.fy == b.fy &&
           a.cx == b.cx && a.cy == b.cy && a.width == b.width && a.height == b.height && same(p.alpha, q.alpha) &&
           same(p.beta, q.beta) && same(p.delta, q.delta) && p.gamma == q.gamma && p.euler == q.euler &&
           p.translation == q.translation;
  }

  static int threads() { return ResolvedThreadCount(0); }

  bool ready() const {
    if (options.mode == DetailMode::kOff || now.empty() || strength <= 0.f) return false;
    return options.mode != DetailMode::kTransient || !rest.empty();
  }
};

DetailTransfer::DetailTransfer(const FaceModel& model, const DetailTransferOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw Error("detail transfer: " + why);
  impl_ = std::make_unique<Impl>(model, options);
}

DetailTransfer::~DetailTransfer() = default;

void DetailTransfer::SetOptions(const DetailTransferOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw Error("detail transfer: " + why);
  impl_->options = options;
}

const DetailTransferOptions& DetailTransfer::options() const { return impl_->options; }
const std::vector<float>& DetailTransfer::skin_weight() const { return impl_->skin; }

void DetailTransfer::Observe(const SourceView& view, float strength) {
  Impl& im = *impl_;
  if (im.options.mode == DetailMode::kOff) return;
  std::string why;
  if (!view.IsValid(&why)) throw Error("detail transfer: " + why);
  if (!std::isfinite(strength)) throw Error("detail transfer: the strength must be finite");
  im.strength = std::clamp(strength, 0.f, 1.f);
  // The frame prepared last, again (a 15 fps source on a 30 fps target gives each of its frames
  // to two target frames): nothing to redo.
  if (!im.now.empty() && Impl::SameView(im.now, view)) return;
  im.now = im.Prepare(view);
  if (im.now.empty() || im.options.mode != DetailMode::kTransient) return;
  // The rest frame: facing the camera, and clearly more relaxed than the one kept (by 0.05 of
  // summed weights: small wobbles of the fit do not swap it every frame).
  constexpr float kClearlyMoreRelaxed = 0.05f;
  if (gpu::head_turn_from_camera_deg(view.params) <= im.options.rest_max_turn_deg &&
      (im.rest.empty() || im.now.expression < im.rest.expression - kClearlyMoreRelaxed)) {
    im.rest = im.now;
    Impl::MakeRange(&im.rest);
  }
}

void DetailTransfer::Reset() {
  impl_->now = PreparedFrame{};
  impl_->rest = PreparedFrame{};
}

bool DetailTransfer::ready() const { return impl_->ready(); }
int64_t DetailTransfer::rest_frame_index() const { return impl_->rest.empty() ? -1 : impl_->rest.frame_index; }

std::string DetailTransfer::Description() const {
  const Impl& im = *impl_;
  if (im.options.mode == DetailMode::kOff) return "off";
  if (im.now.empty()) return "none yet: no tracked source frame has reached it (none does over a udp:// stream, which carries expressions only)";
  if (im.options.mode == DetailMode::kCopy) return "the source's skin detail, copied (the paper's transfer)";
  if (im.rest.empty()) return "none yet: the source has not faced the camera";
  std::ostringstream s;
  s.setf(std::ios::fixed);
  s.precision(2);
  s << "the source's folds and wrinkles against its rest frame " << im.rest.frame_index << " (expression "
    << im.rest.expression << ")";
  return s.str();
}

DetailStats DetailTransfer::Apply(const gpu::GBuffer& g, const gpu::PinholeCamera& camera, const cv::Mat& drawn,
                                  cv::Mat* rendered) const {
  const auto start = SteadyClock::now();
  DetailStats stats;
  const Impl& im = *impl_;
  if (!rendered || rendered->type() != CV_32FC3 || rendered->cols != g.width || rendered->rows != g.height ||
      drawn.type() != CV_8UC1 || drawn.size() != rendered->size() || camera.width != g.width || camera.height != g.height)
    throw Error("detail transfer: the rendered image, its mask and the G-buffer must match the camera's size");
  if (!im.ready()) return stats;
  const int w = g.width, h = g.height;

  // The source level whose band matches the target's finest: by the ratio of the faces' sizes
  // in pixels (a source face twice the target's in pixels is read one level down).
  double z_sum = 0.0;
  int z_count = 0;
  cv::Rect box;
  for (int j = 0; j < h; ++j)
    for (int i = 0; i < w; ++i) {
      const size_t p = static_cast<size_t>(j) * w + i;
      if (g.triangle[p] < 0 || !drawn.at<uchar>(j, i)) continue;
      z_sum += g.position[3 * p + 2];
      ++z_count;
      box |= cv::Rect(i, j, 1, 1);
    }
  if (z_count == 0) return stats;
  const float target_ppm = camera.fx / static_cast<float>(z_sum / z_count);
  const float ratio = im.now.pixels_per_metre / std::max(target_ppm, 1e-3f);
  stats.level = std::clamp(static_cast<int>(std::lround(std::log2(std::max(ratio, 1e-3f)))), 0, kLevels - 1);

  // The target face's own outline (the output's visible face part).
  cv::Mat target_covered = cv::Mat::zeros(box.size(), CV_8UC1);
  for (int j = 0; j < box.height; ++j)
    for (int i = 0; i < box.width; ++i) {
      const size_t p = static_cast<size_t>(j + box.y) * w + static_cast<size_t>(i + box.x);
      if (g.triangle[p] >= 0 && im.model.vertex_part[static_cast<size_t>(g.vertices[3 * p])] == FacePart::Face)
        target_covered.at<uchar>(j, i) = 255;
    }
  const cv::Mat target_inside = distance_inside(target_covered);
  const bool copy = im.options.mode == DetailMode::kCopy;
  // kCopy replaces the target's own level: the rendered face's finest relative level.
  cv::Mat own;
  if (copy) {
    cv::Mat y(box.size(), CV_32FC1);
    for (int j = 0; j < box.height; ++j)
      for (int i = 0; i < box.width; ++i) {
        const cv::Vec3f px = rendered->at<cv::Vec3f>(j + box.y, i + box.x);
        y.at<float>(j, i) = linear_luminance(srgb_decode(px[2] / 255.f), srgb_decode(px[1] / 255.f), srgb_decode(px[0] / 255.f));
      }
    own = relative_detail(y, 1).front();
  }
  const float gain = im.options.gain * im.strength, coring = im.options.coring, limit = im.options.max_contrast;
  // Bands of rows on the process's helper threads: each pixel is read and written by one band.
  const int bands = std::min(box.height, 4 * Impl::threads());
  std::vector<double> change_sums(static_cast<size_t>(bands), 0.0);
  std::vector<int> changed(static_cast<size_t>(bands), 0);
  const int level = stats.level;
  ParallelFor(bands, Impl::threads(), [&](int band) {
    const int j0 = box.y + band * box.height / bands, j1 = box.y + (band + 1) * box.height / bands;
    for (int j = j0; j < j1; ++j)
      for (int i = box.x; i < box.x + box.width; ++i) {
        const size_t p = static_cast<size_t>(j) * w + i;
        if (g.triangle[p] < 0 || !drawn.at<uchar>(j, i)) continue;
        const int32_t* v = &g.vertices[3 * p];
        const float* b = &g.barycentric[3 * p];
        float skin = 0.f;
        for (int k = 0; k < 3; ++k) skin += b[k] * im.skin[static_cast<size_t>(v[k])];
        if (skin <= 0.f) continue;
        // The target's own silhouette: a grazing surface there is the compositor's feathered edge.
        const Eigen::Vector3f xt(g.position[3 * p], g.position[3 * p + 1], g.position[3 * p + 2]),
            nt(g.normal[3 * p], g.normal[3 * p + 1], g.normal[3 * p + 2]);
        const float facing_target = smoothstep(0.4f, 0.7f, -nt.normalized().dot(xt.normalized())) *
                                    smoothstep(kOutlineZeroPx, kOutlineFullPx, target_inside.at<float>(j - box.y, i - box.x));
        if (facing_target <= 0.f) continue;
        float d_now = 0.f, facing_now = 0.f, step_now = 0.f;
        if (!read_detail(im.now, v, b, level, &d_now, &facing_now, nullptr, nullptr, &step_now)) continue;
        float change = 0.f, facing = facing_now;
        if (copy) {
          change = d_now - own.at<float>(j - box.y, i - box.x);
        } else {
          float d_rest = 0.f, facing_rest = 0.f, low = 0.f, high = 0.f;
          if (!read_detail(im.rest, v, b, level, &d_rest, &facing_rest, &low, &high)) continue;
          // Only what lies outside the rest frame's range around the point is new.
          change = d_now - std::clamp(d_now, std::min(low, d_rest), std::max(high, d_rest));
          change = std::copysign(std::max(std::abs(change) - coring, 0.0f), change);
          // On smooth skin only: where the rest frame's own detail spans a wide range (hair over
          // the cheek, a brow, a lid), what moves is that texture, not a fold.
          facing = std::min(facing, facing_rest) * smoothstep(kTexturedRange, kSmoothRange, high - low);
        }
        const float fold =
            copy ? 1.f : smoothstep(kEdgeContrast, kFoldContrast, std::abs(d_now)) * smoothstep(kOutlineStep, kFoldStep, step_now);
        change = std::clamp(gain * skin * fold * std::min(facing, facing_target) * change, -limit, limit);
        if (change == 0.f) continue;
        cv::Vec3f& px = rendered->at<cv::Vec3f>(j, i);
        for (int c = 0; c < 3; ++c) px[c] = 255.f * srgb_encode(srgb_decode(px[c] / 255.f) * (1.f + change));
        change_sums[static_cast<size_t>(band)] += std::abs(change);
        ++changed[static_cast<size_t>(band)];
      }
  });
  double change_sum = 0.0;
  for (int band = 0; band < bands; ++band) {
    change_sum += change_sums[static_cast<size_t>(band)];
    stats.pixels += changed[static_cast<size_t>(band)];
  }
  if (stats.pixels > 0) stats.mean_change = static_cast<float>(change_sum / stats.pixels);
  stats.ms = ms_since(start);
  return stats;
}

}  // namespace face_reenact::reenact
