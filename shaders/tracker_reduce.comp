#version 450
// out[i] = sum over g of partials[g * count + i]: the second stage of every block reduction.
// Summing in a fixed order keeps the result independent of scheduling.
layout(local_size_x = 64) in;

layout(std430, set = 0, binding = 0) readonly buffer Partials { float partials[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Result { float result[]; };

layout(push_constant) uniform Push {
  uint count, groups;
} pc;

void main() {
  const uint i = gl_GlobalInvocationID.x;
  if (i >= pc.count) return;
  float s = 0.0;
  for (uint g = 0u; g < pc.groups; ++g) s += partials[g * pc.count + i];
  result[i] = s;
}
