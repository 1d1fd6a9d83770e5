#include "face_reenact/landmarks/drawing.h"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>

#include "landmark_internal.h"

namespace face_reenact::landmarks {
namespace {
cv::Mat to_bgr(const ImageView& image) {
  const int bpp = bytes_per_pixel(image.format);
  const cv::Mat src(image.height, image.width, bpp == 1 ? CV_8UC1 : (bpp == 3 ? CV_8UC3 : CV_8UC4),
                    const_cast<uint8_t*>(image.data), image.row_bytes());  // NOLINT: read only
  cv::Mat bgr;
  switch (image.format) {
    case PixelFormat::kGray8: cv::cvtColor(src, bgr, cv::COLOR_GRAY2BGR); break;
    case PixelFormat::kRGB8: cv::cvtColor(src, bgr, cv::COLOR_RGB2BGR); break;
    case PixelFormat::kBGRA8: cv::cvtColor(src, bgr, cv::COLOR_BGRA2BGR); break;
    case PixelFormat::kBGR8: bgr = src.clone(); break;
  }
  return bgr;
}

Image from_bgr(const cv::Mat& bgr) {
  Image out;
  out.width = bgr.cols;
  out.height = bgr.rows;
  out.format = PixelFormat::kBGR8;
  const cv::Mat c = bgr.isContinuous() ? bgr : bgr.clone();
  out.pixels.assign(c.data, c.data + size_t(c.cols) * size_t(c.rows) * 3);
  return out;
}
}  // namespace

Image draw_landmarks(const ImageView& image, const LandmarkResult& r, const std::string& caption) {
  if (!image.IsValid(nullptr)) return {};
  cv::Mat bgr = to_bgr(image);
  const double unit = std::max(1.0, std::min(bgr.cols, bgr.rows) / 400.0);
  const int thick = std::max(1, int(std::lround(unit)));
  if (r.has_landmarks) {
    const Box& b = r.face_box;
    cv::rectangle(bgr, cv::Rect(int(b.x), int(b.y), int(b.width), int(b.height)), cv::Scalar(255, 160, 0), thick);
    for (int i = 0; i < 16; ++i) {
      cv::line(bgr, cv::Point2f(r.points[size_t(i)].x(), r.points[size_t(i)].y()),
               cv::Point2f(r.points[size_t(i + 1)].x(), r.points[size_t(i + 1)].y()), cv::Scalar(200, 200, 0), thick,
               cv::LINE_AA);
    }
    const int radius = std::max(2, int(std::lround(2.0 * unit)));
    for (int i = 0; i < kNumLandmarks; ++i) {
      const float c = std::clamp(r.confidence[size_t(i)], 0.f, 1.f);
      const cv::Scalar colour(0, 255.0 * c, 255.0 * (1.0 - c));  // BGR: green confident, red not
      const cv::Point2f p(r.points[size_t(i)].x(), r.points[size_t(i)].y());
      cv::circle(bgr, p, radius, colour, r.visible[size_t(i)] ? cv::FILLED : thick, cv::LINE_AA);
    }
  }
  std::string text = status_name(r.status);
  if (r.has_landmarks) {
    char buf[64];
    std::snprintf(buf, sizeof(buf), " score %.2f", double(r.score));
    text += buf;
  }
  if (!caption.empty()) text = caption + "  " + text;
  const double font = 0.5 * unit;
  cv::putText(bgr, text, cv::Point(int(6 * unit), int(20 * unit)), cv::FONT_HERSHEY_SIMPLEX, font,
              cv::Scalar(0, 0, 0), thick + 2, cv::LINE_AA);
  cv::putText(bgr, text, cv::Point(int(6 * unit), int(20 * unit)), cv::FONT_HERSHEY_SIMPLEX, font,
              cv::Scalar(255, 255, 255), thick, cv::LINE_AA);
  return from_bgr(bgr);
}

Image contact_sheet(const std::vector<Image>& tiles, int columns, int tile_width) {
  if (tiles.empty() || columns <= 0 || tile_width <= 0) return {};
  int tile_height = 0;
  for (const Image& t : tiles) {
    if (t.width > 0) tile_height = std::max(tile_height, int(std::lround(double(t.height) * tile_width / t.width)));
  }
  if (tile_height <= 0) return {};
  const int rows = int((tiles.size() + size_t(columns) - 1) / size_t(columns));
  cv::Mat sheet(rows * tile_height, columns * tile_width, CV_8UC3, cv::Scalar(32, 32, 32));
  for (size_t i = 0; i < tiles.size(); ++i) {
    const Image& t = tiles[i];
    if (t.empty() || !t.view().IsValid(nullptr)) continue;
    const cv::Mat bgr = to_bgr(t.view());
    const int h = std::max(1, int(std::lround(double(t.height) * tile_width / t.width)));
    cv::Mat scaled;
    cv::resize(bgr, scaled, cv::Size(tile_width, std::min(h, tile_height)), 0, 0, cv::INTER_AREA);
    const int col = int(i % size_t(columns)), row = int(i / size_t(columns));
    scaled.copyTo(sheet(cv::Rect(col * tile_width, row * tile_height, scaled.cols, scaled.rows)));
  }
  return from_bgr(sheet);
}

}  // namespace face_reenact::landmarks
