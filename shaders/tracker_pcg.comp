#version 450
#extension GL_GOOGLE_include_directive : require
// Jacobi-preconditioned CG on (J^T J + D) dx = -J^T r, D = lambda diag(J^T J), in one workgroup
// (one unknown per invocation, n <= 256), step for step the loop of core/tracker/src/pcg.cc
// started from dx = 0. The state lives in a buffer between dispatches:
//   [0] rz  [1] |b|  [2] done  [3] iterations  [4] initial |r|  [5] final |r|  [6] converged
//   [16 + k n ...] x (= dx), r, z, p, inverse diagonal, diagonal   (k = 0..5)
// Stages:
//   0 init, matrix-free: input = per-chunk partials of [J^T r | colsum J^2] (tracker_jt.comp
//     mode 0), summed here over `groups` chunks
//   1 init + every iteration, assembled: input = [J^T J | J^T r], n rows of n + 1
//   2 one iteration, matrix-free: input = per-chunk partials of J^T J p (tracker_jt.comp mode 1)
//   3 trial parameters for step control: xs[1 + h] = clamp(xs[0] + 0.5^h dx), h < num_trials
layout(local_size_x = 256) in;
#include "tracker_common.glsl"

layout(std430, set = 0, binding = 0) readonly buffer Input { float input_vector[]; };
layout(std430, set = 0, binding = 1) buffer State { float state[]; };
layout(std430, set = 0, binding = 2) buffer XVectors { float xs[]; };
layout(std430, set = 0, binding = 3) readonly buffer Params { TrackParams params; };  // groups = kSizeFromParams

layout(push_constant) uniform Push {
  uint stage, n, max_iterations, num_trials;
  uint o_exp, k_exp, clamp_expression, groups;  // groups: partials to sum in stages 0 and 2
  float tolerance, damping;
} pc;

const uint kX = 16u;
shared float reduction[256];
shared float p_shared[256];

float reduce_sum(float v) {
  const uint lid = gl_LocalInvocationID.x;
  reduction[lid] = v;
  barrier();
  for (uint s = 128u; s > 0u; s >>= 1) {
    if (lid < s) reduction[lid] += reduction[lid + s];
    barrier();
  }
  const float result = reduction[0];
  barrier();
  return result;
}

// Sum over the chunks of entry e of partials laid out as groups x stride (the chunks of
// tracker_jt.comp over the level's rows when the device-driven loop decides them).
float chunk_sum(uint e, uint stride) {
  const uint groups = pc.groups != kSizeFromParams
                          ? pc.groups
                          : (system_rows(params.num_pixels, params.num_landmarks, params.num_regularizer) + kJtChunkRows - 1u) /
                                kJtChunkRows;
  float s = 0.0;
  for (uint g = 0u; g < groups; ++g) s += input_vector[g * stride + e];
  return s;
}

// [J^T J | J^T r] from tracker_jtj.comp: n rows of n + 1.
uint matrix_index(uint a, uint b) { return a * (pc.n + 1u) + b; }

// Registers of this invocation's unknown and the shared scalars.
float x, r, z, p, inv_diag, diag;
float rz, b_norm, done, iterations, initial_norm, final_norm, converged;

void load_state(uint i, bool in_range) {
  rz = state[0];
  b_norm = state[1];
  done = state[2];
  iterations = state[3];
  initial_norm = state[4];
  final_norm = state[5];
  converged = state[6];
  if (in_range) {
    x = state[kX + i];
    r = state[kX + pc.n + i];
    z = state[kX + 2u * pc.n + i];
    p = state[kX + 3u * pc.n + i];
    inv_diag = state[kX + 4u * pc.n + i];
    diag = state[kX + 5u * pc.n + i];
  } else {
    x = r = z = p = inv_diag = diag = 0.0;
  }
}

void store_state(uint i, bool in_range) {
  barrier();  // every invocation has read the scalars before invocation 0 overwrites them
  if (gl_LocalInvocationID.x == 0u) {
    state[0] = rz;
    state[1] = b_norm;
    state[2] = done;
    state[3] = iterations;
    state[4] = initial_norm;
    state[5] = final_norm;
    state[6] = converged;
  }
  if (in_range) {
    state[kX + i] = x;
    state[kX + pc.n + i] = r;
    state[kX + 2u * pc.n + i] = z;
    state[kX + 3u * pc.n + i] = p;
    state[kX + 4u * pc.n + i] = inv_diag;
    state[kX + 5u * pc.n + i] = diag;
  }
}

void initialise(float jtr, float jj) {
  const float b = -jtr;
  diag = jj * (1.0 + pc.damping);
  inv_diag = diag > 0.0 ? 1.0 / diag : 0.0;
  x = 0.0;
  r = b;
  b_norm = sqrt(reduce_sum(b * b));
  initial_norm = b_norm;
  final_norm = initial_norm;
  iterations = 0.0;
  converged = 0.0;
  done = 0.0;
  z = 0.0;
  p = 0.0;
  rz = 0.0;
  if (b_norm == 0.0 || initial_norm <= pc.tolerance * b_norm) {
    converged = 1.0;
    done = 1.0;
    return;
  }
  z = inv_diag * r;
  p = z;
  rz = reduce_sum(r * z);
}

// One CG step with q = A p of this invocation's unknown.
void iterate(float q) {
  const float pq = reduce_sum(p * q);
  if (!(pq > 0.0) || isinf(pq) || isnan(pq)) {
    done = 1.0;
    return;
  }
  const float step = rz / pq;
  x += step * p;
  r -= step * q;
  iterations += 1.0;
  final_norm = sqrt(reduce_sum(r * r));
  if (final_norm <= pc.tolerance * b_norm) {
    converged = 1.0;
    done = 1.0;
    return;
  }
  z = inv_diag * r;
  const float rz_next = reduce_sum(r * z);
  p = z + (rz_next / rz) * p;
  rz = rz_next;
}

void main() {
  const uint i = gl_LocalInvocationID.x;
  const bool in_range = i < pc.n;
  if (pc.stage == 3u) {
    if (!in_range) return;
    const float x0 = xs[i];
    const float dx = state[kX + i];
    const bool clamped = pc.clamp_expression != 0u && i >= pc.o_exp && i < pc.o_exp + pc.k_exp;
    float scale = 1.0;
    for (uint h = 0u; h < pc.num_trials; ++h, scale *= 0.5) {
      float v = x0 + scale * dx;
      if (clamped) v = clamp(v, 0.0, 1.0);
      xs[(1u + h) * pc.n + i] = v;
    }
    return;
  }
  if (pc.stage == 0u) {
    load_state(i, false);
    initialise(in_range ? chunk_sum(i, 2u * pc.n) : 0.0, in_range ? chunk_sum(pc.n + i, 2u * pc.n) : 0.0);
    store_state(i, in_range);
    return;
  }
  if (pc.stage == 1u) {
    load_state(i, false);
    initialise(in_range ? input_vector[matrix_index(i, pc.n)] : 0.0, in_range ? input_vector[matrix_index(i, i)] : 0.0);
    for (uint it = 0u; it < pc.max_iterations && done == 0.0; ++it) {
      p_shared[i] = p;
      barrier();
      float q = 0.0;
      if (in_range) {
        for (uint k = 0u; k < pc.n; ++k) q += (k == i ? diag : input_vector[matrix_index(i, k)]) * p_shared[k];
      }
      barrier();
      iterate(q);
    }
    store_state(i, in_range);
    return;
  }
  // stage 2
  load_state(i, in_range);
  if (done != 0.0) return;
  const float q = in_range ? chunk_sum(i, pc.n) + (pc.damping / (1.0 + pc.damping)) * diag * p : 0.0;
  iterate(q);
  store_state(i, in_range);
}
