#version 450
#extension GL_GOOGLE_include_directive : require
// The assembled alternative: [J^T J | J^T r] over a chunk of rows, one partial per workgroup.
// Workgroup (x, y) takes rows [x * rows_per_chunk, ...) and the 8 columns a = 8y .. 8y + 7;
// invocation b takes column b (b == n: the residual, giving J^T r). J is read column-major as
// vec4s (4 rows per load; lavapipe loads storage buffers lane by lane, so this quarters the
// loads), J[.][a] is the same for every invocation (a uniform load). No shared memory.
// Output per chunk: n rows of n + 1 floats (A(a, b) at a * (n + 1) + b, J^T r at
// a * (n + 1) + n); tracker_reduce.comp sums the chunks.
layout(local_size_x = 256) in;
#include "tracker_common.glsl"

layout(std430, set = 0, binding = 0) readonly buffer JacobianColumns { vec4 jacobian_columns[]; };  // column-major
layout(std430, set = 0, binding = 1) readonly buffer Residuals { float residuals[]; };
layout(std430, set = 0, binding = 2) writeonly buffer Partials { float partials[]; };
layout(std430, set = 0, binding = 3) readonly buffer Params { TrackParams params; };  // rows = kSizeFromParams

layout(push_constant) uniform Push {
  uint rows, n, rows_per_chunk, col_stride;  // rows_per_chunk: a multiple of 4
} pc;

const uint kColumnsPerGroup = 8u;

void main() {
  const uint b = gl_LocalInvocationID.x;
  const uint n = pc.n;
  if (b > n) return;  // no barriers below
  const uint chunk = gl_WorkGroupID.x;
  const uint a0 = gl_WorkGroupID.y * kColumnsPerGroup;
  const uint row_start = chunk * pc.rows_per_chunk;
  const bool from_params = pc.rows == kSizeFromParams;
  const uint rows = from_params ? system_rows(params.num_pixels, params.num_landmarks, params.num_regularizer) : pc.rows;
  const uint row_end = min(rows, row_start + pc.rows_per_chunk);
  const uint stride4 = (from_params ? params.rows : pc.col_stride) >> 2;
  float acc[kColumnsPerGroup];
  for (uint k = 0u; k < kColumnsPerGroup; ++k) acc[k] = 0.0;
  const uint count = min(kColumnsPerGroup, n - a0);
  for (uint row = row_start; row < row_end; row += 4u) {
    const uint quad = row >> 2;
    const bvec4 ok = lessThan(uvec4(row) + uvec4(0u, 1u, 2u, 3u), uvec4(row_end));
    vec4 jb;
    if (b < n) {
      jb = mix(vec4(0.0), jacobian_columns[b * stride4 + quad], ok);
    } else {
      for (uint k = 0u; k < 4u; ++k) jb[k] = ok[k] ? residuals[row + k] : 0.0;
    }
    for (uint k = 0u; k < kColumnsPerGroup; ++k) {
      if (k < count) acc[k] += dot(mix(vec4(0.0), jacobian_columns[(a0 + k) * stride4 + quad], ok), jb);
    }
  }
  const uint out_base = chunk * n * (n + 1u);
  for (uint k = 0u; k < count; ++k) partials[out_base + (a0 + k) * (n + 1u) + b] = acc[k];
}
