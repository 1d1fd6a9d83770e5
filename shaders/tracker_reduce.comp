#version 450
#extension GL_GOOGLE_include_directive : require
// out[i] = sum over g of partials[g * count + i]: the second stage of every block reduction.
// Summing in a fixed order keeps the result independent of scheduling. groups = kSizeFromParams:
// the chunks of tracker_jtj.comp over the rows its level's TrackParams hold (the device-driven loop).
layout(local_size_x = 64) in;
#include "tracker_common.glsl"

layout(std430, set = 0, binding = 0) readonly buffer Partials { float partials[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Result { float result[]; };
layout(std430, set = 0, binding = 2) readonly buffer Params { TrackParams params; };

layout(push_constant) uniform Push {
  uint count, groups;
} pc;

void main() {
  const uint i = gl_GlobalInvocationID.x;
  if (i >= pc.count) return;
  const uint groups = pc.groups != kSizeFromParams
                          ? pc.groups
                          : (system_rows(params.num_pixels, params.num_landmarks, params.num_regularizer) + kJtjChunkRows - 1u) /
                                kJtjChunkRows;
  float s = 0.0;
  for (uint g = 0u; g < groups; ++g) s += partials[g * pc.count + i];
  result[i] = s;
}
