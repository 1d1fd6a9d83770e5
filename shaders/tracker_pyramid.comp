#version 450
// One level of the input pyramid made on the device from the next finer one (input_frame.cc,
// BuildPyramid, in float): per coarse pixel, the [1 3 3 1] / 8 kernel over the fine pixels
// 2i-1 .. 2i+2 in both directions (clamped at the border) for the colour; for the depth, the
// nearest valid sample of the inner 2x2 block is the reference and only valid samples within
// depth_edge_threshold of it are averaged, so silhouettes do not blend with the background.
// A level is the colour and the depth per pixel, 0 where there is none (tracker_input.comp).
layout(local_size_x = 64) in;

layout(std430, set = 0, binding = 0) readonly buffer Fine { vec4 fine[]; };      // rgb, depth (0 = none)
layout(std430, set = 0, binding = 1) writeonly buffer Coarse { vec4 coarse[]; };  // the same, one level down

layout(push_constant) uniform Push {
  uint fine_width, fine_height, width, height;
  float depth_edge_threshold;  // PyramidOptions::depth_edge_threshold
} pc;

const float kTap[4] = float[4](1.0 / 8.0, 3.0 / 8.0, 3.0 / 8.0, 1.0 / 8.0);

void main() {
  const uint p = gl_GlobalInvocationID.x;
  if (p >= pc.width * pc.height) return;
  const int i = int(p % pc.width), j = int(p / pc.width);
  const int fw = int(pc.fine_width), fh = int(pc.fine_height);
  int cols[4], rows[4];
  for (int a = 0; a < 4; ++a) {
    cols[a] = clamp(2 * i - 1 + a, 0, fw - 1);
    rows[a] = clamp(2 * j - 1 + a, 0, fh - 1);
  }
  vec4 s[16];
  for (int b = 0; b < 4; ++b) {
    for (int a = 0; a < 4; ++a) s[4 * b + a] = fine[uint(rows[b] * fw + cols[a])];
  }
  float nearest = uintBitsToFloat(0x7f800000u);  // +infinity
  for (int b = 1; b <= 2; ++b) {
    for (int a = 1; a <= 2; ++a) {
      const float d = s[4 * b + a].w;
      if (d > 0.0) nearest = min(nearest, d);
    }
  }
  vec3 rgb = vec3(0.0);
  float dsum = 0.0, dw = 0.0;
  for (int b = 0; b < 4; ++b) {
    vec3 row = vec3(0.0);
    for (int a = 0; a < 4; ++a) {
      const vec4 v = s[4 * b + a];
      row += kTap[a] * v.xyz;
      if (v.w > 0.0 && abs(v.w - nearest) <= pc.depth_edge_threshold) {
        dsum += kTap[a] * kTap[b] * v.w;
        dw += kTap[a] * kTap[b];
      }
    }
    rgb += kTap[b] * row;
  }
  coarse[p] = vec4(rgb, dw > 0.0 ? dsum / dw : 0.0);
}
