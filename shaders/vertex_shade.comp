#version 450
#extension GL_GOOGLE_include_directive : require
// Per vertex: area-weighted normal gathered from the incident triangles (CSR adjacency, no
// atomics), rigid transform to camera space, and Lambertian SH shading (Eq. 3).
layout(local_size_x = 64) in;
#include "common.glsl"

layout(std430, set = 0, binding = 0) readonly buffer Shape { float shape[]; };       // 3N, model frame
layout(std430, set = 0, binding = 1) readonly buffer Albedo { float albedo[]; };     // 3N
layout(std430, set = 0, binding = 2) readonly buffer Triangles { uint triangles[]; };  // 3T
layout(std430, set = 0, binding = 3) readonly buffer AdjacencyOffsets { uint adjacency_offsets[]; };  // N + 1
layout(std430, set = 0, binding = 4) readonly buffer Adjacency { uint adjacency[]; };  // triangle ids
layout(std430, set = 0, binding = 5) readonly buffer Frame { FrameBlock frame; };
layout(std430, set = 0, binding = 6) writeonly buffer CameraPositions { vec4 camera_positions[]; };
layout(std430, set = 0, binding = 7) writeonly buffer CameraNormals { vec4 camera_normals[]; };
layout(std430, set = 0, binding = 8) writeonly buffer Colors { vec4 colors[]; };

layout(push_constant) uniform Push {
  uint num_vertices;
} pc;

vec3 model_position(uint v) { return vec3(shape[3 * v], shape[3 * v + 1], shape[3 * v + 2]); }

void main() {
  const uint v = gl_GlobalInvocationID.x;
  if (v >= pc.num_vertices) return;
  vec3 sum = vec3(0.0);
  for (uint k = adjacency_offsets[v]; k < adjacency_offsets[v + 1]; ++k) {
    const uint t = adjacency[k];
    const vec3 a = model_position(triangles[3 * t]);
    const vec3 b = model_position(triangles[3 * t + 1]);
    const vec3 c = model_position(triangles[3 * t + 2]);
    sum += cross(b - a, c - a);
  }
  const float len = length(sum);
  const vec3 n = len > 0.0 ? sum / len : vec3(0.0);
  const mat3 rt = mat3(frame.rotation_rows[0].xyz, frame.rotation_rows[1].xyz, frame.rotation_rows[2].xyz);
  // mat3(rows...) holds R^T as columns; v * M multiplies by R.
  const vec3 p = model_position(v);
  const vec3 x = p * rt + frame.translation.xyz;
  const vec3 nc = n * rt;
  float y[9];
  sh_basis(nc, y);
  vec3 irradiance = vec3(0.0);
  for (int k = 0; k < 9; ++k) {
    irradiance += vec3(frame.gamma[k], frame.gamma[9 + k], frame.gamma[18 + k]) * y[k];
  }
  const vec3 alb = vec3(albedo[3 * v], albedo[3 * v + 1], albedo[3 * v + 2]);
  camera_positions[v] = vec4(x, 1.0);
  camera_normals[v] = vec4(nc, 0.0);
  colors[v] = vec4(alb * irradiance, 1.0);
}
