#version 450
#extension GL_GOOGLE_include_directive : require
// Residuals r and (mode 1) the dense Jacobian J, one invocation per item, exactly the energy of
// core/tracker/src/energy.cc (EvaluateResiduals) in float:
//   items [0, P)          pixels: rows 8i..8i+7 = point (3), plane (2), colour (3, read through
//                         the projection: EnergyOptions::color_follows_projection); a term the
//                         pixel does not carry has zero rows (they add nothing to E, J^T J, J^T r)
//   items [P, P + L)      landmarks: 2 rows each, after the pixel rows
//   items [P + L, ... R)  regulariser: 1 row each (identity, albedo if shared, then expression)
// J is written column-major (column stride params.rows; tracker_jt/jtj read it as vec4s) and,
// for inspection only, also row-major. Every invocation also adds its squared residuals per term to
// a per-workgroup partial sum (energy_partials[(slot_base + group) * 5 + term]).
layout(local_size_x = 64) in;
#include "tracker_common.glsl"

layout(std430, set = 0, binding = 0) readonly buffer Params { TrackParams params; };
layout(std430, set = 0, binding = 1) readonly buffer XVectors { float xs[]; };
layout(std430, set = 0, binding = 2) readonly buffer Base { float base[]; };  // alpha | beta | delta | 1/sigma_id | 1/sigma_alb
layout(std430, set = 0, binding = 3) readonly buffer Vertices { float vertices[]; };  // tracker_vertices.comp
layout(std430, set = 0, binding = 4) readonly buffer IdentityBasis { float identity_basis[]; };      // row-major 3N x K_id
layout(std430, set = 0, binding = 5) readonly buffer ExpressionBasis { float expression_basis[]; };  // row-major 3N x K_exp
layout(std430, set = 0, binding = 7) readonly buffer AlbedoBasis { float albedo_basis[]; };  // row-major 3N x K_alb
layout(std430, set = 0, binding = 8) readonly buffer Items { uint items[]; };
layout(std430, set = 0, binding = 9) readonly buffer Landmarks { vec4 landmarks[]; };
layout(std430, set = 0, binding = 10) readonly buffer Input { vec4 input_data[]; };
layout(std430, set = 0, binding = 11) readonly buffer CameraNormals { vec4 camera_normals[]; };
layout(std430, set = 0, binding = 12) writeonly buffer Residuals { float residuals[]; };
layout(std430, set = 0, binding = 13) writeonly buffer Jacobian { float jacobian[]; };
layout(std430, set = 0, binding = 14) writeonly buffer EnergyPartials { float energy_partials[]; };
// J again, column-major (rows contiguous per column): tracker_jt.comp's J p reads it with
// contiguous loads where the row-major copy would need a gather per element.
layout(std430, set = 0, binding = 15) writeonly buffer JacobianColumns { float jacobian_columns[]; };

layout(push_constant) uniform Push {
  uint x_slot;  // first x in XVectors; workgroup row y evaluates x slot x_slot + y
  uint write_jacobian;  // 0 residuals only, 1 J column-major, 2 J column- and row-major
} pc;

shared float reduction[5][64];
// Lighting and pose of this dispatch's x, staged once per workgroup (the shader also writes
// buffers, so the compiler would otherwise reload them from memory at every use).
shared float gamma_shared[27];
shared vec3 euler_shared, translation_shared;
uint model_id, model_alb, model_exp, n_cols, m_rows, x_slot;
bool write_residuals;  // trial slots only need their energies

void stage_coefficients() {
  const uint lid = gl_LocalInvocationID.x;
  x_slot = pc.x_slot + gl_WorkGroupID.y;
  write_residuals = pc.write_jacobian != 0u || x_slot == 0u;
  const uint xo = x_slot * params.n;
  model_id = params.model_id;
  model_alb = params.model_alb;
  model_exp = params.model_exp;
  n_cols = params.n;
  m_rows = params.rows;
  if (lid < 27u) gamma_shared[lid] = xs[xo + params.o_gam + lid];
  if (lid == 0u) {
    euler_shared = vec3(xs[xo + params.o_rot], xs[xo + params.o_rot + 1u], xs[xo + params.o_rot + 2u]);
    translation_shared = vec3(xs[xo + params.o_t], xs[xo + params.o_t + 1u], xs[xo + params.o_t + 2u]);
  }
  barrier();
}

float gamma_at(uint k) { return gamma_shared[k]; }

// Positions and albedos of this dispatch's x, from tracker_vertices.comp.
vec3 vertex_row(uint base, uint v) { return vec3(vertices[base + 3u * v], vertices[base + 3u * v + 1u], vertices[base + 3u * v + 2u]); }
vec3 model_position(uint v) { return vertex_row(2u * x_slot * 3u * params.num_vertices, v); }
vec3 vertex_albedo(uint v) { return vertex_row((2u * x_slot + 1u) * 3u * params.num_vertices, v); }

vec3 identity_column(uint v, uint q) {
  const uint row = 3u * v;
  return vec3(identity_basis[row * params.model_id + q], identity_basis[(row + 1u) * params.model_id + q],
              identity_basis[(row + 2u) * params.model_id + q]);
}
vec3 expression_column(uint v, uint q) {
  const uint row = 3u * v;
  return vec3(expression_basis[row * params.model_exp + q], expression_basis[(row + 1u) * params.model_exp + q],
              expression_basis[(row + 2u) * params.model_exp + q]);
}

mat3 frozen_rotation() {
  return rows3(vec3(params.r0[0], params.r0[1], params.r0[2]), vec3(params.r0[3], params.r0[4], params.r0[5]),
               vec3(params.r0[6], params.r0[7], params.r0[8]));
}

// Model-frame normal frozen at the linearisation: R0^T n_camera, normalised (energy.cc).
vec3 model_normal(uint v, mat3 r0) {
  const vec3 m = transpose(r0) * camera_normals[v].xyz;
  const float len = length(m);
  return len > 0.0 ? m / len : vec3(0.0);
}

void put(uint row, uint col, float value) {
  if (pc.write_jacobian == 2u) jacobian[row * n_cols + col] = value;  // row-major copy: inspection only
  jacobian_columns[col * m_rows + row] = value;
}

void evaluate_pixel(uint item, inout float e[5]) {
  const uint base_word = kPixelItemWords * item;
  const uint pixel = items[base_word];
  const uint flags = items[base_word + 1u];
  const uint vert[3] = uint[3](items[base_word + 2u], items[base_word + 3u], items[base_word + 4u]);
  const float b[3] = float[3](uintBitsToFloat(items[base_word + 5u]), uintBitsToFloat(items[base_word + 6u]),
                              uintBitsToFloat(items[base_word + 7u]));
  const vec3 euler = euler_shared;
  const vec3 t = translation_shared;
  mat3 r;
  mat3 dr[3];
  rotation_with_derivatives(euler, r, dr);
  const mat3 r0 = frozen_rotation();

  vec3 n_model[3];
  vec3 v_bar = vec3(0.0), n_bar = vec3(0.0);
  for (int k = 0; k < 3; ++k) {
    n_model[k] = model_normal(vert[k], r0);
    v_bar += b[k] * model_position(vert[k]);
    n_bar += b[k] * n_model[k];
  }
  const vec3 xs_point = r * v_bar + t;
  const vec3 input_point = input_data[kInputVec4sPerPixel * pixel].xyz;
  const vec3 input_normal = input_data[kInputVec4sPerPixel * pixel + 1u].xyz;
  const vec3 input_color = input_data[kInputVec4sPerPixel * pixel + 2u].xyz;
  const vec3 grad_u = input_data[kInputVec4sPerPixel * pixel + 3u].xyz;
  const vec3 grad_v = input_data[kInputVec4sPerPixel * pixel + 4u].xyz;
  const bool has_point = (flags & kFlagPoint) != 0u, has_plane = (flags & kFlagPlane) != 0u;
  const bool has_color = (flags & kFlagColor) != 0u;
  const float sp = has_point ? params.s_point : 0.0;
  const float spl = has_plane ? params.s_plane : 0.0;
  // The colour rows scaled by the square root of the pixel's robust weight (classify).
  const float sc = has_color ? params.s_col * sqrt(uintBitsToFloat(items[base_word + 8u])) : 0.0;
  const vec3 diff = (has_point || has_plane) ? xs_point - input_point : vec3(0.0);
  const float n_len = length(n_bar);
  const vec3 n_m = n_len > 0.0 ? n_bar / n_len : vec3(0.0);
  const vec3 n_s = r * n_m;

  // Shading per corner vertex.
  float y[3][9];
  vec3 albedo[3], irradiance[3];
  vec3 color = vec3(0.0);
  for (int k = 0; k < 3; ++k) {
    sh_basis(r * n_model[k], y[k]);
    albedo[k] = vertex_albedo(vert[k]);
    for (uint ch = 0u; ch < 3u; ++ch) {
      float irr = 0.0;
      for (uint q = 0u; q < 9u; ++q) irr += gamma_at(ch * 9u + q) * y[k][q];
      irradiance[k][ch] = irr;
    }
    color += b[k] * albedo[k] * irradiance[k];
  }
  // Colour through the projection (EnergyOptions::color_follows_projection): the input colour
  // where X_S projects, to first order around the pixel, C_I + grad_u du + grad_v dv; the
  // projection's 2 x 3 derivative rows dproj_u, dproj_v turn a motion of X_S into (du, dv).
  const float iz = 1.0 / xs_point.z;
  const vec3 dproj_u = vec3(params.fx * iz, 0.0, -params.fx * xs_point.x * iz * iz);
  const vec3 dproj_v = vec3(0.0, params.fy * iz, -params.fy * xs_point.y * iz * iz);
  const vec2 shift = vec2(params.fx * xs_point.x * iz + params.cx - float(pixel % params.width),
                          params.fy * xs_point.y * iz + params.cy - float(pixel / params.width));
  color -= grad_u * shift.x + grad_v * shift.y;
  if (!has_color) color = input_color;

  float rv[8];
  for (int c = 0; c < 3; ++c) rv[c] = sp * diff[c];
  rv[3] = spl * dot(input_normal, diff);
  rv[4] = spl * dot(n_s, diff);
  for (int c = 0; c < 3; ++c) rv[5 + c] = sc * (color[c] - input_color[c]);
  const uint row0 = kRowsPerPixel * item;
  if (write_residuals) {
    for (uint k = 0u; k < 8u; ++k) residuals[row0 + k] = rv[k];
  }
  e[0] += rv[0] * rv[0] + rv[1] * rv[1] + rv[2] * rv[2];
  e[1] += rv[3] * rv[3] + rv[4] * rv[4];
  e[2] += rv[5] * rv[5] + rv[6] * rv[6] + rv[7] * rv[7];
  if (pc.write_jacobian == 0u) return;

  // Shape columns (identity, expression): dX = R sum_k b_k E[k](q).
  for (uint q = 0u; q < params.k_id + params.k_exp; ++q) {
    const bool is_id = q < params.k_id;
    const uint qq = is_id ? q : q - params.k_id;
    const uint col = is_id ? params.o_id + qq : params.o_exp + qq;
    vec3 ebar = vec3(0.0);
    for (int k = 0; k < 3; ++k) ebar += b[k] * (is_id ? identity_column(vert[k], qq) : expression_column(vert[k], qq));
    const vec3 dx = r * ebar;
    for (uint c = 0u; c < 3u; ++c) put(row0 + c, col, sp * dx[c]);
    put(row0 + 3u, col, spl * dot(input_normal, dx));
    put(row0 + 4u, col, spl * dot(n_s, dx));
    const vec3 dmoved = -sc * (grad_u * dot(dproj_u, dx) + grad_v * dot(dproj_v, dx));
    for (uint c = 0u; c < 3u; ++c) put(row0 + 5u + c, col, dmoved[c]);
  }
  // Albedo columns: dC_c = sum_k b_k irradiance_kc E_alb[k, c](q).
  for (uint q = 0u; q < params.k_alb; ++q) {
    const uint col = params.o_alb + q;
    for (uint c = 0u; c < 5u; ++c) put(row0 + c, col, 0.0);
    for (uint c = 0u; c < 3u; ++c) {
      float s = 0.0;
      for (int k = 0; k < 3; ++k) s += b[k] * irradiance[k][c] * albedo_basis[(3u * vert[k] + c) * params.model_alb + q];
      put(row0 + 5u + c, col, sc * s);
    }
  }
  // Lighting columns: only the channel's own 9 coefficients.
  for (uint g = 0u; g < 27u; ++g) {
    const uint col = params.o_gam + g;
    const uint ch = g / 9u, q = g % 9u;
    for (uint c = 0u; c < 5u; ++c) put(row0 + c, col, 0.0);
    float s = 0.0;
    for (int k = 0; k < 3; ++k) s += b[k] * albedo[k][ch] * y[k][q];
    for (uint c = 0u; c < 3u; ++c) put(row0 + 5u + c, col, c == ch ? sc * s : 0.0);
  }
  // Rotation columns.
  for (uint a = 0u; a < 3u; ++a) {
    const uint col = params.o_rot + a;
    const vec3 dx = dr[a] * v_bar;
    for (uint c = 0u; c < 3u; ++c) put(row0 + c, col, sp * dx[c]);
    put(row0 + 3u, col, spl * dot(input_normal, dx));
    put(row0 + 4u, col, spl * (dot(n_s, dx) + dot(dr[a] * n_m, diff)));
    vec3 dcolor = vec3(0.0);
    for (int k = 0; k < 3; ++k) {
      vec3 grad[9];
      sh_basis_gradient(r * n_model[k], grad);
      const vec3 dn = dr[a] * n_model[k];
      for (uint ch = 0u; ch < 3u; ++ch) {
        float d_irr = 0.0;
        for (uint q = 1u; q < 9u; ++q) d_irr += gamma_at(ch * 9u + q) * dot(grad[q], dn);
        dcolor[ch] += b[k] * albedo[k][ch] * d_irr;
      }
    }
    dcolor -= grad_u * dot(dproj_u, dx) + grad_v * dot(dproj_v, dx);
    for (uint c = 0u; c < 3u; ++c) put(row0 + 5u + c, col, sc * dcolor[c]);
  }
  // Translation columns.
  for (uint a = 0u; a < 3u; ++a) {
    const uint col = params.o_t + a;
    vec3 dx = vec3(0.0);
    dx[a] = 1.0;
    for (uint c = 0u; c < 3u; ++c) put(row0 + c, col, sp * dx[c]);
    put(row0 + 3u, col, spl * input_normal[a]);
    put(row0 + 4u, col, spl * n_s[a]);
    const vec3 dmoved = -sc * (grad_u * dproj_u[a] + grad_v * dproj_v[a]);
    for (uint c = 0u; c < 3u; ++c) put(row0 + 5u + c, col, dmoved[c]);
  }
}

void evaluate_landmark(uint l, inout float e[5]) {
  const vec4 lm = landmarks[l];
  const uint v = floatBitsToUint(lm.x);
  const vec3 euler = euler_shared;
  const vec3 t = translation_shared;
  mat3 r;
  mat3 dr[3];
  rotation_with_derivatives(euler, r, dr);
  const vec3 p = model_position(v);
  const vec3 x = r * p + t;
  const float s = params.s_lan * sqrt(lm.w);
  const float iz = 1.0 / x.z;
  const vec2 uv = vec2(params.fx * x.x * iz + params.cx, params.fy * x.y * iz + params.cy);
  const vec2 res = s * (uv - lm.yz);
  const uint row0 = kRowsPerPixel * params.num_pixels + 2u * l;
  if (write_residuals) {
    residuals[row0] = res.x;
    residuals[row0 + 1u] = res.y;
  }
  e[3] += dot(res, res);
  if (pc.write_jacobian == 0u) return;
  // dr = s * dproj (2 x 3); GLSL matrices are column-major: mat3x2 has 3 columns of vec2.
  const mat3x2 dproj = s * mat3x2(vec2(params.fx * iz, 0.0), vec2(0.0, params.fy * iz),
                                  vec2(-params.fx * x.x * iz * iz, -params.fy * x.y * iz * iz));
  for (uint col = 0u; col < params.n; ++col) {
    put(row0, col, 0.0);
    put(row0 + 1u, col, 0.0);
  }
  for (uint q = 0u; q < params.k_id; ++q) {
    const vec2 d = dproj * (r * identity_column(v, q));
    put(row0, params.o_id + q, d.x);
    put(row0 + 1u, params.o_id + q, d.y);
  }
  for (uint q = 0u; q < params.k_exp; ++q) {
    const vec2 d = dproj * (r * expression_column(v, q));
    put(row0, params.o_exp + q, d.x);
    put(row0 + 1u, params.o_exp + q, d.y);
  }
  for (uint a = 0u; a < 3u; ++a) {
    const vec2 d = dproj * (dr[a] * p);
    put(row0, params.o_rot + a, d.x);
    put(row0 + 1u, params.o_rot + a, d.y);
    put(row0, params.o_t + a, dproj[a].x);
    put(row0 + 1u, params.o_t + a, dproj[a].y);
  }
}

void evaluate_regularizer(uint q, inout float e[5]) {
  const uint row = kRowsPerPixel * params.num_pixels + 2u * params.num_landmarks + q;
  uint col;
  float inv;
  uint rest = q;
  const uint shared_id = params.regularize_shared != 0u ? params.k_id : 0u;
  const uint shared_alb = params.regularize_shared != 0u ? params.k_alb : 0u;
  if (rest < shared_id) {
    col = params.o_id + rest;
    inv = params.s_reg * base[params.model_id + params.model_alb + params.model_exp + rest];
  } else if (rest - shared_id < shared_alb) {
    rest -= shared_id;
    col = params.o_alb + rest;
    inv = params.s_reg * base[2u * params.model_id + params.model_alb + params.model_exp + rest];
  } else {
    rest -= shared_id + shared_alb;
    col = params.o_exp + rest;
    // Eq. 11 plus the reweighted L1 prior, its weight frozen at the linearisation point's delta
    // (energy.cc).
    const float delta0 = abs(base[params.model_id + params.model_alb + rest]);
    inv = sqrt(params.s_reg_exp * params.s_reg_exp + params.w_sparse_exp / (delta0 + params.sparse_eps_exp));
  }
  const float value = inv * xs[x_slot * params.n + col];
  if (write_residuals) residuals[row] = value;
  e[4] += value * value;
  if (pc.write_jacobian == 0u) return;
  for (uint c = 0u; c < params.n; ++c) put(row, c, c == col ? inv : 0.0);
}

void main() {
  const uint item = gl_GlobalInvocationID.x;
  const uint lid = gl_LocalInvocationID.x;
  float e[5] = float[5](0.0, 0.0, 0.0, 0.0, 0.0);
  stage_coefficients();
  const uint p = params.num_pixels, l = params.num_landmarks;
  if (item < p) {
    evaluate_pixel(item, e);
  } else if (item < p + l) {
    evaluate_landmark(item - p, e);
  } else if (item < p + l + params.num_regularizer) {
    evaluate_regularizer(item - p - l, e);
  }
  for (int k = 0; k < 5; ++k) reduction[k][lid] = e[k];
  barrier();
  for (uint stride = 32u; stride > 0u; stride >>= 1) {
    if (lid < stride) {
      for (int k = 0; k < 5; ++k) reduction[k][lid] += reduction[k][lid + stride];
    }
    barrier();
  }
  if (lid == 0u) {
    const uint slot = x_slot * gl_NumWorkGroups.x + gl_WorkGroupID.x;
    for (uint k = 0u; k < 5u; ++k) energy_partials[slot * 5u + k] = reduction[k][0];
  }
}
