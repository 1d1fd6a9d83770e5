#pragma once
// A borrowed view of an 8-bit image as cameras, decoders and OBS hand it over: any size, any
// row stride, grey, BGR, RGB or BGRA. The landmark code converts to grey itself, so callers
// never copy a frame just to change its layout.
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace face_reenact::landmarks {

enum class PixelFormat { kGray8, kBGR8, kRGB8, kBGRA8 };

int bytes_per_pixel(PixelFormat format);
const char* pixel_format_name(PixelFormat format);

struct ImageView {
  const uint8_t* data = nullptr;
  int width = 0;
  int height = 0;
  // Bytes from one row to the next; 0 means tightly packed (width * bytes_per_pixel).
  size_t stride_bytes = 0;
  PixelFormat format = PixelFormat::kBGR8;

  size_t row_bytes() const { return stride_bytes != 0 ? stride_bytes : size_t(width) * bytes_per_pixel(format); }
  // False (with the reason) for null data, non-positive sizes or a stride shorter than a row.
  bool IsValid(std::string* error) const;
};

// An image that owns its pixels (tightly packed); what frame sources hand out.
struct Image {
  std::vector<uint8_t> pixels;
  int width = 0;
  int height = 0;
  PixelFormat format = PixelFormat::kBGR8;

  ImageView view() const { return ImageView{pixels.data(), width, height, 0, format}; }
  bool empty() const { return pixels.empty(); }
};

// A grey copy of any valid view (ITU-R BT.601 luma); empty for an invalid view.
Image to_gray_image(const ImageView& view);

}  // namespace face_reenact::landmarks
