#version 450
#extension GL_GOOGLE_include_directive : require
// Per coordinate row (3 per vertex), for one parameter vector x of XVectors: the model-frame position
// a_id + E_id alpha + E_exp delta and the albedo a_alb + E_alb beta (energy.cc: VertexCache), so
// that the per-pixel pass reads three vertices instead of re-summing the bases per pixel. The
// bases are column-major here (one coefficient's column contiguous) and one invocation takes one
// row, so neighbouring invocations read neighbouring memory (vector loads, no gathers).
layout(local_size_x = 64) in;
#include "tracker_common.glsl"

layout(std430, set = 0, binding = 0) readonly buffer Params { TrackParams params; };
layout(std430, set = 0, binding = 1) readonly buffer XVectors { float xs[]; };
layout(std430, set = 0, binding = 2) readonly buffer Base { float base[]; };
layout(std430, set = 0, binding = 3) readonly buffer MeanShape { float mean_shape[]; };
layout(std430, set = 0, binding = 4) readonly buffer IdentityBasis { float identity_basis[]; };      // column-major 3N x K_id
layout(std430, set = 0, binding = 5) readonly buffer ExpressionBasis { float expression_basis[]; };  // column-major 3N x K_exp
layout(std430, set = 0, binding = 6) readonly buffer MeanAlbedo { float mean_albedo[]; };
layout(std430, set = 0, binding = 7) readonly buffer AlbedoBasis { float albedo_basis[]; };  // column-major 3N x K_alb
layout(std430, set = 0, binding = 8) writeonly buffer Vertices { float vertices[]; };  // per slot: positions (3N) | albedos (3N)
// a_id + E_id alpha (3N) | albedo (3N) of the base coefficients: while identity and albedo are
// not solved (tracking) they are the same for every x, so mode 1 computes them once per
// linearisation and mode 2 adds only the expression part (52 of the real model's 142
// coefficients per row; the identity sum dominated the pass on lavapipe).
layout(std430, set = 0, binding = 9) buffer IdentityCache { float identity_cache[]; };

layout(push_constant) uniform Push {
  uint x_slot;  // first slot; workgroup row y handles slot x_slot + y
  uint mode;    // 0 full sums, 1 fill identity_cache from the base, 2 identity_cache + expression
} pc;

const uint kMaxCoefficients = 512u;
shared float coefficients[kMaxCoefficients];  // alpha | beta | delta

void main() {
  const uint lid = gl_LocalInvocationID.x;
  const uint slot = pc.x_slot + gl_WorkGroupID.y;
  const uint xo = slot * params.n;
  const uint model_id = params.model_id, model_alb = params.model_alb, model_exp = params.model_exp;
  const uint total = model_id + model_alb + model_exp;
  for (uint q = lid; q < total; q += 64u) {
    float value = base[q];
    if (q < model_id) {
      if (q < params.k_id) value = xs[xo + params.o_id + q];
    } else if (q < model_id + model_alb) {
      if (q - model_id < params.k_alb) value = xs[xo + params.o_alb + q - model_id];
    } else if (q - model_id - model_alb < params.k_exp) {
      value = xs[xo + params.o_exp + q - model_id - model_alb];
    }
    coefficients[q] = value;
  }
  barrier();
  const uint rows = 3u * params.num_vertices;
  const uint row = gl_GlobalInvocationID.x;
  if (row >= rows) return;
  if (pc.mode == 1u) {
    float p = mean_shape[row];
    for (uint q = 0u; q < model_id; ++q) p += identity_basis[q * rows + row] * base[q];
    float a = mean_albedo[row];
    for (uint q = 0u; q < model_alb; ++q) a += albedo_basis[q * rows + row] * base[model_id + q];
    identity_cache[row] = p;
    identity_cache[rows + row] = a;
    return;
  }
  float p, a;
  if (pc.mode == 2u) {
    p = identity_cache[row];
    a = identity_cache[rows + row];
  } else {
    p = mean_shape[row];
    for (uint q = 0u; q < model_id; ++q) p += identity_basis[q * rows + row] * coefficients[q];
    a = mean_albedo[row];
    for (uint q = 0u; q < model_alb; ++q) a += albedo_basis[q * rows + row] * coefficients[model_id + q];
  }
  for (uint q = 0u; q < model_exp; ++q) p += expression_basis[q * rows + row] * coefficients[model_id + model_alb + q];
  vertices[2u * slot * rows + row] = p;
  vertices[(2u * slot + 1u) * rows + row] = a;
}
