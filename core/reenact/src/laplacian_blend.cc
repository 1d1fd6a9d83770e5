#include "face_reenact/reenact/laplacian_blend.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "face_reenact/common/error.h"
#include "face_reenact/common/parallel.h"

namespace face_reenact::reenact {

bool LaplacianBlendOptions::IsValid(std::string* why) const {
  if (levels < 1 || levels > 10) {
    if (why) *why = "Laplacian blend: levels must be in [1, 10]";
    return false;
  }
  if (threads < 1) {
    if (why) *why = "Laplacian blend: threads must be at least 1";
    return false;
  }
  return true;
}

int blend_support_radius(int levels) {
  // pyrDown and pyrUp use a 5-tap kernel (radius 2 at the finer level's resolution): going
  // from level l-1 to l widens the mask's footprint by 2^l full-size pixels, coming back up the
  // blended band by as much again: 2 * (2^L - 2) in all, rounded up to 2^(L+1).
  return levels <= 1 ? 0 : (1 << (levels + 1));
}

namespace {

cv::Mat to_float3(const cv::Mat& m) {
  cv::Mat f;
  if (m.type() == CV_32FC3) return m;
  m.convertTo(f, CV_32FC3);
  return f;
}

cv::Mat to_float_mask(const cv::Mat& m) {
  cv::Mat f;
  if (m.type() == CV_32FC1) {
    f = m.clone();
  } else {
    m.convertTo(f, CV_32FC1, 1.0 / 255.0);
  }
  cv::patchNaNs(f, 0.0);
  cv::min(f, 1.0, f);
  cv::max(f, 0.0, f);
  return f;
}

}  // namespace

cv::Mat LaplacianBlend(const cv::Mat& target, const cv::Mat& rendered, const cv::Mat& mask,
                       const LaplacianBlendOptions& options, LaplacianBlendSummary* summary) {
  std::string why;
  if (!options.IsValid(&why)) throw Error(why);
  if (target.empty()) throw Error("Laplacian blend: empty target image");
  if (target.type() != CV_8UC3 && target.type() != CV_32FC3)
    throw Error("Laplacian blend: target must be CV_8UC3 or CV_32FC3");
  if (rendered.size() != target.size() || (rendered.type() != CV_8UC3 && rendered.type() != CV_32FC3))
    throw Error("Laplacian blend: rendered image must be CV_8UC3 or CV_32FC3 of the target's size");
  if (mask.size() != target.size() || (mask.type() != CV_8UC1 && mask.type() != CV_32FC1))
    throw Error("Laplacian blend: mask must be CV_8UC1 or CV_32FC1 of the target's size");

  LaplacianBlendSummary local;
  if (!summary) summary = &local;
  *summary = LaplacianBlendSummary{};

  // The mask's nonzero pixels (after to_float_mask: NaN and negative weights are 0) and the
  // float mask only around them: the rest of the frame is the target.
  const cv::Rect box = cv::boundingRect(mask > 0);
  if (box.empty()) return target.clone();

  const int radius = blend_support_radius(options.levels);
  const int pad = radius + (1 << options.levels);
  const cv::Rect image_rect(0, 0, target.cols, target.rows);
  const cv::Rect roi = cv::Rect(box.x - pad, box.y - pad, box.width + 2 * pad, box.height + 2 * pad) & image_rect;
  int levels = 1;
  while (levels < options.levels && std::min(roi.width, roi.height) >> levels >= 2) ++levels;
  summary->levels_used = levels;

  // Independent steps two at a time on the pool's threads (the pyramids beside the blend region's
  // distance transform, the blended bands' next level up beside the difference's), and the
  // per-pixel passes by rows: every value is computed as one thread would, so the result is the
  // same bits for any thread count. On one thread the blend was the largest part of a 1280x720
  // frame's serial work (docs/real-time.md, "The compositor's serial passes").
  const int threads = options.threads;
  constexpr int kRowsPerItem = 16;

  cv::Mat t;
  std::vector<cv::Mat> gd(static_cast<size_t>(levels)), gm(static_cast<size_t>(levels));
  cv::Mat window;  // the blend region's weight, below
  auto pyramids = [&] {
    t = to_float3(target(roi));
    const cv::Mat r = to_float3(rendered(roi));
    gd[0] = r - t;
    gm[0] = to_float_mask(mask(roi));
    for (int l = 1; l < levels; ++l) {
      cv::pyrDown(gd[static_cast<size_t>(l - 1)], gd[static_cast<size_t>(l)]);
      cv::pyrDown(gm[static_cast<size_t>(l - 1)], gm[static_cast<size_t>(l)]);
    }
  };
  auto blend_region = [&] {
    // Within `radius` of the mask, faded out over its outer half (weight 1 up to radius / 2, 0
    // beyond radius + 1). Outside: where to_float_mask gives 0 (a NaN compares false).
    cv::Mat outside;
    cv::bitwise_not(mask(roi) > 0, outside);
    cv::Mat dist;
    cv::distanceTransform(outside, dist, cv::DIST_L2, cv::DIST_MASK_PRECISE);
    const float inner = 0.5f * static_cast<float>(radius);
    const float outer = static_cast<float>(radius) + 1.0f;
    window = (outer - dist) / (outer - inner);
    cv::min(window, 1.0, window);
    cv::max(window, 0.0, window);
  };
  ParallelInvoke(threads, {pyramids, blend_region});
  // Band-pass levels of the difference, each weighted by the mask at its scale, summed back:
  // blended_l = up(blended_l+1) + m_l * (d_l - up(d_l+1)), the coarsest level d's own. One pass
  // per level over the three images (the per-level temporaries, the band, the mask in three
  // channels and their product, took as long as the pyramids), the same arithmetic in the same
  // order, so the same bits.
  cv::Mat blended = gd[static_cast<size_t>(levels - 1)].clone();
  {
    const cv::Mat& top_mask = gm[static_cast<size_t>(levels - 1)];
    for (int y = 0; y < blended.rows; ++y) {
      cv::Vec3f* row = blended.ptr<cv::Vec3f>(y);
      const float* mrow = top_mask.ptr<float>(y);
      for (int x = 0; x < blended.cols; ++x) row[x] *= mrow[x];
    }
  }
  cv::Mat up_d, up_blended;
  for (int l = levels - 2; l >= 0; --l) {
    const cv::Mat& g = gd[static_cast<size_t>(l)];
    const cv::Mat& gmask = gm[static_cast<size_t>(l)];
    ParallelInvoke(threads, {[&] { cv::pyrUp(gd[static_cast<size_t>(l + 1)], up_d, g.size()); },
                             [&] { cv::pyrUp(blended, up_blended, g.size()); }});
    blended.create(g.size(), CV_32FC3);
    ParallelForBlocks(g.rows, kRowsPerItem, threads, [&](int y) {
      const cv::Vec3f* drow = g.ptr<cv::Vec3f>(y);
      const cv::Vec3f* urow = up_d.ptr<cv::Vec3f>(y);
      const cv::Vec3f* brow = up_blended.ptr<cv::Vec3f>(y);
      const float* mrow = gmask.ptr<float>(y);
      cv::Vec3f* out = blended.ptr<cv::Vec3f>(y);
      for (int x = 0; x < g.cols; ++x)
        for (int c = 0; c < 3; ++c) out[x][c] = brow[x][c] + (drow[x][c] - urow[x][c]) * mrow[x];
    });
  }

  cv::Mat out = target.clone();
  // The region written, in the roi: each row's columns, then the rows that wrote any.
  std::vector<cv::Vec2i> written(static_cast<size_t>(roi.height), cv::Vec2i(roi.width, -1));
  const bool bytes = out.type() == CV_8UC3;
  ParallelForBlocks(roi.height, kRowsPerItem, threads, [&](int y) {
    const float* wrow = window.ptr<float>(y);
    const cv::Vec3f* trow = t.ptr<cv::Vec3f>(y);
    const cv::Vec3f* brow = blended.ptr<cv::Vec3f>(y);
    cv::Vec3b* orow8 = bytes ? out.ptr<cv::Vec3b>(roi.y + y) + roi.x : nullptr;
    cv::Vec3f* orowf = bytes ? nullptr : out.ptr<cv::Vec3f>(roi.y + y) + roi.x;
    cv::Vec2i& span = written[static_cast<size_t>(y)];
    for (int x = 0; x < roi.width; ++x) {
      const float w = wrow[x];
      if (w <= 0.0f) continue;
      const cv::Vec3f v = trow[x] + w * brow[x];
      if (bytes)
        orow8[x] = cv::Vec3b(cv::saturate_cast<uchar>(v[0]), cv::saturate_cast<uchar>(v[1]), cv::saturate_cast<uchar>(v[2]));
      else
        orowf[x] = v;
      span[0] = std::min(span[0], x), span[1] = std::max(span[1], x);
    }
  });
  int x0 = roi.width, x1 = -1, y0 = roi.height, y1 = -1;
  for (int y = 0; y < roi.height; ++y) {
    const cv::Vec2i span = written[static_cast<size_t>(y)];
    if (span[1] < 0) continue;
    x0 = std::min(x0, span[0]), x1 = std::max(x1, span[1]), y0 = std::min(y0, y), y1 = std::max(y1, y);
  }
  const cv::Rect region_box = x1 < 0 ? cv::Rect() : cv::Rect(roi.x + x0, roi.y + y0, x1 - x0 + 1, y1 - y0 + 1);
  summary->blend_region = region_box;
  return out;
}

}  // namespace face_reenact::reenact
