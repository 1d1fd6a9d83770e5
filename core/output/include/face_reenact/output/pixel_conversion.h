#pragma once
// 8-bit BGR (OpenCV's layout) to the two pixel formats conference apps take from a virtual
// webcam (YUYV and I420), with BT.601 limited-range coefficients: Y in [16, 235], Cb/Cr in
// [16, 240], what USB webcams send and what Chrome, Firefox and Zoom assume for these formats.
// Also the fit of any input size into the output frame (letterboxing) and the inverse
// conversions (tests, and checking what a reader received).
#include <cstddef>
#include <cstdint>
#include <opencv2/core/mat.hpp>
#include <optional>
#include <span>
#include <string>

namespace face_reenact::output {

enum class PixelFormat {
  kYuyv,  // packed 4:2:2, Y0 U Y1 V per pixel pair (V4L2_PIX_FMT_YUYV), 2 bytes per pixel
  kI420,  // planar 4:2:0, Y plane, then U (Cb) and V (Cr) planes at half width and height (YU12)
};

const char* pixel_format_name(PixelFormat format);         // "yuyv", "i420"
std::optional<PixelFormat> parse_pixel_format(const std::string& name);  // case-insensitive
uint32_t pixel_format_fourcc(PixelFormat format);           // V4L2_PIX_FMT_YUYV / V4L2_PIX_FMT_YUV420
std::string fourcc_to_string(uint32_t fourcc);              // "YUYV"
// Bytes of one frame; width must be even (and height too for I420).
size_t frame_bytes(PixelFormat format, int width, int height);
size_t bytes_per_line(PixelFormat format, int width);       // of the first (or only) plane

// One pixel, BT.601 limited range, integer arithmetic (the exact values the tests pin down).
struct Ycbcr {
  uint8_t y, cb, cr;
};
Ycbcr bgr_to_ycbcr(uint8_t b, uint8_t g, uint8_t r);
// Inverse, clamped to [0, 255]; bgr_to_ycbcr followed by this is within 3 of the input for
// every colour, under 1 on average (limited range has fewer levels than full range).
void ycbcr_to_bgr(uint8_t y, uint8_t cb, uint8_t cr, uint8_t* b, uint8_t* g, uint8_t* r);

// Converts an 8-bit BGR image (CV_8UC3, even width; even height for I420) into out, which
// holds frame_bytes(format, cols, rows). Chroma is the rounded mean of each pixel pair (YUYV)
// or 2x2 block (I420). Throws face_reenact::Error on a wrong type, odd size or short buffer.
void convert_bgr(const cv::Mat& bgr, PixelFormat format, std::span<uint8_t> out);
// The inverse into a new CV_8UC3 image of the given size.
cv::Mat convert_to_bgr(std::span<const uint8_t> frame, PixelFormat format, int width, int height);

// Fits the image into width x height keeping its aspect ratio, centred, with black bars
// (letterbox or pillarbox). Accepts CV_8UC1 (grey), CV_8UC3 (BGR) and CV_8UC4 (BGRA); returns
// BGR. An image that already has the size is returned as is (no copy). Throws
// face_reenact::Error on an empty image or an unsupported type.
cv::Mat letterbox_bgr(const cv::Mat& image, int width, int height);

// The rectangle letterbox_bgr puts the image into (tests, overlays).
cv::Rect letterbox_rect(int image_width, int image_height, int width, int height);

// A black frame in the format (Y=16, Cb=Cr=128): what the writer primes the device with.
void fill_black(PixelFormat format, int width, int height, std::span<uint8_t> out);

}  // namespace face_reenact::output
