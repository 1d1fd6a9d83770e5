#version 450
// The identity and albedo part of Eq. 1-2, run only when alpha or beta change (during tracking
// both are fixed after calibration, paper Sec. 6.3):
//   base_shape = a_id + E_id alpha,   albedo = a_alb + E_alb beta.
// One thread per scalar row r in [0, 3N); bases are column-major (3N x K).
layout(local_size_x = 64) in;

layout(std430, set = 0, binding = 0) readonly buffer MeanShape { float mean_shape[]; };
layout(std430, set = 0, binding = 1) readonly buffer IdentityBasis { float identity_basis[]; };
layout(std430, set = 0, binding = 2) readonly buffer MeanAlbedo { float mean_albedo[]; };
layout(std430, set = 0, binding = 3) readonly buffer AlbedoBasis { float albedo_basis[]; };
layout(std430, set = 0, binding = 4) readonly buffer Coefficients { float coeffs[]; };  // alpha | delta | beta
layout(std430, set = 0, binding = 5) writeonly buffer BaseShape { float base_shape[]; };
layout(std430, set = 0, binding = 6) writeonly buffer Albedo { float albedo[]; };

layout(push_constant) uniform Push {
  uint rows;  // 3N
  uint num_identity;
  uint num_albedo;
  uint albedo_offset;  // index of beta_0 in coeffs
} pc;

void main() {
  const uint r = gl_GlobalInvocationID.x;
  if (r >= pc.rows) return;
  float s = mean_shape[r];
  for (uint j = 0; j < pc.num_identity; ++j) s += identity_basis[j * pc.rows + r] * coeffs[j];
  base_shape[r] = s;
  float a = mean_albedo[r];
  for (uint j = 0; j < pc.num_albedo; ++j) a += albedo_basis[j * pc.rows + r] * coeffs[pc.albedo_offset + j];
  albedo[r] = a;
}
