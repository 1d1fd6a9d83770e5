#include "face_reenact/output/pixel_conversion.h"

#include <linux/videodev2.h>

#include <algorithm>
#include <cctype>
#include <cstring>
#include <opencv2/imgproc.hpp>

#include "face_reenact/common/paths.h"
#include "face_reenact/common/error.h"

namespace face_reenact::output {
namespace {

uint8_t clamp_u8(int v) { return static_cast<uint8_t>(std::clamp(v, 0, 255)); }

// BT.601 limited range, 8-bit fixed point (coefficients x 256, rounded), the usual integer
// form: Y = 16 + (66 R + 129 G + 25 B) / 256, Cb = 128 + (-38 R - 74 G + 112 B) / 256,
// Cr = 128 + (112 R - 94 G - 18 B) / 256. The shift of a negative sum floors, as intended.
inline int luma(int b, int g, int r) { return ((66 * r + 129 * g + 25 * b + 128) >> 8) + 16; }
inline int chroma_b(int b, int g, int r) { return ((-38 * r - 74 * g + 112 * b + 128) >> 8) + 128; }
inline int chroma_r(int b, int g, int r) { return ((112 * r - 94 * g - 18 * b + 128) >> 8) + 128; }

void check_even(PixelFormat format, int width, int height) {
  if (width <= 0 || height <= 0 || width % 2 != 0 || (format == PixelFormat::kI420 && height % 2 != 0))
    throw Error(std::string(pixel_format_name(format)) + " needs an even width" +
                (format == PixelFormat::kI420 ? " and height" : "") + ", got " + std::to_string(width) + "x" +
                std::to_string(height));
}

}  // namespace

const char* pixel_format_name(PixelFormat format) {
  return format == PixelFormat::kYuyv ? "yuyv" : "i420";
}

std::optional<PixelFormat> parse_pixel_format(const std::string& name) {
  const std::string lower = ascii_lower(name);
  if (lower == "yuyv" || lower == "yuy2") return PixelFormat::kYuyv;
  if (lower == "i420" || lower == "yu12" || lower == "yuv420p") return PixelFormat::kI420;
  return std::nullopt;
}

uint32_t pixel_format_fourcc(PixelFormat format) {
  return format == PixelFormat::kYuyv ? V4L2_PIX_FMT_YUYV : V4L2_PIX_FMT_YUV420;
}

std::string fourcc_to_string(uint32_t fourcc) {
  std::string s;
  for (int i = 0; i < 4; ++i) {
    char c = static_cast<char>((fourcc >> (8 * i)) & 0xff);
    s += std::isprint(static_cast<unsigned char>(c)) ? c : '?';
  }
  return s;
}

size_t frame_bytes(PixelFormat format, int width, int height) {
  check_even(format, width, height);
  size_t pixels = size_t(width) * size_t(height);
  return format == PixelFormat::kYuyv ? 2 * pixels : pixels + pixels / 2;
}

size_t bytes_per_line(PixelFormat format, int width) {
  return format == PixelFormat::kYuyv ? 2 * size_t(width) : size_t(width);
}

Ycbcr bgr_to_ycbcr(uint8_t b, uint8_t g, uint8_t r) {
  return {static_cast<uint8_t>(luma(b, g, r)), static_cast<uint8_t>(chroma_b(b, g, r)),
          static_cast<uint8_t>(chroma_r(b, g, r))};
}

void ycbcr_to_bgr(uint8_t y, uint8_t cb, uint8_t cr, uint8_t* b, uint8_t* g, uint8_t* r) {
  // Inverse of the matrix above in 16.16 fixed point: 1.164 (Y-16), 1.596 Cr, 0.392 Cb +
  // 0.813 Cr, 2.017 Cb.
  int c = (int(y) - 16) * 76309, d = int(cb) - 128, e = int(cr) - 128;
  *r = clamp_u8((c + 104597 * e + 32768) >> 16);
  *g = clamp_u8((c - 25675 * d - 53279 * e + 32768) >> 16);
  *b = clamp_u8((c + 132201 * d + 32768) >> 16);
}

void convert_bgr(const cv::Mat& bgr, PixelFormat format, std::span<uint8_t> out) {
  if (bgr.empty() || bgr.type() != CV_8UC3)
    throw Error("colour conversion needs an 8-bit BGR image (CV_8UC3)");
  const int w = bgr.cols, h = bgr.rows;
  const size_t need = frame_bytes(format, w, h);
  if (out.size() < need)
    throw Error("colour conversion: output buffer holds " + std::to_string(out.size()) + " bytes, " +
                std::to_string(need) + " needed");
  uint8_t* dst = out.data();
  if (format == PixelFormat::kYuyv) {
    for (int row = 0; row < h; ++row) {
      const uint8_t* p = bgr.ptr<uint8_t>(row);
      uint8_t* o = dst + size_t(row) * 2 * w;
      for (int x = 0; x < w; x += 2, p += 6, o += 4) {
        int b0 = p[0], g0 = p[1], r0 = p[2], b1 = p[3], g1 = p[4], r1 = p[5];
        o[0] = static_cast<uint8_t>(luma(b0, g0, r0));
        o[1] = static_cast<uint8_t>((chroma_b(b0, g0, r0) + chroma_b(b1, g1, r1) + 1) >> 1);
        o[2] = static_cast<uint8_t>(luma(b1, g1, r1));
        o[3] = static_cast<uint8_t>((chroma_r(b0, g0, r0) + chroma_r(b1, g1, r1) + 1) >> 1);
      }
    }
    return;
  }
  uint8_t* plane_y = dst;
  uint8_t* plane_u = dst + size_t(w) * h;
  uint8_t* plane_v = plane_u + size_t(w / 2) * (h / 2);
  for (int row = 0; row < h; row += 2) {
    const uint8_t* p0 = bgr.ptr<uint8_t>(row);
    const uint8_t* p1 = bgr.ptr<uint8_t>(row + 1);
    uint8_t* y0 = plane_y + size_t(row) * w;
    uint8_t* y1 = y0 + w;
    uint8_t* u = plane_u + size_t(row / 2) * (w / 2);
    uint8_t* v = plane_v + size_t(row / 2) * (w / 2);
    for (int x = 0; x < w; x += 2, p0 += 6, p1 += 6) {
      int sum_cb = 0, sum_cr = 0;
      const uint8_t* px[4] = {p0, p0 + 3, p1, p1 + 3};
      uint8_t* ys[4] = {y0 + x, y0 + x + 1, y1 + x, y1 + x + 1};
      for (int k = 0; k < 4; ++k) {
        int b = px[k][0], g = px[k][1], r = px[k][2];
        *ys[k] = static_cast<uint8_t>(luma(b, g, r));
        sum_cb += chroma_b(b, g, r);
        sum_cr += chroma_r(b, g, r);
      }
      u[x / 2] = static_cast<uint8_t>((sum_cb + 2) >> 2);
      v[x / 2] = static_cast<uint8_t>((sum_cr + 2) >> 2);
    }
  }
}

cv::Mat convert_to_bgr(std::span<const uint8_t> frame, PixelFormat format, int width, int height) {
  const size_t need = frame_bytes(format, width, height);
  if (frame.size() < need)
    throw Error("colour conversion: frame holds " + std::to_string(frame.size()) + " bytes, " +
                std::to_string(need) + " needed for " + std::to_string(width) + "x" + std::to_string(height) +
                " " + pixel_format_name(format));
  cv::Mat bgr(height, width, CV_8UC3);
  const uint8_t* src = frame.data();
  for (int row = 0; row < height; ++row) {
    uint8_t* o = bgr.ptr<uint8_t>(row);
    for (int x = 0; x < width; ++x, o += 3) {
      uint8_t y, cb, cr;
      if (format == PixelFormat::kYuyv) {
        const uint8_t* pair = src + size_t(row) * 2 * width + size_t(x / 2) * 4;
        y = pair[(x % 2) * 2];
        cb = pair[1];
        cr = pair[3];
      } else {
        y = src[size_t(row) * width + x];
        size_t chroma_index = size_t(row / 2) * (width / 2) + x / 2;
        cb = src[size_t(width) * height + chroma_index];
        cr = src[size_t(width) * height + size_t(width / 2) * (height / 2) + chroma_index];
      }
      ycbcr_to_bgr(y, cb, cr, &o[0], &o[1], &o[2]);
    }
  }
  return bgr;
}

cv::Rect letterbox_rect(int image_width, int image_height, int width, int height) {
  if (image_width <= 0 || image_height <= 0 || width <= 0 || height <= 0) return {0, 0, 0, 0};
  // Compare aspect ratios exactly in integers: image is wider than the frame when
  // iw * h > ih * w.
  int64_t iw = image_width, ih = image_height;
  int fit_w, fit_h;
  if (iw * height >= ih * width) {
    fit_w = width;
    fit_h = static_cast<int>(std::max<int64_t>(1, (ih * width + iw / 2) / iw));
  } else {
    fit_h = height;
    fit_w = static_cast<int>(std::max<int64_t>(1, (iw * height + ih / 2) / ih));
  }
  fit_w = std::min(fit_w, width);
  fit_h = std::min(fit_h, height);
  return {(width - fit_w) / 2, (height - fit_h) / 2, fit_w, fit_h};
}

cv::Mat letterbox_bgr(const cv::Mat& image, int width, int height) {
  if (image.empty()) throw Error("letterbox: empty image");
  if (width <= 0 || height <= 0) throw Error("letterbox: output size must be positive");
  cv::Mat bgr;
  switch (image.type()) {
    case CV_8UC3: bgr = image; break;
    case CV_8UC1: cv::cvtColor(image, bgr, cv::COLOR_GRAY2BGR); break;
    case CV_8UC4: cv::cvtColor(image, bgr, cv::COLOR_BGRA2BGR); break;
    default:
      throw Error("letterbox: unsupported image type (need 8-bit grey, BGR or BGRA), OpenCV type " +
                  std::to_string(image.type()));
  }
  if (bgr.cols == width && bgr.rows == height) return bgr;
  cv::Rect fit = letterbox_rect(bgr.cols, bgr.rows, width, height);
  cv::Mat out(height, width, CV_8UC3, cv::Scalar(0, 0, 0));
  // Area averaging when shrinking (no aliasing), bilinear when enlarging.
  int interpolation = (fit.width < bgr.cols) ? cv::INTER_AREA : cv::INTER_LINEAR;
  cv::resize(bgr, out(fit), fit.size(), 0, 0, interpolation);
  return out;
}

void fill_black(PixelFormat format, int width, int height, std::span<uint8_t> out) {
  const size_t need = frame_bytes(format, width, height);
  if (out.size() < need) throw Error("fill_black: buffer too small");
  if (format == PixelFormat::kYuyv) {
    for (size_t i = 0; i + 1 < need; i += 2) {
      out[i] = 16;
      out[i + 1] = 128;
    }
  } else {
    size_t luma_bytes = size_t(width) * height;
    std::memset(out.data(), 16, luma_bytes);
    std::memset(out.data() + luma_bytes, 128, need - luma_bytes);
  }
}

}  // namespace face_reenact::output
