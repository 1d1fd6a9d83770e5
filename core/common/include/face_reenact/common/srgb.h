#pragma once
// The sRGB transfer function (IEC 61966-2-1): linear light in [0,1] <-> 8-bit-style encoded
// values in [0,1]. The renderer, albedo and tracker work in linear RGB; images and meshes on
// disk are sRGB-encoded.
#include <algorithm>
#include <array>
#include <cmath>

namespace face_reenact {

template <typename T>
T srgb_encode(T linear) {
  linear = std::clamp(linear, T(0), T(1));
  return linear <= T(0.0031308) ? T(12.92) * linear : T(1.055) * std::pow(linear, T(1) / T(2.4)) - T(0.055);
}

template <typename T>
T srgb_decode(T encoded) {
  return encoded <= T(0.04045) ? encoded / T(12.92) : std::pow((encoded + T(0.055)) / T(1.055), T(2.4));
}

// Relative luminance of linear RGB (Rec. 709 / sRGB primaries).
template <typename T>
T linear_luminance(T r, T g, T b) {
  return T(0.2126) * r + T(0.7152) * g + T(0.0722) * b;
}

// srgb_decode of every 8-bit value (v / 255), computed once: images arrive as bytes.
inline const std::array<float, 256>& srgb_decode_table() {
  static const std::array<float, 256> table = [] {
    std::array<float, 256> t{};
    for (int v = 0; v < 256; ++v) t[static_cast<size_t>(v)] = srgb_decode(static_cast<float>(v) / 255.0f);
    return t;
  }();
  return table;
}

}  // namespace face_reenact
