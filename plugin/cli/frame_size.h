#pragma once
// The `--size WIDTHxHEIGHT` option of the commands that make frames (synth, reenact, webcam, bench).
#include <cstdio>
#include <string>

#include "face_reenact/common/error.h"

namespace face_reenact::cli {

struct FrameSizeLimits {
  int min_width = 1, min_height = 1;
  int max_width = 7680, max_height = 4320;
};

// Parses "640x480" (or "640X480") into *width and *height; anything else, or a size outside
// `limits`, is an Error that says what is expected.
inline void parse_frame_size(const std::string& text, int* width, int* height, const FrameSizeLimits& limits = {}) {
  int w = 0, h = 0;
  char x = 0, extra = 0;
  if (std::sscanf(text.c_str(), "%d%c%d%c", &w, &x, &h, &extra) != 3 || (x != 'x' && x != 'X') ||
      w < limits.min_width || h < limits.min_height || w > limits.max_width || h > limits.max_height)
    throw Error("--size '" + text + "': expected WIDTHxHEIGHT between " + std::to_string(limits.min_width) + "x" +
                std::to_string(limits.min_height) + " and " + std::to_string(limits.max_width) + "x" +
                std::to_string(limits.max_height) + ", e.g. 640x480");
  *width = w;
  *height = h;
}

}  // namespace face_reenact::cli
