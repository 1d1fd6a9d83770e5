#include "face_reenact/reenact/mouth_interior.h"

#include <algorithm>
#include <cmath>

#include "image_sampling.h"

namespace face_reenact::reenact {
namespace {

bool all_finite(const std::vector<Eigen::Vector2f>& polygon) {
  return std::all_of(polygon.begin(), polygon.end(), [](const Eigen::Vector2f& v) { return v.allFinite(); });
}

}  // namespace

bool MeanValueCoordinates(const std::vector<Eigen::Vector2f>& polygon, const Eigen::Vector2f& p, std::vector<float>* w) {
  const size_t n = polygon.size();
  if (n < 3 || !p.allFinite() || !all_finite(polygon) || PolygonArea(polygon) <= 0.0) return false;
  std::vector<Eigen::Vector2d> s(n);
  std::vector<double> r(n);
  for (size_t i = 0; i < n; ++i) {
    s[i] = (polygon[i] - p).cast<double>();
    r[i] = s[i].norm();
  }
  // Scale of the polygon, for the tests "on a vertex" / "on an edge" in pixels' terms.
  const double eps = 1e-9 * (1.0 + *std::max_element(r.begin(), r.end()));
  std::vector<double> tan_half(n);  // tan(alpha_i / 2), alpha_i the signed angle at p from v_i to v_i+1
  for (size_t i = 0; i < n; ++i) {
    const size_t j = (i + 1) % n;
    if (r[i] <= eps) {  // p is vertex i
      w->assign(n, 0.f);
      (*w)[i] = 1.f;
      return true;
    }
    const double area2 = s[i].x() * s[j].y() - s[i].y() * s[j].x();  // twice the signed triangle area
    const double dot = s[i].dot(s[j]);
    if (std::abs(area2) <= eps * (r[i] + r[j]) && dot < 0.0) {  // p on the edge i -> j
      w->assign(n, 0.f);
      (*w)[i] = static_cast<float>(r[j] / (r[i] + r[j]));
      (*w)[j] = static_cast<float>(r[i] / (r[i] + r[j]));
      return true;
    }
    // tan(a/2) = (r_i r_j - D) / 2A = 2A / (r_i r_j + D): the second form stays finite as A -> 0
    // away from the edge (D > 0 there).
    tan_half[i] = area2 / (r[i] * r[j] + dot);
  }
  std::vector<double> weights(n);
  double sum = 0.0;
  for (size_t i = 0; i < n; ++i) {
    weights[i] = (tan_half[(i + n - 1) % n] + tan_half[i]) / r[i];
    sum += weights[i];
  }
  if (!std::isfinite(sum) || std::abs(sum) < 1e-12) return false;
  w->resize(n);
  for (size_t i = 0; i < n; ++i) (*w)[i] = static_cast<float>(weights[i] / sum);
  return true;
}

double PolygonArea(const std::vector<Eigen::Vector2f>& polygon) {
  double twice = 0.0;
  for (size_t i = 0; i < polygon.size(); ++i) {
    const Eigen::Vector2d a = polygon[i].cast<double>(), b = polygon[(i + 1) % polygon.size()].cast<double>();
    twice += a.x() * b.y() - a.y() * b.x();
  }
  return std::abs(0.5 * twice);
}

bool MouthExemplarOptions::IsValid(std::string* why) const {
  auto fail = [&](const char* what) {
    if (why) *why = what;
    return false;
  };
  if (!(min_jaw_open >= 0.f && min_jaw_open <= 1.f)) return fail("mouth exemplar: min_jaw_open must be in [0, 1]");
  if (!(min_area_px >= 0.0 && std::isfinite(min_area_px))) return fail("mouth exemplar: min_area_px must be >= 0");
  if (!(max_turn_deg > 0.f && max_turn_deg <= 90.f)) return fail("mouth exemplar: max_turn_deg must be in (0, 90]");
  if (!(replace_area_ratio >= 1.0 && std::isfinite(replace_area_ratio)))
    return fail("mouth exemplar: replace_area_ratio must be >= 1");
  if (margin_px < 1 || margin_px > 64) return fail("mouth exemplar: margin_px must be in [1, 64]");
  return true;
}

bool IsBetterMouthExemplar(const MouthExemplar& current, const std::vector<Eigen::Vector2f>& opening, float jaw_open,
                           float turn_deg, const MouthExemplarOptions& options) {
  if (opening.size() < 3 || !all_finite(opening) || !std::isfinite(jaw_open) || !std::isfinite(turn_deg)) return false;
  if (jaw_open < options.min_jaw_open || std::abs(turn_deg) > options.max_turn_deg) return false;
  const double area = PolygonArea(opening);
  if (area < options.min_area_px) return false;
  return current.empty() || area >= options.replace_area_ratio * current.area_px;
}

MouthExemplar CaptureMouthExemplar(const cv::Mat& frame_bgr, const std::vector<Eigen::Vector2f>& opening, float jaw_open,
                                   int64_t frame_index, const MouthExemplarOptions& options) {
  MouthExemplar e;
  if (frame_bgr.empty() || frame_bgr.type() != CV_8UC3 || opening.size() < 3 || !all_finite(opening)) return e;
  const double area = PolygonArea(opening);
  if (!(area > 0.0)) return e;
  float x0 = opening[0].x(), x1 = x0, y0 = opening[0].y(), y1 = y0;
  for (const auto& v : opening) {
    x0 = std::min(x0, v.x()), x1 = std::max(x1, v.x());
    y0 = std::min(y0, v.y()), y1 = std::max(y1, v.y());
  }
  // The whole opening must be in the frame: a mouth cut by the border is no interior to keep.
  if (x0 < 0.f || y0 < 0.f || x1 > static_cast<float>(frame_bgr.cols - 1) || y1 > static_cast<float>(frame_bgr.rows - 1))
    return e;
  const int m = options.margin_px;
  const int left = std::max(0, static_cast<int>(std::floor(x0)) - m), top = std::max(0, static_cast<int>(std::floor(y0)) - m);
  const int right = std::min(frame_bgr.cols, static_cast<int>(std::ceil(x1)) + m + 1);
  const int bottom = std::min(frame_bgr.rows, static_cast<int>(std::ceil(y1)) + m + 1);
  e.bgr = frame_bgr(cv::Rect(left, top, right - left, bottom - top)).clone();
  e.opening.reserve(opening.size());
  for (const auto& v : opening) e.opening.emplace_back(v.x() - static_cast<float>(left), v.y() - static_cast<float>(top));
  e.area_px = area;
  e.jaw_open = jaw_open;
  e.frame_index = frame_index;
  return e;
}

bool SampleMouthExemplar(const MouthExemplar& exemplar, const std::vector<Eigen::Vector2f>& polygon,
                         const Eigen::Vector2f& p, Eigen::Vector3f* linear_rgb, Eigen::Vector2f* exemplar_point) {
  if (exemplar.empty() || polygon.size() != exemplar.opening.size()) return false;
  std::vector<float> w;
  if (!MeanValueCoordinates(polygon, p, &w)) return false;
  Eigen::Vector2f q = Eigen::Vector2f::Zero();
  for (size_t i = 0; i < w.size(); ++i) q += w[i] * exemplar.opening[i];
  if (!q.allFinite()) return false;
  if (exemplar_point) *exemplar_point = q;
  // Bilinear in linear light; the crop's margin keeps the rim's neighbours inside.
  const cv::Mat& img = exemplar.bgr;
  *linear_rgb = internal::sample_linear(img, std::clamp(q.x(), 0.f, static_cast<float>(img.cols - 1)),
                                        std::clamp(q.y(), 0.f, static_cast<float>(img.rows - 1)));
  return true;
}

float MouthInteriorBrightness(double area_px, double exemplar_area_px) {
  if (!(exemplar_area_px > 0.0) || !(area_px >= 0.0)) return 1.f;
  return static_cast<float>(std::clamp(std::sqrt(area_px / exemplar_area_px), 0.35, 1.0));
}

}  // namespace face_reenact::reenact
