#version 450
#extension GL_GOOGLE_include_directive : require
// A pyramid level's input as the per-pixel passes read it (tracker_common.glsl,
// kInputVec4sPerPixel), made on the device from what the host uploads per pixel: the linear colour
// and the depth, 0 where InputFrame::depth_valid is false (vulkan_solver.cc, prepare_level). The
// host used to compute and upload the five vec4s itself: five times the bytes through host-visible
// memory, which the per-pixel passes then read across the bus. Mirrors input_frame.cc in float:
// the back-projected point (InputFrame::point), the normal from central differences
// (InputNormal) and the colour's gradient (InputColorGradient).
layout(local_size_x = 64) in;
#include "tracker_common.glsl"

layout(std430, set = 0, binding = 0) readonly buffer Raw { vec4 raw[]; };  // rgb, depth (0 = none)
layout(std430, set = 0, binding = 1) writeonly buffer Input { vec4 input_data[]; };

layout(push_constant) uniform Push {
  uint width, height;
  uint gradient;  // EnergyOptions::color_follows_projection applies to this frame
  float fx, fy, cx, cy;
  float max_depth_jump;  // EnergyOptions::max_depth_jump_m
} pc;

float depth_at(int i, int j) { return raw[uint(j) * pc.width + uint(i)].w; }

bool valid_at(int i, int j) {
  if (i < 0 || j < 0 || i >= int(pc.width) || j >= int(pc.height)) return false;
  return depth_at(i, j) > 0.0;
}

vec3 point_at(int i, int j) {
  const float z = depth_at(i, j);
  return vec3((float(i) - pc.cx) * z / pc.fx, (float(j) - pc.cy) * z / pc.fy, z);
}

void main() {
  const uint p = gl_GlobalInvocationID.x;
  if (p >= pc.width * pc.height) return;
  const int i = int(p % pc.width), j = int(p / pc.width);
  const vec4 here = raw[p];
  vec4 point = vec4(0.0), normal = vec4(0.0), grad_u = vec4(0.0), grad_v = vec4(0.0);
  if (here.w > 0.0) {
    point = vec4(point_at(i, j), 1.0);
    if (valid_at(i - 1, j) && valid_at(i + 1, j) && valid_at(i, j - 1) && valid_at(i, j + 1) &&
        abs(depth_at(i - 1, j) - here.w) <= pc.max_depth_jump && abs(depth_at(i + 1, j) - here.w) <= pc.max_depth_jump &&
        abs(depth_at(i, j - 1) - here.w) <= pc.max_depth_jump && abs(depth_at(i, j + 1) - here.w) <= pc.max_depth_jump) {
      vec3 n = cross(point_at(i + 1, j) - point_at(i - 1, j), point_at(i, j + 1) - point_at(i, j - 1));
      const float len = length(n);
      if (len > 0.0) {
        n /= len;
        if (dot(n, point.xyz) > 0.0) n = -n;  // towards the camera
        normal = vec4(n, 1.0);
      }
    }
  }
  if (pc.gradient != 0u) {
    const int i0 = max(i - 1, 0), i1 = min(i + 1, int(pc.width) - 1);
    const int j0 = max(j - 1, 0), j1 = min(j + 1, int(pc.height) - 1);
    if (i1 > i0) grad_u = vec4((raw[uint(j) * pc.width + uint(i1)].xyz - raw[uint(j) * pc.width + uint(i0)].xyz) / float(i1 - i0), 0.0);
    if (j1 > j0) grad_v = vec4((raw[uint(j1) * pc.width + uint(i)].xyz - raw[uint(j0) * pc.width + uint(i)].xyz) / float(j1 - j0), 0.0);
  }
  const uint o = kInputVec4sPerPixel * p;
  input_data[o] = point;
  input_data[o + 1u] = normal;
  input_data[o + 2u] = vec4(here.xyz, 1.0);
  input_data[o + 3u] = grad_u;
  input_data[o + 4u] = grad_v;
}
