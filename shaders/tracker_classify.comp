#version 450
#extension GL_GOOGLE_include_directive : require
// Linearisation, per pixel of the pyramid level (energy.cc: Linearize): a pixel counts when the
// render covers it, EnergyOptions::pixel_sampling takes it and the input has depth there (or the
// frame has none); it carries the geometric terms when |X_S - X_I| <= max_point_distance and the
// plane terms also when N_I exists and N_S . N_I >= min_normal_dot; the colour term when its
// triangle is in the colour parts, with its robust weight. Carrying pixels are compacted into
// items with an atomic counter (order is arbitrary; every later pass is order-independent up to
// rounding).
layout(local_size_x = 64) in;
#include "tracker_common.glsl"

layout(std430, set = 0, binding = 0) readonly buffer GPosition { vec4 g_position[]; };
layout(std430, set = 0, binding = 1) readonly buffer GNormal { vec4 g_normal[]; };
layout(std430, set = 0, binding = 2) readonly buffer GBary { vec4 g_bary[]; };
layout(std430, set = 0, binding = 3) readonly buffer GIds { uvec4 g_ids[]; };
layout(std430, set = 0, binding = 4) readonly buffer Input { vec4 input_data[]; };  // kInputVec4sPerPixel per pixel
layout(std430, set = 0, binding = 5) writeonly buffer Items { uint items[]; };
layout(std430, set = 0, binding = 7) readonly buffer GColor { vec4 g_color[]; };  // C_S, the rendered shaded colour
layout(std430, set = 0, binding = 8) readonly buffer VertexParts { uint vertex_part[]; };  // FacePart per vertex
layout(std430, set = 0, binding = 6) buffer Counters {
  uint pixel_count;
  uint num_point;
  uint num_plane;
  uint num_color;
  uint landmark_count;
  float landmark_weight;
  uint pad[2];
} counters;

layout(push_constant) uniform Push {
  uint width, height, has_depth, use_point, use_plane, use_color;
  float max_point_distance, min_normal_dot;
  float color_robust_threshold;  // EnergyOptions::color_robust_threshold (0 = off)
  uint color_parts;              // EnergyOptions::color_parts (bit per FacePart)
  uint pixel_sampling;           // EnergyOptions::pixel_sampling: 2 = (i + j) even, 4 = (i + 2j) % 4 == 0
} pc;

void main() {
  const uint p = gl_GlobalInvocationID.x;
  if (p >= pc.width * pc.height) return;
  // energy.h: SampledPixel
  if (pc.pixel_sampling == 2u && (((p % pc.width) + (p / pc.width)) & 1u) != 0u) return;
  if (pc.pixel_sampling == 4u && (((p % pc.width) + 2u * (p / pc.width)) & 3u) != 0u) return;
  const uvec4 ids = g_ids[p];
  if (ids.x == 0u) return;
  const vec4 input_point = input_data[kInputVec4sPerPixel * p];
  const vec4 input_normal = input_data[kInputVec4sPerPixel * p + 1u];
  if (pc.has_depth != 0u && input_point.w == 0.0) return;
  bool point = false, plane = false;
  const bool color = pc.use_color != 0u && ((pc.color_parts >> vertex_part[ids.y]) & 1u) != 0u &&
                     ((pc.color_parts >> vertex_part[ids.z]) & 1u) != 0u && ((pc.color_parts >> vertex_part[ids.w]) & 1u) != 0u;
  if (pc.has_depth != 0u && (pc.use_point != 0u || pc.use_plane != 0u)) {
    const bool near = length(g_position[p].xyz - input_point.xyz) <= pc.max_point_distance;
    point = pc.use_point != 0u && near;
    if (pc.use_plane != 0u && near && input_normal.w != 0.0) {
      plane = dot(g_normal[p].xyz, input_normal.xyz) >= pc.min_normal_dot;
    }
  }
  if (!point && !plane && !color) return;
  const uint slot = atomicAdd(counters.pixel_count, 1u);
  if (point) atomicAdd(counters.num_point, 1u);
  if (plane) atomicAdd(counters.num_plane, 1u);
  if (color) atomicAdd(counters.num_color, 1u);
  const vec4 b = g_bary[p];
  const uint base = kPixelItemWords * slot;
  items[base] = p;
  items[base + 1] = (point ? kFlagPoint : 0u) | (plane ? kFlagPlane : 0u) | (color ? kFlagColor : 0u);
  items[base + 2] = ids.y;
  items[base + 3] = ids.z;
  items[base + 4] = ids.w;
  items[base + 5] = floatBitsToUint(b.x);
  items[base + 6] = floatBitsToUint(b.y);
  items[base + 7] = floatBitsToUint(b.z);
  // The robust colour weight (energy.cc, RobustColorWeight), frozen for this linearisation.
  float weight = 1.0;
  if (color && pc.color_robust_threshold > 0.0) {
    const vec3 d = g_color[p].xyz - input_data[kInputVec4sPerPixel * p + 2u].xyz;
    const float difference = sqrt(dot(d, d));
    if (difference > pc.color_robust_threshold) weight = pc.color_robust_threshold / difference;
  }
  items[base + 8] = floatBitsToUint(weight);
}
