#version 450
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
// The assembled alternative: [J^T J | J^T r] over a chunk of rows, one partial per workgroup row.
// [J | r] has n + 1 columns (column n: the residual). They are cut into tiles of kJtjTile and
// each invocation takes one pair of tiles (ta <= tb), so J^T J's symmetric half is computed once
// and every load of J is used kJtjTile times: per 4 rows, 2 x kJtjTile vec4 loads feed
// kJtjTile^2 dot products (the one-column-per-invocation version used 9 loads for 8, and did
// both halves; on lavapipe, whose storage loads go lane by lane, the loads were the cost: a
// 175-unknown calibration frame took 250 ms). Workgroup x is the chunk of rows, workgroup y a
// run of kJtjPairsPerGroup tile pairs. J is read column-major as vec4s. No shared memory.
// Output per chunk: n rows of n + 1 floats (A(a, b) at a * (n + 1) + b, J^T r at
// a * (n + 1) + n), both halves written; tracker_reduce.comp sums the chunks.
layout(local_size_x = 64) in;  // kJtjPairsPerGroup
#include "tracker_common.glsl"

layout(std430, set = 0, binding = 0) readonly buffer JacobianColumns { vec4 jacobian_columns[]; };  // column-major
layout(std430, set = 0, binding = 1) readonly buffer Residuals { float residuals[]; };
layout(std430, set = 0, binding = 2) writeonly buffer Partials { float partials[]; };
layout(std430, set = 0, binding = 3) readonly buffer Params { TrackParams params; };  // rows = kSizeFromParams

layout(push_constant) uniform Push {
  uint rows, n, rows_per_chunk, col_stride;  // rows_per_chunk: a multiple of 4
} pc;

// Column c of [J | r] at rows 4 quad .. 4 quad + 3 (zero past the chunk's rows and past column n).
vec4 augmented_column(uint c, uint n, uint quad, uint row, bvec4 ok, uint stride4) {
  if (c < n) return mix(vec4(0.0), jacobian_columns[c * stride4 + quad], ok);
  vec4 v = vec4(0.0);
  if (c == n) {
    for (uint k = 0u; k < 4u; ++k) v[k] = ok[k] ? residuals[row + k] : 0.0;
  }
  return v;
}

void main() {
  const uint n = pc.n;
  const uint tiles = jtj_tiles(n);
  uint pair = gl_WorkGroupID.y * gl_WorkGroupSize.x + gl_LocalInvocationID.x;
  if (pair >= tiles * (tiles + 1u) / 2u) return;  // no barriers below
  // Pair index -> (ta, tb), ta <= tb, row by row of the upper triangle of tiles.
  uint ta = 0u;
  while (pair >= tiles - ta) {
    pair -= tiles - ta;
    ++ta;
  }
  const uint tb = ta + pair;
  const uint a0 = ta * kJtjTile, b0 = tb * kJtjTile;

  const uint chunk = gl_WorkGroupID.x;
  const uint row_start = chunk * pc.rows_per_chunk;
  const bool from_params = pc.rows == kSizeFromParams;
  const uint rows = from_params ? system_rows(params.num_pixels, params.num_landmarks, params.num_regularizer) : pc.rows;
  const uint row_end = min(rows, row_start + pc.rows_per_chunk);
  const uint stride4 = (from_params ? params.rows : pc.col_stride) >> 2;
  float acc[kJtjTile][kJtjTile];
  [[unroll]] for (uint i = 0u; i < kJtjTile; ++i) {
    [[unroll]] for (uint j = 0u; j < kJtjTile; ++j) acc[i][j] = 0.0;
  }
  for (uint row = row_start; row < row_end; row += 4u) {
    const uint quad = row >> 2;
    const bvec4 ok = lessThan(uvec4(row) + uvec4(0u, 1u, 2u, 3u), uvec4(row_end));
    vec4 ja[kJtjTile], jb[kJtjTile];
    [[unroll]] for (uint i = 0u; i < kJtjTile; ++i) {
      ja[i] = augmented_column(a0 + i, n, quad, row, ok, stride4);
      jb[i] = augmented_column(b0 + i, n, quad, row, ok, stride4);
    }
    [[unroll]] for (uint i = 0u; i < kJtjTile; ++i) {
      [[unroll]] for (uint j = 0u; j < kJtjTile; ++j) acc[i][j] += dot(ja[i], jb[j]);
    }
  }
  const uint out_base = chunk * n * (n + 1u);
  [[unroll]] for (uint i = 0u; i < kJtjTile; ++i) {
    [[unroll]] for (uint j = 0u; j < kJtjTile; ++j) {
      const uint a = a0 + i, b = b0 + j;
      if (a < n && b <= n) partials[out_base + a * (n + 1u) + b] = acc[i][j];
      if (ta != tb && b < n) partials[out_base + b * (n + 1u) + a] = acc[i][j];  // the lower half
    }
  }
}
