#version 450
// Landmark visibility pruning (energy.cc): a detected landmark counts when its model vertex is
// in front of the camera and faces it in the current render. Candidates (confidence > 0, in the
// inner set when asked) come from the host in input order; the order is kept, so the rows match
// the CPU's. At most a few dozen candidates: one invocation walks them.
layout(local_size_x = 1) in;

layout(std430, set = 0, binding = 0) readonly buffer Candidates { vec4 candidates[]; };  // vertex bits, u, v, confidence
layout(std430, set = 0, binding = 1) readonly buffer CameraPositions { vec4 camera_positions[]; };
layout(std430, set = 0, binding = 2) readonly buffer CameraNormals { vec4 camera_normals[]; };
layout(std430, set = 0, binding = 3) writeonly buffer Landmarks { vec4 landmarks[]; };
layout(std430, set = 0, binding = 4) buffer Counters {
  uint pixel_count;
  uint num_point;
  uint num_plane;
  uint num_color;
  uint landmark_count;
  float landmark_weight;
  uint pad[2];
} counters;

layout(push_constant) uniform Push {
  uint count;
  float near_plane;
} pc;

void main() {
  uint kept = 0u;
  float weight = 0.0;
  for (uint c = 0u; c < pc.count; ++c) {
    const vec4 cand = candidates[c];
    const uint v = floatBitsToUint(cand.x);
    const vec3 x = camera_positions[v].xyz;
    const vec3 n = camera_normals[v].xyz;
    if (!(x.z > pc.near_plane) || dot(n, x) >= 0.0) continue;
    landmarks[kept] = cand;
    ++kept;
    weight += cand.w;
  }
  counters.landmark_count = kept;
  counters.landmark_weight = weight;
}
