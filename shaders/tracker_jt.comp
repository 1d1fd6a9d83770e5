#version 450
#extension GL_GOOGLE_include_directive : require
// Column sums over a chunk of 256 rows of J, one partial per workgroup:
//   mode 0: partial[g] = [ J_chunk^T r_chunk (n) | column sums of J_chunk^2 (n) ]  (b and diag)
//   mode 1: partial[g] = J_chunk^T (J_chunk p)  (n)  - the matrix-free normal product of the
//           paper's Sec. 6.2: J p and J^T (J p) fused per chunk, so J is read twice per PCG
//           step from one pass's working set.
// J is read column-major (column stride col_stride, a multiple of 4) as vec4s: lavapipe loads
// storage buffers lane by lane, so a vec4 per lane quarters the loads (measured: this pass was
// most of a Gauss-Newton step with one float per lane). tracker_pcg.comp sums the partials.
// Mode 1 does nothing once the PCG state says done.
layout(local_size_x = 64) in;
#include "tracker_common.glsl"

layout(std430, set = 0, binding = 0) readonly buffer Jacobian { float jacobian[]; };  // row-major (unused)
layout(std430, set = 0, binding = 1) readonly buffer Residuals { float residuals[]; };
layout(std430, set = 0, binding = 2) readonly buffer State { float state[]; };
layout(std430, set = 0, binding = 3) writeonly buffer Partials { float partials[]; };
layout(std430, set = 0, binding = 4) readonly buffer JacobianColumns { vec4 jacobian_columns[]; };  // column-major
layout(std430, set = 0, binding = 5) readonly buffer Params { TrackParams params; };  // rows = kSizeFromParams

layout(push_constant) uniform Push {
  uint rows, n, mode, p_offset, done_index, col_stride;
} pc;

const uint kChunk = kJtChunkRows;  // 64 invocations x 4 rows
shared vec4 weights[kChunk / 4u];
shared float p_shared[kMaxUnknowns];

void main() {
  const uint lid = gl_LocalInvocationID.x;
  const uint chunk = gl_WorkGroupID.x;
  const uint row0 = chunk * kChunk;
  const bool from_params = pc.rows == kSizeFromParams;
  const uint rows = from_params ? system_rows(params.num_pixels, params.num_landmarks, params.num_regularizer) : pc.rows;
  const uint col_stride = from_params ? params.rows : pc.col_stride;
  if (pc.mode == 1u && state[pc.done_index] != 0.0) return;  // uniform over the workgroup
  if (pc.mode == 1u) {
    for (uint i = lid; i < pc.n; i += 64u) p_shared[i] = state[pc.p_offset + i];
    barrier();
  }
  const uint count = min(kChunk, rows - row0);
  // Rows row0 + 4 lid .. + 3 of this invocation; those past the end weigh 0 and their
  // (unwritten) J entries are masked out below.
  const bvec4 valid = lessThan(uvec4(4u * lid) + uvec4(0u, 1u, 2u, 3u), uvec4(count));
  const uint quad = (row0 >> 2) + lid;
  const uint stride4 = col_stride >> 2;
  vec4 w = vec4(0.0);
  if (pc.mode == 0u) {
    for (uint k = 0u; k < 4u; ++k) {
      if (valid[k]) w[k] = residuals[row0 + 4u * lid + k];
    }
  } else if (any(valid)) {
    for (uint i = 0u; i < pc.n; ++i) w += mix(vec4(0.0), jacobian_columns[i * stride4 + quad], valid) * p_shared[i];
  }
  weights[lid] = w;
  barrier();
  const uint quads = (count + 3u) / 4u;
  for (uint col = lid; col < pc.n; col += 64u) {
    float acc = 0.0, acc2 = 0.0;
    const uint base = col * stride4 + (row0 >> 2);
    for (uint q = 0u; q < quads; ++q) {
      const bvec4 ok = lessThan(uvec4(4u * q) + uvec4(0u, 1u, 2u, 3u), uvec4(count));
      const vec4 j = mix(vec4(0.0), jacobian_columns[base + q], ok);
      acc += dot(j, weights[q]);
      acc2 += dot(j, j);
    }
    if (pc.mode == 0u) {
      partials[chunk * 2u * pc.n + col] = acc;
      partials[chunk * 2u * pc.n + pc.n + col] = acc2;
    } else {
      partials[chunk * pc.n + col] = acc;
    }
  }
}
