#version 450
// Landmark visibility pruning (energy.cc, LandmarkVertexVisible): a detected landmark counts
// when its model vertex is in front of the camera and the render, at the pixel the vertex
// projects to, shows no surface more than occlusion_m nearer (uncovered or outside: kept).
// Candidates (confidence > 0, in the inner set when asked) come from the host in input order;
// the order is kept, so the rows match the CPU's. At most a few dozen candidates: one
// invocation walks them.
layout(local_size_x = 1) in;

layout(std430, set = 0, binding = 0) readonly buffer Candidates { vec4 candidates[]; };  // vertex bits, u, v, confidence
layout(std430, set = 0, binding = 1) readonly buffer CameraPositions { vec4 camera_positions[]; };
layout(std430, set = 0, binding = 2) readonly buffer GPosition { vec4 g_position[]; };  // render, camera space; w = 0 uncovered
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
  uint width, height;
  float fx, fy, cx, cy;
  float occlusion_m;
} pc;

bool visible(const vec3 x) {
  if (!(x.z > pc.near_plane)) return false;
  const float fi = floor(pc.fx * x.x / x.z + pc.cx + 0.5), fj = floor(pc.fy * x.y / x.z + pc.cy + 0.5);
  if (!(fi >= 0.0 && fj >= 0.0 && fi < float(pc.width) && fj < float(pc.height))) return true;
  const vec4 g = g_position[uint(fj) * pc.width + uint(fi)];
  if (g.w == 0.0) return true;
  return !(g.z < x.z - pc.occlusion_m);
}

void main() {
  uint kept = 0u;
  float weight = 0.0;
  for (uint c = 0u; c < pc.count; ++c) {
    const vec4 cand = candidates[c];
    const uint v = floatBitsToUint(cand.x);
    if (!visible(camera_positions[v].xyz)) continue;
    landmarks[kept] = cand;
    ++kept;
    weight += cand.w;
  }
  counters.landmark_count = kept;
  counters.landmark_weight = weight;
}
