#include "face_reenact/reenact/teeth_texture.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <limits>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "face_reenact/common/error.h"
#include "image_sampling.h"

namespace face_reenact::reenact {
namespace {

// A lip line (corner, three points, corner) as a function of the position t along the
// corner-to-corner axis: the point where the polyline reaches t (its points sorted by t).
Eigen::Vector2f along(const std::vector<std::pair<float, Eigen::Vector2f>>& line, float t) {
  if (t <= line.front().first) return line.front().second;
  for (size_t k = 1; k < line.size(); ++k) {
    if (t <= line[k].first) {
      const float span = line[k].first - line[k - 1].first;
      const float f = span > 1e-6f ? (t - line[k - 1].first) / span : 1.0f;
      return line[k - 1].second + f * (line[k].second - line[k - 1].second);
    }
  }
  return line.back().second;
}

Eigen::Vector3f reference_colour(const cv::Mat& bgr) {
  // The teeth's bright colour: the brightest third of the middle half's pixels (the corners are
  // the dark of the cheeks' inside, the gaps between teeth are dark too).
  std::vector<Eigen::Vector3f> colours;
  for (int j = 0; j < bgr.rows; ++j)
    for (int i = bgr.cols / 4; i < 3 * bgr.cols / 4; ++i)
      colours.push_back(internal::sample_linear(bgr, static_cast<float>(i), static_cast<float>(j)));
  std::sort(colours.begin(), colours.end(),
            [](const Eigen::Vector3f& a, const Eigen::Vector3f& b) { return a.sum() > b.sum(); });
  const size_t n = std::max<size_t>(1, colours.size() / 3);
  Eigen::Vector3f sum = Eigen::Vector3f::Zero();
  for (size_t k = 0; k < n; ++k) sum += colours[k];
  Eigen::Vector3f ref = sum / static_cast<float>(n);
  // A texture with no light in it would divide by zero: such a texture has no pattern to give.
  for (int c = 0; c < 3; ++c) ref[c] = std::max(ref[c], 1e-3f);
  return ref;
}

// How much a pixel looks like a tooth: bright and unsaturated (lips are red, the cavity dark).
float toothness(const Eigen::Vector3f& linear_rgb) {
  const float hi = linear_rgb.maxCoeff(), lo = linear_rgb.minCoeff();
  const float saturation = hi > 1e-4f ? (hi - lo) / hi : 0.f;
  return linear_rgb.mean() * (1.f - saturation);
}

// Otsu's threshold of `values` (in [0, 1]): the split that maximises the between-class variance.
float otsu_threshold(const std::vector<float>& values) {
  constexpr int kBins = 128;
  std::array<double, kBins> hist{};
  for (float v : values) hist[static_cast<size_t>(std::clamp(static_cast<int>(v * kBins), 0, kBins - 1))] += 1.0;
  const double total = static_cast<double>(values.size());
  double sum_all = 0;
  for (int b = 0; b < kBins; ++b) sum_all += b * hist[static_cast<size_t>(b)];
  double w0 = 0, sum0 = 0, best = -1;
  int best_bin = kBins / 2;
  for (int b = 0; b < kBins - 1; ++b) {
    w0 += hist[static_cast<size_t>(b)];
    sum0 += b * hist[static_cast<size_t>(b)];
    const double w1 = total - w0;
    if (w0 <= 0 || w1 <= 0) continue;
    const double m0 = sum0 / w0, m1 = (sum_all - sum0) / w1;
    const double between = w0 * w1 * (m0 - m1) * (m0 - m1);
    if (between > best) {
      best = between;
      best_bin = b;
    }
  }
  return (static_cast<float>(best_bin) + 1.f) / kBins;
}

// Moves each column's ends to the teeth's own upper and lower edges. dlib places the inner-lip
// points of a small smile a pixel or two inside the teeth (on NASA's portrait the upper line sat
// 2 px below the teeth's top, so the texture lost their upper half): along each column, from
// `gap` above the upper line to `gap` below the lower one, the run of tooth-like pixels (Otsu's
// threshold of toothness over the middle columns) that holds the column's middle is the teeth.
// Columns without such a run (the corners) and runs that shrink the opening below half keep the
// points' lines; the ends are then smoothed across the columns (a median of 9).
// Returns the first and last columns that hold teeth (-1, -1: none).
std::pair<int, int> RefineToTheTeeth(const cv::Mat& photo_bgr, float gap, std::vector<Eigen::Vector2f>* tops,
                                     std::vector<Eigen::Vector2f>* bottoms) {
  const int width = static_cast<int>(tops->size());
  constexpr float kStepPx = 0.25f;
  const float reach = std::max(2.f, gap);
  auto at = [&](const Eigen::Vector2f& p) {
    const float x = std::clamp(p.x(), 0.f, static_cast<float>(photo_bgr.cols - 1));
    const float y = std::clamp(p.y(), 0.f, static_cast<float>(photo_bgr.rows - 1));
    return toothness(internal::sample_linear(photo_bgr, x, y));
  };
  // Each column's direction (from its upper line to its lower one) and its samples, from `reach`
  // above the upper line to `reach` below the lower one.
  std::vector<Eigen::Vector2f> dirs(static_cast<size_t>(width));
  std::vector<std::vector<float>> samples(static_cast<size_t>(width));
  for (int i = 0; i < width; ++i) {
    const Eigen::Vector2f top = (*tops)[static_cast<size_t>(i)], bottom = (*bottoms)[static_cast<size_t>(i)];
    const Eigen::Vector2f dir = (bottom - top).norm() > 1e-3f ? (bottom - top).normalized() : Eigen::Vector2f(0.f, 1.f);
    dirs[static_cast<size_t>(i)] = dir;
    const Eigen::Vector2f start = top - reach * dir, step = kStepPx * dir;
    const int n = static_cast<int>(((bottom - top).norm() + 2.f * reach) / kStepPx) + 1;
    for (int k = 0; k < n; ++k) samples[static_cast<size_t>(i)].push_back(at(start + static_cast<float>(k) * step));
  }
  std::vector<float> middle;
  for (int i = width / 8; i < width - width / 8; ++i)
    middle.insert(middle.end(), samples[static_cast<size_t>(i)].begin(), samples[static_cast<size_t>(i)].end());
  if (middle.empty()) return {-1, -1};
  const float threshold = otsu_threshold(middle);
  std::vector<float> top_shift(static_cast<size_t>(width), 0.f), bottom_shift(static_cast<size_t>(width), 0.f);
  int first = -1, last = -1;
  for (int i = 0; i < width; ++i) {
    const std::vector<float>& s = samples[static_cast<size_t>(i)];
    const float length = ((*bottoms)[static_cast<size_t>(i)] - (*tops)[static_cast<size_t>(i)]).norm();
    const int mid = static_cast<int>((reach + 0.5f * length) / kStepPx);
    if (mid < 0 || mid >= static_cast<int>(s.size()) || s[static_cast<size_t>(mid)] < threshold) continue;
    int a = mid, b = mid;
    while (a > 0 && s[static_cast<size_t>(a - 1)] >= threshold) --a;
    while (b + 1 < static_cast<int>(s.size()) && s[static_cast<size_t>(b + 1)] >= threshold) ++b;
    const float run = static_cast<float>(b - a) * kStepPx;
    if (run < 0.5f * length) continue;
    top_shift[static_cast<size_t>(i)] = static_cast<float>(a) * kStepPx - reach;           // along the column
    bottom_shift[static_cast<size_t>(i)] = static_cast<float>(b) * kStepPx - reach - length;
    if (first < 0) first = i;
    last = i;
  }
  auto median9 = [&](const std::vector<float>& x, int i) {
    std::vector<float> w;
    for (int k = std::max(0, i - 4); k <= std::min(width - 1, i + 4); ++k) w.push_back(x[static_cast<size_t>(k)]);
    std::nth_element(w.begin(), w.begin() + static_cast<long>(w.size() / 2), w.end());
    return w[w.size() / 2];
  };
  std::vector<Eigen::Vector2f> new_tops = *tops, new_bottoms = *bottoms;
  for (int i = 0; i < width; ++i) {
    const Eigen::Vector2f dir = dirs[static_cast<size_t>(i)];
    new_tops[static_cast<size_t>(i)] = (*tops)[static_cast<size_t>(i)] + median9(top_shift, i) * dir;
    new_bottoms[static_cast<size_t>(i)] = (*bottoms)[static_cast<size_t>(i)] + median9(bottom_shift, i) * dir;
  }
  *tops = std::move(new_tops);
  *bottoms = std::move(new_bottoms);
  return {first, last};
}

}  // namespace

TeethTexture BuildTeethTexture(const cv::Mat& photo_bgr, const std::vector<Eigen::Vector2f>& inner_lips, int width,
                               int height) {
  if (photo_bgr.empty() || photo_bgr.type() != CV_8UC3) throw Error("teeth texture: the photo must be 8-bit BGR");
  if (width < 16 || height < 4) throw Error("teeth texture: the texture must be at least 16x4 pixels");
  if (inner_lips.size() != 8) throw Error("teeth texture: expected the 8 inner-lip points (iBUG 60-67)");
  for (const Eigen::Vector2f& p : inner_lips) {
    if (!p.allFinite() || p.x() < 0.f || p.y() < 0.f || p.x() > static_cast<float>(photo_bgr.cols - 1) ||
        p.y() > static_cast<float>(photo_bgr.rows - 1))
      throw Error("teeth texture: an inner-lip point is not finite or outside the photo");
  }
  const Eigen::Vector2f left = inner_lips[0], right = inner_lips[4];
  const Eigen::Vector2f axis = right - left;
  const float length2 = axis.squaredNorm();
  if (!(length2 >= 16.f)) throw Error("teeth texture: the mouth's corners are less than 4 px apart");
  auto line = [&](std::initializer_list<int> order) {
    std::vector<std::pair<float, Eigen::Vector2f>> l;
    for (int k : order) l.emplace_back((inner_lips[static_cast<size_t>(k)] - left).dot(axis) / length2, inner_lips[static_cast<size_t>(k)]);
    std::sort(l.begin(), l.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
    return l;
  };
  const auto upper = line({0, 1, 2, 3, 4}), lower = line({0, 7, 6, 5, 4});

  std::vector<Eigen::Vector2f> tops(static_cast<size_t>(width)), bottoms(static_cast<size_t>(width));
  double gap = 0;
  int gap_samples = 0;
  for (int i = 0; i < width; ++i) {
    const float u = (static_cast<float>(i) + 0.5f) / static_cast<float>(width);
    tops[static_cast<size_t>(i)] = along(upper, u);
    bottoms[static_cast<size_t>(i)] = along(lower, u);
    if (u >= 0.25f && u <= 0.75f) {
      gap += (bottoms[static_cast<size_t>(i)] - tops[static_cast<size_t>(i)]).norm();
      ++gap_samples;
    }
  }
  if (gap_samples == 0 || gap / gap_samples < 2.0)
    throw Error("teeth texture: the lips are shut (less than 2 px apart): no teeth to take");
  const auto [first, last] = RefineToTheTeeth(photo_bgr, static_cast<float>(gap / gap_samples), &tops, &bottoms);
  // The texture spans the columns that show teeth: the mouth's corners beyond them are lips and
  // the dark inside of the cheeks, which the compositor's depth shading already gives the back
  // teeth. When too few columns show teeth (a dark photo), the corners' whole span stays.
  float from = 0.f, to = static_cast<float>(width - 1);
  if (first >= 0 && last - first >= width / 4) {
    from = static_cast<float>(first);
    to = static_cast<float>(last);
  }
  auto column_at = [&](const std::vector<Eigen::Vector2f>& line, float x) {
    const int i0 = std::clamp(static_cast<int>(x), 0, width - 1), i1 = std::min(i0 + 1, width - 1);
    const float f = x - static_cast<float>(i0);
    return Eigen::Vector2f((1.f - f) * line[static_cast<size_t>(i0)] + f * line[static_cast<size_t>(i1)]);
  };

  cv::Mat map_x(height, width, CV_32FC1), map_y(height, width, CV_32FC1);
  for (int i = 0; i < width; ++i) {
    const float x = from + (to - from) * static_cast<float>(i) / static_cast<float>(width - 1);
    const Eigen::Vector2f top = column_at(tops, x), bottom = column_at(bottoms, x);
    for (int j = 0; j < height; ++j) {
      const float v = (static_cast<float>(j) + 0.5f) / static_cast<float>(height);
      const Eigen::Vector2f p = top + v * (bottom - top);
      map_x.at<float>(j, i) = p.x();
      map_y.at<float>(j, i) = p.y();
    }
  }
  TeethTexture out;
  cv::remap(photo_bgr, out.bgr, map_x, map_y, cv::INTER_CUBIC, cv::BORDER_REPLICATE);
  out.reference = reference_colour(out.bgr);
  return out;
}

TeethTexture LoadTeethTexture(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) throw Error("teeth texture '" + path + "' does not exist");
  TeethTexture out;
  out.bgr = cv::imread(path, cv::IMREAD_COLOR);
  if (out.bgr.empty()) throw Error("teeth texture '" + path + "' is not an image");
  if (out.bgr.cols < 16 || out.bgr.rows < 4)
    throw Error("teeth texture '" + path + "' is " + std::to_string(out.bgr.cols) + "x" + std::to_string(out.bgr.rows) +
                ": at least 16x4 pixels are needed");
  out.reference = reference_colour(out.bgr);
  out.source = path;
  return out;
}

void SaveTeethTexture(const TeethTexture& texture, const std::string& path) {
  if (texture.empty()) throw Error("teeth texture: nothing to write");
  if (!cv::imwrite(path, texture.bgr)) throw Error("teeth texture: cannot write '" + path + "'");
}

std::string DefaultTeethTexturePath(const std::string& model_path) {
  return (std::filesystem::path(model_path).parent_path() / "face-teeth.png").string();
}

std::shared_ptr<const TeethTexture> LoadDefaultTeethTexture(const std::string& model_path, std::string* why) {
  const std::string path = DefaultTeethTexturePath(model_path);
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    if (why) *why = "no " + path + " (made by 'face-reenact model teeth')";
    return nullptr;
  }
  try {
    return std::make_shared<const TeethTexture>(LoadTeethTexture(path));
  } catch (const Error& e) {
    if (why) *why = e.what();
    return nullptr;
  }
}

Eigen::Vector3f TeethPattern(const TeethTexture& texture, float u, float v) {
  const float x = std::clamp(u, 0.f, 1.f) * static_cast<float>(texture.bgr.cols) - 0.5f;
  const float y = std::clamp(v, 0.f, 1.f) * static_cast<float>(texture.bgr.rows) - 0.5f;
  const Eigen::Vector3f c =
      internal::sample_linear(texture.bgr, std::clamp(x, 0.f, static_cast<float>(texture.bgr.cols - 1)),
                              std::clamp(y, 0.f, static_cast<float>(texture.bgr.rows - 1)));
  // The texture's brightness relative to the teeth's, and half its tint: a photo's teeth carry
  // its light's colour and the lips' reflection, the rendered teeth are lit by the target's.
  const float brightness = c.sum() / texture.reference.sum();
  Eigen::Vector3f out;
  for (int k = 0; k < 3; ++k) out[k] = std::clamp(0.5f * (brightness + c[k] / texture.reference[k]), 0.f, 1.25f);
  return out;
}

std::vector<Eigen::Vector2f> TeethTextureCoordinates(const FaceModel& model) {
  const int n = model.num_vertices();
  int corner_left = -1, corner_right = -1;
  for (const ModelLandmark& l : model.landmarks) {
    if (l.ibug_index == 60) corner_left = l.vertex;
    if (l.ibug_index == 64) corner_right = l.vertex;
  }
  if (corner_left < 0 || corner_right < 0 || corner_left >= n || corner_right >= n) return {};
  const float x_left = model.mean_shape[3 * corner_left], x_right = model.mean_shape[3 * corner_right];
  if (!(std::abs(x_right - x_left) > 1e-4f)) return {};
  // Each band's height range (its gum and its biting edge).
  float top[2] = {-std::numeric_limits<float>::infinity(), -std::numeric_limits<float>::infinity()};
  float bottom[2] = {std::numeric_limits<float>::infinity(), std::numeric_limits<float>::infinity()};
  auto band = [&](int v) {
    const FacePart p = model.vertex_part[static_cast<size_t>(v)];
    return p == FacePart::UpperTeeth ? 0 : p == FacePart::LowerTeeth ? 1 : -1;
  };
  for (int v = 0; v < n; ++v) {
    const int b = band(v);
    if (b < 0) continue;
    top[b] = std::max(top[b], model.mean_shape[3 * v + 1]);
    bottom[b] = std::min(bottom[b], model.mean_shape[3 * v + 1]);
  }
  if (!(top[0] > bottom[0]) && !(top[1] > bottom[1])) return {};
  const float nan = std::numeric_limits<float>::quiet_NaN();
  std::vector<Eigen::Vector2f> uv(static_cast<size_t>(n), Eigen::Vector2f(nan, nan));
  for (int v = 0; v < n; ++v) {
    const int b = band(v);
    if (b < 0 || !(top[b] > bottom[b])) continue;
    const float x = model.mean_shape[3 * v], y = model.mean_shape[3 * v + 1];
    const float u = (x - x_left) / (x_right - x_left);
    // Upper teeth: the gum at the top, the edge at the bottom; lower teeth the other way up.
    const float from_gum = b == 0 ? (top[b] - y) / (top[b] - bottom[b]) : (y - bottom[b]) / (top[b] - bottom[b]);
    uv[static_cast<size_t>(v)] = Eigen::Vector2f(u, from_gum);
  }
  return uv;
}

}  // namespace face_reenact::reenact
